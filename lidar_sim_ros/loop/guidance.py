"""V-bar approach with hold points, driven only by the navigation estimate (never the truth).

Navigation: an alpha-beta filter on the chaser's position relative to the target in LVLH
(m), measured from the pose estimate; it coasts on its velocity when no estimate comes.
Guidance: a state machine over the hold ranges (config ``guidance.hold_ranges_m``, the
chaser behind the target: LVLH y = -range). At a hold point the reference stands still;
once the filtered state is within ``settle_radius_m`` and slower than
``settle_speed_mps`` the dwell clock runs, and after ``hold_time_s`` the reference moves
on toward the next hold at up to ``approach_speed_mps`` (speeding up and slowing down at
``approach_accel_mps2``, so that it stops on the hold). The last hold is kept.

Pure functions over small frozen states: ``(state, inputs) -> (state, outputs)``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from lidar_sim_ros.loop.config import GuidanceConfig


# ---------------------------------------------------------------- navigation
@dataclass(frozen=True)
class NavState:
    """Filtered relative state in LVLH at ``t_s``: position (m), velocity (m/s); None before
    the first measurement."""

    t_s: float | None = None
    rho_m: np.ndarray | None = None
    rho_dot_mps: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return self.rho_m is not None

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The state carried on (constant velocity) to ``t_s``."""
        return self.rho_m + (t_s - self.t_s) * self.rho_dot_mps, self.rho_dot_mps


def nav_update(cfg: GuidanceConfig, nav: NavState, t_s: float, rho_meas_m: np.ndarray) -> NavState:
    """Fold a measured relative position (m, LVLH) at ``t_s`` into the alpha-beta filter."""
    rho_meas = np.asarray(rho_meas_m, float)
    if not nav.valid:
        return NavState(t_s, rho_meas, np.zeros(3))
    dt = t_s - nav.t_s
    if dt <= 0:
        return nav
    predicted, v = nav.at(t_s)
    residual = rho_meas - predicted
    return NavState(t_s, predicted + cfg.filter_alpha * residual, v + (cfg.filter_beta / dt) * residual)


# ------------------------------------------------------------------ guidance
@dataclass(frozen=True)
class GuidanceState:
    """Which hold (index), the phase ('hold' or 'transfer'), the reference along-track
    position (m), when the current hold settled (s, None = not yet), the last time (s)."""

    index: int = 0
    phase: str = 'hold'
    ref_y_m: float | None = None
    ref_speed_mps: float = 0.0
    settled_since_s: float | None = None
    t_s: float | None = None


@dataclass(frozen=True)
class Reference:
    """Where the chaser should be (m), how fast it should move (m/s) and its acceleration
    (m/s^2, the controller's feed-forward), LVLH."""

    rho_m: np.ndarray
    rho_dot_mps: np.ndarray
    phase: str
    index: int
    settled: bool
    rho_ddot_mps2: np.ndarray = field(default_factory=lambda: np.zeros(3))


def guidance_step(cfg: GuidanceConfig, g: GuidanceState, t_s: float, rho_m: np.ndarray,
                  rho_dot_mps: np.ndarray) -> tuple[GuidanceState, Reference]:
    """Advance the approach to ``t_s`` from the estimated relative state (m, m/s, LVLH)."""
    holds = cfg.hold_ranges_m
    if g.ref_y_m is None:
        g = replace(g, ref_y_m=-holds[0], t_s=t_s)
    dt = max(t_s - g.t_s, 0.0)
    hold_y = -holds[g.index]
    speed = accel = 0.0
    if g.phase == 'transfer':
        # A trapezoidal speed profile: up at approach_accel, cruise, down to stop on the hold.
        left = hold_y - g.ref_y_m
        speed = min(g.ref_speed_mps + cfg.approach_accel_mps2 * dt, cfg.approach_speed_mps,
                    float(np.sqrt(2.0 * cfg.approach_accel_mps2 * max(left, 0.0))))
        ref_y = min(g.ref_y_m + speed * dt, hold_y)
        if ref_y >= hold_y - 1e-6:
            g, speed = replace(g, phase='hold', ref_y_m=hold_y, ref_speed_mps=0.0, settled_since_s=None), 0.0
        else:
            accel = (speed - g.ref_speed_mps) / dt if dt > 0 else 0.0
            g = replace(g, ref_y_m=ref_y, ref_speed_mps=speed)
    if g.phase == 'hold':
        near = np.linalg.norm(np.asarray(rho_m) - [0.0, hold_y, 0.0]) < cfg.settle_radius_m
        slow = np.linalg.norm(rho_dot_mps) < cfg.settle_speed_mps
        if g.settled_since_s is None and near and slow:
            g = replace(g, settled_since_s=t_s)
        if (g.settled_since_s is not None and t_s - g.settled_since_s >= cfg.hold_time_s
                and g.index + 1 < len(holds)):
            g = replace(g, index=g.index + 1, phase='transfer', settled_since_s=None)
    g = replace(g, t_s=t_s)
    ref = Reference(np.array([0.0, g.ref_y_m, 0.0]), np.array([0.0, speed, 0.0]), g.phase, g.index,
                    g.phase == 'hold' and g.settled_since_s is not None, np.array([0.0, accel, 0.0]))
    return g, ref
