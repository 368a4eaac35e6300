"""``fxc speed``: throughput measured side by side with the environments users would otherwise pick.

One module per table (:mod:`~fxc_env.speed.parallel`, :mod:`~fxc_env.speed.vecenv`,
:mod:`~fxc_env.speed.torchrl`, :mod:`~fxc_env.speed.training`, :mod:`~fxc_env.speed.scaling`,
:mod:`~fxc_env.speed.models`, :mod:`~fxc_env.speed.cuda`; each docstring says what it times and
against what), the timing blocks they share in :mod:`~fxc_env.speed.timing`, and the command in
:mod:`~fxc_env.speed.command`. Contenders alternate round by round on one machine, threads pinned to
one; each figure is the median over rounds, and the run closes with every goal line, "met" or "not
met". The docs' benchmark page lists the tables and their goals.
"""
