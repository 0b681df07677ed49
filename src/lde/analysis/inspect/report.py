"""An :class:`~lde.analysis.inspect.inspection.Inspection` as text for a person or JSON for a script.

The text has four parts: the log (its ids per channel), which profile fits, the checked profile's
inputs and integrity, and the physics checks with what to change. The JSON holds the same in
fields (SI units; NaN and infinities as null), keyed so that a script can find a check's outcome
(``checks[i].outcome``) and the lines to change (``checks[i].fix``, ``signs[input].ok``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from enum import Enum
from typing import Any

from lde.analysis.inspect.checks import Outcome, sign_line
from lde.analysis.inspect.inspection import Inspection
from lde.units import DEG, KMH

__all__ = ["render_text", "render_json", "as_dict"]

#: how an input's SI value is shown beside it: (unit, SI per shown unit)
_SHOWN = {"rad": ("deg", DEG), "rad/s": ("deg/s", DEG), "m/s": ("km/h", KMH)}


def _num(x: float, digits: int = 3) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:.{digits}g}"


def _fixed(x: float, decimals: int = 2) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{decimals}f}"


def _table(rows: list[list[str]], right: set[int]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    out = []
    for r in rows:
        cells = [
            c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True))
        ]
        out.append("  " + "  ".join(cells).rstrip())
    return out


def _log_part(insp: Inspection, source: str) -> list[str]:
    s = insp.survey
    chans = ", ".join(c or "(unnamed)" for c in s.channels)
    lines = [
        f"The log: {source}",
        f"  {s.frames} frames, {s.duration_s:.3f} s, {len(s.ids)} ids on {len(s.channels)} channel"
        f"{'s' if len(s.channels) != 1 else ''} ({chans})",
    ]
    rows = [["channel", "id", "frames", "period ms", "jitter ms", "max gap ms", "bytes", "message"]]
    for st in s.ids:
        rows.append(
            [
                st.channel or "-",
                st.id_text,
                str(st.frames),
                _fixed(st.period_ms),
                _fixed(st.jitter_ms),
                _fixed(st.max_gap_ms, 1),
                ",".join(str(x) for x in st.lengths),
                "" if st.extended else insp.names.get(st.can_id, ""),
            ]
        )
    return lines + _table(rows, {2, 3, 4, 5})


def _fit_part(insp: Inspection) -> list[str]:
    lines = ["Which profile fits:"]
    if not insp.matches:
        return [*lines, "  no profile to compare"]
    rows = []
    for m in insp.matches:
        where = f"on {m.channel or '(unnamed)'}" if m.channel is not None else ""
        verdict = "fits" if m.fits else m.why()
        rows.append([m.profile, f"({m.origin})", f"{m.present}/{m.required}", where, verdict])
    lines += _table(rows, {2})
    if insp.profile is None:
        lines.append(
            "  none of the shipped profiles fits this log: write a profile file for this car and give it"
            " with --profile (docs/guide/inspect.md)"
        )
    return lines


def _inputs_part(insp: Inspection) -> list[str]:
    head = f"Profile {insp.profile} ({insp.profile_origin}"
    head += f", channel {insp.channel or '(unnamed)'})" if insp.channel is not None else ")"
    lines = [head + ":"]
    if insp.inputs is None:
        return [*lines, "  none of its input messages is in the log"]
    rows = [
        [
            "input",
            "message",
            "unit",
            "frames",
            "rate Hz",
            "max gap/timeout ms",
            "min",
            "p5",
            "median",
            "p95",
            "max",
        ]
    ]
    for st in insp.inputs.stats:
        rows.append(
            [
                st.name,
                st.message,
                st.unit,
                str(st.frames),
                _fixed(st.rate_hz, 1),
                f"{_fixed(st.max_gap_ms, 0)}/{_fixed(st.timeout_ms, 0)}{' STALE' if st.stale_gaps else ''}",
                *(_num(x, 4) for x in (st.minimum, st.p5, st.median, st.p95, st.maximum)),
            ]
        )
    lines += _table(rows, {3, 4, 5, 6, 7, 8, 9, 10})
    shown = []
    for st in insp.inputs.stats:
        if st.unit in _SHOWN and st.frames:
            u, k = _SHOWN[st.unit]
            shown.append(f"{st.name} {_num(st.minimum / k, 4)}..{_num(st.maximum / k, 4)} {u}")
    if shown:
        lines.append("  that is: " + "; ".join(shown))
    if insp.inputs.wheels:
        lines.append(f"  wheel speeds (FL, FR, RL, RR): {', '.join(insp.inputs.wheels)}")
    lines.append("  integrity:")
    for g in insp.inputs.integrity:
        chk = "not verified" if g.checksum_failures is None else f"{g.checksum_failures} checksum failures"
        ctr = "no counter" if g.counter_jumps is None else f"{g.counter_jumps} counter jumps"
        wl = f", {g.wrong_length} of another length" if g.wrong_length else ""
        head = f"    {g.message} (0x{g.frame_id:X}, {g.check}): {g.frames} frames{wl}, {g.used} used"
        lines.append(f"{head}; {chk}; {ctr}")
    return lines


def _checks_part(insp: Inspection) -> list[str]:
    if not insp.checks or insp.geometry is None:
        return []
    g = insp.geometry
    lines = [
        f"Physics checks (vehicle {insp.vehicle}: steering ratio {g.steering_ratio:g},"
        f" wheelbase {g.wheelbase:g} m, track {g.track:g} m; samples above {g.min_speed / KMH:.0f} km/h;"
        " 95 % intervals):"
    ]
    for c in insp.checks:
        lines.append(f"  {c.label}. {c.title}: {c.outcome.value.upper()}")
        lines.append(f"     {c.why}")
        n = c.numbers
        if c.key == "lat_accel" and "bank_deg" in n:
            lines.append(
                f"     intercept {_num(n['intercept'])} m/s^2 (a bank of {n['bank_deg']:.2f} deg,"
                " or an accelerometer offset)"
            )
        if c.key == "yaw_vs_steering" and "steering_offset_deg" in n:
            lines.append(
                f"     steering-angle offset {n['steering_offset_deg']:.2f} deg"
                f" [{n['steering_offset_lo_deg']:.2f}, {n['steering_offset_hi_deg']:.2f}]"
                " (the angle at zero yaw rate on a calm flat road, the yaw rate taken as unbiased)"
            )
        for f in c.fix:
            lines.append(f"     change: {f}")
    lines.append("Signs (ISO 8855: left positive):")
    for name, s in insp.signs.items():
        if s.ok is None:
            verdict = "undecided"
        elif s.ok:
            verdict = "ok"
        else:
            verdict = f"wrong: set {sign_line(name, insp.input_signs.get(name, 1.0))}"
        lines.append(f"  {name}: {verdict} (checks {', '.join(s.checks)})")
    if insp.signs:
        first = next(iter(insp.signs.values()))
        lines.append(f"  the yaw rate's sign from {first.basis}")
        if first.ambiguous:
            lines.append(
                "  ambiguous: as many checks say the yaw rate is wrong as say the others are: drive more, or"
                " use a DBC with per-wheel speeds"
            )
    undecided = [c.key for c in insp.checks if c.outcome is Outcome.NOT_ENOUGH_EXCITATION]
    if undecided:
        lines.append(
            f"  not enough excitation for {', '.join(undecided)}: drive some curves (both directions) above"
            f" {g.min_speed / KMH:.0f} km/h"
        )
    return lines


def render_text(insp: Inspection, source: str) -> str:
    """The inspection for a person (``source``: the log's name and format)."""
    parts = [_log_part(insp, source), _fit_part(insp)]
    if insp.profile is not None:
        parts += [_inputs_part(insp), _checks_part(insp)]
    return "\n".join("\n".join(p) for p in parts if p) + "\n"


def _plain(x: Any) -> Any:
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        out = {f.name: _plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
        for prop in ("sign", "fits", "present", "required", "rate_hz", "duration_s", "bracket"):
            if hasattr(type(x), prop) and isinstance(getattr(type(x), prop), property):
                out[prop] = _plain(getattr(x, prop))
        return out
    if isinstance(x, Enum):
        return x.value
    if isinstance(x, dict) or hasattr(x, "items"):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, tuple | list):
        return [_plain(v) for v in x]
    if isinstance(x, frozenset | set):
        return sorted(_plain(v) for v in x)
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if hasattr(x, "dtype") and getattr(x, "ndim", 1) == 0:  # a numpy scalar
        return _plain(x.item())
    if hasattr(x, "dtype"):
        return None  # arrays (the series) are not part of the report
    return x


def as_dict(insp: Inspection, source: str) -> dict[str, Any]:
    """The inspection as plain data (the JSON's content)."""
    d = _plain(insp)
    d["source"] = source
    if d.get("inputs") is not None:
        d["inputs"].pop("series", None)
    d["names"] = {f"0x{k:X}": v for k, v in insp.names.items()}
    return d


def render_json(insp: Inspection, source: str) -> str:
    """The inspection for a script (module doc)."""
    return json.dumps(as_dict(insp, source), indent=1, allow_nan=False) + "\n"
