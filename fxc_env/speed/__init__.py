"""``fxc speed``: throughput measured side by side with the environments users would otherwise pick.

One module per table (:mod:`~fxc_env.speed.parallel`, :mod:`~fxc_env.speed.vecenv`,
:mod:`~fxc_env.speed.torchrl`, :mod:`~fxc_env.speed.training`, :mod:`~fxc_env.speed.scaling`,
:mod:`~fxc_env.speed.models`, :mod:`~fxc_env.speed.cuda`), the timing blocks they share in
:mod:`~fxc_env.speed.timing`, and the command in :mod:`~fxc_env.speed.command`.

The CPU tables (the default), all from one run on one machine, contenders alternated round
by round so that both see the same machine state; each figure is the median over rounds:

1. ``parallel``: our PettingZoo ParallelEnv against MPE2 ``simple_spread_v3`` (continuous
   actions) at N = 6 and N = 20, in env-steps per second through the dict API, random actions
   (the goal: >= 20x MPE2 at N = 6);
2. ``vecenv``: our SB3 ``ConsensusVecEnv`` driven by the reference policy against VMAS on the
   CPU (``navigation`` and ``simple_spread``, random actions) at the same total agent count
   (>= 1e5), in agent-steps per second;
3. ``torchrl``: at N = 6 (``paper_fig1``), agent-steps per second of the environment in
   TorchRL's ``PettingZooWrapper`` (:func:`fxc_env.envs.interop.torchrl_wrapper`, one episode), of the
   native batched :class:`fxc_env.envs.torch_env.ConsensusTorchEnv` (``env.step`` + ``step_mdp``,
   ``reference_policy(env)``) at B x N of about 6e3 and 1e5 agents, and of the batched engine
   alone (observations -> :class:`~fxc_env.policies.reference.ReferencePolicy` -> step) on torch and on
   numpy at the same sizes; the goals: ``ConsensusTorchEnv`` >= 1000x the wrapper at 6e3
   agents, and >= 50% of the numpy engine at 1e5 agents;
4. ``training``: PPO end to end per back end on ``paper_fig1`` (it trains: left out by
   ``--skip-contenders``);
5. ``scaling``: one episode on ``random`` digraphs (mean in-degree 4) from N = 10^2 to 10^6,
   for ``dim`` = 1, 2 and 3: seconds per sampling interval (observation + reference policy +
   exact step), per agent-step, and the peak memory traced while building and stepping;
   then the time per interval at ``dim`` = 2 and 3 over that at ``dim`` = 1, at N = 10^5
   (the goal: ``dim`` = 2 within 3x), and one interval at N = 10^6, ``dim`` = 1 (the goal:
   <= 0.1 s);
6. ``models``: time per agent-step of every agent model at N = 10^5 against the double
   integrator's closed forms (the goal: the general path within 10x).

The run closes with every goal line it printed, each "met" or "not met".

``--device cuda`` runs the ``cuda`` table instead: the engine and the reference on torch CUDA
(float64, ``dim`` = 1) from 1e4 to 1e8 agents (N = 1000 random digraphs and N = 6
``paper_fig1``, B episodes each; a size that does not fit in the GPU's memory is skipped with
a note), single episodes of N = 1e6 and 1e7 (ms per interval), and, where importable, VMAS
``simple_spread`` (torch CUDA) and JaxMARL ``MPE_simple_spread_v3`` (``jit`` + ``vmap``) at
262,144 environments, alternated with the engine round by round. ``--only`` picks tables by
name (``--only torchrl``, ``--only cuda``, ``--only parallel,scaling``).

Threads are pinned to one (``OMP_NUM_THREADS`` and friends are set before numpy or torch
start, by re-running the command; ``torch.set_num_threads(1)``). MPE2 and VMAS come from
the optional extra ``bench``, TorchRL from ``torchrl``:
``.venv/bin/pip install -c constraints.txt -e ".[bench,torchrl]"``. Without the ``fxc``
command (a bare GPU machine), ``python -m fxc_env.speed --device cuda`` runs the same code.
"""
