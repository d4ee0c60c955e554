"""Tests for lidar_sim_ros/io/pointcloud.py: our layout, both builders, the generic decoder."""
import array
import struct
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Time as RclpyTime
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import PointCloud2 as RclpyPointCloud2

from lidar_sim_ros.io.pointcloud import (
    DATATYPE_TO_NUMPY, POINT_DTYPE, POINT_FIELDS, from_pointcloud2, make_points,
    ns_to_stamp, stamp_to_ns, to_rclpy_msg, to_rosbags_msg,
)

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
STAMP_NS = 1_700_000_000_123_456_789
FRAME = 'lidar_link'


@pytest.fixture
def points() -> np.ndarray:
    rng = np.random.default_rng(42)
    n = 1000
    return make_points(
        rng.normal(scale=20.0, size=(n, 3)),
        rng.random(n) * 1e3,
        np.linspace(0.0, 0.099, n),
        rng.integers(0, 65536, n),
        rng.integers(0, 256, n),
    )


def assert_same_points(decoded: np.ndarray, expected: np.ndarray) -> None:
    assert decoded.dtype.names == expected.dtype.names
    assert decoded.shape == expected.shape
    for name in expected.dtype.names:
        assert decoded.dtype[name] == expected.dtype[name].newbyteorder('=')
        np.testing.assert_array_equal(decoded[name], expected[name], err_msg=name)


def test_point_fields_match_point_dtype() -> None:
    assert POINT_DTYPE.itemsize == 24
    assert POINT_DTYPE.isalignedstruct
    assert [tuple(f) for f in POINT_FIELDS] == [
        ('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1), ('intensity', 12, 7, 1),
        ('t', 16, 7, 1), ('ring', 20, 4, 1), ('material', 22, 2, 1), ('return', 23, 2, 1),
    ]
    assert POINT_DTYPE.names == tuple(f.name for f in POINT_FIELDS)
    for field in POINT_FIELDS:
        dtype, offset = POINT_DTYPE.fields[field.name][:2]
        assert offset == field.offset
        assert dtype == np.dtype('<' + DATATYPE_TO_NUMPY[field.datatype])


def test_make_points_packs_columns(points: np.ndarray) -> None:
    xyz = np.array([[1.0, -2.0, 3.5], [0.25, 0.0, -7.0]])
    p = make_points(xyz, [10.0, 20.0], 0.05, [3, 7], 2)
    np.testing.assert_array_equal(np.stack([p['x'], p['y'], p['z']], axis=1), xyz)
    np.testing.assert_array_equal(p['intensity'], [10.0, 20.0])
    np.testing.assert_array_equal(p['t'], np.float32([0.05, 0.05]))
    np.testing.assert_array_equal(p['ring'], [3, 7])
    np.testing.assert_array_equal(p['material'], [2, 2])
    empty = make_points(np.empty((0, 3)), [], [], np.array([], int), np.array([], int))
    assert empty.shape == (0,)


@pytest.mark.parametrize('kwargs, match', [
    (dict(xyz_m=np.zeros((3, 2))), r'shape \(N, 3\)'),
    (dict(intensity=np.zeros(4)), r'intensity .*\(3,\)'),
    (dict(ring=[0, 1, 70000]), r'ring .*\[0, 65535\]'),
    (dict(material=[-1, 0, 0]), r'material .*\[0, 255\]'),
    (dict(material=[0.5, 0, 0]), r'material must be integers'),
    (dict(xyz_m=np.array([[0, 0, 0], [np.nan, 0, 0], [0, 0, 0]])), r'finite.*row 1'),
])
def test_make_points_rejects_bad_input(kwargs: dict, match: str) -> None:
    args = dict(xyz_m=np.zeros((3, 3)), intensity=np.zeros(3), t_s=np.zeros(3),
                ring=np.zeros(3, int), material=np.zeros(3, int))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        make_points(**args)


def test_builders_reject_other_dtypes() -> None:
    with pytest.raises(ValueError, match='POINT_DTYPE'):
        to_rosbags_msg(np.zeros((4, 3), np.float32), 0, FRAME, TYPESTORE)
    with pytest.raises(ValueError, match='POINT_DTYPE'):
        to_rclpy_msg(np.zeros(4, [('x', '<f4')]), 0, FRAME)


def test_stamp_conversion_both_implementations() -> None:
    for cls in (RclpyTime, TYPESTORE.types['builtin_interfaces/msg/Time']):
        stamp = ns_to_stamp(STAMP_NS, cls)
        assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789)
        assert stamp_to_ns(stamp) == STAMP_NS
        assert stamp_to_ns(ns_to_stamp(999, cls)) == 999


def cdr_value_mask(cdr: bytes) -> np.ndarray:
    """True where a little-endian PointCloud2 CDR byte holds a value, False for padding.

    rclpy (Fast CDR) leaves alignment padding uninitialised, so only value bytes can
    be compared between implementations.
    """
    mask = np.zeros(len(cdr), dtype=bool)
    mask[:4] = True  # encapsulation header; alignment counts from its end
    pos = 4

    def take(size: int, align: int) -> bytes:
        nonlocal pos
        pos += -(pos - 4) % align
        mask[pos:pos + size] = True
        pos += size
        return cdr[pos - size:pos]

    def u32() -> int:
        return struct.unpack('<I', take(4, 4))[0]

    u32(), u32(), take(u32(), 1)          # header: sec, nanosec, frame_id
    u32(), u32()                          # height, width
    for _ in range(u32()):                # fields: name, offset, datatype, count
        take(u32(), 1), u32(), take(1, 1), u32()
    take(1, 1), u32(), u32()              # is_bigendian, point_step, row_step
    take(u32(), 1), take(1, 1)            # data, is_dense
    assert len(cdr) - pos < 4, 'unexpected trailing bytes'
    return mask


@pytest.mark.parametrize('n', [1000, 0])
def test_rosbags_and_rclpy_cdr_identical_and_cross_decodable(points: np.ndarray, n: int) -> None:
    points = points[:n]
    rosbags_cdr = bytes(TYPESTORE.serialize_cdr(
        to_rosbags_msg(points, STAMP_NS, FRAME, TYPESTORE), 'sensor_msgs/msg/PointCloud2'))
    rclpy_cdr = serialize_message(to_rclpy_msg(points, STAMP_NS, FRAME))
    assert len(rosbags_cdr) == len(rclpy_cdr)
    values = cdr_value_mask(rosbags_cdr)
    np.testing.assert_array_equal(values, cdr_value_mask(rclpy_cdr))
    rosbags_u8, rclpy_u8 = np.frombuffer(rosbags_cdr, np.uint8), np.frombuffer(rclpy_cdr, np.uint8)
    np.testing.assert_array_equal(rosbags_u8[values], rclpy_u8[values])
    assert not rosbags_u8[~values].any(), 'rosbags writes zero padding'
    assert rosbags_cdr[-24 * n - 1:-1] == points.tobytes()

    from_rclpy = TYPESTORE.deserialize_cdr(rclpy_cdr, 'sensor_msgs/msg/PointCloud2')
    from_rosbags = deserialize_message(rosbags_cdr, RclpyPointCloud2)
    for msg in (from_rclpy, from_rosbags):
        assert stamp_to_ns(msg.header.stamp) == STAMP_NS
        assert msg.header.frame_id == FRAME
        assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, n, 24, 24 * n)
        assert not msg.is_bigendian and msg.is_dense
        assert_same_points(from_pointcloud2(msg), points)


def test_from_pointcloud2_accepts_any_data_container(points: np.ndarray) -> None:
    msg = to_rosbags_msg(points, STAMP_NS, FRAME, TYPESTORE)
    raw = points.tobytes()
    for data in (raw, bytearray(raw), memoryview(raw), array.array('B', raw), list(raw[:240])):
        width = len(data) // 24
        cloud = SimpleNamespace(fields=msg.fields, height=1, width=width, point_step=24,
                                row_step=24 * width, is_bigendian=False, data=data)
        assert_same_points(from_pointcloud2(cloud), points[:width])


def field(name: str, offset: int, datatype: int, count: int = 1) -> SimpleNamespace:
    return SimpleNamespace(name=name, offset=offset, datatype=datatype, count=count)


def cloud(fields: list, rows: list[bytes], width: int, point_step: int, row_step: int,
          big_endian: bool = False) -> SimpleNamespace:
    """A duck-typed PointCloud2 from hand-packed rows (struct, not numpy)."""
    return SimpleNamespace(fields=fields, height=len(rows), width=width, point_step=point_step,
                           row_step=row_step, is_bigendian=big_endian, data=b''.join(rows),
                           is_dense=True)


# A foreign 40-byte layout: fields listed out of offset order, a float64, an int16
# triple, a uint32 and padding that no field covers.
FOREIGN_FIELDS = [
    field('range', 24, 8), field('z', 8, 7), field('x', 0, 7), field('y', 4, 7),
    field('label', 16, 3, count=3), field('reflectivity', 12, 6), field('flag', 32, 1),
]
FOREIGN_FORMAT = 'fffIhhh2xdb7x'
FOREIGN_POINTS = [
    (1.5, -2.25, 3.0, 4_000_000_000, -1, 2, -32768, 1e-300, -5),
    (-0.5, 7.0, 1e6, 17, 32767, 0, 3, -123.456789012345, 127),
    (0.0, 0.0, -1e-3, 0, 5, 6, 7, 2.0 ** 40, 0),
]


def check_foreign(decoded: np.ndarray, points: list[tuple]) -> None:
    assert decoded.dtype.names == ('range', 'z', 'x', 'y', 'label', 'reflectivity', 'flag')
    assert decoded.dtype['range'] == np.float64 and decoded.dtype['flag'] == np.int8
    assert decoded.dtype['label'].shape == (3,) and decoded.dtype['label'].base == np.int16
    assert decoded.dtype['reflectivity'] == np.uint32
    assert all(decoded.dtype[name].isnative for name in decoded.dtype.names)
    assert decoded.shape == (len(points),)
    for got, (x, y, z, refl, l0, l1, l2, rng, flag) in zip(decoded, points):
        assert (got['x'], got['y'], got['z']) == (np.float32(x), np.float32(y), np.float32(z))
        assert got['reflectivity'] == refl and got['range'] == rng and got['flag'] == flag
        assert list(got['label']) == [l0, l1, l2]


@pytest.mark.parametrize('order, big_endian', [('<', False), ('>', True)])
def test_from_pointcloud2_foreign_layout(order: str, big_endian: bool) -> None:
    row = b''.join(struct.pack(order + FOREIGN_FORMAT, *p) for p in FOREIGN_POINTS)
    msg = cloud(FOREIGN_FIELDS, [row], 3, 40, 120, big_endian)
    check_foreign(from_pointcloud2(msg), FOREIGN_POINTS)


def test_from_pointcloud2_row_padding_and_height() -> None:
    pad = b'\xab' * 8
    rows = [b''.join(struct.pack('>' + FOREIGN_FORMAT, *p) for p in FOREIGN_POINTS[i:i + 1])
            + pad for i in (0, 1)]
    msg = cloud(FOREIGN_FIELDS, rows, 1, 40, 48, big_endian=True)
    check_foreign(from_pointcloud2(msg), FOREIGN_POINTS[:2])

    # height 2, width 3, row-major: row 0 then row 1, padding skipped
    row0 = b''.join(struct.pack('<ffB', i, -i, i) for i in range(3)) + pad
    row1 = b''.join(struct.pack('<ffB', 10 + i, -10 - i, 10 + i) for i in range(3)) + pad
    msg = cloud([field('a', 0, 7), field('b', 4, 7), field('ring', 8, 2)],
                [row0, row1], 3, 9, 35)
    out = from_pointcloud2(msg)
    np.testing.assert_array_equal(out['a'], [0, 1, 2, 10, 11, 12])
    np.testing.assert_array_equal(out['b'], [0, -1, -2, -10, -11, -12])
    np.testing.assert_array_equal(out['ring'], [0, 1, 2, 10, 11, 12])


def test_from_pointcloud2_on_real_message_classes() -> None:
    """The foreign layout through real rosbags and rclpy PointCloud2 objects."""
    row = b''.join(struct.pack('>' + FOREIGN_FORMAT, *p) for p in FOREIGN_POINTS)
    types = TYPESTORE.types
    msg = types['sensor_msgs/msg/PointCloud2'](
        header=types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=1, nanosec=2), frame_id='os'),
        height=1, width=3,
        fields=[types['sensor_msgs/msg/PointField'](**vars(f)) for f in FOREIGN_FIELDS],
        is_bigendian=True, point_step=40, row_step=120,
        data=np.frombuffer(row, np.uint8), is_dense=True)
    cdr = TYPESTORE.serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2')
    check_foreign(from_pointcloud2(msg), FOREIGN_POINTS)
    check_foreign(from_pointcloud2(deserialize_message(bytes(cdr), RclpyPointCloud2)),
                  FOREIGN_POINTS)


def test_from_pointcloud2_errors() -> None:
    row = struct.pack('<ff', 1.0, 2.0) * 2
    good = dict(fields=[field('x', 0, 7), field('y', 4, 7)], rows=[row], width=2,
                point_step=8, row_step=16)
    assert from_pointcloud2(cloud(**good)).shape == (2,)

    with pytest.raises(ValueError, match=r'15 bytes.*16'):
        from_pointcloud2(cloud(**{**good, 'rows': [row[:-1]]}))
    with pytest.raises(ValueError, match=r"'y'.*unknown datatype code 9"):
        from_pointcloud2(cloud(**{**good, 'fields': [field('x', 0, 7), field('y', 4, 9)]}))
    with pytest.raises(ValueError, match=r"'y'.*point_step 8"):
        from_pointcloud2(cloud(**{**good, 'fields': [field('x', 0, 7), field('y', 4, 8)]}))
    with pytest.raises(ValueError, match=r"'x'.*repeated"):
        from_pointcloud2(cloud(**{**good, 'fields': [field('x', 0, 7), field('x', 4, 7)]}))
    with pytest.raises(ValueError, match=r'row_step 12'):
        from_pointcloud2(cloud(**{**good, 'rows': [row[:12]], 'row_step': 12}))


def test_builders_take_another_layout_by_its_fields() -> None:
    from lidar_sim_ros.io.cepton import SDK3_DTYPE
    pts = np.zeros(3, SDK3_DTYPE)
    pts['x'], pts['channel_id'] = [1.0, 2.0, 3.0], [0, 5, 7]
    msg = to_rosbags_msg(pts, 0, FRAME, TYPESTORE)
    assert [(f.name, f.offset, f.datatype) for f in msg.fields][-2:] == [('flags', 24, 4),
                                                                         ('channel_id', 26, 4)]
    assert msg.point_step == 28 and from_pointcloud2(msg)['channel_id'].tolist() == [0, 5, 7]
    with pytest.raises(ValueError, match="field 'w'"):
        to_rosbags_msg(np.zeros(2, [('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('w', '<i8')]),
                       0, FRAME, TYPESTORE)
