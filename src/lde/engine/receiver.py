"""Frames -> estimator inputs in SI: THE receiver kernel, and its live and batch faces.

One compiled receiver, used by every path (the engine's loop, the live :class:`Receiver`,
:func:`decode_batch`, :func:`lde.engine.grid.build_grid`). Per frame, in time order (:func:`rx_feed`):

1. select by id: only 11-bit frames whose id is one of the profile's input messages (unknown ids and
   29-bit frames are ignored, also a 29-bit frame whose number equals a known 11-bit id); the frame's
   bytes are a uint8 row (8 bytes for classic CAN, up to 64 for CAN FD);
2. a frame whose length (dlc) differs from the message's DBC length is *malformed*: counted, never
   raised, and not passed to the E2E receiver;
3. the E2E receiver (:func:`lde.can.e2e.receive_frame`, one state per message) gives the frame a status,
   an ``accepted`` flag (its values are used) and the message's ``trusted`` flag after the frame;
4. an accepted frame is decoded: ``SI = factor * (combined DBC values of the input's signals +
   offset)``, combined = their mean or sum (:class:`lde.can.profiles.InputMap`), and becomes the
   latest sample of its message's inputs.

Sampling at a time ``t`` after every frame with time ``<= t`` was fed (:func:`rx_sample`)::

    value[i](t)  = value of the latest accepted frame of its message (NaN before the first)
    age[i](t)    = t - time of that frame (-1 before the first)
    valid[i](t)  = such a frame exists and age <= timeout of its message
    trusted_m(t) = 'trusted' after the latest frame of message m passed to the E2E receiver
    mdps_ok(t)   = all MDPS-group inputs valid and all their messages trusted; esc_ok likewise

An input the profile declares absent has no message: its value is NaN, its age -1, it is never
valid, and it does not count in its group's ``ok`` (the group is usable without it).

Stale values are held (``valid`` says they are stale); the estimator decides what to do with them.
Which frames precede which step is the grid's rule (:mod:`lde.engine.grid`): frames with time ``<= t_k``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from lde.can.bitfield import get_parts
from lde.can.channels import ChannelSelect
from lde.can.codec import SignalCodec, raw_value
from lde.can.e2e import (
    C_SIZE,
    S_ACCEPTED,
    S_SIZE,
    S_TRUSTED,
    E2EStatus,
    ReceiverStats,
    integrity_ok,
    new_state,
    receive_frame,
)
from lde.can.frames import MAX_DATA, FrameBatch, data_width
from lde.can.profiles import INPUT_NAMES, MDPS_INPUTS, Profile, observe_timeouts
from lde.errors import ConfigError

__all__ = [
    "RxTables",
    "RxState",
    "rx_feed",
    "rx_sample",
    "FEED_IGNORED",
    "FEED_MALFORMED",
    "N_INPUTS",
    "SignalSeries",
    "MessageDecode",
    "Decoded",
    "decode_batch",
    "FrameStatus",
    "InputSample",
    "Receiver",
]

#: the estimator inputs, in :data:`lde.can.profiles.INPUT_NAMES` order (the kernels' slots)
N_INPUTS = len(INPUT_NAMES)
I_COLUMN_TORQUE, I_ASSIST_TORQUE, I_STEERING_ANGLE, I_STEERING_RATE, I_YAW_RATE, I_LAT_ACCEL, I_SPEED = range(
    7
)
assert INPUT_NAMES[I_SPEED] == "speed" and INPUT_NAMES[I_LAT_ACCEL] == "lat_accel"

#: :func:`rx_feed` codes besides the E2E statuses
FEED_IGNORED = -1  #: unknown id or a 29-bit frame
FEED_MALFORMED = -2  #: a known id with the wrong length
#: input groups as ints
G_MDPS, G_ESC = 0, 1
_NO_ID = -1


# ------------------------------------------------------------------------------ compiled tables


@dataclass(frozen=True, eq=False)
class RxTables:
    """A profile's input messages and signals as the arrays the receiver kernel reads.

    Message rows (``m``): ``frame_id``, ``length``, ``kind`` (``lde.can.e2e.K_*``), ``ctr_parts`` and
    ``chk_parts`` (m, 2, 2), ``cfg`` (m, C_SIZE) receiver configuration, ``timeout_ns``, ``group``
    (``G_MDPS`` | ``G_ESC``). ``id2msg`` maps an 11-bit id to its row (-1: not an input).
    Input rows (:data:`N_INPUTS`, :data:`INPUT_NAMES` order): ``in_msg`` (-1: absent), ``in_sig0`` /
    ``in_nsig`` (their signals' rows), ``in_factor``, ``in_group``, ``in_div`` (the number of signals
    for a mean, 1 for a sum). Signal rows: ``sig_*`` (``sig_pos``: the packer position,
    :mod:`lde.can.bitfield`; an input's offset is folded into its signals' offsets).
    """

    names: tuple[str, ...]
    anchor: int
    id2msg: np.ndarray
    frame_id: np.ndarray
    length: np.ndarray
    kind: np.ndarray
    ctr_parts: np.ndarray
    chk_parts: np.ndarray
    cfg: np.ndarray
    timeout_ns: np.ndarray
    group: np.ndarray
    in_msg: np.ndarray
    in_sig0: np.ndarray
    in_nsig: np.ndarray
    in_factor: np.ndarray
    in_group: np.ndarray
    sig_pos: np.ndarray
    sig_nbits: np.ndarray
    sig_le: np.ndarray
    sig_signed: np.ndarray
    sig_scale: np.ndarray
    sig_offset: np.ndarray
    in_div: np.ndarray

    @classmethod
    def of(cls, profile: Profile) -> RxTables:
        if not profile.timeouts_known:
            late = [m.name for m in profile.messages.values() if m.receiver is None]
            raise ConfigError(
                f"{profile.path or profile.name}: no timeout for {', '.join(late)} (no cycle time in the "
                f"DBC): set timeout_ms in [messages.{late[0]}] (a replay takes it from the log's rate)"
            )
        specs = list(profile.messages.values())
        names = tuple(s.name for s in specs)
        row = {n: k for k, n in enumerate(names)}
        m = len(specs)
        id2msg = np.full(2048, _NO_ID, np.int64)
        for k, s in enumerate(specs):
            if 0 <= s.frame_id < 2048:
                id2msg[s.frame_id] = k
        cfg = np.zeros((m, C_SIZE), np.int64)
        ctr = np.zeros((m, 2, 3), np.int64)
        chk = np.zeros((m, 2, 3), np.int64)
        for k, s in enumerate(specs):
            ctr[k] = s.scheme.counter_parts
            chk[k] = s.scheme.checksum_parts
            assert s.receiver is not None
            cfg[k] = s.receiver.as_array()
        codecs: list[SignalCodec] = []
        in_msg, in_sig0, in_nsig, in_factor, in_group, in_div = [], [], [], [], [], []
        for name in INPUT_NAMES:
            in_group.append(G_MDPS if name in MDPS_INPUTS else G_ESC)
            im = profile.inputs.get(name)
            if im is None:  # absent: no message, never valid
                in_msg.append(-1)
                in_sig0.append(len(codecs))
                in_nsig.append(0)
                in_factor.append(0.0)
                in_div.append(1.0)
                continue
            sigs = {sg.name: sg for sg in profile.signals[im.message]}
            in_msg.append(row[im.message])
            in_sig0.append(len(codecs))
            in_nsig.append(len(im.signals))
            in_factor.append(float(im.factor))
            n = len(im.signals)
            in_div.append(float(n) if im.combine == "mean" else 1.0)
            # the input's offset on its signals: mean(v) + o = mean(v + o); sum(v) + o on the first
            for j, sn in enumerate(im.signals):
                sc = SignalCodec.of(sigs[sn])
                if im.offset and (im.combine == "mean" or j == 0):
                    sc = replace(sc, offset=sc.offset + im.offset)
                codecs.append(sc)
        group = np.zeros(m, np.int64)
        for k, s in enumerate(specs):
            group[k] = G_MDPS if s.group == "mdps" else G_ESC
        return cls(
            names=names,
            anchor=row[profile.anchor_message],
            id2msg=id2msg,
            frame_id=np.array([s.frame_id for s in specs], np.int64),
            length=np.array([s.length for s in specs], np.int64),
            kind=np.array([s.scheme.kind_code for s in specs], np.int64),
            ctr_parts=ctr,
            chk_parts=chk,
            cfg=cfg,
            timeout_ns=np.array([s.timeout_ns for s in specs], np.int64),
            group=group,
            in_msg=np.array(in_msg, np.int64),
            in_sig0=np.array(in_sig0, np.int64),
            in_nsig=np.array(in_nsig, np.int64),
            in_factor=np.array(in_factor, np.float64),
            in_group=np.array(in_group, np.int64),
            sig_pos=np.array([c.pos for c in codecs], np.int64),
            sig_nbits=np.array([c.length for c in codecs], np.int64),
            sig_le=np.array([c.little_endian for c in codecs], np.bool_),
            sig_signed=np.array([c.signed for c in codecs], np.bool_),
            sig_scale=np.array([c.scale for c in codecs], np.float64),
            sig_offset=np.array([c.offset for c in codecs], np.float64),
            in_div=np.array(in_div, np.float64),
        )

    def kernel_args(self) -> tuple:
        """The tables in the kernels' argument order (a tuple: one compiled argument)."""
        return (
            self.id2msg,
            self.length,
            self.kind,
            self.frame_id,
            self.chk_parts,
            self.ctr_parts,
            self.cfg,
            self.timeout_ns,
            self.group,
            self.in_msg,
            self.in_sig0,
            self.in_nsig,
            self.in_factor,
            self.in_group,
            self.sig_pos,
            self.sig_nbits,
            self.sig_le,
            self.sig_signed,
            self.sig_scale,
            self.sig_offset,
            self.in_div,
        )


@dataclass(eq=False)
class RxState:
    """The receiver's state (mutated in place by the kernels).

    ``e2e`` (m, S_SIZE) E2E state per message; ``malformed`` (m,) counts; ``acc_t`` (m,) time of the
    latest accepted frame and ``acc_have`` (m,) whether there is one; ``value`` (N_INPUTS,) the
    latest accepted SI value per input; ``ignored`` (1,) count of ignored frames.
    """

    e2e: np.ndarray
    malformed: np.ndarray
    acc_t: np.ndarray
    acc_have: np.ndarray
    value: np.ndarray
    ignored: np.ndarray

    @classmethod
    def initial(cls, tables: RxTables) -> RxState:
        m = tables.frame_id.shape[0]
        e2e = np.zeros((m, S_SIZE), np.int64)
        for k in range(m):
            e2e[k] = new_state()
        return cls(
            e2e=e2e,
            malformed=np.zeros(m, np.int64),
            acc_t=np.zeros(m, np.int64),
            acc_have=np.zeros(m, np.bool_),
            value=np.full(N_INPUTS, np.nan),
            ignored=np.zeros(1, np.int64),
        )

    def kernel_args(self) -> tuple:
        return (self.e2e, self.malformed, self.acc_t, self.acc_have, self.value, self.ignored)

    def stats(self, tables: RxTables) -> dict[str, ReceiverStats]:
        """Per-message counts (:class:`lde.can.e2e.ReceiverStats`)."""
        return {
            n: ReceiverStats.from_state(self.e2e[k], malformed=int(self.malformed[k]))
            for k, n in enumerate(tables.names)
        }


# ------------------------------------------------------------------------------ the kernel


@njit(cache=True, inline="always")
def rx_msg_of(tb, can_id, is_extended):  # pragma: no cover - compiled
    """Row of the input message with this id (-1: ignored: unknown id or a 29-bit frame)."""
    if is_extended or can_id < 0 or can_id >= 2048:
        return -1
    return tb[0][can_id]


@njit(cache=True, inline="always")
def rx_count_ignored(st):  # pragma: no cover - compiled
    """Count one frame the profile ignores (what :func:`rx_feed` does for an id without a row; a
    caller that has looked the id up already counts it without the call)."""
    st[5][0] += 1


@njit(cache=True, inline="always")
def rx_feed(tb, st, t_ns, can_id, is_extended, dlc, data):  # pragma: no cover - compiled
    """Feed one frame (time ``t_ns``, id, length ``dlc`` in bytes, ``data`` its bytes: a uint8 row
    of at least ``dlc`` bytes). Returns (message row or -1, code): :data:`FEED_IGNORED`,
    :data:`FEED_MALFORMED` or the frame's E2E status; ``st[0][m, S_ACCEPTED]`` says if its values
    are now the message's latest sample."""
    (
        id2msg,
        length,
        kind,
        frame_id,
        chk_parts,
        ctr_parts,
        cfg,
        _timeout,
        _group,
        in_msg,
        in_sig0,
        in_nsig,
        in_factor,
        _in_group,
        sig_pos,
        sig_nbits,
        sig_le,
        sig_signed,
        sig_scale,
        sig_offset,
        in_div,
    ) = tb
    e2e, malformed, acc_t, acc_have, value, _ignored = st
    m = rx_msg_of(tb, can_id, is_extended)
    if m < 0:
        rx_count_ignored(st)
        return -1, FEED_IGNORED
    n = length[m]
    if dlc != n or n > data.shape[0]:
        malformed[m] += 1
        return m, FEED_MALFORMED
    ok = integrity_ok(kind[m], frame_id[m], data, n, chk_parts[m])
    counter = np.int64(get_parts(data, ctr_parts[m]))
    status = receive_frame(e2e[m], cfg[m], np.int64(t_ns), counter, ok)
    if e2e[m, S_ACCEPTED] != 0:
        acc_t[m] = t_ns
        acc_have[m] = True
        for i in range(in_msg.shape[0]):
            if in_msg[i] != m:
                continue
            k0 = in_sig0[i]
            v = 0.0
            for k in range(k0, k0 + in_nsig[i]):
                raw = raw_value(data, sig_pos[k], sig_nbits[k], sig_le[k], sig_signed[k])
                v = v + (raw * sig_scale[k] + sig_offset[k])
            if in_div[i] != 1.0:  # a mean (x / 1.0 is x: a sum is left as it is)
                v = v / in_div[i]
            value[i] = v * in_factor[i]
    return m, status


@njit(cache=True, inline="always")
def rx_sample(tb, st, t_ns, values, ages):  # pragma: no cover - compiled
    """Sample the inputs at ``t_ns`` (module docstring): fills ``values`` (SI) and ``ages`` [ns] per
    input and returns (valid bit mask over the inputs, mdps_ok, esc_ok)."""
    timeout = tb[7]
    group = tb[8]
    in_msg = tb[9]
    in_group = tb[13]
    e2e, _malformed, acc_t, acc_have, value, _ignored = st
    valid_mask = 0
    ok_mdps = True
    ok_esc = True
    for i in range(in_msg.shape[0]):
        m = in_msg[i]
        if m < 0:  # absent: never valid, not part of its group's verdict
            values[i] = np.nan
            ages[i] = -1
            continue
        good = False
        if acc_have[m]:
            values[i] = value[i]
            a = t_ns - acc_t[m]
            ages[i] = a
            good = a <= timeout[m]
        else:
            values[i] = np.nan
            ages[i] = -1
        if good:
            valid_mask |= 1 << i
        elif in_group[i] == G_MDPS:
            ok_mdps = False
        else:
            ok_esc = False
    for m in range(group.shape[0]):
        if e2e[m, S_TRUSTED] == 0:
            if group[m] == G_MDPS:
                ok_mdps = False
            else:
                ok_esc = False
    return valid_mask, ok_mdps, ok_esc


# ------------------------------------------------------------------------------ batch decoding


@dataclass
class SignalSeries:
    """Accepted samples of one estimator input: times [ns] and SI values."""

    t_ns: np.ndarray  # int64 [m]
    value: np.ndarray  # float64 [m]

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass
class MessageDecode:
    """Receiver results of one input message over a batch (frames of the right length, in order)."""

    name: str
    frame_id: int
    timeout_ns: int
    t_ns: np.ndarray  # int64 [k], frames passed to the receiver
    status: np.ndarray  # uint8 [k], E2EStatus values
    accepted: np.ndarray  # bool [k], values used
    trusted: np.ndarray  # bool [k], message trusted after this frame
    stats: ReceiverStats
    malformed_t_ns: np.ndarray  # int64, times of frames with a wrong length

    def status_counts(self) -> dict[E2EStatus, int]:
        """Frames per E2E status."""
        vals, counts = np.unique(self.status, return_counts=True)
        return {E2EStatus(int(v)): int(c) for v, c in zip(vals, counts, strict=True)}


@dataclass
class Decoded:
    """Result of :func:`decode_batch` (``frames``: the time-sorted batch it decoded)."""

    profile: str
    inputs: dict[str, SignalSeries]
    messages: dict[str, MessageDecode]
    n_frames: int  # frames in the batch
    n_ignored: int  # unknown ids and 29-bit frames
    t_first_ns: int | None  # first / last frame time of the whole batch
    t_last_ns: int | None
    frames: FrameBatch | None = None
    #: the profile as decoded with (its timeouts observed in the frames where its DBC has none)
    used_profile: Profile | None = None
    #: input-message frames on another bus than their message's (:class:`lde.can.channels.ChannelSelect`)
    other_bus: int = 0

    @property
    def stats(self) -> dict[str, ReceiverStats]:
        return {k: m.stats for k, m in self.messages.items()}


@njit(cache=True)
def _feed_all(tb, st, t, can_id, is_ext, dlc, data, msg_out, code_out, acc_out, trusted_out, values_out):  # noqa: E501  # pragma: no cover
    """:func:`rx_feed` for every frame (in the given order), recording each frame's results and the
    SI values of the accepted ones."""
    e2e = st[0]
    value = st[4]
    for i in range(t.shape[0]):
        m, code = rx_feed(tb, st, t[i], np.int64(can_id[i]), is_ext[i], np.int64(dlc[i]), data[i])
        msg_out[i] = m
        code_out[i] = code
        if code >= 0:
            acc_out[i] = e2e[m, S_ACCEPTED] != 0
            trusted_out[i] = e2e[m, S_TRUSTED] != 0
            if acc_out[i]:
                for k in range(value.shape[0]):
                    values_out[i, k] = value[k]


def decode_batch(profile: Profile, frames: FrameBatch, tables: RxTables | None = None) -> Decoded:
    """Decode a batch of frames (any order; stably sorted by time first) with the receiver kernel:
    each input message's frames of its own bus (:class:`lde.can.channels.ChannelSelect`), the
    timeouts its DBC does not give observed in the frames (:func:`lde.can.profiles.observe_timeouts`)."""
    frames = frames.sort()
    select = ChannelSelect(profile)
    frames = select(frames)
    profile = observe_timeouts(profile, frames)
    tb = RxTables.of(profile) if tables is None else tables
    n = len(frames)
    st = RxState.initial(tb)
    msg = np.empty(n, np.int64)
    code = np.empty(n, np.int64)
    acc = np.zeros(n, np.bool_)
    trusted = np.zeros(n, np.bool_)
    values = np.full((n, N_INPUTS), np.nan)
    _feed_all(
        tb.kernel_args(),
        st.kernel_args(),
        frames.t_ns,
        frames.can_id,
        frames.is_extended,
        frames.dlc,
        frames.data,
        msg,
        code,
        acc,
        trusted,
        values,
    )
    stats = st.stats(tb)
    messages: dict[str, MessageDecode] = {}
    inputs: dict[str, SignalSeries] = {}
    for k, name in enumerate(tb.names):
        spec = profile.messages[name]
        mine = msg == k
        passed = mine & (code >= 0)
        bad = mine & (code == FEED_MALFORMED)
        messages[name] = MessageDecode(
            name=name,
            frame_id=spec.frame_id,
            timeout_ns=spec.timeout_ns,
            t_ns=frames.t_ns[passed],
            status=code[passed].astype(np.uint8),
            accepted=acc[passed],
            trusted=trusted[passed],
            stats=stats[name],
            malformed_t_ns=frames.t_ns[bad],
        )
    for i, name in enumerate(INPUT_NAMES):
        sel = acc & (msg == tb.in_msg[i])
        inputs[name] = SignalSeries(frames.t_ns[sel], values[sel, i])
    return Decoded(
        profile=profile.name,
        inputs=inputs,
        messages=messages,
        n_frames=n,
        n_ignored=int(st.ignored[0]),
        t_first_ns=int(frames.t_ns[0]) if n else None,
        t_last_ns=int(frames.t_ns[-1]) if n else None,
        frames=frames,
        used_profile=profile,
        other_bus=select.dropped,
    )


# ------------------------------------------------------------------------------ live receiver


@dataclass(frozen=True)
class FrameStatus:
    """What the live receiver did with one frame.

    ``message`` is None for an ignored frame (unknown id / 29-bit); ``malformed`` for a wrong length;
    otherwise ``status`` is the E2E status and ``accepted`` says whether its values are used.
    """

    message: str | None
    status: E2EStatus | None = None
    accepted: bool = False
    malformed: bool = False

    @property
    def ignored(self) -> bool:
        return self.message is None


_IGNORED = FrameStatus(None)


@dataclass(frozen=True)
class InputSample:
    """The estimator inputs at one step time (SI, ISO 8855 signs; NaN before the first sample).

    ``valid[name]``: a value exists and is not older than its message's timeout. ``mdps_ok`` /
    ``esc_ok``: every input of the group valid and its messages trusted by the E2E receiver.
    ``age_ns[name]``: ``t_ns`` minus the time of the sample used (-1 if none).
    """

    t_ns: int
    column_torque: float  # Nm
    assist_torque: float  # Nm, total motor torque referred to the column
    steering_angle: float  # rad, steering wheel
    steering_rate: float  # rad/s, steering wheel
    yaw_rate: float  # rad/s
    lat_accel: float  # m/s^2
    speed: float  # m/s
    valid: Mapping[str, bool] = field(default_factory=dict)
    age_ns: Mapping[str, int] = field(default_factory=dict)
    mdps_ok: bool = False
    esc_ok: bool = False

    def value(self, name: str) -> float:
        return float(getattr(self, name))


class Receiver:
    """The receiver kernel one frame at a time: ``feed`` frames in time order, ``sample`` the inputs
    at a step time after feeding every frame up to it (module docstring)."""

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self.tables = RxTables.of(profile)
        self._tb = self.tables.kernel_args()
        self.reset()

    @classmethod
    def bound(cls, profile: Profile, tables: RxTables, state: RxState) -> Receiver:
        """A receiver over an existing state (the live engine's; shared, not copied)."""
        r = cls.__new__(cls)
        r.profile, r.tables, r._tb = profile, tables, tables.kernel_args()
        r.state, r._st = state, state.kernel_args()
        return r

    def reset(self) -> None:
        self.state = RxState.initial(self.tables)
        self._st = self.state.kernel_args()

    @property
    def n_ignored(self) -> int:
        return int(self.state.ignored[0])

    def feed(
        self,
        t_ns: int,
        can_id: int,
        data: bytes | bytearray,
        dlc: int | None = None,
        is_extended: bool = False,
    ) -> FrameStatus:
        """Process one received frame (time ``t_ns`` [ns]); never raises for a bad frame."""
        raw = bytes(data)[:MAX_DATA]
        length = len(raw) if dlc is None else int(dlc)
        if len(raw) < length:  # fewer data bytes than the dlc says: cannot be decoded
            length = -1
        row = np.frombuffer(raw.ljust(data_width(len(raw)), b"\x00"), np.uint8)
        m, code = rx_feed(
            self._tb, self._st, np.int64(t_ns), np.int64(can_id), bool(is_extended), np.int64(length), row
        )
        if m < 0:
            return _IGNORED
        name = self.tables.names[m]
        if code == FEED_MALFORMED:
            return FrameStatus(name, malformed=True)
        return FrameStatus(name, E2EStatus(int(code)), bool(self.state.e2e[m, S_ACCEPTED]))

    def sample(self, t_ns: int) -> InputSample:
        """Inputs at time ``t_ns`` (sample-and-hold, staleness, trust; module docstring)."""
        values = np.empty(N_INPUTS)
        ages = np.empty(N_INPUTS, np.int64)
        mask, mdps_ok, esc_ok = rx_sample(self._tb, self._st, np.int64(t_ns), values, ages)
        return InputSample(
            t_ns=int(t_ns),
            **{n: float(v) for n, v in zip(INPUT_NAMES, values, strict=True)},
            valid={n: bool(mask >> i & 1) for i, n in enumerate(INPUT_NAMES)},
            age_ns={n: int(a) for n, a in zip(INPUT_NAMES, ages, strict=True)},
            mdps_ok=bool(mdps_ok),
            esc_ok=bool(esc_ok),
        )

    # ---------------------------------------------------------------- counters
    @property
    def stats(self) -> dict[str, ReceiverStats]:
        """Per-message counts (same meaning as :attr:`Decoded.stats`)."""
        return self.state.stats(self.tables)

    @property
    def e2e_rejects(self) -> int:
        """Frames rejected since start: E2E (repeated, wrong sequence, wrong CRC) plus malformed."""
        return sum(s.rejected + s.malformed for s in self.stats.values())

    def trusted(self, message: str) -> bool:
        """Current trust of an input message."""
        return bool(self.state.e2e[self.tables.names.index(message), S_TRUSTED])

    def timed_out(self, t_ns: int) -> dict[str, bool]:
        """Per input message: no accepted frame within its timeout before ``t_ns`` (E2E NONEWDATA)."""
        st, tb = self.state, self.tables
        return {
            n: (not st.acc_have[k]) or int(t_ns) - int(st.acc_t[k]) > int(tb.timeout_ns[k])
            for k, n in enumerate(tb.names)
        }
