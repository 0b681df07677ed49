"""gzip-compressed logs: decompressed piece by piece (every member of a multi-member file).

A gzip stream cut short (a log still being written, a crash) keeps what decompressed; the last
piece then says so. Trailing bytes after the last member are ignored, as ``gzip -d`` does.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator
from pathlib import Path

from lde.errors import LogFormatError

__all__ = ["GZ", "GZIP_MAGIC", "gunzip_pieces", "gunzip_head"]

GZ = ".gz"
GZIP_MAGIC = b"\x1f\x8b"


def gunzip_pieces(p: Path, max_bytes: int | None = None) -> Iterator[tuple[bytes, bool]]:
    """Decompressed pieces of the gzip file ``p``, each with a flag that is True on the last piece
    when the stream was cut short. Stops after ``max_bytes``.

    Raises:
        LogFormatError: unreadable file or data that is not gzip.
    """
    d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
    fed = False  # the current member's decompressor has had input
    out_n = 0
    try:
        with p.open("rb") as fh:
            while block := fh.read(1 << 20):
                while block:
                    try:
                        piece = d.decompress(block)
                    except zlib.error as exc:
                        raise LogFormatError(f"{p}: corrupt gzip data ({exc})") from exc
                    fed = True
                    out_n += len(piece)
                    yield piece, False
                    if max_bytes is not None and out_n >= max_bytes:
                        return
                    block = b""
                    if d.eof:  # the member ended: another one may follow
                        block = d.unused_data
                        if block and not block.startswith(GZIP_MAGIC[: len(block)]):
                            return  # trailing bytes after the last member: ignored, like gzip -d
                        d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
                        fed = False
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc}") from exc
    yield d.flush(), fed and not d.eof


def gunzip_head(p: Path, n: int) -> bytes:
    """The first ``n`` decompressed bytes of ``p``."""
    head = b"".join(piece for piece, _ in gunzip_pieces(p, n))
    return head[:n]
