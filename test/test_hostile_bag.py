"""Hostile recordings (issue 22, part 2): each broken input the issue lists is dropped and
counted, or refused naming bag, topic and value, where the bag is read; nothing reaches
the comparison as a plausible-looking number.

Bags are written with rosbags messages built by hand, so that the writer's own checks
(which refuse a non-unit quaternion) do not stop the broken input from being recorded.
"""
from dataclasses import replace as dc_replace

import numpy as np
import pytest

from lidar_sim_ros.compare.recording.measurements import (MAX_POINT_RANGE_M, MeasurementError,
                                                          load_measurements)
from lidar_sim_ros.io.bag import BagWriter
from lidar_sim_ros.io.pointcloud import FLOAT64, UINT8, make_points, to_rosbags_msg

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
N = 400


def _points(rng):
    xyz = rng.uniform(5, 15, (N, 3))
    return make_points(xyz, rng.random(N), np.sort(rng.random(N)) * 0.09, 0, 0)


def write_bag(path, points_edit=None, msg_edit=None, poses_edit=None):
    """Two clouds and five poses around them; the edits break one thing."""
    rng = np.random.default_rng(1)
    stamps = T0_NS + np.arange(-1, 4) * PERIOD_NS // 2
    pos = np.column_stack([10.0 - 0.01 * np.arange(5), np.zeros(5), np.zeros(5)])
    ang = 0.02 * np.arange(5)
    quat = np.column_stack([np.zeros(5), np.zeros(5), np.sin(ang / 2), np.cos(ang / 2)])
    if poses_edit:
        poses_edit(pos, quat)
    with BagWriter(path) as bag:
        T = bag.typestore.types
        for k in range(2):
            points = _points(rng)
            if points_edit:
                points_edit(points)
            msg = to_rosbags_msg(points, T0_NS + k * PERIOD_NS, 'lidar', bag.typestore)
            if msg_edit:
                msg = msg_edit(msg, T)
            bag.write_raw('/lidar/points', 'sensor_msgs/msg/PointCloud2', T0_NS + k * PERIOD_NS,
                          bag.typestore.serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2'))
        for s, p, q in zip(stamps, pos, quat):
            msg = T['geometry_msgs/msg/PoseStamped'](
                header=bag._header(int(s), 'lidar'),
                pose=T['geometry_msgs/msg/Pose'](
                    position=T['geometry_msgs/msg/Point'](x=p[0], y=p[1], z=p[2]),
                    orientation=T['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2], w=q[3])))
            bag.write_raw('/target/pose', 'geometry_msgs/msg/PoseStamped', int(s),
                          bag.typestore.serialize_cdr(msg, 'geometry_msgs/msg/PoseStamped'))
    return path


def test_points_beyond_any_lidar_range_are_dropped_and_counted(tmp_path):
    def far(points):
        points['x'][::10] = 3e38        # 10 % of the points
    meas = load_measurements(write_bag(tmp_path / 'b', points_edit=far))
    assert meas.dropped['beyond_range'] == 2 * N // 10
    assert len(meas) == 2 * N - 2 * N // 10
    assert meas.range_m.max() < 30.0
    assert any('beyond' in n for n in meas.notes)


def test_mostly_garbage_points_refuse_the_bag(tmp_path):
    def far(points):
        points['x'][::2] = 3e38
        points['x'][1::4] = -3e38
    with pytest.raises(MeasurementError, match=f'beyond {MAX_POINT_RANGE_M:g} m'):
        load_measurements(write_bag(tmp_path / 'b', points_edit=far))


@pytest.mark.parametrize('pose', [
    (None, [1.0, 1.0, 0.0, 0.0]),        # not unit: "missing effect: time_offset"
    ([np.nan, 0.0, 0.0], None),          # NaN position: "up to noise", 8x slower
    (None, [0.0, 0.0, 0.0, 0.0]),        # zero quaternion: scipy's message, no bag named
    (None, [np.nan, 0.0, 0.0, 1.0]),
    ([1e300, 0.0, 0.0], None),           # finite but absurd: "0 of N rays hit", the pose blamed
])
def test_one_bad_pose_is_dropped_counted_and_noted(tmp_path, pose):
    def edit(pos, quat):
        if pose[0] is not None:
            pos[2] = pose[0]
        if pose[1] is not None:
            quat[2] = pose[1]
    meas = load_measurements(write_bag(tmp_path / 'b', poses_edit=edit))
    assert meas.dropped['bad_poses'] == 1
    assert any("1 of 5 pose(s) on '/target/pose' dropped" in n for n in meas.notes)
    # The track interpolates over the good samples only: unit and finite everywhere, and
    # the z rotation is the recorded 0.02 rad per sample (an independent closed form).
    poses = meas.poses.at(meas.t_s)
    assert np.allclose(np.linalg.norm(poses.quat_xyzw, axis=1), 1.0)
    assert np.isfinite(poses.position_m).all()
    assert np.all(np.abs(poses.rotation.as_rotvec()[:, 2]) < 0.1)


def test_no_usable_pose_names_bag_and_topic(tmp_path):
    def edit(pos, quat):
        quat[:] = 0.0
    with pytest.raises(MeasurementError, match=r"none of the 5 pose\(s\) on '/target/pose'") as err:
        load_measurements(write_bag(tmp_path / 'b', poses_edit=edit))
    assert str(tmp_path / 'b') in str(err.value)


def test_x_declared_uint8_is_refused(tmp_path):
    def edit(msg, T):
        fields = [dc_replace(f, datatype=UINT8) if f.name == 'x' else f for f in msg.fields]
        return dc_replace(msg, fields=fields)
    with pytest.raises(MeasurementError, match=r'declares x \(uint8\).*FLOAT32 or FLOAT64'):
        load_measurements(write_bag(tmp_path / 'b', msg_edit=edit))


def test_float64_fields_over_float32_data_are_refused(tmp_path):
    def edit(msg, T):
        fields = [dc_replace(f, datatype=FLOAT64) if f.name in 'xyz' else f for f in msg.fields]
        return dc_replace(msg, fields=fields)
    with pytest.raises(MeasurementError, match=r"cloud #0 on '/lidar/points'.*overlap"):
        load_measurements(write_bag(tmp_path / 'b', msg_edit=edit))


def test_big_endian_flag_on_little_endian_data_is_refused(tmp_path):
    def edit(msg, T):
        return dc_replace(msg, is_bigendian=True)
    with pytest.raises(MeasurementError, match='is_bigendian'):
        load_measurements(write_bag(tmp_path / 'b', msg_edit=edit))


def test_nan_point_times_are_dropped_and_counted(tmp_path):
    def nan_t(points):
        points['t'][::20] = np.nan
    meas = load_measurements(write_bag(tmp_path / 'b', points_edit=nan_t))
    assert meas.dropped['bad_time'] == 2 * N // 20
    assert np.isfinite(meas.t_s).all()


def test_clouds_are_dense_only_when_finite_in_float32():
    # 1e300 m is finite in float64 but inf in the float32 cloud: refused, not published.
    with pytest.raises(ValueError, match='float32 range'):
        make_points(np.array([[1.0, 2.0, 3.0], [1e300, 0.0, 0.0]]), 0.0, 0.0, 0, 0)


def test_cloud_size_is_limited(monkeypatch, tmp_path):
    import lidar_sim_ros.io.pointcloud as pc
    monkeypatch.setattr(pc, 'MAX_CLOUD_POINTS', N - 1)
    with pytest.raises(MeasurementError, match=f'exceeds the limit of {N - 1} points per cloud'):
        load_measurements(write_bag(tmp_path / 'b'))


def test_dropped_input_is_said_on_the_terminal():
    from lidar_sim_ros.compare.command import dropped_line
    assert dropped_line({'non_finite': 5, 'subsampled': 9, 'beyond_range': 0}) is None
    line = dropped_line({'beyond_range': 40, 'bad_poses': 1})
    assert line.startswith('dropped as unusable: 40 points beyond 10 km, 1 poses')


def test_tracker_node_keeps_only_usable_points():
    # The pose tracker node's input: NaN, origin and 3e38 points left out; integer x refused.
    from lidar_sim_ros.gnc.pose_tracker_node import usable_xyz_m
    pts = make_points(np.array([[10.0, 0, 0], [0, 0, 0], [3e38, 0, 0], [5.0, 1.0, 0]]), 0.0, 0.0, 0, 0)
    pts['y'][1] = np.nan
    np.testing.assert_array_equal(usable_xyz_m(pts), [[10.0, 0, 0], [5.0, 1.0, 0]])
    bad = np.zeros(3, dtype=[('x', 'u1'), ('y', 'f4'), ('z', 'f4')])
    with pytest.raises(ValueError, match='FLOAT32 or FLOAT64'):
        usable_xyz_m(bad)
