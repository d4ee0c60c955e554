"""rosbag2 reading and writing with `rosbags` (no ROS installation needed).

Bags are written as rosbag2 version 9 (what Jazzy writes) with the Jazzy typestore.
Every reader opens its input with ``open_bag``, which takes what recorders produce:
a rosbag2 directory (MCAP or sqlite3, with metadata.yaml), a bare ``.mcap`` file (as
Foxglove or ``ros2 bag record`` without its directory leave it), a bare ``.db3`` and a
ROS 1 ``.bag`` file, all through `rosbags.highlevel.AnyReader`; anything else is
refused with one line saying what was expected. ROS 1 messages come back with ROS 2
type names (``sensor_msgs/msg/PointCloud2``) and the same fields. Timestamps are
integer nanoseconds; the bag's log time of every message written here is its header
stamp.
"""
from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Iterator, Sequence

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Rosbag1ReaderError
from rosbags.interfaces import (Connection, Qos, QosDurability, QosHistory, QosLiveliness,
                                QosReliability, QosTime)
from rosbags.rosbag2 import ReaderError as Rosbag2ReaderError
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from lidar_sim_ros.io.pointcloud import from_pointcloud2, ns_to_stamp, stamp_to_ns, to_rosbags_msg

CLOUD_TOPIC = '/lidar/points'
POSE_TOPIC = '/target/pose'
MATERIAL_NAMES_TOPIC = '/lidar/material_names'
SUN_TOPIC = '/sun/direction'

POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
STRING = 'std_msgs/msg/String'
VECTOR3_STAMPED = 'geometry_msgs/msg/Vector3Stamped'

_STORAGE_PLUGINS = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
_BAG_VERSION = 9
_QUAT_NORM_TOL = 1e-5


# rmw's "infinite" duration as rosbag2 (Jazzy) writes it in offered_qos_profiles.
QOS_INFINITE = QosTime(9223372036, 854775807)
LATCHED_QOS = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
                  QOS_INFINITE, QOS_INFINITE, QosLiveliness.AUTOMATIC, QOS_INFINITE, False)
"""What the node offers on /lidar/material_names (depth 1, reliable, transient local):
recorded with the topic so that ``ros2 bag play`` republishes it latched."""


class BagContentError(ValueError):
    """A bag lacks an expected topic or holds an unexpected message type or content."""


class BagFormatError(ValueError):
    """A path that is not a bag of a supported kind, or a bag file that cannot be read."""


class _MissingTopicError(BagContentError):
    """The requested topic is not in the bag."""


@dataclass(frozen=True)
class CloudFrame:
    """One PointCloud2: header stamp [ns], frame id, points as decoded by from_pointcloud2."""

    stamp_ns: int
    frame_id: str
    points: np.ndarray


@dataclass(frozen=True)
class PoseSeries:
    """Stamped poses of one frame, sorted by header stamp.

    stamp_ns is int64 (N,), position_m float64 (N, 3), quat_xyzw float64 (N, 4).
    """

    stamp_ns: np.ndarray
    frame_id: str
    position_m: np.ndarray
    quat_xyzw: np.ndarray


@dataclass(frozen=True)
class VectorSeries:
    """Stamped 3-vectors of one frame (e.g. the sun direction), sorted by header stamp:
    stamp_ns int64 (N,), vector float64 (N, 3)."""

    stamp_ns: np.ndarray
    frame_id: str
    vector: np.ndarray


def encode_material_names(names: Sequence[str]) -> str:
    """Material names -> the JSON text published on /lidar/material_names."""
    names = list(names)
    if not all(isinstance(name, str) for name in names):
        raise ValueError(f'material names must be strings, got {names!r}')
    return json.dumps(names)


def decode_material_names(text: str, source: str = 'material names') -> list[str]:
    """JSON text from /lidar/material_names -> list of names; source names the origin."""
    try:
        names = json.loads(text)
    except json.JSONDecodeError as err:
        raise BagContentError(f'{source}: not valid JSON ({err}): {text[:80]!r}') from None
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise BagContentError(f'{source}: expected a JSON list of strings, got {text[:80]!r}')
    return names


class BagWriter:
    """Write a new rosbag2 directory; use as a context manager.

    Connections are created on the first message of each topic. On leaving the
    `with` block, even through an exception, the bag is closed with its metadata so
    that what was written stays readable.
    """

    def __init__(self, path: str | Path, storage: str = 'mcap') -> None:
        self.path = Path(path)
        if storage not in _STORAGE_PLUGINS:
            raise ValueError(f'storage must be one of {sorted(_STORAGE_PLUGINS)}, got {storage!r}')
        if self.path.exists():
            raise FileExistsError(f'bag directory {self.path} already exists; not overwriting it')
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self._writer = Writer(self.path, version=_BAG_VERSION,
                              storage_plugin=_STORAGE_PLUGINS[storage])
        self._connections: dict[str, Connection] = {}
        self._offered_qos: dict[str, list[Qos]] = {}
        self._is_open = False

    def offer_qos(self, topic: str, profiles: Sequence[Qos]) -> None:
        """The QoS profiles the topic's publishers offered, recorded in the bag's metadata
        (``offered_qos_profiles``) so that a replay publishes with them. Only before the
        topic's first message: the profiles are part of its connection."""
        if topic in self._connections:
            raise ValueError(f'topic {topic!r} already has messages in bag {self.path}; '
                             'offer its QoS before the first one')
        self._offered_qos[topic] = list(profiles)

    def open(self) -> None:
        """Create the bag directory and storage file."""
        self._writer.open()
        self._is_open = True

    def close(self) -> None:
        """Write the index and metadata.yaml; idempotent."""
        if self._is_open:
            self._is_open = False
            self._writer.close()

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def write_cloud(self, topic: str, points: np.ndarray, stamp_ns: int, frame_id: str) -> None:
        """Write a POINT_DTYPE array as sensor_msgs/msg/PointCloud2."""
        msg = to_rosbags_msg(points, stamp_ns, frame_id, self.typestore)
        self._write_msg(topic, POINTCLOUD2, stamp_ns, msg)

    def write_pose(self, topic: str, stamp_ns: int, frame_id: str,
                   position_xyz_m: Sequence[float] | np.ndarray,
                   quat_xyzw: Sequence[float] | np.ndarray) -> None:
        """Write geometry_msgs/msg/PoseStamped: position [m] and unit quaternion (x, y, z, w)."""
        position = np.asarray(position_xyz_m, dtype=float)
        quat = np.asarray(quat_xyzw, dtype=float)
        if position.shape != (3,) or not np.isfinite(position).all():
            raise ValueError(f'position_xyz_m must be 3 finite numbers, got {position_xyz_m!r}')
        if quat.shape != (4,) or abs(np.linalg.norm(quat) - 1.0) > _QUAT_NORM_TOL:
            raise ValueError(
                f'quat_xyzw must be a unit quaternion (x, y, z, w), got {quat_xyzw!r}')
        types = self.typestore.types
        msg = types[POSE_STAMPED](
            header=self._header(stamp_ns, frame_id),
            pose=types['geometry_msgs/msg/Pose'](
                position=types['geometry_msgs/msg/Point'](
                    x=float(position[0]), y=float(position[1]), z=float(position[2])),
                orientation=types['geometry_msgs/msg/Quaternion'](
                    x=float(quat[0]), y=float(quat[1]), z=float(quat[2]), w=float(quat[3])),
            ),
        )
        self._write_msg(topic, POSE_STAMPED, stamp_ns, msg)

    def write_vector3(self, topic: str, stamp_ns: int, frame_id: str,
                      vector: Sequence[float] | np.ndarray) -> None:
        """Write geometry_msgs/msg/Vector3Stamped (e.g. the sun direction, lidar frame)."""
        v = np.asarray(vector, dtype=float)
        if v.shape != (3,) or not np.isfinite(v).all():
            raise ValueError(f'vector must be 3 finite numbers, got {vector!r}')
        types = self.typestore.types
        msg = types[VECTOR3_STAMPED](header=self._header(stamp_ns, frame_id),
                                     vector=types['geometry_msgs/msg/Vector3'](
                                         x=float(v[0]), y=float(v[1]), z=float(v[2])))
        self._write_msg(topic, VECTOR3_STAMPED, stamp_ns, msg)

    def write_string(self, topic: str, stamp_ns: int, text: str) -> None:
        """Write std_msgs/msg/String."""
        self._write_msg(topic, STRING, stamp_ns, self.typestore.types[STRING](data=text))

    def write_material_names(self, topic: str, stamp_ns: int, names: Sequence[str]) -> None:
        """Write the material names list as JSON in a std_msgs/msg/String, on a topic
        recorded as latched (``LATCHED_QOS``) unless other QoS was offered for it."""
        if topic not in self._connections:
            self._offered_qos.setdefault(topic, [LATCHED_QOS])
        self.write_string(topic, stamp_ns, encode_material_names(names))

    def write_raw(self, topic: str, msgtype: str, stamp_ns: int, cdr_bytes: bytes) -> None:
        """Write an already CDR-serialised message of a type known to the Jazzy typestore."""
        self._writer.write(self._connection(topic, msgtype), int(stamp_ns), cdr_bytes)

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        types = self.typestore.types
        return types['std_msgs/msg/Header'](
            stamp=ns_to_stamp(stamp_ns, types['builtin_interfaces/msg/Time']), frame_id=frame_id)

    def _write_msg(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        cdr = self.typestore.serialize_cdr(msg, msgtype)
        self.write_raw(topic, msgtype, stamp_ns, cdr)

    def _connection(self, topic: str, msgtype: str) -> Connection:
        """The topic's connection, created on first use; one message type per topic."""
        if not self._is_open:
            raise RuntimeError(f'bag {self.path} is not open; use BagWriter in a with block')
        connection = self._connections.get(topic)
        if connection is None:
            if msgtype not in self.typestore.types:
                raise ValueError(f'message type {msgtype!r} for topic {topic!r} is not in '
                                 'the ROS 2 Jazzy typestore')
            connection = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore,
                offered_qos_profiles=self._offered_qos.get(topic, ()))
            self._connections[topic] = connection
        elif connection.msgtype != msgtype:
            raise ValueError(f'topic {topic!r} in bag {self.path} already carries '
                             f'{connection.msgtype}, cannot write {msgtype}')
        return connection


def read_clouds(path: str | Path, topic: str = CLOUD_TOPIC) -> list[CloudFrame]:
    """All PointCloud2 messages of a topic, in bag order, decoded with from_pointcloud2."""
    return [_cloud_frame(msg, path, topic, k)
            for k, msg in enumerate(_read_messages(path, topic, POINTCLOUD2))]


def _cloud_frame(msg: Any, path: str | Path, topic: str, k: int) -> CloudFrame:
    """One decoded cloud; a layout the decoder refuses is named with bag, topic and index."""
    try:
        points = from_pointcloud2(msg)
    except ValueError as exc:
        raise BagContentError(f'bag {path}: cloud #{k} on {topic!r}: {exc}') from None
    return CloudFrame(stamp_to_ns(msg.header.stamp), msg.header.frame_id, points)


def cloud_count(path: str | Path, topic: str = CLOUD_TOPIC) -> int:
    """Number of PointCloud2 messages on ``topic`` (from the bag's index, nothing decoded)."""
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        return sum(c.msgcount for c in reader.connections if c.topic == topic)


def iter_clouds(path: str | Path, topic: str = CLOUD_TOPIC):
    """The PointCloud2 messages of a topic one at a time, in bag order (long recordings
    need not fit in memory); same checks and decoding as ``read_clouds``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f'bag {path} does not exist')
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            _read_messages(path, topic, POINTCLOUD2)      # raises, naming the topics
        for k, (c, _, raw) in enumerate(reader.messages(connections=connections)):
            if c.msgtype != POINTCLOUD2:
                raise BagContentError(f'topic {topic!r} in bag {path} has type {c.msgtype}, '
                                      f'expected {POINTCLOUD2}')
            yield _cloud_frame(reader.deserialize(raw, c.msgtype), path, topic, k)


def read_poses(path: str | Path, topic: str = POSE_TOPIC) -> PoseSeries:
    """All PoseStamped messages of a topic as arrays sorted by header stamp.

    Raises BagContentError if the messages do not share one frame_id.
    """
    msgs = _read_messages(path, topic, POSE_STAMPED)
    frames = sorted({msg.header.frame_id for msg in msgs})
    if len(frames) > 1:
        raise BagContentError(f'poses on {topic!r} in bag {path} use several frames: {frames}')
    stamp_ns = np.array([stamp_to_ns(msg.header.stamp) for msg in msgs], dtype=np.int64)
    position_m = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z]
                           for m in msgs], dtype=np.float64).reshape(-1, 3)
    quat_xyzw = np.array([[m.pose.orientation.x, m.pose.orientation.y,
                           m.pose.orientation.z, m.pose.orientation.w]
                          for m in msgs], dtype=np.float64).reshape(-1, 4)
    order = np.argsort(stamp_ns, kind='stable')
    return PoseSeries(stamp_ns[order], frames[0] if frames else '',
                      position_m[order], quat_xyzw[order])


def read_material_names(path: str | Path, topic: str = MATERIAL_NAMES_TOPIC) -> list[str] | None:
    """The material names list (JSON String, last message wins), or None if the topic is absent."""
    try:
        msgs = _read_messages(path, topic, STRING)
    except _MissingTopicError:
        return None
    if not msgs:
        return None
    return decode_material_names(msgs[-1].data, f'{topic!r} in bag {path}')


def read_vectors(path: str | Path, topic: str = SUN_TOPIC) -> VectorSeries | None:
    """All Vector3Stamped messages of a topic sorted by stamp, or None if the topic is absent."""
    try:
        msgs = _read_messages(path, topic, VECTOR3_STAMPED)
    except _MissingTopicError:
        return None
    frames = sorted({m.header.frame_id for m in msgs})
    if len(frames) > 1:
        raise BagContentError(f'vectors on {topic!r} in bag {path} use several frames: {frames}')
    stamp_ns = np.array([stamp_to_ns(m.header.stamp) for m in msgs], dtype=np.int64)
    vector = np.array([[m.vector.x, m.vector.y, m.vector.z] for m in msgs], dtype=float).reshape(-1, 3)
    order = np.argsort(stamp_ns, kind='stable')
    return VectorSeries(stamp_ns[order], frames[0] if frames else '', vector[order])


def _read_messages(path: str | Path, topic: str, msgtype: str) -> list[Any]:
    """Deserialised messages of one topic, checking that it exists with the expected type."""
    path = Path(path)
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            available = ', '.join(f'{name} ({info.msgtype})'
                                  for name, info in sorted(reader.topics.items())) or 'none'
            raise _MissingTopicError(
                f'bag {path} has no topic {topic!r}; topics in the bag: {available}')
        found = sorted({c.msgtype for c in connections if c.msgtype != msgtype})
        if found:
            raise BagContentError(
                f'topic {topic!r} in bag {path} has type {", ".join(found)}, expected {msgtype}')
        return [reader.deserialize(raw, c.msgtype)
                for c, _, raw in reader.messages(connections=connections)]


# ------------------------------------------------------------------ naming
_GENERIC_BAG_NAMES = {'bag', 'bags', 'rosbag', 'rosbag2', 'recording', 'data'}


def recording_name(path: str | Path) -> str:
    """A recording's name for titles: ``measured`` for ``measured/bag`` (``make demo`` and
    ``lidar-sim simulate`` call every bag ``bag``), the stem of a bare file
    (``flight_03`` for ``flight_03.mcap``), otherwise the folder's own name."""
    path = Path(path)
    if path.suffix in _FILE_KINDS:
        return path.stem
    resolved = path.resolve()
    if resolved.name.lower() in _GENERIC_BAG_NAMES and resolved.parent.name:
        return resolved.parent.name
    return resolved.name or str(path)


# ------------------------------------------------------------------ opening
BAG_KINDS = ('a rosbag2 directory (with metadata.yaml), a bare .mcap file (e.g. from Foxglove) '
             'or a ROS 1 .bag file')
_FILE_KINDS = {'.mcap': 'MCAP file', '.db3': 'rosbag2 sqlite3 file', '.bag': 'ROS 1 bag'}


def bag_kind(path: str | Path) -> str:
    """What ``path`` holds: 'rosbag2 directory', 'MCAP file', 'rosbag2 sqlite3 file' or
    'ROS 1 bag'; FileNotFoundError or BagFormatError (one line) for anything else."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f'bag {path} does not exist')
    if path.is_dir():
        if (path / 'metadata.yaml').is_file():
            return 'rosbag2 directory'
        inside = sorted(p.name for p in path.iterdir() if p.suffix in _FILE_KINDS)
        hint = f'; it holds {", ".join(inside)}: give that file instead' if inside else ''
        bags = sorted(str(p) for p in path.iterdir() if (p / 'metadata.yaml').is_file())
        if bags and not inside:  # e.g. `make demo`'s demo-output/ holding demo-output/bag
            hint = f'; it holds the bag {" and ".join(bags[:3])}: give that instead'

        raise BagFormatError(f'{path} is a directory without metadata.yaml, so not a rosbag2 bag '
                             f'(expected {BAG_KINDS}){hint}')
    kind = _FILE_KINDS.get(path.suffix)
    if kind is None:
        raise BagFormatError(f'{path} is not a bag: expected {BAG_KINDS}, got '
                             f'{"a " + path.suffix + " file" if path.suffix else "a file without extension"}')
    return kind


@contextmanager
def open_bag(path: str | Path) -> Iterator[AnyReader]:
    """An open ``AnyReader`` over one bag of any supported kind (see ``bag_kind``).

    Messages without embedded definitions are decoded with the ROS 2 Jazzy types.
    A damaged or unreadable file raises BagFormatError naming it.
    """
    path = Path(path)
    kind = bag_kind(path)
    # rosbags picks the rosbag1 reader by the exact suffix '.bag'.
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
    try:
        reader.open()
    except (AnyReaderError, Rosbag1ReaderError, Rosbag2ReaderError, OSError, ValueError, KeyError) as exc:
        text = ' '.join(str(exc).split()) or type(exc).__name__
        raise BagFormatError(f'{path}: cannot read this {kind}: {text}') from None
    try:
        yield reader
    finally:
        reader.close()
