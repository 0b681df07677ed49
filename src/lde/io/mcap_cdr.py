"""The CAN frame as an MCAP message: schema ``lde_msgs/msg/CanFrame`` (``ros2msg``), CDR payload.

``/can/rx`` holds the frames lde received, ``/can/tx`` the frames lde sent; message encoding
``cdr``; ``log_time`` = ``publish_time`` = the frame's timestamp in ns (the log's own time base).
Every CAN message has the same size: a 4-byte CDR encapsulation header (``00 01 00 00``, little
endian) and 15 bytes of fields::

    offset  field            type
    0       id               uint32   arbitration id (11 or 29 bit)
    4       is_extended      bool
    5       is_rx            bool     False for frames lde sent
    6       dlc              uint8    data length in bytes (0..64; > 8 = CAN FD)
    7       data             uint8[8] first 8 data bytes, zero padded

The fixed size is what lets a log be read in bulk (:mod:`lde.io.mcap_read`).
"""

from __future__ import annotations

import struct

import numpy as np

from lde.can.frames import FrameBatch

__all__ = [
    "CAN_SCHEMA_NAME",
    "CAN_SCHEMA_TEXT",
    "CAN_PAYLOAD_SIZE",
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
uint8 dlc          # data length in bytes (0..64; above 8 only the first 8 bytes are kept)
uint8[8] data      # first 8 data bytes, zero padded
"""
CDR_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian
CAN_PAYLOAD_SIZE = 4 + 15


def can_payload(can_id: int, is_extended: bool, is_rx: bool, dlc: int, data: bytes) -> bytes:
    """CDR payload (19 bytes) of one CAN frame on ``/can/rx``/``/can/tx`` (layout in the module doc).

    For writers that use the ``mcap`` library directly: register the schema ``CAN_SCHEMA_NAME`` /
    ``"ros2msg"`` / ``CAN_SCHEMA_TEXT`` and channels with encoding ``"cdr"``.
    """
    d = bytes(data[:8]).ljust(8, b"\x00")
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
    p[:, 11:19] = frames.data
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
