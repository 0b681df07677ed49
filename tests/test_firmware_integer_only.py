"""The step is integer-only: no float literal, no true division, no float()/math/numpy in the
functions of the integer path (the reference and its numba twin). Floats are allowed only at the
boundary (quantise_inputs, the output scaling), which is outside these functions."""

from __future__ import annotations

import ast
import inspect
import textwrap

import pytest

from firmware_model import fast, qformat, step

REFERENCE = [
    step.step_raw,
    step.schedule,
    step._scalar_update,
    step._predict,
    step._sat32,
    step._mac,
    step._add64,
    step._set_p0,
    step.reset,
    qformat.shift_round,
    qformat.div_round,
    qformat.add_sat64,
    qformat.saturate,
]
TWIN = [
    fast.step_kernel,
    fast.schedule,
    fast._scalar_update,
    fast._predict,
    fast.shift_round,
    fast.div_round,
    fast.sat32,
    fast.add64,
    fast.mac,
    fast.reset_kernel,
    fast._set_p0,
]
FORBIDDEN_NAMES = {"float", "math", "np.float64", "numpy", "round"}


def _source(fn) -> ast.AST:
    f = getattr(fn, "py_func", fn)  # numba dispatchers keep the Python function
    return ast.parse(textwrap.dedent(inspect.getsource(f)))


@pytest.mark.parametrize("fn", REFERENCE + TWIN, ids=lambda f: f"{f.__module__}.{f.__name__}")
def test_function_is_integer_only(fn):
    tree = _source(fn)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant):
            assert not isinstance(node.value, float), f"float literal {node.value!r}"
        if isinstance(node, ast.BinOp | ast.AugAssign):
            assert not isinstance(node.op, ast.Div), "true division '/'"
        if isinstance(node, ast.Name):
            assert node.id not in FORBIDDEN_NAMES, f"uses {node.id}"
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "np":
            assert node.attr == "int64", f"uses np.{node.attr}"
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "math":
            raise AssertionError(f"uses math.{node.attr}")
