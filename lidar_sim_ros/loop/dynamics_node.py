"""``loop_dynamics``: Basilisk's chaser and target on DDS, the loop's clock.

Each control period it applies the force command in force, advances Basilisk over the
period (``step.propagate``, the in-process loop's own stage), and publishes, stamped on
the simulated clock (``epoch_s`` + loop time):

- ``/target/pose`` (geometry_msgs/PoseStamped, frame ``lidar_frame``): the target body
  pose in the lidar frame at every dynamics sub-step (``timing.pose_rate_hz``, 100 Hz);
- ``/sun/direction`` (geometry_msgs/Vector3Stamped, lidar frame), once per period; a zero
  vector while the chaser is in the Earth's shadow (``sun.eclipse``: lidar_sim_node then
  simulates without sunlight; entering and leaving it are logged);
- ``/chaser/attitude`` (geometry_msgs/QuaternionStamped, frame ``lvlh``): the chaser
  body's attitude in LVLH at every sub-step, what its own attitude determination would
  give the GNC (no target information);
- ``/loop/chaser_pose``, ``/loop/target_pose`` (PoseStamped, frame ``lvlh``), once per
  period: the truth for plots and scoring (no GNC node may read them);
- ``/tf``: lvlh -> chaser, chaser -> lidar (the mount), lvlh -> target, when tf2_msgs is
  installed (a Jazzy install has it; the pip wheels do not: then it logs so once);
- then ``/clock`` (rosgraph_msgs/Clock) at the period's end.

It subscribes to ``/chaser/force_command`` (geometry_msgs/WrenchStamped; frame ``lvlh``
or ``chaser``: force in the chaser body frame; the torque is ignored: the attitude is
kinematic). Which command answers which period, what is refused and clipped, and when
to advance are ``timing``'s (``admit_force``, ``CommandGate``; docs/loop.md): every
refusal and clip is counted by cause and logged with the command's stamp (at most one
line a second per cause, with the count), and the counts, the late and timed-out periods
go to ``stats_file`` at the end.
"""
from __future__ import annotations

import sys
import time
from functools import partial

import numpy as np
from geometry_msgs.msg import PoseStamped, QuaternionStamped, Vector3Stamped, WrenchStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.io.pointcloud import ns_to_stamp, stamp_to_ns
from lidar_sim_ros.loop import frames
from lidar_sim_ros.loop.config import load_loop_config
from lidar_sim_ros.loop.step import TruthSamples, propagate
from lidar_sim_ros.loop.timing import CommandGate, admit_force
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros.parameters import declare_startup
from lidar_sim_ros.ros.spin import run_node

NODE_NAME = 'loop_dynamics'
NS_PER_S = 1_000_000_000
POLL_S = 0.001       # the shortest wait of the poll (wall s)
MAX_POLL_S = 0.05    # the longest: the poll wakes when the next thing is due (``_schedule``); a
                     # fixed 1 kHz poll cost the node ~25 % of a core, the most of the five nodes
STATS_PERIOD_S = 10.0
NOTE_PERIOD_S = 1.0   # per refusal or clip cause: at most one log line a second (with its count)
REFUSAL_TEXT = {
    'non_finite': 'a force component is NaN or infinite',
    'frame': "frame_id must be 'lvlh' or 'chaser'",
    'stale': "stamped before the pending period (an older period's answer)",
    'future': 'stamped at or after the end of the pending period (no frame of that time yet)',
    'duplicate': 'the pending period already has its command (the first one stands)',
    'sent_early': "sent before the /clock that closed its period (cannot answer that period's frame)",
}
PEER_SETTLE_S = 0.5
START_DELAY_S = 0.5  # between the first /clock (loop time zero) and the first period
ZERO_CLOCK_EVERY_S = 0.05  # the /clock at loop time zero, repeated until the first period
CLOCK_DELAY_S = 0.002  # /clock goes out this long after the period's poses: DDS does not
                       # order two topics, and a frame computed on part of its poses fails  # after discovery, let the publishers and subscriptions match


def _stamp(t_s: float):
    from builtin_interfaces.msg import Time
    return ns_to_stamp(round(t_s * NS_PER_S), Time)


def _pose_msg(frame_id: str, t_s: float, R: np.ndarray, p: np.ndarray) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id, msg.header.stamp = frame_id, _stamp(t_s)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, p)
    q = Rotation.from_matrix(R).as_quat()
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = map(float, q)
    return msg


class LoopDynamicsNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)

    def setup(self) -> None:
        p = partial(declare_startup, self)
        config_file = p('config_file', '', "loop YAML; '' = the package's config/loop.yaml")
        self.epoch_s = p('epoch_s', 100.0, 'clock time (s) of loop time zero (> 0: ROS reads 0 as no clock)')
        self.lidar_frame = p('lidar_frame', 'lidar', 'frame_id of /target/pose and /sun/direction '
                                                     '(the simulator node\'s frame_id)')
        mode = p('timing_mode', '', "'lockstep' | 'realtime'; '' = the config's timing.mode")
        timeout = p('command_timeout_s', 0.0, "lock-step wait for a command (s); 0 = the config's")
        startup = p('startup_timeout_s', 0.0, "lock-step wait for the run's first command (s); 0 = the config's")
        skew = p('max_clock_skew_s', 0.0, (
            'a command sent (DDS source time) earlier than this before the /clock that closed its '
            'period is refused as sent_early; > 0 for a controller on another machine whose wall '
            'clock may run behind (s)'))
        self.stats_file = p('stats_file', '', "write the counts and per-period records here (JSON) "
                                              "at the end; '' = none")
        command_topic = p('command_topic', '/chaser/force_command', 'geometry_msgs/WrenchStamped in')
        self.wait_for_peers = p('wait_for_peers', True, 'start once each of wait_for_subscribers '
                                                        'has a subscriber and each of wait_for_publishers a publisher')
        self.wait_for_publishers = list(p('wait_for_publishers', [command_topic],
                                          'topics that need a publisher before the lock-step starts'))
        self.wait_for_subscribers = list(p('wait_for_subscribers', ['/target/pose'], (
            'topics that need a subscriber before the lock-step starts (add /chaser/attitude when '
            'the GNC reads it: its first samples are not lost to discovery)')))
        self.command_topic = command_topic
        self.clock_delay_s = float(p('clock_delay_s', 0.002, (
            "/clock goes out this long (wall s) after the period's poses: DDS does not order two "
            'topics, nor does an executor serve one queue before another, and a frame computed on '
            'part of its poses can fail')))
        for name, value, low, high in (('epoch_s', self.epoch_s, 1e-9, 4e9), ('command_timeout_s', timeout, 0, 3600),
                                       ('startup_timeout_s', startup, 0, 3600), ('max_clock_skew_s', skew, 0, 60),
                                       ('clock_delay_s', self.clock_delay_s, 0, 1)):
            if not (isinstance(value, (int, float)) and np.isfinite(value) and low <= value <= high):
                raise ConfigError('<parameter>', name, value, f'must be a number in [{low:g}, {high:g}]')
        self.config, _ = load_loop_config(config_file or config_path('loop.yaml'))
        cfg = self.config
        mode = mode or cfg.timing.mode
        if mode not in ('lockstep', 'realtime'):
            raise ConfigError('<parameter>', 'timing_mode', mode, "must be 'lockstep' or 'realtime'")
        from lidar_sim_ros.loop.dynamics import Dynamics
        self.dynamics = Dynamics(cfg)
        self.R_BL, self.t_B = frames.mount_transform(cfg.chaser.mount)
        self.gate = CommandGate(mode, cfg.control_period_s, timeout or cfg.timing.command_timeout_s,
                                startup or cfg.timing.startup_timeout_s, skew,
                                realtime_waits_for_first_command=cfg.timing.realtime_waits_for_first_command)
        self._noted: dict[tuple[str, str], float] = {}
        self.late_periods: list[int] = []
        self.timeout_periods: list[int] = []
        self.steps = int(round(cfg.duration_s / cfg.control_period_s))
        self.k = 0
        self.dark = False  # in the Earth's shadow (the last period)
        self.peers_since: float | None = None
        self.pending_clock: tuple[float, float, float] | None = None
        self.start_wall: float | None = None
        self.force_lvlh = np.zeros(3)
        self.R_HB = np.eye(3)
        self.delta_v = 0.0
        self.wall0 = time.monotonic()

        reliable = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.clock_pub = self.create_publisher(ClockMsg, '/clock', QoSProfile(depth=10))
        self.pose_pub = self.create_publisher(PoseStamped, '/target/pose', reliable)
        self.sun_pub = self.create_publisher(Vector3Stamped, '/sun/direction', QoSProfile(depth=10))
        self.attitude_pub = self.create_publisher(QuaternionStamped, '/chaser/attitude', reliable)
        self._setup_tf()
        # depth 100: a burst of other commands must not push the pending period's out of the queue
        self.create_subscription(WrenchStamped, command_topic, self._on_command, QoSProfile(depth=100))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.poll = self.create_timer(POLL_S, self._poll, clock=steady)
        self.create_timer(STATS_PERIOD_S, self._log_stats, clock=steady)
        self.get_logger().info(
            f'{mode}: {self.steps} periods of {cfg.control_period_s:g} s, poses at '
            f'{cfg.timing.pose_rate_hz:g} Hz on {self.pose_pub.topic_name} (frame {self.lidar_frame!r}), '
            f'commands on {command_topic}, clock epoch {self.epoch_s:g} s')

    # ------------------------------------------------------------------ tf
    def _setup_tf(self) -> None:
        self.chaser_pose_pub = self.create_publisher(PoseStamped, '/loop/chaser_pose', QoSProfile(depth=50))
        self.target_pose_pub = self.create_publisher(PoseStamped, '/loop/target_pose', QoSProfile(depth=50))
        try:
            from geometry_msgs.msg import TransformStamped
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.tf_pub = None
            self.get_logger().info('tf2_msgs is not installed (no pip wheel for Jazzy): no /tf; '
                                   'the same poses are on /loop/chaser_pose, /loop/target_pose '
                                   '(PoseStamped, frame lvlh); the mount is config chaser.mount')
            return
        self._TransformStamped, self._TFMessage = TransformStamped, TFMessage
        self.tf_pub = self.create_publisher(TFMessage, '/tf', QoSProfile(depth=100))

    def _transform(self, parent: str, child: str, t_s: float, R: np.ndarray, p: np.ndarray):
        tf = self._TransformStamped()
        tf.header.frame_id, tf.header.stamp, tf.child_frame_id = parent, _stamp(t_s), child
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = map(float, p)
        r = tf.transform.rotation
        r.x, r.y, r.z, r.w = map(float, Rotation.from_matrix(R).as_quat())
        return tf

    def _publish_scene(self, t_s: float, truth: TruthSamples) -> None:
        """LVLH -> chaser, chaser -> lidar, LVLH -> target at the period's end."""
        R_HB, rho = truth.R_HB[-1], truth.rho_m[-1]
        R_HT = R_HB @ self.R_BL @ truth.R_LT[-1]
        self.chaser_pose_pub.publish(_pose_msg('lvlh', t_s, R_HB, rho))
        self.target_pose_pub.publish(_pose_msg('lvlh', t_s, R_HT, np.zeros(3)))
        if self.tf_pub is None:
            return
        self.tf_pub.publish(self._TFMessage(transforms=[
            self._transform('lvlh', 'chaser', t_s, R_HB, rho),
            self._transform('chaser', self.lidar_frame, t_s, self.R_BL, self.t_B),
            self._transform('lvlh', 'target', t_s, R_HT, np.zeros(3))]))

    # --------------------------------------------------------------- commands
    def _on_command(self, msg: WrenchStamped, info: dict) -> None:
        """Every command is admitted (``timing.admit_force``) and offered to the gate, or
        refused with a line naming the cause and the stamp (``_note``)."""
        stamp_ns = stamp_to_ns(msg.header.stamp)
        t_s = stamp_ns / NS_PER_S - self.epoch_s
        w = msg.wrench.force
        cfg = self.config.chaser
        force, refused, clip = admit_force(msg.header.frame_id, [w.x, w.y, w.z], self.R_HB,
                                           cfg.thrust_limit_n, cfg.dead_band_n)
        sent_ns = info.get('source_timestamp') if isinstance(info, dict) else None  # rclpy's message info
        sent_s = sent_ns / NS_PER_S if sent_ns else None
        if refused is not None:
            self.gate.refuse(refused)
        else:
            refused = self.gate.offer(t_s, force, sent_s, clip)
        if refused is not None:
            window = self.gate.window_s
            pending = (f'[{window[0]:.3f}, {window[1]:.3f}) s' if window else 'none yet')
            self._note('refused', refused, f'refused force command stamped {t_s:.6f} s (loop time; '
                       f'{stamp_ns / NS_PER_S:.6f} s on the clock), frame {msg.header.frame_id[:64]!r}, '
                       f'force {[w.x, w.y, w.z]} N: {REFUSAL_TEXT[refused]}; pending period {pending}',
                       self.gate.refused[refused])
        else:
            self._tick()         # the pending period's command: go on now, not at the next poll
            self._schedule()
        if refused is None and clip is not None:
            self._note('clipped', clip, f'force command stamped {t_s:.6f} s clipped ({clip}): '
                       f'{[w.x, w.y, w.z]} N in {msg.header.frame_id[:64]!r} flies as '
                       f'{np.round(force, 6).tolist()} N (LVLH)', self.gate.clipped[clip])

    def _note(self, what: str, cause: str, text: str, count: int) -> None:
        """One warning per cause at most every NOTE_PERIOD_S (wall), with that cause's count:
        a flood of one cause cannot hide another (each has its own throttle)."""
        now = time.monotonic()
        key = (what, cause)
        if now - self._noted.get(key, -np.inf) >= NOTE_PERIOD_S:
            self._noted[key] = now
            self.get_logger().warn(f'{text} [{what} for {cause}: {count} so far]')

    # ------------------------------------------------------------------ step
    def _peers_ready(self) -> bool:
        """Lock-step starts when the loop is there: nothing published before is lost."""
        if self.peers_since is None:
            if all(self.count_subscribers(topic) for topic in self.wait_for_subscribers) and all(
                    self.count_publishers(topic) for topic in self.wait_for_publishers):
                self.peers_since = time.monotonic()
                self.get_logger().info('peers found: starting in 0.5 s')
            return False
        return time.monotonic() - self.peers_since >= PEER_SETTLE_S

    def _poll(self) -> None:
        self._tick()
        self._schedule()

    def _schedule(self) -> None:
        """Wake the poll when the next thing is due: the pending /clock, the real-time period,
        the lock-step timeout (an accepted command ticks at once, ``_on_command``); at least
        every MAX_POLL_S, at most every POLL_S."""
        now = time.monotonic()
        g = self.gate
        if self.pending_clock is not None:
            wait = self.pending_clock[2] - now
        elif self.k == 0 or self.k >= self.steps or g.published_wall_s is None:
            wait = MAX_POLL_S if self.k >= self.steps else POLL_S
        elif g.mode == 'realtime' and not g.starting:
            wait = g.next_wall_s - now - 1e-4
        else:
            wait = g.published_wall_s + g.current_timeout_s - now
        period_ns = round(min(max(wait, POLL_S), MAX_POLL_S) * 1e9)
        if self.poll.timer_period_ns != period_ns:
            self.poll.timer_period_ns = period_ns
        self.poll.reset()

    def _tick(self) -> None:
        if self.pending_clock is not None:
            t_end, t0, wall = self.pending_clock
            if time.monotonic() < wall:
                return
            sent_s = time.time()   # before the /clock: an answer is sent after this
            self.clock_pub.publish(ClockMsg(clock=_stamp(t_end)))
            self.gate.published(t0, time.monotonic(), sent_s)
            self.pending_clock = None
            if self.k == self.steps:
                self._log_stats()
                self._write_stats()
                self.get_logger().info('done: the configured duration is simulated; the clock stops here')
            return
        if self.k >= self.steps:
            return
        # Both modes start when the loop is there (real time waits for the first command too).
        if self.k == 0 and self.wait_for_peers and not self._peers_ready():
            return
        if self.k == 0 and self.start_wall is None:
            self.start_wall = time.monotonic() + START_DELAY_S
            self._zero_clock_wall = -np.inf
        if self.k == 0 and time.monotonic() < self.start_wall:
            # The clock at loop time zero first, again every ZERO_CLOCK_EVERY_S until the first
            # period: a use_sim_time node drops poses before any /clock, and a single zero
            # /clock was lost once to a subscription not yet matched (lidar_sim_node then
            # dropped the first period's poses: no frame 0, a 30 s start-up timeout).
            if time.monotonic() - self._zero_clock_wall >= ZERO_CLOCK_EVERY_S:
                self.clock_pub.publish(ClockMsg(clock=_stamp(self.epoch_s)))
                self._zero_clock_wall = time.monotonic()
            return
        wall = time.monotonic()
        if not self.gate.due(wall):
            return
        timeout_s = self.gate.current_timeout_s
        force, problem = self.gate.take()
        if problem in ('timeout', 'startup_timeout'):
            self.timeout_periods.append(self.k - 1)
            what = ("the run's first command (start-up timeout)" if problem == 'startup_timeout'
                    else 'a command for the period')
            self.get_logger().warn(f'period {self.k - 1}: no command for the period from '
                                   f'{self.gate.pending_start_s:.2f} s within {timeout_s:g} s (wall) '
                                   f'waiting for {what}: going on with no force')
        elif problem == 'late':
            self.late_periods.append(self.k - 1)
        self.force_lvlh = force
        self._advance()

    def _advance(self) -> None:
        cfg = self.config
        t0 = self.dynamics.t_s
        truth = propagate(cfg, self.dynamics, self.force_lvlh, self.R_BL, self.t_B)
        self.delta_v += float(np.linalg.norm(self.force_lvlh)) * cfg.control_period_s / cfg.chaser.mass_kg
        # The sun first: lidar_sim_node simulates a frame with the newest sun it has (not the one
        # stamped for the frame), so the period's sun gets the longest lead over the /clock.
        if truth.dark != self.dark:
            self.dark = truth.dark
            self.get_logger().info(f"t = {t0:.1f} s: the chaser {'enters' if self.dark else 'leaves'} "
                                   "the Earth's shadow (/sun/direction " + ('zero: the sun hidden)' if self.dark
                                                                          else 'the direction again)'))
        sun = Vector3Stamped()
        sun.header.frame_id, sun.header.stamp = self.lidar_frame, _stamp(self.epoch_s + t0)
        if not self.dark:
            sun.vector.x, sun.vector.y, sun.vector.z = map(float, truth.sun_lidar[0])
        self.sun_pub.publish(sun)
        first = 0 if self.k == 0 else 1   # the period's first sample is the last one's end
        for j in range(first, len(truth.t_s)):
            t = self.epoch_s + float(truth.t_s[j])
            self.pose_pub.publish(_pose_msg(self.lidar_frame, t, truth.R_LT[j], truth.t_L_m[j]))
            att = QuaternionStamped()
            att.header.frame_id, att.header.stamp = 'lvlh', _stamp(t)
            q = att.quaternion
            q.x, q.y, q.z, q.w = map(float, Rotation.from_matrix(truth.R_HB[j]).as_quat())
            self.attitude_pub.publish(att)
        t_end = self.epoch_s + float(truth.t_s[-1])
        self._publish_scene(t_end, truth)
        self.R_HB = truth.R_HB[-1]
        self.pending_clock = (t_end, t0, time.monotonic() + self.clock_delay_s)
        self.k += 1
        self.range_m = float(np.linalg.norm(truth.t_L_m[-1]))
        self.rho = truth.rho_m[-1]

    def _log_stats(self) -> None:
        if self.k == 0:
            return
        t = self.dynamics.t_s
        wall = time.monotonic() - self.wall0
        g = self.gate
        publishers = self.get_publishers_info_by_topic(self.command_topic)
        if len(publishers) > 1:
            # The gate cannot tell two publishers apart: the first command in a period's
            # window stands, whoever sent it (docs/loop.md: keep others off the topic).
            self.get_logger().warn(f'{len(publishers)} publishers on {self.command_topic}: '
                                   + ', '.join(sorted(f'{p.node_namespace.rstrip("/")}/{p.node_name}'
                                                      for p in publishers)))
        self.get_logger().info(
            f't = {t:.1f} s ({t / wall:.2f}x real time), range {self.range_m:.2f} m, LVLH '
            f'[{self.rho[0]:.2f}, {self.rho[1]:.2f}, {self.rho[2]:.2f}] m, delta-v {self.delta_v:.3f} m/s; '
            f'commands {g.commands}, timeouts {g.timeouts} (start-up {g.startup_timeouts}), late {g.late}, '
            f'refused {_nonzero(g.refused)}, clipped {_nonzero(g.clipped)}')

    def statistics(self) -> dict:
        """What happened (loop.json): the gate's counts, the periods late or timed out, the
        timing mode actually run, the wall time since start."""
        return {**self.gate.statistics(), 'timing_mode': self.gate.mode, 'periods': self.k,
                'late_period_indices': list(self.late_periods),
                'timeout_period_indices': list(self.timeout_periods),
                'wall_s': time.monotonic() - (self.start_wall or self.wall0), 'simulated_s': self.dynamics.t_s}

    def _write_stats(self) -> None:
        if self.stats_file:
            import json
            from pathlib import Path
            Path(self.stats_file).write_text(json.dumps(self.statistics(), indent=1))


def _nonzero(counts: dict) -> dict:
    return {k: v for k, v in counts.items() if v} or 0


def main(args: list[str] | None = None) -> int:
    return run_node(LoopDynamicsNode, args if args is not None else sys.argv, (ConfigError, ValueError))


if __name__ == '__main__':
    sys.exit(main())
