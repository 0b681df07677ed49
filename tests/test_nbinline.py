"""lde.nbinline: numba's IR inliner without its redundant copies gives the same kernels."""

from __future__ import annotations

import numpy as np
from numba import njit
from numba.core import inline_closurecall as ic

import lde.refcount  # noqa: F401  (installs it, as every kernel module does)
from lde import nbinline


@njit(inline="always")
def _leaf(x, k):  # pragma: no cover - compiled
    y = 0
    for j in range(k):
        y += (x >> j) & 1
    return y


@njit(inline="always")
def _mid(x):  # pragma: no cover - compiled
    return _leaf(x, 8) + 2 * _leaf(x >> 8, 8)


def _outer(a):  # pragma: no cover - compiled
    s = 0
    for v in a:
        s += _mid(v) - _leaf(v, 4) + _mid(v + 1)
    return s


def _reference(a: np.ndarray) -> int:
    def leaf(x: int, k: int) -> int:
        return sum((x >> j) & 1 for j in range(k))

    def mid(x: int) -> int:
        return leaf(x, 8) + 2 * leaf(x >> 8, 8)

    return sum(mid(int(v)) - leaf(int(v), 4) + mid(int(v) + 1) for v in a)


def test_installed_by_the_kernel_modules_and_idempotent() -> None:
    assert nbinline.installed()
    before = ic.InlineWorker.inline_function
    nbinline.install()
    assert ic.InlineWorker.inline_function is before
    assert ic.copy.deepcopy is __import__("copy").deepcopy  # the switch is only on inside a call


def test_nested_inlined_helpers_compute_as_before_and_as_python() -> None:
    a = np.arange(0, 70000, 37, dtype=np.int64)
    patched = njit(_outer)(a)
    saved = ic.InlineWorker.inline_function
    ic.InlineWorker.inline_function = nbinline._ORIGINAL
    try:
        copied = njit(_outer)(a)  # a new dispatcher: compiled with numba's own copies
    finally:
        ic.InlineWorker.inline_function = saved
    assert patched == copied == _reference(a)
