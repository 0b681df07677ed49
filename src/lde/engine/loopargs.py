"""The compiled loop's fixed arrays as one argument: a numba ``StructRef`` (:class:`LoopArrays`).

numba unboxes every array argument of a compiled call on its own (the Python object, its dtype, a
meminfo each): about 35-50 ns per array on a hot cache, several cache misses per array when the call
runs once per 3.9 ms period on caches that other work has cooled (the live step). The arrays whose
identity never changes between calls (the receiver's and the output encoder's tables, the
receiver's state, the limiter's, the output counters: 51 arrays) are therefore held by one
``StructRef``: one object to unbox, its fields read through a pointer inside the compiled code. Unlike
a ``jitclass`` (which held them in an earlier experiment), a ``StructRef`` type is defined at module
level and numba caches the functions that take it.

The struct holds the arrays themselves (references, not copies): stores by the compiled code are
seen from Python and the other way round. A caller that replaces an array (``Engine.reset``) makes
a new :class:`LoopArrays`.
"""

from __future__ import annotations

from typing import Any

from numba import njit
from numba.core import types
from numba.experimental import structref

__all__ = ["LoopArrays", "LoopArraysType", "FIELDS", "loop_arrays"]

#: the fields, in the constructor's order: ``tb`` (lde.engine.receiver.RxTables.kernel_args), ``otab``
#: (lde.engine.engine.OutputTable.args), ``st`` (lde.engine.receiver.RxState.kernel_args), ``prev_t``, ``lp``,
#: ``lsi``, ``lsf``, ``counters``, ``used_since`` (lde.engine.loop's loop arguments of those names)
FIELDS = ("tb", "otab", "rxst", "prev_t", "lp", "lsi", "lsf", "counters", "used_since")


@structref.register
class LoopArraysType(types.StructRef):
    def preprocess_fields(self, fields: Any) -> tuple:
        return tuple((name, types.unliteral(t)) for name, t in fields)


class LoopArrays(structref.StructRefProxy):
    """The loop's fixed arrays (:data:`FIELDS`) as one compiled argument."""


structref.define_proxy(LoopArrays, LoopArraysType, list(FIELDS))


@njit(cache=True)
def _new(tb, otab, rxst, prev_t, lp, lsi, lsf, counters, used_since):  # pragma: no cover - compiled
    return LoopArrays(tb, otab, rxst, prev_t, lp, lsi, lsf, counters, used_since)


def loop_arrays(*arrays: Any) -> LoopArrays:
    """A :class:`LoopArrays` of ``arrays`` (:data:`FIELDS` order), made by a cached compiled
    constructor (the proxy's own constructor would be compiled again in every process)."""
    if len(arrays) != len(FIELDS):
        raise TypeError(f"loop_arrays takes {len(FIELDS)} arguments ({', '.join(FIELDS)}), got {len(arrays)}")
    return _new(*arrays)
