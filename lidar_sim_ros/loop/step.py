"""The closed loop, one control period at a time, in one process (no DDS).

``loop_step(ctx, state) -> (state, StepOutput)`` reads as the loop it closes:

    propagate   Basilisk over the period under the last force command, sampling the truth
                (the target pose in the lidar frame, the sun there, the relative state)
    sense       the core Simulator's frame over the period: the full error model's cloud
                (``cloud='model'``) or the noise-free one (``'truth'``)
    estimate    the pose tracker on the cloud (``PoseTracker``); ``cloud=None`` feeds the
                true pose instead (tests of guidance and control alone)
    navigate    the estimate -> the chaser's relative position in LVLH -> alpha-beta filter
    guide       the V-bar hold-point state machine (estimate only)
    control     PD + CW cancellation, thrust limit, dead band -> force (LVLH) for the next period

The Basilisk simulation, the simulator and the tracker are handles held by the context
and state and advanced in place; everything else is passed in and returned. The ROS
nodes (``loop.dynamics_node``, ``loop.controller_node``) call the same stage functions.

``run_loop(config, cloud)`` runs a whole approach and returns its ``LoopResult``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.loop import frames
from lidar_sim_ros.loop.config import LoopConfig
from lidar_sim_ros.loop.control import control_step, limit_force
from lidar_sim_ros.loop.guidance import GuidanceState, NavState, Reference, guidance_step, nav_update


# --------------------------------------------------------------- the truth
@dataclass(frozen=True)
class TruthSamples:
    """Truth at K sample times t_s (K,) over one period (both ends included): the target
    pose in the lidar frame (R_LT (K, 3, 3), t_L (K, 3) m), the sun in the lidar frame
    (K, 3), the chaser's attitude in LVLH R_HB (K, 3, 3), the relative state rho (K, 3) m,
    rho_dot (K, 3) m/s, the LVLH rate n (rad/s), and whether the chaser is in the Earth's
    shadow (K,) (all False with ``sun.eclipse`` off)."""

    t_s: np.ndarray
    R_LT: np.ndarray
    t_L_m: np.ndarray
    sun_lidar: np.ndarray
    R_HB: np.ndarray
    rho_m: np.ndarray
    rho_dot_mps: np.ndarray
    n_rad_s: float
    eclipsed: np.ndarray

    @property
    def dark(self) -> bool:
        """Whether the period is in the Earth's shadow: at its middle sample (a period is
        0.1 s, a frame is lit or dark as a whole)."""
        return bool(self.eclipsed[len(self.eclipsed) // 2])

    def pose_track(self, previous: 'TruthSamples | None' = None, extrapolation_s: float = 0.0):
        """These samples (after ``previous``'s) as a core ``PoseTrack`` for the simulator."""
        from lidar_sim_ros.core.pose import PoseTrack
        t, R, p = self.t_s, self.R_LT, self.t_L_m
        if previous is not None:
            keep = previous.t_s < t[0]
            t = np.concatenate([previous.t_s[keep], t])
            R = np.concatenate([previous.R_LT[keep], R])
            p = np.concatenate([previous.t_L_m[keep], p])
        return PoseTrack(t, p, Rotation.from_matrix(R).as_quat(), max_extrapolation_s=extrapolation_s)


def chaser_attitude(config: LoopConfig, r_chaser, r_target, R_NH, R_BL, t_B) -> np.ndarray:
    """R_NB from the configured attitude law (kinematic: an ideal attitude controller)."""
    if config.chaser.attitude_law == 'hold_lvlh':
        return frames.attitude_hold_lvlh(R_NH)
    return frames.attitude_point_at_target(r_chaser, r_target, R_NH, R_BL, t_B)


def sample_truth(config: LoopConfig, s, R_BL, t_B) -> dict:
    """The truth of one dynamics state ``s`` (``DynamicsState``) as a dict of arrays."""
    R_NH, n = s.lvlh()
    R_NB = chaser_attitude(config, s.r_chaser_m, s.r_target_m, R_NH, R_BL, t_B)
    R_LT, t_L = frames.target_in_lidar(s.r_chaser_m, R_NB, R_BL, t_B, s.r_target_m, s.R_NT)
    rho, rho_dot = s.relative_lvlh()
    return {'t_s': s.t_s, 'R_LT': R_LT, 't_L_m': t_L,
            'sun_lidar': frames.sun_in_lidar(np.asarray(config.sun.direction_inertial), R_NB, R_BL),
            'R_HB': R_NH.T @ R_NB, 'rho_m': rho, 'rho_dot_mps': rho_dot, 'n_rad_s': n,
            'R_NH': R_NH}


def propagate(config: LoopConfig, dynamics, force_lvlh_n: np.ndarray, R_BL, t_B) -> TruthSamples:
    """Advance the dynamics one control period under ``force_lvlh_n`` (N, LVLH, turned to
    inertial at the period start and held), sampling the truth at every sub-step."""
    R_NH0, _ = dynamics.state().lvlh()
    dynamics.set_force_inertial(R_NH0 @ force_lvlh_n)
    states = dynamics.advance_sampled(dynamics.t_s + config.control_period_s)
    # The samples: every ``substeps``-th of the period (a finer integration step keeps fewer).
    since_ns = np.round((states['t_s'] - states['t_s'][0]) * 1e9).astype(np.int64)
    keep = since_ns % round(config.control_period_s * 1e9 / config.substeps) == 0
    if keep.sum() != config.substeps + 1:
        raise ValueError(f'dynamics: integration step {dynamics.step_ns} ns does not divide the '
                         f'pose sample period ({config.substeps} per {config.control_period_s} s; samples at '
                         f'{np.round(states["t_s"], 4).tolist()} s)')
    return truth_of_states(config, {k: v[keep] for k, v in states.items()}, R_BL, t_B)


def truth_of_states(config: LoopConfig, states: dict, R_BL, t_B) -> TruthSamples:
    """``sample_truth`` of K dynamics states (``Dynamics.advance_sampled``) at once (the same
    numbers to ~1e-15)."""
    r_c, v_c, r_t, v_t = (states[k] for k in ('r_chaser_m', 'v_chaser_mps', 'r_target_m', 'v_target_mps'))
    R_NT = states['R_NT']
    R_NH, n = frames.lvlh_basis_k(r_t, v_t)
    if config.chaser.attitude_law == 'hold_lvlh':
        R_NB = frames.frame_from_axes_k(R_NH[:, :, 1], R_NH[:, :, 0])
    else:
        R_NB = frames.attitude_point_at_target_k(r_c, r_t, R_NH, R_BL, t_B)
    R_NL = R_NB @ R_BL
    R_LN = np.swapaxes(R_NL, 1, 2)
    R_HN = np.swapaxes(R_NH, 1, 2)
    origin = r_c + R_NB @ t_B
    rho = np.einsum('kij,kj->ki', R_HN, r_c - r_t)
    w = np.zeros_like(rho)
    w[:, 2] = n
    rho_dot = np.einsum('kij,kj->ki', R_HN, v_c - v_t) - np.cross(w, rho)
    sun_n = np.asarray(config.sun.direction_inertial, float)
    eclipsed = (frames.in_earth_shadow(r_c, sun_n) if config.sun.eclipse
                else np.zeros(len(r_c), dtype=bool))
    return TruthSamples(
        t_s=states['t_s'], R_LT=R_LN @ R_NT, t_L_m=np.einsum('kij,kj->ki', R_LN, r_t - origin),
        sun_lidar=frames.unit(R_LN @ frames.unit(sun_n)),
        R_HB=R_HN @ R_NB, rho_m=rho, rho_dot_mps=rho_dot, n_rad_s=float(n[0]), eclipsed=eclipsed)


# ------------------------------------------------------------ sense, estimate
def sense(simulator, truth: TruthSamples, previous: TruthSamples | None, frame_index: int,
          cloud: str, sun_config=None) -> np.ndarray:
    """The cloud (N, 3) m, lidar frame, of the frame over ``truth``'s period.

    ``sun_config``: the scenario's sun (None: none), held at the period's first direction
    over the frame, as ``loop_dynamics`` publishes it once a period (the sun turns ~1e-4
    rad in the lidar frame over a period; interpolating it per shot cost 0.5 ms a frame);
    none while the chaser is in the Earth's shadow (``truth.dark``)."""
    from lidar_sim_ros.core.sun import ScenarioSun
    if sun_config is not None:
        simulator.sun = None if truth.dark else ScenarioSun(sun_config).with_direction(truth.sun_lidar[0])
    period = truth.t_s[-1] - truth.t_s[0]
    frame = simulator.simulate_frame(float(truth.t_s[0]), truth.pose_track(previous, period), frame_index)
    return frame.xyz_m if cloud == 'model' else frame.truth_xyz_m


def gate_cloud(xyz_m: np.ndarray, centre_m: np.ndarray | None, radius_m: float) -> np.ndarray:
    """The points within ``radius_m`` of ``centre_m`` (lidar frame, m); all without a centre or radius."""
    if centre_m is None or radius_m <= 0:
        return xyz_m
    d = xyz_m - centre_m
    return xyz_m[np.einsum('ij,ij->i', d, d) <= radius_m * radius_m]


def capture_centre(xyz_m: np.ndarray) -> np.ndarray | None:
    """Where to centre the gate before a capture, from the cloud alone: its per-axis median
    (m, lidar frame; None for no points). Background triggers and sun returns spread over
    the whole range gate, the target's returns bunch: the median sits on the target while
    it gives most of the points. Non-finite points are left out."""
    finite = xyz_m[np.isfinite(xyz_m).all(axis=1)]
    return np.median(finite, axis=0) if len(finite) else None


def tracker_cloud(config: LoopConfig, xyz_m: np.ndarray, state: 'LoopState') -> np.ndarray:
    """The points the tracker gets: within ``cloud_gate_m`` of the last estimate while
    tracking; before a capture from the cloud, within ``capture_gate_m`` of the cloud's
    median (the acquisition's hypotheses span the cloud's extent, and false returns 250 m
    out made it try ~2000 and fail, docs/loop.md); a capture from the truth keeps the
    old gate about the last estimate, if any."""
    if state.last_estimate is not None and state.tracking:
        return gate_cloud(xyz_m, state.last_estimate[:3, 3], config.cloud_gate_m)
    if config.acquire_from_cloud:
        return gate_cloud(xyz_m, capture_centre(xyz_m), config.capture_gate_m)
    if state.last_estimate is not None:
        return gate_cloud(xyz_m, state.last_estimate[:3, 3], config.cloud_gate_m)
    return xyz_m


def track(tracker, t_s: float, xyz_m: np.ndarray, truth_guess: np.ndarray, from_cloud: bool):
    """One tracker update; returns (Estimate, whether the truth guess was used for capture).

    The adapter between the loop and ``PoseTracker``: with ``from_cloud`` the tracker is
    given no guess and acquires from the cloud alone (gnc/acquire.py), first and after a
    loss; nothing of the truth reaches it. With ``from_cloud`` off, a capture starts from
    the true pose (a reference run); once tracking, the tracker ignores the guess.
    """
    if from_cloud:
        return tracker.update(t_s, xyz_m), False
    capturing = not tracker.tracking
    return tracker.update(t_s, xyz_m, guess=truth_guess), capturing


# ----------------------------------------------------------- the loop state
@dataclass(frozen=True)
class LoopContext:
    """What does not change over a run: config, mount, and the handles.

    ``R_BL`` is the mount the GNC knows (the config's); ``R_BL_true`` the one the lidar
    is really mounted with (None: the same), which the truth (the attitude law's pointing
    and the frame chain) uses: a misaligned mount the navigation does not know of."""

    config: LoopConfig
    dynamics: object
    simulator: object | None
    tracker: object | None
    cloud: str | None
    R_BL: np.ndarray
    t_B: np.ndarray
    R_BL_true: np.ndarray | None = None
    sun_config: object | None = None  # the scenario's core SunConfig (None: no sun)
    gnc: object | None = None         # user_gnc.UserGnc: the config's own controller / navigation

    @property
    def mount_true(self) -> np.ndarray:
        return self.R_BL if self.R_BL_true is None else self.R_BL_true


@dataclass(frozen=True)
class LoopState:
    """What a step carries to the next: the commanded force (N, LVLH), the filter, the
    guidance, the previous period's truth samples, the frame index, acquisition state."""

    force_lvlh_n: np.ndarray = field(default_factory=lambda: np.zeros(3))
    nav: NavState = NavState()
    guidance: GuidanceState = GuidanceState()
    previous: TruthSamples | None = None
    frame_index: int = 0
    tracking: bool = False
    last_estimate: np.ndarray | None = None


@dataclass(frozen=True)
class StepOutput:
    """One period: its truth, the estimate (4 x 4 pose in the lidar frame at ``est_t_s``, or
    None), the reference, and the force (N, LVLH) commanded for the next period."""

    truth: TruthSamples
    est_t_s: float
    est_pose: np.ndarray | None
    true_pose: np.ndarray
    reference: Reference
    force_lvlh_n: np.ndarray
    lost: bool
    truth_capture: bool
    rho_est_m: np.ndarray | None


def _pose_at(truth: TruthSamples, previous: TruthSamples | None, t_s: float) -> np.ndarray:
    """The true pose (4 x 4, lidar frame) at ``t_s``: a sample's own when ``t_s`` is one of
    the sample times (the period's middle with an even number of sub-steps: the default),
    else interpolated as the simulator does (1.3 ms a period)."""
    T = np.eye(4)
    k = int(np.argmin(np.abs(truth.t_s - t_s)))
    if abs(truth.t_s[k] - t_s) < 1e-9:
        T[:3, :3], T[:3, 3] = truth.R_LT[k], truth.t_L_m[k]
        return T
    poses = truth.pose_track(previous).at(np.array([t_s]))
    T[:3, :3] = poses.rotation.as_matrix()[0]
    T[:3, 3] = poses.position_m[0]
    return T


def sense_period(ctx: LoopContext, state: LoopState, truth: TruthSamples) -> np.ndarray | None:
    """The period's cloud (N, 3) m, lidar frame; None without a sensor (``cloud=None``) and
    in the sensor's first period (the poses before it are unknown)."""
    if ctx.cloud is None or state.previous is None:
        return None
    return sense(ctx.simulator, truth, state.previous, state.frame_index, ctx.cloud, ctx.sun_config)


def estimate(ctx: LoopContext, state: LoopState, xyz_m: np.ndarray | None, t_mid: float,
             true_pose: np.ndarray) -> tuple[np.ndarray | None, bool]:
    """(estimate 4 x 4 at ``t_mid`` or None, whether the truth guess captured): the tracker on
    the gated cloud; without a sensor (``cloud=None``) the true pose itself."""
    if ctx.cloud is None:
        return true_pose, False
    if xyz_m is None:
        return None, False
    xyz_m = tracker_cloud(ctx.config, xyz_m, state)
    est, used_truth = track(ctx.tracker, t_mid, xyz_m, true_pose, ctx.config.acquire_from_cloud)
    return (est.pose if est.acceptable(ctx.tracker.config) else None), used_truth


def navigate(ctx: LoopContext, nav: NavState, truth: TruthSamples, t_mid: float,
             est_pose: np.ndarray | None) -> tuple[NavState, np.ndarray | None]:
    """Fold the estimate into the filter; the chaser's own attitude (R_HB at the estimate's
    time, from its attitude determination) turns it into LVLH."""
    user_nav = ctx.gnc.navigation if ctx.gnc is not None else None
    if est_pose is None:
        if user_nav is not None:
            user_nav.update(t_mid, None)
        return nav, None
    k = int(np.argmin(np.abs(truth.t_s - t_mid)))
    rho = frames.chaser_from_estimate(est_pose[:3, 3], truth.R_HB[k], ctx.R_BL, ctx.t_B)
    if user_nav is not None:
        user_nav.update(t_mid, rho.copy())
        return nav, rho
    return nav_update(ctx.config.guidance, nav, t_mid, rho), rho


def guide_and_control(config: LoopConfig, nav: NavState, g: GuidanceState, t_s: float, n_rad_s: float,
                      gnc=None):
    """(guidance state, reference, force (N, LVLH)) at ``t_s`` from the filtered estimate;
    ``gnc`` (``user_gnc.UserGnc``): the config's own navigation and controller instead of
    the alpha-beta filter and the PD (the thrust limit and dead band apply to both)."""
    state = (gnc.navigation.at(t_s) if gnc is not None and gnc.navigation is not None
             else nav.at(t_s) if nav.valid else None)
    if state is None:
        ref = Reference(np.zeros(3), np.zeros(3), 'wait', g.index, False)
        return g, ref, np.zeros(3)
    rho, rho_dot = (np.asarray(x, float) for x in state)
    g, ref = guidance_step(config.guidance, g, t_s, rho, rho_dot)
    if gnc is not None and gnc.controller is not None:
        force = limit_force(gnc.force(t_s, rho, rho_dot, ref, n_rad_s), config.chaser.thrust_limit_n,
                            config.chaser.dead_band_n)
        return g, ref, force
    return g, ref, control_step(config.guidance, config.chaser, rho, rho_dot, ref, n_rad_s)


def next_state(state: LoopState, truth: TruthSamples, nav: NavState, g: GuidanceState,
               force_lvlh_n: np.ndarray, est_pose: np.ndarray | None) -> LoopState:
    """What the period hands on to the next."""
    tracking = est_pose is not None
    return replace(state, force_lvlh_n=force_lvlh_n, nav=nav, guidance=g, previous=truth,
                   frame_index=state.frame_index + 1, tracking=tracking,
                   last_estimate=est_pose if tracking else state.last_estimate)


def loop_step(ctx: LoopContext, state: LoopState) -> tuple[LoopState, StepOutput]:
    """One control period: propagate, sense, estimate, navigate, guide, control."""
    truth = propagate(ctx.config, ctx.dynamics, state.force_lvlh_n, ctx.mount_true, ctx.t_B)
    t_mid = float(0.5 * (truth.t_s[0] + truth.t_s[-1]))  # a scan's fit sits at its mean time
    true_pose = _pose_at(truth, state.previous, t_mid)
    xyz = sense_period(ctx, state, truth)
    est_pose, truth_capture = estimate(ctx, state, xyz, t_mid, true_pose)
    nav, rho_est = navigate(ctx, state.nav, truth, t_mid, est_pose)
    g, ref, force = guide_and_control(ctx.config, nav, state.guidance, float(truth.t_s[-1]), truth.n_rad_s,
                                      ctx.gnc)
    new = next_state(state, truth, nav, g, force, est_pose)
    return new, StepOutput(truth, t_mid, est_pose, true_pose, ref, force,
                           state.tracking and not new.tracking, truth_capture, rho_est)


# ----------------------------------------------------------------- a whole run
@dataclass(frozen=True)
class LoopResult:
    """A run's metrics (``metrics``, the keys of loop.json) and its time series (arrays,
    one row per period unless said): t_s, rho_true_m (N, 3), rho_est_m (N, 3; NaN without
    an estimate), range_m (lidar to target centre), force_lvlh_n (N, 3), delta_v_mps
    (cumulative), phase (str), hold_index, est_trans_err_m, est_axis_err_deg (NaN without)."""

    metrics: dict
    series: dict


def build_context(config: LoopConfig, scenario_path, cloud: str | None, dynamics=None, *,
                  target=None, tracker_model=None, misalignment_xyzw=None) -> LoopContext:
    """Load the scenario's simulator and the tracker (not for ``cloud=None``) and start Basilisk.

    ``scenario_path``: a scenario file, or an already loaded (e.g. dispersed) core
    ``Scenario``, as a campaign case would pass. ``target`` (the scenario's loaded mesh)
    and ``tracker_model`` (its ``gnc.tracker.build_model``): built here if not given (a
    campaign worker reuses them). ``misalignment_xyzw``: rotation M of the real lidar
    frame from the configured one (p_lidar = M p_lidar_configured), unknown to the GNC."""
    from lidar_sim_ros.loop.dynamics import Dynamics
    if cloud not in (None, 'model', 'truth'):
        raise ValueError(f"cloud must be 'model', 'truth' or None, not {cloud!r}")
    simulator = tracker = None
    if cloud is not None:
        from lidar_sim_ros.core.scenario import load_scenario
        from lidar_sim_ros.core.pipeline import Simulator
        from lidar_sim_ros.gnc.tracker import PoseTracker, TrackerConfig, build_model
        scenario = scenario_path if hasattr(scenario_path, 'sensor') else load_scenario(scenario_path)
        simulator = Simulator.from_scenario(scenario, target=target)
        tcfg = TrackerConfig(num_threads=config.tracker_threads)
        if tracker_model is None:
            tracker_model = build_model(simulator.target.vertices_m, simulator.target.faces, tcfg)
        tracker = PoseTracker(tracker_model, tcfg)
    R_BL, t_B = frames.mount_transform(config.chaser.mount)
    R_BL_true = None
    if misalignment_xyzw is not None:  # p_L' = M p_L = M R_BL^T p_B: R_BL' = R_BL M^T
        R_BL_true = R_BL @ Rotation.from_quat(misalignment_xyzw).as_matrix().T
    sun_config = simulator.sun.config if simulator is not None and simulator.sun is not None else None
    from lidar_sim_ros.loop.user_gnc import load_user_gnc
    return LoopContext(config, dynamics or Dynamics(config), simulator, tracker, cloud, R_BL, t_B,
                       R_BL_true, sun_config, load_user_gnc(config))


def _axis_angle_deg(R_est: np.ndarray, R_true: np.ndarray) -> float:
    """Angle (deg) between the estimated and true body long axes (+Z)."""
    c = float(np.clip(R_est[:, 2] @ R_true[:, 2], -1.0, 1.0))
    return math.degrees(math.acos(c))


def run_loop(config: LoopConfig, cloud: str | None = 'model', scenario_path=None,
             duration_s: float | None = None) -> LoopResult:
    """Run the approach for ``duration_s`` (default: the config's) and score it.

    ``scenario_path``: a file or a loaded ``Scenario`` (default: the config's scenario,
    resolved next to the package's config/loop.yaml)."""
    if scenario_path is None and cloud is not None:
        from lidar_sim_ros.core.config import resolve
        from lidar_sim_ros.paths import config_path
        scenario_path = resolve(config.scenario, Path(config_path('loop.yaml')).parent)
    ctx = build_context(config, scenario_path, cloud)
    return run_steps(ctx, duration_s)


def run_steps(ctx: LoopContext, duration_s: float | None = None) -> LoopResult:
    """Step a built context for ``duration_s`` (default: the config's) and score the run as
    it goes (``RunRecord``: memory bounded whatever the duration)."""
    config = ctx.config
    state = LoopState()
    steps = int(round((duration_s or config.duration_s) / config.control_period_s))
    record = RunRecord(config)
    for _ in range(steps):
        state, out = loop_step(ctx, state)
        record.add(out)
    return record.result()


SERIES_MAX_ROWS = 36_000
"""Rows of a run's series kept at most (an hour at 10 Hz); a longer run keeps every 2nd,
4th, ... period (the metrics still see every period)."""


class RunRecord:
    """A run's metrics (``metrics.LoopScore``, over every period) and its series (one row a
    period up to ``max_rows``, then decimated by two each time it fills), in memory bounded
    by ``max_rows`` and the hold time: a step's truth samples (5.5 kB) are not kept."""

    FIELDS = ('t_s', 'rho_true_m', 'rho_est_m', 'ref_m', 'range_m', 'force_lvlh_n', 'delta_v_mps', 'phase',
              'hold_index', 'settled', 'est_trans_err_m', 'est_axis_err_deg')

    def __init__(self, config: LoopConfig, max_rows: int = SERIES_MAX_ROWS):
        from lidar_sim_ros.loop.metrics import LoopScore
        self.config, self.max_rows = config, max(2, int(max_rows))
        self.score = LoopScore(config.control_period_s, config.chaser.mass_kg, config.guidance.hold_time_s)
        self.rows: list[tuple] = []
        self.stride, self.index = 1, 0
        self.delta_v_mps = 0.0
        self.truth_captures = self.holds_reached = 0

    def add(self, o: StepOutput) -> None:
        cfg = self.config
        t = float(o.truth.t_s[-1])
        rho_true, rng = o.truth.rho_m[-1], float(np.linalg.norm(o.truth.t_L_m[-1]))
        trans = axis = float('nan')
        if o.est_pose is not None:
            trans = float(np.linalg.norm(o.est_pose[:3, 3] - o.true_pose[:3, 3]))
            axis = _axis_angle_deg(o.est_pose[:3, :3], o.true_pose[:3, :3])
        est_t = o.est_t_s if np.isfinite(trans) else None
        self.score.add(t, rho_true, o.reference.rho_m, rng, o.force_lvlh_n, est_t, trans, axis, o.lost)
        self.delta_v_mps += float(np.linalg.norm(o.force_lvlh_n)) * cfg.control_period_s / cfg.chaser.mass_kg
        self.truth_captures += bool(o.truth_capture)
        self.holds_reached = max(self.holds_reached, o.reference.index + o.reference.settled)
        if self.index % self.stride == 0:
            rho_est = o.rho_est_m if o.rho_est_m is not None else np.full(3, np.nan)
            self.rows.append((t, rho_true.copy(), np.asarray(rho_est, float), o.reference.rho_m.copy(), rng,
                              np.asarray(o.force_lvlh_n, float), self.delta_v_mps, o.reference.phase,
                              o.reference.index, o.reference.settled, trans, axis))
            if len(self.rows) >= self.max_rows:
                self.rows, self.stride = self.rows[::2], 2 * self.stride
        self.index += 1

    def result(self) -> LoopResult:
        metrics = self.score.result()
        metrics['truth_captures'] = int(self.truth_captures)
        metrics['holds_reached'] = int(self.holds_reached)
        columns = dict(zip(self.FIELDS, zip(*self.rows))) if self.rows else {f: () for f in self.FIELDS}
        series = {}
        for name in self.FIELDS:
            values = columns[name]
            if name == 'phase':
                series[name] = list(values)
            elif name in ('rho_true_m', 'rho_est_m', 'ref_m', 'force_lvlh_n'):
                series[name] = np.array(values, float).reshape(-1, 3)
            else:
                series[name] = np.array(values)
        series['every_periods'] = self.stride
        return LoopResult(metrics, series)


def score(config: LoopConfig, outputs: list[StepOutput]) -> LoopResult:
    """Metrics and series of a run's step outputs (``RunRecord``)."""
    record = RunRecord(config)
    for o in outputs:
        record.add(o)
    return record.result()
