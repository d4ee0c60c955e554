"""``lidar_sim_node``: target pose in, simulated PointCloud2 out at the sensor frame rate.

A thin rclpy shell around ``core.pipeline.Simulator``. It owns the parameters, QoS,
subscriptions and timer; ``pose_input`` validates poses and keeps their history,
``scheduler`` says which frame is due; the frame itself is ``simulate_frame``.

Frame k covers [k T, (k + 1) T) of the node clock (``/clock`` under use_sim_time);
it is computed once its window has ended and the poses reach over it, with header
stamp k T and the generator ``Simulator.frame_rng(k)``, so a run is reproducible
from the seed and the poses.
"""
from __future__ import annotations

import sys
import threading
import time
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)
from rclpy.validate_topic_name import validate_topic_name
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from lidar_sim_ros.core.config import ConfigError, parse, with_frame_rate
from lidar_sim_ros.core.scenario import Scenario, load_scenario, scenario_effect_spec
from lidar_sim_ros.core.effects import (Effect, builtin_classes, get_effect_class, is_plugin_spec,
                                        make_effect)
from lidar_sim_ros.core.geometry import MeshMaterialError
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.io.bag import encode_material_names
from lidar_sim_ros.core.driver_layout import OutputLayout
from lidar_sim_ros.ros.mount import check_mount, mount_message, rclpy_lookup
from lidar_sim_ros.io import cepton
from lidar_sim_ros.io.pointcloud import frame_points, stamp_to_ns, to_rclpy_msg
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros import cepton_udp
from lidar_sim_ros.ros.deadline import DeadlinePublisher
from lidar_sim_ros.ros.spin import run_node
from lidar_sim_ros.ros.pose_input import (NS_PER_S, PoseHistory, PoseSample, ReasonThrottle,
                                          check_pose, twist_to_lidar)
from lidar_sim_ros.ros.scheduler import COMPUTE, WAIT, FrameScheduler, pose_window_ns, readiness
from lidar_sim_ros.ros.sun_input import SunTrack, check_sun_direction, sun_with_direction

NODE_NAME = 'lidar_sim_node'
QOS_CHOICES = ('best_effort', 'reliable')
STATS_PERIOD_S = 10.0
WAKE_MARGIN_S = 0.0002  # wake this long after a window ends, so the clock has surely passed it

# Start-up problems that are the user's (bad file, bad parameter): one log line, exit 2.
USER_ERRORS = (ConfigError, MeshMaterialError, ParameterException, ValueError, KeyError,
               TypeError, FileNotFoundError)


def _descriptor(ptype: int, text: str, read_only: bool = False, float_range=None,
                int_range=None) -> ParameterDescriptor:
    desc = ParameterDescriptor(type=ptype, description=text, read_only=read_only)
    if float_range is not None:
        desc.floating_point_range = [FloatingPointRange(from_value=float_range[0],
                                                        to_value=float_range[1])]
    if int_range is not None:
        desc.integer_range = [IntegerRange(from_value=int_range[0], to_value=int_range[1])]
    return desc


S, F, I, B = (ParameterType.PARAMETER_STRING, ParameterType.PARAMETER_DOUBLE,
              ParameterType.PARAMETER_INTEGER, ParameterType.PARAMETER_BOOL)
FA = ParameterType.PARAMETER_DOUBLE_ARRAY


def _startup(ptype: int, text: str, **ranges) -> ParameterDescriptor:
    return _descriptor(ptype, text, read_only=True, **ranges)


# Parameters read once at start-up (read-only). Empty file paths mean "as the scenario says".
STARTUP_PARAMETERS: dict[str, tuple[Any, ParameterDescriptor]] = {
    'scenario_file': ('', _startup(S, "scenario YAML; '' = the package's config/scenario.yaml")),
    'sensor_file': ('', _startup(S, "sensor YAML instead of the scenario's; '' = the scenario's")),
    'materials_file': ('', _startup(S, "materials YAML instead of the scenario's; '' = the scenario's")),
    'mesh_file': ('', _startup(S, "target mesh (.obj, or .gltf/.glb/.stl/.ply mapped by the "
                                  "scenario's mesh_materials) instead of the scenario's; '' = "
                                  "the scenario's")),
    'mesh_materials': ('', _startup(S, "the mesh's material/node names -> config materials, as "
                                       "YAML: one material for the whole mesh ('ALUMINIUM') or a "
                                       "map ('{bus_mli: MLI, solar_cells: SOLAR_ARRAY}'), checked "
                                       "as a scenario's; '' = the scenario's")),
    'pose_topic': ('/target/pose', _startup(
        S, 'geometry_msgs/PoseStamped input: target body pose in the lidar frame')),
    'odom_topic': ('', _startup(
        S, "nav_msgs/Odometry input (twist in the target body frame); '' = off")),
    'points_topic': ('/lidar/points', _startup(S, 'sensor_msgs/PointCloud2 output')),
    'truth_topic': ('/lidar/points_truth', _startup(
        S, 'noise-free PointCloud2 output (see publish_truth)')),
    'material_names_topic': ('/lidar/material_names', _startup(
        S, 'std_msgs/String JSON list of material names, latched')),
    'sun_topic': ('/sun/direction', _startup(
        S, 'geometry_msgs/Vector3Stamped input: direction toward the sun in the lidar frame')),
    'rate_hz': (0.0, _startup(F, "frame rate (Hz); 0 = the sensor's frame_rate_hz",
                              float_range=(0.0, 1000.0))),
    'seed': (-1, _startup(I, "random seed; -1 = the scenario's seed", int_range=(-1, 2**31 - 1))),
    'qos_reliability': ('best_effort', _startup(
        S, "cloud QoS: 'best_effort' (sensor data profile) or 'reliable'")),
    'pose_qos_reliability': ('best_effort', _startup(
        S, "pose QoS: 'best_effort' (matches any publisher) or 'reliable' (lossless, "
           'needs reliable publishers)')),
    'ticks_per_frame': (2, _startup(
        I, 'fallback checks for due frames per frame period, on top of the wake-up at '
           'each frame end', int_range=(1, 1000))),
    'threads': (2, _startup(
        I, 'threads a frame is split over (Embree and the beam-footprint kernels release the '
           'GIL); frames are the same for any count', int_range=(1, 64))),
    'publish_latency_s': (0.0, _startup(
        F, "publish each frame this long after its scan window ends (wall clock), as a "
           "sensor's fixed processing latency: the period jitter is then the wake-up's, not "
           "the computation's; a frame computed later is published at once (late); "
           '0 = as soon as computed; ignored under use_sim_time', float_range=(0.0, 1.0))),
    'max_catch_up_frames': (10, _startup(
        I, 'most frames computed at once after a clock jump; older ones are dropped',
        int_range=(1, 1000))),
    'point_layout': ('native', _startup(
        S, "cloud layout: 'native' (ours: x y z intensity t ring material) or 'cepton' (the "
           "Cepton SDK3 driver's: topic cepton_pcl2 and frame cepton3 unless points_topic / "
           'frame_id say otherwise; docs/real-data.md)')),
    'no_return_points': (False, _startup(
        B, 'cepton layout: also one NO_RETURN point (0, 0, 0) per shot that returned nothing')),
    'polar_fields': (False, _startup(
        B, "cepton layout: also the driver's optional azimuth, elevation (rad) and range (m) "
           'fields')),
    'mount_parent_frame': ('', _startup(
        S, "parent frame of the sensor mount, published as a static transform to frame_id "
           "on /tf_static; '' = no transform")),
    'mount_translation_m': ([0.0, 0.0, 0.0], _startup(
        FA, 'sensor origin in mount_parent_frame (m)')),
    'mount_quat_xyzw': ([0.0, 0.0, 0.0, 1.0], _startup(
        FA, 'sensor orientation in mount_parent_frame (unit quaternion x, y, z, w)')),
    'plugin_effects': (Parameter.Type.STRING_ARRAY, _startup(
        ParameterType.PARAMETER_STRING_ARRAY,
        "user effects ('module:Class' or 'file.py:Class') loaded once at start-up, from the "
        "parameters file: a plugin is code run as the node's user. 'effects' may switch "
        'them on and off at run time; no runtime change loads code')),
}

STARTUP_PARAMETERS.update(cepton_udp.PARAMETERS)   # the Cepton wire output (ros/cepton_udp.py)

# Parameters that may change while running.
DYNAMIC_PARAMETERS: dict[str, tuple[Any, ParameterDescriptor]] = {
    'publish_truth': (False, _descriptor(B, 'also publish the noise-free cloud on truth_topic')),
    'max_extrapolation_s': (0.05, _descriptor(
        F, 'how far past the newest pose a frame may be posed (s)', float_range=(0.0, 10.0))),
    'stale_pose_timeout_s': (0.5, _descriptor(
        F, 'poses older (or newer) than this vs the clock are dropped; also how long a frame '
           'waits for poses and the largest pose gap interpolated across (s)',
        float_range=(0.001, 3600.0))),
}


class LidarSimNode(Node):
    """Pose in, PointCloud2 out. Call ``setup()`` after construction (it may raise)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.scenario: Scenario | None = None
        self.sim: Simulator | None = None
        self._effects_specs: dict[str, dict] = {}
        self._plugins: frozenset[str] = frozenset()  # plugin specs loaded at start-up
        # Every effect 'effects' may name once running: the package's own and the plugins
        # loaded at start-up, by the exact string that loaded them (an allow-list).
        self._effect_classes: dict[str, type[Effect]] = {}
        self._ready = False
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

    # ------------------------------------------------------------- set-up
    def setup(self) -> None:
        """Declare parameters, load the scenario, create the simulator and the ROS interfaces."""
        for name, (value, desc) in STARTUP_PARAMETERS.items():
            self.declare_parameter(name, value, desc)
        self.scenario = self._load_scenario()
        self._effects_specs = {e.name: dict(e.params) for e in self.scenario.config.effects}
        seed, rate = self.get_parameter('seed').value, self.get_parameter('rate_hz').value
        if seed >= 0:
            self.scenario.config = self.scenario.config.model_copy(update={'seed': int(seed)})
        if rate > 0:
            # The scan pattern is laid over the frame period, so a rate override
            # stretches or compresses it over the new period.
            self.scenario.sensor = with_frame_rate(self.scenario.sensor, rate, '<parameters>')
        self.sim = Simulator.from_scenario(self.scenario, effects=[],
                                           threads=self.get_parameter('threads').value)

        # Validated by the layout's own model (ConfigError naming the parameter).
        self.layout = parse(OutputLayout, {name: self.get_parameter(name).value for name in
                                           ('point_layout', 'no_return_points', 'polar_fields')},
                            '<parameters>')
        self.declare_parameter('frame_id', self.layout.frame(self.scenario.config.frame_id),
                               _descriptor(S, "header frame_id of the clouds; poses must carry it "
                                              "(default: cepton3 for the cepton layout, else "
                                              "the scenario's frame_id)"))
        for name, (value, desc) in DYNAMIC_PARAMETERS.items():
            self.declare_parameter(name, value, desc)
        default_effects = list(self._effects_specs) or Parameter.Type.STRING_ARRAY
        self.declare_parameter('effects', default_effects, _descriptor(
            ParameterType.PARAMETER_STRING_ARRAY,
            "enabled effects: catalogue names, 'module:Class' or 'file.py:Class' (parameters "
            "from the scenario's effects list, else defaults); default: the scenario's"))
        # Plugins are code: they load here, at start-up, from what the operator's files name
        # (the scenario's effects list, plugin_effects, effects as started); a runtime change
        # may only switch them on and off (_invalid_reason).
        self._plugins = frozenset(
            name for name in [*self._effects_specs, *(self.get_parameter_or('plugin_effects').value or []),
                              *self._effects_value()] if is_plugin_spec(name))
        for name in sorted(self._plugins):
            make_effect(self._load_spec(name), self._effects_specs.get(name))
        self._effect_classes = {**builtin_classes(),
                                **{spec: get_effect_class(self._load_spec(spec))
                                   for spec in sorted(self._plugins)}}
        self.sim.effects = self._build_effects(self._effects_value())
        sun = self.scenario.config.sun
        self.declare_parameter(
            'sun_direction', list(sun.direction) if sun else Parameter.Type.DOUBLE_ARRAY,
            _descriptor(FA, "direction toward the sun, lidar frame (normalised); [] = no sun; "
                            "default: the scenario's sun.direction; the sun topic overrides it"))
        self._hidden_sun = None              # the sun model kept while hidden (topic zero)
        self._sun_track = SunTrack()         # topic samples, applied by stamp per frame
        self._set_sun(self.get_parameter_or('sun_direction').value)
        # Compiled kernels (and the effects' first calls) before anything is timed: the
        # frame grid, the pose subscriptions and their staleness checks all start after
        # this, so a slow first start (numba compiling) is not followed by a catch-up
        # burst of frames or stale poses.
        try:
            self.sim.warm_up()
        except Exception as exc:  # noqa: BLE001 - a broken effect fails its frames, not start-up
            self.get_logger().warning(f'warm-up failed ({type(exc).__name__}: {exc}); '
                                      'frames will report it')
        self.declare_parameter('material_names', list(self.scenario.materials.names),
                               _descriptor(ParameterType.PARAMETER_STRING_ARRAY,
                                           'material index -> name of the material field',
                                           read_only=True), ignore_override=True)

        self.scheduler = FrameScheduler(self.scenario.sensor.frame_rate_hz,
                                        self.get_parameter('max_catch_up_frames').value)
        self._last_shot_ns = int(np.ceil(float(self.sim.shots.t_s.max()) * NS_PER_S))
        keep_s = max(5.0, 4 * self.scheduler.period_s * self.scheduler.max_catch_up)
        self.history = PoseHistory(keep_s=keep_s)
        self.throttle = ReasonThrottle(1.0)
        self._waiting = False
        self._warned_no_pose = False
        self._stats = {'published': 0, 'skipped': 0, 'failed': 0, 'compute_ms': [], 'publish_ms': []}
        self._latency_ns = round(self.get_parameter('publish_latency_s').value * NS_PER_S)
        if self._latency_ns and self.get_parameter('use_sim_time').value:
            self.get_logger().warning('publish_latency_s is ignored under use_sim_time (it holds '
                                      'frames on the wall clock): frames go out when computed')
            self._latency_ns = 0
        self._deadline = DeadlinePublisher() if self._latency_ns else None
        self.udp = cepton_udp.sender_from_node(self)   # None unless cepton_udp

        self._create_interfaces()
        self.get_logger().info(
            f'simulating {self.scenario.sensor.name} at {self.scheduler.rate_hz:g} Hz '
            f'({len(self.sim.shots)} shots a frame), seed {self.sim.seed}, '
            f'target {self.scenario.mesh_path.name}; '
            f'poses on {self.pose_sub.topic_name}, clouds on {self.points_pub.topic_name} '
            f'({self.get_parameter("qos_reliability").value}); sun {self._sun_text()} '
            f'(topic {self.sun_sub.topic_name})')
        self._ready = True

    def _load_scenario(self) -> Scenario:
        p = {name: self.get_parameter(name).value for name in
             ('scenario_file', 'sensor_file', 'materials_file', 'mesh_file', 'mesh_materials')}
        return load_scenario(p['scenario_file'] or config_path('scenario.yaml'),
                             sensor_file=p['sensor_file'], materials_file=p['materials_file'],
                             mesh_file=p['mesh_file'], mesh_materials=p['mesh_materials'])

    def _create_interfaces(self) -> None:
        param = lambda name: self.get_parameter(name).value  # noqa: E731
        if param('qos_reliability') == 'reliable':
            cloud_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                                   reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.VOLATILE)
        else:
            cloud_qos = qos_profile_sensor_data
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        # Best effort matches both reliable and best-effort publishers; reliable loses
        # nothing but only matches reliable ones. The deep queue holds the poses that
        # arrive while a frame is being computed.
        pose_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                              reliability=ReliabilityPolicy.RELIABLE
                              if param('pose_qos_reliability') == 'reliable'
                              else ReliabilityPolicy.BEST_EFFORT,
                              durability=DurabilityPolicy.VOLATILE)
        points_topic = param('points_topic')
        if self.layout.point_layout == 'cepton' and points_topic == STARTUP_PARAMETERS['points_topic'][0]:
            points_topic = cepton.TOPIC     # the driver's topic, relative as the driver's
        self.points_pub = self.create_publisher(PointCloud2, points_topic, cloud_qos)
        self._publish_mount()
        self.truth_pub = self.create_publisher(PointCloud2, param('truth_topic'), cloud_qos)
        self.names_pub = self.create_publisher(String, param('material_names_topic'), latched)
        self.pose_sub = self.create_subscription(PoseStamped, param('pose_topic'),
                                                 self._on_pose, pose_qos)
        self.sun_sub = self.create_subscription(
            Vector3Stamped, param('sun_topic'), self._on_sun,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.odom_sub = None
        if param('odom_topic'):
            self.odom_sub = self.create_subscription(Odometry, param('odom_topic'),
                                                     self._on_odometry, pose_qos)
        self.names_pub.publish(String(data=encode_material_names(self.scenario.materials.names)))
        # When to check for due frames: right after each window ends (a thread sleeping
        # to the wall-clock frame end, or each /clock message under use_sim_time), plus a
        # slow fallback timer on the steady clock that also runs while /clock pauses.
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        self.create_subscription(ClockMsg, '/clock', self._on_clock,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self._frame_end = self.create_guard_condition(self._tick)
        self._stop = threading.Event()
        self._waker = threading.Thread(target=self._wake_at_frame_ends, daemon=True,
                                       name='frame_end_waker')
        self._waker.start()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.scheduler.period_s / param('ticks_per_frame'), self._tick,
                          clock=steady)
        self.create_timer(STATS_PERIOD_S, self._log_stats, clock=steady)

    def _publish_mount(self) -> None:
        """The sensor mount as a static transform (mount_parent_frame -> frame_id), when one
        is configured (``mount.py``). tf2_msgs comes with ROS (no wheel exists): without
        it, say so once."""
        parent = self.get_parameter('mount_parent_frame').value
        if not parent:
            return
        xyz = list(self.get_parameter('mount_translation_m').value)
        quat = list(self.get_parameter('mount_quat_xyzw').value)
        problem = check_mount(xyz, quat)
        if problem:
            raise ConfigError('<parameters>', 'mount_translation_m / mount_quat_xyzw',
                              f'{xyz} / {quat}', problem)
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.get_logger().warning(
                f'mount_parent_frame {parent!r} is set but tf2_msgs is not installed: the '
                'sensor mount is not published on /tf_static')
            return
        msg = mount_message(rclpy_lookup, parent, self.get_parameter('frame_id').value, xyz,
                            quat, self.get_clock().now().nanoseconds)
        static = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                            reliability=ReliabilityPolicy.RELIABLE)
        self.tf_static_pub = self.create_publisher(TFMessage, '/tf_static', static)
        self.tf_static_pub.publish(msg)

    def _wake_at_frame_ends(self) -> None:
        """Waker thread (wall clock only): trigger a tick just after each frame window ends."""
        while not self._stop.is_set():
            if self._sim_time:
                self._stop.wait(self.scheduler.period_s)
                continue
            now_ns = time.time_ns()  # the node clock without use_sim_time: system time
            end_ns = self.scheduler.end_ns(self.scheduler.index_at(now_ns))
            if self._stop.wait((end_ns - now_ns) / NS_PER_S + WAKE_MARGIN_S):
                return
            try:
                self._frame_end.trigger()  # runs _tick in the executor, between callbacks
            except Exception:  # noqa: BLE001 - the node is being destroyed
                return

    def _on_clock(self, msg: ClockMsg) -> None:
        """Under use_sim_time, check for due frames as soon as /clock passes a window end."""
        if not self._sim_time:
            return
        now_ns = stamp_to_ns(msg.clock)
        nxt = self.scheduler.next_index
        if nxt is None or now_ns >= self.scheduler.end_ns(nxt) or self._waiting:
            self._tick(now_ns)

    def destroy_node(self):
        if hasattr(self, '_stop'):
            self._stop.set()
        if getattr(self, '_deadline', None) is not None:
            self._deadline.close()
        if getattr(self, 'udp', None) is not None:
            self.udp.close()
        return super().destroy_node()

    def _pose_window_ns(self, start_ns: int) -> tuple[int, int]:
        return pose_window_ns(start_ns, self._last_shot_ns, self.sim.effects)

    # --------------------------------------------------------- parameters
    def _effects_value(self) -> list[str]:
        value = self.get_parameter_or('effects').value  # NOT_SET (empty list) -> None
        return list(value) if value else []

    def _load_spec(self, name: str) -> str:
        """What loads the effect ``name``: a scenario's ``file.py:Class`` beside the scenario
        file, never in the current directory; any other name as given."""
        source = self.scenario.source
        if name in self._effects_specs and source is not None:
            return scenario_effect_spec(name, Path(source).resolve().parent)
        return name

    def _build_effects(self, names: list[str]) -> list[Effect]:
        """Effect instances by name. Once set up, from the allow-list only: a name outside
        it raises ValueError (the reason a runtime change is refused) and nothing is
        imported or executed."""
        if not self._effect_classes:             # start-up: the operator's files name them
            return [make_effect(self._load_spec(name), self._effects_specs.get(name)) for name in names]
        unknown = [name for name in names if name not in self._effect_classes]
        if unknown:
            raise ValueError(f'unknown effect {unknown[0]!r}: runtime changes pick from the '
                             'catalogue and the plugins loaded at start-up (plugin_effects in '
                             'the parameters file), and never load code; catalogue: '
                             f'{sorted(builtin_classes())}; loaded at start-up: '
                             f'{sorted(self._plugins) or "none"}')
        return [self._effect_classes[name](self._effects_specs.get(name)) for name in names]

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for p in params:
            reason = self._invalid_reason(p)
            if reason:
                return SetParametersResult(successful=False,
                                           reason=f'{p.name} = {p.value!r} rejected: {reason}')
        return SetParametersResult(successful=True)

    def _invalid_reason(self, p: Parameter) -> str | None:
        name, value = p.name, p.value
        if name.endswith('_topic') and value:
            try:
                validate_topic_name(value)
            except Exception as exc:  # noqa: BLE001 - rclpy raises several name exceptions
                return f'not a valid topic name ({exc})'
        elif name.endswith('_topic') and name != 'odom_topic':
            return 'a topic name is required'
        elif name in ('qos_reliability', 'pose_qos_reliability') and value not in QOS_CHOICES:
            return f'must be one of {list(QOS_CHOICES)}'
        elif name == 'frame_id' and (not value or value.startswith('/') or value != value.strip()
                                     or ' ' in value):
            return 'must be a non-empty frame name without spaces or a leading slash'
        elif name in ('max_extrapolation_s', 'stale_pose_timeout_s', 'rate_hz') and value is not None:
            if not np.isfinite(value):
                return 'must be finite'
        elif name == 'sun_direction' and value is not None and len(value):
            _, rejection = check_sun_direction(list(value))
            if rejection is not None:
                return rejection.reason
        elif name == 'effects' and value:
            if len(set(value)) != len(value):
                return 'an effect is listed twice'
            try:
                self._build_effects(list(value))
            except Exception as exc:  # noqa: BLE001 - any failure to build is the reason
                return f'{type(exc).__name__}: {exc}'
        return None

    def _apply_parameters(self, params: list[Parameter]) -> None:
        if not self._ready:
            return
        for p in params:
            if p.name == 'use_sim_time':
                self._sim_time = bool(p.value)
            if p.name == 'effects':
                self.sim.effects = self._build_effects(list(p.value or []))
                names = [e.name or type(e).__name__ for e in self.sim.effects]
                self.get_logger().info(f'effects now {names}')
            if p.name == 'sun_direction':
                self._sun_track.clear()         # the parameter wins until the topic speaks
                self._set_sun(p.value)
                self.get_logger().info(f'sun direction now {self._sun_text()}')

    # ---------------------------------------------------------------- sun
    def _set_sun(self, direction) -> None:
        """Point the simulator's sun along ``direction`` (a checked vector); empty = no sun."""
        if direction is None or len(direction) == 0:
            self.sim.sun = None
            return
        unit, _ = check_sun_direction(list(direction))
        self.sim.sun = sun_with_direction(self.sim.sun, unit)

    def _sun_text(self) -> str:
        if self.sim.sun is None:
            return 'none'
        return '[' + ', '.join(f'{x:.4f}' for x in self.sim.sun.config.direction) + ']'

    def _on_sun(self, msg: Vector3Stamped) -> None:
        v = msg.vector
        topic = self.sun_sub.topic_name
        unit, rejection = check_sun_direction([v.x, v.y, v.z], msg.header.frame_id,
                                              self.get_parameter('frame_id').value,
                                              zero_is_dark=True)
        if rejection is not None:
            self._warn(rejection.kind, f'dropped sun direction on {topic}: {rejection.reason}')
            return
        now_ns = self.get_clock().now().nanoseconds
        stamp_ns = stamp_to_ns(msg.header.stamp) or now_ns   # unstamped: from its arrival
        lead_ns = round(self.get_parameter('stale_pose_timeout_s').value * NS_PER_S)
        if now_ns and stamp_ns - now_ns > lead_ns:
            self._warn('sun_future', f'dropped sun direction on {topic}: stamp '
                                     f'{stamp_ns / NS_PER_S:.3f} s is more than '
                                     f'stale_pose_timeout_s ahead of the clock '
                                     f'({now_ns / NS_PER_S:.3f} s)')
            return
        self._sun_track.add(stamp_ns, unit)

    def _apply_sun_at(self, start_ns: int) -> None:
        """The sun of the frame starting at ``start_ns``: the newest topic sample stamped at
        or before it (none: the sun stays as it was)."""
        found, unit = self._sun_track.at(start_ns)
        if not found:
            return
        topic = self.sun_sub.topic_name
        if unit is None:                        # a zero vector: the sun is hidden
            if self.sim.sun is not None:
                self._hidden_sun = self.sim.sun
                self.sim.sun = None
                self.get_logger().info(f'sun hidden (zero vector on {topic}): frames without '
                                       'sunlight until a direction comes')
            return
        if self.sim.sun is None and self._hidden_sun is not None:
            self.get_logger().info(f'sun back on {topic}')
        current = self.sim.sun or self._hidden_sun
        if current is not None and np.array_equal(current.config.direction, unit):
            self.sim.sun = current
            return
        self.sim.sun = sun_with_direction(current, unit)

    # -------------------------------------------------------------- poses
    def _on_pose(self, msg: PoseStamped) -> None:
        p, q = msg.pose.position, msg.pose.orientation
        self._accept(PoseSample(stamp_to_ns(msg.header.stamp), msg.header.frame_id,
                                np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w])),
                     self.pose_sub.topic_name)

    def _on_odometry(self, msg: Odometry) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        v, w = msg.twist.twist.linear, msg.twist.twist.angular
        self._accept(PoseSample(stamp_to_ns(msg.header.stamp), msg.header.frame_id,
                                np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w]),
                                np.array([v.x, v.y, v.z]), np.array([w.x, w.y, w.z])),
                     self.odom_sub.topic_name)

    def _accept(self, sample: PoseSample, topic: str) -> None:
        now_ns = self.get_clock().now().nanoseconds
        if now_ns == 0:
            self._warn('no_clock', f'dropped pose on {topic}: no /clock received yet (use_sim_time)')
            return
        stale_s = self.get_parameter('stale_pose_timeout_s').value
        newest = self.history.end_ns
        if newest is not None and newest - now_ns > round(stale_s * NS_PER_S):
            # Poses never lead the clock by more than stale_s: the clock went back
            # (e.g. a simulation restarted), so the history belongs to another run.
            self.history.clear()
        good, rejection = check_pose(sample, self.get_parameter('frame_id').value,
                                     self.history.end_ns, now_ns, stale_s)
        if rejection is not None:
            self._warn(rejection.kind, f'dropped pose on {topic}: {rejection.reason}')
            return
        if good.velocity_mps is not None:
            v, w = twist_to_lidar(good.quat_xyzw, good.velocity_mps, good.angular_velocity_rad_s)
            good = replace(good, velocity_mps=v, angular_velocity_rad_s=w)
        self.history.add(good)
        if self._waiting:
            self._tick()

    # ------------------------------------------------------------- frames
    def _tick(self, now_ns: int | None = None) -> None:
        if now_ns is None:
            now_ns = self.get_clock().now().nanoseconds
        if now_ns == 0:
            return  # use_sim_time and no /clock yet
        poll = self.scheduler.poll(now_ns)
        if poll.reset:
            self.get_logger().warning(
                f'clock went back to {now_ns / NS_PER_S:.3f} s: restarting the frame grid and '
                'forgetting the pose history')
            self.history.clear()
            self._sun_track.clear()
            self._warned_no_pose = False
        if poll.skipped:
            self._stats['skipped'] += poll.skipped
            self._warn('catch_up', f'clock jumped: dropped {poll.skipped} frames older than '
                                   f'the newest {self.scheduler.max_catch_up} (max_catch_up_frames)')
        self._waiting = False
        for k in poll.due:
            start_ns, end_ns = self.scheduler.start_ns(k), self.scheduler.end_ns(k)
            first_ns, last_ns = self._pose_window_ns(start_ns)
            ready = readiness(first_ns, last_ns, end_ns, now_ns,
                              self.history.start_ns, self.history.end_ns,
                              self.get_parameter('max_extrapolation_s').value,
                              self.get_parameter('stale_pose_timeout_s').value,
                              self.history.max_gap_ns(first_ns, max(last_ns, first_ns + 1)))
            if ready.action == WAIT:
                self._waiting = True
                return
            if ready.action == COMPUTE:
                self._publish_frame(k, start_ns)
            else:
                self._report_skip(k, start_ns, ready.kind, ready.reason)
            self.scheduler.done(k)

    def _report_skip(self, k: int, start_ns: int, kind: str, reason: str) -> None:
        self._stats['skipped'] += 1
        if kind == 'no_pose':
            if not self._warned_no_pose:
                self._warned_no_pose = True
                self.get_logger().warning(f'no pose received yet on {self.pose_sub.topic_name}: '
                                          'no frames until one arrives')
        elif kind == 'before_first_pose':
            self.get_logger().debug(f'frame {k} skipped: {reason}')
        else:
            self._warn(kind, f'frame {k} (stamp {start_ns / NS_PER_S:.3f} s) not published: {reason}')

    def _publish_frame(self, k: int, start_ns: int) -> None:
        t0 = time.perf_counter()
        try:
            # Pose times relative to the frame start keep float64 resolution at wall-clock epochs.
            track = self.history.track(start_ns, self.get_parameter('max_extrapolation_s').value,
                                       from_ns=min(start_ns, self._pose_window_ns(start_ns)[0]))
            self._apply_sun_at(start_ns)
            frame = self.sim.simulate_frame(0.0, track, frame_index=k)
            t1 = time.perf_counter()
            frame_id = self.get_parameter('frame_id').value
            points = self.layout.points(frame, self.sim, start_ns)
            out = [(self.points_pub, to_rclpy_msg(points, start_ns, frame_id))]
            # Packing and serialising the truth cloud costs ~1 ms: only for listeners.
            if (self.get_parameter('publish_truth').value
                    and self.truth_pub.get_subscription_count() > 0):
                truth = frame_points(frame, truth=True)
                out.append((self.truth_pub, to_rclpy_msg(truth, start_ns, frame_id)))
            if self.udp is not None:
                self.udp.submit(frame, start_ns)    # its own thread, paced; never blocks
            if self._deadline is None:
                _publish_all(out)
            else:
                self._deadline.submit(self.scheduler.end_ns(k) + self._latency_ns,
                                      partial(_publish_all, out))
        except Exception as exc:  # noqa: BLE001 - a bad frame must never kill the node
            self._stats['failed'] += 1
            self._warn('frame_error', f'frame {k} (stamp {start_ns / NS_PER_S:.3f} s) failed: '
                                      f'{type(exc).__name__}: {exc}', error=True)
            return
        self._stats['published'] += 1
        self._stats['compute_ms'].append(1e3 * (t1 - t0))
        self._stats['publish_ms'].append(1e3 * (time.perf_counter() - t1))

    # ------------------------------------------------------------ logging
    def _warn(self, kind: str, text: str, error: bool = False) -> None:
        log, suppressed = self.throttle.allow(kind, time.monotonic())
        if not log:
            return
        if suppressed:
            text += f' ({suppressed} more like this in the last {self.throttle.period_s:g} s)'
        # rclpy ties a severity to each calling line, so the two levels log from two lines.
        if error:
            self.get_logger().error(text)
        else:
            self.get_logger().warning(text)

    def _log_stats(self) -> None:
        s = self._stats
        ms, pub = np.array(s['compute_ms']), np.array(s['publish_ms'])
        timing = (f'; simulate p50 {np.median(ms):.1f} ms, max {ms.max():.1f} ms; publish '
                  f'p50 {np.median(pub):.1f} ms, max {pub.max():.1f} ms' if len(ms) else '')
        if self._deadline is not None:
            late, held, errors = self._deadline.take_stats()
            timing += (f'; held to the {self._latency_ns / 1e6:g} ms latency: p50 '
                       f'{np.median(held) if held else 0.0:.1f} ms, {late} late')
            if errors:
                self._warn('publish_error', f'publishing a held frame failed: {errors[0]} '
                                            f'({len(errors)} in the last {STATS_PERIOD_S:g} s)',
                           error=True)
        if self.udp is not None:
            timing += cepton_udp.stats_text(self.udp.take_stats())
        self.get_logger().info(f'last {STATS_PERIOD_S:g} s: {s["published"]} frames published, '
                               f'{s["skipped"]} skipped, {s["failed"]} failed{timing}')
        self._stats = {'published': 0, 'skipped': 0, 'failed': 0, 'compute_ms': [], 'publish_ms': []}


def _publish_all(out: list[tuple[Any, Any]]) -> None:
    """Publish each (publisher, message) of a frame."""
    for pub, msg in out:
        pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    return run_node(LidarSimNode, args, USER_ERRORS)


if __name__ == '__main__':
    sys.exit(main())
