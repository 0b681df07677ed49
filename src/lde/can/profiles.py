"""CAN profiles: which DBC, which message/signal feeds each estimator input, units, signs, timeouts,
integrity check per message, the bus of each message, and lde's output messages.

A profile is a TOML file (``docs/guide/profiles.md``; :mod:`lde.can.profile_file` reads it) that names its
DBC. Three ship beside their DBCs (``dbc/`` in a source tree, ``lde/data/`` in an installed wheel),
each loadable by its short name: ``lde`` (lde's own bus, AUTOSAR E2E Profile 1), ``hyundai`` (a real
car's C-CAN: alive counters, the WHL_SPD11 checksum) and ``toyota_rav4_2017`` (a real car's bus from
opendbc's facts: Toyota checksums, torques of unknown scale).

Estimator inputs (SI, ISO 8855 signs; names used everywhere, see docs/design/architecture.md)::

    column_torque [Nm]  assist_torque [Nm]  steering_angle [rad]  steering_rate [rad/s]   group "mdps"
    yaw_rate [rad/s]    lat_accel [m/s^2]   speed [m/s]                                   group "esc"

    SI value = sign * scale * (combined DBC physical values of the input's signals + offset)
    combined = their mean (default) or their sum

An input the car does not have is declared absent: it is never valid (NaN), never fresh, and does not
count against its group (the group is usable without it); what the estimator then does without it is
documented in ``docs/guide/profiles.md``. A torque input may have an unknown scale (raw counts): its value
enters as the DBC value with scale 1, and :attr:`Profile.torque_scales_known` is False: the
estimator learns what the data make identifiable and the engine keeps the overlay off until it is
learned, or for good with both torques of unknown scale (``docs/guide/profiles.md``).

A message without a cycle time in its DBC (``GenMsgCycleTime`` or lde's ``LdeCycleTime_us``) and
without ``timeout_ms`` gets its timeout from a log: :func:`observe_timeouts` (3 periods of the rate
observed in the log's first frames).
"""

from __future__ import annotations

import contextlib
import difflib
import hashlib
import os
import pickle
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from lde.can.bitfield import field_bytes
from lde.can.e2e import INTEGRITY, P01_SCHEME, IntegrityScheme, ReceiverConfig
from lde.can.frames import FrameBatch
from lde.can.profile_file import (
    ESC_INPUTS,
    INPUT_NAMES,
    MDPS_INPUTS,
    InputDecl,
    MessageDecl,
    ProfileFile,
    read_profile_file,
)
from lde.errors import ConfigError

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
    "observe_timeouts",
    "dbc_dir",
    "shipped_profiles",
    "PROFILE_NAMES",
    "SignalDef",
    "profile_cache_dir",
    "DOCS",
]

GROUPS: Mapping[str, tuple[str, ...]] = MappingProxyType({"mdps": MDPS_INPUTS, "esc": ESC_INPUTS})
OUTPUT_MESSAGES: tuple[str, ...] = ("LDE_Overlay", "LDE_Estimate", "LDE_Diag", "LDE_Disturbance")
#: where a user reads how to write a profile
DOCS = "docs/guide/profiles.md"

#: what the estimator does without an input the car lacks (docs/guide/profiles.md)
_ABSENT_EFFECT: Mapping[str, str] = MappingProxyType(
    {
        "lat_accel": "crosswind and bank are not told apart, the learner does not learn",
        "assist_torque": "no aligning torque: every step has MDPS_FAULT, no estimate is valid",
        "steering_rate": "the paper filter's friction correction does without it",
    }
)

#: default message timeout, in periods of the message (SPEC section 3)
TIMEOUT_PERIODS = 3
#: frames of a log looked at for a message's observed period
_OBSERVE_MIN_FRAMES = 3


@dataclass(frozen=True)
class InputMap:
    """Estimator input <- DBC signal(s): ``si = sign * to_si * (combine(signals) + offset)``."""

    name: str
    message: str
    signals: tuple[str, ...]
    to_si: float  # SI units per DBC unit (DEG for deg -> rad, KMH for km/h -> m/s, 1.0 otherwise)
    sign: float = 1.0  # +1: the DBC signal is ISO 8855 already
    note: str = ""
    signed: bool = True  # False: the signal is a magnitude (no direction)
    offset: float = 0.0  # in the DBC signal's unit, added before the scale and sign
    combine: str = "mean"  # "mean" or "sum" of the signals
    unknown_scale: bool = False  # raw counts of an unpublished unit: to_si is 1

    @property
    def group(self) -> str:
        return "mdps" if self.name in MDPS_INPUTS else "esc"

    @property
    def factor(self) -> float:
        """Signed conversion: SI = factor * (combined DBC value + offset)."""
        return self.sign * self.to_si

    def to_dbc(self, value_si: float | np.ndarray) -> float | np.ndarray:
        """SI -> the combined DBC value (before it is split over the signals)."""
        return value_si / self.factor - self.offset


@dataclass(frozen=True)
class MessageSpec:
    """One CAN message lde receives or sends. ``period_ns`` / ``timeout_ns`` 0: not known yet (a
    log's observed rate gives them, :func:`observe_timeouts`); ``receiver`` is None until then."""

    name: str
    frame_id: int
    length: int  # bytes (up to 64: CAN FD); frames of another length are malformed
    period_ns: int
    timeout_ns: int
    scheme: IntegrityScheme
    receiver: ReceiverConfig | None
    inputs: tuple[str, ...] = ()  # estimator inputs fed by this message (empty for outputs)
    channel: str | None = None  # the bus it is read from in a log with several (None: whichever)

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
    unit: str = ""

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
            unit=str(sig.unit or ""),
        )


@dataclass(frozen=True, eq=False)
class Profile:
    """A CAN profile: input signal map, input and output message specs, the signals of those
    messages; the whole DBC database (:attr:`db`, cantools) is parsed only when asked for."""

    name: str
    dbc_path: Path
    inputs: Mapping[str, InputMap]  # the inputs the car has (absent ones are in ``absent``)
    messages: Mapping[str, MessageSpec]  # input messages by name
    outputs: Mapping[str, MessageSpec]  # lde's output messages by name
    #: every signal of each input and output message, in the DBC's order
    signals: Mapping[str, tuple[SignalDef, ...]]
    anchor_message: str  # its first accepted frame anchors the step grid (the MDPS torque message)
    angle_above_torsion_bar: bool = False  # the steering angle sensor reads the torsion bar's twist
    dbc_sha256: str = ""  # of the DBC file's bytes when the profile was loaded
    path: Path | None = None  # the profile file
    absent: frozenset[str] = frozenset()  # inputs the car does not have
    description: str = ""
    #: the receivers' (timeout periods, MaxDeltaCounter, sync frames) it was loaded with
    params: tuple[int, int, int] = (TIMEOUT_PERIODS, 2, 2)
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
    def shipped(self) -> bool:
        """One of the profiles that ship with lde (loadable by its name)."""
        return self.path is not None and self.path == _shipped_path(self.name)

    @property
    def steering_rate_signed(self) -> bool:
        """The steering rate carries its direction (needed by the friction correction)."""
        im = self.inputs.get("steering_rate")
        return im is not None and im.signed

    @property
    def unknown_scale(self) -> frozenset[str]:
        """The torque inputs whose scale is not known (raw counts)."""
        return frozenset(n for n, im in self.inputs.items() if im.unknown_scale)

    @property
    def torque_scales_known(self) -> bool:
        """Every torque input present has a known scale (a torque request in unknown units is unsafe:
        otherwise the overlay waits for the learned factor, or stays off with both unknown)."""
        return not self.unknown_scale

    @property
    def timeouts_known(self) -> bool:
        """Every input message has a timeout (else :func:`observe_timeouts` on a log first)."""
        return all(m.receiver is not None for m in self.messages.values())

    def notes(self) -> list[str]:
        """What this profile's car lacks, one line each for the user (``docs/guide/profiles.md``): its
        absent inputs and its torques of unknown scale."""
        out = [f"profile {self.name}: {name} absent: {_ABSENT_EFFECT[name]}" for name in sorted(self.absent)]
        if self.unknown_scale:
            names = " and ".join(sorted(self.unknown_scale))
            why = (
                "the overlay stays off (the torques' unit to Nm is not identifiable)"
                if len(self.unknown_scale) > 1
                else "its factor to the other torque is learned; the overlay stays off until it is"
            )
            out.append(f"profile {self.name}: {names} of unknown scale: {why}")
        return out

    def metadata(self) -> dict[str, str]:
        """The entries of a recording's ``lde`` metadata record that name this profile: ``profile``
        (its name) and, for a profile file that does not ship with lde, ``profile_file`` (its path)."""
        out = {"profile": self.name}
        if not self.shipped and self.path is not None:
            out["profile_file"] = str(self.path.resolve())
        return out

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
        return tuple(dict.fromkeys(self.inputs[i].message for i in GROUPS[group] if i in self.inputs))


# ------------------------------------------------------------------------ where profiles live


def dbc_dir() -> Path:
    """The directory holding the shipped profiles and DBCs (repo ``dbc/`` or the package's ``data/``)."""
    here = Path(__file__).resolve()
    for d in (here.parents[3] / "dbc", here.parents[1] / "data"):
        if (d / "lde.toml").is_file():
            return d
    looked = f"{here.parents[3] / 'dbc'} and {here.parents[1] / 'data'}"
    raise ConfigError(f"cannot find the shipped profiles (looked in {looked})")


def shipped_profiles() -> tuple[str, ...]:
    """The names of the shipped profiles (``lde`` first)."""
    try:
        names = sorted(p.stem for p in dbc_dir().glob("*.toml"))
    except ConfigError:
        return ()
    return tuple(sorted(names, key=lambda n: (n != "lde", n)))


#: the shipped profiles' names
PROFILE_NAMES: tuple[str, ...] = shipped_profiles()


def _shipped_path(name: str) -> Path | None:
    if name not in PROFILE_NAMES:
        return None
    return dbc_dir() / f"{name}.toml"


def resolve_profile_path(name_or_path: str | Path) -> Path:
    """The profile file of a shipped name or a path (ConfigError for anything else, with the way
    out for a ``.dbc`` given where a profile is asked for)."""
    key = str(name_or_path)
    shipped = _shipped_path(key)
    if shipped is not None:
        return shipped
    path = Path(key)
    if path.suffix.lower() == ".dbc":
        raise ConfigError(
            f'{key}: a DBC is not a profile: write a profile file that names it (dbc = "{path.name}") '
            f"and maps its signals to lde's inputs ({DOCS}); shipped profiles: {', '.join(PROFILE_NAMES)}"
        )
    if not path.is_file():
        raise ConfigError(
            f"unknown CAN profile {key!r}: give a shipped name ({', '.join(PROFILE_NAMES)}) or a profile "
            f"file (.toml, {DOCS})"
        )
    return path


# ------------------------------------------------------------------------------ the cache

#: bump when what the cache holds changes shape (the sources of the modules that build a profile
#: are part of the key as well, so a code change never serves an old entry)
_CACHE_FORMAT = 2


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


def _cache_key(shas: tuple[str, ...], params: tuple[int, int, int], path: Path) -> str:
    """The profile file's, its DBC's (and its output DBC's) bytes, the file's path (relative paths in
    it), the receiver parameters, the sources that build a profile and the interpreter (pickle)."""
    h = hashlib.sha256()
    h.update(f"{_CACHE_FORMAT}|{params}|{sys.version_info[:2]}|{path.resolve()}|".encode())
    here = Path(__file__)
    for src in (
        here,
        here.with_name("e2e.py"),
        here.with_name("profile_file.py"),
        here.with_name("bitfield.py"),
    ):
        try:
            h.update(src.read_bytes())
        except OSError:
            return ""  # sources not readable as files (a zip): no cache
    for s in shas:
        h.update(s.encode())
    return h.hexdigest()


_PARTS = ("inputs", "messages", "outputs", "signals")


def _cache_get(where: Path | None, key: str) -> dict | None:
    """The cached parts of a profile, or None (no entry, unreadable, corrupt, incomplete). The
    entries are pickles in the user's own cache, trusted as numba's cache beside them is."""
    if where is None or not key:
        return None
    try:
        with open(where / f"{key}.pickle", "rb") as fh:
            parts = pickle.load(fh)
    except Exception:  # missing, unreadable, truncated or corrupt: parse the DBC instead
        return None
    if not isinstance(parts, dict) or parts.get("key") != key:
        return None
    if not all(isinstance(parts.get(k), dict) for k in _PARTS) or not isinstance(parts.get("anchor"), str):
        return None
    if not isinstance(parts.get("absent"), frozenset):
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


# ------------------------------------------------------------------------------ loading


def load_profile(
    name_or_path: str | Path = "lde",
    *,
    timeout_periods: int = TIMEOUT_PERIODS,
    max_delta: int = 2,
    sync_frames: int = 2,
) -> Profile:
    """Load a shipped profile by name (``"lde"``, ``"hyundai"``, ...) or a profile file (``.toml``).

    ``timeout_periods`` (a message's default timeout in periods of its cycle time), ``max_delta``
    (MaxDeltaCounter) and ``sync_frames`` (good frames before a message is trusted again) configure
    every receiver.

    The built profile is cached (:func:`profile_cache_dir`) under a key of the profile file's and
    the DBC's bytes, these arguments and the sources that build it: a changed file is read again,
    never served from the cache; a missing, corrupt or unwritable cache falls back to parsing.

    Raises:
        ConfigError: an unknown name, a ``.dbc`` given instead of a profile, an unreadable file, or
            a profile that does not fit its DBC; the message names the file and the key.
    """
    path = resolve_profile_path(name_or_path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the profile: {exc.strerror or exc}") from None
    pf = read_profile_file(path, raw)
    dbc_data = _read_dbc_for(pf, pf.dbc, "dbc")
    out_dbc = pf.output_dbc
    out_data = _read_dbc_for(pf, out_dbc, "[outputs] dbc") if out_dbc is not None else b""
    shas = tuple(hashlib.sha256(x).hexdigest() for x in (raw, dbc_data, out_data))
    params = (int(timeout_periods), int(max_delta), int(sync_frames))
    where = profile_cache_dir()
    ckey = _cache_key(shas, params, path) if where is not None else ""
    parts = _cache_get(where, ckey)
    db = None
    if parts is None:
        db = _parse_dbc(pf.dbc, dbc_data)
        parts = _build(pf, db, params)
        parts["key"] = ckey
        _cache_put(where, ckey, parts)
    return Profile(
        name=pf.name,
        dbc_path=pf.dbc,
        inputs=MappingProxyType(dict(parts["inputs"])),
        messages=MappingProxyType(dict(parts["messages"])),
        outputs=MappingProxyType(dict(parts["outputs"])),
        signals=MappingProxyType(dict(parts["signals"])),
        anchor_message=parts["anchor"],
        angle_above_torsion_bar=pf.angle_above_torsion_bar,
        dbc_sha256=shas[1],
        path=path,
        absent=parts["absent"],
        description=pf.description,
        params=params,
        _db=db,
    )


def _read_dbc_for(pf: ProfileFile, path: Path, key: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise ConfigError(f"{pf.path}: {key} {path} cannot be read: {e.strerror or e}") from None


def _near(name: str, names: list[str], n: int = 12) -> str:
    """``names`` for an error message: all of them when few, else the closest ones."""
    if len(names) <= n:
        return ", ".join(names)
    close = difflib.get_close_matches(name, names, n=5, cutoff=0.4)
    return (f"closest: {', '.join(close)}; " if close else "") + f"{len(names)} in all"


def _attr(msg: cantools.database.can.Message, db: cantools.database.can.Database, name: str):
    attrs = msg.dbc.attributes if msg.dbc is not None else {}
    if name in attrs:
        return attrs[name].value
    defs = db.dbc.attribute_definitions if db.dbc is not None else {}
    return defs[name].default_value if name in defs else None


def _period_ns(msg, db) -> int:
    """The cycle time the DBC gives (lde's ``LdeCycleTime_us``, else ``GenMsgCycleTime``), 0: none."""
    us = _attr(msg, db, "LdeCycleTime_us")
    if us:
        return int(us) * 1000
    if msg.cycle_time:
        return int(msg.cycle_time) * 1_000_000
    return 0


class _Check:
    """Errors of one profile: ``FILE: [table] text``."""

    def __init__(self, pf: ProfileFile) -> None:
        self.pf = pf

    def error(self, table: str, text: str) -> ConfigError:
        return ConfigError(f"{self.pf.path}: {f'[{table}] ' if table else ''}{text}")


def _message(c: _Check, db, name: str, table: str, dbc: Path):
    names = [m.name for m in db.messages]
    if name not in names:
        raise c.error(table, f"message {name!r} not in {dbc.name} (messages: {_near(name, names)})")
    return db.get_message_by_name(name)


def _signal(c: _Check, msg, name: str, table: str, what: str = "signal") -> SignalDef:
    names = [s.name for s in msg.signals]
    if name not in names:
        raise c.error(table, f"{what} {name!r} not in message {msg.name!r} (signals: {_near(name, names)})")
    sig = SignalDef.from_cantools(msg.get_signal_by_name(name))
    if sig.is_float:
        raise c.error(table, f"{what} {name!r} of {msg.name!r} is an IEEE float: lde reads integer signals")
    return sig


def _input_map(c: _Check, db, d: InputDecl, dbc: Path) -> InputMap:
    table = f"inputs.{d.name}"
    msg = _message(c, db, d.message, table, dbc)
    for s in d.signals:
        _signal(c, msg, s, table)
    note = "scale unknown: raw counts" if d.scale is None else ""
    return InputMap(
        name=d.name,
        message=d.message,
        signals=d.signals,
        to_si=1.0 if d.scale is None else d.scale,
        sign=float(d.sign),
        note=note,
        signed=d.signed,
        offset=d.offset,
        combine=d.combine,
        unknown_scale=d.scale is None,
    )


def _fields(
    c: _Check, msg, names: tuple[str, ...], table: str, what: str
) -> tuple[tuple[int, int, bool], ...]:
    out = []
    for n in names:
        s = _signal(c, msg, n, table, what)
        out.append((s.start, s.length, s.little_endian))
    return tuple(out)


def _scheme(c: _Check, msg, d: MessageDecl, table: str) -> IntegrityScheme:
    integ = INTEGRITY[d.integrity]
    cf = _fields(c, msg, d.counter, table, "counter signal")
    kf = _fields(c, msg, d.checksum, table, "checksum signal")
    length = int(msg.length)
    if d.integrity == "autosar_e2e_p01":
        if cf != P01_SCHEME.counter_fields or kf != P01_SCHEME.checksum_fields:
            raise c.error(
                table,
                "autosar_e2e_p01 needs the CRC at 0|8@1 (byte 0) and the counter at 8|4@1 (low nibble of "
                "byte 1)",
            )
        return P01_SCHEME
    if d.integrity == "toyota_checksum" and (len(kf) != 1 or field_bytes(*kf[0]) != (length - 1, length - 1)):
        raise c.error(
            table, f"toyota_checksum needs its checksum in the last byte (byte {length - 1}), one field"
        )
    if d.integrity == "hyundai_whl_spd11" and length != 8:
        raise c.error(table, f"hyundai_whl_spd11 checks 8-byte frames; {msg.name} has {length}")
    if sum(n for _, n, _ in cf) > 16:
        raise c.error(table, "a counter of more than 16 bits")
    return IntegrityScheme.of(integ, cf, kf)


def _spec(
    c: _Check, pf: ProfileFile, db, name: str, feeds: tuple[str, ...], params: tuple[int, int, int]
) -> MessageSpec:
    timeout_periods, max_delta, sync_frames = params
    table = f"messages.{name}"
    d = pf.messages[name]
    msg = _message(c, db, name, table, pf.dbc)
    if msg.is_extended_frame:
        raise c.error(table, f"{name} has a 29-bit id: lde reads 11-bit input messages")
    if not 0 < int(msg.length) <= 64:
        raise c.error(table, f"{name} has {msg.length} bytes: a CAN frame has 1..64")
    scheme = _scheme(c, msg, d, table)
    period = _period_ns(msg, db)
    asked = {t for i in feeds if (t := pf.inputs[i].timeout_ms) is not None}
    if len(asked) > 1:
        raise c.error(f"inputs.{feeds[0]}", f"inputs of {name} ask for different timeout_ms {sorted(asked)}")
    timeout_ms = d.timeout_ms if d.timeout_ms is not None else (asked.pop() if asked else None)
    timeout = int(round(timeout_ms * 1e6)) if timeout_ms is not None else timeout_periods * period
    receiver = (
        ReceiverConfig.for_scheme(scheme, timeout, max_delta=max_delta, sync_frames=sync_frames)
        if timeout
        else None
    )
    return MessageSpec(
        name=name,
        frame_id=int(msg.frame_id),
        length=int(msg.length),
        period_ns=period,
        timeout_ns=timeout,
        scheme=scheme,
        receiver=receiver,
        inputs=feeds,
        channel=d.channel if d.channel is not None else pf.channel,
    )


def _outputs(c: _Check, pf: ProfileFile, db, params: tuple[int, int, int]):
    """lde's output messages: their layouts (the output DBC, else the profile's DBC when it defines
    them, else the shipped lde.dbc), their ids (``[outputs]``), checked against the DBC's ids."""
    names = {m.name for m in db.messages}
    if pf.output_dbc is not None:
        src_path = pf.output_dbc
        src = _parse_dbc(src_path, _read_dbc(src_path))
    elif set(OUTPUT_MESSAGES) <= names:
        src_path, src = pf.dbc, db
    else:
        src_path = dbc_dir() / "lde.dbc"
        src = _parse_dbc(src_path, _read_dbc(src_path))
    timeout_periods, max_delta, sync_frames = params
    outputs: dict[str, MessageSpec] = {}
    signals: dict[str, tuple[SignalDef, ...]] = {}
    for oname in OUTPUT_MESSAGES:
        if oname not in {m.name for m in src.messages}:
            raise c.error("outputs", f"{src_path.name} has no output message {oname!r}")
        msg = src.get_message_by_name(oname)
        cf = _fields(c, msg, ("Counter",), "outputs", "signal")
        kf = _fields(c, msg, ("CRC",), "outputs", "signal")
        if cf != P01_SCHEME.counter_fields or kf != P01_SCHEME.checksum_fields or msg.length != 8:
            raise c.error("outputs", f"{oname} of {src_path.name} is not an 8-byte E2E Profile 1 message")
        period = _period_ns(msg, src) or 3_900_000
        fid = pf.output_ids.get(oname, int(msg.frame_id))
        timeout = timeout_periods * period
        outputs[oname] = MessageSpec(
            name=oname,
            frame_id=fid,
            length=8,
            period_ns=period,
            timeout_ns=timeout,
            scheme=P01_SCHEME,
            receiver=ReceiverConfig.for_scheme(
                P01_SCHEME, timeout, max_delta=max_delta, sync_frames=sync_frames
            ),
        )
        signals[oname] = tuple(SignalDef.from_cantools(s) for s in msg.signals)
    taken = {
        int(m.frame_id): m.name
        for m in db.messages
        if m.name not in OUTPUT_MESSAGES and not m.is_extended_frame
    }
    seen: dict[int, str] = {}
    for oname, spec in outputs.items():
        fid = spec.frame_id
        if fid in taken:
            raise c.error(
                "outputs",
                f"{oname} id 0x{fid:X} collides with message {taken[fid]!r} (0x{fid:X}) of {pf.dbc.name}",
            )
        if fid in seen:
            raise c.error("outputs", f"{oname} and {seen[fid]} share the id 0x{fid:X}")
        seen[fid] = oname
    return outputs, signals


def _build(
    pf: ProfileFile, db: cantools.database.can.Database, params: tuple[int, int, int]
) -> dict[str, Any]:
    """A profile's parts (plain data: cached) from its file and its parsed DBC; ConfigError where
    they do not fit."""
    c = _Check(pf)
    inputs = {n: _input_map(c, db, d, pf.dbc) for n, d in pf.inputs.items() if not d.absent}
    absent = frozenset(n for n, d in pf.inputs.items() if d.absent)
    for m in dict.fromkeys(im.message for im in inputs.values()):
        if m not in pf.messages:
            raise c.error(
                f"messages.{m}",
                f"missing: every input message names its integrity check (one of: {', '.join(INTEGRITY)})",
            )
    messages: dict[str, MessageSpec] = {}
    for mname in dict.fromkeys(im.message for im in inputs.values()):
        feeds = tuple(n for n, im in inputs.items() if im.message == mname)
        groups = {GROUPS_OF[f] for f in feeds}
        if len(groups) != 1:
            raise c.error(
                f"messages.{mname}",
                f"{mname} feeds inputs of both groups ({', '.join(feeds)}): the MDPS inputs and the ESC "
                "inputs come from different messages",
            )
        messages[mname] = _spec(c, pf, db, mname, feeds, params)
    anchor = pf.anchor or inputs["column_torque"].message
    if messages[anchor].group != "mdps":
        raise c.error(
            "", f"anchor {anchor!r} is not an MDPS message (the grid steps on the steering messages)"
        )
    outputs, out_signals = _outputs(c, pf, db, params)
    in_ids: dict[int, str] = {}
    for spec in messages.values():
        fid = spec.frame_id
        if fid in in_ids:
            raise c.error(f"messages.{spec.name}", f"{spec.name} and {in_ids[fid]} share the id 0x{fid:X}")
        in_ids[fid] = spec.name
    for oname, o in outputs.items():
        if o.frame_id in in_ids:
            raise c.error("outputs", f"{oname} id 0x{o.frame_id:X} is the input message {in_ids[o.frame_id]}")
    signals = {
        name: tuple(SignalDef.from_cantools(sg) for sg in db.get_message_by_name(name).signals)
        for name in messages
    }
    signals.update(out_signals)
    return {
        "inputs": inputs,
        "messages": messages,
        "outputs": outputs,
        "signals": signals,
        "anchor": anchor,
        "absent": absent,
    }


GROUPS_OF: Mapping[str, str] = MappingProxyType({i: g for g, ins in GROUPS.items() for i in ins})


# ------------------------------------------------------------------------------ observed rates


def observe_timeouts(profile: Profile, frames: FrameBatch, *, source: str = "the log") -> Profile:
    """``profile`` with the timeouts its DBC does not give taken from ``frames`` (a log's first
    frames): the profile's timeout periods (default 3) times the median period of each such message's
    received 11-bit frames. The profile itself when every message has a timeout.

    Raises:
        ConfigError: such a message has fewer than 3 frames in ``frames`` (set its ``timeout_ms``).
    """
    if profile.timeouts_known:
        return profile
    timeout_periods, max_delta, sync_frames = profile.params
    rx = frames.is_rx & ~frames.is_extended
    new = dict(profile.messages)
    for name, spec in profile.messages.items():
        if spec.receiver is not None:
            continue
        t = frames.t_ns[rx & (frames.can_id == spec.frame_id)]
        if t.size < _OBSERVE_MIN_FRAMES:
            raise ConfigError(
                f"{profile.path or profile.name}: [messages.{name}] its DBC gives no cycle time and {source} "
                f"starts with {t.size} frames of it (0x{spec.frame_id:X}): set timeout_ms"
            )
        period = int(np.median(np.diff(np.sort(t))))
        if period <= 0:
            where = profile.path or profile.name
            raise ConfigError(f"{where}: [messages.{name}] no period observed in {source}: set timeout_ms")
        timeout = timeout_periods * period
        new[name] = replace(
            spec,
            period_ns=period,
            timeout_ns=timeout,
            receiver=ReceiverConfig.for_scheme(
                spec.scheme, timeout, max_delta=max_delta, sync_frames=sync_frames
            ),
        )
    return replace(profile, messages=MappingProxyType(new))
