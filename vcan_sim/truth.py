"""Ground truth: what the estimator should find, every 3.9 ms step, in the log's own time base.

Definitions (SPEC section 2; all computed inside the plant at the same state the frames sample)::

    Fw     = F_aero,y + m g sin(bank) cos(psi)       total lateral disturbance force along body y [N]
    Mw     = M_aero,mid + (lf - lr)/2 F_aero,y       crosswind yaw moment about the ACTUAL CG [Nm]
                                                     (the bank force acts through the CG: no moment)
    Mw_ref = Mw + dx Fw                              the same about the unloaded reference CG, where
                                                     dx = x_cg - x_ref (forward) is the payload's CG shift

Other columns are the plant's true states and inputs (not sensor readings): see
:data:`TRUTH_COLUMNS` for names, units and signs (ISO, left positive; T_align paper sign).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lde.errors import ConfigError

from . import plant as P

#: truth column -> (plant output index or None for time, unit and meaning)
TRUTH_COLUMNS: dict[str, tuple[int | None, str]] = {
    "t": (None, "s, the log's time base (epoch seconds, like the candump timestamps)"),
    "Fw": (P.O_FW, "N, lateral disturbance force along body y (crosswind + bank), left positive"),
    "Mw": (P.O_MW, "Nm, disturbance yaw moment about the actual CG, left positive"),
    "Mw_ref": (P.O_MWREF, "Nm, disturbance yaw moment about the unloaded reference CG"),
    "vx": (P.O_VX, "m/s, longitudinal speed"),
    "vy": (P.O_VY, "m/s, lateral speed at the CG"),
    "r": (P.O_R, "rad/s, yaw rate"),
    "beta": (P.O_BETA, "rad, side slip at the CG"),
    "y": (P.O_Y, "m, lateral position (left positive; the lane centre starts at 0)"),
    "psi": (P.O_PSI, "rad, heading relative to the road"),
    "delta_sw": (P.O_DSW, "rad, steering-wheel angle"),
    "delta_f": (P.O_DF, "rad, road-wheel angle (= theta_p / N)"),
    "theta_p": (P.O_THP, "rad, pinion angle at steering-wheel scale (below the torsion bar)"),
    "T_column": (P.O_TCOL, "Nm, torsion-bar (column) torque"),
    "T_assist": (P.O_TAST, "Nm, total MDPS motor torque at the column (boost + overlay)"),
    "T_overlay": (P.O_TOV, "Nm, overlay torque the motor applies"),
    "T_boost": (P.O_TBOOST, "Nm, boost share of the assist torque"),
    "T_driver": (P.O_TDRV, "Nm, driver's torque on the wheel"),
    "T_align": (P.O_TALIGN, "Nm, front tires' aligning torque on the steering axis, paper sign"),
    "ay": (P.O_AYKIN, "m/s^2, kinematic lateral acceleration vy' + r vx"),
    "wind_speed": (P.O_WIND, "m/s, wind speed over ground"),
    "beta_cw": (P.O_BCW, "rad, airflow side-slip angle"),
    "Fy_wind": (P.O_FYW, "N, crosswind lateral force"),
    "Mz_wind": (P.O_MZW, "Nm, crosswind yaw moment about the actual CG"),
    "F_bank": (P.O_FBANK, "N, bank gravity component along body y"),
    "bank": (P.O_BANK, "rad, road bank angle (left side lower positive)"),
    "roll": (P.O_PHI, "rad, body roll (right side down positive)"),
    "alpha_f": (P.O_AF, "rad, mean front slip angle"),
    "alpha_r": (P.O_AR, "rad, mean rear slip angle"),
    "Fy_front": (P.O_FYF, "N, front tires' lateral force, body y"),
    "Fy_rear": (P.O_FYR, "N, rear tires' lateral force"),
    "Mz_tires": (P.O_MZT, "Nm, yaw moment of all tire forces and aligning moments about the CG"),
    "Fz_fl": (P.O_FZ1, "N, wheel load front left"),
    "Fz_fr": (P.O_FZ2, "N, wheel load front right"),
    "Fz_rl": (P.O_FZ3, "N, wheel load rear left"),
    "Fz_rr": (P.O_FZ4, "N, wheel load rear right"),
}


def truth_rows(t_ns: np.ndarray, rows: np.ndarray) -> dict[str, np.ndarray]:
    """Truth columns from plant output rows sampled at times ``t_ns`` (absolute, ns)."""
    cols: dict[str, np.ndarray] = {"t": np.asarray(t_ns, dtype=np.int64) / 1e9}
    for name, (idx, _) in TRUTH_COLUMNS.items():
        if idx is not None:
            cols[name] = rows[:, idx].copy()
    return cols


def concat_truth(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Join truth chunks (same columns)."""
    if not parts:
        return {name: np.zeros(0) for name in TRUTH_COLUMNS}
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def truth_csv_names(truth: Mapping[str, np.ndarray], exact_t: bool = True) -> list[str]:
    """The CSV's column names in order: ``t`` first when it is printed from ``t_ns`` (``exact_t``)."""
    names = list(truth)
    if exact_t and "t" in names:
        return ["t"] + [k for k in names if k != "t"]
    return names


def format_truth_rows(
    truth: Mapping[str, np.ndarray], t_ns: np.ndarray | None = None, digits: int = 12
) -> str:
    """The CSV lines of ``truth``'s rows (each ending in a newline; no header), columns in the
    order of :func:`truth_csv_names`. ``t`` is printed exactly from ``t_ns`` when given (9 decimals,
    the log's time base), the other columns with ``digits`` significant digits. Rows are formatted
    one by one, so the lines of a run written in pieces are those of the run written at once."""
    names = list(truth)
    other = [k for k in names if k != "t" or t_ns is None]
    body = io.StringIO()
    if other:
        np.savetxt(
            body,
            np.column_stack([np.asarray(truth[k], np.float64) for k in other]),
            fmt=f"%.{digits}g",
            delimiter=",",
        )
    rows = body.getvalue().splitlines()
    if t_ns is not None and "t" in names:
        t_txt = [f"{v // 1_000_000_000}.{v % 1_000_000_000:09d}" for v in np.asarray(t_ns, np.int64).tolist()]
        rows = [f"{a},{b}" for a, b in zip(t_txt, rows, strict=True)] if other else t_txt
    return "".join(r + "\n" for r in rows)


def write_truth_csv(
    path: str | Path, truth: Mapping[str, np.ndarray], t_ns: np.ndarray | None = None, digits: int = 12
) -> None:
    """CSV with a header, the rows of :func:`format_truth_rows`."""
    try:
        with open(path, "w", newline="") as fh:
            fh.write(",".join(truth_csv_names(truth, t_ns is not None)) + "\n")
            fh.write(format_truth_rows(truth, t_ns, digits))
    except OSError as exc:
        raise ConfigError(f"cannot write truth CSV {path}: {exc}") from exc


@dataclass(frozen=True)
class TruthCsv:
    """A truth CSV read back (:func:`read_truth_csv`).

    Attributes:
        columns: name -> values (float64; ``t`` in s).
        cut: the file ended inside a line (a writer killed while writing it): that line is skipped.
        offset: byte offset where the whole lines end; size: the file's size [bytes].
    """

    columns: dict[str, np.ndarray]
    cut: bool
    offset: int
    size: int

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0


def read_truth_csv(path: str | Path) -> TruthCsv:
    """Read a truth CSV up to its last whole line (a cut last line, from a killed ``lde sim``, is
    skipped and reported in :attr:`TruthCsv.cut`).

    Raises:
        ConfigError: no header line, or a whole line that is not numbers in the header's columns.
    """
    raw = Path(path).read_bytes()
    end = raw.rfind(b"\n") + 1
    head_end = raw.find(b"\n")
    if head_end < 0:
        raise ConfigError(f"{path}: not a truth CSV (no complete header line)")
    names = raw[:head_end].decode("ascii", "replace").strip().split(",")
    body = raw[head_end + 1 : end]
    try:
        data = np.loadtxt(io.BytesIO(body), delimiter=",", ndmin=2) if body.strip() else None
    except ValueError as exc:
        raise ConfigError(f"{path}: not a truth CSV: {exc}") from exc
    if data is None:
        data = np.zeros((0, len(names)))
    if data.shape[1] != len(names):
        raise ConfigError(f"{path}: {data.shape[1]} columns per row, {len(names)} in the header")
    cols = {n: data[:, i] for i, n in enumerate(names)}
    return TruthCsv(cols, cut=end < len(raw), offset=end, size=len(raw))
