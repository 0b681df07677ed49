"""The study's ``cli`` engine: score exactly what a user runs, ``lde replay`` on a log file.

It lives in the CLI layer because it runs the command line in process (:func:`lde.cli.main`); the
study (:mod:`lde.analysis.study`, below the CLI) receives it as the ``engine`` of
:func:`lde.analysis.study.run_specs` from ``lde evaluate`` / ``lde study`` (:func:`engine`).

For one :class:`~lde.analysis.study.spec.RunSpec` (on a worker):

1. simulate the run (seeded) and write its candump ``-L`` log, as ``lde sim --log`` does;
2. write the estimator's vehicle file: the simulated car's spec sheet (``est_vehicle =
   "spec-sheet"``, :mod:`lde.analysis.study.specsheet`), the spec sheet with the load (``"spec-sheet+load"``:
   the loaded car's mass, yaw inertia and CG) or the file the spec names;
3. cold: run the command line in process,
   ``lde.cli.main(["replay", LOG, "--profile", P, "--backend", B, "--vehicle", FILE, "--csv", OUT])``;
   warm (``est_options.learned_prior``): first ``lde replay PRIOR --learned S`` on an earlier drive
   of the same car (the named scenario, seed + :data:`PRIOR_SEED_OFFSET`), then
   ``lde replay LOG --learned S --csv OUT`` (the same options as cold);
4. read the CSV (``t``, ``Fw``, ``Mw``, ``status``; ``Fw_wind``, ``bank_deg``, ``learn_state`` where
   it has them) and hand it to the metric with the truth.

The files live in a temporary directory removed after scoring, or under ``spec.work_dir`` (kept).
A non-zero exit status of ``lde`` fails the run with its last error line.

Warm mode is only meaningful with a backend that learns (``lateral``); the others ignore the learned
file (``lde replay`` says so), so their warm numbers equal their cold ones.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lde.analysis.study.execute import (
    check_plant,
    load_sim_vehicle,
    plant_name,
    simulate_and_estimate,
    simulate_run,
    truth_of,
)
from lde.analysis.study.spec import SPEC_SHEET, SPEC_SHEET_LOADED, Estimate, Estimator, RunSpec
from lde.analysis.study.specsheet import write_spec_sheet
from lde.analysis.study.zoo import PRIOR_SCENARIO as PRIOR_DRIVE
from lde.cli import main
from lde.errors import ConfigError, LdeError, LogFormatError
from lde.status import VALID
from vcan_sim.output import write_outputs
from vcan_sim.run import SimResult

#: the prior drive of a warm run uses the run's seed + this (another drive of the same car)
PRIOR_SEED_OFFSET = 500


@dataclass(frozen=True)
class CliRun:
    """One in-process ``lde`` command: its argv, exit status and what it printed on stderr."""

    argv: tuple[str, ...]
    code: int
    stderr: str

    def error_line(self) -> str:
        lines = [ln for ln in self.stderr.splitlines() if ln.strip()]
        err = [ln for ln in lines if "error" in ln]
        return (err or lines or [f"exit status {self.code}"])[-1]


def run_cli(argv: list[str]) -> CliRun:
    """``lde ARGV`` in this process (:func:`lde.cli.main`), stdout and stderr captured; LdeError on a
    non-zero exit status (with the command's error line)."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse: a usage error
            code = exc.code if isinstance(exc.code, int) else 2
    run = CliRun(tuple(argv), int(code), err.getvalue())
    if run.code != 0:
        raise LdeError(f"`lde {' '.join(argv)}` exited with {run.code}: {run.error_line()}")
    return run


def replay_argv(
    log: Path,
    profile: str,
    backend: str,
    vehicle: Path | str,
    csv: Path | None = None,
    learned: Path | None = None,
) -> list[str]:
    """The ``lde replay`` command line of a run (cold without ``learned``)."""
    argv = ["replay", str(log), "--profile", profile, "--backend", backend, "--vehicle", str(vehicle)]
    if learned is not None:
        argv += ["--learned", str(learned)]
    if csv is not None:
        argv += ["--csv", str(csv)]
    return argv


def run_dir_name(spec: RunSpec) -> Path:
    """The run's directory below ``spec.work_dir``:
    plant/profile-backend/scenario[-fFRICTION]-sSEED[-warm[-PRIOR]] (``-PRIOR`` after another prior
    drive than the zoo's shipped one; ``-fFRICTION`` with the rack friction set by the run)."""
    prior = spec.est_options.learned_prior
    warm = "" if not prior else "-warm" if prior == PRIOR_DRIVE else f"-warm-{prior}"
    fr = spec.sim_options.friction_Nm
    rack = "" if fr is None else f"-f{fr:g}"
    return (
        Path(plant_name(spec.sim_vehicle))
        / f"{spec.profile}-{spec.backend}"
        / f"{spec.scenario}{rack}-s{spec.seed}{warm}"
    )


@contextlib.contextmanager
def _run_dir(spec: RunSpec) -> Iterator[Path]:
    if spec.work_dir:
        d = Path(spec.work_dir) / run_dir_name(spec)
        d.mkdir(parents=True, exist_ok=True)
        yield d
    else:
        with tempfile.TemporaryDirectory(prefix="lde-zoo-") as tmp:
            yield Path(tmp)


#: the CSV columns the metric reads (lde.replay.replay.CSV_COLUMNS)
_CSV_USE = ("t", "Fw", "Mw", "status")
#: the CSV columns read where the CSV has them: wind apart from bank, the learner's state
_CSV_SPLIT = ("Fw_wind", "bank_deg", "learn_state")


@dataclass(frozen=True)
class EstimateCsv:
    """What the metric reads from an ``lde replay --csv`` file: t [s], Fw [N], Mw [Nm], status,
    and where the CSV has them Fw_wind [N], bank [rad] and learn_state (else None)."""

    t: np.ndarray
    fw: np.ndarray
    mw: np.ndarray
    status: np.ndarray
    fw_wind: np.ndarray | None = None
    bank: np.ndarray | None = None
    learn_state: np.ndarray | None = None


def read_estimate_csv(path: Path) -> EstimateCsv:
    """The columns of an ``lde replay --csv`` file the zoo scores (:class:`EstimateCsv`)."""
    try:
        with path.open() as fh:
            header = fh.readline().strip().split(",")
        idx = [header.index(c) for c in _CSV_USE]
    except (OSError, ValueError) as exc:
        raise LogFormatError(f"{path}: not an lde replay CSV with columns {', '.join(_CSV_USE)}") from exc
    split = [c for c in _CSV_SPLIT if c in header]
    data = np.loadtxt(
        path, delimiter=",", skiprows=1, usecols=idx + [header.index(c) for c in split], ndmin=2
    )
    if data.shape[0] == 0:
        raise LogFormatError(f"{path}: no estimator step")
    col = {c: data[:, len(idx) + i] for i, c in enumerate(split)}
    return EstimateCsv(
        data[:, 0],
        data[:, 1],
        data[:, 2],
        data[:, 3].astype(np.int64),
        fw_wind=col.get("Fw_wind"),
        bank=np.radians(col["bank_deg"]) if "bank_deg" in col else None,
        learn_state=col["learn_state"].astype(np.int64) if "learn_state" in col else None,
    )


def estimator_file(spec: RunSpec, sim: SimResult, d: Path) -> Path | str:
    """The ``--vehicle`` of a run: the spec sheet (:data:`SPEC_SHEET`), the spec sheet with the load
    (:data:`SPEC_SHEET_LOADED`: the loaded car's mass, yaw inertia and CG, what a load signal gives
    through eqs. 17-18), or the file the spec names."""
    if spec.est_vehicle not in (SPEC_SHEET, SPEC_SHEET_LOADED):
        return spec.est_vehicle  # a shipped name or a path, as --vehicle takes it
    car = load_sim_vehicle(spec.sim_vehicle)
    if spec.est_vehicle == SPEC_SHEET_LOADED:
        b = sim.body
        car = car.with_body(mass=b.mass, yaw_inertia=b.yaw_inertia, lf=b.lf, lr=b.lr)
    return write_spec_sheet(car, d / "spec_sheet.toml")


def estimate_with_cli(spec: RunSpec) -> Estimate:
    """The ``cli`` engine (see the module docstring)."""
    opts = spec.est_options
    rejected = [k for k, v in opts if k != "learned_prior"]
    if rejected:
        raise ConfigError(
            f"the cli engine runs `lde replay` as a user does: estimator options {sorted(rejected)} "
            "do not apply (put corrections in the vehicle file)"
        )
    sim = simulate_run(spec, spec.scenario, spec.seed)
    check_plant(sim.truth)
    with _run_dir(spec) as d:
        log = d / "drive.log"
        write_outputs(sim, log=log, truth=d / "truth.csv" if spec.work_dir else None)
        vehicle = estimator_file(spec, sim, d)
        learned = None
        if opts.learned_prior:
            prior = simulate_run(spec, opts.learned_prior, spec.seed + PRIOR_SEED_OFFSET)
            check_plant(prior.truth)
            prior_log = d / "prior.log"
            write_outputs(prior, log=prior_log)
            learned = d / "learned"
            run_cli(replay_argv(prior_log, spec.profile, spec.backend, vehicle, learned=learned))
        out = d / "estimate.csv"
        run_cli(replay_argv(log, spec.profile, spec.backend, vehicle, csv=out, learned=learned))
        e = read_estimate_csv(out)
    valid = (e.status & int(VALID)) != 0
    return Estimate(
        e.t, e.fw, e.mw, valid, truth_of(sim), fw_wind=e.fw_wind, bank=e.bank, learn_state=e.learn_state
    )


def engine(spec: RunSpec) -> Estimate:
    """The engine of ``lde evaluate`` / ``lde study``: the ``cli`` estimator runs the command line
    (:func:`estimate_with_cli`), the others the in-process study engine."""
    if spec.estimator == Estimator.CLI.value:
        return estimate_with_cli(spec)
    return simulate_and_estimate(spec)
