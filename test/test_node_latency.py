"""publish_latency_s: frames held to a fixed time after their scan window, over REAL DDS.

A node and the pose player run on the wall clock in two processes; this process receives
the clouds. Held frames must never arrive before window end + latency (a correctness
property, not a speed figure: a loaded machine may make them late, never early).
The thread that holds them is also tested alone with a clock the test controls.
"""
from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from lidar_sim_ros.demo import start as start_ros_process, stop as stop_ros_process
from lidar_sim_ros.ros.deadline import DeadlinePublisher
from lidar_sim_ros.ros.recorder import header_stamp_ns
from conftest import private_domain_id

DOMAIN_ID = private_domain_id(20, 100)  # Fast DDS takes ids <= 232; serial tests run one at a time
LATENCY_S = 0.25
PERIOD_NS = 100_000_000  # the P-60 at 10 Hz

pytestmark = pytest.mark.timeout(150)


def test_deadline_publisher_holds_in_order_and_counts_late():
    published: list[tuple[str, int]] = []
    done = threading.Event()
    held = DeadlinePublisher()
    try:
        now = time.time_ns()
        held.submit(now - 10_000_000, lambda: published.append(('late', time.time_ns())))
        held.submit(now + 60_000_000, lambda: published.append(('a', time.time_ns())))
        held.submit(now + 120_000_000, lambda: (published.append(('b', time.time_ns())), done.set()))
        assert done.wait(10.0)
        late, held_ms, errors = held.take_stats()
    finally:
        held.close()
    assert [name for name, _ in published] == ['late', 'a', 'b']
    assert published[1][1] >= now + 60_000_000 and published[2][1] >= now + 120_000_000
    assert late == 1 and len(held_ms) == 3 and held_ms[0] == 0.0 and errors == []


def test_deadline_publisher_reports_a_failing_publish_and_goes_on():
    done = threading.Event()
    held = DeadlinePublisher()
    try:
        held.submit(0, lambda: 1 / 0)
        held.submit(0, done.set)
        assert done.wait(10.0)
        late, _, errors = held.take_stats()
    finally:
        held.close()
    assert errors == ['ZeroDivisionError: division by zero'] and late == 1


def ros_env() -> dict:
    return {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1'}


def test_held_frames_never_arrive_before_window_end_plus_latency(tmp_path):
    os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('latency_test', context=context)
    received: list[tuple[int, int]] = []  # (header stamp, receipt), ns
    node.create_subscription(PointCloud2, '/lidar/points',
                             lambda raw: received.append((header_stamp_ns(raw), time.time_ns())),
                             QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE), raw=True)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    sim = start_ros_process('lidar_sim_ros.ros.lidar_sim_node',
                            ['-p', 'qos_reliability:=reliable',
                             '-p', f'publish_latency_s:={LATENCY_S}'], ros_env(), tmp_path / 'node.log')
    player = start_ros_process('lidar_sim_ros.ros.target_pose_player', [], ros_env(),
                               tmp_path / 'player.log')
    try:
        deadline = time.monotonic() + 90
        while len(received) < 12 and time.monotonic() < deadline and sim.poll() is None:
            executor.spin_once(timeout_sec=0.1)
    finally:
        codes = stop_ros_process(sim, 20.0), stop_ros_process(player, 20.0)
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    log = (tmp_path / 'node.log').read_text()
    assert codes == (0, 0), log
    assert len(received) >= 12, log
    stamps, receipts = np.array(received).T
    # One cloud per grid slot, in order (reliable QoS: none lost).
    assert np.all(np.diff(stamps) == PERIOD_NS), np.diff(stamps)
    early_ns = stamps + PERIOD_NS + round(LATENCY_S * 1e9) - receipts
    assert np.all(early_ns <= 0), f'clouds arrived {early_ns.max() / 1e6:.1f} ms before their deadline'
