"""lde.engine.loop.LoopArrays: the compiled loop's backend-independent arrays as one StructRef hold
the arrays themselves (stores seen both ways), and the engine makes a new one when it replaces its
arrays."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from lde.can.profiles import load_profile
from lde.engine.engine import Engine, StepBlock
from lde.engine.loop import LOOP_FIELDS, loop_arrays
from lde.params import load_vehicle


@njit(cache=True)
def _touch(la):  # a store through the struct, and what it reads
    la.counters[1] = 77
    return la.prev_t[0], la.tb[0].shape[0], la.otab[18].shape[0], la.rxst[5][0], la.grid[0], la.anchor


def _engine() -> Engine:
    return Engine(load_profile("lde"), load_vehicle("reference"), "float", explicit=True)


def test_the_struct_holds_the_engines_arrays_not_copies() -> None:
    eng = _engine()
    eng.prev_t[0] = 123
    eng.rx.ignored[0] = 5
    prev, n_ids, n_sig, ignored, mode, anchor = _touch(eng._la)
    assert (prev, ignored, mode, anchor) == (123, 5, eng.grid[0], eng.rx_tables.anchor)
    assert n_ids == eng.rx_tables.id2msg.shape[0] and n_sig == eng.outputs.args[18].shape[0]
    assert eng.counters[1] == 77  # the compiled store landed in the engine's own array


def test_reset_makes_a_new_struct_and_old_live_arguments_are_refused() -> None:
    eng = _engine()
    cols = tuple(np.zeros(0, dt) for dt in (np.int64, np.uint32, np.bool_, np.uint8, np.uint64, np.bool_))
    block, _ = StepBlock.packed(1)
    args = eng.live_args(cols, block, np.zeros(0, np.int64), np.zeros(0, np.bool_), np.zeros(0, np.uint8))
    assert eng.live_args_valid(args)
    old = eng._la
    eng.reset()
    assert eng._la is not old and not eng.live_args_valid(args)
    eng.counters[0] = 9
    _touch(eng._la)
    assert eng.counters[1] == 77 and eng.counters[0] == 9


def test_loop_arrays_names_its_fields_when_miscalled() -> None:
    with pytest.raises(TypeError, match="used_since"):
        loop_arrays(*range(len(LOOP_FIELDS) - 1))
