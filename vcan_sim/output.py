"""Writing a finished run: candump ``-L`` log, ground-truth CSV, MCAP (frames + ``/truth`` JSON channel)."""

from __future__ import annotations

from pathlib import Path

from lde.errors import LogFormatError
from lde.logio import McapWriter, write_candump

from .run import SimResult
from .truth import TRUTH_COLUMNS, write_truth_csv

TRUTH_TOPIC = "/truth"


def write_mcap(path: str | Path, res: SimResult) -> None:
    """MCAP: the frames on ``/can/rx`` and one JSON truth record per 3.9 ms step on ``/truth``."""
    meta = {
        "scenario": res.scenario.name,
        "seed": str(res.seed),
        "profile": res.profile,
        "source": "vcan_sim",
        "t0_ns": str(res.t0_ns),
    }
    props = {name: {"type": "number", "description": unit} for name, (_, unit) in TRUTH_COLUMNS.items()}
    with McapWriter(path, profile=res.profile, metadata=meta) as w:
        w.write_frames(res.frames)
        cid = w.add_json_channel(TRUTH_TOPIC, props, title="vcan_sim_truth")
        w.write_json_columns(cid, res.truth_t_ns, res.truth)


def write_outputs(
    res: SimResult,
    log: str | Path | None = None,
    truth: str | Path | None = None,
    mcap: str | Path | None = None,
    channel: str = "vcan0",
) -> list[Path]:
    """Write whichever outputs are given; the paths written."""
    done: list[Path] = []
    if log:
        try:
            write_candump(log, res.frames, channel=channel)
        except OSError as exc:
            raise LogFormatError(f"cannot write {log}: {exc}") from exc
        done.append(Path(log))
    if truth:
        write_truth_csv(truth, res.truth, res.truth_t_ns)
        done.append(Path(truth))
    if mcap:
        write_mcap(mcap, res)
        done.append(Path(mcap))
    return done
