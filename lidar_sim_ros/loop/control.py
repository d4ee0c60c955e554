"""Translational control in LVLH: a PD law on the reference with the Clohessy-Wiltshire
accelerations cancelled, a per-axis thrust limit and a dead band.

The CW equations (LVLH: x radial, y along-track, z normal; n the orbit rate) are

    x'' = 3 n^2 x + 2 n y' + a_x,   y'' = -2 n x' + a_y,   z'' = -n^2 z + a_z,

so commanding a = -Kp e - Kd e' + a_ref - (3 n^2 x + 2 n y', -2 n x', -n^2 z) leaves
e'' + Kd e' + Kp e = 0: Kp = w^2, Kd = 2 zeta w (``natural_frequency_rad_s``,
``damping_ratio``).
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.loop.config import ChaserConfig, GuidanceConfig
from lidar_sim_ros.loop.guidance import Reference


def cw_acceleration(rho_m: np.ndarray, rho_dot_mps: np.ndarray, n_rad_s: float) -> np.ndarray:
    """The CW free-motion acceleration (m/s^2) at a relative state (LVLH)."""
    x, _, z = rho_m
    vx, vy, _ = rho_dot_mps
    return np.array([3 * n_rad_s ** 2 * x + 2 * n_rad_s * vy, -2 * n_rad_s * vx, -n_rad_s ** 2 * z])


def pd_force_lvlh(guidance: GuidanceConfig, chaser: ChaserConfig, rho_m: np.ndarray,
                  rho_dot_mps: np.ndarray, ref: Reference, n_rad_s: float) -> np.ndarray:
    """The force (N, LVLH) the PD law asks for, before limits."""
    w, zeta = guidance.natural_frequency_rad_s, guidance.damping_ratio
    e, e_dot = np.asarray(rho_m) - ref.rho_m, np.asarray(rho_dot_mps) - ref.rho_dot_mps
    accel = ref.rho_ddot_mps2 - w * w * e - 2 * zeta * w * e_dot - cw_acceleration(rho_m, rho_dot_mps, n_rad_s)
    return chaser.mass_kg * accel


def limit_force(force_n: np.ndarray, thrust_limit_n: float, dead_band_n: float) -> np.ndarray:
    """Clip each axis to +-thrust_limit_n (N); a command weaker than dead_band_n (norm) is not fired."""
    f = np.clip(np.asarray(force_n, float), -thrust_limit_n, thrust_limit_n)
    return np.zeros(3) if np.linalg.norm(f) < dead_band_n else f


def control_step(guidance: GuidanceConfig, chaser: ChaserConfig, rho_m, rho_dot_mps, ref: Reference,
                 n_rad_s: float) -> np.ndarray:
    """The limited force command (N, LVLH) for one control period."""
    return limit_force(pd_force_lvlh(guidance, chaser, rho_m, rho_dot_mps, ref, n_rad_s),
                       chaser.thrust_limit_n, chaser.dead_band_n)
