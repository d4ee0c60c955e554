"""Pose interpolation: SLERP against scipy, extrapolation bounds, scenario motion."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from lidar_sim_ros.core.pose import PoseCoverageError, PoseTrack, ScenarioTrajectory


def test_interpolation_matches_scipy_slerp_and_linear_position():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 5, 12))
    q = Rotation.random(12, random_state=4)
    p = rng.normal(size=(12, 3))
    track = PoseTrack(t, p, q.as_quat())
    tq = rng.uniform(t[0], t[-1], 500)
    poses = track.at(tq)
    # float64, two SLERP implementations: agree to ~1e-15; 1e-12 still fails NLERP by 1e-3.
    assert np.allclose(poses.rotation.as_matrix(), Slerp(t, q)(tq).as_matrix(), atol=1e-12)
    assert np.allclose(poses.position_m[:, 0], np.interp(tq, t, p[:, 0]))


def test_coverage_errors_and_bounded_extrapolation():
    t = np.array([0.0, 1.0])
    q = Rotation.from_rotvec([[0, 0, 0], [0, 0, 0.1]]).as_quat()
    track = PoseTrack(t, [[0, 0, 0], [1, 0, 0]], q, max_extrapolation_s=0.5)
    with pytest.raises(PoseCoverageError):
        track.at([-0.01])
    with pytest.raises(PoseCoverageError):
        track.at([1.51])
    poses = track.at([1.5])  # extrapolated with the last segment's velocities
    assert poses.position_m[0] == pytest.approx([1.5, 0, 0])
    assert poses.rotation.as_rotvec()[0] == pytest.approx([0, 0, 0.15])
    # Inside and extrapolated times mixed in one query: each as if asked alone.
    times = [1.2, 0.25, 1.5, 0.9, 1.0]
    mixed = track.at(times)
    for k, ti in enumerate(times):  # the same float64 arithmetic either way: 1e-12
        alone = track.at([ti])
        assert mixed.position_m[k] == pytest.approx(alone.position_m[0], abs=1e-12)
        assert mixed.rotation[k].as_rotvec() == pytest.approx(alone.rotation.as_rotvec()[0], abs=1e-12)
    assert mixed.position_m[0] == pytest.approx([1.2, 0, 0])
    assert mixed.rotation[0].as_rotvec() == pytest.approx([0, 0, 0.12])


def test_body_lidar_round_trip():
    track = PoseTrack([0.0], [[10, 1, 2]], Rotation.from_euler('xyz', [10, 20, 30], degrees=True).as_quat())
    poses = track.at(np.zeros(5))
    pts = np.random.default_rng(0).normal(size=(5, 3))
    assert np.allclose(poses.to_body(poses.to_lidar(pts)), pts)


def test_scenario_trajectory_closed_form(default_scenario):
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    cfg = default_scenario.config
    poses = traj.at(np.array([0.0, 2.0]))
    p0 = np.array(cfg.initial_pose.position_m)
    assert poses.position_m[0] == pytest.approx(p0)
    closing = np.linalg.norm(p0) - np.linalg.norm(poses.position_m[1])
    assert closing == pytest.approx(2.0 * cfg.motion.approach_speed_mps)
    rel = poses.rotation[1] * poses.rotation[0].inv()
    assert np.degrees(rel.magnitude()) == pytest.approx(2.0 * cfg.motion.tumble_rate_dps)
    axis = np.array(cfg.motion.tumble_axis) / np.linalg.norm(cfg.motion.tumble_axis)
    assert rel.as_rotvec() / rel.magnitude() == pytest.approx(axis)


def test_quaternion_product_matches_scipy_both_branches():
    from lidar_sim_ros.core.pose import quat_multiply, rotvec_to_quat
    a = Rotation.random(20, random_state=1)
    b = Rotation.random(20, random_state=2)
    one = Rotation.random(random_state=3)
    assert np.allclose(Rotation.from_quat(quat_multiply(a.as_quat(), b.as_quat())).as_matrix(),
                       (a * b).as_matrix())
    assert np.allclose(Rotation.from_quat(quat_multiply(a.as_quat(), one.as_quat())).as_matrix(),
                       (a * one).as_matrix())
    rv = np.random.default_rng(0).normal(size=(20, 3))
    rv[0] = 0.0
    assert np.allclose(Rotation.from_quat(rotvec_to_quat(rv)).as_matrix(), Rotation.from_rotvec(rv).as_matrix())
