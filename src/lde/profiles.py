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

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import cantools
import numpy as np

from .e2e import P01_SCHEME, IntegrityKind, IntegrityScheme, ReceiverConfig
from .errors import ConfigError
from .units import DEG, KMH

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


@dataclass(frozen=True, eq=False)
class Profile:
    """A CAN profile: DBC database, input signal map, input and output message specs."""

    name: str
    dbc_path: Path
    db: cantools.database.can.Database
    inputs: Mapping[str, InputMap]
    messages: Mapping[str, MessageSpec]  # input messages by name
    outputs: Mapping[str, MessageSpec]  # lde's output messages by name
    anchor_message: str  # its first accepted frame anchors the step grid (the MDPS torque message)
    angle_above_torsion_bar: bool = False  # the steering angle sensor reads the torsion bar's twist

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
    here = Path(__file__).resolve()
    for d in (here.parents[2] / "dbc", here.parent / "data"):
        if (d / "lde.dbc").is_file():
            return d
    raise ConfigError(
        f"cannot find the DBC directory (looked in {here.parents[2] / 'dbc'} and {here.parent / 'data'})"
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
    try:
        db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    except Exception as e:  # cantools raises several parser error types
        raise ConfigError(f"cannot read DBC {path}: {e}") from e
    if not isinstance(db, cantools.database.can.Database):
        raise ConfigError(f"{path} is not a CAN database")
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
    where = f"profile {pname!r} ({path})"

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

    return Profile(
        name=pname,
        dbc_path=path,
        db=db,
        inputs=MappingProxyType(inputs),
        messages=MappingProxyType(messages),
        outputs=MappingProxyType(outputs),
        anchor_message=pdef.anchor,
        angle_above_torsion_bar=pdef.angle_above_torsion_bar,
    )
