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
from collections import deque
from functools import partial

import numpy as np
from geometry_msgs.msg import PointStamped, PoseStamped, QuaternionStamped, WrenchStamped
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
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros.parameters import declare_startup
from lidar_sim_ros.ros.spin import run_node

NODE_NAME = 'loop_controller'
NS_PER_S = 1_000_000_000


class LoopControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)

    def setup(self) -> None:
        p = partial(declare_startup, self)
        config_file = p('config_file', '', "loop YAML; '' = the package's config/loop.yaml")
        self.lidar_frame = p('lidar_frame', 'lidar', 'the frame_id estimates must carry')
        estimate_topic = p('estimate_topic', '/target/pose_estimate', 'geometry_msgs/PoseStamped in')
        command_topic = p('command_topic', '/chaser/force_command', 'geometry_msgs/WrenchStamped out')
        self.config, _ = load_loop_config(config_file or config_path('loop.yaml'))
        self.R_BL, self.t_B = frames.mount_transform(self.config.chaser.mount)
        a = EARTH_RADIUS_M + self.config.orbit.altitude_m
        self.n_rad_s = math.sqrt(EARTH_MU_M3_S2 / a ** 3)   # the nominal orbit's rate (known a priori)
        self.nav, self.guidance = NavState(), GuidanceState()
        self.attitudes: deque[tuple[int, np.ndarray]] = deque(maxlen=400)
        reliable = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(QuaternionStamped, '/chaser/attitude', self._on_attitude, reliable)
        self.create_subscription(PoseStamped, estimate_topic, self._on_estimate, QoSProfile(depth=20))
        self.pub = self.create_publisher(WrenchStamped, command_topic, QoSProfile(depth=20))
        self.ref_pub = self.create_publisher(PointStamped, '/loop/reference', QoSProfile(depth=20))
        self.get_logger().info(f'estimates on {estimate_topic} -> commands on {command_topic} (frame lvlh)')

    def _on_attitude(self, msg: QuaternionStamped) -> None:
        q = msg.quaternion
        self.attitudes.append((stamp_to_ns(msg.header.stamp), Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()))

    def _on_estimate(self, msg: PoseStamped) -> None:
        if msg.header.frame_id != self.lidar_frame:
            self.get_logger().warn(f'dropped estimate: frame_id {msg.header.frame_id!r} is not '
                                   f'{self.lidar_frame!r}', throttle_duration_sec=5.0)
            return
        if not self.attitudes:
            self.get_logger().warn('no /chaser/attitude yet: estimate dropped', throttle_duration_sec=5.0)
            return
        stamp_ns = stamp_to_ns(msg.header.stamp)
        _, R_HB = min(self.attitudes, key=lambda a: abs(a[0] - stamp_ns))
        pos = msg.pose.position
        t_s = stamp_ns / NS_PER_S
        rho = frames.chaser_from_estimate(np.array([pos.x, pos.y, pos.z]), R_HB, self.R_BL, self.t_B)
        self.nav = nav_update(self.config.guidance, self.nav, t_s, rho)
        # The command acts from the end of the frame's period: half a period after the estimate.
        t_cmd = t_s + 0.5 * self.config.control_period_s
        self.guidance, ref, force = guide_and_control(self.config, self.nav, self.guidance, t_cmd, self.n_rad_s)
        cmd = WrenchStamped()
        cmd.header.frame_id, cmd.header.stamp = 'lvlh', msg.header.stamp
        cmd.wrench.force.x, cmd.wrench.force.y, cmd.wrench.force.z = map(float, force)
        self.pub.publish(cmd)
        ref_msg = PointStamped()
        ref_msg.header = cmd.header
        ref_msg.point.x, ref_msg.point.y, ref_msg.point.z = map(float, ref.rho_m)
        self.ref_pub.publish(ref_msg)


def main(args: list[str] | None = None) -> int:
    return run_node(LoopControllerNode, args if args is not None else sys.argv, (ConfigError, ValueError))


if __name__ == '__main__':
    sys.exit(main())
