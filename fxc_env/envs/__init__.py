"""The environment front ends over the engine: PettingZoo (parallel and AEC), the SB3 VecEnv, TorchRL.

Layer 4. ``fxc_consensus_v0`` is the versioned module (``env``, ``parallel_env``, ``raw_env``);
:mod:`~fxc_env.envs.vec_env` and :mod:`~fxc_env.envs.torch_env` are the batched forms;
:mod:`~fxc_env.envs.interop` puts the PettingZoo env in TorchRL's own wrapper.
"""
