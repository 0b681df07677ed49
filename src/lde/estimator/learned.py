"""What the estimator learned about a car, kept between drives: ``--learned FILE`` (docs/guide/learned.md).

JSON, one object, written atomically (a temporary file in the same directory, then renamed)::

    {"format": "lde-learned", "version": 1,
     "vehicle": {"name", "mass_kg", "yaw_inertia_kgm2", "lf_m", "lr_m", "ratio"},   # checked on load
     "profile": "lde" | "hyundai" | <a DBC's name>,                                # checked on load
     "drives": n, "seconds": s,                          # drives and driving time learned from
     "state": "not learned" | "learning" | "learned",   # the tire group
     "params": {"cf_N_per_rad", "cr_N_per_rad", "align_rate_Nm_per_rad", "accel_scale",
                "steering_friction_Nm", "torsion_deg_per_Nm", "steering_angle_offset_deg",
                "yaw_rate_bias_deg_s", "align_offset_Nm",
                "column_torque_scale", "assist_torque_scale"},
     "learner": [... the learner's state vector ...]}

On load the parameters go into the filter's parameter vector and the learner's state is restored
with the between-drive changes (:func:`between_drives`): the regressions' intercepts (which carry the
previous drive's disturbance and bank) return to their priors, the gyro-bias variance is widened (the
bias drifts with temperature), the signal filters restart.

``column_torque_scale`` and ``assist_torque_scale`` are the factors from each torque signal as the
profile reads it to the unit the aligning torque is in (both 1 when the profile's torques are in Nm;
a torque of unknown scale has its learned factor, :mod:`lde.estimator.learner`, ``L_TSCALE``). With
both torques of unknown scale that unit is the column signal's, and ``align_rate_Nm_per_rad`` and
``steering_friction_Nm`` are in it too. A file without them (written before they existed) reads as 1.
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lde.errors import ConfigError
from lde.estimator import lateral as E
from lde.estimator import learner as Ln

__all__ = [
    "LearnedState",
    "LearnedSnapshot",
    "LearnedKeeper",
    "load_learned",
    "parse_learned",
    "save_learned",
    "save_snapshot",
    "between_drives",
    "FORMAT",
    "VERSION",
]

log = logging.getLogger("lde.estimator.learned")

FORMAT, VERSION = "lde-learned", 1
STATE_NAMES = {Ln.ST_NOT: "not learned", Ln.ST_LEARNING: "learning", Ln.ST_LEARNED: "learned"}


@dataclass
class LearnedState:
    """A learned-state file read for one run: the parameters (already in ``p``), the learner state,
    and how much it was learned from."""

    learner: np.ndarray
    drives: int
    seconds: float
    text: str = ""  # the file as read (a live recording keeps it: its replay starts from it too)


@dataclass(frozen=True)
class LearnedSnapshot:
    """A copy of what was learned at one instant, ready to be written from another thread."""

    vehicle_name: str
    profile: str
    p: np.ndarray
    learner: np.ndarray
    drives: int
    seconds: float


def _vehicle_key(p: np.ndarray) -> dict[str, float]:
    return {
        "mass_kg": float(p[E.P_M]),
        "yaw_inertia_kgm2": float(p[E.P_IZ]),
        "lf_m": float(p[E.P_LF]),
        "lr_m": float(p[E.P_LR]),
        "ratio": float(p[E.P_N]),
    }


def save_learned(
    path: str | Path,
    vehicle_name: str,
    profile: str,
    p: np.ndarray,
    ls: np.ndarray,
    drives: int,
    seconds: float,
) -> None:
    """Write the learned state atomically (a reader never sees half a file; a crash leaves the
    previous file)."""
    d = math.degrees
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "vehicle": {"name": vehicle_name, **_vehicle_key(p)},
        "profile": profile,
        "drives": int(drives),
        "seconds": float(seconds),
        "state": STATE_NAMES[Ln.tire_state(ls)],
        "params": {
            "cf_N_per_rad": float(p[E.P_CF]),
            "cr_N_per_rad": float(p[E.P_CR]),
            "align_rate_Nm_per_rad": float(p[E.P_K]),
            "accel_scale": float(p[E.P_S]),
            "steering_friction_Nm": float(p[E.P_TFRIC]),
            "torsion_deg_per_Nm": d(float(p[E.P_CTB])),
            "steering_angle_offset_deg": d(float(p[E.P_DSW])),
            "yaw_rate_bias_deg_s": d(float(p[E.P_BR])),
            "align_offset_Nm": float(p[E.P_T0]),
            "column_torque_scale": float(p[E.P_KC]),
            "assist_torque_scale": float(p[E.P_KA]),
        },
        "learner": [float(v) for v in ls],
    }
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(
            dir=path.parent if str(path.parent) else ".", prefix=f".{path.name}.", suffix=".tmp"
        )
        with os.fdopen(fd, "w") as fh:
            json.dump(doc, fh, indent=1)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        raise ConfigError(f"--learned {path}: cannot write: {exc}") from exc


def save_snapshot(path: str | Path, snap: LearnedSnapshot) -> None:
    """:func:`save_learned` of a :class:`LearnedSnapshot`."""
    save_learned(path, snap.vehicle_name, snap.profile, snap.p, snap.learner, snap.drives, snap.seconds)


class LearnedKeeper:
    """Writes the live service's learned state every ``period_ns`` (``lde run --learned``: 60 s) on a
    writer thread, so that the file system never delays a step, and once more at :meth:`close`.

    The loop hands over a copy (:meth:`offer`, a few microseconds); the writer keeps only the newest
    copy not yet written. A failed periodic write is logged and counted (the next one may succeed);
    a failed final write raises ConfigError from :meth:`close`.
    """

    def __init__(self, path: str | Path, period_ns: int) -> None:
        self.path = Path(path)
        self.period_ns = int(period_ns)
        self.next_ns: int | None = None  # the next periodic write is due at this step time
        self.writes = 0
        self.errors = 0
        self._pending: LearnedSnapshot | None = None
        self._cv = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._writer, name="lde-learned", daemon=True)
        self._thread.start()

    def due(self, t_ns: int) -> bool:
        """Whether a periodic write is due at step time ``t_ns`` (the first step starts the period)."""
        if self.next_ns is None:
            self.next_ns = t_ns + self.period_ns
            return False
        if t_ns < self.next_ns:
            return False
        self.next_ns += self.period_ns * max(1, (t_ns - self.next_ns) // self.period_ns + 1)
        return True

    def offer(self, snap: LearnedSnapshot) -> None:
        """Hand a snapshot to the writer (replaces one not yet written)."""
        with self._cv:
            self._pending = snap
            self._cv.notify()

    def _writer(self) -> None:
        while True:
            with self._cv:
                while self._pending is None and not self._closed:
                    self._cv.wait()
                snap, self._pending = self._pending, None
                if snap is None:
                    return
            self._write(snap)

    def _write(self, snap: LearnedSnapshot) -> None:
        try:
            save_snapshot(self.path, snap)
        except ConfigError as exc:
            self.errors += 1
            log.error("%s (%d failed writes)", exc, self.errors)
        else:
            self.writes += 1

    def close(self, final: LearnedSnapshot | None) -> None:
        """Stop the writer (after a write in progress) and write ``final`` in this thread;
        ConfigError when that write fails."""
        with self._cv:
            self._closed = True
            self._pending = None
            self._cv.notify()
        self._thread.join()
        if final is not None:
            save_snapshot(self.path, final)
            self.writes += 1


def load_learned(path: str | Path, profile: str, p: np.ndarray, lp: np.ndarray) -> LearnedState:
    """Read ``path``: its parameters go into ``p``; returns the learner state (between-drive changes
    applied). ConfigError (one line) when it is not such a file or was learned for another vehicle
    or profile."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--learned {path}: not a readable lde learned-state file ({exc})") from exc
    return parse_learned(text, f"--learned {path}", profile, p, lp)


def parse_learned(text: str, source: str, profile: str, p: np.ndarray, lp: np.ndarray) -> LearnedState:
    """:func:`load_learned` of a file's text; ``source`` names it in errors (``--learned FILE``,
    ``the recording's learned start``)."""
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise ConfigError(f"{source}: not a readable lde learned-state file ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise ConfigError(f"{source}: not an {FORMAT} version {VERSION} file")
    if doc.get("profile") != profile:
        raise ConfigError(
            f"{source}: learned on CAN profile {doc.get('profile')!r}, this run uses {profile!r}"
        )
    veh_doc = doc.get("vehicle")
    veh: dict[str, Any] = veh_doc if isinstance(veh_doc, dict) else {}
    for key, want in _vehicle_key(p).items():
        got = veh.get(key)
        if not isinstance(got, (int, float)) or abs(got - want) > 1e-6 * max(1.0, abs(want)):
            raise ConfigError(
                f"{source}: learned for another vehicle ({veh.get('name', '?')}: {key} {got}, "
                f"this vehicle file {want:g})"
            )
    try:
        ls = np.asarray(doc["learner"], dtype=np.float64)
        q = doc["params"]
        vals = [
            float(q["cf_N_per_rad"]),
            float(q["cr_N_per_rad"]),
            float(q["align_rate_Nm_per_rad"]),
            float(q["accel_scale"]),
            float(q["steering_friction_Nm"]),
            math.radians(float(q["torsion_deg_per_Nm"])),
            math.radians(float(q["steering_angle_offset_deg"])),
            math.radians(float(q["yaw_rate_bias_deg_s"])),
            float(q.get("align_offset_Nm", 0.0)),
            float(q.get("column_torque_scale", 1.0)),
            float(q.get("assist_torque_scale", 1.0)),
        ]
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: incomplete ({exc})") from exc
    if ls.shape != (Ln.N_LS,) or not np.all(np.isfinite(ls)) or not all(math.isfinite(v) for v in vals):
        raise ConfigError(f"{source}: learner state of the wrong size or not finite")
    cf, cr, k, s, tfric, ctb, dsw, br, t0, kc, ka = vals
    got = {"cf": cf, "cr": cr, "k": k, "s": s}
    # with both torques of unknown scale K is in the column signal's unit: no bound in Nm applies
    free_k = lp[Ln.L_TSCALE] == Ln.TS_BOTH
    bad = [
        n for n, (lo, hi) in Ln.PLAUSIBLE.items() if not (lo <= got[n] <= hi) and not (free_k and n == "k")
    ]
    if bad or not (kc > 0.0 and ka > 0.0):
        raise ConfigError(
            f"{source}: implausible values (cf {cf:g}, cr {cr:g}, K {k:g}, s {s:g}, "
            f"torque scales {kc:g}, {ka:g})"
        )
    if lp[Ln.L_TSCALE] == Ln.TS_KNOWN and (kc, ka) != (1.0, 1.0):
        raise ConfigError(
            f"{source}: learned with torques of unknown scale (factors {kc:g}, {ka:g}); "
            "this profile's are in Nm"
        )
    p[E.P_CF], p[E.P_CR], p[E.P_K], p[E.P_S] = cf, cr, k, s
    p[E.P_KC], p[E.P_KA] = kc, ka
    p[E.P_TFRIC], p[E.P_CTB], p[E.P_DSW], p[E.P_BR], p[E.P_T0] = tfric, ctb, dsw, br, t0
    return LearnedState(between_drives(ls), int(doc.get("drives", 1)), float(doc.get("seconds", 0.0)), text)


def between_drives(ls: np.ndarray) -> np.ndarray:
    """Reset what belongs to one drive (the regressions' intercepts, the signal filters, the heading
    windows), widen the gyro-bias variance (it drifts with temperature between drives)."""
    ls = ls.copy()
    blocks = (
        (Ln.LS_T1, Ln.LS_P1, Ln.N1, 2000.0**2),
        (Ln.LS_T2, Ln.LS_P2, Ln.N2, 3000.0**2),
        (Ln.LS_T3, Ln.LS_P3, Ln.N3, 1.0),
    )
    for toff, poff, n, var in blocks:
        i = n - 1  # the intercept is each regression's last coefficient
        ls[toff + i] = 0.0
        for j in range(n):
            ls[poff + i * n + j] = 0.0
            ls[poff + j * n + i] = 0.0
        ls[poff + i * n + i] = var
    ls[Ln.LS_B + 1] = max(ls[Ln.LS_B + 1], (0.05 * math.pi / 180.0) ** 2)
    for slot in (Ln.LS_INIT, Ln.LS_HI, Ln.LS_AC, Ln.LS_STEP):
        ls[slot] = 0.0
    ls[Ln.LS_HT] = -1.0  # a new drive: its first gyro-bias window opens at its first anchor
    return ls
