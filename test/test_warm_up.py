"""First start on a cold numba cache: no catch-up burst, no stale poses; warm_up caches every kernel.

The node and the pose player run with ``NUMBA_CACHE_DIR`` set to an empty directory,
so both compile their kernels as on a fresh install (~10 s: the one slow test here).
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from rcl_interfaces.msg import Log
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from lidar_sim_ros.demo import start as start_ros_process, stop as stop_ros_process
from lidar_sim_ros.io.pointcloud import stamp_to_ns
from lidar_sim_ros.warm_up import _calls, cached_kernels
from conftest import private_domain_id

REPO = Path(__file__).resolve().parents[1]
PARAMS = REPO / 'config' / 'params.yaml'
DOMAIN_ID = private_domain_id(20, 100)
PERIOD_NS = 100_000_000  # P-60 at 10 Hz
FRAMES = 6
# A frame is published once its window has ended and it is computed; a catch-up burst
# publishes frames whose windows ended seconds before (while the node was compiling).
MAX_LATENCY_S = 0.5
SYMPTOMS = ('stale', 'clock jumped', 'not published')


@pytest.mark.timeout(240)
def test_cold_first_start_publishes_on_the_grid_and_warm_up_caches_every_kernel(tmp_path):
    cache = tmp_path / 'numba_cache'
    cache.mkdir()
    env = {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1',
           'NUMBA_CACHE_DIR': str(cache)}
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('warm_up_test', context=context)
    clouds: list[tuple[int, int]] = []  # (stamp ns, receipt wall time ns)
    rosout: list[Log] = []
    node.create_subscription(PointCloud2, '/lidar/points',
                             lambda m: clouds.append((stamp_to_ns(m.header.stamp), time.time_ns())),
                             QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    node.create_subscription(Log, '/rosout', rosout.append,
                             QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    logs = {name: tmp_path / f'{name}.log' for name in ('lidar_sim_node', 'target_pose_player')}
    node_args = {'lidar_sim_node': ('-p', 'qos_reliability:=reliable'), 'target_pose_player': ()}
    procs = {name: start_ros_process(f'lidar_sim_ros.ros.{name}',
                                     ['--params-file', str(PARAMS), *node_args[name]], env, logs[name])
             for name in logs}
    try:
        deadline = time.monotonic() + 150
        while len(clouds) < FRAMES:
            executor.spin_once(timeout_sec=0.05)
            assert all(p.poll() is None for p in procs.values()), {n: l.read_text() for n, l in logs.items()}
            assert time.monotonic() < deadline, f'{len(clouds)} clouds; ' + logs['lidar_sim_node'].read_text()
        for _ in range(20):
            executor.spin_once(timeout_sec=0.01)  # late /rosout lines
    finally:
        for proc in procs.values():
            stop_ros_process(proc)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)

    stamps = [s for s, _ in clouds[:FRAMES]]
    assert all(b - a == PERIOD_NS for a, b in zip(stamps, stamps[1:])), stamps
    latency_s = [(received - stamp - PERIOD_NS) / 1e9 for stamp, received in clouds[:FRAMES]]
    assert max(latency_s) < MAX_LATENCY_S, (latency_s, logs['lidar_sim_node'].read_text())
    warnings = [m.msg for m in rosout if m.level >= Log.WARN and m.name in logs]
    assert not [w for w in warnings if any(s in w for s in SYMPTOMS)], warnings

    # The install-time warm-up completes the cache (the player's kernel included) and
    # checks that it compiled every cached kernel of the package.
    run = subprocess.run([sys.executable, '-m', 'lidar_sim_ros.warm_up'], env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    cached = {p.name.split('-')[0] for p in cache.rglob('*.nbi')}
    # numba names a cache file module.function (e.g. pose._slerp_track, in a folder per
    # subpackage: effects/beam_divergence._walk-602.py311.nbi). A kernel called only
    # from other kernels may have no file of its own: its code is in its callers'.
    kernels = cached_kernels()
    short = {name: '.'.join(name.split('.')[-2:]) for name in kernels}
    on_disk = {name for name in kernels if short[name] in cached}
    inside = {name for name in kernels if any(_calls(kernels[c], kernels[name]) for c in on_disk)}
    assert on_disk and set(kernels) <= on_disk | inside, (sorted(kernels), sorted(cached))
