"""Frame integrity: the registry of checks a profile chooses from, and the E2E receiver.

The registry (:data:`INTEGRITY`, chosen per message by a profile file's ``integrity`` key):

==================== ======== ======== =================================================================
name                 counter  checksum what is verified
==================== ======== ======== =================================================================
``none``             --       --       nothing: every frame is used
``counter``          required optional the alive counter's sequence; a checksum signal, if named, is not
                                       verified (its algorithm is not published)
``autosar_e2e_p01``  required required AUTOSAR E2E Profile 1 (SPEC section 3): CRC byte 0, counter low
                                       nibble of byte 1, 0..14
``toyota_checksum``  optional required Toyota's checksum in the last byte
``hyundai_whl_spd11`` required required the hyundai WHL_SPD11 checksum (SPEC section 3), its split
                                       counter
==================== ======== ======== =================================================================

The checks, on a frame's bytes ``d[0 .. len-1]``::

    Profile 1: Data ID mode BOTH, Data ID = the CAN id
        CRC     = CRC-8-SAE-J1850 (poly 0x1D, start 0x00, no final xor)
                  over [data_id & 0xFF, data_id >> 8, d[1], ..., d[len-1]]       (byte 0 = CRC)
    Toyota:     checksum = (sum of the id's bytes + len + d[0] + ... + d[len-2]) mod 256
    WHL_SPD11:  checksum = (popcount(d[0..7], the top two bits of bytes 1, 3, 5, 7 masked) ^ 9) & 15

Adding a check: its compiled checksum function, its line in :data:`INTEGRITY` and its branch in
:func:`integrity_ok` and :func:`protect_row` (the kernels dispatch on the registry's code).

Three Profile 1 CRC implementations exist on purpose: the scalar path uses the PyPI package
``autosar-e2e`` (``e2e.p01``, what the SPEC asks for), the kernels a 256-entry table
(:func:`p01_crc_row`), and the tests carry a third, bitwise one. They are checked against each other.

The receiver (one per message) follows the Profile 1 check state machine, event-driven (called per
received frame, not per cycle); every scheme uses it (a message without a counter takes every good
frame as the next in sequence). Its per-frame logic exists ONCE, :func:`receive_frame`, a numba
function on a small int64 state vector; the live :class:`P01Receiver` and the replay batch loop
:func:`receive_batch` both call it, so live and replay give the same statuses by construction.

Per frame (``check_ok`` = CRC / checksum verified or not verified by the scheme)::

    gap since the last frame with a good check > timeout  -> re-init (counted as one NONEWDATA)
    check failed                                           -> WRONGCRC      (rejected; trust lost)
    counter == invalid value (15 in Profile 1)             -> WRONGSEQUENCE (rejected; trust lost)
    first frame after (re-)init                            -> INITIAL       (sequence unknown: not used)
    delta = (counter - last_counter) mod modulus
      delta == 0                                           -> REPEATED      (rejected, trust kept)
      1 <= delta <= max_delta                              -> OK (delta 1) / OKSOMELOST (delta-1 lost)
      delta > max_delta                                    -> WRONGSEQUENCE (rejected; trust lost,
                                                              the new counter is the new reference)

A message is *trusted* after ``sync_frames`` consecutive good (OK/OKSOMELOST) frames following an
INITIAL frame or a fault (WRONGCRC/WRONGSEQUENCE); the frame that completes the count is the first
whose values are *used* (``accepted``). With the default ``sync_frames=2`` values flow from the second
in-sequence frame after a (re-)start. NONEWDATA is a *time* status: :meth:`P01Receiver.status_at`
reports it when the timeout has passed without a good frame; the counter ``nonewdata`` counts each
timeout once, when the next frame shows the gap (so live and replay count identically).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from types import MappingProxyType

import e2e.p01 as _p01
import numba as nb
import numpy as np
from numba import njit

from lde.can.bitfield import get_parts, parts_array, put_parts

__all__ = [
    "E2EStatus",
    "Integrity",
    "INTEGRITY",
    "IntegrityScheme",
    "ReceiverConfig",
    "ReceiverStats",
    "P01Receiver",
    "P01Sender",
    "P01_SCHEME",
    "P01_COUNTER_MAX",
    "crc8_j1850_table",
    "P01_CRC_TABLE",
    "p01_crc",
    "p01_crc_batch",
    "p01_check",
    "toyota_checksum",
    "whl_spd11_checksum",
    "whl_spd11_checksum_batch",
    "read_counter",
    "read_counter_batch",
    "check_batch",
    "check_frame",
    "protect_frame",
    "receive_frame",
    "receive_batch",
    "new_state",
]


class E2EStatus(IntEnum):
    """Profile 1 check statuses (values as AUTOSAR's ``E2E_P01STATUS_*``)."""

    OK = 0x00
    NONEWDATA = 0x01
    WRONGCRC = 0x02
    INITIAL = 0x04
    REPEATED = 0x08
    OKSOMELOST = 0x20
    WRONGSEQUENCE = 0x40


#: Profile 1 counter range 0..14; 15 is invalid.
P01_COUNTER_MAX = 14

# ----------------------------------------------------------------------------------------- CRC


def crc8_j1850_table(poly: int = 0x1D) -> np.ndarray:
    """256-entry table of the MSB-first CRC-8 with polynomial ``poly``: ``table[b] = crc(b)``."""
    table = np.zeros(256, dtype=np.uint8)
    for b in range(256):
        c = b
        for _ in range(8):
            c = ((c << 1) ^ poly) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        table[b] = c
    return table


P01_CRC_TABLE = crc8_j1850_table(0x1D)


def p01_crc(data_id: int, data: bytes | bytearray) -> int:
    """Profile 1 CRC of a frame (``data[0]`` is the CRC slot and is ignored) via ``autosar-e2e``
    (the reference the compiled :func:`p01_crc_row` is tested against)."""
    buf = bytearray(data)
    _p01.e2e_p01_protect(buf, int(data_id) & 0xFFFF, increment_counter=False)
    return buf[0]


def p01_check(data_id: int, data: bytes | bytearray) -> bool:
    """True if ``data[0]`` is the Profile 1 CRC of the frame (``autosar-e2e``). Needs >= 2 bytes."""
    if len(data) < 2:
        return False
    return bool(_p01.e2e_p01_check(bytearray(data), int(data_id) & 0xFFFF))


# ------------------------------------------------------------------------ the integrity registry

# the kernels' codes (:attr:`Integrity.code`)
K_NONE, K_COUNTER, K_P01, K_TOYOTA, K_WHL_SPD = range(5)

#: a counter or checksum signal: "required", "optional" or "none" (the check takes none)
REQUIRED, OPTIONAL, NONE = "required", "optional", "none"


@dataclass(frozen=True)
class Integrity:
    """One integrity check of the registry (module doc).

    Attributes:
        name: its name in a profile file (``integrity = "..."``).
        code: the kernels' code (``K_*``).
        counter, checksum: whether the profile names a counter / checksum signal for it
            (:data:`REQUIRED`, :data:`OPTIONAL` or :data:`NONE`).
        verifies_checksum: the checksum is computed and compared (else a named checksum is only
            carried).
        summary: one line for the docs and error messages.
    """

    name: str
    code: int
    counter: str
    checksum: str
    verifies_checksum: bool
    summary: str


INTEGRITY: Mapping[str, Integrity] = MappingProxyType(
    {
        i.name: i
        for i in (
            Integrity("none", K_NONE, NONE, NONE, False, "nothing checked"),
            Integrity(
                "counter", K_COUNTER, REQUIRED, OPTIONAL, False, "alive counter; checksum not verified"
            ),
            Integrity("autosar_e2e_p01", K_P01, REQUIRED, REQUIRED, True, "AUTOSAR E2E Profile 1"),
            Integrity("toyota_checksum", K_TOYOTA, OPTIONAL, REQUIRED, True, "Toyota checksum, last byte"),
            Integrity("hyundai_whl_spd11", K_WHL_SPD, REQUIRED, REQUIRED, True, "hyundai WHL_SPD11 checksum"),
        )
    }
)

#: (start, length, little_endian) of a DBC field, as in ``start|length@1`` (True) / ``@0`` (False)
Field = tuple[int, int, bool]


@dataclass(frozen=True)
class IntegrityScheme:
    """How a message is protected: the check (:data:`INTEGRITY`) and where its counter / checksum
    live (DBC fields, least significant part first; WHL_SPD11 splits both into 2-bit halves).

    ``modulus`` is the counter period (15 in Profile 1, 2**bits otherwise; 1 without a counter) and
    ``invalid_counter`` a value that is never valid (15 in Profile 1, -1 for none).
    """

    integrity: Integrity
    counter_fields: tuple[Field, ...] = ()
    checksum_fields: tuple[Field, ...] = ()
    modulus: int = 15
    invalid_counter: int = 15

    @property
    def name(self) -> str:
        return self.integrity.name

    @property
    def has_counter(self) -> bool:
        return bool(self.counter_fields)

    @property
    def verifies_checksum(self) -> bool:
        return self.integrity.verifies_checksum

    @property
    def kind_code(self) -> int:
        """The check as the kernels' int (``K_*``)."""
        return self.integrity.code

    @property
    def counter_parts(self) -> np.ndarray:
        return parts_array(self.counter_fields)

    @property
    def checksum_parts(self) -> np.ndarray:
        return parts_array(self.checksum_fields)

    def next_counter(self, counter: int) -> int:
        """The counter after ``counter``: +1 modulo ``modulus``, skipping ``invalid_counter``."""
        if not self.has_counter:
            return 0
        return int(advance_counter(counter, self.modulus, self.invalid_counter))

    @classmethod
    def of(
        cls, integrity: Integrity, counter_fields: tuple[Field, ...], checksum_fields: tuple[Field, ...]
    ) -> IntegrityScheme:
        """A scheme whose counter period is 2**bits of its counter (Profile 1: :data:`P01_SCHEME`)."""
        if integrity.code == K_P01:
            return P01_SCHEME
        bits = sum(n for _, n, _ in counter_fields)
        return cls(integrity, counter_fields, checksum_fields, modulus=max(1, 1 << bits), invalid_counter=-1)


#: The scheme of every lde message (and of lde's outputs on every profile): CRC 0|8, counter 8|4.
P01_SCHEME = IntegrityScheme(
    INTEGRITY["autosar_e2e_p01"], counter_fields=((8, 4, True),), checksum_fields=((0, 8, True),)
)

# ------------------------------------------------------------------ the compiled integrity kernels

# bytes 1, 3, 5 and 7 of WHL_SPD11 lose their top two bits (the alive counter and checksum halves)
_WHL_SPD_MASK = np.uint64(0x3FFF3FFF3FFF3FFF)


@njit(cache=True, inline="always")
def p01_crc_row(data_id, data, length):  # pragma: no cover - compiled
    """Profile 1 CRC of the frame ``data`` (``length`` bytes):
    crc = 0; for b in [id_lo, id_hi, byte 1, ..., byte length-1]: crc = T[crc ^ b]."""
    t = P01_CRC_TABLE
    crc = t[np.int64(data_id) & 0xFF]
    crc = t[crc ^ ((np.int64(data_id) >> 8) & 0xFF)]
    for k in range(1, length):
        crc = t[crc ^ data[k]]
    return crc


@njit(cache=True, inline="always")
def toyota_checksum_row(data_id, data, length):  # pragma: no cover - compiled
    """Toyota's checksum: (the id's bytes + length + bytes 0 .. length-2) mod 256."""
    s = np.int64(length)
    a = np.int64(data_id)
    while a > 0:
        s += a & 0xFF
        a >>= 8
    for k in range(length - 1):
        s += data[k]
    return s & 0xFF


@njit(cache=True, inline="always")
def whl_spd11_checksum_row(data):  # pragma: no cover - compiled
    """hyundai WHL_SPD11 checksum (SPEC 3): ``(popcount(bytes 0..7 masked) ^ 9) & 15``."""
    v = np.uint64(0)
    for k in range(8):
        v |= np.uint64(data[k]) << np.uint64(8 * k)
    v &= _WHL_SPD_MASK
    count = 0
    while v:
        v &= v - np.uint64(1)
        count += 1
    return (count ^ 9) & 15


@njit(cache=True, inline="always")
def integrity_ok(kind, data_id, data, length, chk_parts):  # pragma: no cover - compiled
    """The frame's CRC / checksum verdict (True where the check verifies nothing)."""
    if kind == K_P01:
        return length >= 2 and p01_crc_row(data_id, data, length) == data[0]
    if kind == K_TOYOTA:
        return length >= 1 and np.uint64(toyota_checksum_row(data_id, data, length)) == get_parts(
            data, chk_parts
        )
    if kind == K_WHL_SPD:
        return length >= 8 and np.uint64(whl_spd11_checksum_row(data)) == get_parts(data, chk_parts)
    return True


@njit(cache=True, inline="always")
def protect_row(kind, data_id, data, length, ctr_parts, chk_parts, counter):  # pragma: no cover - compiled
    """Write ``counter`` (where the scheme has one) and the CRC / checksum into the frame ``data``
    (``counter`` schemes: the counter only; their checksum field, algorithm unknown, is left as is)."""
    put_parts(data, ctr_parts, np.uint64(counter))
    if kind == K_P01:
        data[0] = p01_crc_row(data_id, data, length)
    elif kind == K_TOYOTA:
        put_parts(data, chk_parts, np.uint64(toyota_checksum_row(data_id, data, length)))
    elif kind == K_WHL_SPD:
        put_parts(data, chk_parts, np.uint64(whl_spd11_checksum_row(data)))


@njit(cache=True, inline="always")
def advance_counter(counter, modulus, invalid):  # pragma: no cover - compiled
    """+1 modulo ``modulus``, skipping ``invalid`` (the sender's counter rule, once)."""
    c = (counter + 1) % modulus
    if c == invalid:
        c = (c + 1) % modulus
    return c


def _rows(data: np.ndarray) -> np.ndarray:
    """uint8 [n, >= 8] frames, contiguous."""
    d = np.ascontiguousarray(np.asarray(data, dtype=np.uint8))
    if d.ndim != 2 or d.shape[1] < 8:
        d = np.pad(d.reshape(d.shape[0], -1), ((0, 0), (0, max(0, 8 - d.reshape(d.shape[0], -1).shape[1]))))
    return d


def _row(data: bytes | bytearray) -> np.ndarray:
    """One frame's bytes as a uint8 row of at least 8 bytes (zero padded)."""
    raw = bytes(data)
    return np.frombuffer(raw.ljust(max(8, len(raw)), b"\x00"), np.uint8).copy()


@njit(cache=True)
def _check_loop(kind, data_id, data, length, chk_parts, out):  # pragma: no cover - compiled
    for i in range(data.shape[0]):
        out[i] = integrity_ok(kind, data_id, data[i], length, chk_parts)


@njit(cache=True)
def _counter_loop(data, parts, out):  # pragma: no cover - compiled
    for i in range(data.shape[0]):
        out[i] = np.int64(get_parts(data[i], parts))


@njit(cache=True)
def _crc_loop(data_id, data, length, out):  # pragma: no cover - compiled
    for i in range(data.shape[0]):
        out[i] = p01_crc_row(data_id, data[i], length)


@njit(cache=True)
def _whl_loop(data, out):  # pragma: no cover - compiled
    for i in range(data.shape[0]):
        out[i] = whl_spd11_checksum_row(data[i])


def p01_crc_batch(data_id: int, data: np.ndarray, length: int = 8) -> np.ndarray:
    """Profile 1 CRC of every frame of ``data`` (uint8 [n, >=length]) -> uint8 [n] (compiled table
    CRC, :func:`p01_crc_row`)."""
    out = np.empty(np.shape(data)[0], dtype=np.uint8)
    _crc_loop(int(data_id), _rows(data), int(length), out)
    return out


def toyota_checksum(data_id: int, data: bytes | bytearray) -> int:
    """Toyota's checksum of one frame (its length is ``len(data)``; module doc)."""
    return int(toyota_checksum_row(int(data_id), _row(data), len(data)))


def whl_spd11_checksum(data: bytes | bytearray) -> int:
    """hyundai WHL_SPD11 checksum of one frame (SPEC 3).

    ``(number of 1-bits in all 8 bytes, the top 2 bits of bytes 1, 3, 5, 7 masked) ^ 9) & 15``
    """
    return int(whl_spd11_checksum_row(_row(data)))


def whl_spd11_checksum_batch(data: np.ndarray) -> np.ndarray:
    """:func:`whl_spd11_checksum` over uint8 [n, 8] -> uint8 [n]."""
    out = np.empty(np.shape(data)[0], dtype=np.uint8)
    _whl_loop(_rows(data), out)
    return out


def read_counter_batch(scheme: IntegrityScheme, data: np.ndarray) -> np.ndarray:
    """Counters of uint8 [n, >= 8] frames -> int64 [n]."""
    out = np.empty(np.shape(data)[0], dtype=np.int64)
    _counter_loop(_rows(data), scheme.counter_parts, out)
    return out


def read_counter(scheme: IntegrityScheme, data: bytes | bytearray) -> int:
    """Counter of one frame."""
    return int(get_parts(_row(data), scheme.counter_parts))


def check_batch(scheme: IntegrityScheme, data_id: int, data: np.ndarray, length: int = 8) -> np.ndarray:
    """Checksum / CRC verdict per frame -> bool [n] (all True where the scheme verifies nothing)."""
    d = _rows(data)
    out = np.empty(d.shape[0], dtype=np.bool_)
    _check_loop(scheme.kind_code, int(data_id), d, int(length), scheme.checksum_parts, out)
    return out


def check_frame(scheme: IntegrityScheme, data_id: int, data: bytes | bytearray) -> bool:
    """:func:`check_batch` of one frame (its length is ``len(data)``)."""
    return bool(integrity_ok(scheme.kind_code, int(data_id), _row(data), len(data), scheme.checksum_parts))


def protect_frame(scheme: IntegrityScheme, data_id: int, buf: bytearray, counter: int) -> None:
    """Write ``counter`` and the CRC / checksum into ``buf`` in place (the sender's side).

    ``counter`` schemes get the counter only; their checksum field (algorithm unknown) is left as is.
    """
    n = len(buf)
    row = _row(buf)
    protect_row(
        scheme.kind_code, int(data_id), row, n, scheme.counter_parts, scheme.checksum_parts, int(counter)
    )
    buf[:n] = row[:n].tobytes()


# ----------------------------------------------------------------------------------- receiver

# config vector slots
C_MODULUS, C_INVALID, C_MAX_DELTA, C_SYNC, C_TIMEOUT_NS, C_HAS_COUNTER = range(6)
C_SIZE = 6

# state vector slots
S_WAIT_FIRST = 0  # 1 until the first good frame after (re-)init
S_LAST_COUNTER = 1  # counter of the last frame accepted into the sequence
S_SYNC_LEFT = 2  # good frames still needed before the message is trusted
S_LAST_T = 3  # t_ns of the last frame whose check passed (for the timeout)
S_TRUSTED = 4  # 1 while trusted
S_ACCEPTED = 5  # 1 if the last frame's values are used
S_LOST_LAST = 6  # frames lost before the last frame (OKSOMELOST)
S_N_RECEIVED = 7
S_N_USED = 8
S_N_LOST = 9
S_N_REPEATED = 10
S_N_WRONGSEQ = 11
S_N_WRONGCRC = 12
S_N_NONEWDATA = 13
S_N_INITIAL = 14
S_N_OKSOMELOST = 15
S_N_RESYNC = 16  # frames that passed the check but were not used: INITIAL and the sync frames after it
S_SIZE = 17

_OK = np.int64(E2EStatus.OK)
_WRONGCRC = np.int64(E2EStatus.WRONGCRC)
_INITIAL = np.int64(E2EStatus.INITIAL)
_REPEATED = np.int64(E2EStatus.REPEATED)
_OKSOMELOST = np.int64(E2EStatus.OKSOMELOST)
_WRONGSEQ = np.int64(E2EStatus.WRONGSEQUENCE)


def new_state() -> np.ndarray:
    """A fresh receiver state vector (waiting for the first frame, untrusted)."""
    s = np.zeros(S_SIZE, dtype=np.int64)
    s[S_WAIT_FIRST] = 1
    return s


@nb.njit(cache=True, inline="always")
def receive_frame(
    state: np.ndarray, cfg: np.ndarray, t_ns: np.int64, counter: np.int64, check_ok: bool
) -> np.int64:
    """THE per-frame receiver step (module docstring); updates ``state`` in place, returns the status."""
    state[S_N_RECEIVED] += 1
    if cfg[C_HAS_COUNTER] == 0:  # no counter: every good frame is the next in sequence
        counter = (state[S_LAST_COUNTER] + 1) % cfg[C_MODULUS]
    state[S_ACCEPTED] = 0
    state[S_LOST_LAST] = 0
    # timeout without a good frame -> re-init (one NONEWDATA event)
    if state[S_WAIT_FIRST] == 0 and t_ns - state[S_LAST_T] > cfg[C_TIMEOUT_NS]:
        state[S_WAIT_FIRST] = 1
        state[S_TRUSTED] = 0
        state[S_N_NONEWDATA] += 1
    if not check_ok:
        state[S_N_WRONGCRC] += 1
        state[S_TRUSTED] = 0
        state[S_SYNC_LEFT] = cfg[C_SYNC]
        return _WRONGCRC
    if counter == cfg[C_INVALID] or counter < 0 or counter >= cfg[C_MODULUS]:
        state[S_N_WRONGSEQ] += 1
        state[S_TRUSTED] = 0
        state[S_SYNC_LEFT] = cfg[C_SYNC]
        return _WRONGSEQ
    state[S_LAST_T] = t_ns
    if state[S_WAIT_FIRST] != 0:
        state[S_WAIT_FIRST] = 0
        state[S_LAST_COUNTER] = counter
        state[S_SYNC_LEFT] = cfg[C_SYNC]
        state[S_TRUSTED] = 1 if cfg[C_SYNC] == 0 else 0
        state[S_N_INITIAL] += 1
        state[S_N_RESYNC] += 1
        return _INITIAL
    delta = (counter - state[S_LAST_COUNTER]) % cfg[C_MODULUS]
    if delta == 0:
        state[S_N_REPEATED] += 1
        return _REPEATED
    if delta > cfg[C_MAX_DELTA]:
        state[S_N_WRONGSEQ] += 1
        state[S_LAST_COUNTER] = counter
        state[S_TRUSTED] = 0
        state[S_SYNC_LEFT] = cfg[C_SYNC]
        return _WRONGSEQ
    state[S_LAST_COUNTER] = counter
    lost = delta - 1
    state[S_LOST_LAST] = lost
    state[S_N_LOST] += lost
    status = _OK
    if lost > 0:
        status = _OKSOMELOST
        state[S_N_OKSOMELOST] += 1
    if state[S_SYNC_LEFT] > 0:
        state[S_SYNC_LEFT] -= 1
    if state[S_SYNC_LEFT] == 0:
        state[S_TRUSTED] = 1
        state[S_ACCEPTED] = 1
        state[S_N_USED] += 1
    else:
        state[S_N_RESYNC] += 1
    return status


@nb.njit(cache=True)
def receive_batch(
    state: np.ndarray,
    cfg: np.ndarray,
    t_ns: np.ndarray,
    counter: np.ndarray,
    check_ok: np.ndarray,
    status_out: np.ndarray,
    accepted_out: np.ndarray,
    trusted_out: np.ndarray,
) -> None:
    """Run :func:`receive_frame` over one message's frames (in time order), writing per-frame outputs."""
    for i in range(t_ns.shape[0]):
        status_out[i] = receive_frame(state, cfg, t_ns[i], counter[i], check_ok[i])
        accepted_out[i] = state[S_ACCEPTED] != 0
        trusted_out[i] = state[S_TRUSTED] != 0


@dataclass(frozen=True)
class ReceiverConfig:
    """Receiver parameters of one message.

    Attributes:
        timeout_ns: a gap longer than this without a good frame re-initialises the receiver [ns].
        modulus: counter period (15 for Profile 1).
        invalid_counter: a counter value that is never valid (15 for Profile 1; -1 for none).
        max_delta: MaxDeltaCounter, the largest accepted counter step (default 2: one frame lost).
        sync_frames: consecutive good frames needed after a (re-)start or fault before values are used.
        has_counter: False for a message without an alive counter (every good frame counts as the
            next in sequence: no REPEATED, WRONGSEQUENCE or lost frames can be seen).
    """

    timeout_ns: int
    modulus: int = 15
    invalid_counter: int = 15
    max_delta: int = 2
    sync_frames: int = 2
    has_counter: bool = True

    def __post_init__(self) -> None:
        if self.timeout_ns <= 0 or (
            self.has_counter and (self.modulus < 2 or not 1 <= self.max_delta < self.modulus)
        ):
            raise ValueError(f"invalid ReceiverConfig {self}")
        if self.sync_frames < 0:
            raise ValueError(f"ReceiverConfig.sync_frames must be >= 0, got {self.sync_frames}")

    def as_array(self) -> np.ndarray:
        cfg = np.zeros(C_SIZE, dtype=np.int64)
        cfg[C_MODULUS] = self.modulus
        cfg[C_INVALID] = self.invalid_counter
        cfg[C_MAX_DELTA] = self.max_delta
        cfg[C_SYNC] = self.sync_frames
        cfg[C_TIMEOUT_NS] = self.timeout_ns
        cfg[C_HAS_COUNTER] = int(self.has_counter)
        return cfg

    @classmethod
    def for_scheme(cls, scheme: IntegrityScheme, timeout_ns: int, max_delta: int = 2, sync_frames: int = 2):
        if not scheme.has_counter:
            return cls(int(timeout_ns), 2, -1, 1, sync_frames, has_counter=False)
        return cls(
            timeout_ns=int(timeout_ns),
            modulus=scheme.modulus,
            invalid_counter=scheme.invalid_counter,
            max_delta=min(max_delta, scheme.modulus - 1),
            sync_frames=sync_frames,
        )


@dataclass
class ReceiverStats:
    """Counts of one message's receiver.

    ``received``: frames of the right length passed to the receiver; ``used``: frames whose values were
    used; ``lost``: frames missing in the counter sequence (seen at OKSOMELOST frames); ``repeated``,
    ``wrong_sequence``, ``wrong_crc``: rejected frames by cause; ``resync``: frames that passed the
    check but were not used because the message was (re-)synchronising (the INITIAL frame and the
    ``sync_frames - 1`` good frames after it); ``nonewdata``: timeouts (counted when the next frame
    arrives); ``initial``: (re-)starts; ``malformed``: frames with the message's id but the wrong
    length (rejected before the receiver, counted by :mod:`lde.engine.receiver`).

    Every received frame is exactly one of used, rejected or resync:
    ``received == used + rejected + resync``.
    """

    received: int = 0
    used: int = 0
    lost: int = 0
    repeated: int = 0
    wrong_sequence: int = 0
    wrong_crc: int = 0
    nonewdata: int = 0
    initial: int = 0
    oksomelost: int = 0
    malformed: int = 0
    resync: int = 0

    @property
    def rejected(self) -> int:
        """Frames rejected by the E2E check (repeated + wrong sequence + wrong CRC)."""
        return self.repeated + self.wrong_sequence + self.wrong_crc

    @classmethod
    def from_state(cls, state: np.ndarray, malformed: int = 0) -> ReceiverStats:
        return cls(
            received=int(state[S_N_RECEIVED]),
            used=int(state[S_N_USED]),
            lost=int(state[S_N_LOST]),
            repeated=int(state[S_N_REPEATED]),
            wrong_sequence=int(state[S_N_WRONGSEQ]),
            wrong_crc=int(state[S_N_WRONGCRC]),
            nonewdata=int(state[S_N_NONEWDATA]),
            initial=int(state[S_N_INITIAL]),
            oksomelost=int(state[S_N_OKSOMELOST]),
            malformed=malformed,
            resync=int(state[S_N_RESYNC]),
        )


@dataclass
class P01Receiver:
    """Live receiver of one message: the scalar face of :func:`receive_frame`.

    ``receive(t_ns, counter, check_ok)`` takes an already checked frame (any scheme);
    ``receive_frame(t_ns, data)`` checks a frame of ``scheme`` itself (Profile 1 via ``autosar-e2e``).
    """

    config: ReceiverConfig
    data_id: int = 0
    scheme: IntegrityScheme = P01_SCHEME
    state: np.ndarray = field(default_factory=new_state)

    def __post_init__(self) -> None:
        self._cfg = self.config.as_array()

    def reset(self) -> None:
        self.state = new_state()

    def receive(self, t_ns: int, counter: int, check_ok: bool) -> E2EStatus:
        """One frame -> its status; the state (trust, counters) is updated."""
        return E2EStatus(
            int(receive_frame(self.state, self._cfg, np.int64(t_ns), np.int64(counter), bool(check_ok)))
        )

    def receive_frame(self, t_ns: int, data: bytes | bytearray) -> E2EStatus:
        """Check and receive one frame of this receiver's scheme and data id."""
        ok = check_frame(self.scheme, self.data_id, data)
        return self.receive(t_ns, read_counter(self.scheme, data), ok)

    @property
    def trusted(self) -> bool:
        return bool(self.state[S_TRUSTED])

    @property
    def accepted(self) -> bool:
        """True if the last received frame's values are to be used."""
        return bool(self.state[S_ACCEPTED])

    @property
    def lost_last(self) -> int:
        return int(self.state[S_LOST_LAST])

    def timed_out(self, t_ns: int) -> bool:
        """True if no good frame arrived within the timeout before ``t_ns`` (or none ever)."""
        if self.state[S_WAIT_FIRST]:
            return True
        return int(t_ns) - int(self.state[S_LAST_T]) > self.config.timeout_ns

    def status_at(self, t_ns: int) -> E2EStatus | None:
        """NONEWDATA if timed out at ``t_ns``, else None (the per-frame status is what ``receive`` gave)."""
        return E2EStatus.NONEWDATA if self.timed_out(t_ns) else None

    @property
    def stats(self) -> ReceiverStats:
        return ReceiverStats.from_state(self.state)


class P01Sender:
    """Sender side of one message: fills counter (0..14, wrapping) and CRC in place.

    >>> s = P01Sender(0x2A0); buf = bytearray(8); s.protect(buf); buf[1] & 0x0F
    0
    """

    def __init__(self, data_id: int, counter_start: int = 0, scheme: IntegrityScheme = P01_SCHEME) -> None:
        if not 0 <= counter_start < scheme.modulus or counter_start == scheme.invalid_counter:
            raise ValueError(f"counter_start {counter_start} outside 0..{scheme.modulus - 1}")
        self.data_id = int(data_id)
        self.scheme = scheme
        self.counter = int(counter_start)

    def protect(self, buf: bytearray) -> bytearray:
        """Write the current counter and the CRC/checksum into ``buf`` (in place); advance the counter."""
        protect_frame(self.scheme, self.data_id, buf, self.counter)
        self.counter = self.scheme.next_counter(self.counter)
        return buf
