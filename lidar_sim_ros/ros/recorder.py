"""A small rosbag2 recorder: rclpy raw subscriptions straight into a ``BagWriter``.

``rclpy`` hands raw subscriptions the CDR bytes as they came off the wire, which is
exactly what rosbag2 stores, so nothing is deserialised. The log time of each
message is its receipt time on the recording node's clock, as ``ros2 bag record``
does. Like ``ros2 bag record``, each topic is subscribed once its first publisher
is discovered, with QoS adapted to the publishers': reliable if they all are (so
nothing is lost), transient local if they all are (so latched messages arrive).
"""
from __future__ import annotations

import struct
from typing import Any, NamedTuple, Sequence

from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)

from lidar_sim_ros.io.bag import BagWriter

QUEUE_DEPTH = 50
DISCOVERY_PERIOD_S = 0.1


class TopicSpec(NamedTuple):
    """One recorded topic: name, rclpy message class, rosbag2 type name."""

    topic: str
    msg_class: Any
    msgtype: str
    stamped: bool = True
    """Whether the message starts with a std_msgs/Header (its stamp bounds the window)."""


NODE_TOPICS = (
    TopicSpec('/lidar/points', PointCloud2, 'sensor_msgs/msg/PointCloud2'),
    TopicSpec('/lidar/points_truth', PointCloud2, 'sensor_msgs/msg/PointCloud2'),
    TopicSpec('/target/pose', PoseStamped, 'geometry_msgs/msg/PoseStamped'),
    TopicSpec('/lidar/material_names', String, 'std_msgs/msg/String', stamped=False),
)
"""What the lidar_sim_node system publishes."""


def header_stamp_ns(cdr: bytes) -> int:
    """header.stamp (ns) of a serialised message that starts with a std_msgs/Header.

    CDR: a 4-byte encapsulation header (byte 1 is 1 for little endian), then the
    stamp's int32 sec and uint32 nanosec.
    """
    if len(cdr) < 12:
        raise ValueError(f'{len(cdr)} bytes are too few for a CDR message with a header')
    sec, nanosec = struct.unpack_from('<iI' if cdr[1] & 1 else '>iI', cdr, 4)
    return sec * 1_000_000_000 + nanosec


def adapted_qos(offered: Sequence[QoSProfile], depth: int = QUEUE_DEPTH) -> QoSProfile:
    """A subscription QoS that matches every offered publisher QoS and loses least."""
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def bag_qos(profile: QoSProfile) -> Qos:
    """An rclpy QoS profile as rosbag2 stores it in ``offered_qos_profiles``. The enums
    share rmw's numbering; a duration is (sec, nsec)."""
    def time(duration) -> QosTime:
        ns = duration.nanoseconds
        return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)

    return Qos(QosHistory(int(profile.history)), int(profile.depth),
               QosReliability(int(profile.reliability)), QosDurability(int(profile.durability)),
               time(profile.deadline), time(profile.lifespan), QosLiveliness(int(profile.liveliness)),
               time(profile.liveliness_lease_duration), bool(profile.avoid_ros_namespace_conventions))


class BagRecorder:
    """Record ``topics`` seen by ``node`` into an open ``writer``; ``counts`` per topic.

    The node must be spun (an executor) for discovery and recording to happen.
    With ``armed=False`` messages are only counted in ``seen`` (latched ones are
    written all the same: they come once) until ``arm()``: a caller can wait until
    every topic flows, so that the bag has no stretch where one is missing.
    ``arm(since_ns)`` also drops stamped messages older than ``since_ns``: a backlog
    that a late publisher or a lagging subscriber delivers after arming would
    otherwise start one topic earlier than the others.
    """

    def __init__(self, node: Node, writer: BagWriter, topics: Sequence[TopicSpec] = NODE_TOPICS,
                 armed: bool = True):
        self.node, self.writer = node, writer
        self.armed = armed
        self.since_ns: int | None = None
        self.counts: dict[str, int] = {spec.topic: 0 for spec in topics}
        self.seen: dict[str, int] = {spec.topic: 0 for spec in topics}
        self.qos: dict[str, QoSProfile] = {}
        self._pending = {spec.topic: spec for spec in topics}
        self._subs = []
        self._timer = node.create_timer(DISCOVERY_PERIOD_S, self._discover,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._discover()

    @property
    def subscribed(self) -> bool:
        """Whether every topic has a publisher and a subscription."""
        return not self._pending

    @property
    def flowing(self) -> bool:
        """Whether every topic is subscribed and has delivered at least one message."""
        return self.subscribed and all(self.seen.values())

    def arm(self, since_ns: int | None = None) -> None:
        """Start writing every topic's messages; with ``since_ns`` (header stamp, ns) only
        the stamped ones from that time on."""
        self.since_ns = since_ns
        self.armed = True

    def _discover(self) -> None:
        for topic, spec in list(self._pending.items()):
            offered = [info.qos_profile for info in self.node.get_publishers_info_by_topic(topic)]
            if not offered:
                continue
            qos = adapted_qos(offered)
            # As ros2 bag record does: the publishers' QoS goes into the bag, so that a
            # replay offers the same (a latched topic stays latched).
            self.writer.offer_qos(topic, [bag_qos(q) for q in offered])
            self._subs.append(self.node.create_subscription(
                spec.msg_class, topic, self._callback(spec), qos, raw=True))
            self.qos[topic] = qos
            del self._pending[topic]

    def _callback(self, spec: TopicSpec):
        def record(cdr: bytes) -> None:
            self.seen[spec.topic] += 1
            latched = self.qos[spec.topic].durability == DurabilityPolicy.TRANSIENT_LOCAL
            if not (self.armed or latched):
                return
            if (spec.stamped and not latched and self.since_ns is not None
                    and header_stamp_ns(cdr) < self.since_ns):
                return
            self.writer.write_raw(spec.topic, spec.msgtype,
                                  self.node.get_clock().now().nanoseconds, cdr)
            self.counts[spec.topic] += 1
        return record

    def close(self) -> None:
        """Stop recording (the writer stays open; close it separately)."""
        self.node.destroy_timer(self._timer)
        for sub in self._subs:
            self.node.destroy_subscription(sub)
        self._subs = []
