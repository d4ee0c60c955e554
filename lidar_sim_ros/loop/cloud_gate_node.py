"""``loop_cloud_gate``: the GNC's range gate between the lidar and the tracker.

Republishes each cloud (``input_topic`` -> ``output_topic``, PointCloud2, same stamp and
frame) without the points farther than ``gate_m`` from the target centre of the
estimate of the period before the cloud's (``/target/pose_estimate``: the GNC's own
output, never the truth; matched by stamp, ``EstimateBook``); without one (before the
first estimate, after a loss), without the points farther than ``capture_gate_m`` from
the cloud's median (``step.capture_centre``: what the acquisition needs, docs/loop.md).
A cloud that cannot be read (truncated, point_step 0, no float x, y, z) and an estimate
that is not finite or farther than 10 km are dropped, counted, with a warning. Far returns (solar background: up to the end of
the range gate) cost the tracker's nearest-neighbour search about 15 times what the
target's points cost (0.74 s against 0.05 s a frame, measured in the loop at 30 m):
the in-process loop gates the same way (``step.tracker_cloud``).
"""
from __future__ import annotations

import sys
import time
from functools import partial

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from lidar_sim_ros.io.pointcloud import from_pointcloud2, stamp_to_ns
from lidar_sim_ros.ros.parameters import declare_startup
from lidar_sim_ros.ros.pose_input import DropCounter
from lidar_sim_ros.ros.spin import run_node

NODE_NAME = 'loop_cloud_gate'
MAX_ESTIMATE_RANGE_M = 10_000.0
ESTIMATES_KEPT = 50


class EstimateBook:
    """The last estimates' centres by stamp (ns), and which one gates a cloud.

    A cloud whose frame starts at t_k is gated about the estimate of the period before,
    stamped in [t_k - period, t_k): the one the in-process loop uses (``step.tracker_cloud``),
    whatever order the topics arrive in, never a later or an older one. Without it (no
    estimate yet, or the track was lost in that period) the cloud is re-captured: the
    capture gate about its median, never the stale estimate."""

    def __init__(self, period_ns: int):
        self.period_ns = int(period_ns)
        self.centres: dict[int, np.ndarray] = {}
        self.lost: set[int] = set()

    def add(self, stamp_ns: int, position_m) -> str | None:
        """Keep an estimate's centre (m, lidar frame); the cause it is dropped for, or None."""
        p = np.asarray(position_m, float)
        if not np.isfinite(p).all():
            return 'non_finite'
        if np.abs(p).max() > MAX_ESTIMATE_RANGE_M or float(np.linalg.norm(p)) > MAX_ESTIMATE_RANGE_M:
            return 'range'
        self.centres[int(stamp_ns)] = p
        while len(self.centres) > ESTIMATES_KEPT:
            del self.centres[min(self.centres)]
        return None

    def add_lost(self, stamp_ns: int) -> None:
        """A period whose cloud gave no estimate (the tracker's lost notice): answered, no centre."""
        self.lost.add(int(stamp_ns))
        while len(self.lost) > ESTIMATES_KEPT:
            self.lost.discard(min(self.lost))

    def answered(self, cloud_stamp_ns: int) -> bool:
        """Whether the period before the cloud's has its answer: an estimate or a lost notice."""
        lo = cloud_stamp_ns - self.period_ns
        return any(lo <= s < cloud_stamp_ns for s in (*self.centres, *self.lost))

    def centre_for(self, cloud_stamp_ns: int) -> np.ndarray | None:
        """The centre of the estimate stamped in [cloud - period, cloud), the latest if several."""
        got = [s for s in self.centres if cloud_stamp_ns - self.period_ns <= s < cloud_stamp_ns]
        return self.centres[max(got)] if got else None


def gated_bytes(msg: PointCloud2, centre_m: np.ndarray | None, gate_m: float,
                capture_gate_m: float) -> tuple[bytes, int]:
    """(the kept points' bytes as they came, every field, the row padding dropped; how many);
    ValueError for a cloud that cannot be read (a truncated buffer, point_step 0, no float x, y, z)."""
    if int(msg.point_step) <= 0:
        raise ValueError(f'point_step {msg.point_step} must be positive')
    points = from_pointcloud2(msg)     # checks the sizes against the buffer
    names = points.dtype.names or ()
    if not all(f in names and points.dtype[f].kind == 'f' for f in 'xyz'):
        raise ValueError(f'x, y, z must be FLOAT32 or FLOAT64 fields, got {list(names)}')
    xyz = np.column_stack([points['x'], points['y'], points['z']]).astype(float)
    keep = gate_mask(xyz, centre_m, gate_m, capture_gate_m)
    if keep is None:
        keep = np.ones(len(xyz), bool)
    step, width = int(msg.point_step), int(msg.width)
    data = np.frombuffer(memoryview(msg.data), np.uint8).reshape(int(msg.height), int(msg.row_step))
    rows = np.ascontiguousarray(data[:, :width * step]).reshape(-1, step)
    return rows[keep].tobytes(), int(keep.sum())


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
    with np.errstate(over='ignore', invalid='ignore'):
        return np.einsum('ij,ij->i', d, d) <= gate_m ** 2


class CloudGateNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)

    def setup(self) -> None:
        p = partial(declare_startup, self)
        input_topic = p('input_topic', '/lidar/points', 'PointCloud2 in')
        output_topic = p('output_topic', '/loop/points_gated', 'PointCloud2 out')
        estimate_topic = p('estimate_topic', '/target/pose_estimate', 'PoseStamped: the gate centre')
        lost_topic = p('lost_topic', '/target/pose_lost', (
            "std_msgs/Header: the tracker's notice of a period without an estimate; with it a cloud "
            "waits (up to answer_wait_s) for the period before's answer, so that the gate never "
            "depends on which topic came first; '' = none (gate on what has come)"))
        self.answer_wait_s = float(p('answer_wait_s', 1.0, (
            "wall s a cloud waits for the period before's estimate or lost notice (then it is "
            're-captured, logged)')))
        self.gate_m = float(p('gate_m', 8.0, 'keep points within this of the estimated centre (m)'))
        self.capture_gate_m = float(p('capture_gate_m', 12.0, 'before the first estimate: keep points '
                                      "within this of the cloud's median (m; 0 = all)"))
        period_s = float(p('period_s', 0.1, "the loop's control period (s): a cloud is gated about the "
                                           'estimate of the period before its own'))
        if not (np.isfinite(self.gate_m) and self.gate_m >= 0 and np.isfinite(self.capture_gate_m)
                and self.capture_gate_m >= 0 and np.isfinite(period_s) and period_s > 0):
            raise ValueError(f'gate_m {self.gate_m}, capture_gate_m {self.capture_gate_m} must be >= 0 and '
                             f'period_s {period_s} > 0')
        self.book = EstimateBook(round(period_s * 1e9))
        self._drops = DropCounter(('cloud', 'non_finite', 'range'))
        self.dropped = self._drops.counts
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(PointCloud2, output_topic, qos)
        # The estimates' subscription first: an executor serves ready subscriptions in the order
        # they were made, so an estimate and the next cloud waiting together go estimate first.
        self.create_subscription(PoseStamped, estimate_topic, self._on_estimate, QoSProfile(depth=10))
        self.wait_for_answers = bool(lost_topic)
        if lost_topic:
            from std_msgs.msg import Header
            self.create_subscription(Header, lost_topic, self._on_lost, QoSProfile(depth=10))
        self.create_subscription(PointCloud2, input_topic, self._on_cloud, qos)
        self.held: list[tuple[PointCloud2, float]] = []   # clouds waiting for the period before's answer
        self.seen_cloud_ns: int | None = None             # the first cloud's stamp: it has no period before
        self.counts = {'gated': 0, 'captured': 0, 'unanswered': 0}
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(0.01, self._release, clock=steady)
        self.create_timer(10.0, self._log_stats, clock=steady)
        self.get_logger().info(f'{input_topic} -> {output_topic}: points within {self.gate_m:g} m '
                               f'of the last estimate on {estimate_topic}')

    def _drop(self, cause: str, text: str) -> None:
        self._drops.drop(cause, text, self.get_logger().warn)

    def _on_estimate(self, msg: PoseStamped) -> None:
        p = msg.pose.position
        cause = self.book.add(stamp_to_ns(msg.header.stamp), [p.x, p.y, p.z])
        if cause is not None:
            self._drop(cause, f'estimate stamped {stamp_to_ns(msg.header.stamp) / 1e9:.6f} s dropped: '
                              f'position {[p.x, p.y, p.z]} m ({cause})')
        self._release()

    def _log_stats(self) -> None:
        c = self.counts
        self.get_logger().info(f"clouds gated about the period before's estimate {c['gated']}, re-captured "
                               f"{c['captured']} (of them without an answer in time {c['unanswered']}), "
                               f'dropped {self.dropped}')

    def _on_lost(self, msg) -> None:
        self.book.add_lost(stamp_to_ns(msg.stamp))
        self._release()

    def _on_cloud(self, msg: PointCloud2) -> None:
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if self.seen_cloud_ns is None:
            self.seen_cloud_ns = stamp_ns
        if self.wait_for_answers and stamp_ns > self.seen_cloud_ns and not self.book.answered(stamp_ns):
            self.held.append((msg, time.monotonic()))
            return
        self._pass(msg)

    def _release(self) -> None:
        """Pass on the held clouds whose answer came, or that waited answer_wait_s (in order)."""
        while self.held:
            msg, since = self.held[0]
            if not self.book.answered(stamp_to_ns(msg.header.stamp)):
                if time.monotonic() - since < self.answer_wait_s and len(self.held) < 5:
                    return
                self.counts['unanswered'] += 1
                self.get_logger().warn(f'cloud stamped {stamp_to_ns(msg.header.stamp) / 1e9:.6f} s: no estimate '
                                       f'or lost notice of the period before within {self.answer_wait_s:g} s: '
                                       're-captured about its median')
            self.held.pop(0)
            self._pass(msg)

    def _pass(self, msg: PointCloud2) -> None:
        out = self.gated(msg)
        if out is not None:
            self.pub.publish(out)

    def gated(self, msg: PointCloud2) -> PointCloud2 | None:
        """The cloud to pass on, or None when it is dropped (counted, logged)."""
        stamp_ns = stamp_to_ns(msg.header.stamp)
        centre = self.book.centre_for(stamp_ns)
        self.counts['gated' if centre is not None else 'captured'] += 1
        try:
            data, n = gated_bytes(msg, centre, self.gate_m, self.capture_gate_m)
        except (ValueError, TypeError) as exc:
            self._drop('cloud', f'cloud stamped {stamp_ns / 1e9:.6f} s dropped: {exc}')
            return None
        out = PointCloud2(header=msg.header, height=1, width=n, fields=msg.fields,
                          is_bigendian=msg.is_bigendian, point_step=msg.point_step,
                          row_step=msg.point_step * n, is_dense=msg.is_dense)
        out.data = data
        return out


def main(args: list[str] | None = None) -> int:
    return run_node(CloudGateNode, args if args is not None else sys.argv, (ValueError,))


if __name__ == '__main__':
    sys.exit(main())
