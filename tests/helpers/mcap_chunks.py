"""Test helper: where the chunks of an MCAP file are, found with the ``mcap`` library alone (its
``StreamReader`` over the records, file positions taken after each one) so that tests can cut a
file inside or after a chunk whatever its layout (compact files have no chunk indexes)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from mcap.records import Chunk
from mcap.stream_reader import StreamReader


class ChunkSpan(NamedTuple):
    chunk_start_offset: int
    chunk_length: int
    message_start_time: int
    message_end_time: int


def chunk_spans(path: Path) -> list[ChunkSpan]:
    out = []
    with Path(path).open("rb") as fh:
        for rec in StreamReader(fh, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                length = 9 + 8 + 8 + 8 + 4 + 4 + len(rec.compression) + 8 + len(rec.data)
                out.append(
                    ChunkSpan(fh.tell() - length, length, rec.message_start_time, rec.message_end_time)
                )
    return out
