"""Every log format python-can reads (ASC, BLF, TRC, CSV, SQLite, MF4, ...) -> FrameBatch pieces.

The format's ``can.LogReader`` is iterated and its messages are turned into columns in batches of
:data:`BATCH` (file order). python-can gives float-second timestamps: they are converted with
:func:`lde.can.frames.seconds_to_ns` (rounded to the microsecond). Error and remote frames are skipped
with a count. A message's ``channel`` is its frame's bus (:attr:`lde.can.frames.FrameBatch.channels`;
None: ``""``); CAN FD messages keep all their bytes. Any exception of the format's reader becomes a
:class:`LogFormatError` that says where the reader was: the line (text formats: ASC, TRC, CSV, read
through a line-counting text file) or the byte offset it had read up to (binary formats such as BLF).
"""

from __future__ import annotations

import io
import locale
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lde.can.frames import MAX_DATA, FrameBatch, pack_payloads, seconds_to_ns
from lde.errors import LogFormatError

if TYPE_CHECKING:
    import can

__all__ = ["PycanReader", "pycan_suffixes", "BATCH"]

#: messages per batch
BATCH = 1 << 16


def pycan_suffixes() -> set[str]:
    """File suffixes python-can has a reader for (built-in and plugins)."""
    from can.io import player  # here, not at import: a candump or MCAP replay never needs python-can

    player._update_reader_plugins()
    return set(player.MESSAGE_READERS)


class PycanReader:
    """A python-can log read in batches: iterate for the frames (file order); :attr:`error_frames`
    and :attr:`remote_frames` count what was skipped (final once the iteration ends).

    Raises:
        LogFormatError: no reader for the suffix, or the format's reader failed (at open or while
            iterating).
    """

    def __init__(
        self, path: str | Path, batch: int = BATCH, limit: int | None = None, text: bool = False
    ) -> None:
        self.path = Path(path)
        self.batch = batch
        self.limit = limit  # a text log read only up to this byte (its cut last line left out)
        self.text = text  # a text format: read through a line counter (errors name the line)
        self.error_frames = 0
        self.remote_frames = 0

    def __iter__(self) -> Iterator[FrameBatch]:
        import can

        p = self.path
        lines: _LineCounter | None = None
        try:
            if self.text or self.limit is not None:
                lines = _text_file(p, self.limit)
                reader = _text_reader(p, lines)
            else:
                reader = can.LogReader(str(p))
        except ValueError as exc:
            raise LogFormatError(f"{p}: no reader for this file type ({exc})") from exc
        except Exception as exc:  # noqa: BLE001 - format readers raise anything on bad input
            raise LogFormatError(
                f"{p}: cannot open as a {p.suffix} log ({type(exc).__name__}: {exc})"
            ) from exc
        cols = _Columns()
        with reader:  # the error names the reader's position: taken before the file is closed
            try:
                for m in reader:
                    if m.is_error_frame:
                        self.error_frames += 1
                        continue
                    if m.is_remote_frame:
                        self.remote_frames += 1
                        continue
                    cols.add(m)
                    if cols.n >= self.batch:
                        yield cols.take()
            except Exception as exc:  # noqa: BLE001
                raise LogFormatError(
                    f"{p}: corrupt {p.suffix} log {_where(reader, lines)}({type(exc).__name__}: {exc})"
                ) from exc
        if cols.n:
            yield cols.take()


def _where(reader: Any, lines: _LineCounter | None) -> str:
    """Where a reader failed: ``at line N `` (text) or ``before byte N `` (the position of its
    binary file: the record it failed in ends there), else nothing."""
    if lines is not None:
        return f"at line {lines.lines} "
    try:
        return f"before byte {int(reader.file.tell())} "
    except Exception:  # noqa: BLE001 - a reader without a seekable file: say nothing
        return ""


class _LineCounter(io.TextIOWrapper):
    """A text file that counts the lines read from it (python-can's text readers iterate it or
    call ``readline``; iterating goes through ``readline`` here): :attr:`lines` is the number of
    the line read last."""

    lines = 0

    def __next__(self) -> str:  # type: ignore[override]  # typeshed: the base class's bytes
        line = self.readline()
        if not line:
            raise StopIteration
        return line

    def readline(self, size: int | None = -1) -> str:  # type: ignore[override]
        line = super().readline(-1 if size is None else size)
        if line:
            self.lines += 1
        return line


class _Head(io.RawIOBase):
    """The first ``limit`` bytes of a binary file."""

    def __init__(self, fh: io.BufferedReader, limit: int) -> None:
        self._fh = fh
        self._left = limit

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        n = self._fh.readinto(memoryview(b)[: max(0, min(len(b), self._left))]) or 0
        self._left -= n
        return n

    def close(self) -> None:
        self._fh.close()
        super().close()


def _text_file(p: Path, limit: int | None) -> _LineCounter:
    """``p`` as text (the encoding python-can uses for a path), over its first ``limit`` bytes
    when given, counting lines."""
    fh = p.open("rb")
    raw: io.BufferedReader = fh if limit is None else io.BufferedReader(_Head(fh, limit))
    return _LineCounter(raw, locale.getpreferredencoding(False))


def _text_reader(p: Path, text: _LineCounter) -> can.io.generic.MessageReader:
    """python-can's text reader for ``p``'s suffix over the open ``text``."""
    from can.io import player

    player._update_reader_plugins()
    cls: Any = player.MESSAGE_READERS.get(p.suffix.lower())
    if cls is None:
        text.close()
        raise ValueError(f"no reader for {p.suffix!r}")
    try:
        return cls(file=text)
    except BaseException:
        text.close()
        raise


class _Columns:
    """Messages gathered into a batch: CAN FD messages keep all their bytes; each message's
    ``channel`` names its bus (the table grows over the log, so batches share its prefix)."""

    def __init__(self) -> None:
        self.t: list[int] = []
        self.ids: list[int] = []
        self.ext: list[bool] = []
        self.rx: list[bool] = []
        self.chan: list[int] = []
        self.payloads: list[bytes] = []
        self.names: dict[str, int] = {}

    @property
    def n(self) -> int:
        return len(self.t)

    def add(self, m: can.Message) -> None:
        self.t.append(seconds_to_ns(m.timestamp))
        self.ids.append(int(m.arbitration_id))
        self.ext.append(bool(m.is_extended_id))
        self.rx.append(True)  # the logger's direction, not lde's (module doc)
        name = "" if m.channel is None else str(m.channel)
        self.chan.append(self.names.setdefault(name, len(self.names)))
        self.payloads.append(bytes(m.data or b"")[:MAX_DATA])

    def take(self) -> FrameBatch:
        out = FrameBatch(
            t_ns=np.array(self.t, np.int64),
            can_id=np.array(self.ids, np.uint32),
            is_extended=np.array(self.ext, np.bool_),
            dlc=np.array([len(p) for p in self.payloads], np.uint8),
            data=pack_payloads(self.payloads),
            is_rx=np.array(self.rx, np.bool_),
            channel=np.array(self.chan, np.uint16),
            channels=tuple(self.names) or ("",),
        )
        self.t, self.ids, self.ext, self.rx, self.chan, self.payloads = [], [], [], [], [], []
        return out
