"""python-can plugins for ``.mcap`` (entry points ``can.io.message_reader`` / ``message_writer``).

After ``pip install -e .``, ``can.LogReader("x.mcap")`` iterates the CAN frames of an lde recording
(every CAN channel: ``/can/rx``, ``/can/tx``, CAN FD and other buses' topics) as :class:`can.Message`
in time order, each with its bus as ``channel``, read chunk by chunk
(:class:`lde.io.mcap_read.McapLog`), and ``can.Logger("x.mcap")`` records messages to ``/can/rx``
(``msg.is_rx`` True) or ``/can/tx``, on their bus's topics when ``msg.channel`` names one and on
the CAN FD topics when longer than 8 bytes (:class:`lde.io.mcap_write.McapWriter`).
"""

from __future__ import annotations

from collections.abc import Generator
from pathlib import Path
from typing import Any

import can
from can.io.generic import MessageReader, MessageWriter

from lde.can.frames import seconds_to_ns
from lde.io.mcap_read import McapLog
from lde.io.mcap_write import McapWriter

__all__ = ["McapCanReader", "McapCanWriter"]


class McapCanReader(MessageReader):
    """Iterates the CAN frames of an lde MCAP file in time order."""

    def __init__(self, file: Any, **kwargs: Any) -> None:
        self._path = Path(file if not hasattr(file, "name") else file.name)

    def __iter__(self) -> Generator[can.Message, None, None]:
        with McapLog(self._path) as m:
            for piece in m.iter_frames(chunk_frames=1 << 14):
                yield from piece.to_messages(channel=None)
        self.stop()

    def stop(self) -> None:
        pass


class McapCanWriter(MessageWriter):
    """A ``can.Listener`` that records every message it receives into an lde MCAP file.

    Timestamps (float s) are stored as int ns rounded to the microsecond. Error and remote frames
    are not recorded (counted in :attr:`skipped`). Keyword arguments: ``buffer_bytes`` (flush
    threshold), ``compression`` (``zstd``, ``lz4`` or ``""``), ``indexed`` (message and chunk
    indexes, see :mod:`lde.io.mcap_write`).
    """

    def __init__(self, file: Any, **kwargs: Any) -> None:
        path = Path(file if not hasattr(file, "name") else file.name)
        self._writer = McapWriter(
            path,
            buffer_bytes=int(kwargs.get("buffer_bytes", 8 << 20)),
            compression=str(kwargs.get("compression", "zstd")),
            indexed=bool(kwargs.get("indexed", False)),
        )
        self.skipped = 0
        self._stopped = False

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame:
            self.skipped += 1
            return
        data = bytes(msg.data or b"")
        self._writer.write_frame(
            seconds_to_ns(msg.timestamp),
            int(msg.arbitration_id),
            bool(msg.is_extended_id),
            len(data),
            data,
            bool(msg.is_rx),
            "" if msg.channel is None else str(msg.channel),
        )

    def stop(self) -> None:
        if not self._stopped:
            self._stopped = True
            self._writer.close()
