"""How a log file ends: closed cleanly, not closed, or cut short, and where reading stopped.

A log cut by a crash, a kill or a full disk still reads up to its last complete record; what is
lost must be said, with where it stopped. :class:`FileEnd` holds it for every format:

* candump ``-L`` (and any text format python-can reads: ASC, TRC, CSV): a last line without
  newline is cut (skipped); the line number and the byte offset where the complete lines end.
  An ASC file without its ``End TriggerBlock`` line was not closed by its writer.
* MCAP: no footer = not closed (a recording killed before its summary was written); a record
  cut short = cut; the byte offset of the end of the last complete record (what was recovered).
* BLF: the file header's size field is written when the writer closes: still the header's own
  size = not closed; a container object running past the end of the file = cut (its frames are
  partly lost); the byte offset where the last complete object ends.
* gzip: a stream without its end (the writer never finished it) is not closed and cut; offsets
  are then in the decompressed content.

:func:`text_end` and :func:`blf_end` look only at the file's tail or its object headers (no
message is parsed twice). The time of the last frame read comes from the stream
(:attr:`lde.io.LogStream.last_t_ns`).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

__all__ = ["FileEnd", "text_end", "blf_end", "TAIL_BYTES"]

#: bytes of a text log's tail looked at for its last newline and an ASC end marker
TAIL_BYTES = 1 << 16
_ASC_END = b"end triggerblock"
_BLF_HEADER = struct.Struct("<4sI")  # signature, header size
_BLF_FILE_SIZE = struct.Struct("<Q")  # at byte 32 of the file header (python-can's FILE_HEADER_STRUCT)
_BLF_OBJ = struct.Struct("<4sHHI")  # signature, header size, header version, object size


@dataclass(frozen=True)
class FileEnd:
    """How a log file ends.

    Attributes:
        closed: True if the file carries its writer's closing record (MCAP footer, ASC
            ``End TriggerBlock``, BLF header size field, gzip end of stream), False if not,
            None when the format has none (candump text, TRC, CSV).
        cut: the file ends inside a record or line; that record was skipped.
        offset: byte offset where the complete records end (what was read) [bytes].
        size: the file's size [bytes].
        line: for text logs, the number of complete lines (the cut one is line + 1); else 0.
        what: the record the file ends in or lacks, for the message ("line", "chunk", ...).
        compressed: ``offset`` and ``size`` are of the gzip file's decompressed content.
    """

    closed: bool | None
    cut: bool
    offset: int
    size: int
    line: int = 0
    what: str = ""
    compressed: bool = False

    @property
    def lossy(self) -> bool:
        """The file was cut or not closed: something may be missing at its end."""
        return self.cut or self.closed is False


def text_end(path: str | Path, asc: bool = False) -> FileEnd:
    """The end of a text log: a last line without newline is cut; for ASC (``asc``) the
    ``End TriggerBlock`` line says it was closed. ``line`` counts the complete lines (the whole
    file is scanned for newlines, block by block, only when it is cut)."""
    p = Path(path)
    with p.open("rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        fh.seek(max(0, size - TAIL_BYTES))
        tail = fh.read()
        nl = tail.rfind(b"\n")
        cut = bool(tail) and not tail.endswith(b"\n") and bool(tail[nl + 1 :].strip(b" \t\r"))
        offset = size - (len(tail) - nl - 1) if cut else size
        if cut and nl < 0 and size > TAIL_BYTES:  # a last line longer than the tail: find its start
            offset = _last_newline(fh, size - TAIL_BYTES) + 1
        line = 0
        if cut:
            fh.seek(0)
            left = offset
            while left > 0 and (block := fh.read(min(1 << 20, left))):
                line += block.count(b"\n")
                left -= len(block)
    closed: bool | None = None
    if asc:
        closed = _ASC_END in tail[: nl + 1 if cut else len(tail)].lower()
    return FileEnd(closed, cut, offset, size, line, "line")


def _last_newline(fh, before: int) -> int:
    """The offset of the last newline before ``before`` (-1: none)."""
    pos = before
    while pos > 0:
        a = max(0, pos - TAIL_BYTES)
        fh.seek(a)
        k = fh.read(pos - a).rfind(b"\n")
        if k >= 0:
            return a + k
        pos = a
    return -1


def blf_end(path: str | Path) -> FileEnd:
    """The end of a BLF file, from its header's size field and a walk over its object headers."""
    p = Path(path)
    with p.open("rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        head = fh.read(48)
        if len(head) < 40 or not head.startswith(b"LOGG"):
            return FileEnd(None, False, size, size, what="object")
        _, header_size = _BLF_HEADER.unpack_from(head)
        (declared,) = _BLF_FILE_SIZE.unpack_from(head, 32)
        pos = header_size
        cut = False
        while pos < size:
            fh.seek(pos)
            raw = fh.read(_BLF_OBJ.size)
            if len(raw) < _BLF_OBJ.size:
                cut = True
                break
            sig, _hs, _hv, obj_size = _BLF_OBJ.unpack(raw)
            if sig != b"LOBJ" or obj_size < _BLF_OBJ.size:
                break  # not an object: python-can's reader says what is wrong with it
            end = pos + obj_size + obj_size % 4
            if pos + obj_size > size:
                cut = True
                break
            pos = min(end, size)
    closed = declared not in (0, header_size)
    cut = cut or (closed and declared > size)  # shorter than its header says: cut after closing
    return FileEnd(closed, cut, pos, size, what="object")
