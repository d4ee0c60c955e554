"""A constant pose rotation about the tumble axis read as a clock offset.

On a target tumbling at a constant rate about a fixed axis, a clock offset dt between
the pose and LiDAR stamps turns the recorded attitude by the spin over dt, the same in
every cloud: one rigid rotation about the tumble axis, which a constant correction of
the reference pose takes as well (``pose_error``; a clock offset evaluates the pose at
t + dt, so its rotation is exp(w dt) in the lidar frame, w the spatial angular
velocity). ``clock_equivalent`` says which clock offset a correction's rotation is, and
whether the rotation lies along the spin closely enough to be one; it decides nothing
(the verdict says it where a constant pose is reported). Angles in deg, rates in
deg/s, times in s.
"""
from __future__ import annotations

import numpy as np

MIN_ALIGNMENT = 0.95        # cos of the angle between the rotation and the spin axis
MIN_ROTATION_DEG = 0.05     # smaller rotations say nothing of a clock
MIN_RATE_DPS = 1.0          # slower tumbles: a clock moves the target by too little
MAX_RATE_CHANGE = 0.1       # the spin's rate and axis the same in both halves, to 10 %


def clock_equivalent(rotation_deg: np.ndarray, spin_halves_dps: np.ndarray) -> dict | None:
    """The clock offset a constant rotation of the reference pose is on a constant spin.

    ``rotation_deg`` (3,) or (C, 3): the correction's rotation vector(s) in the lidar
    frame (their mean is taken); ``spin_halves_dps`` (2, 3): the spatial angular velocity
    over the recording's first and second half. None where the spin is too slow or
    changes between the halves (a clock is then no constant rotation), or the rotation
    is too small; else {'dt_s': rotation . w / |w|^2, 'alignment': cos of the angle
    between them, 'tumble_rate_dps', 'rotation_deg', 'shown': alignment >=
    MIN_ALIGNMENT}."""
    rot = np.asarray(rotation_deg, float).reshape(-1, 3).mean(axis=0)
    angle = float(np.linalg.norm(rot))
    if not fixed_spin(spin_halves_dps) or not np.isfinite(angle) or angle < MIN_ROTATION_DEG:
        return None
    w = np.asarray(spin_halves_dps, float).reshape(2, 3).mean(axis=0)
    rate = float(np.linalg.norm(w))
    alignment = float(rot @ w / (angle * rate))
    return {'dt_s': round(float(rot @ w / rate ** 2), 5), 'alignment': round(alignment, 4),
            'tumble_rate_dps': round(rate, 3), 'rotation_deg': round(angle, 4),
            'shown': bool(alignment >= MIN_ALIGNMENT)}


def fixed_spin(spin_halves_dps: np.ndarray) -> bool:
    """Whether the target spins at a constant rate about a fixed axis: ``spin_halves_dps``
    (2, 3), the spatial angular velocity over the recording's two halves, at least
    MIN_RATE_DPS and the same in both to MAX_RATE_CHANGE of the rate (a clock offset is
    then one rotation of the pose about that axis)."""
    halves = np.asarray(spin_halves_dps, float).reshape(2, 3)
    rate = float(np.linalg.norm(halves.mean(axis=0)))
    return bool(np.all(np.isfinite(halves)) and rate >= MIN_RATE_DPS
                and np.linalg.norm(halves[0] - halves[1]) <= MAX_RATE_CHANGE * rate)


def words(figures: dict) -> str:
    """The verdict's sentence where ``figures['shown']``."""
    return (f'Its rotation ({figures["rotation_deg"]:.2f} deg) lies along the tumble axis, '
            f'as a clock offset of {1000 * figures["dt_s"]:+.1f} ms between the pose and '
            f'LiDAR stamps turns the target at the recorded {figures["tumble_rate_dps"]:.1f} '
            'deg/s: on a tumble at a constant rate about a fixed axis the two turn it alike, '
            'so that part of the correction may be the stamps\' (a recording at another '
            'tumble rate separates them; if the tracking system\'s attitude is known to be '
            'right, try --effect time_offset --fit).')
