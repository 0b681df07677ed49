"""CAN profiles: which DBC, which message/signal feeds each estimator input, units, signs, timeouts,
integrity scheme per message, and lde's output messages.

Two profiles ship (SPEC section 3):

* ``lde`` (``dbc/lde.dbc``): MDPS_Sensors (3.9 ms) and ESC_Motion (10 ms), AUTOSAR E2E Profile 1.
* ``hyundai`` (``dbc/hyundai.dbc``): MDPS12, SAS11, ESP12, WHL_SPD11 of a real car; alive counters
  checked on all, the WHL_SPD11 checksum verified, the other checksums not (algorithms unknown).
  Signs of the car's signals are not published: ISO 8855 (left positive) is assumed for all.
  ``SAS_Speed`` is unsigned on the car, so ``steering_rate`` is a magnitude on this profile.

Estimator inputs (SI, ISO 8855 signs; names used everywhere, see docs/ARCHITECTURE.md)::

    column_torque [Nm]  assist_torque [Nm]  steering_angle [rad]  steering_rate [rad/s]   group "mdps"
    yaw_rate [rad/s]    lat_accel [m/s^2]   speed [m/s]                                   group "esc"

    SI value = sign * to_si * mean(DBC physical values of the input's signals)

The DBC directory is found as ``<repo root>/dbc`` (source checkout or editable install:
``Path(lde.__file__).parents[2] / "dbc"``), else ``lde/data/`` (installed wheel, package data).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import pickle
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from lde.can.e2e import P01_SCHEME, IntegrityKind, IntegrityScheme, ReceiverConfig
from lde.errors import ConfigError
from lde.units import DEG, KMH

if TYPE_CHECKING:  # cantools (and python-can through it) is imported only to parse a DBC
    import cantools

__all__ = [
    "INPUT_NAMES",
    "MDPS_INPUTS",
    "ESC_INPUTS",
    "GROUPS",
    "OUTPUT_MESSAGES",
    "InputMap",
    "MessageSpec",
    "Profile",
    "load_profile",
    "dbc_dir",
    "PROFILE_NAMES",
    "SignalDef",
    "profile_cache_dir",
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
GROUPS: Mapping[str, tuple[str, ...]] = MappingProxyType({"mdps": MDPS_INPUTS, "esc": ESC_INPUTS})
OUTPUT_MESSAGES: tuple[str, ...] = ("LDE_Overlay", "LDE_Estimate", "LDE_Diag", "LDE_Disturbance")

#: default message timeout, in periods of the message (SPEC section 3)
TIMEOUT_PERIODS = 3


@dataclass(frozen=True)
class InputMap:
    """Estimator input <- DBC signal(s): ``si = sign * to_si * mean(signals)``."""

    name: str
    message: str
    signals: tuple[str, ...]
    to_si: float  # SI units per DBC unit (DEG for deg -> rad, KMH for km/h -> m/s, 1.0 otherwise)
    sign: float = 1.0  # +1: the DBC signal is ISO 8855 already
    note: str = ""
    signed: bool = True  # False: the signal is a magnitude (no direction)

    @property
    def group(self) -> str:
        return "mdps" if self.name in MDPS_INPUTS else "esc"

    @property
    def factor(self) -> float:
        """Signed conversion: SI = factor * DBC value."""
        return self.sign * self.to_si

    def to_dbc(self, value_si: float | np.ndarray) -> float | np.ndarray:
        """SI -> DBC physical units (each of ``signals`` gets this value)."""
        return value_si / self.factor


@dataclass(frozen=True)
class MessageSpec:
    """One CAN message lde receives or sends."""

    name: str
    frame_id: int
    length: int  # bytes; frames of another length are malformed
    period_ns: int
    timeout_ns: int
    scheme: IntegrityScheme
    receiver: ReceiverConfig
    inputs: tuple[str, ...] = ()  # estimator inputs fed by this message (empty for outputs)

    @property
    def group(self) -> str | None:
        if not self.inputs:
            return None
        return "mdps" if self.inputs[0] in MDPS_INPUTS else "esc"


@dataclass(frozen=True)
class SignalDef:
    """One DBC signal's bit layout and scaling, as the DBC gives them (physical value = raw * scale +
    offset, in the DBC's unit; ``start``: the DBC start bit, LSB for Intel, MSB for Motorola)."""

    name: str
    start: int
    length: int
    little_endian: bool
    signed: bool
    scale: float
    offset: float
    minimum: float | None
    maximum: float | None
    is_float: bool = False

    @classmethod
    def from_cantools(cls, sig: cantools.database.can.Signal) -> SignalDef:
        return cls(
            name=sig.name,
            start=int(sig.start),
            length=int(sig.length),
            little_endian=sig.byte_order == "little_endian",
            signed=bool(sig.is_signed),
            scale=float(sig.scale),
            offset=float(sig.offset),
            minimum=None if sig.minimum is None else float(sig.minimum),
            maximum=None if sig.maximum is None else float(sig.maximum),
            is_float=bool(sig.is_float),
        )


@dataclass(frozen=True, eq=False)
class Profile:
    """A CAN profile: input signal map, input and output message specs, the signals of those
    messages; the whole DBC database (:attr:`db`, cantools) is parsed only when asked for."""

    name: str
    dbc_path: Path
    inputs: Mapping[str, InputMap]
    messages: Mapping[str, MessageSpec]  # input messages by name
    outputs: Mapping[str, MessageSpec]  # lde's output messages by name
    #: every signal of each input and output message, in the DBC's order
    signals: Mapping[str, tuple[SignalDef, ...]]
    anchor_message: str  # its first accepted frame anchors the step grid (the MDPS torque message)
    angle_above_torsion_bar: bool = False  # the steering angle sensor reads the torsion bar's twist
    dbc_sha256: str = ""  # of the DBC file's bytes when the profile was loaded
    _db: Any = field(default=None, repr=False)

    @property
    def db(self) -> cantools.database.can.Database:
        """The DBC parsed by cantools (on first use: a profile from the cache has not parsed it).
        ConfigError if the file changed since the profile was loaded."""
        if self._db is None:
            data = _read_dbc(self.dbc_path)
            if self.dbc_sha256 and hashlib.sha256(data).hexdigest() != self.dbc_sha256:
                raise ConfigError(f"DBC {self.dbc_path} changed since profile {self.name!r} was loaded")
            object.__setattr__(self, "_db", _parse_dbc(self.dbc_path, data))
        return self._db

    @property
    def steering_rate_signed(self) -> bool:
        """The steering rate carries its direction (needed by the friction correction)."""
        return self.inputs["steering_rate"].signed

    def message_by_id(self, frame_id: int) -> MessageSpec | None:
        """Input message with this 11-bit id, or None."""
        for m in self.messages.values():
            if m.frame_id == frame_id:
                return m
        return None

    def spec(self, name: str) -> MessageSpec:
        """Input or output message spec by name (ConfigError if unknown)."""
        if name in self.messages:
            return self.messages[name]
        if name in self.outputs:
            return self.outputs[name]
        raise ConfigError(
            f"profile {self.name!r} has no message {name!r}; known: {sorted([*self.messages, *self.outputs])}"
        )

    def output_id(self, name: str) -> int:
        return self.outputs[name].frame_id if name in self.outputs else self.spec(name).frame_id

    def group_messages(self, group: str) -> tuple[str, ...]:
        """Names of the input messages feeding the ``group`` ("mdps" | "esc")."""
        return tuple(dict.fromkeys(self.inputs[i].message for i in GROUPS[group]))


# ------------------------------------------------------------------------ profile definitions


@dataclass(frozen=True)
class _ProfileDef:
    inputs: tuple[InputMap, ...]
    counters: Mapping[str, tuple[str, ...]]  # message -> counter signals, LSB part first
    checksums: Mapping[str, tuple[str, ...]]  # message -> checksum signals, LSB part first
    anchor: str
    angle_above_torsion_bar: bool  # the steering angle sensor reads above the torsion bar (its twist)


_LDE = _ProfileDef(
    inputs=(
        InputMap("column_torque", "MDPS_Sensors", ("ColumnTorque",), 1.0),
        InputMap("assist_torque", "MDPS_Sensors", ("AssistTorque",), 1.0),
        InputMap("steering_angle", "MDPS_Sensors", ("SteeringAngle",), DEG),
        InputMap("steering_rate", "MDPS_Sensors", ("SteeringRate",), DEG),
        InputMap("yaw_rate", "ESC_Motion", ("YawRate",), DEG),
        InputMap("lat_accel", "ESC_Motion", ("LatAccel",), 1.0),
        InputMap("speed", "ESC_Motion", ("VehicleSpeed",), KMH),
    ),
    counters={"MDPS_Sensors": ("Counter",), "ESC_Motion": ("Counter",)},
    checksums={"MDPS_Sensors": ("CRC",), "ESC_Motion": ("CRC",)},
    anchor="MDPS_Sensors",
    angle_above_torsion_bar=False,  # the MDPS senses the angle on the motor/pinion side
)

_HYUNDAI = _ProfileDef(
    inputs=(
        InputMap("column_torque", "MDPS12", ("CR_Mdps_StrTq",), 1.0, note="ISO sign assumed"),
        InputMap("assist_torque", "MDPS12", ("CR_Mdps_OutTq",), 1.0, note="taken as Nm; ISO sign assumed"),
        InputMap("steering_angle", "SAS11", ("SAS_Angle",), DEG, note="ISO sign assumed"),
        InputMap(
            "steering_rate",
            "SAS11",
            ("SAS_Speed",),
            DEG,
            note="unsigned on the car: a magnitude",
            signed=False,
        ),
        InputMap("yaw_rate", "ESP12", ("YAW_RATE",), DEG, note="ISO sign assumed"),
        InputMap("lat_accel", "ESP12", ("LAT_ACCEL",), 1.0, note="ISO sign assumed"),
        InputMap(
            "speed",
            "WHL_SPD11",
            ("WHL_SPD_FL", "WHL_SPD_FR", "WHL_SPD_RL", "WHL_SPD_RR"),
            KMH,
            note="mean of the four wheel speeds",
        ),
    ),
    counters={
        "MDPS12": ("CF_Mdps_MsgCount2",),
        "SAS11": ("MsgCount",),
        "ESP12": ("ESP12_AliveCounter",),
        "WHL_SPD11": ("WHL_SPD_AliveCounter_LSB", "WHL_SPD_AliveCounter_MSB"),
    },
    checksums={
        "MDPS12": ("CF_Mdps_Chksum2",),
        "SAS11": ("CheckSum",),
        "ESP12": ("ESP12_Checksum",),
        "WHL_SPD11": ("WHL_SPD_Checksum_LSB", "WHL_SPD_Checksum_MSB"),
    },
    anchor="MDPS12",
    angle_above_torsion_bar=True,  # SAS11 sits on the column, above the torsion bar
)

_DEFS: Mapping[str, _ProfileDef] = MappingProxyType({"lde": _LDE, "hyundai": _HYUNDAI})
PROFILE_NAMES: tuple[str, ...] = tuple(_DEFS)

_OUTPUT_COUNTERS = ("Counter",)
_OUTPUT_CHECKSUMS = ("CRC",)


def dbc_dir() -> Path:
    """The directory holding the shipped ``*.dbc`` files (repo ``dbc/`` or the package's ``data/``)."""
    package = Path(__file__).resolve().parents[1]  # src/lde
    for d in (package.parents[1] / "dbc", package / "data"):
        if (d / "lde.dbc").is_file():
            return d
    raise ConfigError(
        f"cannot find the DBC directory (looked in {package.parents[1] / 'dbc'} and {package / 'data'})"
    )


def _fields(
    msg: cantools.database.can.Message, names: tuple[str, ...], where: str
) -> tuple[tuple[int, int], ...]:
    out = []
    for n in names:
        try:
            s = msg.get_signal_by_name(n)
        except KeyError:
            raise ConfigError(f"{where}: message {msg.name} has no signal {n!r}") from None
        if s.byte_order != "little_endian":
            raise ConfigError(f"{where}: integrity signal {msg.name}.{n} must be Intel (little-endian)")
        out.append((int(s.start), int(s.length)))
    return tuple(out)


def _attr(msg: cantools.database.can.Message, db: cantools.database.can.Database, name: str):
    attrs = msg.dbc.attributes if msg.dbc is not None else {}
    if name in attrs:
        return attrs[name].value
    defs = db.dbc.attribute_definitions if db.dbc is not None else {}
    return defs[name].default_value if name in defs else None


def _period_ns(msg, db) -> int:
    us = _attr(msg, db, "LdeCycleTime_us")
    if us:
        return int(us) * 1000
    if msg.cycle_time:
        return int(msg.cycle_time) * 1_000_000
    raise ConfigError(f"message {msg.name} has no cycle time (BA_ LdeCycleTime_us or GenMsgCycleTime)")


def _scheme(msg, db, counters, checksums, where: str) -> IntegrityScheme:
    kind_s = _attr(msg, db, "LdeE2E") or "P01_BOTH"
    try:
        kind = IntegrityKind(kind_s)
    except ValueError:
        raise ConfigError(f"{where}: {msg.name} has unknown LdeE2E {kind_s!r}") from None
    cf = _fields(msg, counters, where)
    kf = _fields(msg, checksums, where) if checksums else ()
    if kind is IntegrityKind.P01:
        if cf != P01_SCHEME.counter_fields or kf != P01_SCHEME.checksum_fields:
            raise ConfigError(f"{where}: {msg.name} is Profile 1 but Counter/CRC are not at 8|4 and 0|8")
        return P01_SCHEME
    bits = sum(n for _, n in cf)
    return IntegrityScheme(kind, cf, kf, modulus=1 << bits, invalid_counter=-1)


def _spec(
    msg, db, counters, checksums, inputs, where, timeout_periods, max_delta, sync_frames
) -> MessageSpec:
    period = _period_ns(msg, db)
    timeout = timeout_periods * period
    scheme = _scheme(msg, db, counters, checksums, where)
    return MessageSpec(
        name=msg.name,
        frame_id=int(msg.frame_id),
        length=int(msg.length),
        period_ns=period,
        timeout_ns=timeout,
        scheme=scheme,
        receiver=ReceiverConfig.for_scheme(scheme, timeout, max_delta=max_delta, sync_frames=sync_frames),
        inputs=inputs,
    )


#: bump when what the cache holds changes shape (the sources of this module and lde.can.e2e are part of
#: the key as well, so a code change never serves an old entry)
_CACHE_FORMAT = 1


def profile_cache_dir() -> Path | None:
    """Where parsed profiles are cached: ``$LDE_PROFILE_CACHE`` (``off``: no cache), else
    ``$XDG_CACHE_HOME/lde/profiles`` (default ``~/.cache/lde/profiles``)."""
    env = os.environ.get("LDE_PROFILE_CACHE")
    if env:
        return None if env.lower() in ("off", "0", "no") else Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "lde" / "profiles"


def _read_dbc(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise ConfigError(f"cannot read DBC {path}: {e.strerror or e}") from None


def _parse_dbc(path: Path, data: bytes) -> cantools.database.can.Database:
    import cantools  # ~20 ms, and python-can (~35-110 ms) through its tester: only on a cache miss

    try:
        # decoded as cantools.database.load_file decodes a .dbc (cp1252, errors replaced), from the
        # bytes that were hashed: the cache key is always the parsed file's
        text = data.decode("cp1252", errors="replace")
        db = cantools.database.load_string(text, database_format="dbc", strict=True)
    except Exception as e:  # cantools raises several parser error types
        raise ConfigError(f"cannot read DBC {path}: {e}") from e
    if not isinstance(db, cantools.database.can.Database):
        raise ConfigError(f"{path} is not a CAN database")
    return db


def _cache_key(dbc_sha: str, key: str, params: tuple[int, int, int]) -> str:
    """The DBC's bytes (their SHA-256), which definition it is read with, the receiver parameters,
    this module's and lde.can.e2e's sources (what a profile is built from) and the interpreter (pickle)."""
    h = hashlib.sha256()
    h.update(f"{_CACHE_FORMAT}|{key if key in _DEFS else '<path>'}|{params}|{sys.version_info[:2]}|".encode())
    for src in (Path(__file__), Path(__file__).with_name("e2e.py")):
        try:
            h.update(src.read_bytes())
        except OSError:
            return ""  # sources not readable as files (a zip): no cache
    h.update(dbc_sha.encode())
    return h.hexdigest()


def _cache_get(where: Path | None, key: str, dbc_sha: str) -> dict | None:
    """The cached parts of a profile, or None (no entry, unreadable, corrupt, incomplete, or another
    DBC's). The entries are pickles in the user's own cache, trusted as numba's cache beside them is."""
    if where is None or not key:
        return None
    try:
        with open(where / f"{key}.pickle", "rb") as fh:
            parts = pickle.load(fh)
    except Exception:  # missing, unreadable, truncated or corrupt: parse the DBC instead
        return None
    if not isinstance(parts, dict) or parts.get("key") != key or parts.get("dbc_sha256") != dbc_sha:
        return None
    if not all(isinstance(parts.get(k), dict) for k in ("inputs", "messages", "outputs", "signals")):
        return None
    if not isinstance(parts.get("anchor"), str) or not isinstance(parts.get("angle_above_torsion_bar"), bool):
        return None
    return parts


def _cache_put(where: Path | None, key: str, parts: dict) -> None:
    """Write an entry atomically; a cache that cannot be written is skipped (the DBC is parsed
    again next time)."""
    if where is None or not key:
        return
    tmp = where / f".{key}.{os.getpid()}.tmp"
    try:
        where.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            pickle.dump(parts, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, where / f"{key}.pickle")
    except Exception:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


def load_profile(
    name_or_path: str | Path = "lde",
    *,
    timeout_periods: int = TIMEOUT_PERIODS,
    max_delta: int = 2,
    sync_frames: int = 2,
) -> Profile:
    """Load profile ``"lde"`` / ``"hyundai"``, or a ``.dbc`` file laid out like one of them.

    A path to a DBC is matched to a profile definition by its input message names (a variant of
    ``lde.dbc`` with other ids or scalings works). ``timeout_periods``, ``max_delta`` (MaxDeltaCounter)
    and ``sync_frames`` (good frames before a message is trusted again) configure every receiver.

    The parsed profile is cached (:func:`profile_cache_dir`) under a key of the DBC file's bytes,
    these arguments and the sources that build it: a changed DBC is parsed again, never served from
    the cache; a missing, corrupt or unwritable cache falls back to parsing (cantools).

    Raises:
        ConfigError: unknown profile, unreadable DBC, or a DBC missing a message/signal the profile needs.
    """
    key = str(name_or_path)
    if key in _DEFS:
        path = dbc_dir() / f"{key}.dbc"
        pname = key
    else:
        path = Path(key)
        if path.suffix.lower() != ".dbc" or not path.is_file():
            raise ConfigError(
                f"unknown CAN profile {key!r}: use one of {list(_DEFS)} or the path of a .dbc file"
            )
        pname = path.stem
    data = _read_dbc(path)
    dbc_sha = hashlib.sha256(data).hexdigest()
    params = (int(timeout_periods), int(max_delta), int(sync_frames))
    where = profile_cache_dir()
    ckey = _cache_key(dbc_sha, key, params) if where is not None else ""
    parts = _cache_get(where, ckey, dbc_sha)
    db = None
    if parts is None:
        db = _parse_dbc(path, data)
        parts = _build(db, key, path, f"profile {pname!r} ({path})", params)
        parts.update(key=ckey, dbc_sha256=dbc_sha)
        _cache_put(where, ckey, parts)
    return Profile(
        name=pname,
        dbc_path=path,
        inputs=MappingProxyType(dict(parts["inputs"])),
        messages=MappingProxyType(dict(parts["messages"])),
        outputs=MappingProxyType(dict(parts["outputs"])),
        signals=MappingProxyType(dict(parts["signals"])),
        anchor_message=parts["anchor"],
        angle_above_torsion_bar=parts["angle_above_torsion_bar"],
        dbc_sha256=dbc_sha,
        _db=db,
    )


def _build(
    db: cantools.database.can.Database, key: str, path: Path, where: str, params: tuple[int, int, int]
) -> dict[str, Any]:
    """A profile's parts (plain data: cached) from the parsed DBC; ConfigError where it does not fit."""
    timeout_periods, max_delta, sync_frames = params
    names = {m.name for m in db.messages}
    if key in _DEFS:
        pdef = _DEFS[key]
    else:
        matches = [k for k, d in _DEFS.items() if {i.message for i in d.inputs} <= names]
        if not matches:
            raise ConfigError(
                f"{path}: its messages {sorted(names)} do not contain the inputs of any profile "
                f"({ {k: sorted({i.message for i in d.inputs}) for k, d in _DEFS.items()} })"
            )
        pdef = _DEFS[matches[0]]
    inputs = {}
    for im in pdef.inputs:
        if im.message not in names:
            raise ConfigError(f"{where}: missing message {im.message!r}")
        msg = db.get_message_by_name(im.message)
        for s in im.signals:
            if s not in msg.signal_tree:
                raise ConfigError(f"{where}: message {im.message} has no signal {s!r} (input {im.name})")
        inputs[im.name] = im

    messages: dict[str, MessageSpec] = {}
    for mname in dict.fromkeys(im.message for im in pdef.inputs):
        msg = db.get_message_by_name(mname)
        feeds = tuple(i.name for i in pdef.inputs if i.message == mname)
        groups = {("mdps" if f in MDPS_INPUTS else "esc") for f in feeds}
        if len(groups) != 1:
            raise ConfigError(f"{where}: message {mname} feeds inputs of both groups")
        messages[mname] = _spec(
            msg,
            db,
            pdef.counters[mname],
            pdef.checksums.get(mname, ()),
            feeds,
            where,
            timeout_periods,
            max_delta,
            sync_frames,
        )

    outputs: dict[str, MessageSpec] = {}
    for oname in OUTPUT_MESSAGES:
        if oname not in names:
            raise ConfigError(f"{where}: missing output message {oname!r}")
        msg = db.get_message_by_name(oname)
        spec = _spec(
            msg, db, _OUTPUT_COUNTERS, _OUTPUT_CHECKSUMS, (), where, timeout_periods, max_delta, sync_frames
        )
        if spec.scheme.kind is not IntegrityKind.P01:
            raise ConfigError(f"{where}: output {oname} must carry E2E Profile 1 (LdeE2E P01_BOTH)")
        outputs[oname] = spec

    ids = [m.frame_id for m in messages.values()] + [m.frame_id for m in outputs.values()]
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{where}: duplicate CAN ids among inputs and outputs: {ids}")

    signals = {
        name: tuple(SignalDef.from_cantools(sg) for sg in db.get_message_by_name(name).signals)
        for name in [*messages, *outputs]
    }
    return {
        "inputs": inputs,
        "messages": messages,
        "outputs": outputs,
        "signals": signals,
        "anchor": pdef.anchor,
        "angle_above_torsion_bar": pdef.angle_above_torsion_bar,
    }
