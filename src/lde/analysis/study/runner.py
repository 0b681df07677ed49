"""The study's Dask runner: run specs on a ``dask.distributed`` cluster with a tqdm progress bar.

:func:`run_specs` maps :func:`lde.analysis.study.execute.run_one` over the specs on a
``LocalCluster(n_workers=2, threads_per_worker=1)`` by default or on an existing scheduler by
address, feeds the progress bar from ``distributed.as_completed`` and returns the results in the
order of the specs. ``n_workers=0`` runs in this process (debugging).
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from distributed import Client, LocalCluster, as_completed
from tqdm import tqdm

from lde.analysis.study.execute import Engine, run_one
from lde.analysis.study.spec import RunResult, RunSpec
from lde.errors import LdeError


@dataclass(frozen=True)
class ClusterConfig:
    """Where to run: ``scheduler`` address (None: a local cluster of ``n_workers`` processes)."""

    scheduler: str | None = None
    n_workers: int = 2
    threads_per_worker: int = 1
    connect_timeout: float = 10.0  # s, to reach an existing scheduler


def run_specs(
    specs: Sequence[RunSpec],
    cluster: ClusterConfig | None = None,
    engine: Engine | None = None,
    progress: bool = True,
    desc: str = "lde study",
) -> list[RunResult]:
    """Run every spec on a Dask cluster; results in the order of ``specs``.

    With ``cluster.n_workers == 0`` and no scheduler the specs run in this process (debugging).
    """
    cfg = cluster or ClusterConfig()
    if not specs:
        return []
    if cfg.scheduler is None and cfg.n_workers == 0:
        it: Iterable[RunSpec] = _progress(specs, progress, len(specs), desc)
        return [run_one(s, engine) for s in it]

    # the scheduler and nanny INFO lines would drown the progress bar (-v shows them)
    if logging.getLogger().getEffectiveLevel() >= logging.WARNING:
        logging.getLogger("distributed").setLevel(logging.WARNING)

    local = None
    try:
        if cfg.scheduler is None:
            local = LocalCluster(
                n_workers=cfg.n_workers,
                threads_per_worker=cfg.threads_per_worker,
                processes=True,
                dashboard_address=None,
            )
            client = Client(local)
        else:
            client = Client(cfg.scheduler, timeout=cfg.connect_timeout)
    except (OSError, TimeoutError) as exc:
        raise LdeError(f"cannot reach the Dask scheduler {cfg.scheduler!r}: {exc}") from exc
    try:
        futures = client.map(run_one, list(specs), engine=engine, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        out: list[RunResult | None] = [None] * len(specs)
        for fut in _progress(as_completed(futures), progress, len(futures), desc):
            i = index[fut.key]
            try:
                out[i] = fut.result()
            except Exception as exc:  # a worker died or could not unpickle: report, keep going
                out[i] = RunResult(specs[i], None, f"worker: {type(exc).__name__}: {exc}")
        return [r for r in out if r is not None]
    finally:
        client.close()
        if local is not None:
            local.close()


def _progress(it: Iterable[Any], enabled: bool, total: int, desc: str) -> Iterable[Any]:
    """A tqdm bar over ``it``, only on a terminal (its carriage returns would land in a file)."""
    if not enabled or not sys.stderr.isatty():
        return it

    return tqdm(it, total=total, unit="run", desc=desc)
