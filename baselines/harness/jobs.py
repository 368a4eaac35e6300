"""The benchmark's unit of work: one contender on one case at one budget K, and what it measured.

:func:`run_job` runs a :class:`Job` in this process, :func:`run_in_processes` a list of them over processes. Every job is seeded (initial states from the suite's
seeds; noise, dropout and random switching from a generator seeded by the same seeds), so a job gives the
same numbers wherever and whenever it runs.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from multiprocessing import get_context
from typing import Any

import numpy as np

from fxc_env.baselines.harness.suite import BenchmarkCase, Contender, Suite, contender_config, load_policy
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.protocol import seeded_engine
from fxc_env.utils.threads import single_threaded_children


@dataclass(frozen=True)
class Job:
    """One contender on one case at K intervals, for every seed of the suite."""

    contender: Contender
    case: BenchmarkCase
    n_intervals: int
    seeds: tuple[int, ...]
    settling_time: float
    record_trace: bool

    @property
    def cost(self) -> float:
        """Rough relative run time, to start the longest jobs first."""
        design = 50.0 * self.case.n_agents**2 if self.contender.name == "linear_sampled" else 0.0
        return self.n_intervals * (self.case.n_agents + 20.0) * len(self.seeds) + design


@dataclass
class JobResult:
    """What one job measured.

    Attributes:
        metrics: the engine's episode metrics, one ``(B,)`` array per name, plus ``final_value_gap``
            (``|achieved - predicted|`` mean position at ``T_s``, m) and ``initial_disagreement``.
        trace_times, trace: sampling instants and the median over seeds of ``D(t_k) / D(0)``
            (only for the suite's trace case).
        description: the policy's law, source, graph class and parameters (as text).
        parameters: the policy's parameters as numbers.
        guarantee: whether this run is covered by the policy's theorem.
        error: why the job could not run (a learned model that does not fit, say), else None.
    """

    job: Job
    metrics: dict[str, np.ndarray] = field(default_factory=dict)
    trace_times: np.ndarray | None = None
    trace: np.ndarray | None = None
    description: dict[str, str] = field(default_factory=dict)
    parameters: dict[str, float] = field(default_factory=dict)
    guarantee: str = ""
    error: str | None = None
    seconds: float = 0.0


def make_jobs(suite: Suite, contenders: list[Contender]) -> list[Job]:
    """Every (contender, case, K) of the suite, in table order."""
    return [
        Job(contender, case, k, suite.seeds, suite.settling_time, case == suite.trace_case)
        for contender in contenders
        for case in suite.cases
        for k in (suite.budgets if contender.sampled else (suite.fine_intervals,))
    ]


def run_in_processes(
    jobs: list[Job], workers: int | None = None, on_done: Callable[[], Any] = lambda: None
) -> list[JobResult]:
    """Run ``jobs`` over ``workers`` spawned, single-threaded processes (default: all cores, at most one per job);
    ``on_done()`` after each. The results in ``jobs``' order, each with its job as submitted."""
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    done: dict[int, JobResult] = {}
    with single_threaded_children(), ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        submitted = {pool.submit(run_job, job): i for i, job in enumerate(jobs)}
        for future in as_completed(submitted):
            result = done[submitted[future]] = future.result()
            # The job as submitted: a copy back from another process may not compare equal
            # (a Topology object, say, compares by identity).
            result.job = jobs[submitted[future]]
            on_done()
    return [done[i] for i in range(len(jobs))]


def run_job(job: Job) -> JobResult:
    """Run one job in this process (see :class:`JobResult`)."""
    start = time.perf_counter()
    result = JobResult(job)
    try:
        config = contender_config(job.contender, job.case, job.n_intervals, job.settling_time)
        trust = {"trusted": job.contender.trusted, "allow_out_of_domain": job.contender.allow_out_of_domain}
        policy = load_policy(job.contender.spec, config, **trust)
    except ArgumentError as exc:
        result.error = str(exc)
        return result
    describe = getattr(policy, "describe", None)
    result.description = describe() if describe else {}
    result.parameters = policy.parameters() if hasattr(policy, "parameters") else {}
    result.guarantee = policy.guarantee() if hasattr(policy, "guarantee") else _reference_guarantee(job)

    # Each seed draws its episode (topology of a family, input limit of a set, initial state);
    # noise, dropout and random switching draw from the job's own seeded stream.
    engine, _ = seeded_engine(config, job.seeds, job_generator(job))
    d0 = engine.initial_disagreement.copy()
    trace = [np.ones(len(job.seeds))]
    obs = np.empty((engine.n_episodes, config.n_agents, config.layout.size))
    reads_graph = getattr(policy, "arch", None) == "gnn"  # a torch 'gnn' policy also reads the interval graph
    if reads_graph:
        from fxc_env.policies.torch_memory import interval_graph
    with np.errstate(all="ignore"):  # a diverging law overflows; its metrics say so
        while not engine.done:
            engine.observations(out=obs)
            actions = policy(obs, graph=interval_graph(engine, obs)) if reads_graph else policy(obs)
            engine.step(np.asarray(actions, dtype=np.float64))
            trace.append(engine.current_disagreement / d0)
        metrics = engine.batch_metrics()
    relative = metrics["relative_deadline_error"]
    metrics["relative_deadline_error"] = np.where(np.isfinite(relative), relative, np.inf)
    metrics["final_value_gap"] = np.abs(metrics["achieved_final_position"] - metrics["predicted_final_position"])
    metrics["initial_disagreement"] = d0
    result.metrics = metrics
    if job.record_trace:
        result.trace_times = config.schedule.times.copy()
        result.trace = np.median(np.array(trace), axis=1)
    result.seconds = time.perf_counter() - start
    return result


def _reference_guarantee(job: Job) -> str:
    if job.contender.spec == "reference":
        return "proven: Theorems 1-2 (limit K -> infinity; finite K leaves a residual)"
    return "learned: no guarantee"


def job_generator(job: Job) -> np.random.Generator:
    """The generator of a job's noise, dropout and random switching, seeded by its seeds and budget."""
    return np.random.default_rng([*job.seeds, job.n_intervals])
