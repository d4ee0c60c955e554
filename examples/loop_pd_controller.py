"""A PD controller for the closed loop (docs/loop.md, "Your own GNC in process"): the
built-in law written out, to start your own from. In the loop config:

    gnc:
      controller: loop_pd_controller.py:make_controller   # beside the config, or an absolute path
"""
import numpy as np


def make_controller(config):
    """Called once per run with the LoopConfig; returns the control law."""
    w = config.guidance.natural_frequency_rad_s       # closed-loop bandwidth (rad/s)
    zeta = config.guidance.damping_ratio
    mass_kg = config.chaser.mass_kg

    def control(t_s, rho_m, rho_dot_mps, reference, n_rad_s):
        """Force (N, LVLH) for the next period: PD on the reference, its feed-forward
        acceleration, and the Clohessy-Wiltshire free motion cancelled."""
        e = rho_m - reference.rho_m
        e_dot = rho_dot_mps - reference.rho_dot_mps
        x, _, z = rho_m
        vx, vy, _ = rho_dot_mps
        cw = np.array([3 * n_rad_s ** 2 * x + 2 * n_rad_s * vy, -2 * n_rad_s * vx, -n_rad_s ** 2 * z])
        accel = reference.rho_ddot_mps2 - w * w * e - 2 * zeta * w * e_dot - cw
        return mass_kg * accel

    return control
