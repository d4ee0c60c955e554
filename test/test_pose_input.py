"""Tests for lidar_sim_ros/ros/pose_input.py: pose validation and history, without ROS."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.pose import PoseCoverageError
from lidar_sim_ros.ros.pose_input import (NS_PER_S, QUAT_NORM_TOL, PoseHistory, PoseSample,
                                          ReasonThrottle, check_pose, twist_to_lidar)

T0 = 1_700_000_000 * NS_PER_S  # a wall-clock epoch, where float seconds lose resolution
Q_UNIT = np.array([0.0, 0.0, np.sin(0.2), np.cos(0.2)])


def sample(dt_s=0.0, position=(10.0, 0.0, 0.0), quat=Q_UNIT, frame_id='lidar', **kw):
    return PoseSample(T0 + round(dt_s * NS_PER_S), frame_id, np.array(position, dtype=float),
                      np.array(quat, dtype=float), **kw)


def check(s, last=None, now_dt_s=0.0, stale=0.5):
    return check_pose(s, 'lidar', last, T0 + round(now_dt_s * NS_PER_S), stale)


def test_good_pose_is_accepted_unchanged():
    good, rejection = check(sample())
    assert rejection is None
    np.testing.assert_array_equal(good.quat_xyzw, Q_UNIT)
    np.testing.assert_array_equal(good.position_m, [10.0, 0.0, 0.0])


def test_near_unit_quaternion_is_normalised():
    good, rejection = check(sample(quat=Q_UNIT * (1 + 0.5 * QUAT_NORM_TOL)))
    assert rejection is None
    # float64: normalising costs a couple of ulps of 1 (2.2e-16 each).
    assert np.linalg.norm(good.quat_xyzw) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(good.quat_xyzw, Q_UNIT, atol=1e-15)


@pytest.mark.parametrize('kw, kind, words', [
    ({'position': (np.nan, 0, 0)}, 'position', 'not finite'),
    ({'position': (0, np.inf, 0)}, 'position', 'not finite'),
    ({'quat': (0, 0, 0, 0)}, 'quaternion_zero', 'zero'),
    ({'quat': (0, 0, np.nan, 1)}, 'quaternion', 'not finite'),
    ({'quat': Q_UNIT * 2.0}, 'quaternion_norm', 'norm 2 is far from 1'),
    ({'quat': Q_UNIT * (1 + 2 * QUAT_NORM_TOL)}, 'quaternion_norm', 'far from 1'),
    ({'frame_id': 'map'}, 'frame_id', "'map' is not the node frame_id 'lidar'"),
    ({'velocity_mps': np.array([0, np.nan, 0])}, 'twist', 'velocity_mps'),
    # Finite but absurd: a frame from 1e300 m sees nothing and blames nobody.
    ({'position': (1e300, 0, 0)}, 'position', 'beyond 100000 m'),
    ({'position': (0, 0, -1.5e5)}, 'position', 'beyond 100000 m'),
    ({'velocity_mps': np.array([0, 1e300, 0])}, 'twist', 'beyond 10000'),
    ({'angular_velocity_rad_s': np.array([0, 0, 100.0])}, 'twist', 'beyond 62.83'),
])
def test_bad_content_is_rejected_with_reason(kw, kind, words):
    good, rejection = check(sample(**kw))
    assert good is None
    assert rejection.kind == kind
    assert words in rejection.reason


def test_stamps_must_advance():
    last = T0 + NS_PER_S // 10
    for dt_s in (0.0, 0.1):  # before and equal to the last accepted stamp
        good, rejection = check(sample(dt_s), last=last)
        assert good is None and rejection.kind == 'stamp_order'
        assert '1700000000.100000000' in rejection.reason
    assert check(sample(0.100000001), last=last)[1] is None


def test_stale_and_future_stamps_are_rejected():
    assert check(sample(0.0), now_dt_s=0.5, stale=0.5)[1] is None  # exactly at the limit
    good, rejection = check(sample(0.0), now_dt_s=0.51, stale=0.5)
    assert good is None and rejection.kind == 'stale' and '0.510 s old' in rejection.reason
    good, rejection = check(sample(2.0), now_dt_s=0.0, stale=0.5)
    assert good is None and rejection.kind == 'future'


def test_twist_is_rotated_from_body_to_lidar_frame():
    # Body rotated 90 deg about z: body +x is lidar +y.
    quat = Rotation.from_euler('z', 90, degrees=True).as_quat()
    v, w = twist_to_lidar(quat, np.array([1.0, 0, 0]), np.array([0, 0.0, 0.3]))
    # float64: cos(90 deg) is 6e-17, not 0; a few ulps of 1 allowed.
    np.testing.assert_allclose(v, [0, 1.0, 0], atol=1e-15)
    np.testing.assert_allclose(w, [0, 0, 0.3], atol=1e-15)


def spin_samples(n, dt_s=0.02, rate=(0.0, 0.0, 0.5), velocity=(-0.1, 0.02, 0.0)):
    """Samples of a body spinning at a constant rate (lidar frame) and moving linearly."""
    t = np.arange(n) * dt_s
    rot = Rotation.from_rotvec(t[:, None] * np.array(rate)) * Rotation.from_quat(Q_UNIT)
    pos = np.array([10.0, 1.0, -0.5]) + t[:, None] * np.array(velocity)
    return [sample(ti, p, q) for ti, p, q in zip(t, pos, rot.as_quat())], rot, pos


def test_track_interpolates_exactly_for_constant_rates():
    samples, _, _ = spin_samples(6)
    history = PoseHistory()
    for s in samples:
        history.add(s)
    epoch = T0 + 5 * NS_PER_S // 1000
    track = history.track(epoch, max_extrapolation_s=0.05)
    # Closed form at times between and beyond the samples (relative to epoch).
    t_abs = np.array([0.005, 0.031, 0.0999, 0.1, 0.14])
    poses = track.at(t_abs - 0.005)
    rot = Rotation.from_rotvec(t_abs[:, None] * np.array([0, 0, 0.5])) * Rotation.from_quat(Q_UNIT)
    np.testing.assert_allclose(poses.position_m,
                               np.array([10.0, 1.0, -0.5]) + t_abs[:, None] * [-0.1, 0.02, 0.0],
                               atol=1e-12)  # float64 (~1e4 ulps at 10 m: interpolation arithmetic)
    # SLERP of a constant-rate spin is exact; float64 arccos near 0 limits this to ~1e-8 rad.
    assert np.all((poses.rotation * rot.inv()).magnitude() < 1e-9)
    with pytest.raises(PoseCoverageError):
        track.at(np.array([0.1 + 0.05 + 0.001 - 0.005]))


def test_track_uses_odometry_twist_to_extrapolate():
    history = PoseHistory()
    history.add(sample(0.0))
    history.add(sample(0.02, velocity_mps=np.array([1.0, 0, 0]),
                       angular_velocity_rad_s=np.array([0, 0, 2.0])))
    track = history.track(T0, max_extrapolation_s=0.1)
    pose = track.at(np.array([0.07]))
    np.testing.assert_allclose(pose.position_m[0], [10.05, 0, 0], atol=1e-12)
    expected = Rotation.from_rotvec([0, 0, 0.1]) * Rotation.from_quat(Q_UNIT)
    assert (pose.rotation[0] * expected.inv()).magnitude() < 1e-12


def test_history_bounds_coverage_and_gaps():
    history = PoseHistory(keep_s=0.1)
    assert history.start_ns is None and not history.covers(T0, T0, 1.0)
    samples, _, _ = spin_samples(11)  # 0 .. 0.2 s
    for s in samples:
        history.add(s)
    # The newest 0.1 s are kept, starting at the last sample at or before their start.
    assert history.start_ns == T0 + NS_PER_S // 10 and history.end_ns == T0 + NS_PER_S // 5
    assert history.covers(T0 + NS_PER_S // 10, T0 + NS_PER_S // 4, 0.05)
    assert not history.covers(T0 + NS_PER_S // 10, T0 + NS_PER_S // 4 + 1, 0.05)
    assert not history.covers(T0 + NS_PER_S // 10 - 1, T0 + NS_PER_S // 5, 0.05)
    assert history.max_gap_ns(T0 + NS_PER_S // 10, T0 + NS_PER_S // 5) == 20_000_000
    # from_ns trims the track to the samples it needs: from the last one at or before it.
    track = history.track(T0, 0.0, from_ns=T0 + 150_000_000)
    np.testing.assert_allclose(track.t_s, [0.14, 0.16, 0.18, 0.2], atol=1e-12)
    history.add(sample(1.0))
    assert history.max_gap_ns(T0 + NS_PER_S // 2, T0 + NS_PER_S // 2 + 1) == 800_000_000
    with pytest.raises(ValueError, match='not after'):
        history.add(sample(1.0))


def test_reason_throttle_counts_suppressed_lines_per_kind():
    throttle = ReasonThrottle(1.0)
    assert throttle.allow('stale', 0.0) == (True, 0)
    assert throttle.allow('stale', 0.5) == (False, 0)
    assert throttle.allow('frame_id', 0.6) == (True, 0)  # other kinds are not held back
    assert throttle.allow('stale', 0.9) == (False, 0)
    assert throttle.allow('stale', 1.2) == (True, 2)
