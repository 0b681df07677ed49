"""The CAN frame as an MCAP message: schemas ``lde_msgs/msg/CanFrame`` (classic) and
``lde_msgs/msg/CanFdFrame`` (CAN FD), ``ros2msg``, CDR payloads.

Topics: the frames lde received and sent on ``/can/rx`` and ``/can/tx``; CAN FD frames (more than 8
data bytes) on ``/can/fd/rx`` and ``/can/fd/tx``. A log of several buses has a set of topics per bus,
``/can/<bus>/rx`` ..., each channel naming its bus in its metadata (``bus``); lde's sent frames'
channels say ``direction = tx``. Message encoding ``cdr``; ``log_time`` = ``publish_time`` = the
frame's timestamp in ns (the log's own time base).

Classic frames have a fixed size: a 4-byte CDR encapsulation header (``00 01 00 00``, little endian)
and 15 bytes of fields::

    offset  field            type
    0       id               uint32   arbitration id (11 or 29 bit)
    4       is_extended      bool
    5       is_rx            bool     False for frames lde sent
    6       dlc              uint8    data length in bytes (0..8)
    7       data             uint8[8] the data bytes, zero padded

The fixed size is what lets a log be read in bulk (:mod:`lde.io.mcap_read`). A CAN FD frame's data
is a CDR sequence (its length, aligned to 4, then the bytes)::

    0 id uint32 | 4 is_extended bool | 5 is_rx bool | 6 dlc uint8 | 7 (padding)
    8 length uint32 (= dlc, 9..64) | 12 data uint8[length]

(A frame read from a file that kept only its first 8 bytes is written with those: ``length < dlc``.)
"""

from __future__ import annotations

import struct

import numpy as np

from lde.can.frames import FrameBatch, pack_payloads

__all__ = [
    "CAN_SCHEMA_NAME",
    "CAN_SCHEMA_TEXT",
    "CAN_PAYLOAD_SIZE",
    "CAN_FD_SCHEMA_NAME",
    "CAN_FD_SCHEMA_TEXT",
    "TOPIC_FD_RX",
    "TOPIC_FD_TX",
    "can_fd_payloads",
    "frames_of_fd_payloads",
    "topic_of",
    "CDR_HEADER",
    "TOPIC_RX",
    "TOPIC_TX",
    "can_payload",
    "can_payloads",
    "frames_of_payloads",
]

TOPIC_RX = "/can/rx"
TOPIC_TX = "/can/tx"
CAN_SCHEMA_NAME = "lde_msgs/msg/CanFrame"
CAN_SCHEMA_TEXT = """\
# One raw CAN frame as lde received (/can/rx) or sent (/can/tx) it.
# Fixed size (15 bytes of CDR after the 4-byte encapsulation header) so that logs decode in bulk.
uint32 id          # arbitration id (11 or 29 bit)
bool is_extended   # 29-bit identifier
bool is_rx         # false for frames lde itself sent
uint8 dlc          # data length in bytes (0..8; longer CAN FD frames: lde_msgs/msg/CanFdFrame)
uint8[8] data      # the data bytes, zero padded
"""
CDR_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian
CAN_PAYLOAD_SIZE = 4 + 15
TOPIC_FD_RX = "/can/fd/rx"
TOPIC_FD_TX = "/can/fd/tx"
CAN_FD_SCHEMA_NAME = "lde_msgs/msg/CanFdFrame"
CAN_FD_SCHEMA_TEXT = """\
# One raw CAN FD frame (more than 8 data bytes) as lde received (/can/fd/rx) or sent (/can/fd/tx) it.
uint32 id          # arbitration id (11 or 29 bit)
bool is_extended   # 29-bit identifier
bool is_rx         # false for frames lde itself sent
uint8 dlc          # data length in bytes (9..64)
uint8[] data       # the data bytes (dlc of them)
"""
#: bytes of a CAN FD payload before its data (header and fields)
CAN_FD_HEAD = 4 + 12


def topic_of(bus: str, is_rx: bool, fd: bool) -> str:
    """The topic of a bus's received / sent, classic / CAN FD frames (module doc)."""
    way = "rx" if is_rx else "tx"
    return "/can" + (f"/{bus}" if bus else "") + ("/fd" if fd else "") + f"/{way}"


def can_payload(can_id: int, is_extended: bool, is_rx: bool, dlc: int, data: bytes) -> bytes:
    """CDR payload (19 bytes) of one CAN frame on ``/can/rx``/``/can/tx`` (layout in the module doc).

    For writers that use the ``mcap`` library directly: register the schema ``CAN_SCHEMA_NAME`` /
    ``"ros2msg"`` / ``CAN_SCHEMA_TEXT`` and channels with encoding ``"cdr"``.
    """
    d = bytes(data[:8]).ljust(8, b"\x00")  # a classic frame (CAN FD: can_fd_payloads)
    return CDR_HEADER + struct.pack("<I??B", int(can_id), bool(is_extended), bool(is_rx), int(dlc)) + d


def can_payloads(frames: FrameBatch) -> np.ndarray:
    """CDR payloads of ``frames`` as a ``uint8[n, 19]`` array (layout in the module doc)."""
    n = len(frames)
    p = np.zeros((n, CAN_PAYLOAD_SIZE), np.uint8)
    p[:, 1] = 1
    p[:, 4:8] = frames.can_id.astype("<u4").view(np.uint8).reshape(n, 4)
    p[:, 8] = frames.is_extended
    p[:, 9] = frames.is_rx
    p[:, 10] = frames.dlc
    p[:, 11:19] = frames.data[:, :8]
    return p


def frames_of_payloads(t_ns: np.ndarray, payloads: bytes) -> FrameBatch:
    """Frames (in the given order) from their log times and concatenated 19-byte payloads."""
    n = len(t_ns)
    p = np.frombuffer(payloads, np.uint8).reshape(n, CAN_PAYLOAD_SIZE)
    return FrameBatch(
        t_ns=np.asarray(t_ns, np.int64),
        can_id=p[:, 4:8].copy().view("<u4").reshape(n),
        is_extended=p[:, 8] != 0,
        dlc=p[:, 10],
        data=p[:, 11:19],
        is_rx=p[:, 9] != 0,
    )


def can_fd_payloads(frames: FrameBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CDR payloads of CAN FD ``frames`` (module doc), concatenated: (bytes, offset and length of each).
    A frame with fewer bytes stored than its ``dlc`` (read from a file that kept only 8) keeps its
    ``dlc`` and only the bytes it has."""
    n = len(frames)
    stored = np.minimum(frames.dlc.astype(np.int64), frames.width)
    length = CAN_FD_HEAD + stored
    off = np.zeros(n, np.int64)
    if n:
        off[1:] = np.cumsum(length)[:-1]
    out = np.zeros(int(length.sum()), np.uint8)
    for i in range(n):
        d, k = int(frames.dlc[i]), int(stored[i])
        o = int(off[i])
        out[o : o + CAN_FD_HEAD] = np.frombuffer(
            CDR_HEADER
            + struct.pack(
                "<I??BxI", int(frames.can_id[i]), bool(frames.is_extended[i]), bool(frames.is_rx[i]), d, k
            ),
            np.uint8,
        )
        out[o + CAN_FD_HEAD : o + CAN_FD_HEAD + k] = frames.data[i, :k]
    return out, off, length


def frames_of_fd_payloads(t_ns: np.ndarray, payloads: list[bytes]) -> tuple[FrameBatch, np.ndarray]:
    """Frames (in the given order) from CAN FD payloads, and the indices of the payloads they
    came from (a malformed payload is skipped)."""
    keep_t, ids, ext, rx, data, kept, dlcs = [], [], [], [], [], [], []
    for i, (t, p) in enumerate(zip(np.asarray(t_ns, np.int64).tolist(), payloads, strict=True)):
        if len(p) < CAN_FD_HEAD or p[:2] != CDR_HEADER[:2]:
            continue
        cid, e, r, d, n = struct.unpack_from("<I??BxI", p, 4)
        if n > d or d > 64 or len(p) != CAN_FD_HEAD + n:
            continue
        kept.append(i)
        keep_t.append(t)
        ids.append(cid)
        ext.append(e)
        rx.append(r)
        data.append(bytes(p[CAN_FD_HEAD:]))
        dlcs.append(d)
    return (
        FrameBatch(
            t_ns=np.array(keep_t, np.int64),
            can_id=np.array(ids, np.uint32),
            is_extended=np.array(ext, np.bool_),
            dlc=np.array(dlcs, np.uint8),
            data=pack_payloads(data),
            is_rx=np.array(rx, np.bool_),
        ),
        np.array(kept, np.int64),
    )
