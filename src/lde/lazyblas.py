"""numba's BLAS check without importing ``scipy.linalg`` (issue 12 item 5: a warm start).

numba's first load of any kernel, cached or not, loads its CPU target's registries, among them
``numba.np.arraymath``, which decides at import whether BLAS is there (``_HAVE_BLAS``, used only
when a kernel calling ``np.dot`` is *compiled*) by importing ``scipy.linalg.cython_blas``, i.e. all
of ``scipy.linalg`` (0.2 s on a quiet machine, 0.4-0.5 s at load 9), whatever the kernels use.

:func:`defer_blas_import` makes that one check find ``scipy.linalg.cython_blas``'s extension module
on disk instead of importing it, and keeps the rest of numba's check (the LP64 / ILP64 width of
scipy's BLAS against numba's build). Nothing else changes: numba's own ``ensure_blas`` is put back
at once, so a kernel compiled later imports scipy as before, and a cached kernel that calls LAPACK
has numba's helper import ``scipy.linalg.cython_lapack`` at its first call. lde's own kernels call
neither BLAS nor LAPACK (scipy is no dependency of lde; where it is installed, this keeps
``scipy.linalg`` out of the process).
"""

from __future__ import annotations

import importlib.util
import os
import sys

__all__ = ["defer_blas_import", "blas_on_disk"]


def blas_on_disk() -> bool:
    """Whether scipy's ``linalg.cython_blas`` extension is installed (found without importing
    scipy: ``find_spec`` of the dotted name would import ``scipy.linalg``)."""
    try:
        spec = importlib.util.find_spec("scipy")
    except (ImportError, ValueError):
        return False
    if spec is None or not spec.submodule_search_locations:
        return False
    for root in spec.submodule_search_locations:
        try:
            names = os.listdir(os.path.join(root, "linalg"))
        except OSError:
            continue
        if any(n.startswith("cython_blas.") and n.endswith((".so", ".pyd")) for n in names):
            return True
    return False


def defer_blas_import() -> bool:
    """Load numba's array registry (``numba.np.arraymath``) with its BLAS check answered from disk
    (the module doc). Call before the first kernel loads; afterwards it does nothing. Returns
    True when the check was answered from disk, False when numba ran (or had run) its own."""
    if "numba.np.arraymath" in sys.modules or not blas_on_disk():
        return False
    import numba  # noqa: F401 - numba's own start-up first, in its order
    import numba.np.linalg as nplinalg

    real = getattr(nplinalg, "ensure_blas", None)
    width_check = getattr(nplinalg, "_check_lapack_int_width", None)
    if real is None or width_check is None:  # another numba (the dependency is not pinned): its own check
        return False

    def ensure_blas_on_disk() -> None:
        width_check()  # reads scipy.__config__ only

    nplinalg.ensure_blas = ensure_blas_on_disk
    try:
        import numba.np.arraymath as arraymath
    finally:
        nplinalg.ensure_blas = real
    if getattr(arraymath, "ensure_blas", None) is ensure_blas_on_disk:
        arraymath.ensure_blas = real  # bound by its `from numba.np.linalg import ensure_blas`
    return bool(getattr(arraymath, "_HAVE_BLAS", False))
