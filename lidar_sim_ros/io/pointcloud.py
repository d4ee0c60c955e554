"""The one PointCloud2 layout of lidar_sim_ros, its builders and a generic decoder.

Every simulated cloud, whether published by the ROS node, written by the offline CLI
or read back by the comparison tool, uses `POINT_DTYPE`: 24 bytes a point,
little-endian, in the sensor frame (REP-103: x forward, y left, z up), metres.

`from_pointcloud2` does not assume this layout: it decodes any PointCloud2 (rosbags
or rclpy message) from its own field list, so real measurements with other field
sets load through the same function.
"""
from __future__ import annotations

import array
from typing import Any, NamedTuple

import numpy as np

# sensor_msgs/msg/PointField datatype codes.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

# PointField datatype code -> numpy scalar type without byte order.
DATATYPE_TO_NUMPY: dict[int, str] = {
    INT8: 'i1', UINT8: 'u1', INT16: 'i2', UINT16: 'u2',
    INT32: 'i4', UINT32: 'u4', FLOAT32: 'f4', FLOAT64: 'f8',
}

POINT_DTYPE = np.dtype(
    {
        'names': ['x', 'y', 'z', 'intensity', 't', 'ring', 'material', 'return'],
        'formats': ['<f4', '<f4', '<f4', '<f4', '<f4', '<u2', 'u1', 'u1'],
        'offsets': [0, 4, 8, 12, 16, 20, 22, 23],
        'itemsize': 24,
    },
    align=True,
)
"""One simulated return: x, y, z [m, sensor frame], intensity [arbitrary units],
t [s since the header stamp], ring [laser id], material [index into the materials
list], return [1 = the shot's nearest reported return, 2 the next, ...; see
``core/returns.py``]."""

POINT_STEP = POINT_DTYPE.itemsize


class FieldSpec(NamedTuple):
    """One sensor_msgs/PointField: name, byte offset, datatype code, element count."""

    name: str
    offset: int
    datatype: int
    count: int


POINT_FIELDS: list[FieldSpec] = [
    FieldSpec('x', 0, FLOAT32, 1),
    FieldSpec('y', 4, FLOAT32, 1),
    FieldSpec('z', 8, FLOAT32, 1),
    FieldSpec('intensity', 12, FLOAT32, 1),
    FieldSpec('t', 16, FLOAT32, 1),
    FieldSpec('ring', 20, UINT16, 1),
    FieldSpec('material', 22, UINT8, 1),
    FieldSpec('return', 23, UINT8, 1),
]

_NS_PER_S = 1_000_000_000
MAX_CLOUD_POINTS = 50_000_000
"""Points in one decoded cloud (a P-60 frame has ~21,000; the decoded copy costs ~40 B each)."""


def make_points(
    xyz_m: np.ndarray,
    intensity: np.ndarray | float,
    t_s: np.ndarray | float,
    ring: np.ndarray | int,
    material: np.ndarray | int,
    return_number: np.ndarray | int = 1,
) -> np.ndarray:
    """Pack per-point arrays into a `POINT_DTYPE` array of length N.

    xyz_m is (N, 3) in metres, sensor frame, and must be finite (clouds are
    published with is_dense=True). The other arguments are (N,) arrays or scalars
    broadcast to N: intensity, t_s [s since the header stamp], ring [laser id,
    0..65535], material [index into the materials list, 0..255], return_number [1 = the
    shot's nearest reported return, 1..255].
    """
    xyz = np.asarray(xyz_m)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f'xyz_m must have shape (N, 3), got {xyz.shape}')
    if not np.isfinite(xyz).all():
        bad = int(np.flatnonzero(~np.isfinite(xyz).all(axis=1))[0])
        raise ValueError(f'xyz_m must be finite (is_dense clouds); row {bad} is {xyz[bad]}')
    n = xyz.shape[0]
    points = np.empty(n, dtype=POINT_DTYPE)
    with np.errstate(over='ignore'):
        points['x'], points['y'], points['z'] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    _check_float32_finite(points, xyz)
    points['intensity'] = _per_point('intensity', intensity, n)
    points['t'] = _per_point('t_s', t_s, n)
    points['ring'] = _per_point('ring', ring, n, np.iinfo(np.uint16).max)
    points['material'] = _per_point('material', material, n, np.iinfo(np.uint8).max)
    points['return'] = _per_point('return_number', return_number, n, np.iinfo(np.uint8).max)
    return points


def _check_float32_finite(points: np.ndarray, xyz: np.ndarray) -> None:
    """Clouds are published is_dense: a coordinate finite in float64 but past the float32
    range (a 1e300 m bias) would go out as inf."""
    finite = np.isfinite(points['x']) & np.isfinite(points['y']) & np.isfinite(points['z'])
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise ValueError(f'xyz_m row {bad} is {xyz[bad]}: beyond the float32 range of the '
                         'cloud (is_dense clouds are finite)')


def _per_point(name: str, values: Any, n: int, int_max: int | None = None) -> np.ndarray:
    """Broadcast a scalar or (n,) array to (n,), checking length and integer range."""
    arr = np.asarray(values)
    if arr.ndim == 0:
        arr = np.broadcast_to(arr, (n,))
    elif arr.shape != (n,):
        raise ValueError(f'{name} must be a scalar or have shape ({n},), got {arr.shape}')
    if int_max is not None and n:
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f'{name} must be integers, got dtype {arr.dtype}')
        lo, hi = int(arr.min()), int(arr.max())
        if lo < 0 or hi > int_max:
            raise ValueError(f'{name} must lie in [0, {int_max}], got values in [{lo}, {hi}]')
    return arr


def _check_points(points: np.ndarray) -> np.ndarray:
    """Return points as a contiguous 1-D array of a known layout (POINT_DTYPE or another
    little-endian structured dtype of PointField types, e.g. ``io/cepton.py``'s)."""
    names = getattr(getattr(points, 'dtype', None), 'names', None) or ()
    if not isinstance(points, np.ndarray) or not all(
            n in names and points.dtype[n] == np.dtype('<f4') for n in 'xyz'):
        found = getattr(points, 'dtype', type(points).__name__)
        raise ValueError(f'points must be a POINT_DTYPE array (see make_points) or another '
                         f'layout with x, y, z FLOAT32 fields, got {found}')
    if points.ndim != 1:
        raise ValueError(f'points must be 1-D, got shape {points.shape}')
    fields_of(points.dtype)       # raises naming a field no PointField can carry
    return np.ascontiguousarray(points)


_NUMPY_TO_DATATYPE = {v: k for k, v in DATATYPE_TO_NUMPY.items()}


def fields_of(dtype: np.dtype) -> list[FieldSpec]:
    """The PointFields of a structured point dtype (POINT_FIELDS for POINT_DTYPE)."""
    if dtype == POINT_DTYPE:
        return POINT_FIELDS
    out = []
    for name in dtype.names or ():
        sub, offset = dtype.fields[name][:2]
        code = _NUMPY_TO_DATATYPE.get(sub.base.str[1:])
        if code is None or sub.base.byteorder == '>' or sub.ndim:
            raise ValueError(f'point field {name!r} of dtype {sub} has no PointField datatype '
                             '(scalar little-endian int/uint 8-32 bit or float 32/64 expected)')
        out.append(FieldSpec(name, offset, code, 1))
    return out


def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time (rosbags or rclpy) -> integer nanoseconds."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


def ns_to_stamp(ns: int, cls: type) -> Any:
    """Integer nanoseconds -> `cls(sec=..., nanosec=...)`, nanosec in [0, 1e9)."""
    sec, nanosec = divmod(int(ns), _NS_PER_S)
    return cls(sec=sec, nanosec=nanosec)


def to_rosbags_msg(points: np.ndarray, stamp_ns: int, frame_id: str, typestore: Any) -> Any:
    """Build a rosbags sensor_msgs/msg/PointCloud2 from a POINT_DTYPE array (or another
    layout, ``fields_of``)."""
    points = _check_points(points)
    step = points.dtype.itemsize
    types = typestore.types
    field_cls = types['sensor_msgs/msg/PointField']
    header = types['std_msgs/msg/Header'](
        stamp=ns_to_stamp(stamp_ns, types['builtin_interfaces/msg/Time']),
        frame_id=frame_id,
    )
    return types['sensor_msgs/msg/PointCloud2'](
        header=header,
        height=1,
        width=len(points),
        fields=[field_cls(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                for f in fields_of(points.dtype)],
        is_bigendian=False,
        point_step=step,
        row_step=step * len(points),
        data=np.frombuffer(points.tobytes(), dtype=np.uint8),
        is_dense=True,
    )


def to_rclpy_msg(points: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
    """Build an rclpy sensor_msgs.msg.PointCloud2 from a POINT_DTYPE array (or another
    layout, ``fields_of``).

    ROS is imported here so this module loads without a ROS installation.
    """
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField

    points = _check_points(points)
    msg = PointCloud2()
    msg.header.stamp = ns_to_stamp(stamp_ns, Time)
    msg.header.frame_id = frame_id
    msg.height = 1
    msg.width = len(points)
    msg.fields = [PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                  for f in fields_of(points.dtype)]
    msg.is_bigendian = False
    msg.point_step = points.dtype.itemsize
    msg.row_step = points.dtype.itemsize * len(points)
    # The generated setter takes an array.array('B') as is (bytes or lists are checked
    # element by element). frombytes() on a uint8 view is one memcpy: ~15 us for 25k
    # points, whereas array.array('B', points.tobytes()) takes ~300 us.
    data = array.array('B')
    data.frombytes(points.view(np.uint8))
    msg.data = data
    msg.is_dense = True
    return msg


def from_pointcloud2(msg: Any) -> np.ndarray:
    """Decode any PointCloud2 (rosbags or rclpy) into a 1-D structured array.

    The output has one field per message field (in message order, native byte
    order, count > 1 as a sub-array) and height * width points in row-major order.
    Row padding, big-endian data and arbitrary offsets are honoured.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    if height * width > MAX_CLOUD_POINTS:
        raise ValueError(f'PointCloud2 of {height} x {width} points exceeds the limit of '
                         f'{MAX_CLOUD_POINTS} points per cloud')
    order = '>' if msg.is_bigendian else '<'
    wire_dtype, out_dtype = _field_dtypes(msg.fields, order, point_step)

    data = _as_uint8(msg.data)
    if row_step < width * point_step:
        raise ValueError(
            f'PointCloud2 row_step {row_step} is smaller than width {width} x '
            f'point_step {point_step}')
    if data.size != height * row_step:
        raise ValueError(
            f'PointCloud2 data has {data.size} bytes, expected height {height} x '
            f'row_step {row_step} = {height * row_step}')

    rows = data.reshape(height, row_step)[:, :width * point_step]
    wire = np.ascontiguousarray(rows).view(wire_dtype).reshape(-1)
    out = np.empty(wire.shape, dtype=out_dtype)
    for name in out_dtype.names or ():
        out[name] = wire[name]
    return out


def _field_dtypes(fields: Any, order: str, point_step: int) -> tuple[np.dtype, np.dtype]:
    """Message fields -> (dtype of the bytes on the wire, packed native output dtype)."""
    names: list[str] = []
    wire_formats: list[Any] = []
    out_formats: list[Any] = []
    offsets: list[int] = []
    for field in fields:
        name, offset = str(field.name), int(field.offset)
        datatype, count = int(field.datatype), int(field.count)
        if datatype not in DATATYPE_TO_NUMPY:
            raise ValueError(
                f'PointCloud2 field {name!r} has unknown datatype code {datatype}; '
                f'known codes are {sorted(DATATYPE_TO_NUMPY)}')
        if not name or name in names:
            raise ValueError(f'PointCloud2 field name {name!r} is empty or repeated')
        if count < 1:
            raise ValueError(f'PointCloud2 field {name!r} has count {count}, expected >= 1')
        base = DATATYPE_TO_NUMPY[datatype]
        size = np.dtype(base).itemsize * count
        if offset < 0 or offset + size > point_step:
            raise ValueError(
                f'PointCloud2 field {name!r} (offset {offset}, {size} bytes) does not fit '
                f'in point_step {point_step}')
        shape = () if count == 1 else (count,)
        names.append(name)
        offsets.append(offset)
        wire_formats.append((np.dtype(order + base), shape))
        out_formats.append((np.dtype('=' + base), shape))
    _check_no_overlap(names, offsets, [np.dtype(f[0]).itemsize * max(1, int(np.prod(f[1])))
                                       for f in wire_formats])
    wire = np.dtype({'names': names, 'formats': wire_formats, 'offsets': offsets,
                     'itemsize': point_step})
    out = np.dtype({'names': names, 'formats': out_formats})
    return wire, out


def _check_no_overlap(names: list[str], offsets: list[int], sizes: list[int]) -> None:
    """Fields may not share bytes: FLOAT64 declared over float32 data (x at 0, y at 4)
    read every coordinate from its neighbour's bytes."""
    spans = sorted(zip(offsets, sizes, names))
    for (o1, s1, n1), (o2, _, n2) in zip(spans, spans[1:]):
        if o1 + s1 > o2:
            raise ValueError(f'PointCloud2 fields {n1!r} (offset {o1}, {s1} bytes) and {n2!r} '
                             f'(offset {o2}) overlap: check their datatypes')


def _as_uint8(data: Any) -> np.ndarray:
    """PointCloud2.data (ndarray, array.array, bytes, memoryview or list) -> uint8 view."""
    if isinstance(data, (list, tuple)):
        return np.asarray(data, dtype=np.uint8)
    return np.frombuffer(data, dtype=np.uint8)


def frame_points(frame: Any, truth: bool = False) -> np.ndarray:
    """A simulated ``core.pipeline.Frame`` in this layout: detected returns, or the noise-free truth."""
    if truth:
        return make_points(frame.truth_xyz_m, frame.truth_intensity, frame.truth_t_s,
                           frame.truth_ring, frame.truth_material)
    return make_points(frame.xyz_m, frame.intensity, frame.t_s, frame.ring, frame.material,
                       1 if frame.return_number is None else frame.return_number)
