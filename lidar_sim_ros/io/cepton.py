"""The point layouts of Cepton's ROS drivers: what a P-60 recording holds and what a
navigation stack written against the driver subscribes to.

Facts from the driver (ceptontech/ros, ``ros2/cepton_publisher``) and the SDK header
``cepton_sdk3.h``; no code of theirs is used:

* SDK3 driver: topic ``cepton_pcl2``, frame ``cepton3``, header stamp = the frame's
  start time; fields in order x, y, z, intensity (FLOAT32; intensity = reflectivity x
  0.01, the reflectivity in 1 % steps), timestamp_s, timestamp_us (INT32: absolute
  seconds and microseconds), flags (UINT16), channel_id (UINT16), optionally azimuth,
  elevation, range (FLOAT32).
* SDK2 driver: x, y, z, reflectivity (FLOAT32), relative_timestamp, flags,
  channel_id, valid (UINT8 each).
* Point flags (``FLAGS``); the driver drops points whose flags are outside its
  ``include_flag`` mask.

``cepton_points`` packs per-point arrays into the SDK3 layout (packed, little-endian);
``from_pointcloud2`` in ``pointcloud.py`` decodes it like any other cloud.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.io.pointcloud import FLOAT32, INT32, UINT16, FieldSpec

TOPIC = 'cepton_pcl2'
FRAME_ID = 'cepton3'

SATURATED = 1 << 0
BLOOMING = 1 << 1
FRAME_PARITY = 1 << 2
FRAME_BOUNDARY = 1 << 3
SECOND_RETURN = 1 << 4
NO_RETURN = 1 << 5
NOISE = 1 << 6
BLOCKED = 1 << 7
FLAGS = {'SATURATED': SATURATED, 'BLOOMING': BLOOMING, 'FRAME_PARITY': FRAME_PARITY,
         'FRAME_BOUNDARY': FRAME_BOUNDARY, 'SECOND_RETURN': SECOND_RETURN,
         'NO_RETURN': NO_RETURN, 'NOISE': NOISE, 'BLOCKED': BLOCKED}

REFLECTIVITY_STEP = 0.01
"""The driver's intensity is reflectivity x 0.01 with the reflectivity in whole per cent."""

SDK3_FIELDS: list[FieldSpec] = [
    FieldSpec('x', 0, FLOAT32, 1), FieldSpec('y', 4, FLOAT32, 1), FieldSpec('z', 8, FLOAT32, 1),
    FieldSpec('intensity', 12, FLOAT32, 1), FieldSpec('timestamp_s', 16, INT32, 1),
    FieldSpec('timestamp_us', 20, INT32, 1), FieldSpec('flags', 24, UINT16, 1),
    FieldSpec('channel_id', 26, UINT16, 1)]
POLAR_FIELDS: list[FieldSpec] = [
    FieldSpec('azimuth', 28, FLOAT32, 1), FieldSpec('elevation', 32, FLOAT32, 1),
    FieldSpec('range', 36, FLOAT32, 1)]
SDK2_FIELD_NAMES = ('x', 'y', 'z', 'reflectivity', 'relative_timestamp', 'flags',
                    'channel_id', 'valid')

_NUMPY = {FLOAT32: '<f4', INT32: '<i4', UINT16: '<u2'}


def _dtype(fields: list[FieldSpec]) -> np.dtype:
    last = fields[-1]
    return np.dtype({'names': [f.name for f in fields],
                     'formats': [_NUMPY[f.datatype] for f in fields],
                     'offsets': [f.offset for f in fields],
                     'itemsize': last.offset + np.dtype(_NUMPY[last.datatype]).itemsize})


SDK3_DTYPE = _dtype(SDK3_FIELDS)
"""SDK3 point without polar fields: 28 bytes."""
SDK3_POLAR_DTYPE = _dtype(SDK3_FIELDS + POLAR_FIELDS)
"""SDK3 point with azimuth, elevation (rad) and range (m): 40 bytes."""


def quantise_reflectivity(reflectivity: np.ndarray) -> np.ndarray:
    """Reflectivity (fraction, 0.30 = 30 %) in the driver's 1 % steps (float32)."""
    r = np.asarray(reflectivity, float)
    steps = np.round(np.clip(np.nan_to_num(r, nan=0.0), 0.0, 655.35) / REFLECTIVITY_STEP)
    return (steps * REFLECTIVITY_STEP).astype(np.float32)


def cepton_points(xyz_m: np.ndarray, reflectivity: np.ndarray, t_abs_ns: np.ndarray,
                  flags: np.ndarray, channel: np.ndarray, polar: bool = False) -> np.ndarray:
    """Per-point arrays -> the SDK3 driver's point array (``SDK3_DTYPE``, or with
    ``polar`` the azimuth/elevation/range fields too).

    xyz_m (N, 3) lidar frame, metres (zeros for NO_RETURN points); reflectivity (N,)
    fraction, quantised to 1 %; t_abs_ns (N,) absolute point time, integer ns, split into
    timestamp_s + timestamp_us (truncated to the microsecond, as the driver's clock);
    flags (N,) FLAGS bits; channel (N,) laser id.
    """
    xyz = np.asarray(xyz_m, float).reshape(-1, 3)
    n = len(xyz)
    t_ns = np.asarray(t_abs_ns, np.int64)
    if t_ns.shape != (n,):
        raise ValueError(f't_abs_ns must have shape ({n},), got {t_ns.shape}')
    out = np.zeros(n, SDK3_POLAR_DTYPE if polar else SDK3_DTYPE)
    out['x'], out['y'], out['z'] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    out['intensity'] = quantise_reflectivity(reflectivity)
    sec, rem_ns = np.divmod(t_ns, 1_000_000_000)
    out['timestamp_s'] = sec.astype(np.int32)
    out['timestamp_us'] = (rem_ns // 1000).astype(np.int32)
    out['flags'] = np.asarray(flags, np.uint16)
    out['channel_id'] = np.asarray(channel, np.uint16)
    if polar:
        rng = np.linalg.norm(xyz, axis=1)
        safe = np.where(rng > 0, rng, 1.0)
        out['azimuth'] = np.arctan2(xyz[:, 1], xyz[:, 0])
        out['elevation'] = np.where(rng > 0, np.arcsin(np.clip(xyz[:, 2] / safe, -1, 1)), 0.0)
        out['range'] = rng
    return out


def flag_names(bits: int) -> list[str]:
    """The names of the FLAGS set in ``bits``."""
    return [name for name, bit in FLAGS.items() if int(bits) & bit]
