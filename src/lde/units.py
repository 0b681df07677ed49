"""Unit conversions at the DBC boundary. Inside lde everything is SI (rad, rad/s, N, Nm, m/s)."""

from __future__ import annotations

import math

DEG = math.pi / 180.0  # rad per degree
KMH = 1.0 / 3.6  # (m/s) per (km/h)
G = 9.80665  # m/s^2, standard gravity

#: The estimator / frame period: the paper's MDPS sensor computation delay (SPEC section 1).
STEP_NS = 3_900_000  # ns
STEP_S = STEP_NS * 1e-9  # s


def deg2rad(x: float) -> float:
    return x * DEG


def rad2deg(x: float) -> float:
    return x / DEG


def kmh2ms(x: float) -> float:
    return x * KMH


def ms2kmh(x: float) -> float:
    return x / KMH
