"""The bag recorder's stamp window: header stamps read from CDR, cloud counts on the frame grid."""
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from lidar_sim_ros.gnc.demo import published
from lidar_sim_ros.io.bag import BagWriter, read_poses
from lidar_sim_ros.ros.recorder import BagRecorder, TopicSpec, header_stamp_ns
from conftest import private_domain_id

DOMAIN_ID = private_domain_id(20, 100)


def spin_until(executor: SingleThreadedExecutor, done, timeout_s: float = 20.0) -> None:
    """Spin ``executor`` until ``done()`` or ``timeout_s`` (the caller asserts)."""
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)


@pytest.mark.parametrize('msg_class', [PointCloud2, PoseStamped])
@pytest.mark.parametrize('sec,nanosec', [(0, 0), (1_795_448_987, 440_000_000), (-3, 999_999_999)])
def test_header_stamp_read_from_rclpy_cdr(msg_class, sec, nanosec):
    msg = msg_class()
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.header.frame_id = 'lidar'
    assert header_stamp_ns(serialize_message(msg)) == sec * 1_000_000_000 + nanosec


def test_header_stamp_rejects_a_truncated_message():
    with pytest.raises(ValueError, match='too few'):
        header_stamp_ns(b'\x00\x01\x00\x00\x05')


def test_published_counts_the_grid_between_received_stamps():
    step = 100_000_000
    got = {7 + k * step for k in (3, 4, 7, 9)}  # best effort lost 5, 6, 8
    # grid stamps 7 + k*step in [3.5 step, 9.5 step): k = 4..9
    assert published(got, int(3.5 * step), int(9.5 * step)) == 6
    assert published(got, 0, 10 * step) == 10
    assert published({7}, 0, step) == 1 and published(set(), 0, step) == 0


def test_armed_recorder_drops_messages_stamped_before_the_window(tmp_path):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('recorder_window_test', context=context)
    try:
        reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        pub = node.create_publisher(PoseStamped, '/window/pose', reliable)
        bag = tmp_path / 'bag'
        with BagWriter(bag) as writer:
            spec = TopicSpec('/window/pose', PoseStamped, 'geometry_msgs/msg/PoseStamped')
            recorder = BagRecorder(node, writer, [spec], armed=False)
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            spin_until(executor, lambda: recorder.subscribed)
            assert recorder.subscribed
            since = 50 * 1_000_000_000
            recorder.arm(since)
            stamps = [since - 20_000_000, since, since + 20_000_000]  # a late one, then the window
            for ns in stamps:
                msg = PoseStamped()
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
                msg.header.frame_id = 'lidar'
                msg.pose.orientation.w = 1.0
                pub.publish(msg)
            spin_until(executor, lambda: recorder.seen['/window/pose'] >= 3)
            recorder.close()
            executor.shutdown()
        assert recorder.seen['/window/pose'] == 3 and recorder.counts['/window/pose'] == 2
        np.testing.assert_array_equal(read_poses(bag, '/window/pose').stamp_ns, stamps[1:])
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_recorded_topics_keep_their_publishers_qos(tmp_path):
    """A latched publisher (depth 1, reliable, transient local) is recorded with that QoS in
    offered_qos_profiles, so that a replay republishes it latched."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('recorder_qos_test', context=context)
    try:
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        pub = node.create_publisher(String, '/qos/names', latched)
        pub.publish(String(data='["PIF"]'))
        bag = tmp_path / 'bag'
        with BagWriter(bag) as writer:
            spec = TopicSpec('/qos/names', String, 'std_msgs/msg/String', stamped=False)
            recorder = BagRecorder(node, writer, [spec])
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            spin_until(executor, lambda: recorder.counts['/qos/names'] >= 1)
            recorder.close()
            executor.shutdown()
        assert recorder.counts['/qos/names'] == 1
        with Reader(bag) as reader:
            (conn,) = reader.connections
            (offered,) = conn.ext.offered_qos_profiles
        assert offered.durability == QosDurability.TRANSIENT_LOCAL
        assert offered.reliability == QosReliability.RELIABLE
        # (the depth is not: DDS discovery does not carry it, and ros2 bag record's is 0 too)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
