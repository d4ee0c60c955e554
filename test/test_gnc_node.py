"""pose_tracker over real DDS: clouds of a known box in, PoseStamped at mid-scan out.

The node runs as its own process on a private domain with a box mesh, capturing either
from an initial guess (with the pose topic set) or, by default, from the cloud alone;
the test publishes clouds built from the box's closed form (see
test_gnc_tracker.box_scan) and one pose far off on /target/pose, which the node must
ignore (tracking, or not subscribed at all).
"""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import PointCloud2

pytest.importorskip('small_gicp')

from lidar_sim_ros.gnc.tracker import pose_matrix, pose_parts  # noqa: E402
from lidar_sim_ros.io.pointcloud import make_points, stamp_to_ns, to_rclpy_msg  # noqa: E402
from test_gnc_acquire import BOX_ACQUISITION, BOX_TURNS  # noqa: E402
from test_gnc_tracker import HALF, box_scan, errors, nudged  # noqa: E402
from conftest import private_domain_id  # noqa: E402

DOMAIN_ID = private_domain_id(220, 10)
NS = 1_000_000_000
PERIOD_NS = 100_000_000


def write_box(folder):
    """The box as an OBJ whose faces carry the material PIF (known to the default config)."""
    v = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * HALF
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    lines = ['mtllib box.mtl'] + [f'v {x} {y} {z}' for x, y, z in v] + ['usemtl PIF']
    lines += [f'f {a + 1} {b + 1} {c + 1}\nf {a + 1} {c + 1} {d + 1}' for a, b, c, d in quads]
    (folder / 'box.obj').write_text('\n'.join(lines) + '\n')
    (folder / 'box.mtl').write_text('newmtl PIF\nKd 0.8 0.5 0.2\n')
    return folder / 'box.obj'


def capture_args(capture, guess_position, guess_quat):
    """The node's capture: from an initial guess (the truth topic set too), or acquisition."""
    if capture == 'initial_pose':
        return ['-p', f'initial_pose:={[*map(float, guess_position), *map(float, guess_quat)]}',
                '-p', 'pose_topic:=/target/pose']
    acquisition = BOX_ACQUISITION.model_dump(exclude={'primary_axis_body'})
    return [arg for name, value in acquisition.items() for arg in ('-p', f'acquire.{name}:={value}')]


@pytest.mark.timeout(120)
@pytest.mark.parametrize('capture', ['initial_pose', 'acquisition'])
def test_the_node_tracks_a_box_and_stamps_mid_scan(tmp_path, capture):
    truth = pose_matrix([6.0, 0.5, -0.3], Rotation.from_euler('xyz', [20, -35, 50], degrees=True).as_quat())
    axis, rate, v = np.array([0.0, 0.3, 1.0]) / np.hypot(0.3, 1.0), np.radians(15.0), np.array([-0.1, 0.05, 0])

    def at(t_s):
        return pose_matrix(truth[:3, 3] + v * t_s,
                           (Rotation.from_rotvec(rate * t_s * axis) * Rotation.from_matrix(truth[:3, :3])).as_quat())

    guess_position, guess_quat = pose_parts(nudged(at(0.05)))
    log = tmp_path / 'pose_tracker.log'
    env = {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1'}
    with open(log, 'wb') as fh:
        proc = subprocess.Popen(
            [sys.executable, '-m', 'lidar_sim_ros.gnc.pose_tracker_node', '--ros-args',
             '-p', f'mesh_file:={write_box(tmp_path)}', '-p', 'model_spacing_m:=0.02', '-p', 'scan_voxel_m:=0.0',
             *capture_args(capture, guess_position, guess_quat)],
            env=env, stdout=fh, stderr=subprocess.STDOUT)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('pose_tracker_test', context=context)
    estimates: list[PoseStamped] = []
    node.create_subscription(PoseStamped, '/target/pose_estimate', estimates.append, 10)
    clouds = node.create_publisher(PointCloud2, '/lidar/points',
                                   QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    poses = node.create_publisher(PoseStamped, '/target/pose', 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin_until(predicate, timeout_s, what):
        deadline = time.monotonic() + timeout_s
        while not predicate():
            executor.spin_once(timeout_sec=0.02)
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, f'timed out waiting for {what}:\n{log.read_text()}'

    t0_ns = 1_800_000_000 * NS
    try:
        spin_until(lambda: node.count_subscribers('/lidar/points') > 0, 60, 'the node')
        time.sleep(0.3)
        far = PoseStamped()
        far.header.frame_id, far.pose.position.x, far.pose.orientation.w = 'lidar', 50.0, 1.0
        poses.publish(far)  # a capture guess far off: initial_pose wins (or no subscriber)
        for k in range(5):
            stamp = t0_ns + k * PERIOD_NS
            xyz = box_scan(at(k * 0.1 + 0.05))
            n = len(xyz)
            clouds.publish(to_rclpy_msg(make_points(xyz, np.ones(n), np.zeros(n), np.zeros(n, int),
                                                    np.zeros(n, int)), stamp, 'lidar'))
            spin_until(lambda: len(estimates) == k + 1, 20, f'estimate {k}')
    finally:
        proc.send_signal(2)
        # The exit code is the check, not how fast it comes: a registration in progress
        # (C++, GIL released) finishes before the interrupt is seen, slowly on a busy machine.
        proc.wait(timeout=30)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)

    assert proc.returncode == 0, log.read_text()
    for k, msg in enumerate(estimates):
        assert stamp_to_ns(msg.header.stamp) == t0_ns + k * PERIOD_NS + PERIOD_NS // 2
        assert msg.header.frame_id == 'lidar'
        p, q = msg.pose.position, msg.pose.orientation
        estimate = pose_matrix([p.x, p.y, p.z], [q.x, q.y, q.z, q.w])
        # Acquired, the box is known up to its two-fold turns (test_gnc_acquire.py).
        dt, dr = min(errors(estimate @ turn, at(k * 0.1 + 0.05)) for turn in BOX_TURNS)
        assert dt < 2e-3 and dr < 0.1, (k, dt, dr)
    if capture == 'acquisition':
        assert 'capture from the cloud alone' in log.read_text()
        assert 'acquisition at' in log.read_text() and ': acquired, score' in log.read_text()


@pytest.mark.parametrize('args, message', [
    (['-p', 'scan_voxel_m:=-1.0'], 'key "scan_voxel_m" = -1.0: Input should be greater than or equal to 0'),
    (['-p', 'initial_pose:=[1.0, 2.0]'], 'key "initial_pose" = [1.0, 2.0]: expected [x, y, z, qx, qy, qz, qw]'),
    (['-p', 'acquire.voxel_m:=-0.3'], 'key "acquire.voxel_m" = -0.3: Input should be greater than 0'),
])
def test_bad_parameters_stop_the_node_with_one_line(args, message):
    env = {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID)}
    run = subprocess.run([sys.executable, '-m', 'lidar_sim_ros.gnc.pose_tracker_node', '--ros-args', *args],
                         env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    fatal = [line for line in (run.stdout + run.stderr).splitlines() if 'FATAL' in line]
    assert len(fatal) == 1 and message in fatal[0], run.stdout + run.stderr


def test_acquisition_field_of_view_of_every_scan_type():
    """The tracker's acquisition searches the sensor's field: a rosette's circle (its
    bounding square), a flash array's rectangle, the P-60's."""
    from lidar_sim_ros.core.config import load_sensor
    from lidar_sim_ros.gnc.pose_tracker_node import sensor_fov
    config = os.path.join(os.path.dirname(__file__), '..', 'config')
    fov = {name: sensor_fov(load_sensor(os.path.join(config, name)).scan)
           for name in ('livox_mid40.yaml', 'flash_256.yaml', 'cepton_vista_p60.yaml')}
    assert fov['livox_mid40.yaml'] == pytest.approx({'fov_az_deg': 38.4, 'fov_el_deg': 38.4})
    assert fov['flash_256.yaml'] == {'fov_az_deg': 20.0, 'fov_el_deg': 20.0}
    assert fov['cepton_vista_p60.yaml'] == {'fov_az_deg': 60.0, 'fov_el_deg': 22.0}


def test_a_cad_mesh_file_needs_no_material_map():
    """mesh_file = the box-wing .glb under the rocket body's scenario stopped the tracker
    at start-up ("['antenna_aluminium', 'bus_mli', ...] not mapped") though it reads the
    shape alone; every part is now one material to it. In process (no DDS traffic)."""
    from rclpy.parameter import Parameter
    from lidar_sim_ros.core.geometry import read_target_mesh
    from lidar_sim_ros.gnc.pose_tracker_node import PoseTrackerNode
    glb = os.path.join(os.path.dirname(__file__), '..', 'meshes', 'box_wing_satellite.glb')
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = PoseTrackerNode(context=context, parameter_overrides=[
        Parameter('mesh_file', Parameter.Type.STRING, glb)])
    try:
        node.setup()
        # The model is sampled on the satellite's surface: its box is the mesh's (the
        # 10.6 m wing span), to the sampling's spacing.
        vertices_m, _, _ = read_target_mesh(glb, ['X'], mesh_materials='X')
        points = node.tracker.model.points_m
        spacing = node.config.model_spacing_m
        np.testing.assert_allclose(points.min(axis=0), vertices_m.min(axis=0), atol=4 * spacing)
        np.testing.assert_allclose(points.max(axis=0), vertices_m.max(axis=0), atol=4 * spacing)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
