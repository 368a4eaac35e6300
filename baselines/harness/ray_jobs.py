"""The benchmark's jobs as Ray tasks (one CPU, one BLAS thread each): ``fxc benchmark --ray [--address ADDR]``.

Jobs are seeded, so the results are those of the single-machine run.
"""

from __future__ import annotations

from collections.abc import Callable

from fxc_env.baselines.harness.jobs import Job, JobResult, run_job
from fxc_env.utils.cluster import ray_session
from fxc_env.utils.threads import single_thread_environment


def run_jobs_on_ray(
    jobs: list[Job],
    *,
    address: str | None = None,
    num_cpus: int | None = None,
    on_done: Callable[[int], object] | None = None,
) -> list[JobResult]:
    """Run ``jobs`` as Ray tasks (submitted in the given order); results in the order of ``jobs``.

    ``address`` joins a cluster, else a local Ray with ``num_cpus`` cores (default: all) is started and stopped;
    ``on_done(n)`` is called as ``n`` jobs finish.
    """
    with ray_session("--ray", address, num_cpus) as ray:
        task = ray.remote(num_cpus=1, runtime_env={"env_vars": single_thread_environment()})(run_job)
        submitted = [task.remote(job) for job in jobs]
        position = {ref: i for i, ref in enumerate(submitted)}
        results: list[JobResult | None] = [None] * len(jobs)
        pending = list(submitted)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref, result in zip(done, ray.get(done), strict=True):
                results[position[ref]] = result
            if on_done is not None:
                on_done(len(done))
    return results
