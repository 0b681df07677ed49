"""The estimator backends: one module each, one registration line each, one registry that fails loudly.

===========  ======================================================================================
``fixed``    :mod:`.fixed`: the lateral filter in integers (the firmware model,
             :mod:`firmware_model.lateral`), its float step on the same parameters as a shadow at every
             step (a deviation beyond 5 N / 2 Nm sets ``SHADOW_DEVIATION`` and is counted), and the
             learner, whose pushes re-quantise the integer coefficient set. The default.
``float``    :mod:`.float`: the lateral filter (:mod:`lde.estimator.lateral`) with the lateral
             acceleration (wind apart from bank) and online learning (:mod:`lde.estimator.learner`).
``paper``    :mod:`.paper`: the paper's float Kalman step (:mod:`lde.estimator.paper`), with the
             vehicle file's input corrections: the seed's reference.
===========  ======================================================================================

**The protocol** (:class:`BackendModule`). A backend module declares

- ``Params`` and ``State``: NamedTuples of numpy arrays (units in their field comments): what the
  step reads, and what it changes. They are made by ``make(vehicle, dt, angle_above_torsion_bar,
  torque_scale)`` (``torque_scale``: which torque's scale a learning backend learns,
  :func:`lde.estimator.learner.torque_scale_mode`; 0: both in Nm) and owned by the engine; the
  compiled loop (:mod:`lde.engine.loop`) passes them to the step.
- ``step(params, state, t_ns, inputs, fresh, mdps_ok, esc_ok, out) -> status``: the compiled step
  (:func:`lde.engine.loop.backend_step` says what the arguments are; ``out`` is a row of
  :mod:`lde.estimator.outputs`).
- ``NAME``, ``DESCRIPTION``, ``LEARNS`` (and ``SMOOTHABLE``: ``lde replay --smooth`` may stand the
  smoothed float lateral filter beside it). A backend that learns has the filter's parameter vector
  ``p`` and the learner's state ``ls`` in its ``State`` and the learner's parameters ``lp`` in its
  ``Params`` (:class:`lde.engine.engine.Engine` loads and saves them: ``--learned``); it may define
  ``params_changed(params, state)``, called after ``p`` was changed from outside (a learned file).

:func:`register` adds a module: the loop gets its step for its ``State`` class (numba compiles one
loop per backend), the registry its name. Removed names raise :class:`lde.errors.ConfigError`
naming the replacement (:data:`REMOVED`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from lde.engine.loop import register_step
from lde.errors import ConfigError
from lde.params import Vehicle
from lde.units import STEP_S

__all__ = [
    "Backend",
    "BackendModule",
    "BackendState",
    "BACKENDS",
    "DEFAULT_BACKEND",
    "REMOVED",
    "backend_names",
    "get_backend",
    "make_backend_state",
    "register",
]


class BackendModule(Protocol):
    """What a backend module defines (module docstring)."""

    NAME: str
    DESCRIPTION: str
    LEARNS: bool
    Params: type
    State: type
    step: Any  # the compiled step

    def make(
        self, vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool, torque_scale: int = 0
    ) -> tuple[Any, Any]: ...


@dataclass(frozen=True)
class Backend:
    """One registered backend (made from its module by :func:`register`)."""

    name: str
    description: str
    make: Callable[[Vehicle, float, bool, int], tuple[Any, Any]]  # (vehicle, dt, above bar, torque_scale)
    state_class: type
    learns: bool = False
    smoothable: bool = False  # the smoother's float lateral filter can stand beside it (--smooth)
    params_changed: Callable[[Any, Any], None] | None = None


@dataclass
class BackendState:
    """A backend's ``Params`` and ``State`` for one engine (:func:`make_backend_state`)."""

    backend: Backend
    params: Any
    state: Any

    def params_changed(self) -> None:
        """The parameter vector ``state.p`` was changed from outside (a learned-state file was
        loaded): a backend that derives constants from it re-derives them."""
        if self.backend.params_changed is not None:
            self.backend.params_changed(self.params, self.state)


BACKENDS: dict[str, Backend] = {}

#: removed backend names -> what to use instead
REMOVED: dict[str, str] = {
    "lateral": "float (the lateral filter in float)",
    "paper-fixed": "fixed (the firmware model, of the lateral filter) or paper (the paper's filter in float)",
}

#: the backend of every command without ``--backend``
DEFAULT_BACKEND = "fixed"


def register(module: Any) -> Backend:
    """Add a backend module (:class:`BackendModule`) to the registry and its step to the loop."""
    b = Backend(
        module.NAME,
        module.DESCRIPTION,
        module.make,
        module.State,
        module.LEARNS,
        getattr(module, "SMOOTHABLE", False),
        getattr(module, "params_changed", None),
    )
    if b.name in BACKENDS:
        raise ValueError(f"backend {b.name!r} registered twice")
    register_step(module.State, module.step)
    BACKENDS[b.name] = b
    return b


def backend_names() -> tuple[str, ...]:
    return tuple(BACKENDS)


def get_backend(name: str) -> Backend:
    """The backend registered under ``name``; ConfigError otherwise (no fallback), naming the
    replacement of a removed name."""
    try:
        return BACKENDS[name]
    except KeyError:
        if name in REMOVED:
            raise ConfigError(f"backend {name!r} was removed: use {REMOVED[name]}") from None
        raise ConfigError(f"unknown backend {name!r}: choose one of {', '.join(BACKENDS)}") from None


def make_backend_state(
    name: str,
    vehicle: Vehicle,
    dt: float = STEP_S,
    angle_above_torsion_bar: bool = False,
    torque_scale: int = 0,
) -> BackendState:
    """:func:`get_backend` and its ``Params`` and ``State`` for ``vehicle``; ``torque_scale``
    (:func:`lde.estimator.learner.torque_scale_mode`) only for a backend that learns."""
    b = get_backend(name)
    if torque_scale and not b.learns:
        raise ConfigError(
            f"backend {name!r} does not learn: a profile with a torque of unknown scale needs a learning "
            "backend (fixed or float)"
        )
    params, state = b.make(vehicle, dt, angle_above_torsion_bar, torque_scale)
    return BackendState(b, params, state)


# one line per backend (the modules import this one's names above: registered after them)
from lde.engine.backends import fixed, paper  # noqa: E402
from lde.engine.backends import float as float_backend  # noqa: E402

register(fixed)
register(float_backend)
register(paper)
