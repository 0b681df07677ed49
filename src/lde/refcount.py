"""Kernels compiled without numba's reference counting (issue 12, replay speed).

numba counts references to every array a compiled function passes on, unpacks from a tuple or slices,
with atomic increments and decrements (``NRT_incref`` / ``NRT_decref``); its pruning pass removes the
pairs within a basic block, not those split across the branches of saturating arithmetic or status
checks. In the fixed backend's integer lateral step they were about a fifth of the step's CPU samples
(perf). A kernel that allocates nothing and returns no array needs none of them: numba's ``_nrt=False``
option (private; what its maintainers advise for this, numba issues #2345 and #2350) compiles it
without. Such a kernel may still call kernels that allocate (they keep their own counting); one that
allocates itself fails to compile, loudly.
"""

from __future__ import annotations

from typing import Any

from lde.nbinline import install

# every module with kernels of lde and the firmware model imports this one before it compiles: the
# IR inliner without its redundant copies (lde.nbinline) is in place for all their compilations
install()

#: ``@njit(cache=True, **NO_REFCOUNT)``: a kernel that allocates no array (module docstring)
NO_REFCOUNT: dict[str, Any] = {"_nrt": False}
