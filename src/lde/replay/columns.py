"""The columns of ``lde replay --csv``: names, decimals, units and signs, defined once.

The order is a contract: ``t, Fw, Mw, T_overlay`` first (the product's contract), then the other
estimate columns, then with ``--smooth`` the smoothed columns, then the decoded status columns
(:data:`STATUS_COLUMNS`, one 0/1 column per ``LDE_Estimate.Status`` bit and the overlay's Active
bit). New columns are only ever appended, so that a script reading columns by position keeps
working. Signs are ISO 8855 (x forward, y left, z up: left and counter-clockwise positive) except
``T_align``, which keeps the paper's sign. Units are SI except ``bank_deg`` (degrees, as on the bus).

This module is light (no numba): ``lde replay --help`` lists the columns from it
(:func:`columns_help`), and ``docs/guide/csv.md`` documents the same list (a test holds them equal).
"""

from __future__ import annotations

import textwrap

from lde.status import STATUS_BITS, STATUS_MEANINGS

__all__ = ["CSV_COLUMNS", "SMOOTHED", "STATUS_COLUMNS", "csv_columns", "columns_help"]

#: one column: (name, decimals printed, "unit, meaning and sign")
ColumnSpec = tuple[str, int, str]

#: the estimate columns, in order (the first four are the product's contract)
CSV_COLUMNS: tuple[ColumnSpec, ...] = (
    ("t", 6, "s, step time in the log's own time base (6 decimals, 9 when not whole microseconds)"),
    ("Fw", 3, "N, lateral disturbance force at the CG along body y, left positive"),
    ("Mw", 3, "Nm, disturbance yaw moment about the CG, counter-clockwise seen from above (left) positive"),
    ("T_overlay", 4, "Nm, overlay torque request at the steering column, left positive"),
    (
        "T_align",
        4,
        "Nm, estimated aligning torque at the steering axis, positive when it resists a left steer",
    ),
    ("status", 0, "LDE_Estimate.Status bit map as an integer (decoded in the status columns)"),
    ("overlay_state", 0, "overlay limiter state: 0 off, 1 ramp-in, 2 active, 3 ramp-out, 4 fault"),
    ("beta", 7, "rad, estimated side slip angle at the CG, velocity pointing left of x positive"),
    ("yaw_rate", 6, "rad/s, estimated yaw rate, left positive"),
    ("speed", 4, "m/s, input speed (sample-and-hold; nan before the first speed frame)"),
    ("mdps_ok", 0, "0/1, 1: MDPS inputs fresh and trusted"),
    ("esc_ok", 0, "0/1, 1: ESC inputs fresh and trusted"),
    ("Fw_wind", 3, "N, the wind's part of Fw, left positive (nan: the backend does not tell wind from bank)"),
    ("Mw_wind", 3, "Nm, the wind's yaw moment, left positive (nan: not told apart)"),
    ("bank_deg", 4, "deg, road bank angle, road's left side lower positive (nan: not told apart)"),
    ("learn_state", 0, "tire values: 0 not learned, 1 learning, 2 learned, 3 the backend does not learn"),
)

#: ``--smooth``: the RTS smoother's outputs (the CSV and the MCAP topic ``/lde/smooth`` use these)
SMOOTHED: tuple[ColumnSpec, ...] = (
    ("Fw_smooth", 3, "N, RTS-smoothed Fw (float lateral filter, non-causal), left positive"),
    ("Mw_smooth", 3, "Nm, RTS-smoothed Mw, left positive"),
    ("Fw_wind_smooth", 3, "N, RTS-smoothed wind force, left positive"),
    ("Mw_wind_smooth", 3, "Nm, RTS-smoothed wind yaw moment, left positive"),
    ("bank_deg_smooth", 4, "deg, RTS-smoothed road bank angle, road's left side lower positive"),
)

#: the decoded status: one 0/1 column per ``LDE_Estimate.Status`` bit (:mod:`lde.status`, the
#: names of the MCAP recording's ``/lde/estimate`` fields), then the overlay's Active bit
STATUS_COLUMNS: tuple[ColumnSpec, ...] = (
    *((name, 0, f"0/1, status bit {i}: {STATUS_MEANINGS[name]}") for i, name in enumerate(STATUS_BITS)),
    ("overlay_active", 0, "0/1, the overlay torque is applied (overlay_state ramp-in or active)"),
)


def csv_columns(smooth: bool = False) -> tuple[ColumnSpec, ...]:
    """Every column of a replay CSV, in order (``smooth``: with the ``--smooth`` columns)."""
    return CSV_COLUMNS + (SMOOTHED if smooth else ()) + STATUS_COLUMNS


def columns_help(width: int = 100) -> str:
    """The columns as plain text for ``lde replay --help``: name, then unit and meaning wrapped
    to ``width`` characters."""
    indent = 2 + max(len(name) for name, _, _ in csv_columns(smooth=True)) + 2

    def rows(cols: tuple[ColumnSpec, ...]) -> list[str]:
        return [
            textwrap.fill(
                text, width, initial_indent=f"  {name:<{indent - 2}}", subsequent_indent=" " * indent
            )
            for name, _, text in cols
        ]

    return "\n".join(
        [
            "CSV columns (--csv), in this order; SI units, ISO 8855 signs (x forward, y left, z up:",
            "left and counter-clockwise positive; T_align keeps the paper's sign); docs/guide/csv.md:",
            *rows(CSV_COLUMNS),
            "with --smooth:",
            *rows(SMOOTHED),
            "the status decoded (always, after every other column):",
            *rows(STATUS_COLUMNS),
        ]
    )
