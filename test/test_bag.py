"""Tests for lidar_sim_ros/io/bag.py: rosbag2 round trips in MCAP and sqlite3."""
import re
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message

from lidar_sim_ros.io.bag import (
    BagContentError, BagWriter, CloudFrame, PoseSeries, read_clouds, read_material_names,
    read_poses,
)
from lidar_sim_ros.io.pointcloud import make_points, to_rclpy_msg

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
MATERIALS = ['mli_gold', 'solar_cell', 'aluminium 6061', 'unknown/ü']


def random_points(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_points(rng.uniform(-50, 50, (n, 3)), rng.random(n), rng.random(n) * 0.1,
                       rng.integers(0, 60, n), rng.integers(0, len(MATERIALS), n))


def assert_points_equal(decoded: np.ndarray, expected: np.ndarray) -> None:
    assert decoded.dtype.names == expected.dtype.names
    for name in expected.dtype.names:
        np.testing.assert_array_equal(decoded[name], expected[name], err_msg=name)


def write_scene(path: Path, storage: str) -> tuple[list[np.ndarray], PoseSeries]:
    """Three clouds (one empty), four poses written out of order, the material names."""
    clouds = [random_points(0, 500), random_points(1, 0), random_points(2, 1234)]
    poses = PoseSeries(
        stamp_ns=T0_NS + PERIOD_NS * np.arange(4, dtype=np.int64),
        frame_id='world',
        position_m=np.array([[10.0, 0, 0], [9.5, 0.1, 0], [9.0, 0.2, -0.1], [8.5, 0.3, -0.2]]),
        quat_xyzw=np.array([[0, 0, 0, 1.0], [0, 0, np.sin(0.05), np.cos(0.05)],
                            [0, np.sin(0.1), 0, np.cos(0.1)], [np.sqrt(0.5), 0, 0, np.sqrt(0.5)]]),
    )
    with BagWriter(path, storage=storage) as bag:
        bag.write_material_names('/lidar/material_names', T0_NS, MATERIALS)
        for i, points in enumerate(clouds):
            bag.write_cloud('/lidar/points', points, T0_NS + i * PERIOD_NS, 'lidar_link')
        for i in (3, 0, 2, 1):
            bag.write_pose('/target/pose', int(poses.stamp_ns[i]), poses.frame_id,
                           poses.position_m[i], poses.quat_xyzw[i])
    return clouds, poses


@pytest.mark.parametrize('storage, suffix', [('mcap', '.mcap'), ('sqlite3', '.db3')])
def test_round_trip(tmp_path: Path, storage: str, suffix: str) -> None:
    path = tmp_path / 'run'
    clouds, poses = write_scene(path, storage)
    assert (path / 'metadata.yaml').is_file()
    assert [p.suffix for p in path.iterdir() if p.name != 'metadata.yaml'] == [suffix]

    frames = read_clouds(path)
    assert [f.stamp_ns for f in frames] == [T0_NS, T0_NS + PERIOD_NS, T0_NS + 2 * PERIOD_NS]
    assert all(isinstance(f, CloudFrame) and f.frame_id == 'lidar_link' for f in frames)
    for frame, points in zip(frames, clouds):
        assert_points_equal(frame.points, points)

    got = read_poses(path)
    assert got.frame_id == 'world'
    assert got.stamp_ns.dtype == np.int64
    np.testing.assert_array_equal(got.stamp_ns, poses.stamp_ns)
    np.testing.assert_array_equal(got.position_m, poses.position_m)
    np.testing.assert_array_equal(got.quat_xyzw, poses.quat_xyzw)

    assert read_material_names(path) == MATERIALS


def test_write_raw_stores_rclpy_cdr(tmp_path: Path) -> None:
    """A DDS recorder's bytes (serialised by rclpy) read back like our own clouds."""
    points = random_points(3, 300)
    with BagWriter(tmp_path / 'rec') as bag:
        cdr = serialize_message(to_rclpy_msg(points, T0_NS, 'lidar_link'))
        bag.write_raw('/lidar/points', 'sensor_msgs/msg/PointCloud2', T0_NS, cdr)
    (frame,) = read_clouds(tmp_path / 'rec')
    assert (frame.stamp_ns, frame.frame_id) == (T0_NS, 'lidar_link')
    assert_points_equal(frame.points, points)


def test_missing_topic_names_topic_and_lists_available(tmp_path: Path) -> None:
    path = tmp_path / 'run'
    write_scene(path, 'mcap')
    with pytest.raises(BagContentError) as info:
        read_clouds(path, topic='/os_cloud_node/points')
    message = str(info.value)
    for expected in ('/os_cloud_node/points', str(path),
                     '/lidar/points (sensor_msgs/msg/PointCloud2)',
                     '/target/pose (geometry_msgs/msg/PoseStamped)',
                     '/lidar/material_names (std_msgs/msg/String)'):
        assert expected in message
    with pytest.raises(BagContentError, match='/nope'):
        read_poses(path, topic='/nope')


def test_wrong_type_names_expected_and_found(tmp_path: Path) -> None:
    path = tmp_path / 'run'
    write_scene(path, 'sqlite3')
    found_expected = 'sensor_msgs/msg/PointCloud2, expected geometry_msgs/msg/PoseStamped'
    with pytest.raises(BagContentError, match=found_expected):
        read_poses(path, topic='/lidar/points')
    with pytest.raises(BagContentError, match='std_msgs/msg/String, expected'):
        read_clouds(path, topic='/lidar/material_names')


def test_material_names_absent_or_malformed(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'a') as bag:
        bag.write_cloud('/lidar/points', random_points(0, 5), T0_NS, 'lidar_link')
        bag.write_string('/bad_names', T0_NS, '{"not": "a list"}')
    assert read_material_names(tmp_path / 'a') is None
    with pytest.raises(BagContentError, match='JSON list of strings'):
        read_material_names(tmp_path / 'a', topic='/bad_names')


def test_existing_or_missing_paths(tmp_path: Path) -> None:
    existing = tmp_path / 'taken'
    existing.mkdir()
    with pytest.raises(FileExistsError, match=re.escape(str(existing))):
        BagWriter(existing)
    write_scene(tmp_path / 'run', 'mcap')
    with pytest.raises(FileExistsError, match='run'):
        BagWriter(tmp_path / 'run', storage='sqlite3')
    with pytest.raises(FileNotFoundError, match='no_such_bag'):
        read_clouds(tmp_path / 'no_such_bag')
    with pytest.raises(ValueError, match="'rosbag1'"):
        BagWriter(tmp_path / 'x', storage='rosbag1')


def test_writer_guards(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'g') as bag:
        bag.write_cloud('/lidar/points', random_points(0, 3), T0_NS, 'lidar_link')
        with pytest.raises(ValueError, match='already carries sensor_msgs/msg/PointCloud2'):
            bag.write_string('/lidar/points', T0_NS, 'hello')
        with pytest.raises(ValueError, match='unit quaternion'):
            bag.write_pose('/target/pose', T0_NS, 'world', [0, 0, 0], [0, 0, 0, 2])
        with pytest.raises(ValueError, match='position_xyz_m'):
            bag.write_pose('/target/pose', T0_NS, 'world', [0, 0], [0, 0, 0, 1])
        with pytest.raises(ValueError, match='not_a/msg/Type'):
            bag.write_raw('/x', 'not_a/msg/Type', T0_NS, b'')


def test_bag_is_readable_after_exception(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match='simulated crash'):
        with BagWriter(tmp_path / 'crash') as bag:
            bag.write_cloud('/lidar/points', random_points(0, 10), T0_NS, 'lidar_link')
            raise RuntimeError('simulated crash')
    assert len(read_clouds(tmp_path / 'crash')) == 1


def test_poses_with_several_frames_are_refused(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'f') as bag:
        bag.write_pose('/target/pose', T0_NS, 'world', [0, 0, 0], [0, 0, 0, 1])
        bag.write_pose('/target/pose', T0_NS + 1, 'chaser', [0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(BagContentError, match=r"\['chaser', 'world'\]"):
        read_poses(tmp_path / 'f')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_material_names_are_recorded_latched(tmp_path, storage):
    """offered_qos_profiles of /lidar/material_names: depth 1, reliable, transient local, as
    the node offers it, in metadata.yaml (Jazzy's v9 list form) and read back by rosbags;
    the clouds keep the empty list (replay defaults)."""
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2 import Reader
    path = tmp_path / 'bag'
    with BagWriter(path, storage=storage) as bag:
        bag.write_material_names('/lidar/material_names', T0_NS, MATERIALS)
        bag.write_cloud('/lidar/points', make_points(np.ones((2, 3)), 0.5, 0.0, 0, 0), T0_NS,
                        'lidar')
    metadata = (path / 'metadata.yaml').read_text()
    assert 'durability: transient_local' in metadata
    with Reader(path) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    (names_qos,) = qos['/lidar/material_names']
    assert names_qos.durability == QosDurability.TRANSIENT_LOCAL
    assert names_qos.reliability == QosReliability.RELIABLE and names_qos.depth == 1
    assert qos['/lidar/points'] == []


def test_qos_is_offered_before_the_first_message(tmp_path):
    with BagWriter(tmp_path / 'bag') as bag:
        bag.write_material_names('/names', T0_NS, MATERIALS)
        with pytest.raises(ValueError, match="'/names' already has messages"):
            bag.offer_qos('/names', [])


def test_a_folder_holding_a_bag_names_it(tmp_path):
    """`lidar-sim compare demo-output` (make demo's folder): the bag inside is suggested."""
    from lidar_sim_ros.io.bag import BagFormatError, bag_kind
    with BagWriter(tmp_path / 'bag') as bag:
        bag.write_material_names('/lidar/material_names', T0_NS, MATERIALS)
    (tmp_path / 'scan_pattern.png').write_bytes(b'')
    with pytest.raises(BagFormatError) as err:
        bag_kind(tmp_path)
    assert str(err.value).endswith(f'; it holds the bag {tmp_path / "bag"}: give that instead')
