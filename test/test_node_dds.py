"""lidar_sim_node and target_pose_player over REAL DDS (no rclpy mocks).

One node process (use_sim_time, reliable clouds and poses, truth on) serves the module. The test
process publishes /clock and poses and receives the clouds and /rosout. Each test
works in its own block of simulated time, later blocks later, so the shared node
sees a clock that only moves forward; it jumps between blocks, which also exercises
the catch-up cap. The ROS domain is derived from the pid, so parallel runs do not cross.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import trimesh
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Log
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.demo import start as start_ros_process, stop as stop_ros_process
from lidar_sim_ros.io.bag import BagWriter, read_clouds, read_material_names, read_poses
from lidar_sim_ros.io.pointcloud import from_pointcloud2, stamp_to_ns
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros.pose_input import PoseHistory, PoseSample
from lidar_sim_ros.ros.recorder import BagRecorder
from conftest import embree_range_tol_m, private_domain_id

DOMAIN_ID = private_domain_id(120, 100)
REPO = Path(__file__).resolve().parents[1]
PARAMS = REPO / 'config' / 'params.yaml'
NS = 1_000_000_000
PERIOD_NS = 100_000_000            # P-60 at 10 Hz
POSE_STEP_NS = 20_000_000          # poses at 50 Hz
SCENARIO = load_scenario(config_path('scenario.yaml'))
TRAJECTORY = ScenarioTrajectory.from_config(SCENARIO.config)
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Simulated-time blocks (s), one per test, increasing.
NO_POSE_S, MAIN_S, BAD_S, ODOM_S, FAIL_S, RECORD_S, PLAYER_S = 10, 20, 40, 60, 80, 90, 100

pytestmark = pytest.mark.timeout(120)


def ros_env() -> dict:
    return {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1'}


class Harness:
    """The test side: publishers of /clock and poses, recorders of what the node says."""

    def __init__(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.node = rclpy.create_node('lidar_sim_test', context=self.context)
        self.clock_pub = self.node.create_publisher(Clock, '/clock', RELIABLE)
        self.pose_pub = self.node.create_publisher(PoseStamped, '/target/pose', RELIABLE)
        self.odom_pub = self.node.create_publisher(Odometry, '/target/odom', RELIABLE)
        self.points: dict[int, PointCloud2] = {}
        self.truth: dict[int, PointCloud2] = {}
        self.rosout: list[Log] = []
        self.player_poses: list[PoseStamped] = []
        self.published_poses: list[PoseSample] = []
        self.clock_ns = 0
        self.node.create_subscription(PointCloud2, '/lidar/points', self._store(self.points), RELIABLE)
        self.node.create_subscription(PointCloud2, '/lidar/points_truth', self._store(self.truth), RELIABLE)
        self.node.create_subscription(Log, '/rosout', self.rosout.append,
                                      QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                                 durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.node.create_subscription(PoseStamped, '/player_test/pose', self.player_poses.append,
                                      RELIABLE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()

    @staticmethod
    def _store(store: dict):
        return lambda msg: store.__setitem__(stamp_to_ns(msg.header.stamp), msg)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    # ----------------------------------------------------------- inputs
    def clock(self, t_ns: int) -> None:
        self.clock_ns = int(t_ns)
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(self.clock_ns, NS)
        self.clock_pub.publish(msg)

    def pose(self, t_ns: int, epoch_ns: int, *, shift_m=0.0, quat_scale=1.0, frame_id='lidar',
             position=None, quat=None, record=True) -> None:
        """Publish the scenario trajectory at t_ns (trajectory time t_ns - epoch_ns), or a variant."""
        pose = TRAJECTORY.at((t_ns - epoch_ns) / NS)
        pos = pose.position_m[0] + shift_m if position is None else np.asarray(position, float)
        q = pose.rotation.as_quat()[0] * quat_scale if quat is None else np.asarray(quat, float)
        msg = PoseStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(t_ns), NS)
        msg.header.frame_id = frame_id
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, pos)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = map(float, q)
        self.pose_pub.publish(msg)
        if record:
            self.published_poses.append(PoseSample(int(t_ns), frame_id, pos, q / np.linalg.norm(q)))

    def begin_block(self, block_ns: int, before_poses=None, publish=None) -> None:
        """Jump the clock to a new block; poses start 40 ms before it, run to 20 ms after.

        Poses are only accepted within stale_pose_timeout_s of the node clock, so the
        jump must reach the node before them: /clock and poses come from different
        writers, with no order between them.
        """
        self.clock(block_ns)
        time.sleep(0.3)
        self.clock(block_ns)
        time.sleep(0.05)
        self.block_ns = block_ns
        if before_poses is not None:
            before_poses()
        self.pose_cursor_ns = block_ns - 3 * POSE_STEP_NS
        self.poses_to(block_ns + POSE_STEP_NS, publish)

    def poses_to(self, t1_ns: int, publish=None) -> None:
        """Publish the poses of the 50 Hz grid after the last one published, up to t1_ns."""
        t0 = self.pose_cursor_ns + POSE_STEP_NS
        if publish is None:
            for t in range(t0, t1_ns + 1, POSE_STEP_NS):
                self.pose(t, self.block_ns)
        else:
            publish(t0, t1_ns)
        self.pose_cursor_ns = t1_ns

    def wait(self, predicate, timeout_s: float = 15.0, what: str = 'condition') -> None:
        """Wait for predicate(), re-publishing the clock (its subscription is best effort)."""
        deadline = time.monotonic() + timeout_s
        last = 0.0
        while not predicate():
            now = time.monotonic()
            if now > deadline:
                raise AssertionError(f'timed out after {timeout_s} s waiting for {what}')
            if now - last > 0.1 and self.clock_ns:
                self.clock(self.clock_ns)
                last = now
            time.sleep(0.01)

    def step_frames(self, first: int, last: int, publish=None) -> None:
        """Advance the clock one period at a time over frames first..last of the block and
        wait for each frame (cloud and truth); poses run 20 ms ahead of the clock."""
        for i in range(first, last + 1):
            start = self.block_ns + i * PERIOD_NS
            self.poses_to(start + PERIOD_NS + POSE_STEP_NS, publish)
            self.clock(start + PERIOD_NS)
            self.wait(lambda: start in self.points and start in self.truth, what=f'frame at {start} ns')

    def rosout_since(self, index: int, level: int | None = None) -> list[str]:
        return [m.msg for m in self.rosout[index:] if m.name == 'lidar_sim_node'
                and (level is None or m.level == level)]

    def call(self, srv_type, name: str, request):
        client = self.node.create_client(srv_type, name)
        assert client.wait_for_service(timeout_sec=15.0), f'service {name} not available'
        future = client.call_async(request)
        self.wait(future.done, what=f'response of {name}')
        self.node.destroy_client(client)
        return future.result()

    def set_parameter(self, name: str, ptype: Parameter.Type, value):
        req = SetParameters.Request(parameters=[Parameter(name, ptype, value).to_parameter_msg()])
        return self.call(SetParameters, '/lidar_sim_node/set_parameters', req).results[0]


def start_process(module: str, *ros_args: str, log: Path) -> subprocess.Popen:
    return start_ros_process(module, list(ros_args), ros_env(), log)


@pytest.fixture(scope='module')
def harness():
    h = Harness()
    yield h
    h.close()


@pytest.fixture(scope='module')
def faulty_plugin(tmp_path_factory) -> str:
    """A user effect whose frames fail, loaded by the node at start-up (plugin_effects)."""
    path = tmp_path_factory.mktemp('plugin') / 'faulty_effect.py'
    path.write_text(FAULTY_EFFECT)
    return f'{path}:Faulty'


@pytest.fixture(scope='module')
def node(harness, tmp_path_factory, faulty_plugin):
    log = tmp_path_factory.mktemp('node') / 'lidar_sim_node.log'
    proc = start_process('lidar_sim_ros.ros.lidar_sim_node', '--params-file', str(PARAMS),
                         '-p', 'use_sim_time:=true', '-p', 'qos_reliability:=reliable',
                         '-p', 'pose_qos_reliability:=reliable',
                         '-p', f'plugin_effects:=["{faulty_plugin}"]',
                         '-p', 'publish_truth:=true', '-p', 'odom_topic:=/target/odom', log=log)
    n = harness.node
    try:
        harness.wait(lambda: proc.poll() is not None or (
            n.count_publishers('/lidar/points') and n.count_subscribers('/target/pose')
            and n.count_subscribers('/clock') and n.count_subscribers('/target/odom')),
            timeout_s=30, what='the node to come up')
        assert proc.poll() is None, log.read_text()
        time.sleep(0.5)  # let the matched endpoints settle
        yield proc
    finally:
        code = stop_ros_process(proc)
        print(log.read_text())
    assert code == 0, f'node exited with {code}'


# ------------------------------------------------------------------ tests
def test_no_pose_means_no_frame_and_one_warning(harness, node):
    block = NO_POSE_S * NS
    for i in range(6):
        harness.clock(block + i * PERIOD_NS)
        time.sleep(0.1)
    harness.wait(lambda: any('no pose received yet' in m for m in harness.rosout_since(0)),
                 what='the no-pose warning')
    time.sleep(0.3)
    assert harness.points == {} and harness.truth == {}
    warnings = [m for m in harness.rosout_since(0, Log.WARN) if 'no pose' in m]
    assert len(warnings) == 1, warnings
    assert node.poll() is None


@pytest.fixture(scope='module')
def main_block(harness, node):
    """Frames 0..5 one period at a time, then a jump of three periods (frames 6..8)."""
    block = MAIN_S * NS
    harness.begin_block(block)
    harness.step_frames(0, 5)
    harness.poses_to(block + 9 * PERIOD_NS + POSE_STEP_NS)
    harness.clock(block + 9 * PERIOD_NS)
    stamps = [block + i * PERIOD_NS for i in range(9)]
    harness.wait(lambda: all(s in harness.points and s in harness.truth for s in stamps),
                 what='the catch-up frames')
    time.sleep(0.3)  # nothing else may arrive
    return block, stamps


def test_frames_follow_sim_time_one_per_period(harness, main_block):
    block, stamps = main_block
    got = sorted(s for s in harness.points if block <= s < block + NS)
    assert got == stamps  # exactly k T: no drift, none missing, none extra
    assert sorted(s for s in harness.truth if block <= s < block + NS) == stamps


def test_cloud_field_layout(harness, main_block):
    msg = harness.points[main_block[1][0]]
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1), ('intensity', 12, 7, 1), ('t', 16, 7, 1),
        ('ring', 20, 4, 1), ('material', 22, 2, 1), ('return', 23, 2, 1)]  # FLOAT32 = 7, UINT16 = 4, UINT8 = 2
    assert (msg.point_step, msg.height, msg.is_bigendian, msg.is_dense) == (24, 1, False, True)
    assert msg.row_step == 24 * msg.width and len(msg.data) == msg.row_step
    assert msg.header.frame_id == 'lidar' and msg.width > 10_000
    decoded = from_pointcloud2(msg)
    # A second decoder written from the offsets above.
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(-1, 24)
    xyz = raw[:, 0:12].copy().view('<f4')
    np.testing.assert_array_equal(np.column_stack([decoded['x'], decoded['y'], decoded['z']]), xyz)
    np.testing.assert_array_equal(decoded['t'], raw[:, 16:20].copy().view('<f4')[:, 0])
    np.testing.assert_array_equal(decoded['ring'], raw[:, 20:22].copy().view('<u2')[:, 0])
    np.testing.assert_array_equal(decoded['material'], raw[:, 22])
    assert decoded['t'].min() >= 0 and decoded['t'].max() < 0.1
    assert decoded['ring'].max() < 24 and decoded['material'].max() < len(SCENARIO.materials.names)


def body_frame(points: np.ndarray, stamp_ns: int, epoch_ns: int, use_shot_time=True) -> np.ndarray:
    """Cloud points into the target body frame at the pose of each shot (or of the stamp)."""
    t = (stamp_ns - epoch_ns) / NS + (points['t'].astype(float) if use_shot_time else 0.0)
    poses = TRAJECTORY.at(np.broadcast_to(t, len(points)))
    xyz = np.column_stack([points['x'], points['y'], points['z']]).astype(float)
    return poses.to_body(xyz)


@pytest.fixture(scope='module')
def mesh():
    return trimesh.load(SCENARIO.mesh_path, force='mesh')


def closest_points_on_triangles(p, a, b, c):
    """Closest point to p on triangle abc, row by row (Ericson, Real-Time Collision Detection 5.1.5)."""
    dot = lambda u, v: np.einsum('ij,ij->i', u, v)  # noqa: E731
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide='ignore', invalid='ignore'):
        denom = va + vb + vc
        out = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]  # inside the face
        regions = [  # lowest priority first: later rows override earlier ones
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
             b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None]),
            ((d6 >= 0) & (d5 <= d6), c),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None]),
            ((d3 >= 0) & (d4 <= d3), b),
            ((d1 <= 0) & (d2 <= 0), a),
        ]
    for mask, point in regions:
        out = np.where(mask[:, None], point, out)
    return out


def surface_distance_m(mesh, points_body: np.ndarray, n=200, seed=0, margin_m=0.05) -> np.ndarray:
    """Distance of a random subset of points to the mesh, by brute force over the triangles
    whose bounding box (grown by margin_m) holds the point; margin_m if there is none."""
    pick = np.random.default_rng(seed).choice(len(points_body), min(n, len(points_body)), replace=False)
    tri = mesh.triangles
    lo, hi = tri.min(axis=1) - margin_m, tri.max(axis=1) + margin_m
    dist = np.full(len(pick), margin_m)
    for i, p in enumerate(points_body[pick]):
        near = np.flatnonzero(np.all((p >= lo) & (p <= hi), axis=1))
        if len(near):
            t = tri[near]
            q = closest_points_on_triangles(np.broadcast_to(p, (len(near), 3)), t[:, 0], t[:, 1], t[:, 2])
            dist[i] = min(np.linalg.norm(q - p, axis=1).min(), margin_m)
    return dist


def test_surface_distance_helper(mesh):
    """The helper is itself checked: face centres and vertices at 0, offsets along normals."""
    rng = np.random.default_rng(1)
    faces = rng.choice(len(mesh.faces), 50, replace=False)
    centres = mesh.triangles_center[faces]
    # float64 throughout (trimesh): 1e-9 m is ~1e6 ulps at 5 m, far below the 1e-6 m checks.
    assert surface_distance_m(mesh, centres).max() < 1e-9
    assert surface_distance_m(mesh, mesh.vertices[mesh.faces[faces, 0]]).max() < 1e-9
    # Off the lateral surface (normals radial): a 1 cm step out along the normal.
    lateral = faces[np.abs(mesh.face_normals[faces, 2]) < 0.1]
    out = mesh.triangles_center[lateral] + 0.01 * mesh.face_normals[lateral]
    np.testing.assert_allclose(surface_distance_m(mesh, out), 0.01, atol=2e-4)


def test_truth_points_lie_on_target_at_their_shot_poses(harness, main_block, mesh):
    block, stamps = main_block
    for stamp in (stamps[0], stamps[-1]):
        truth = from_pointcloud2(harness.truth[stamp])
        dist = surface_distance_m(mesh, body_frame(truth, stamp, block))
        # Poses at 50 Hz of a constant-rate tumble: SLERP and linear position are exact, so
        # only Embree's float32 range (8 ulps) and the float32 x, y, z fields (half an ulp
        # each) remain: ~9e-6 m at 12 m (1.5e-6 m measured).
        range_m = np.linalg.norm(np.column_stack([truth['x'], truth['y'], truth['z']]).astype(float), axis=1)
        packed_m = np.sqrt(3) * 0.5 * float(np.spacing(np.float32(range_m.max())))
        assert dist.max() < embree_range_tol_m(range_m) + packed_m, dist.max()
        # Control: posing every point at the frame stamp misses the surface (the target
        # tumbles during the 0.1 s frame), so the check above can fail.
        late = truth[truth['t'] > 0.05]
        dist_stamp = surface_distance_m(mesh, body_frame(late, stamp, block, use_shot_time=False))
        assert dist_stamp.max() > 0.01, dist_stamp.max()


def test_noisy_points_follow_the_material_error_model(harness, main_block):
    bias, sigma = SCENARIO.materials.column('bias_m'), SCENARIO.materials.column('sigma_m')
    residuals = {m: [] for m in range(len(bias))}
    for stamp in main_block[1]:
        noisy, truth = from_pointcloud2(harness.points[stamp]), from_pointcloud2(harness.truth[stamp])
        assert 0 < len(noisy) <= len(truth)
        # Shot times are unique within a frame: they pair each return with its truth.
        _, i_n, i_t = np.intersect1d(noisy['t'], truth['t'], return_indices=True)
        assert len(i_n) == len(noisy)
        n, t = noisy[i_n], truth[i_t]
        np.testing.assert_array_equal(n['material'], t['material'])
        np.testing.assert_array_equal(n['ring'], t['ring'])
        xyz_n = np.column_stack([n['x'], n['y'], n['z']]).astype(float)
        xyz_t = np.column_stack([t['x'], t['y'], t['z']]).astype(float)
        r_n, r_t = np.linalg.norm(xyz_n, axis=1), np.linalg.norm(xyz_t, axis=1)
        # Same ray, both clouds rounded to float32 fields: about eps32 per cloud (7e-8 measured).
        np.testing.assert_allclose(xyz_n / r_n[:, None], xyz_t / r_t[:, None],
                                   atol=4 * np.finfo(np.float32).eps)
        for m in residuals:
            residuals[m].append((r_n - r_t)[n['material'] == m])
    seen = 0
    for m, parts in residuals.items():
        res = np.concatenate(parts)
        if len(res) < 500:
            continue
        seen += 1
        assert np.abs(res - bias[m]).max() < 6 * sigma[m]
        # 5 standard errors of the mean, plus the float32 rounding of both points' x, y, z.
        packed_m = np.sqrt(3) * float(np.spacing(np.float32(16.0)))
        assert abs(res.mean() - bias[m]) < 5 * sigma[m] / np.sqrt(len(res)) + packed_m
        assert res.std() == pytest.approx(sigma[m], rel=0.1)
    assert seen >= 2


def test_clouds_are_reproducible_from_the_seed(harness, main_block):
    """The node's frame k equals an offline simulation of frame k with the same poses."""
    block, stamps = main_block
    sim = Simulator.from_scenario(SCENARIO)
    history = PoseHistory()
    for sample in harness.published_poses:
        if block - NS < sample.stamp_ns < block + NS:
            history.add(sample)
    for stamp in (stamps[1], stamps[7]):
        k = stamp // PERIOD_NS
        frame = sim.simulate_frame(0.0, history.track(stamp, 0.05, from_ns=stamp), frame_index=k)
        got = from_pointcloud2(harness.points[stamp])
        assert len(got) == len(frame)
        # The same float64 computation, then the float32 fields: half a float32 ulp apart.
        got_xyz = np.column_stack([got['x'], got['y'], got['z']]).astype(float)
        half_ulp = 0.5 * np.spacing(np.abs(frame.xyz_m).astype(np.float32)).astype(float)
        assert np.all(np.abs(got_xyz - frame.xyz_m) <= half_ulp)
        np.testing.assert_array_equal(got['ring'], frame.ring)
        np.testing.assert_array_equal(got['material'], frame.material)


def test_bad_poses_are_dropped_and_the_node_keeps_publishing(harness, node, mesh):
    block = BAD_S * NS
    mark = len(harness.rosout)
    stale = 'stale: stamp 39.000000000 s is 1.000 s old'

    def stale_and_future():
        # /clock and the poses come from different writers, with no order between them: a
        # pose sent just after the clock jump may meet the old clock (and read as ahead of
        # it). Dropped either way, so it is sent again until the node calls it stale.
        sent = [0.0]

        def called_stale() -> bool:
            if stale in '\n'.join(harness.rosout_since(mark, Log.WARN)):
                return True
            if time.monotonic() - sent[0] > 0.2:
                harness.pose(block - NS, block, shift_m=1.0, record=False)  # stale (1 s old)
                sent[0] = time.monotonic()
            return False

        harness.wait(called_stale, timeout_s=20.0, what='the stale pose to be called stale')
        harness.pose(block + 5 * NS, block, shift_m=1.0, record=False)  # from the future

    harness.begin_block(block, stale_and_future)
    half = POSE_STEP_NS // 2

    def poses_with_bad_ones(t0, t1):
        for t in range(t0, t1 + 1, POSE_STEP_NS):
            harness.pose(t, block, quat_scale=1.004)                 # near-unit: normalised, kept
            bad = t + half
            harness.pose(bad, block, position=(np.nan, 0, 10), record=False)
            harness.pose(bad, block, position=(np.inf, 0, 10), record=False)
            harness.pose(bad, block, quat=(0, 0, 0, 0), record=False)
            harness.pose(bad, block, quat_scale=2.0, record=False)
            harness.pose(bad, block, shift_m=1.0, frame_id='map', record=False)
            harness.pose(t - half, block, shift_m=1.0, record=False)  # stamp going backwards

    harness.step_frames(0, 3, poses_with_bad_ones)
    for i in range(4):
        stamp = block + i * PERIOD_NS
        dist = surface_distance_m(mesh, body_frame(from_pointcloud2(harness.truth[stamp]), stamp, block))
        assert dist.max() < 0.003, (i, dist.max())
    warnings = '\n'.join(harness.rosout_since(mark, Log.WARN))
    for reason in (stale, 'ahead of the clock',
                   'is not finite', 'quaternion is zero', 'quaternion norm 2 is far from 1',
                   "frame_id 'map' is not the node frame_id 'lidar'",
                   'is not after the last accepted stamp'):
        assert reason in warnings, (reason, warnings)
    assert 'dropped pose on /target/pose' in warnings
    assert node.poll() is None


def test_odometry_input(harness, node, mesh):
    block = ODOM_S * NS

    def odometry(t0, t1):
        for t in range(t0, t1 + 1, POSE_STEP_NS):
            pose = TRAJECTORY.at((t - block) / NS)
            msg = Odometry()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, NS)
            msg.header.frame_id, msg.child_frame_id = 'lidar', 'target'
            p, q = pose.position_m[0], pose.rotation.as_quat()[0]
            msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z = map(float, p)
            o = msg.pose.pose.orientation
            o.x, o.y, o.z, o.w = map(float, q)
            # Twist in the child (body) frame: rotate the lidar-frame rates into it.
            los = TRAJECTORY.position0_m / np.linalg.norm(TRAJECTORY.position0_m)
            v = pose.rotation.inv().apply(-TRAJECTORY.approach_speed_mps * los)[0]
            w = pose.rotation.inv().apply(TRAJECTORY.tumble_rate_rad_s * TRAJECTORY.tumble_axis)[0]
            msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.linear.z = map(float, v)
            msg.twist.twist.angular.x, msg.twist.twist.angular.y, msg.twist.twist.angular.z = map(float, w)
            harness.odom_pub.publish(msg)

    harness.begin_block(block, publish=odometry)
    # Odometry runs 40 ms behind the frame end: the twist extrapolates the rest.
    for i in range(3):
        start = block + i * PERIOD_NS
        harness.poses_to(start + PERIOD_NS - 2 * POSE_STEP_NS, odometry)
        harness.clock(start + PERIOD_NS)
        harness.wait(lambda: start in harness.truth, what=f'frame at {start} ns')
    stamp = block + 2 * PERIOD_NS
    dist = surface_distance_m(mesh, body_frame(from_pointcloud2(harness.truth[stamp]), stamp, block))
    assert dist.max() < 0.003, dist.max()


def test_parameters_are_validated(harness, node):
    D, S, SA = Parameter.Type.DOUBLE, Parameter.Type.STRING, Parameter.Type.STRING_ARRAY
    for name, ptype, value, words in [
        ('max_extrapolation_s', D, -1.0, 'max_extrapolation_s'),
        ('stale_pose_timeout_s', D, 0.0, 'stale_pose_timeout_s'),
        ('frame_id', S, '', 'non-empty frame name'),
        ('frame_id', S, '/lidar', 'leading slash'),
        ('effects', SA, ['no_such_effect'], "unknown effect 'no_such_effect'"),
        ('effects', SA, ['range_walk', 'range_walk'], 'listed twice'),
        ('qos_reliability', S, 'reliable', 'read-only'),
        ('material_names', SA, ['x'], 'read-only'),
        ('max_extrapolation_s', S, 'soon', 'type'),
    ]:
        result = harness.set_parameter(name, ptype, value)
        assert not result.successful, (name, value)
        assert words in result.reason, (name, value, result.reason)
    assert harness.set_parameter('max_extrapolation_s', D, 0.05).successful
    assert harness.set_parameter('effects', SA, ['range_walk']).successful  # a catalogue effect
    assert harness.set_parameter('effects', SA, []).successful
    names = harness.call(GetParameters, '/lidar_sim_node/get_parameters',
                         GetParameters.Request(names=['material_names', 'frame_id']))
    assert list(names.values[0].string_array_value) == SCENARIO.materials.names
    assert names.values[1].string_value == 'lidar'
    # The latched names reach a subscriber that joins late.
    got: list[str] = []
    sub = harness.node.create_subscription(String, '/lidar/material_names',
                                           lambda m: got.append(m.data), LATCHED)
    harness.wait(lambda: got, what='latched material names')
    harness.node.destroy_subscription(sub)
    assert got[0] == '["' + '", "'.join(SCENARIO.materials.names) + '"]'


FAULTY_EFFECT = '''
from lidar_sim_ros.core.effects import Effect

class Faulty(Effect):
    name = 'faulty'

    def power_scale(self, ctx):
        raise RuntimeError('injected failure')
'''


PLANTED_EFFECT = '''
from pathlib import Path
Path(__file__).with_suffix('.ran').write_text('imported')  # proof that the file ran
from lidar_sim_ros.core.effects import Effect

class Planted(Effect):
    name = 'planted'
'''


def test_no_runtime_parameter_loads_code(harness, node, faulty_plugin, tmp_path):
    """Any DDS peer can call SetParameters: a plugin not loaded at start-up is refused, unrun."""
    # A directory holding '=' once passed a pattern-based guard for a catalogue name.
    (tmp_path / 'a=b').mkdir()
    planted = [tmp_path / 'planted_effect.py', tmp_path / 'a=b' / 'evil.py']
    for path in planted:
        path.write_text(PLANTED_EFFECT)
    SA = Parameter.Type.STRING_ARRAY
    for value in ([f'{planted[0]}:Planted'], ['range_walk', f'{planted[0]}:Planted'],
                  [f'{planted[0]}:Planted={{}}'], ['os.path:join'], [f'{planted[1]}:Planted'],
                  [f'range_walk={planted[1]}:Planted'], [str(planted[1])]):
        result = harness.set_parameter('effects', SA, value)
        assert not result.successful, value
        assert 'never load code' in result.reason and 'start-up' in result.reason, result.reason
    for path in planted:
        assert not path.with_suffix('.ran').exists(), f'{path} was imported'
    # What the operator loaded at start-up may still be switched on and off.
    assert harness.set_parameter('effects', SA, ['range_walk']).successful
    assert harness.set_parameter('effects', SA, []).successful
    assert node.poll() is None


def test_a_failing_frame_does_not_kill_the_node(harness, node, faulty_plugin):
    block = FAIL_S * NS
    mark = len(harness.rosout)
    harness.begin_block(block)
    harness.step_frames(0, 0)
    assert harness.set_parameter('effects', Parameter.Type.STRING_ARRAY, [faulty_plugin]).successful
    harness.poses_to(block + 2 * PERIOD_NS + POSE_STEP_NS)
    harness.clock(block + 2 * PERIOD_NS)
    harness.wait(lambda: any('injected failure' in m for m in harness.rosout_since(mark, Log.ERROR)),
                 what='the frame error')
    assert block + PERIOD_NS not in harness.points
    assert harness.set_parameter('effects', Parameter.Type.STRING_ARRAY, []).successful
    harness.step_frames(2, 3)
    assert node.poll() is None
    errors = harness.rosout_since(mark, Log.ERROR)
    assert any(f'frame {block // PERIOD_NS + 1} (stamp {FAIL_S}.100 s) failed: RuntimeError' in m
               for m in errors), errors


def test_recorder_writes_what_the_node_publishes(harness, node, tmp_path):
    block = RECORD_S * NS
    bag = tmp_path / 'bag'
    with BagWriter(bag) as writer:
        recorder = BagRecorder(harness.node, writer)
        harness.wait(lambda: recorder.subscribed, what='the recorder subscriptions')
        # QoS adapted to the publishers: reliable everywhere here, latched names.
        assert all(q.reliability == ReliabilityPolicy.RELIABLE for q in recorder.qos.values())
        assert recorder.qos['/lidar/material_names'].durability == DurabilityPolicy.TRANSIENT_LOCAL
        time.sleep(0.3)
        harness.begin_block(block)
        harness.step_frames(0, 2)
        harness.wait(lambda: recorder.counts['/lidar/points_truth'] >= 3, what='recorded truth')
        recorder.close()
    stamps = [block + i * PERIOD_NS for i in range(3)]
    clouds = read_clouds(bag)
    assert [c.stamp_ns for c in clouds] == stamps
    for cloud in clouds:
        expected = from_pointcloud2(harness.points[cloud.stamp_ns])
        assert cloud.frame_id == 'lidar'
        for name in expected.dtype.names:
            np.testing.assert_array_equal(cloud.points[name], expected[name])
    assert [c.stamp_ns for c in read_clouds(bag, '/lidar/points_truth')] == stamps
    assert read_material_names(bag) == SCENARIO.materials.names
    poses = read_poses(bag)
    assert len(poses.stamp_ns) > 0 and poses.frame_id == 'lidar'
    assert set(poses.stamp_ns) <= {p.stamp_ns for p in harness.published_poses}


def test_bad_config_file_exits_non_zero_naming_file_key_and_value(tmp_path):
    bad = tmp_path / 'scenario.yaml'
    text = (REPO / 'config' / 'scenario.yaml').read_text().replace(
        'tumble_rate_dps: 6.0', 'tumble_rate_dps: fast')
    bad.write_text(text.replace('../meshes/', str(REPO / 'meshes') + '/'))
    result = subprocess.run([sys.executable, '-m', 'lidar_sim_ros.ros.lidar_sim_node', '--ros-args',
                             '-p', f'scenario_file:={bad}'], env=ros_env(), capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert f'{bad}: key "motion.tumble_rate_dps" = \'fast\'' in result.stderr, result.stderr


def test_pose_player_publishes_the_scenario_trajectory(harness, tmp_path):
    block = PLAYER_S * NS
    # The clock is at the block before the player starts: its first tick (right after
    # start-up, its kernel compiled in setup) publishes the present, i.e. the block start.
    harness.clock(block)
    proc = start_process('lidar_sim_ros.ros.target_pose_player', '-p', 'use_sim_time:=true',
                         '-p', 'topic:=/player_test/pose', '-p', f'epoch_s:={PLAYER_S}.0',
                         log=tmp_path / 'player.log')
    try:
        harness.wait(lambda: harness.node.count_publishers('/player_test/pose'), timeout_s=30,
                     what='the player')
        harness.clock(block)
        for i in range(4):
            harness.clock(block + i * PERIOD_NS)
            harness.wait(lambda: any(stamp_to_ns(m.header.stamp) == harness.clock_ns
                                     for m in harness.player_poses), what='player poses')
    finally:
        assert stop_ros_process(proc) == 0, (tmp_path / 'player.log').read_text()
    stamps = np.array([stamp_to_ns(m.header.stamp) for m in harness.player_poses])
    # The first tick publishes the present; every later grid stamp is published once.
    expected = np.arange(block, block + 3 * PERIOD_NS + 1, POSE_STEP_NS)
    np.testing.assert_array_equal(stamps, expected)
    pose = TRAJECTORY.at((stamps - block) / NS)
    got_p = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z]
                      for m in harness.player_poses])
    got_q = np.array([[m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                       m.pose.orientation.w] for m in harness.player_poses])
    # geometry_msgs are float64 and the player evaluates the same closed form: 1e-12.
    np.testing.assert_allclose(got_p, pose.position_m, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(got_q * pose.rotation.as_quat(), axis=1)), 1.0, atol=1e-12)
    assert {m.header.frame_id for m in harness.player_poses} == {'lidar'}
