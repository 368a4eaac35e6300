"""``fxc train --backend rllib``: PPO in Ray RLlib, one module shared by every agent.

The environment reaches RLlib through :class:`ConsensusRLlibEnv` (RLlib's PettingZoo wrapper, whose
``render()`` passes an argument PettingZoo's does not take). Env runners sample on a local Ray or a cluster
(``--address``); settings are the ``rllib_<algo>`` entry of the hyperparameter file; ``--timesteps`` is rounded
up to whole iterations. The run directory is :mod:`fxc_env.training.run_dir`'s (no TensorBoard events), with:

    runs/<name>/progress.csv                         one row per iteration (:data:`PROGRESS_COLUMNS`, SB3's names)
    runs/<name>/checkpoints/rllib_<timesteps>_steps/ RLlib algorithm checkpoints (the newest is the policy)
    runs/<name>/checkpoints/rllib_<timesteps>_steps/fxc_policy.json   its training settings and domain (plain JSON:
                                                     :func:`~fxc_env.policies.saving.write_rllib_record`)
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

import fxc_env
from fxc_env.policies.learned import RLLIB_MODULE
from fxc_env.policies.saving import write_rllib_record
from fxc_env.training.args import TrainArgs, env_label, env_settings
from fxc_env.training.run_dir import RunDir, begin_run
from fxc_env.utils.cluster import ray_session

#: Columns of ``progress.csv`` (SB3's names where they mean the same, so one curve plotter serves both).
PROGRESS_COLUMNS = (
    "time/iterations",
    "time/total_timesteps",
    "time/env_steps",
    "rollout/ep_rew_mean",
    "rollout/episodes",
    "time/iteration_seconds",
)


class ConsensusRLlibEnv(ParallelPettingZooEnv):
    """``fxc_env.parallel_env(**config)`` as an RLlib ``MultiAgentEnv``.

    RLlib's wrapper with ``render()`` without an argument and agents in the environment's order (the wrapper
    takes them from a set, whose order changes from process to process).
    """

    def __init__(self, config: dict[str, Any] | None = None) -> None:
        super().__init__(fxc_env.parallel_env(**dict(config or {})))
        self.agents = list(self.par_env.possible_agents)
        self.possible_agents = list(self.par_env.possible_agents)

    def render(self) -> Any:
        return self.par_env.render()


def env_config(args: TrainArgs, params: dict[str, Any]) -> dict[str, Any]:
    """Keyword arguments of the environment each env runner builds."""
    return env_settings(args, params)


def algorithm_config(args: TrainArgs, params: dict[str, Any]) -> Any:
    """The RLlib ``PPOConfig`` of this run: one module for all agents, actions clipped to the Box."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig

    training = dict(params["algo"])
    model = training.pop("model", {})
    return (
        PPOConfig()
        .environment(ConsensusRLlibEnv, env_config=env_config(args, params), clip_actions=True, normalize_actions=False)
        .env_runners(num_env_runners=args.num_env_runners, num_envs_per_env_runner=args.envs_per_runner)
        .multi_agent(policies={RLLIB_MODULE}, policy_mapping_fn=_shared_module)
        .training(**training)
        .rl_module(model_config=DefaultModelConfig(**model))
        .debugging(seed=args.seed)
    )


def _shared_module(agent_id: str, episode: Any, **kwargs: Any) -> str:
    return RLLIB_MODULE


def latest_rllib_checkpoint(run_dir: Path) -> Path | None:
    """The whole RLlib checkpoint with the most timesteps in ``run_dir/checkpoints`` (None if there is none)."""
    return RunDir(run_dir, "rllib").newest_checkpoint()


def save(algo: Any, run: RunDir, timesteps: int, config: Any) -> Path:
    """Save the whole algorithm (module, optimiser, connectors, counters) as ``rllib_<timesteps>_steps``, and
    beside it the training settings and domain of ``config``, the training EnvConfig (RLlib records neither)."""
    path = run.checkpoint_path(timesteps)
    algo.save_to_path(str(path.resolve()))
    write_rllib_record(path, config, RLLIB_MODULE)
    return path


def train_rllib(args: TrainArgs) -> Path:
    """Run (or resume) RLlib PPO training; returns the run directory."""
    args, params, run, checkpoint = begin_run(args, "rllib")
    config = fxc_env.make_config(**env_config(args, params))
    n_agents = config.n_agents
    per_iteration = int(params["algo"]["train_batch_size_per_learner"]) * n_agents
    iterations = math.ceil(args.timesteps / per_iteration)
    save_every = max(1, math.ceil(args.checkpoint_every / per_iteration))

    with ray_session("--backend rllib", args.address) as ray:
        algo = algorithm_config(args, params).build_algo()
        if checkpoint is not None:
            algo.restore_from_path(str(checkpoint.resolve()))
            run.announce_resume(checkpoint, f"iteration {algo.iteration}")
        else:
            record = {"args": dataclasses.asdict(args), "hyperparams": params, "n_agents": n_agents}
            cpus = ray.cluster_resources().get("CPU")
            run.start({**record, "timesteps_per_iteration": per_iteration, "ray_cluster_cpus": cpus})
        print(
            f"fxc train: RLlib PPO on {env_label(args)} (N = {n_agents}, one shared module), "
            f"{args.num_env_runners} env runner(s) x {args.envs_per_runner} env(s), "
            f"{ray.cluster_resources().get('CPU', 0):g} CPUs in the Ray cluster; "
            f"{iterations} iteration(s) of {per_iteration} timesteps"
        )

        resumed_at = (algo.iteration, algo.iteration * per_iteration) if checkpoint is not None else None
        try:
            with (
                run.progress(PROGRESS_COLUMNS, tensorboard=False, resumed_at=resumed_at) as progress,
                run.interruptible(
                    "iteration", lambda: save(algo, run, algo.iteration * per_iteration, config)
                ) as interrupted,
            ):
                while algo.iteration < iterations and not interrupted:
                    row = progress_row(algo.train(), n_agents)
                    progress.write(row)
                    print(
                        f"  iteration {algo.iteration}/{iterations}: {row['time/total_timesteps']} timesteps, "
                        f"mean episode return {row['rollout/ep_rew_mean']:.4g} "
                        f"over {row['rollout/episodes']} episodes, {row['time/iteration_seconds']:.1f} s"
                    )
                    if algo.iteration % save_every == 0 or algo.iteration == iterations:
                        save(algo, run, algo.iteration * per_iteration, config)
        finally:
            logdir = Path(algo.logdir)
            algo.stop()
            if logdir.is_dir() and not any(logdir.iterdir()):
                logdir.rmdir()  # RLlib's empty ~/ray_results/<date> directory; our logs are in run_dir

    # -------------------------------------------------------------- artefacts
    run.finish(algo.iteration * per_iteration, latest_rllib_checkpoint(run.path))
    return run.path


def progress_row(result: dict[str, Any], n_agents: int) -> dict[str, Any]:
    """One ``progress.csv`` row from an RLlib result; the return is per agent (= the team's)."""
    runners = result.get("env_runners", {})
    env_steps = int(runners.get("num_env_steps_sampled_lifetime", result.get("num_env_steps_sampled_lifetime", 0)))
    team_return = float(runners.get("episode_return_mean", math.nan))
    return {
        "time/iterations": int(result["training_iteration"]),
        "time/total_timesteps": env_steps * n_agents,
        "time/env_steps": env_steps,
        "rollout/ep_rew_mean": team_return / n_agents,
        "rollout/episodes": int(runners.get("num_episodes", 0)),
        "time/iteration_seconds": float(result.get("time_this_iter_s", math.nan)),
    }
