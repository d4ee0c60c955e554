"""Basilisk dynamics of the chaser and the tumbling target (optional extra ``[loop]``).

Two 6-DOF Basilisk spacecraft share a point-mass Earth (``gravityEffector.GravBodyData``
built directly: Basilisk's ``simIncludeGravBody`` is not imported, because importing it
sends an HTTP request for its support data and its Earth helpers may fetch files; no
spherical harmonics, no ephemeris, no SPICE). The target starts on a circular orbit and
tumbles torque-free about a non-principal axis (Basilisk integrates Euler's equations).
The chaser carries an ``extForceTorque`` effector whose inertial force is written from
Python between chunks (``extForce_N``, read by the spacecraft's integrator at each step:
it acts from the very next integration step whichever order the effector and the
spacecraft are added to the task in; issue 29 found both orders bit-identical, and
``test_relative_motion_matches_clohessy_wiltshire`` checks F t^2 / 2m).

The chaser's attitude is kinematic: the attitude law (``frames.attitude_*``) gives it
each step as an ideal attitude controller would, and it enters only the frame chain and
the force's frame. Basilisk's chaser hub keeps its initial attitude and no rate; as the
force is applied in inertial components, its attitude does not act on the dynamics.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.loop import frames
from lidar_sim_ros.loop.config import LoopConfig

EARTH_MU_M3_S2 = 3.986004415e14   # Basilisk's astroConstants MU_EARTH (km^3/s^2 x 1e9)
EARTH_RADIUS_M = 6378136.6        # Basilisk's REQ_EARTH (km x 1e3)
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class DynamicsState:
    """Inertial states at ``t_s`` (s): positions (m), velocities (m/s), the target's attitude
    R_NT (body -> inertial) and body rate omega_T (rad/s, body frame)."""

    t_s: float
    r_chaser_m: np.ndarray
    v_chaser_mps: np.ndarray
    r_target_m: np.ndarray
    v_target_mps: np.ndarray
    R_NT: np.ndarray
    omega_target_rad_s: np.ndarray

    def relative_lvlh(self) -> tuple[np.ndarray, np.ndarray]:
        """The chaser relative to the target in LVLH: (rho (m), rho_dot (m/s))."""
        return frames.relative_lvlh(self.r_chaser_m, self.v_chaser_mps, self.r_target_m, self.v_target_mps)

    def lvlh(self) -> tuple[np.ndarray, float]:
        return frames.lvlh_basis(self.r_target_m, self.v_target_mps)


def circular_orbit(config: LoopConfig) -> tuple[np.ndarray, np.ndarray]:
    """Inertial position (m) and velocity (m/s) of the target's circular orbit at t = 0."""
    o = config.orbit
    a = EARTH_RADIUS_M + o.altitude_m
    speed = math.sqrt(EARTH_MU_M3_S2 / a)
    rot = Rotation.from_euler('ZXZ', [o.raan_deg, o.inclination_deg, o.arg_latitude_deg], degrees=True)
    return rot.apply([a, 0.0, 0.0]), rot.apply([0.0, speed, 0.0])


def initial_relative_state(config: LoopConfig) -> tuple[np.ndarray, np.ndarray]:
    """The chaser's start in LVLH (m, m/s), dispersed by a generator seeded with config.seed."""
    init = config.initial
    rng = np.random.default_rng([config.seed, 1])  # stream 1: initial-state dispersion
    rho = np.asarray(init.position_m, float) + init.position_sigma_m * rng.standard_normal(3)
    rho_dot = np.asarray(init.velocity_mps, float) + init.velocity_sigma_mps * rng.standard_normal(3)
    return rho, rho_dot


class Dynamics:
    """The Basilisk simulation of both spacecraft, advanced in chunks (``advance_to``).

    ``rho_m``/``rho_dot_mps`` override the configured initial relative state (LVLH).
    """

    def __init__(self, config: LoopConfig, rho_m=None, rho_dot_mps=None, step_s: float | None = None):
        from Basilisk.simulation import extForceTorque, gravityEffector, spacecraft
        from Basilisk.utilities import SimulationBaseClass

        self.config = config
        self.step_ns = round((step_s or 1.0 / config.timing.pose_rate_hz) * NS_PER_S)
        self.sim = SimulationBaseClass.SimBaseClass()
        self.sim.SetProgressBar(False)
        proc = self.sim.CreateNewProcess('loop_dynamics')
        proc.addTask(self.sim.CreateNewTask('loop_task', self.step_ns))

        earth = gravityEffector.GravBodyData()
        earth.planetName = 'earth_planet_data'
        earth.mu = EARTH_MU_M3_S2
        earth.radEquator = EARTH_RADIUS_M
        earth.isCentralBody = True
        self._earth = earth  # keep the SWIG object alive as long as the spacecraft use it

        r_t, v_t = circular_orbit(config)
        if rho_m is None or rho_dot_mps is None:
            rho0, rho_dot0 = initial_relative_state(config)
            rho_m = rho0 if rho_m is None else rho_m
            rho_dot_mps = rho_dot0 if rho_dot_mps is None else rho_dot_mps
        r_c, v_c = frames.inertial_from_lvlh(r_t, v_t, rho_m, rho_dot_mps)
        R_NH, _ = frames.lvlh_basis(r_t, v_t)
        tgt = config.target
        R_NT = R_NH @ Rotation.from_quat(tgt.quat_xyzw_lvlh).as_matrix()
        omega_T = math.radians(tgt.tumble_rate_dps) * frames.unit(tgt.tumble_axis_body)

        self.target = self._spacecraft(spacecraft, 'target', tgt.mass_kg, tgt.inertia_kg_m2,
                                       r_t, v_t, R_NT, omega_T)
        self.chaser = self._spacecraft(spacecraft, 'chaser', config.chaser.mass_kg,
                                       config.chaser.inertia_kg_m2, r_c, v_c, np.eye(3), np.zeros(3))
        self.force = extForceTorque.ExtForceTorque()
        self.force.ModelTag = 'chaser_force'
        self.chaser.addDynamicEffector(self.force)
        # The effector is added first, by habit: with extForce_N written directly (not from
        # an input message) the order does not change the states (issue 29: bit-identical).
        self.sim.AddModelToTask('loop_task', self.force)
        self.sim.AddModelToTask('loop_task', self.chaser)
        self.sim.AddModelToTask('loop_task', self.target)
        # Recorders after the spacecraft: each step's state once it is integrated, so that a
        # control period is one ExecuteSimulation (``advance_sampled``), not one per sample.
        self._rec_chaser = self.chaser.scStateOutMsg.recorder()
        self._rec_target = self.target.scStateOutMsg.recorder()
        self.sim.AddModelToTask('loop_task', self._rec_chaser)
        self.sim.AddModelToTask('loop_task', self._rec_target)
        self.sim.InitializeSimulation()
        self.t_ns = 0

    def _spacecraft(self, spacecraft, tag, mass_kg, inertia, r, v, R_NB, omega_B):
        sc = spacecraft.Spacecraft()
        sc.ModelTag = tag
        sc.hub.mHub = float(mass_kg)
        sc.hub.IHubPntBc_B = [list(map(float, row)) for row in inertia]
        sc.hub.r_CN_NInit = [float(x) for x in r]
        sc.hub.v_CN_NInit = [float(x) for x in v]
        sc.hub.sigma_BNInit = [float(x) for x in Rotation.from_matrix(R_NB).as_mrp()]
        sc.hub.omega_BN_BInit = [float(x) for x in omega_B]
        sc.gravField.gravBodies = spacecraft.GravBodyVector([self._earth])
        return sc

    @property
    def t_s(self) -> float:
        return self.t_ns / NS_PER_S

    def set_force_inertial(self, force_n: np.ndarray) -> None:
        """The force (N, inertial components) on the chaser from now until changed."""
        self.force.extForce_N = [float(x) for x in force_n]

    def advance_to(self, t_s: float) -> DynamicsState:
        """Integrate to ``t_s`` (s, a whole number of integration steps) and return the state."""
        t_ns = round(t_s * NS_PER_S)
        if t_ns <= self.t_ns:
            raise ValueError(f'dynamics: cannot go back from {self.t_s} s to {t_s} s')
        self._run_to(t_ns)
        return self.state()

    def _run_to(self, t_ns: int) -> None:
        self._rec_chaser.clear()
        self._rec_target.clear()
        self.sim.ConfigureStopTime(t_ns)
        self.sim.ExecuteSimulation()
        self.t_ns = t_ns

    def advance_sampled(self, t_s: float) -> dict[str, np.ndarray]:
        """Integrate to ``t_s`` in one chunk; the states now and after every integration step,
        stacked (K + 1 rows): t_s, r_chaser_m, v_chaser_mps, r_target_m, v_target_mps, R_NT.
        The same numbers as ``state()`` after ``advance_to`` each step (bit for bit)."""
        t_ns = round(t_s * NS_PER_S)
        if t_ns <= self.t_ns:
            raise ValueError(f'dynamics: cannot go back from {self.t_s} s to {t_s} s')
        now = self.state()
        t0_ns = self.t_ns
        self._run_to(t_ns)
        c, t = self._rec_chaser, self._rec_target
        times = np.asarray(c.times())
        keep = times > t0_ns  # the very first chunk also records t = 0
        sigma = np.asarray(t.sigma_BN)[keep]
        return {'t_s': np.concatenate([[now.t_s], times[keep] / NS_PER_S]),
                'r_chaser_m': np.vstack([now.r_chaser_m, np.asarray(c.r_BN_N)[keep]]),
                'v_chaser_mps': np.vstack([now.v_chaser_mps, np.asarray(c.v_BN_N)[keep]]),
                'r_target_m': np.vstack([now.r_target_m, np.asarray(t.r_BN_N)[keep]]),
                'v_target_mps': np.vstack([now.v_target_mps, np.asarray(t.v_BN_N)[keep]]),
                'R_NT': np.concatenate([now.R_NT[None], Rotation.from_mrp(sigma).as_matrix()])}

    def state(self) -> DynamicsState:
        c, t = self.chaser.scStateOutMsg.read(), self.target.scStateOutMsg.read()
        return DynamicsState(self.t_s, np.array(c.r_BN_N), np.array(c.v_BN_N), np.array(t.r_BN_N),
                             np.array(t.v_BN_N), frames.rotation_from_mrp(t.sigma_BN),
                             np.array(t.omega_BN_B))
