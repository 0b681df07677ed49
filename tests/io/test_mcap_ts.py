"""Foxglove's TypeScript MCAP reader (npm ``@mcap/core``) reads the files lde writes: compact (zstd and
lz4 chunks, no message or chunk indexes: its stream reader, which Foxglove uses for such files) and
indexed (its indexed reader too), every CAN frame with its log time and payload, the JSON channel's
count and the ``lde`` metadata.

Needs node and the npm packages of ``tests/ts/package.json``: ``npm install --prefix tests/ts``
(skipped with that reason otherwise)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from lde.io import McapWriter, can_payloads

from helpers import TESTS
from helpers.frames import random_frames

TS = TESTS / "ts"


def _node_ready() -> str | None:
    if shutil.which("node") is None:
        return "node is not installed"
    if not (TS / "node_modules" / "@mcap" / "core").is_dir():
        return f"@mcap/core is not installed: npm install --prefix {TS}"
    return None


pytestmark = pytest.mark.skipif(_node_ready() is not None, reason=str(_node_ready()))


def _read_ts(path: Path) -> dict:
    proc = subprocess.run(
        ["node", str(TS / "read_mcap.mjs"), str(path)], capture_output=True, text=True, timeout=120, cwd=TS
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def _expected(frames) -> dict[str, list[list[str]]]:
    pay = can_payloads(frames)
    out: dict[str, list[list[str]]] = {"/can/rx": [], "/can/tx": []}
    for i in np.argsort(frames.t_ns, kind="stable").tolist():
        topic = "/can/rx" if frames.is_rx[i] else "/can/tx"
        out[topic].append([str(int(frames.t_ns[i])), pay[i].tobytes().hex()])
    return out


@pytest.mark.parametrize(
    ("compression", "indexed"), [("zstd", False), ("lz4", False), ("", False), ("zstd", True)]
)
def test_typescript_reader_reads_what_lde_wrote(tmp_path: Path, compression: str, indexed: bool):
    frames = random_frames(3000, seed=41)
    path = tmp_path / "x.mcap"
    meta = {"profile": "lde", "vehicle": "reference"}
    with McapWriter(path, compression=compression, indexed=indexed, chunk_size=16 << 10, metadata=meta) as w:
        w.write_frames(frames)
        est = w.add_json_channel("/lde/estimate", ["Fw", "Mw"])
        t = frames.t_ns[::5]
        w.write_json_columns(est, t, {"Fw": np.arange(t.size) * 0.5, "Mw": np.zeros(t.size)})
    got = _read_ts(path)
    want = _expected(frames)
    readers = ["stream", "indexed"] if indexed else ["stream"]
    for reader in readers:
        topics = got[reader]["topics"]
        for topic, rows in want.items():
            assert topics[topic]["frames"] == rows, (reader, topic)
        assert topics["/lde/estimate"]["count"] == t.size
    assert got["stream"]["done"] and got["stream"]["metadata"]["lde"] == meta
    if not indexed:  # what Foxglove sees: no chunk index, so it reads the file with the stream reader
        assert "no chunk indexes" in got["indexed"]["error"]
