"""Random CAN frames for the log readers' and writers' round trips."""

from __future__ import annotations

import numpy as np

from lde.can.frames import FrameBatch

#: an epoch-like time base [ns]
T0 = 1_700_000_000_000_000_000


def random_frames(n: int, seed: int = 0, us_exact: bool = True, classic: bool = False) -> FrameBatch:
    """``n`` frames over a minute from ``T0``, sorted in time: 20 % extended ids, 70 % received, random
    lengths of 0-8 bytes (``classic``: the lengths a classic candump line holds, with some 8-byte
    frames added otherwise) and zeroed bytes beyond each length; ``us_exact``: whole microseconds."""
    rng = np.random.default_rng(seed)
    t = T0 + np.sort(rng.integers(0, 60 * 10**9, n))
    if us_exact:
        t = t // 1000 * 1000
    ext = rng.random(n) < 0.2
    cid = np.where(ext, rng.integers(0, 1 << 29, n), rng.integers(0, 0x800, n))
    dlc = rng.integers(0, 9, n)
    if not classic:
        dlc[rng.random(n) < 0.05] = 8  # classic only: FD beyond 8 bytes is lossy by design
    data = rng.integers(0, 256, (n, 8)).astype(np.uint8)
    data[np.arange(8)[None, :] >= dlc[:, None]] = 0
    return FrameBatch(t_ns=t, can_id=cid, is_extended=ext, dlc=dlc, data=data, is_rx=rng.random(n) < 0.7)


def assert_frames_equal(
    a: FrameBatch, b: FrameBatch, fields=("t_ns", "can_id", "is_extended", "dlc", "data", "is_rx")
) -> None:
    """The two batches hold the same frames in ``fields``, element for element."""
    assert len(a) == len(b)
    for name in fields:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
