"""``target_pose_player``: the scenario's relative trajectory on ``/target/pose``.

Publishes ``ScenarioTrajectory`` (approach + tumble from the scenario YAML) as
``geometry_msgs/PoseStamped`` in the scenario's frame, so the node runs end to end
with no external GNC. Stamps sit on a fixed grid of the node clock (j / rate_hz),
published as soon as the clock passes them, so under ``use_sim_time`` every grid
point is published once however ``/clock`` advances.
"""
from __future__ import annotations

import sys

from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, ParameterType
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.io.pointcloud import ns_to_stamp
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros.spin import run_node
from lidar_sim_ros.ros.scheduler import NS_PER_S, FrameScheduler

NODE_NAME = 'target_pose_player'
MAX_BURST = 500  # most poses published in one tick after a clock jump


def _param(ptype: int, text: str, read_only: bool = True, lo: float | None = None,
           hi: float | None = None) -> ParameterDescriptor:
    desc = ParameterDescriptor(type=ptype, description=text, read_only=read_only)
    if lo is not None:
        desc.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi)]
    return desc


class TargetPosePlayer(Node):
    """Publish the scenario trajectory at ``rate_hz`` on ``topic``."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)

    def setup(self) -> None:
        S, F = ParameterType.PARAMETER_STRING, ParameterType.PARAMETER_DOUBLE
        scenario_file = self.declare_parameter(
            'scenario_file', '', _param(S, "scenario YAML; '' = the package's config/scenario.yaml")).value
        topic = self.declare_parameter(
            'topic', '/target/pose', _param(S, 'geometry_msgs/PoseStamped output')).value
        rate_hz = self.declare_parameter(
            'rate_hz', 50.0, _param(F, 'poses per second (>= 5 per sensor frame advised)',
                                    lo=0.1, hi=10000.0)).value
        scenario = load_scenario(scenario_file or config_path('scenario.yaml'))
        self.frame_id = self.declare_parameter(
            'frame_id', scenario.config.frame_id,
            _param(S, "header frame_id (default: the scenario's frame_id)")).value
        self.epoch_s = self.declare_parameter(
            'epoch_s', -1.0, _param(F, 'clock time (s) of trajectory time zero; < 0 = the '
                                       'first published stamp', lo=-1.0, hi=1e12)).value
        self.trajectory = ScenarioTrajectory.from_config(scenario.config)
        self.trajectory.at(0.0)  # compile the trajectory kernel now, not in the first tick
        self.grid = FrameScheduler(rate_hz)
        self.epoch_ns: int | None = None if self.epoch_s < 0 else round(self.epoch_s * NS_PER_S)
        self.last_index: int | None = None
        self.pub = self.create_publisher(
            PoseStamped, topic, QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        # Tick on the wall clock at twice the rate; stamps come from the node clock.
        self.create_timer(0.5 / rate_hz, self._tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'publishing the trajectory of {scenario.source} on '
                               f'{self.pub.topic_name} at {rate_hz:g} Hz, frame {self.frame_id!r}')

    def _tick(self) -> None:
        now_ns = self.get_clock().now().nanoseconds
        if now_ns == 0:
            return  # use_sim_time and no /clock yet
        j_now = self.grid.index_at(now_ns)
        if self.last_index is None or j_now < self.last_index or j_now - self.last_index > MAX_BURST:
            self.last_index = j_now - 1  # start, clock went back, or a big jump: resume at now
        for j in range(self.last_index + 1, j_now + 1):
            self._publish(self.grid.start_ns(j))
        self.last_index = j_now

    def _publish(self, stamp_ns: int) -> None:
        if self.epoch_ns is None:
            self.epoch_ns = stamp_ns
        pose = self.trajectory.at((stamp_ns - self.epoch_ns) / NS_PER_S)
        x, y, z = pose.position_m[0]
        qx, qy, qz, qw = pose.rotation.as_quat()[0]
        msg = PoseStamped()
        msg.header.stamp = ns_to_stamp(stamp_ns, type(msg.header.stamp))
        msg.header.frame_id = self.frame_id
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = float(x), float(y), float(z)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = float(qx), float(qy), float(qz), float(qw)
        self.pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    return run_node(TargetPosePlayer, args, (ConfigError, ValueError, ParameterException))


if __name__ == '__main__':
    sys.exit(main())
