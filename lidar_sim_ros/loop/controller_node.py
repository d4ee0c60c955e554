"""``loop_controller``: the V-bar guidance and PD control on DDS, from the pose estimate only.

Reads ``/target/pose_estimate`` (geometry_msgs/PoseStamped in the lidar frame, as
pose_tracker publishes it) and ``/chaser/attitude`` (QuaternionStamped, the chaser's
own attitude in LVLH: to turn the estimate into LVLH; it says nothing about the target),
and for each estimate publishes a ``/chaser/force_command`` (WrenchStamped, frame
``lvlh``, stamped with the estimate's stamp, which is how the lock-step dynamics knows
the command answers the period it published), and the guidance reference it flew to on
``/loop/reference`` (PointStamped, LVLH, same stamp: for plots and scoring). The stages are the in-process loop's
(``step.navigate``'s frame chain, ``guidance``, ``control``). Run it with use_sim_time.
"""
from __future__ import annotations

import math
import sys
import time
from collections import deque
from functools import partial

import numpy as np
from geometry_msgs.msg import PointStamped, PoseStamped, QuaternionStamped, WrenchStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.io.pointcloud import stamp_to_ns
from lidar_sim_ros.loop import frames
from lidar_sim_ros.loop.config import load_loop_config
from lidar_sim_ros.loop.dynamics import EARTH_MU_M3_S2, EARTH_RADIUS_M
from lidar_sim_ros.loop.guidance import GuidanceState, NavState, nav_update
from lidar_sim_ros.loop.step import guide_and_control
from lidar_sim_ros.loop.user_gnc import load_user_gnc
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros.pose_input import DropCounter
from lidar_sim_ros.ros.parameters import declare_startup
from lidar_sim_ros.ros.spin import run_node

NODE_NAME = 'loop_controller'
NS_PER_S = 1_000_000_000
MAX_ESTIMATE_RANGE_M = 10_000.0   # farther than this an estimate is garbage (the sensor's gate is 250 m)
QUATERNION_TOLERANCE = 0.01       # |q| within 1 +- this is read as a unit quaternion (then normalised)
ATTITUDE_WAIT_S = 1.0            # wall s an input waits for the attitude sample at its time
DROP_CAUSES = ('attitude', 'frame', 'non_finite', 'range', 'stale', 'future', 'no_attitude', 'command')


def unit_quaternion(xyzw) -> np.ndarray | None:
    """The quaternion normalised, or None when it is not finite or not near unit length
    (a zero or NaN quaternion cannot be an attitude)."""
    q = np.asarray(xyzw, float)
    if not np.isfinite(q).all():
        return None
    with np.errstate(over='ignore'):
        norm = float(np.linalg.norm(q))
    return q / norm if abs(norm - 1.0) <= QUATERNION_TOLERANCE else None


def estimate_problem(frame_id: str, lidar_frame: str, stamp_s: float, position_m, quat_xyzw,
                     last_stamp_s: float | None, now_s: float, period_s: float) -> str | None:
    """Why an estimate cannot be flown on (None: it can): its frame, a non-finite or absurd
    position (farther than MAX_ESTIMATE_RANGE_M), a non-unit quaternion, a stamp not after
    the last estimate's (stale: a replay or reordering), or one more than a period ahead of
    the node's clock (future; ``now_s`` 0: no clock yet, not checked)."""
    if frame_id != lidar_frame:
        return 'frame'
    p = np.asarray(position_m, float)
    if not np.isfinite(p).all() or unit_quaternion(quat_xyzw) is None:
        return 'non_finite'
    if np.abs(p).max() > MAX_ESTIMATE_RANGE_M or float(np.linalg.norm(p)) > MAX_ESTIMATE_RANGE_M:
        return 'range'
    if last_stamp_s is not None and stamp_s <= last_stamp_s:
        return 'stale'
    if now_s > 0 and stamp_s > now_s + period_s:
        return 'future'
    return None


class LoopControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)

    def setup(self) -> None:
        p = partial(declare_startup, self)
        config_file = p('config_file', '', "loop YAML; '' = the package's config/loop.yaml")
        self.lidar_frame = p('lidar_frame', 'lidar', 'the frame_id estimates must carry')
        estimate_topic = p('estimate_topic', '/target/pose_estimate', 'geometry_msgs/PoseStamped in')
        lost_topic = p('lost_topic', '/target/pose_lost', (
            "std_msgs/Header in: a period whose cloud gave no estimate (pose_tracker's lost_topic); "
            "answered from the filter coasting, as in process; '' = none"))
        command_topic = p('command_topic', '/chaser/force_command', 'geometry_msgs/WrenchStamped out')
        self.config, _ = load_loop_config(config_file or config_path('loop.yaml'))
        self.R_BL, self.t_B = frames.mount_transform(self.config.chaser.mount)
        a = EARTH_RADIUS_M + self.config.orbit.altitude_m
        self.n_rad_s = math.sqrt(EARTH_MU_M3_S2 / a ** 3)   # the nominal orbit's rate (known a priori)
        self.nav, self.guidance = NavState(), GuidanceState()
        # The config's own controller / navigation (user_gnc): from the start-up config file only.
        self.gnc = load_user_gnc(self.config)
        self.attitudes: deque[tuple[int, np.ndarray]] = deque(maxlen=400)
        self.last_stamp_s: float | None = None
        self._drops = DropCounter(DROP_CAUSES)
        self.dropped = self._drops.counts
        reliable = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(QuaternionStamped, '/chaser/attitude', self._on_attitude, reliable)
        self.create_subscription(PoseStamped, estimate_topic, self._on_estimate, QoSProfile(depth=20))
        if lost_topic:
            from std_msgs.msg import Header
            self.create_subscription(Header, lost_topic, self._on_lost, QoSProfile(depth=20))
        self.waiting: deque = deque(maxlen=20)   # inputs whose attitude sample has not come yet
        # An input whose attitude sample never comes (lost to discovery at the start) is
        # answered with the nearest sample after ATTITUDE_WAIT_S of wall time (logged).
        self.create_timer(0.05, self._flush_waiting, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.pub = self.create_publisher(WrenchStamped, command_topic, QoSProfile(depth=20))
        self.ref_pub = self.create_publisher(PointStamped, '/loop/reference', QoSProfile(depth=20))
        self.get_logger().info(f'estimates on {estimate_topic} -> commands on {command_topic} (frame lvlh)')

    def _drop(self, cause: str, text: str) -> None:
        self._drops.drop(cause, text, self.get_logger().warn)

    def _on_attitude(self, msg: QuaternionStamped) -> None:
        q = msg.quaternion
        unit = unit_quaternion([q.x, q.y, q.z, q.w])
        if unit is None:
            self._drop('attitude', f'dropped /chaser/attitude stamped {stamp_to_ns(msg.header.stamp) / NS_PER_S:.6f} s: '
                                   f'quaternion {[q.x, q.y, q.z, q.w]} is not a finite unit quaternion')
            return
        self.attitudes.append((stamp_to_ns(msg.header.stamp), Rotation.from_quat(unit).as_matrix()))
        ready = sorted((w for w in self.waiting if w[0] <= self.attitudes[-1][0]), key=lambda w: w[0])
        for item in ready:
            self.waiting.remove(item)
        for item in ready:
            self._answer(*item[1:5])

    def _flush_waiting(self) -> None:
        """Answer inputs that waited ATTITUDE_WAIT_S for their attitude sample with the nearest one."""
        now = time.monotonic()
        overdue = sorted((w for w in self.waiting if now - w[5] >= ATTITUDE_WAIT_S), key=lambda w: w[0])
        for item in overdue:
            self.waiting.remove(item)
        for item in overdue:
            self.get_logger().warn(f'no /chaser/attitude sample at or after {item[0] / NS_PER_S:.6f} s within '
                                   f'{ATTITUDE_WAIT_S:g} s: answered with the nearest one (start the dynamics '
                                   'with /chaser/attitude in wait_for_subscribers)')
            self._answer(*item[1:5], force_now=True)

    def _on_estimate(self, msg: PoseStamped) -> None:
        pos, o = msg.pose.position, msg.pose.orientation
        self._answer(msg.header, msg.header.frame_id, [pos.x, pos.y, pos.z], [o.x, o.y, o.z, o.w])

    def _on_lost(self, msg) -> None:
        self._answer(msg, msg.frame_id, None, None)

    def _answer(self, header, frame_id: str, position_m, quat_xyzw, force_now: bool = False) -> None:
        """Command the period of an estimate (or of a lost one: ``position_m`` None) once the
        chaser's attitude at its stamp is in (DDS does not order the two topics: the
        attitude nearest an estimate must not depend on which came first)."""
        stamp_ns = stamp_to_ns(header.stamp)
        now_s = self.get_clock().now().nanoseconds / NS_PER_S
        ahead = now_s > 0 and stamp_ns / NS_PER_S > now_s + self.config.control_period_s
        if not ahead and not (force_now and self.attitudes) and (
                not self.attitudes or self.attitudes[-1][0] < stamp_ns):
            if len(self.waiting) == self.waiting.maxlen:
                self._drop('stale', f'input stamped {self.waiting[0][0] / NS_PER_S:.6f} s dropped: no attitude '
                                    f'sample at its time came while {self.waiting.maxlen} inputs waited')
            self.waiting.append((stamp_ns, header, frame_id, position_m, quat_xyzw, time.monotonic()))
            return
        out = (self.command_for(frame_id, stamp_ns, position_m, quat_xyzw, now_s) if position_m is not None
               else self.command_for_loss(frame_id, stamp_ns, now_s))
        if out is None:
            return
        force, ref = out
        cmd = WrenchStamped()
        cmd.header.frame_id, cmd.header.stamp = 'lvlh', header.stamp
        cmd.wrench.force.x, cmd.wrench.force.y, cmd.wrench.force.z = map(float, force)
        self.pub.publish(cmd)
        ref_msg = PointStamped()
        ref_msg.header = cmd.header
        ref_msg.point.x, ref_msg.point.y, ref_msg.point.z = map(float, ref.rho_m)
        self.ref_pub.publish(ref_msg)

    def command_for(self, frame_id: str, stamp_ns: int, position_m, quat_xyzw, now_s: float):
        """(force (N, LVLH), reference) for an estimate, or None when it is dropped (counted,
        logged): the navigation, guidance and control stages of ``step``."""
        t_s = stamp_ns / NS_PER_S
        period = self.config.control_period_s
        problem = estimate_problem(frame_id, self.lidar_frame, t_s, position_m, quat_xyzw,
                                   self.last_stamp_s, now_s, period)
        if problem is None and not self.attitudes:
            problem = 'no_attitude'
        if problem is not None:
            self._drop(problem, f'dropped estimate stamped {t_s:.6f} s (frame {frame_id[:64]!r}, position '
                                f'{list(map(float, position_m))} m, quaternion {list(map(float, quat_xyzw))}): '
                                f'{problem}' + (f' (the last was {self.last_stamp_s:.6f} s)'
                                                if problem == 'stale' else '')
                                + (f' (the clock is {now_s:.6f} s)' if problem == 'future' else ''))
            return None
        _, R_HB = min(self.attitudes, key=lambda a: abs(a[0] - stamp_ns))
        rho = frames.chaser_from_estimate(np.asarray(position_m, float), R_HB, self.R_BL, self.t_B)
        if self.gnc is not None and self.gnc.navigation is not None:
            self.gnc.navigation.update(t_s, rho)
            nav = self.nav
        else:
            nav = nav_update(self.config.guidance, self.nav, t_s, rho)
        # The command acts from the end of the frame's period: half a period after the estimate.
        guidance, ref, force = guide_and_control(self.config, nav, self.guidance, t_s + 0.5 * period,
                                                 self.n_rad_s, self.gnc)
        if not np.isfinite(force).all():
            self._drop('command', f'estimate stamped {t_s:.6f} s gives a non-finite command: dropped, '
                                  'the filter and guidance keep their state')
            return None
        self.nav, self.guidance, self.last_stamp_s = nav, guidance, t_s
        return force, ref

    def command_for_loss(self, frame_id: str, stamp_ns: int, now_s: float):
        """(force, reference) for a period whose cloud gave no estimate: the filter coasts, as
        ``step.navigate`` does in process; None when the notice is dropped."""
        t_s = stamp_ns / NS_PER_S
        period = self.config.control_period_s
        problem = estimate_problem(frame_id, self.lidar_frame, t_s, [0.0, 0.0, 0.0], [0, 0, 0, 1],
                                   self.last_stamp_s, now_s, period)
        if problem is not None:
            self._drop(problem, f'dropped a lost-track notice stamped {t_s:.6f} s (frame {frame_id[:64]!r}): {problem}')
            return None
        if self.gnc is not None and self.gnc.navigation is not None:
            self.gnc.navigation.update(t_s, None)
        guidance, ref, force = guide_and_control(self.config, self.nav, self.guidance, t_s + 0.5 * period,
                                                 self.n_rad_s, self.gnc)
        self.guidance, self.last_stamp_s = guidance, t_s
        return force, ref


def main(args: list[str] | None = None) -> int:
    return run_node(LoopControllerNode, args if args is not None else sys.argv, (ConfigError, ValueError))


if __name__ == '__main__':
    sys.exit(main())
