"""Replays of many logs on a ``dask.distributed`` cluster (``lde replay --jobs N | --scheduler ADDR``).

:func:`run_jobs_on_dask` maps :func:`lde.fleet.replay_job` over the jobs on a ``LocalCluster`` of
``n_workers`` processes (one thread each: a replay's loop holds one core) or on an existing
scheduler by address, and feeds the progress bar from ``distributed.as_completed``. A worker that
dies or cannot import lde gives a failed :class:`lde.fleet.LogReport`; the other logs go on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from distributed import Client, LocalCluster, as_completed

from .errors import LdeError
from .fleet import LogReport, ReplayJob, job_done, progress_bar, replay_job

__all__ = ["ClusterConfig", "run_jobs_on_dask"]


@dataclass(frozen=True)
class ClusterConfig:
    """Where to run: ``scheduler`` address, else a local cluster of ``n_workers`` processes."""

    scheduler: str | None = None
    n_workers: int = 2
    connect_timeout: float = 10.0  # s, to reach an existing scheduler


def run_jobs_on_dask(
    jobs: Sequence[ReplayJob],
    cfg: ClusterConfig,
    *,
    progress: bool = True,
    on_report: Callable[[LogReport], None] | None = None,
) -> list[LogReport]:
    """Every job on the cluster; reports in the order of ``jobs`` (``on_report`` sees each one as
    it arrives).

    Raises:
        LdeError: the scheduler cannot be reached.
    """
    if not jobs:
        return []
    bar = progress_bar(progress, len(jobs))
    try:
        return _run(jobs, cfg, bar, on_report)
    finally:
        if bar is not None:
            bar.close()


def _run(
    jobs: Sequence[ReplayJob],
    cfg: ClusterConfig,
    bar: Any,
    on_report: Callable[[LogReport], None] | None,
) -> list[LogReport]:
    # the scheduler's and nannies' INFO lines would drown the progress bar (-v shows them)
    if logging.getLogger().getEffectiveLevel() >= logging.WARNING:
        logging.getLogger("distributed").setLevel(logging.WARNING)
    local = None
    try:
        if cfg.scheduler is None:
            local = LocalCluster(
                n_workers=cfg.n_workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            client = Client(local)
        else:
            client = Client(cfg.scheduler, timeout=cfg.connect_timeout)
    except (OSError, TimeoutError) as exc:
        if local is not None:
            local.close()
        raise LdeError(f"cannot reach the Dask scheduler {cfg.scheduler!r}: {exc}") from exc
    try:
        futures = client.map(replay_job, list(jobs), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        out: list[LogReport | None] = [None] * len(jobs)
        for fut in as_completed(futures):
            i = index[fut.key]
            try:
                rep = fut.result()
            except Exception as exc:  # noqa: BLE001 - a worker died or could not import lde: report it
                rep = LogReport(jobs[i].log, error=f"worker: {type(exc).__name__}: {exc}")
            out[i] = rep
            job_done(bar, rep, on_report)
        return [r for r in out if r is not None]
    finally:
        client.close()
        if local is not None:
            local.close()
