"""io/bag.py open_bag: a bare .mcap and a ROS 1 .bag read like a rosbag2 directory; anything else
gets one line.

The ROS 1 bag is written with rosbags' rosbag1 Writer from ROS 1 (Noetic) messages in
ROS 1 serialisation, headers with ``seq``, as a ROS 1 recorder would; the bare MCAP is
the storage file of a rosbag2 directory without its metadata.yaml, as Foxglove and
``ros2 bag record`` write them. Both are read back through ``load_measurements``, the
path ``lidar-sim compare`` takes.
"""
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Rosbag1Writer
from rosbags.typesys import Stores, get_typestore

from lidar_sim_ros.compare.recording.measurements import load_measurements
from lidar_sim_ros.io.bag import (BagFormatError, BagWriter, bag_kind, read_clouds, read_material_names,
                                  read_poses)
from lidar_sim_ros.io.pointcloud import make_points, to_rosbags_msg

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
NAMES = ['PIF', 'MLI']


def scene():
    """Two clouds with per-point t, five poses around them."""
    rng = np.random.default_rng(3)
    clouds = [make_points(rng.uniform(5, 15, (n, 3)), rng.random(n), np.sort(rng.random(n)) * 0.1,
                          rng.integers(0, 24, n), rng.integers(0, 2, n)) for n in (300, 450)]
    stamps = T0_NS + np.arange(-1, 4) * PERIOD_NS // 2
    positions = np.column_stack([10.0 - 0.01 * np.arange(5), np.zeros(5), np.zeros(5)])
    angles = 0.02 * np.arange(5)
    quats = np.column_stack([np.zeros(5), np.zeros(5), np.sin(angles / 2), np.cos(angles / 2)])
    return clouds, stamps, positions, quats


def write_rosbag2(path: Path) -> Path:
    clouds, stamps, positions, quats = scene()
    with BagWriter(path) as bag:
        bag.write_material_names('/lidar/material_names', T0_NS, NAMES)
        for k, points in enumerate(clouds):
            bag.write_cloud('/lidar/points', points, T0_NS + k * PERIOD_NS, 'lidar')
        for s, p, q in zip(stamps, positions, quats):
            bag.write_pose('/target/pose', int(s), 'lidar', p, q)
    return path


def write_rosbag1(path: Path) -> Path:
    """The same scene as a ROS 1 recorder would write it (Noetic types and md5sums)."""
    clouds, stamps, positions, quats = scene()
    noetic, jazzy = get_typestore(Stores.ROS1_NOETIC), get_typestore(Stores.ROS2_JAZZY)
    T = noetic.types
    time_of = lambda ns: T['builtin_interfaces/msg/Time'](sec=int(ns) // 10**9, nanosec=int(ns) % 10**9)  # noqa: E731
    with Rosbag1Writer(path) as bag:
        conns = {topic: bag.add_connection(topic, msgtype, typestore=noetic) for topic, msgtype in (
            ('/lidar/material_names', 'std_msgs/msg/String'),
            ('/lidar/points', 'sensor_msgs/msg/PointCloud2'),
            ('/target/pose', 'geometry_msgs/msg/PoseStamped'))}

        def write(topic, stamp_ns, msg):
            bag.write(conns[topic], int(stamp_ns), noetic.serialize_ros1(msg, conns[topic].msgtype))

        write('/lidar/material_names', T0_NS, T['std_msgs/msg/String'](data='["PIF", "MLI"]'))
        for k, points in enumerate(clouds):
            stamp = T0_NS + k * PERIOD_NS
            m2 = to_rosbags_msg(points, stamp, 'lidar', jazzy)  # the ROS 2 message, fields copied
            fields = [T['sensor_msgs/msg/PointField'](name=f.name, offset=f.offset, datatype=f.datatype,
                                                      count=f.count) for f in m2.fields]
            write('/lidar/points', stamp, T['sensor_msgs/msg/PointCloud2'](
                header=T['std_msgs/msg/Header'](seq=k, stamp=time_of(stamp), frame_id='lidar'),
                height=m2.height, width=m2.width, fields=fields, is_bigendian=m2.is_bigendian,
                point_step=m2.point_step, row_step=m2.row_step, data=m2.data, is_dense=m2.is_dense))
        for j, (s, p, q) in enumerate(zip(stamps, positions, quats)):
            write('/target/pose', s, T['geometry_msgs/msg/PoseStamped'](
                header=T['std_msgs/msg/Header'](seq=j, stamp=time_of(s), frame_id='lidar'),
                pose=T['geometry_msgs/msg/Pose'](
                    position=T['geometry_msgs/msg/Point'](x=p[0], y=p[1], z=p[2]),
                    orientation=T['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2], w=q[3]))))
    return path


@pytest.fixture()
def inputs(tmp_path):
    """The same scene as a rosbag2 directory, a bare MCAP file and a ROS 1 bag."""
    directory = write_rosbag2(tmp_path / 'run')
    bare = tmp_path / 'foxglove.mcap'
    shutil.copy(next(directory.glob('*.mcap')), bare)
    return {'rosbag2 directory': directory, 'MCAP file': bare,
            'ROS 1 bag': write_rosbag1(tmp_path / 'lab.bag')}


def test_every_kind_reads_the_same_clouds_poses_and_names(inputs):
    clouds, stamps, positions, quats = scene()
    for kind, path in inputs.items():
        assert bag_kind(path) == kind
        frames = read_clouds(path)
        assert [f.stamp_ns for f in frames] == [T0_NS, T0_NS + PERIOD_NS], kind
        assert all(f.frame_id == 'lidar' for f in frames)
        for frame, points in zip(frames, clouds):
            for name in points.dtype.names:
                np.testing.assert_array_equal(frame.points[name], points[name], err_msg=f'{kind} {name}')
        poses = read_poses(path)
        np.testing.assert_array_equal(poses.stamp_ns, stamps)
        np.testing.assert_array_equal(poses.position_m, positions)
        np.testing.assert_array_equal(poses.quat_xyzw, quats)
        assert read_material_names(path) == NAMES, kind


def test_compare_loads_measurements_from_every_kind(inputs):
    loaded = {kind: load_measurements(path) for kind, path in inputs.items()}
    reference = loaded['rosbag2 directory']
    assert len(reference.range_m) == 750 and reference.has_point_time
    for kind, m in loaded.items():
        np.testing.assert_array_equal(m.xyz_m, reference.xyz_m, err_msg=kind)
        np.testing.assert_array_equal(m.t_s, reference.t_s, err_msg=kind)
        np.testing.assert_allclose(m.poses.at(m.t_s).position_m, reference.poses.at(m.t_s).position_m)


def test_anything_else_gets_one_line(tmp_path, inputs):
    no_meta = tmp_path / 'no_metadata'
    shutil.copytree(inputs['rosbag2 directory'], no_meta)
    (no_meta / 'metadata.yaml').unlink()
    (tmp_path / 'empty').mkdir()
    (tmp_path / 'notes.txt').write_text('not a bag\n')
    (tmp_path / 'broken.mcap').write_bytes(b'\x89MCAP0\r\n' + bytes(100))
    (tmp_path / 'broken.bag').write_text('#ROSBAG V2.0\ngarbage\n')
    cases = {
        no_meta: r'no_metadata is a directory without metadata\.yaml.*it holds run\.mcap: give that file',
        tmp_path / 'empty': r'empty is a directory without metadata\.yaml, so not a rosbag2 bag \(expected a '
                            r'rosbag2 directory',
        tmp_path / 'notes.txt': r'notes\.txt is not a bag: expected .* got a \.txt file',
        tmp_path / 'broken.mcap': r'broken\.mcap: cannot read this MCAP file',
        tmp_path / 'broken.bag': r'broken\.bag: cannot read this ROS 1 bag',
    }
    for path, message in cases.items():
        with pytest.raises(BagFormatError, match=message) as info:
            read_clouds(path)
        assert '\n' not in str(info.value)
    with pytest.raises(FileNotFoundError, match='does not exist'):
        read_clouds(tmp_path / 'nowhere.mcap')


def test_the_cli_prints_the_line_without_a_traceback(tmp_path):
    (tmp_path / 'empty').mkdir()
    run = subprocess.run([sys.executable, '-m', 'lidar_sim_ros.cli', 'calibrate', 'scan', str(tmp_path / 'empty'),
                          '--out', str(tmp_path / 'scan.yaml')], capture_output=True, text=True)
    assert run.returncode == 2, run.stderr
    assert run.stderr.count('\n') == 1 and 'directory without metadata.yaml' in run.stderr, run.stderr
