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

:func:`field` reads a field in a kernel compiled without reference counting (:mod:`lde.refcount`),
where numba's own attribute access is refused ("NRT required"): the per-frame and per-step parts of
the loop take the struct (one pointer) instead of its arrays (by value: 26-39 arrays, 1.7-2.5 kB
copied onto the stack per call).
"""

from __future__ import annotations

from typing import Any

from llvmlite import ir
from numba import njit
from numba.core import cgutils, types
from numba.experimental import structref
from numba.extending import intrinsic

__all__ = ["LoopArrays", "LoopArraysType", "FIELDS", "loop_arrays", "field"]

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


#: numba's ``NRT_MemInfo`` header (numba/core/runtime/nrtdynmod.py, ``_meminfo_struct_type``):
#: refcount, destructor, its argument, data pointer, size; the data pointer is field 3
_MEMINFO = ir.LiteralStructType(
    [cgutils.intp_t, cgutils.voidptr_t, cgutils.voidptr_t, cgutils.voidptr_t, cgutils.intp_t]
)


@intrinsic
def field(typingctx: Any, la: Any, name: Any) -> Any:
    """``field(la, "tb")``: the field of a :class:`LoopArrays`, readable in a kernel without reference
    counting. The struct's data pointer is read from its meminfo header as numba's own
    ``NRT_MemInfo_data_fast`` does (which a kernel without NRT may not call); the field is a
    borrowed reference there (the caller holds the struct), a new one where NRT is on."""
    if not isinstance(la, LoopArraysType) or not isinstance(name, types.StringLiteral):
        return None
    attr = name.literal_value
    if attr not in la.field_dict:
        return None
    ftype = la.field_dict[attr]

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        ref = cgutils.create_struct_proxy(sig.args[0])(context, builder, value=args[0])
        header = builder.bitcast(ref.meminfo, _MEMINFO.as_pointer())
        data = builder.load(cgutils.gep_inbounds(builder, header, 0, 3))
        dtype = sig.args[0].get_data_type()
        alloc = context.data_model_manager[dtype].get_value_type()
        data = builder.bitcast(data, alloc.as_pointer())
        value = getattr(cgutils.create_struct_proxy(dtype)(context, builder, ref=data), attr)
        if context.enable_nrt:
            context.nrt.incref(builder, ftype, value)
        return value

    return ftype(la, name), codegen
