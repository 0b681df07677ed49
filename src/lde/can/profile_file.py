"""A profile file (TOML) read into typed declarations, before any DBC is looked at.

The format is documented for users in ``docs/guide/profiles.md``; :func:`read_profile_file` checks its
shape (known keys, types, values from the allowed sets) and says what is wrong in one line that names
the file and the key, ``PROFILE.toml: [inputs.yaw_rate] sign must be +1 or -1, got 2``.
:mod:`lde.can.profiles` then checks the declarations against the DBC (messages, signals, positions).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lde.can.e2e import INTEGRITY
from lde.errors import ConfigError
from lde.units import DEG, KMH, G

__all__ = [
    "INPUT_NAMES",
    "MDPS_INPUTS",
    "ESC_INPUTS",
    "MAY_BE_ABSENT",
    "MAY_BE_UNKNOWN",
    "QUANTITY",
    "UNITS",
    "InputDecl",
    "MessageDecl",
    "ProfileFile",
    "read_profile_file",
    "parse_profile",
]

INPUT_NAMES: tuple[str, ...] = (
    "column_torque",
    "assist_torque",
    "steering_angle",
    "steering_rate",
    "yaw_rate",
    "lat_accel",
    "speed",
)
MDPS_INPUTS: tuple[str, ...] = ("column_torque", "assist_torque", "steering_angle", "steering_rate")
ESC_INPUTS: tuple[str, ...] = ("yaw_rate", "lat_accel", "speed")
#: inputs a car may lack (``absent = true``); the others the estimator cannot run without
MAY_BE_ABSENT: frozenset[str] = frozenset({"assist_torque", "lat_accel", "steering_rate"})
#: inputs whose scale may be ``"unknown"`` (raw counts of a DBC that publishes no unit)
MAY_BE_UNKNOWN: frozenset[str] = frozenset({"column_torque", "assist_torque"})

#: each input's physical quantity, and each quantity's unit names -> SI per unit
QUANTITY: Mapping[str, str] = {
    "column_torque": "torque",
    "assist_torque": "torque",
    "steering_angle": "angle",
    "steering_rate": "angular rate",
    "yaw_rate": "angular rate",
    "lat_accel": "acceleration",
    "speed": "speed",
}
UNITS: Mapping[str, Mapping[str, float]] = {
    "torque": {"Nm": 1.0, "dNm": 0.1, "cNm": 0.01, "mNm": 0.001},
    "angle": {"deg": DEG, "rad": 1.0},
    "angular rate": {"deg/s": DEG, "rad/s": 1.0},
    "acceleration": {"m/s^2": 1.0, "m/s2": 1.0, "g": G},
    "speed": {"km/h": KMH, "kph": KMH, "m/s": 1.0, "mph": 0.44704},
}

_TOP_KEYS = {"name", "description", "dbc", "anchor", "angle_above_torsion_bar", "channel"}
_TABLES = {"inputs", "messages", "outputs"}
_INPUT_KEYS = {
    "absent",
    "message",
    "signal",
    "signals",
    "combine",
    "scale",
    "sign",
    "offset",
    "signed",
    "timeout_ms",
}
_MESSAGE_KEYS = {"integrity", "counter", "checksum", "timeout_ms", "channel"}
_OUTPUT_KEYS = {"dbc", "LDE_Overlay", "LDE_Estimate", "LDE_Diag", "LDE_Disturbance"}


@dataclass(frozen=True)
class InputDecl:
    """One ``[inputs.NAME]`` table. ``scale`` is SI per DBC unit (None: ``"unknown"``), ``unit`` the
    unit name it was given as (empty for a number)."""

    name: str
    absent: bool = False
    message: str = ""
    signals: tuple[str, ...] = ()
    combine: str = "mean"
    scale: float | None = 1.0
    unit: str = ""
    sign: int = 1
    offset: float = 0.0
    signed: bool = True
    timeout_ms: float | None = None


@dataclass(frozen=True)
class MessageDecl:
    """One ``[messages.NAME]`` table."""

    name: str
    integrity: str
    counter: tuple[str, ...] = ()
    checksum: tuple[str, ...] = ()
    timeout_ms: float | None = None
    channel: str | None = None


@dataclass(frozen=True)
class ProfileFile:
    """A profile file's declarations (paths resolved against the file's folder)."""

    path: Path
    name: str
    description: str
    dbc: Path
    anchor: str | None
    angle_above_torsion_bar: bool
    channel: str | None
    inputs: Mapping[str, InputDecl]
    messages: Mapping[str, MessageDecl]
    output_ids: Mapping[str, int]
    output_dbc: Path | None


class _Where:
    """Error messages that start with the file and the table: ``FILE: [inputs.x] ...``."""

    def __init__(self, path: Path, table: str = "") -> None:
        self.path = path
        self.table = table

    def at(self, table: str) -> _Where:
        return _Where(self.path, table)

    def error(self, text: str) -> ConfigError:
        return ConfigError(f"{self.path}: {f'[{self.table}] ' if self.table else ''}{text}")

    def keys(self, table: Mapping[str, Any], allowed: set[str], what: str) -> None:
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.error(f"unknown {what} {unknown[0]!r} (known: {', '.join(sorted(allowed))})")


def _str(w: _Where, d: Mapping[str, Any], key: str, default: str | None = None) -> str | None:
    v = d.get(key, default)
    if v is not None and not isinstance(v, str):
        raise w.error(f"{key} must be a string, got {v!r}")
    return v


def _names(w: _Where, v: Any, key: str) -> tuple[str, ...]:
    """A signal name or a list of them."""
    if isinstance(v, str):
        return (v,)
    if isinstance(v, list) and v and all(isinstance(x, str) for x in v):
        return tuple(v)
    raise w.error(f"{key} must be a signal name or a list of signal names, got {v!r}")


def _number(w: _Where, d: Mapping[str, Any], key: str) -> float | None:
    v = d.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise w.error(f"{key} must be a finite number, got {v!r}")
    return float(v)


def _scale(w: _Where, name: str, v: Any) -> tuple[float | None, str]:
    """(SI per DBC unit or None for unknown, the unit name)."""
    quantity = QUANTITY[name]
    units = UNITS[quantity]
    if isinstance(v, bool):
        raise w.error(f"scale must be a unit name or a number, got {v!r}")
    if isinstance(v, int | float):
        if not (math.isfinite(v) and v > 0):
            raise w.error(f"scale must be a positive number (SI per DBC unit; the sign is 'sign'), got {v!r}")
        return float(v), ""
    if isinstance(v, str):
        if v == "unknown":
            if name not in MAY_BE_UNKNOWN:
                raise w.error(f"scale 'unknown' is allowed only for {' and '.join(sorted(MAY_BE_UNKNOWN))}")
            return None, v
        if v in units:
            return units[v], v
        others = [q for q, us in UNITS.items() if v in us]
        why = f"a unit of {others[0]}, not {quantity}" if others else "not a unit lde knows"
        raise w.error(f"scale {v!r} is {why} (for {name}: {', '.join(units)} or a number)")
    raise w.error(f"scale must be a unit name or a number, got {v!r}")


def _input(w: _Where, name: str, d: Any) -> InputDecl:
    if not isinstance(d, dict):
        raise w.error("must be a table")
    w.keys(d, _INPUT_KEYS, "key")
    absent = d.get("absent", False)
    if not isinstance(absent, bool):
        raise w.error(f"absent must be true or false, got {absent!r}")
    if absent:
        if name not in MAY_BE_ABSENT:
            raise w.error(
                f"{name} cannot be absent: lde needs it (absent: {', '.join(sorted(MAY_BE_ABSENT))})"
            )
        extra = sorted(set(d) - {"absent"})
        if extra:
            raise w.error(f"an absent input takes no other key, got {extra[0]!r}")
        return InputDecl(name, absent=True)
    message = _str(w, d, "message")
    if not message:
        raise w.error("message missing (the DBC message that carries it; or absent = true)")
    if ("signal" in d) == ("signals" in d):
        raise w.error("give the DBC signal as 'signal' (one) or 'signals' (several), not both nor neither")
    signals = _names(w, d.get("signal", d.get("signals")), "signal" if "signal" in d else "signals")
    if len(set(signals)) != len(signals):
        raise w.error(f"signals {list(signals)} name a signal twice")
    combine = _str(w, d, "combine", "mean")
    if combine not in ("mean", "sum"):
        raise w.error(f"combine must be 'mean' or 'sum', got {combine!r}")
    if "scale" not in d:
        raise w.error(f"scale missing (SI per DBC unit: {', '.join(UNITS[QUANTITY[name]])} or a number)")
    scale, unit = _scale(w, name, d["scale"])
    sign = d.get("sign", 1)
    if isinstance(sign, bool) or sign not in (1, -1):
        raise w.error(f"sign must be +1 or -1, got {sign!r}")
    signed = d.get("signed", True)
    if not isinstance(signed, bool):
        raise w.error(f"signed must be true or false, got {signed!r}")
    timeout = _number(w, d, "timeout_ms")
    if timeout is not None and timeout <= 0:
        raise w.error(f"timeout_ms must be > 0, got {timeout:g}")
    return InputDecl(
        name=name,
        message=message,
        signals=signals,
        combine=combine,
        scale=scale,
        unit=unit,
        sign=int(sign),
        offset=_number(w, d, "offset") or 0.0,
        signed=signed,
        timeout_ms=timeout,
    )


def _message(w: _Where, name: str, d: Any) -> MessageDecl:
    if not isinstance(d, dict):
        raise w.error("must be a table")
    w.keys(d, _MESSAGE_KEYS, "key")
    kind = _str(w, d, "integrity")
    if kind is None:
        raise w.error(f"integrity missing (one of: {', '.join(INTEGRITY)})")
    if kind not in INTEGRITY:
        raise w.error(f"unknown integrity {kind!r} (one of: {', '.join(INTEGRITY)})")
    integ = INTEGRITY[kind]
    got: dict[str, tuple[str, ...]] = {}
    for key, need in (("counter", integ.counter), ("checksum", integ.checksum)):
        if key in d:
            if need == "none":
                raise w.error(f"integrity {kind!r} takes no {key} signal")
            got[key] = _names(w, d[key], key)
        elif need == "required":
            raise w.error(f'integrity {kind!r} needs its {key} signal ({key} = "SIGNAL")')
    timeout = _number(w, d, "timeout_ms")
    if timeout is not None and timeout <= 0:
        raise w.error(f"timeout_ms must be > 0, got {timeout:g}")
    channel = _str(w, d, "channel")
    return MessageDecl(name, kind, got.get("counter", ()), got.get("checksum", ()), timeout, channel)


def parse_profile(data: Mapping[str, Any], path: Path) -> ProfileFile:
    """The declarations of a parsed profile file (``path``: where it was read, for paths and errors)."""
    w = _Where(path)
    w.keys(data, _TOP_KEYS | _TABLES, "top-level key")
    for t in _TABLES:
        if t in data and not isinstance(data[t], dict):
            raise w.error(f"{t} must be a table ([{t}])")
    dbc = _str(w, data, "dbc")
    if not dbc:
        raise w.error("dbc missing (the DBC file, relative to this file)")
    above = data.get("angle_above_torsion_bar", False)
    if not isinstance(above, bool):
        raise w.error(f"angle_above_torsion_bar must be true or false, got {above!r}")
    raw_inputs = data.get("inputs", {})
    unknown = sorted(set(raw_inputs) - set(INPUT_NAMES))
    if unknown:
        raise w.error(f"unknown input [inputs.{unknown[0]}] (inputs: {', '.join(INPUT_NAMES)})")
    inputs: dict[str, InputDecl] = {}
    for name in INPUT_NAMES:
        if name not in raw_inputs:
            how = " (or absent = true: the car has none)" if name in MAY_BE_ABSENT else ""
            raise w.error(f"[inputs.{name}] missing: declare its message, signal and scale{how}")
        inputs[name] = _input(w.at(f"inputs.{name}"), name, raw_inputs[name])
    messages = {
        name: _message(w.at(f"messages.{name}"), name, d) for name, d in data.get("messages", {}).items()
    }
    used = dict.fromkeys(i.message for i in inputs.values() if not i.absent)
    for m in messages:
        if m not in used:
            raise w.at(f"messages.{m}").error("no input reads this message")
    outs = data.get("outputs", {})
    wo = w.at("outputs")
    wo.keys(outs, _OUTPUT_KEYS, "key")
    ids: dict[str, int] = {}
    for k, v in outs.items():
        if k == "dbc":
            continue
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 0x800:
            raise wo.error(f"{k} must be an 11-bit CAN id (0..0x7FF), got {v!r}")
        ids[k] = int(v)
    out_dbc = _str(wo, outs, "dbc")
    anchor = _str(w, data, "anchor")
    if anchor is not None and anchor not in used:
        raise w.error(f"anchor {anchor!r} is not one of the input messages ({', '.join(used)})")
    return ProfileFile(
        path=path,
        name=_str(w, data, "name") or path.stem,
        description=_str(w, data, "description") or "",
        dbc=(path.parent / dbc),
        anchor=anchor,
        angle_above_torsion_bar=above,
        channel=_str(w, data, "channel"),
        inputs=inputs,
        messages=messages,
        output_ids=ids,
        output_dbc=None if out_dbc is None else path.parent / out_dbc,
    )


def read_profile_file(path: Path, data: bytes | None = None) -> ProfileFile:
    """Read and check a profile file (``data``: its bytes, when already read)."""
    try:
        raw = path.read_bytes() if data is None else data
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the profile: {exc.strerror or exc}") from None
    try:
        parsed = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not a TOML profile file: {exc}") from None
    return parse_profile(parsed, path)
