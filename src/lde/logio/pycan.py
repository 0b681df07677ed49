"""Every log format python-can reads (ASC, BLF, TRC, CSV, SQLite, MF4, ...) -> FrameBatch.

python-can gives float-second timestamps: they are converted with
:func:`lde.frames.seconds_to_ns` (rounded to the microsecond). Error and remote frames are skipped
with a count. Any exception of the format's reader becomes a :class:`LogFormatError`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
from can.io import player

from ..errors import LogFormatError
from ..frames import FrameBatch, seconds_to_ns

__all__ = ["PycanParse", "read_pycan", "pycan_suffixes"]


def pycan_suffixes() -> set[str]:
    """File suffixes python-can has a reader for (built-in and plugins)."""

    player._update_reader_plugins()
    return set(player.MESSAGE_READERS)


@dataclass(frozen=True)
class PycanParse:
    frames: FrameBatch
    error_frames: int
    remote_frames: int


def read_pycan(path: str | Path) -> PycanParse:
    """Read ``path`` with ``can.LogReader`` (format by suffix). Frames in file order."""
    p = Path(path)
    t: list[int] = []
    ids: list[int] = []
    ext: list[bool] = []
    dlc: list[int] = []
    rx: list[bool] = []
    payload = bytearray()
    n_err = 0
    n_rtr = 0
    try:
        reader = can.LogReader(str(p))
    except ValueError as exc:
        raise LogFormatError(f"{p}: no reader for this file type ({exc})") from exc
    except Exception as exc:  # noqa: BLE001 - format readers raise anything on bad input
        raise LogFormatError(f"{p}: cannot open as a {p.suffix} log ({type(exc).__name__}: {exc})") from exc
    try:
        with reader:
            for m in reader:
                if m.is_error_frame:
                    n_err += 1
                    continue
                if m.is_remote_frame:
                    n_rtr += 1
                    continue
                raw = bytes(m.data or b"")
                t.append(seconds_to_ns(m.timestamp))
                ids.append(int(m.arbitration_id))
                ext.append(bool(m.is_extended_id))
                dlc.append(len(raw))
                rx.append(bool(m.is_rx))
                payload += raw[:8].ljust(8, b"\x00")
    except LogFormatError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise LogFormatError(f"{p}: corrupt {p.suffix} log ({type(exc).__name__}: {exc})") from exc
    n = len(t)
    frames = FrameBatch(
        t_ns=np.array(t, np.int64),
        can_id=np.array(ids, np.uint32),
        is_extended=np.array(ext, np.bool_),
        dlc=np.array(dlc, np.uint8),
        data=np.frombuffer(bytes(payload), np.uint8).reshape(n, 8),
        is_rx=np.array(rx, np.bool_),
    )
    return PycanParse(frames, n_err, n_rtr)
