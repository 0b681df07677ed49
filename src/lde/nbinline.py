"""numba's IR inlining of ``inline="always"`` callees without its two redundant deep copies.

For every call site of a ``@njit(inline="always")`` function numba builds the callee's IR afresh
(``InlineWorker.inline_function`` runs the untyped front end on its bytecode), then
``InlineWorker.inline_ir`` deep-copies that IR block by block twice: once to have a copy to change,
once to return an unchanged one, which the only caller (the ``InlineInlinables`` pass) discards. The
IR was made for this call site alone, so neither copy protects anything; ``copy.deepcopy`` of numba
IR is slow (each block copies its scope and every variable), and it was about a third of the first
compile of the data path's per-frame and per-step parts (docs/startup.md). numba issue #8989 and the
numba-cuda change #689 describe the same copies.

:func:`install` makes ``inline_function`` call ``inline_ir`` with those block copies turned into the
identity. The IR handed to the caller is the same (the copies were equal to it), so the compiled
code and numba's cache entries are unchanged; numba compiles under its global compile lock, so no
other compilation sees the switch. Other users of ``inline_ir`` (numba's overload inliner, which
reuses IR) keep the copies.
"""

from __future__ import annotations

import copy
import types
from typing import Any

__all__ = ["install", "installed"]

_ORIGINAL: Any = None


def installed() -> bool:
    """Whether :func:`install` has replaced numba's ``InlineWorker.inline_function``."""
    return _ORIGINAL is not None


def install() -> None:
    """Inline without the redundant copies (module docstring); idempotent. Leaves numba as it is
    when its inliner is not the one this was written for (numba 0.59-0.68: a module-level ``copy``
    and ``inline_function(caller_ir, block, i, function, arg_typs=None)``)."""
    global _ORIGINAL
    if _ORIGINAL is not None:
        return
    from numba.core import inline_closurecall

    ic: Any = inline_closurecall  # its ``copy`` and a method are replaced: not the module's types

    original = getattr(ic.InlineWorker, "inline_function", None)
    if original is None or getattr(ic, "copy", None) is not copy or not hasattr(ic.InlineWorker, "inline_ir"):
        return  # another inliner than the one this was written for
    no_copy = types.SimpleNamespace(deepcopy=lambda x, memo=None: x, copy=copy.copy)

    def inline_function(
        self: Any, caller_ir: Any, block: Any, i: Any, function: Any, arg_typs: Any = None
    ) -> Any:
        callee_ir = self.run_untyped_passes(function)  # fresh for this call site: nothing to protect
        freevars = function.__code__.co_freevars
        ic.copy = no_copy
        try:
            return self.inline_ir(caller_ir, block, i, callee_ir, freevars, arg_typs=arg_typs)
        finally:
            ic.copy = copy

    ic.InlineWorker.inline_function = inline_function
    _ORIGINAL = original
