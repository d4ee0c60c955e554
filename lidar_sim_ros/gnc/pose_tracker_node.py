"""``pose_tracker``: clouds in, the target body pose in the lidar frame out.

A thin rclpy shell around ``gnc.tracker.PoseTracker``: it loads the target mesh of the
scenario, turns each ``sensor_msgs/PointCloud2`` into points, and publishes every
accepted estimate as ``geometry_msgs/PoseStamped`` stamped at the middle of the scan
(cloud stamp + half the scan period), when the cloud's points were taken on average.

By default nothing but the cloud is read: the first capture, and every capture after
a lost track, acquires the pose from the cloud alone (``gnc.acquire``; its settings are
the ``acquire.*`` parameters, the field of view defaulting to the scenario sensor's).
The first capture may instead start from the ``initial_pose`` parameter, and, when
``pose_topic`` is set (e.g. ``/target/pose``, the truth the simulator runs on), from
the pose there nearest the scan's mid time, first and (``recapture_from_pose``) after
each loss.
"""
from __future__ import annotations

import sys
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from pydantic import ValidationError
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.geometry import MeshMaterialError, read_target_mesh
from lidar_sim_ros.gnc.acquire import AcquisitionConfig
from lidar_sim_ros.gnc.tracker import PoseTracker, TrackerConfig, build_model, pose_matrix, pose_parts
from lidar_sim_ros.io.pointcloud import from_pointcloud2, ns_to_stamp, stamp_to_ns
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros.spin import run_node

NODE_NAME = 'pose_tracker'
NS_PER_S = 1_000_000_000
STATS_PERIOD_S = 10.0
POSES_KEPT = 500  # recent poses on pose_topic searched for a capture guess
USER_ERRORS = (ConfigError, MeshMaterialError, ParameterException, ValueError, KeyError,
               TypeError, FileNotFoundError)

S, F, I, B = (ParameterType.PARAMETER_STRING, ParameterType.PARAMETER_DOUBLE,
              ParameterType.PARAMETER_INTEGER, ParameterType.PARAMETER_BOOL)
FA = ParameterType.PARAMETER_DOUBLE_ARRAY


def _read_only(ptype: int, text: str) -> ParameterDescriptor:
    return ParameterDescriptor(type=ptype, description=text, read_only=True)


PARAMETERS: dict[str, tuple[Any, ParameterDescriptor]] = {
    'scenario_file': ('', _read_only(S, "scenario YAML (its mesh and sensor); '' = the package's")),
    'mesh_file': ('', _read_only(S, "target mesh (.obj, .gltf/.glb/.stl/.ply: its shape, whatever "
                                    "its material names) instead of the scenario's; '' = the "
                                    "scenario's")),
    'points_topic': ('/lidar/points', _read_only(S, 'sensor_msgs/PointCloud2 input')),
    'points_reliable': (False, _read_only(
        B, 'subscribe to the clouds reliably (a lock-step loop: no cloud lost); false: best effort, '
           'which also matches best-effort publishers')),
    'pose_topic': ('', _read_only(
        S, "geometry_msgs/PoseStamped giving capture guesses (e.g. the truth, /target/pose); "
           "'' = none: the tracker acquires from the cloud")),
    'estimate_topic': ('/target/pose_estimate', _read_only(S, 'geometry_msgs/PoseStamped output')),
    'lost_topic': ('/target/pose_lost', _read_only(
        S, "std_msgs/Header out, stamped as the estimate would have been, for each cloud that gives "
           "no estimate (so a lock-step loop's controller answers that period too); '' = none")),
    'initial_pose': (Parameter.Type.DOUBLE_ARRAY, _read_only(
        FA, 'first capture guess [x, y, z, qx, qy, qz, qw] (m, unit quaternion); unset = '
            'the pose on pose_topic, or else acquisition from the cloud')),
    'recapture_from_pose': (True, _read_only(
        B, 'after a lost track, capture from the pose on pose_topic when set (else acquire '
           'from the cloud)')),
    'scan_period_s': (0.0, _read_only(F, "scan period (s); 0 = the scenario sensor's frame period")),
}

# TrackerConfig fields become parameters of the same name (read-only, set at start-up).
_PTYPE = {float: F, int: I, str: S}


ACQUIRE_PREFIX = 'acquire.'


def _config_parameters(model: type, prefix: str = '',
                       defaults: dict[str, Any] | None = None) -> dict[str, tuple[Any, ParameterDescriptor]]:
    """A parameter per field of a pydantic config (fields without a default value are left out)."""
    params = {}
    for name, field in model.model_fields.items():
        default = (defaults or {}).get(name, field.get_default())
        if default is None:
            continue
        ptype = FA if isinstance(default, list) else _PTYPE[type(default)]
        params[prefix + name] = (default, _read_only(ptype, field.description or name))
    return params


def sensor_fov(scan) -> dict[str, float]:
    """The field of view (deg, centred on +x) of a scan config, as ``AcquisitionConfig`` fields;
    {} for a scan read from a file (the acquisition's defaults then apply)."""
    if scan.type == 'lissajous_array':
        return {'fov_az_deg': float(scan.fov_az_deg), 'fov_el_deg': float(scan.fov_el_deg)}
    if scan.type == 'rotating':
        return {'fov_az_deg': min(360.0, 2 * max(abs(scan.az_min_deg), abs(scan.az_max_deg))),
                'fov_el_deg': min(180.0, 2 * max(abs(e) for e in scan.elevations_deg) + 1.0)}
    if scan.type == 'risley':      # the circle's bounding square
        full = 2.0 * float(sum(scan.prism_deviation_deg))
        return {'fov_az_deg': full, 'fov_el_deg': full}
    if scan.type == 'flash':
        return {'fov_az_deg': float(scan.fov_az_deg), 'fov_el_deg': float(scan.fov_el_deg)}
    return {}

MAX_POINT_RANGE_M = 10_000.0
"""Farther than this (m) a point is no return (a float marker or garbage): left out."""


def usable_xyz_m(points: np.ndarray) -> np.ndarray:
    """(N, 3) x, y, z (m) of the decoded cloud's points that are finite, not at the
    origin (a driver's "no return") and within MAX_POINT_RANGE_M; ValueError when x, y, z
    are missing or not floating point."""
    names = points.dtype.names or ()
    if not all(f in names and points.dtype[f].kind == 'f' for f in 'xyz'):
        raise ValueError(f'x, y, z must be FLOAT32 or FLOAT64 fields, got {list(names)}')
    xyz = np.column_stack([points['x'], points['y'], points['z']]).astype(float)
    with np.errstate(over='ignore', invalid='ignore'):
        rng = np.linalg.norm(xyz, axis=1)
    return xyz[(rng > 1e-6) & (rng <= MAX_POINT_RANGE_M)]


class PoseTrackerNode(Node):
    """Clouds in, PoseStamped out. Call ``setup()`` after construction (it may raise)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)

    def setup(self) -> None:
        """Declare parameters, build the target model and the ROS interfaces."""
        for name, (value, desc) in {**PARAMETERS, **_config_parameters(TrackerConfig)}.items():
            self.declare_parameter(name, value, desc)
        param = lambda name: self.get_parameter(name).value  # noqa: E731
        scenario = load_scenario(param('scenario_file') or config_path('scenario.yaml'))
        mesh = Path(param('mesh_file')).expanduser() if param('mesh_file') else scenario.mesh_path
        self.config = self._config(TrackerConfig, {name: param(name) for name in TrackerConfig.model_fields})
        # The acquisition's field of view is the scenario sensor's unless set.
        acquire_params = _config_parameters(AcquisitionConfig, ACQUIRE_PREFIX, sensor_fov(scenario.sensor.scan))
        for name, (value, desc) in acquire_params.items():
            self.declare_parameter(name, value, desc)
        self.acquisition = self._config(AcquisitionConfig, {
            name[len(ACQUIRE_PREFIX):]: param(name) for name in acquire_params}, ACQUIRE_PREFIX)
        period_s = param('scan_period_s') or scenario.sensor.frame_period_s
        if not (np.isfinite(period_s) and period_s > 0):
            raise ConfigError('<parameters>', 'scan_period_s', period_s, 'must be positive')
        self.half_scan_ns = round(0.5 * period_s * NS_PER_S)
        initial = self.get_parameter_or('initial_pose', Parameter('initial_pose', value=None)).value
        self.initial_guess = self._initial_guess(initial)
        self.recapture_from_pose = bool(param('recapture_from_pose'))

        # The tracker needs the shape alone: every part as one material, so a mesh_file of
        # another target (a CAD export whose names the scenario's map does not cover) loads.
        vertices_m, faces, _ = read_target_mesh(mesh, scenario.materials.names,
                                                mesh_materials=scenario.materials.names[0])
        t0 = time.perf_counter()
        self.tracker = PoseTracker(build_model(vertices_m, faces, self.config), self.config,
                                   self.acquisition)
        model_s = time.perf_counter() - t0
        self.poses: deque[tuple[int, np.ndarray]] = deque(maxlen=POSES_KEPT)
        self._captured_once = False
        self._epoch_ns: int | None = None
        self._last_warn: dict[str, float] = {}
        self._stats = {'clouds': 0, 'published': 0, 'rejected': 0, 'ms': [], 'acquisitions': 0}

        # Best effort matches reliable and best-effort publishers; a short queue keeps the
        # newest clouds when a registration overruns a period. A lock-step loop asks for
        # reliable (points_reliable): a lost cloud is a lost period.
        cloud_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                               reliability=ReliabilityPolicy.RELIABLE if param('points_reliable')
                               else ReliabilityPolicy.BEST_EFFORT)
        self.create_subscription(PointCloud2, param('points_topic'), self._on_cloud, cloud_qos)
        if param('pose_topic'):
            self.create_subscription(PoseStamped, param('pose_topic'), self._on_pose,
                                     QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.pub = self.create_publisher(PoseStamped, param('estimate_topic'), 10)
        self.lost_pub = None
        if param('lost_topic'):
            from std_msgs.msg import Header
            self.lost_pub = self.create_publisher(Header, param('lost_topic'), 10)
        self.create_timer(STATS_PERIOD_S, self._log_stats, clock=Clock(clock_type=ClockType.STEADY_TIME))
        source = ('initial_pose' if self.initial_guess is not None else param('pose_topic')
                  or 'the cloud alone (acquisition)')
        self.get_logger().info(
            f'tracking {mesh.name} ({len(self.tracker.model)} model points, built in {model_s:.2f} s) '
            f'on {param("points_topic")} -> {param("estimate_topic")}; capture from {source}')

    @staticmethod
    def _config(model: type, values: dict[str, Any], prefix: str = ''):
        try:
            return model(**values)
        except ValidationError as exc:
            first = exc.errors()[0]
            key = prefix + '.'.join(str(part) for part in first['loc'])
            raise ConfigError('<parameters>', key, values.get(first['loc'][0]), first['msg']) from None

    def _initial_guess(self, value) -> np.ndarray | None:
        if value is None or len(value) == 0:
            return None
        v = np.asarray(value, dtype=float)
        if v.shape != (7,) or not np.isfinite(v).all() or abs(np.linalg.norm(v[3:]) - 1) > 0.01:
            raise ConfigError('<parameters>', 'initial_pose', list(value),
                              'expected [x, y, z, qx, qy, qz, qw] with a unit quaternion')
        return pose_matrix(v[:3], v[3:] / np.linalg.norm(v[3:]))

    # ------------------------------------------------------------ callbacks
    def _on_pose(self, msg: PoseStamped) -> None:
        p, q = msg.pose.position, msg.pose.orientation
        quat = np.array([q.x, q.y, q.z, q.w])
        if not (np.isfinite(quat).all() and abs(np.linalg.norm(quat) - 1) < 0.01):
            return
        self.poses.append((stamp_to_ns(msg.header.stamp),
                           pose_matrix([p.x, p.y, p.z], quat / np.linalg.norm(quat))))

    def _guess(self, t_ns: int) -> np.ndarray | None:
        """The capture guess for a scan centred at t_ns, or None to acquire from the cloud."""
        if not self._captured_once and self.initial_guess is not None:
            return self.initial_guess
        if (self.recapture_from_pose or not self._captured_once) and self.poses:
            return min(self.poses, key=lambda sp: abs(sp[0] - t_ns))[1]
        return None

    def _on_cloud(self, msg: PointCloud2) -> None:
        self._stats['clouds'] += 1
        t_ns = stamp_to_ns(msg.header.stamp) + self.half_scan_ns
        guess = None if self.tracker.tracking else self._guess(t_ns)
        if self._epoch_ns is None:
            self._epoch_ns = t_ns  # seconds since the first scan keep float64 resolution
        try:
            xyz = usable_xyz_m(from_pointcloud2(msg))
        except ValueError as exc:   # a malformed cloud from any peer must not stop the node
            self._stats['rejected'] += 1
            self._warn('bad_cloud', f'cloud dropped: {exc}')
            self._publish_lost(t_ns, msg.header)
            return
        t0 = time.perf_counter()
        estimate = self.tracker.update((t_ns - self._epoch_ns) / NS_PER_S, xyz, guess)
        self._stats['ms'].append(1e3 * (time.perf_counter() - t0))
        if self.tracker.last_acquisition is not None:
            self._log_acquisition(t_ns, self.tracker.last_acquisition)
        if not estimate.acceptable(self.config):
            self._stats['rejected'] += 1
            self._publish_lost(t_ns, msg.header)
            self._warn('lost', f'track lost at {t_ns / NS_PER_S:.3f} s: {estimate.inliers} of '
                               f'{estimate.points} points on the model (need '
                               f'{self.config.min_inlier_fraction:.0%} of at least {self.config.min_points})')
            return
        self._captured_once = True
        position, quat = pose_parts(estimate.pose)
        out = PoseStamped()
        out.header.stamp = ns_to_stamp(t_ns, type(out.header.stamp))
        out.header.frame_id = msg.header.frame_id
        out.pose.position.x, out.pose.position.y, out.pose.position.z = (float(v) for v in position)
        o = out.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in quat)
        self.pub.publish(out)
        self._stats['published'] += 1

    def _publish_lost(self, t_ns: int, header) -> None:
        """Say that the cloud stamped ``header.stamp`` gives no estimate (stamped mid-scan)."""
        if self.lost_pub is not None:
            from std_msgs.msg import Header
            self.lost_pub.publish(Header(stamp=ns_to_stamp(t_ns, type(header.stamp)), frame_id=header.frame_id))

    # -------------------------------------------------------------- logging
    def _warn(self, kind: str, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warn.get(kind, -np.inf) >= 1.0:
            self._last_warn[kind] = now
            self.get_logger().warning(text)

    def _log_acquisition(self, t_ns: int, acq) -> None:
        self._stats['acquisitions'] += 1
        text = (f'acquisition at {t_ns / NS_PER_S:.3f} s: {"acquired" if acq.success else "failed"}, score '
                f'{acq.score:.3f} (fit {acq.fit:.3f}, coverage {acq.coverage:.3f}), {acq.hypotheses} '
                f'hypotheses in {acq.seconds:.2f} s' + (f' ({acq.reason})' if acq.reason else ''))
        if acq.success:
            other = ('no other place or end fitted' if np.isnan(acq.runner_up_score)
                     else f'another place or end scored {acq.runner_up_score:.3f}')
            text += f'; roll {"ambiguous" if acq.roll_ambiguous else "resolved"}, {other}'

            self.get_logger().info(text)
        else:
            self._warn('acquisition', text)

    def _log_stats(self) -> None:
        s = self._stats
        ms = np.array(s['ms'])
        timing = f'; registration p50 {np.median(ms):.1f} ms, max {ms.max():.1f} ms' if len(ms) else ''
        self.get_logger().info(f'last {STATS_PERIOD_S:g} s: {s["clouds"]} clouds, {s["published"]} '
                               f'estimates, {s["rejected"]} rejected, {s["acquisitions"]} '
                               f'acquisitions{timing}')
        self._stats = {'clouds': 0, 'published': 0, 'rejected': 0, 'ms': [], 'acquisitions': 0}


def main(args: list[str] | None = None) -> int:
    return run_node(PoseTrackerNode, args, USER_ERRORS)


if __name__ == '__main__':
    sys.exit(main())
