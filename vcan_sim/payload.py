"""Payload: mass, yaw inertia and CG of the loaded vehicle (paper section 5, eqs. 17-18).

Added masses sit at named seat positions (``[sim.seats]``, x behind the front axle, y left, z up).
The loaded vehicle's static wheel loads follow from the lever rule; the CG is then recovered from
the wheel loads exactly as the paper does (1 = front left, 2 = front right, 3 = rear left,
4 = rear right, t = tread, L = wheelbase)::

    y = (Fz2 + Fz4) / (Fz1 + Fz2 + Fz3 + Fz4) t        (17)  distance from the left wheels
    x = (Fz3 + Fz4) / (Fz1 + Fz2 + Fz3 + Fz4) L        (18)  distance behind the front axle

so that y_left (ISO, from the centre line) = t/2 - y and lf = x, lr = L - x. The yaw inertia about
the new CG is the parallel-axis sum of the unloaded body and the point masses::

    Iz = Iz0 + m0 |r0 - r_cg|^2 + sum_i m_i |r_i - r_cg|^2          (planar distances)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from lde.errors import ConfigError
from lde.params import Vehicle
from lde.units import G

from .config import Seat, SimParams


@dataclass(frozen=True)
class Payload:
    """Added masses: (seat name, mass [kg]) pairs. Empty = the unloaded reference vehicle."""

    items: tuple[tuple[str, float], ...] = ()
    name: str = "none"

    @property
    def total(self) -> float:
        """Added mass [kg]."""
        return float(sum(m for _, m in self.items))


@dataclass(frozen=True)
class LoadedBody:
    """Mass properties of the loaded vehicle (SI).

    Attributes:
        mass [kg]; yaw_inertia [kg m^2] about the loaded CG; lf, lr [m] (CG to axles);
        y_cg [m] lateral CG offset from the centre line, left positive; cg_height [m];
        dx_ref [m] CG shift forward relative to the unloaded reference CG (negative: moved back);
        dy_ref [m] lateral CG shift relative to the reference CG (left positive);
        wheel_loads: static (Fz1, Fz2, Fz3, Fz4) [N] on level ground (FL, FR, RL, RR).
    """

    mass: float
    yaw_inertia: float
    lf: float
    lr: float
    y_cg: float
    cg_height: float
    dx_ref: float
    dy_ref: float
    wheel_loads: tuple[float, float, float, float]


def static_wheel_loads(
    mass: float, x_behind_front: float, y_left: float, wheelbase: float, tread: float
) -> tuple[float, float, float, float]:
    """Static wheel loads (FL, FR, RL, RR) [N] of a mass at (x behind the front axle, y left) [m]."""
    w = mass * G
    front = w * (wheelbase - x_behind_front) / wheelbase
    rear = w * x_behind_front / wheelbase
    left = (0.5 * tread + y_left) / tread
    return front * left, front * (1.0 - left), rear * left, rear * (1.0 - left)


def cg_from_wheel_loads(fz: Sequence[float], wheelbase: float, tread: float) -> tuple[float, float]:
    """Eqs. (17)-(18): (x behind the front axle [m], y left of the centre line [m]) from wheel loads."""
    f1, f2, f3, f4 = fz
    total = f1 + f2 + f3 + f4
    if total <= 0.0:
        raise ConfigError("wheel loads must sum to a positive value")
    y_from_left = (f2 + f4) / total * tread  # (17)
    x = (f3 + f4) / total * wheelbase  # (18)
    return x, 0.5 * tread - y_from_left


def _seat(sp: SimParams, name: str) -> Seat:
    try:
        return sp.seats[name]
    except KeyError:
        raise ConfigError(f"unknown payload seat {name!r} (known: {', '.join(sorted(sp.seats))})") from None


def loaded_body(vehicle: Vehicle, sp: SimParams, payload: Payload) -> LoadedBody:
    """Mass, inertia and CG of ``vehicle`` carrying ``payload`` (eqs. 17-18 from the wheel loads)."""
    b = vehicle.body
    L = b.wheelbase
    t = 0.5 * (b.track_front + b.track_rear)
    m0, x0, y0, z0 = b.mass, b.lf, 0.0, sp.chassis.cg_height
    masses = [(m0, x0, y0, z0)]
    for seat_name, m in payload.items:
        if not (0.0 < m <= 2000.0):
            raise ConfigError(f"payload mass at {seat_name!r} must lie in (0, 2000] kg, got {m}")
        s = _seat(sp, seat_name)
        masses.append((m, s.x_behind_front_axle, s.y_left, s.z))
    fz = [0.0, 0.0, 0.0, 0.0]
    for m, x, y, _ in masses:
        for i, f in enumerate(static_wheel_loads(m, x, y, L, t)):
            fz[i] += f
    x_cg, y_cg = cg_from_wheel_loads(fz, L, t)
    mass = sum(m for m, *_ in masses)
    z_cg = sum(m * z for m, _, _, z in masses) / mass
    iz = b.yaw_inertia + sum(m * ((x - x_cg) ** 2 + (y - y_cg) ** 2) for m, x, y, _ in masses)
    if not (0.2 < x_cg < L - 0.2):
        raise ConfigError(f"payload puts the CG {x_cg:.2f} m behind the front axle: outside the wheelbase")
    return LoadedBody(
        mass=mass,
        yaw_inertia=iz,
        lf=x_cg,
        lr=L - x_cg,
        y_cg=y_cg,
        cg_height=z_cg,
        dx_ref=-(x_cg - x0),
        dy_ref=y_cg - y0,
        wheel_loads=(fz[0], fz[1], fz[2], fz[3]),
    )


#: Named payload cases (the paper's Fig. 9 range: about 1500-1900 kg with the 1466 kg car).
PAYLOADS: dict[str, Payload] = {
    "none": Payload((), "none"),
    "passenger": Payload((("front_passenger", 75.0),), "passenger"),
    "four_occupants": Payload(
        (("front_passenger", 75.0), ("rear_left", 75.0), ("rear_right", 75.0)), "four_occupants"
    ),
    "trunk": Payload((("trunk", 150.0),), "trunk"),
    "full": Payload(
        (
            ("front_passenger", 80.0),
            ("rear_left", 80.0),
            ("rear_right", 80.0),
            ("rear_middle", 80.0),
            ("trunk", 130.0),
        ),
        "full",
    ),
    "left_side": Payload((("rear_left", 90.0), ("rear_left", 70.0)), "left_side"),
}


def combined(sp: SimParams, scenario_payload: Payload) -> Payload:
    """What the car carries in a run: its own load (``[sim.payload]``) plus the scenario's payload."""
    if not sp.payload:
        return scenario_payload
    name = "car" if scenario_payload.name == "none" else f"car+{scenario_payload.name}"
    return Payload(tuple(sp.payload) + scenario_payload.items, name)


def payload_by_name(name: str) -> Payload:
    try:
        return PAYLOADS[name]
    except KeyError:
        raise ConfigError(f"unknown payload {name!r} (known: {', '.join(PAYLOADS)})") from None
