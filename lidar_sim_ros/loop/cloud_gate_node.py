"""``loop_cloud_gate``: the GNC's range gate between the lidar and the tracker.

Republishes each cloud (``input_topic`` -> ``output_topic``, PointCloud2, same stamp and
frame) without the points farther than ``gate_m`` from the target centre of the last
pose estimate (``/target/pose_estimate``: the GNC's own output, never the truth); until
the first estimate, without the points farther than ``capture_gate_m`` from the cloud's
median (``step.capture_centre``: what the acquisition needs, docs/loop.md). Far returns (solar background: up to the end of
the range gate) cost the tracker's nearest-neighbour search about 15 times what the
target's points cost (0.74 s against 0.05 s a frame, measured in the loop at 30 m):
the in-process loop gates the same way (``step.tracker_cloud``).
"""
from __future__ import annotations

import sys
from functools import partial

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from lidar_sim_ros.io.pointcloud import from_pointcloud2
from lidar_sim_ros.ros.parameters import declare_startup
from lidar_sim_ros.ros.spin import run_node

NODE_NAME = 'loop_cloud_gate'


def gate_mask(xyz_m: np.ndarray, centre_m: np.ndarray | None, gate_m: float,
              capture_gate_m: float) -> np.ndarray | None:
    """Which points (N, 3, m) go on to the tracker: within ``gate_m`` of the estimated
    centre, or without one within ``capture_gate_m`` of the cloud's median; None: all
    (no centre and no capture gate)."""
    from lidar_sim_ros.loop.step import capture_centre  # here: the node's imports stay light
    if centre_m is None:
        if capture_gate_m <= 0 or not len(xyz_m):
            return None
        centre_m, gate_m = capture_centre(xyz_m), capture_gate_m
    d = xyz_m - centre_m
    return np.einsum('ij,ij->i', d, d) <= gate_m ** 2


class CloudGateNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)

    def setup(self) -> None:
        p = partial(declare_startup, self)
        input_topic = p('input_topic', '/lidar/points', 'PointCloud2 in')
        output_topic = p('output_topic', '/loop/points_gated', 'PointCloud2 out')
        estimate_topic = p('estimate_topic', '/target/pose_estimate', 'PoseStamped: the gate centre')
        self.gate_m = float(p('gate_m', 8.0, 'keep points within this of the estimated centre (m)'))
        self.capture_gate_m = float(p('capture_gate_m', 12.0, 'before the first estimate: keep points '
                                      "within this of the cloud's median (m; 0 = all)"))
        self.centre: np.ndarray | None = None
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(PointCloud2, output_topic, qos)
        self.create_subscription(PointCloud2, input_topic, self._on_cloud, qos)
        self.create_subscription(PoseStamped, estimate_topic, self._on_estimate, QoSProfile(depth=10))
        self.get_logger().info(f'{input_topic} -> {output_topic}: points within {self.gate_m:g} m '
                               f'of the last estimate on {estimate_topic}')

    def _on_estimate(self, msg: PoseStamped) -> None:
        p = msg.pose.position
        self.centre = np.array([p.x, p.y, p.z])

    def _on_cloud(self, msg: PointCloud2) -> None:
        if (self.centre is None and self.capture_gate_m <= 0) or msg.width * msg.height == 0:
            self.pub.publish(msg)
            return
        points = from_pointcloud2(msg)
        xyz = np.column_stack([points['x'], points['y'], points['z']]).astype(float)
        keep = gate_mask(xyz, self.centre, self.gate_m, self.capture_gate_m)
        # The kept points' bytes as they came: every field, whatever the layout.
        rows = np.frombuffer(memoryview(msg.data), np.uint8).reshape(-1, msg.point_step)[keep]
        out = PointCloud2(header=msg.header, height=1, width=int(keep.sum()), fields=msg.fields,
                          is_bigendian=msg.is_bigendian, point_step=msg.point_step,
                          row_step=msg.point_step * int(keep.sum()), is_dense=msg.is_dense)
        out.data = rows.tobytes()
        self.pub.publish(out)


def main(args: list[str] | None = None) -> int:
    return run_node(CloudGateNode, args if args is not None else sys.argv, (ValueError,))


if __name__ == '__main__':
    sys.exit(main())
