"""Golden vectors: inputs and bit-exact expected outputs of the integer step
(``firmware_model/golden_vectors.json``, made by ``python -m firmware_model.gen_golden``), replayed
on the pure-Python reference and on the numba twin. The file carries its own constants, so it
checks the integer algorithm, independent of later tuning changes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from firmware_model.fast import FastState, run_batch_raw, tables_vector
from firmware_model.gen_golden import GOLDEN_PATH
from firmware_model.step import SAT_NAMES, FixedState, quantise_inputs, step_raw
from firmware_model.tables import FixedTables


@pytest.fixture(scope="module")
def golden():
    g = json.loads(GOLDEN_PATH.read_text())
    tb = FixedTables.from_dict(g["tables"])
    rows = g["inputs"]
    t = np.array([r[0] for r in rows], dtype=np.int64)
    cols = [np.array([float.fromhex(r[i]) for r in rows]) for i in range(1, 6)]
    flags = [np.array([bool(r[i]) for r in rows]) for i in (6, 7)]
    return g, tb, (t, *cols, *flags)


def test_golden_vectors_cover_the_status_cases(golden):
    g, _, _ = golden
    statuses = {r[0] for r in g["expected"]}
    for bit in (1, 2, 4, 8, 16, 32):
        assert any(s & bit for s in statuses), f"no golden step with status bit {bit}"
    assert any(s == 1 for s in statuses)  # VALID alone
    sat = dict(zip(SAT_NAMES, g["final_state"]["sat"], strict=True))
    assert sat["in_torque"] > 0 and sat["speed_clamp"] > 0 and sat["in_yaw"] > 0


def test_reference_reproduces_golden_vectors(golden):
    g, tb, d = golden
    st = FixedState.initial(tb)
    for k, exp in enumerate(g["expected"]):
        raw = quantise_inputs(tb, d[1][k], d[2][k], d[3][k], d[4][k], d[5][k])
        got = step_raw(tb, st, int(d[0][k]), *raw, bool(d[6][k]), bool(d[7][k]))
        assert list(got) == exp, f"step {k}"
    f = g["final_state"]
    assert (st.x, st.P, st.delta, st.t_align, st.sat) == (f["x"], f["P"], f["delta"], f["t_align"], f["sat"])


def test_numba_twin_reproduces_golden_vectors(golden):
    g, tb, d = golden
    st = FastState.initial(tables_vector(tb))
    _, outs, status = run_batch_raw(tb, st, *d)
    exp = np.array(g["expected"], dtype=np.int64)
    np.testing.assert_array_equal(status, exp[:, 0])
    np.testing.assert_array_equal(outs, exp[:, 1:])
    assert st.sat.tolist() == g["final_state"]["sat"]
    assert st.P.tolist() == g["final_state"]["P"]
