"""lidar_sim_node with point_layout: cepton over REAL DDS: a subscriber written against the
Cepton driver (topic cepton_pcl2, frame cepton3, fields decoded by name and datatype)
reads our clouds unchanged; the sensor mount goes out as a static transform when tf2_msgs
is installed, and the node says so once when it is not."""
from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import Log
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import PointCloud2

from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.demo import start as start_ros_process, stop as stop_ros_process
from lidar_sim_ros.io.pointcloud import stamp_to_ns
from lidar_sim_ros.paths import config_path
from conftest import private_domain_id
from test_cepton_layout import DRIVER_FIELDS, NO_RETURN, read_points

DOMAIN_ID = private_domain_id(160, 1)
NS = 1_000_000_000
PERIOD_NS = 100_000_000
POSE_STEP_NS = 20_000_000
TRAJECTORY = ScenarioTrajectory.from_config(load_scenario(config_path('scenario.yaml')).config)
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
BLOCK_NS = 10 * NS

pytestmark = pytest.mark.timeout(120)


def test_cepton_layout_over_dds(tmp_path):
    env = {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1'}
    log = tmp_path / 'node.log'
    proc = start_ros_process('lidar_sim_ros.ros.lidar_sim_node', [
        '-p', 'use_sim_time:=true', '-p', 'qos_reliability:=reliable',
        '-p', 'pose_qos_reliability:=reliable', '-p', 'point_layout:=cepton',
        '-p', 'no_return_points:=true', '-p', 'mount_parent_frame:=base_link',
        '-p', 'mount_translation_m:=[1.0, 0.0, 0.5]'], env, log)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    node = rclpy.create_node('cepton_subscriber', context=ctx)
    clouds: dict[int, PointCloud2] = {}
    rosout: list[Log] = []
    node.create_subscription(PointCloud2, 'cepton_pcl2',
                             lambda m: clouds.__setitem__(stamp_to_ns(m.header.stamp), m),
                             RELIABLE)
    node.create_subscription(Log, '/rosout', rosout.append, QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    clock_pub = node.create_publisher(Clock, '/clock', RELIABLE)
    pose_pub = node.create_publisher(PoseStamped, '/target/pose', RELIABLE)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()

    def clock(t_ns):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), NS)
        clock_pub.publish(msg)

    def pose(t_ns):
        p = TRAJECTORY.at((t_ns - BLOCK_NS) / NS)
        msg = PoseStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(t_ns), NS)
        msg.header.frame_id = 'cepton3'
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(
            float, p.position_m[0])
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = map(float, p.rotation.as_quat()[0])
        pose_pub.publish(msg)

    def wait(pred, what, timeout_s=30.0):
        end = time.monotonic() + timeout_s
        while not pred():
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < end, f'timed out waiting for {what}\n{log.read_text()}'
            time.sleep(0.05)

    try:
        wait(lambda: node.count_publishers('cepton_pcl2') and node.count_subscribers('/clock')
             and node.count_subscribers('/target/pose'), 'the node to come up')
        time.sleep(0.5)
        clock(BLOCK_NS)
        time.sleep(0.3)
        clock(BLOCK_NS)
        for t in range(BLOCK_NS - 3 * POSE_STEP_NS, BLOCK_NS + PERIOD_NS + 2 * POSE_STEP_NS,
                       POSE_STEP_NS):
            pose(t)
        time.sleep(0.2)

        def tick():
            clock(BLOCK_NS + PERIOD_NS)
            return BLOCK_NS in clouds
        wait(tick, 'the first cepton cloud')
        msg = clouds[BLOCK_NS]
        assert msg.header.frame_id == 'cepton3'
        assert [(f.name, f.datatype) for f in msg.fields] == DRIVER_FIELDS
        pts = read_points(msg)
        t_us = np.array([p['timestamp_s'] * 1_000_000 + p['timestamp_us'] for p in pts])
        assert t_us.min() >= BLOCK_NS // 1000 and t_us.max() < (BLOCK_NS + PERIOD_NS) // 1000
        flags = np.array([p['flags'] for p in pts])
        inten = np.array([p['intensity'] for p in pts])
        assert np.sum(flags == 0) > 1000 and np.any(flags == NO_RETURN)
        assert np.all(inten[flags == 0] >= 0)   # specular glints may read above 1
        assert np.median(inten[flags == 0]) > 0.05
        try:
            import tf2_msgs  # noqa: F401
        except ImportError:
            wait(lambda: any('tf2_msgs is not installed' in m.msg for m in rosout),
                 'the tf2_msgs warning')
    finally:
        code = stop_ros_process(proc)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert code == 0, log.read_text()
