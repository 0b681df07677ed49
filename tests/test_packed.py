"""lde.packed: many constant arrays as one buffer, read back inside compiled code; and the engine's
packed tables read back exactly as the receiver's and the output encoder's arrays."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from lde.engine import Engine
from lde.packed import b1_1, f8_1, i8_1, i8_2, i8_3, pack
from lde.params import load_vehicle
from lde.pipeline import TABLE_KINDS, output_table_of
from lde.profiles import load_profile
from lde.signals import RX_TABLE_KINDS, rx_tables_of


@njit(cache=True)
def _read_back(mem, lay):
    a = i8_1(mem, lay, 0)
    b = i8_2(mem, lay, 1)
    c = i8_3(mem, lay, 2)
    d = f8_1(mem, lay, 3)
    e = b1_1(mem, lay, 4)
    c[1, 0, 2] = -5  # a view: the store lands in the buffer
    return a.copy(), b.copy(), c.copy(), d.copy(), e.copy()


def test_pack_reads_back_every_kind_and_stores_go_to_the_buffer() -> None:
    arrays = (
        np.arange(5, dtype=np.int64),
        np.arange(6, dtype=np.int64).reshape(2, 3) * 7,
        np.arange(12, dtype=np.int64).reshape(2, 2, 3) - 4,
        np.array([0.5, -1.25, np.inf]),
        np.array([True, False, True]),
    )
    mem, lay = pack(arrays, ("i8:1", "i8:2", "i8:3", "f8:1", "b1:1"))
    got = _read_back(mem, lay)
    for g, a in zip(got[:2] + got[3:], arrays[:2] + arrays[3:], strict=True):
        assert g.dtype == a.dtype and g.shape == a.shape
        np.testing.assert_array_equal(g, a)
    want = arrays[2].copy()
    want[1, 0, 2] = -5
    np.testing.assert_array_equal(got[2], want)
    assert all(off % 64 == (-mem.ctypes.data) % 64 for off in lay[:, 0])  # aligned in memory
    # the store is in the buffer: a second read sees it
    np.testing.assert_array_equal(_read_back(mem, lay)[2], want)


@pytest.mark.parametrize(
    ("array", "kind"),
    [(np.zeros(3, np.int32), "i8:1"), (np.zeros((2, 2)), "f8:1"), (np.zeros(3, np.int64), "b1:1")],
)
def test_pack_refuses_an_array_of_another_kind(array: np.ndarray, kind: str) -> None:
    with pytest.raises(ValueError, match="is expected"):
        pack((array,), (kind,))


def test_pack_needs_one_kind_per_array() -> None:
    with pytest.raises(ValueError, match="kinds"):
        pack((np.zeros(1, np.int64),), ("i8:1", "i8:1"))


@njit(cache=True)
def _tables(mem, lay):
    return rx_tables_of(mem, lay, 0), output_table_of(mem, lay, 20)


def test_the_engine_tables_unpack_to_the_receiver_and_output_arrays() -> None:
    eng = Engine(load_profile("lde"), load_vehicle("reference"), "float", explicit=True)
    mem, lay = eng._tables
    assert len(RX_TABLE_KINDS) == 20 and len(TABLE_KINDS) == lay.shape[0]
    rx, out = _tables(mem, lay)
    want = eng.rx_tables.kernel_args() + eng.outputs.args
    assert len(rx) + len(out) == len(want)
    for k, (g, a) in enumerate(zip(rx + out, want, strict=True)):
        assert g.dtype == a.dtype and g.shape == a.shape, k
        np.testing.assert_array_equal(g, a, err_msg=f"table {k}")
