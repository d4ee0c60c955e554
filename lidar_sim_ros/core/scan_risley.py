"""Risley-prism scan (the Livox Mid-40's rosette): two wedge prisms turning at their own rates.

A thin wedge of index n and apex angle alpha deviates a ray by delta = (n - 1) alpha
toward its thick end; turning the wedge turns the deviation with it. Two wedges in
series, at angles phi_1(t) = phase_1 + 2 pi f_1 t and phi_2(t) = phase_2 + 2 pi f_2 t,
add their deviations as two-dimensional vectors (first order in the deviations):

    p(t) = delta_1 (cos phi_1, sin phi_1) + delta_2 (cos phi_2, sin phi_2)   (rad)

and the beam leaves at an angle |p| off the boresight (+x), toward arg p about it
(0: +y, left; pi/2: +z, up). |p| never exceeds delta_1 + delta_2: the field is a
circle of that half-angle (the Mid-40's 38.4 deg field: 9.6 deg per prism).

Why first order, not an exact Snell trace through both wedges: the Mid-40's wedge
angles, glass and prism spacing are not published, so an exact trace would rest on
invented numbers; what is published (the circular field, the point rate) and what the
pattern's shape depends on (the prism rates: period and petals) the first-order form
reproduces exactly: the exact trace is periodic in both prism angles too, so the period
and the petals are the same, and with both wedges in line the beam is on a circle by
symmetry (whose radius the published 38.4 deg fixes either way). Inside the circle the
exact trace moves shots by up to several per cent of the radius (one n = 1.5 wedge of
19.2 deg deviates 10.4 deg at normal incidence where the first order gives 9.6 deg); Brazeal et al. (Sensors 21(14) 4722, 2021) fit the exact model
to Mid-40 data.

The rosette: |p|^2 = delta_1^2 + delta_2^2 + 2 delta_1 delta_2 cos(phi_1 - phi_2), so
the beam reaches the rim (a petal's tip) |f_1 - f_2| times a second. With rates in a
ratio of whole numbers the pattern closes after T = 1 / gcd(f_1, f_2) with
|f_1 - f_2| T petals; the Mid-40's rates have no such small ratio, so the pattern does
not repeat and the field fills as the integration time grows. Each frame therefore
has its own shots: frame k starts at k x frame period on the prisms' clock (its start's
turns taken in exact arithmetic, so frame k's shots are as precise at a wall-clock k as
at k = 0).
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from lidar_sim_ros.core.config import RisleyScan
from lidar_sim_ros.core.shots import Shots, angles_from_directions

# Prism rates are rounded to this many decimals for the closed-form period (rev/s).
_RATE_DECIMALS = 6


def shots_per_frame(cfg: RisleyScan, frame_period_s: float) -> int:
    """Whole shots of the laser in one frame (the last shot starts before the frame ends)."""
    return int(np.floor(cfg.shot_rate_hz * frame_period_s + 1e-9))


def field_half_angle_rad(cfg: RisleyScan) -> float:
    """Half-angle (rad) of the circular field: the two deviations in line."""
    return float(np.radians(sum(cfg.prism_deviation_deg)))


def prism_angles_rad(cfg: RisleyScan, t_s: np.ndarray,
                     start_turns: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Each prism's rotation angle (rad) at ``t_s`` (s) after a start where the prisms
    had turned ``start_turns`` (revolutions, ``frame_start_turns``) on the prisms' clock."""
    t = np.asarray(t_s, dtype=float)
    (f1, f2), (p1, p2), (s1, s2) = cfg.prism_rates_hz, cfg.prism_phase_rad, start_turns
    return p1 + 2.0 * np.pi * (s1 + f1 * t), p2 + 2.0 * np.pi * (s2 + f2 * t)


def frame_start_turns(cfg: RisleyScan, frame_index: int,
                      frame_period_s: float) -> tuple[float, float]:
    """Each prism's turns at frame ``frame_index``'s start (k x period on the prisms'
    clock), modulo whole turns, in exact arithmetic: the node's frames are numbered on the
    wall clock (k ~ 1.8e10 at 10 Hz), where 2 pi f k T in float64 (1e12 rad) is only good to
    ~1e-4 rad and k T + t to 2.4e-7 s: every shot's direction was off by up to ~1e-4 rad."""
    k = Fraction(int(frame_index)) * Fraction(frame_period_s)
    return tuple(float((Fraction(f) * k) % 1) for f in cfg.prism_rates_hz)


def deviation_rad(cfg: RisleyScan, phi1_rad: np.ndarray,
                  phi2_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The summed first-order deviation p (rad, two components: toward +y, toward +z)."""
    d1, d2 = np.radians(cfg.prism_deviation_deg)
    return (d1 * np.cos(phi1_rad) + d2 * np.cos(phi2_rad),
            d1 * np.sin(phi1_rad) + d2 * np.sin(phi2_rad))


def directions_from_deviation(py_rad: np.ndarray, pz_rad: np.ndarray) -> np.ndarray:
    """Unit beam directions (N, 3), lidar frame: |p| off +x, toward arg p about it."""
    theta = np.hypot(py_rad, pz_rad)
    psi = np.arctan2(pz_rad, py_rad)
    sin_t = np.sin(theta)
    return np.stack([np.cos(theta), sin_t * np.cos(psi), sin_t * np.sin(psi)], axis=-1)


def risley_shots(cfg: RisleyScan, frame_period_s: float, frame_index: int = 0) -> Shots:
    """One frame's shots: the laser fires every 1 / shot_rate_hz from the frame start
    (frame_index x frame_period_s on the prisms' clock); laser id 0."""
    return risley_frame(cfg, frame_period_s, frame_index)[0]


def risley_frame(cfg: RisleyScan, frame_period_s: float,
                 frame_index: int = 0) -> tuple[Shots, np.ndarray]:
    """``risley_shots`` and the shots' unit directions (N, 3), computed once."""
    n = shots_per_frame(cfg, frame_period_s)
    t = np.arange(n) / cfg.shot_rate_hz
    phi1, phi2 = prism_angles_rad(cfg, t, frame_start_turns(cfg, frame_index, frame_period_s))
    directions = directions_from_deviation(*deviation_rad(cfg, phi1, phi2))
    az, el = angles_from_directions(directions)
    return Shots(t, az, el, np.zeros(n, np.uint16)), directions


def rosette_period_s(rates_hz: tuple[float, float]) -> float:
    """T = 1 / gcd(f_1, f_2) (s), rates read to 1e-6 rev/s: when both prisms are back
    where they started together (a long time for rates with no small ratio)."""
    f1, f2 = (Fraction(round(abs(f) * 10 ** _RATE_DECIMALS), 10 ** _RATE_DECIMALS)
              for f in rates_hz)
    g = Fraction(math.gcd(f1.numerator * f2.denominator, f2.numerator * f1.denominator),
                 f1.denominator * f2.denominator)
    return float(1 / g)


def petals_per_period(rates_hz: tuple[float, float]) -> int:
    """Petal tips (the beam on the field's rim) in one period: |f_1 - f_2| T."""
    f1, f2 = rates_hz
    return int(round(abs(f1 - f2) * rosette_period_s(rates_hz)))



def field_coverage(cfg: RisleyScan, integration_s: float, cell_rad: float) -> float:
    """Share (-) of the circular field's cells (square cells of side ``cell_rad`` on the
    deviation plane, centres inside the circle) that at least one shot falls in during the
    first ``integration_s`` seconds: how the non-repeating rosette fills its field."""
    n = int(np.floor(cfg.shot_rate_hz * integration_s + 1e-9))
    t = np.arange(n) / cfg.shot_rate_hz
    py, pz = deviation_rad(cfg, *prism_angles_rad(cfg, t))
    half = field_half_angle_rad(cfg)
    cells = int(np.ceil(2 * half / cell_rad))
    i = np.clip(((py + half) / cell_rad).astype(np.int64), 0, cells - 1)
    j = np.clip(((pz + half) / cell_rad).astype(np.int64), 0, cells - 1)
    seen = np.zeros((cells, cells), bool)
    seen[i, j] = True
    centre = (np.arange(cells) + 0.5) * cell_rad - half
    inside = np.hypot(*np.meshgrid(centre, centre, indexing='ij')) <= half
    return float(seen[inside].mean())
