"""``fxc speed``: the throughput harness, ours beside the contenders (MPE2, VMAS, JaxMARL, TorchRL, SB3)."""
