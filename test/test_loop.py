"""loop/dynamics.py and loop/step.py on Basilisk: closed forms, invariants, the loop itself.

Cheap by design: Basilisk integrates a minute of two spacecraft in well under a second;
the closed-loop runs use a few frames of the plain scenario or the true pose.
"""
import math
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip('Basilisk')

from lidar_sim_ros.loop.config import LoopConfig, load_loop_config  # noqa: E402
from lidar_sim_ros.loop.dynamics import EARTH_MU_M3_S2, EARTH_RADIUS_M, Dynamics  # noqa: E402
from lidar_sim_ros.loop.step import run_loop  # noqa: E402
from lidar_sim_ros.paths import config_path  # noqa: E402


@pytest.fixture(scope='module')
def config() -> LoopConfig:
    return load_loop_config(config_path('loop.yaml'))[0]


def with_(config: LoopConfig, **changes) -> LoopConfig:
    """The config with nested changes given as {'guidance': {...}, ...} (validated again)."""
    data = config.model_dump()
    for key, value in changes.items():
        if isinstance(value, dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = value
    return LoopConfig.model_validate(data)


def cw_closed_form(rho0, v0, n, t):
    """Clohessy-Wiltshire solution (LVLH: x radial, y along-track, z normal)."""
    x0, y0, z0 = rho0
    vx, vy, vz = v0
    c, s = math.cos(n * t), math.sin(n * t)
    return np.array([(4 - 3 * c) * x0 + s / n * vx + 2 / n * (1 - c) * vy,
                     6 * (s - n * t) * x0 + y0 - 2 / n * (1 - c) * vx + (4 * s - 3 * n * t) / n * vy,
                     c * z0 + s / n * vz])


def test_relative_motion_matches_clohessy_wiltshire(config):
    rho0, v0 = np.array([5.0, -30.0, 3.0]), np.array([0.02, -0.01, 0.015])
    dyn = Dynamics(config, rho0, v0, step_s=0.1)
    n = math.sqrt(EARTH_MU_M3_S2 / (EARTH_RADIUS_M + config.orbit.altitude_m) ** 3)
    worst = 0.0
    for t in (10.0, 30.0, 60.0):
        rho, _ = dyn.advance_to(t).relative_lvlh()
        worst = max(worst, float(np.linalg.norm(rho - cw_closed_form(rho0, v0, n, t))))
    # The free drift over the minute is metres (so the frame and the CW terms matter) ...
    assert np.linalg.norm(rho - (rho0 + 60.0 * v0)) > 0.05
    assert worst < 1e-3  # ... and Basilisk agrees with the closed form to a millimetre
    # A force moves the chaser by F t^2 / 2m (the effector acts from the next step, not one late).
    dyn2 = Dynamics(config, np.zeros(3), np.zeros(3), step_s=0.01)
    dyn2.set_force_inertial(np.array([0.0, 0.0, 5.0]))
    s = dyn2.advance_to(1.0)
    dz = s.r_chaser_m - s.r_target_m
    # Along the inertial z (the force), over 1 s: 5 N / 500 kg / 2 = 5 mm, gravity gradient negligible.
    assert dz[2] == pytest.approx(0.5 * 5.0 / config.chaser.mass_kg, rel=1e-3)


def test_torque_free_tumble_keeps_its_angular_momentum(config):
    dyn = Dynamics(config)
    inertia = np.asarray(config.target.inertia_kg_m2)
    first = dyn.state()
    h0 = first.R_NT @ inertia @ first.omega_target_rad_s
    axis0 = first.omega_target_rad_s / np.linalg.norm(first.omega_target_rad_s)
    drift = 0.0
    for t in np.arange(5.0, 61.0, 5.0):
        s = dyn.advance_to(t)
        h = s.R_NT @ inertia @ s.omega_target_rad_s
        drift = max(drift, float(np.linalg.norm(h - h0) / np.linalg.norm(h0)))
        axis = s.omega_target_rad_s / np.linalg.norm(s.omega_target_rad_s)
    assert drift < 1e-9
    # Not about a principal axis: the rate vector moves in the body (nutation) by degrees.
    assert math.degrees(math.acos(np.clip(axis @ axis0, -1, 1))) > 1.0


def test_basilisk_fetches_nothing():
    """Building and running the dynamics imports no support-data fetcher (an HTTP request at
    import) and no pooch: point-mass gravity needs no files."""
    code = ('import sys; from lidar_sim_ros.loop.config import load_loop_config; '
            'from lidar_sim_ros.loop.dynamics import Dynamics; from lidar_sim_ros.paths import config_path; '
            "d = Dynamics(load_loop_config(config_path('loop.yaml'))[0]); d.advance_to(1.0); "
            "print(sorted(m for m in sys.modules if 'pooch' in m or 'dataFetcher' in m or m == 'requests'))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[]'


def test_controller_holds_on_the_true_pose(config):
    """Fed the true pose, the PD holds within 5 cm of its hold point (tumbling target, real orbit)."""
    cfg = with_(config, duration_s=60.0, guidance={'hold_ranges_m': [15.0]},
                initial={'position_m': (0.4, -15.6, -0.3), 'velocity_mps': (0.01, 0.0, 0.0),
                         'position_sigma_m': 0.0, 'velocity_sigma_mps': 0.0},
                timing={'pose_rate_hz': 20.0})
    result = run_loop(cfg, cloud=None)
    rho = result.series['rho_true_m']
    t = result.series['t_s']
    late = t > 30.0
    error = np.linalg.norm(rho[late] - [0.0, -15.0, 0.0], axis=1)
    assert error.max() < 0.05
    assert result.metrics['holds_reached'] == 1
    assert np.linalg.norm(rho[0] - [0.0, -15.0, 0.0]) > 0.5  # it did have to move


def test_lock_step_runs_are_identical(config):
    """Two runs of the whole loop (Basilisk, simulator with noise, tracker) with one seed are
    identical to the bit; another seed differs."""
    plain = config_path('scenario.yaml')
    cfg = with_(config, scenario=str(plain), initial={'position_m': (0.0, -10.0, 0.0)},
                guidance={'hold_ranges_m': [10.0]})

    def run(c):
        return run_loop(c, cloud='model', scenario_path=plain, duration_s=0.6)

    a, b = run(cfg), run(cfg)
    assert a.metrics['acquired_at_s'] is not None
    for key in ('rho_true_m', 'rho_est_m', 'force_lvlh_n', 'est_trans_err_m'):
        np.testing.assert_array_equal(a.series[key], b.series[key])
    c = run(with_(cfg, seed=cfg.seed + 1))
    assert not np.array_equal(a.series['rho_true_m'], c.series['rho_true_m'])


def test_capture_adapter_uses_the_truth_only_to_capture():
    """``step.track``: with acquire_from_cloud off the true pose starts the capture and only
    the capture; on, the tracker gets no guess and acquires from the cloud alone."""
    pytest.importorskip('small_gicp')
    import trimesh

    from lidar_sim_ros.gnc.tracker import PoseTracker, TrackerConfig, build_model, pose_matrix
    from lidar_sim_ros.loop.step import track
    box = trimesh.creation.box(extents=[1.2, 0.8, 0.5])
    cfg = TrackerConfig(model_spacing_m=0.03, min_points=20)
    T = pose_matrix([5.0, 0.2, -0.1], [0.0, 0.0, 0.0, 1.0])
    points = trimesh.sample.sample_surface(box, 3000, seed=1)[0]
    xyz = points[points[:, 0] < 0] + T[:3, 3]       # the face toward the sensor and the edges

    tracker = PoseTracker(build_model(box.vertices, box.faces, cfg), cfg)
    est, used = track(tracker, 0.0, xyz, T, from_cloud=False)
    assert used and est.acceptable(cfg)
    est, used = track(tracker, 0.1, xyz, np.eye(4), from_cloud=False)   # tracking: the guess is unused
    assert not used and np.linalg.norm(est.pose[:3, 3] - T[:3, 3]) < 0.05

    fresh = PoseTracker(build_model(box.vertices, box.faces, cfg), cfg)
    est, used = track(fresh, 0.0, xyz, np.full((4, 4), np.nan), from_cloud=True)
    assert not used and est.acceptable(cfg) and np.linalg.norm(est.pose[:3, 3] - T[:3, 3]) < 0.05


def test_capture_gate_keeps_the_target_and_drops_far_false_returns():
    """Before a capture there is no estimate to gate on: the gate is centred on the cloud's
    median, which a target giving most of the points pins, whatever the false returns do."""
    from lidar_sim_ros.loop.step import capture_centre, gate_cloud
    rng = np.random.default_rng(3)
    body = np.array([30.0, 1.0, -0.5]) + rng.uniform(-5.0, 5.0, (800, 3)) * [0.2, 1.0, 0.4]
    far = rng.uniform([40.0, -100.0, -30.0], [250.0, 100.0, 30.0], (300, 3))  # 27 % background
    near_dust = rng.uniform([1.0, -1.0, -1.0], [6.0, 1.0, 1.0], (20, 3))
    cloud = np.concatenate([body, far, near_dust])[rng.permutation(1120)]
    kept = gate_cloud(cloud, capture_centre(cloud), 12.0)
    assert len(kept) == 800 + np.sum(np.linalg.norm(far - capture_centre(cloud), axis=1) <= 12.0)
    assert np.all(np.linalg.norm(kept - [30.0, 1.0, -0.5], axis=1) < 15.0)
    assert capture_centre(np.zeros((0, 3))) is None
    # What the loop hands the tracker: before the capture, the cloud about its median ...
    from lidar_sim_ros.loop.config import load_loop_config
    from lidar_sim_ros.loop.step import LoopState, tracker_cloud
    config = load_loop_config(config_path('loop.yaml'))[0]
    assert config.acquire_from_cloud and config.capture_gate_m == 12.0
    np.testing.assert_array_equal(tracker_cloud(config, cloud, LoopState()), kept)
    # ... while tracking, the points within cloud_gate_m (8 m) of the last estimate.
    est = np.eye(4)
    est[:3, 3] = [30.0, 6.0, 0.0]
    near = tracker_cloud(config, cloud, LoopState(tracking=True, last_estimate=est))
    assert len(near) == np.sum(np.linalg.norm(cloud - est[:3, 3], axis=1) <= 8.0) < 800
    # The DDS loop's gate node keeps the same points.
    from lidar_sim_ros.loop.cloud_gate_node import gate_mask
    np.testing.assert_array_equal(cloud[gate_mask(cloud, None, 8.0, 12.0)], kept)
    np.testing.assert_array_equal(cloud[gate_mask(cloud, est[:3, 3], 8.0, 12.0)], near)
    assert gate_mask(cloud, None, 8.0, 0.0) is None


@pytest.mark.parametrize('law, start_s', [('point_at_target', 0.0), ('hold_lvlh', 0.5)])
def test_period_truth_equals_the_per_sample_truth(config, law, start_s):
    """``propagate`` samples a period in one stacked pass: the per-sample ``sample_truth``
    (a second implementation, one state at a time) gives the same numbers."""
    from lidar_sim_ros.loop import frames
    from lidar_sim_ros.loop.step import propagate, sample_truth
    cfg = with_(config, chaser={'attitude_law': law})
    dyn = Dynamics(cfg, np.array([1.0, -20.0, 0.5]), np.array([0.01, 0.0, -0.02]))
    R_BL, t_B = frames.mount_transform(cfg.chaser.mount)
    R_BL = R_BL @ frames.Rotation.from_rotvec([0.01, -0.02, 0.03]).as_matrix()  # not the identity
    if start_s:
        dyn.advance_to(start_s)
    states = [dyn.state()]
    truth = propagate(cfg, dyn, np.zeros(3), R_BL, t_B)
    # The same period again, one state at a time.
    dyn2 = Dynamics(cfg, np.array([1.0, -20.0, 0.5]), np.array([0.01, 0.0, -0.02]))
    if start_s:  # from t = 0, Basilisk's recorders also hold the state at 0
        dyn2.advance_to(start_s)
    rows = [sample_truth(cfg, dyn2.state(), R_BL, t_B)]
    for t in truth.t_s[1:]:
        rows.append(sample_truth(cfg, dyn2.advance_to(float(t)), R_BL, t_B))
    assert len(rows) == cfg.substeps + 1 == len(states) + cfg.substeps
    for key in ('t_s', 'R_LT', 't_L_m', 'sun_lidar', 'R_HB', 'rho_m', 'rho_dot_mps'):
        np.testing.assert_allclose(getattr(truth, key), np.array([r[key] for r in rows]), rtol=0,
                                   atol=1e-9, err_msg=key)
    assert truth.n_rad_s == pytest.approx(rows[0]['n_rad_s'], rel=1e-14)


def test_true_pose_at_mid_period_is_the_interpolated_one(config):
    """The period's true pose at its middle, read off the sample there, equals the
    simulator's interpolation of the samples (and an off-grid time still interpolates)."""
    from lidar_sim_ros.loop import frames
    from lidar_sim_ros.loop.step import _pose_at, propagate
    dyn = Dynamics(config, np.array([0.0, -20.0, 0.0]), np.array([0.01, 0.05, -0.02]))
    R_BL, t_B = frames.mount_transform(config.chaser.mount)
    first = propagate(config, dyn, np.zeros(3), R_BL, t_B)
    truth = propagate(config, dyn, np.zeros(3), R_BL, t_B)
    for t in (0.5 * (truth.t_s[0] + truth.t_s[-1]), truth.t_s[0] + 0.0123):
        poses = truth.pose_track(first).at(np.array([t]))
        T = _pose_at(truth, first, float(t))
        np.testing.assert_allclose(T[:3, :3], poses.rotation.as_matrix()[0], atol=1e-12)
        np.testing.assert_allclose(T[:3, 3], poses.position_m[0], atol=1e-9)


def test_in_the_earth_shadow_the_frame_is_simulated_without_the_sun(config):
    """The sun straight behind the Earth as seen from the orbit's start (the target starts on
    inertial +x: RAAN 0, argument of latitude 0): every sample of the period is in the shadow,
    and the frame is the one the simulator computes with no sun at all (no sunlight, no
    solar background); the same period lit has the solar background's far returns. With
    ``sun.eclipse`` off the same geometry is lit."""
    from dataclasses import replace

    from lidar_sim_ros.loop import step
    cfg = with_(config, sun={'direction_inertial': (-1.0, 0.0, 0.0)})
    scenario = config_path('scenario_all_effects.yaml')
    ctx = step.build_context(cfg, scenario, 'model')
    state, _ = step.loop_step(ctx, step.LoopState())  # the sensor's first period: no frame
    truth = step.propagate(cfg, ctx.dynamics, np.zeros(3), ctx.R_BL, ctx.t_B)
    assert truth.eclipsed.all() and truth.dark
    dark = step.sense(ctx.simulator, truth, state.previous, 1, 'model', ctx.sun_config)
    assert ctx.simulator.sun is None
    no_sun = step.sense(ctx.simulator, truth, state.previous, 1, 'model', None)
    np.testing.assert_array_equal(dark, no_sun)
    lit = step.sense(ctx.simulator, replace(truth, eclipsed=np.zeros(len(truth.t_s), bool)), state.previous, 1,
                     'model', ctx.sun_config)
    # Lit, the frame's sun is the period's first direction (as loop_dynamics publishes it).
    np.testing.assert_allclose(ctx.simulator.sun.direction_at(np.array([0.05]))[0], truth.sun_lidar[0],
                               atol=1e-12)

    def far(xyz):  # returns more than 8 m from the target centre: background, mostly the sun's
        return int((np.linalg.norm(xyz - truth.t_L_m[5], axis=1) > 8.0).sum())
    assert far(lit) > far(dark) + 20

    off = with_(cfg, sun={'eclipse': False})
    dyn = Dynamics(off)
    R_BL, t_B = step.frames.mount_transform(off.chaser.mount)
    assert not step.propagate(off, dyn, np.zeros(3), R_BL, t_B).eclipsed.any()
