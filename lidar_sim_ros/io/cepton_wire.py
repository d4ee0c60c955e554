"""Cepton's own wire: STDV point data packets, as a Cepton sensor sends them over UDP.

Layouts from Cepton's public "Cepton Sensor Communication Specifications"
(developer.cepton.com, data_format), each named beside its section; no code of Cepton's
is used. Facts taken from it:

* section 3 "Point Data Packet": UDP on IPv4, destination port 8808; points follow the
  firing order; a packet holds a 24-byte header (header version 2) and up to 144 points
  of 10 bytes (point version 0); little-endian;
* header V2: signature ``STDV``, header version, header size, flags (0), timestamp
  (8 bytes, microseconds: the reference time the points' relative timestamps count
  from), point version, point size, point count, sequence id (4 bytes);
* point V0: x (int16), y (uint16), z (int16) in 0.5 cm units, x right, y forward, z up;
  reflectivity (uint8 code: 0-127 = 0-127 % linear, 128-255 on a log scale up to 5000 %),
  relative timestamp (uint8, microseconds since the previous point: where the gap
  exceeds 255 us, the stream carries NO_RETURN filler points), channel id (uint8, the
  laser), flags (uint8);
* point flags: bit 0 saturated, 1 blooming, 2 frame parity (toggles once a frame),
  3 frame boundary (reserved for the SDK: never set by a sensor), 4 second return (a
  later return of the same shot: relative timestamp 0), 5 no return, 6 noise, 7 blocked.

What the sensor would fill and we do not: header flags (0).  INFO packets (the sensor's
twice-a-second status, signature ``INFZ``) are not built here: their layout (the
specification's INFO section) could not be read when this was written
(docs/real-data.md, "the node as a Cepton sensor on the wire").

Our lidar frame is REP-103 (x forward, y left, z up); Cepton's is x right, y forward,
z up: ``to_cepton_axes`` turns one into the other.

Everything here is a pure function of arrays, plus :class:`WireStream`, the little state
a sensor carries from one frame to the next (the last point's time, the packet sequence
number, the frame parity).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.io import cepton

PORT = 8808
"""Section 3: the default destination port."""
SIGNATURE = b'STDV'
HEADER_VERSION = 2
HEADER_SIZE = 24
POINT_VERSION = 0
POINT_SIZE = 10
MAX_POINTS = 144
"""Section 3, header V2 with point V0: at most 144 points a packet."""
UNIT_M = 0.005
"""Section 3, point V0: position unit, 0.5 cm."""
MAX_RELATIVE_US = 255
"""Section 3, point V0: the relative timestamp is one byte."""
MAX_BRIDGED_GAP_US = 1_000_000
"""Longest gap from one frame's last point to the next frame's first that NO_RETURN
fillers bridge (1 s: 3,922 fillers). A longer one (a clock jumped forward: 1000 s took
240 MB of fillers and 27,000 packets, a day would take ~20 GB), or a frame that starts before the last point (a clock jumped back:
every frame was refused until the clock passed the old time), begins the stream afresh,
as at the first frame: the next packet's header carries the new time (``frame_packets``)."""
LINEAR_MAX_CODE = 127
LINEAR_MAX = 1.27
"""Reflectivity codes 0-127: 0-127 % in 1 % steps."""
LOG_MAX = 50.0
"""Code 255: 5000 %; codes 128-255 evenly spaced in log(reflectivity) from 127 %."""
LOG_STEPS = 128

# Section 3, "Point Data Packet Header" (header version 2, 24 bytes).
HEADER_DTYPE = np.dtype([('signature', 'S4'), ('header_version', 'u1'), ('header_size', 'u1'),
                         ('flags', '<u2'), ('timestamp_us', '<u8'), ('point_version', 'u1'),
                         ('point_size', 'u1'), ('point_count', '<u2'), ('sequence_id', '<u4')])
# Section 3, point data V0 (10 bytes).
POINT_DTYPE = np.dtype([('x', '<i2'), ('y', '<u2'), ('z', '<i2'), ('reflectivity', 'u1'),
                        ('relative_timestamp_us', 'u1'), ('channel_id', 'u1'), ('flags', 'u1')])
assert HEADER_DTYPE.itemsize == HEADER_SIZE and POINT_DTYPE.itemsize == POINT_SIZE


def reflectivity_code(reflectivity: np.ndarray) -> np.ndarray:
    """Reflectivity (fraction, 0.30 = 30 %) -> the point's uint8 code (nearest step):
    0-127 linear in 1 % steps, 128-255 log-spaced from 127 % to 5000 % (above: 255;
    NaN or negative: 0)."""
    r = np.nan_to_num(np.asarray(reflectivity, float), nan=0.0, posinf=LOG_MAX, neginf=0.0)
    r = np.clip(r, 0.0, LOG_MAX)
    linear = np.rint(r * 100.0)
    with np.errstate(divide='ignore'):
        log = LINEAR_MAX_CODE + np.rint(LOG_STEPS * np.log(np.maximum(r, LINEAR_MAX) / LINEAR_MAX)
                                        / np.log(LOG_MAX / LINEAR_MAX))
    # Between 1.27 and the first log step (1.307) the nearer code wins.
    high = r > (LINEAR_MAX + reflectivity_from_code(np.uint8(128))) / 2
    return np.where(high, np.minimum(log, 255), np.minimum(linear, LINEAR_MAX_CODE)).astype(np.uint8)


def reflectivity_from_code(code: np.ndarray) -> np.ndarray:
    """A point's reflectivity code -> reflectivity (fraction)."""
    c = np.asarray(code).astype(float)
    log = LINEAR_MAX * (LOG_MAX / LINEAR_MAX) ** ((c - LINEAR_MAX_CODE) / LOG_STEPS)
    return np.where(c <= LINEAR_MAX_CODE, c / 100.0, log)


def to_cepton_axes(xyz_m: np.ndarray) -> np.ndarray:
    """Our lidar frame (x forward, y left, z up) -> Cepton's (x right, y forward, z up)."""
    xyz = np.asarray(xyz_m, float).reshape(-1, 3)
    return np.column_stack([-xyz[:, 1], xyz[:, 0], xyz[:, 2]])


def from_cepton_axes(xyz_c: np.ndarray) -> np.ndarray:
    """Cepton's axes (x right, y forward, z up) -> our lidar frame (x forward, y left, z up)."""
    c = np.asarray(xyz_c, float).reshape(-1, 3)
    return np.column_stack([c[:, 1], -c[:, 0], c[:, 2]])


def quantise_position(xyz_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Our-frame positions (m) -> Cepton x, y, z in 5 mm units (int64, rounded) and a mask
    of the points that fit the point's fields (x, z int16; y uint16: forward of the sensor)."""
    q = np.rint(to_cepton_axes(xyz_m) / UNIT_M)
    with np.errstate(invalid='ignore'):
        fits = (np.isfinite(q).all(axis=1) & (np.abs(q[:, 0]) <= 32767)
                & (q[:, 1] >= 0) & (q[:, 1] <= 65535) & (np.abs(q[:, 2]) <= 32767))
    return np.where(fits[:, None], q, 0).astype(np.int64), fits


@dataclass
class WireStream:
    """What a sensor carries from frame to frame: the last point's time (us, None before
    the first point), the next packet's sequence id, and the frames begun so far (their
    count's parity is the frame-parity flag)."""

    last_t_us: int | None = None
    sequence_id: int = 0
    frames: int = 0
    restarts: int = 0
    """Frames that began the point stream afresh (``MAX_BRIDGED_GAP_US``)."""


@dataclass(frozen=True)
class Packet:
    """One UDP payload and its send time (us, the same clock as the points): the time of
    its last point, when a sensor has filled it."""

    t_us: int
    payload: bytes


def stream_points(t_us: np.ndarray, xyz_m: np.ndarray, reflectivity: np.ndarray,
                  channel: np.ndarray, flags: np.ndarray, parity: bool,
                  last_t_us: int | None) -> tuple[np.ndarray, np.ndarray]:
    """One frame's points, in firing order, as the wire's point stream.

    t_us (N,) absolute point time (int, us, non-decreasing); xyz_m (N, 3) our lidar frame
    (ignored for NO_RETURN points, which sit at 0, 0, 0); reflectivity (N,) fraction;
    channel (N,) laser; flags (N,) cepton.FLAGS bits (FRAME_PARITY and FRAME_BOUNDARY are
    the stream's: cleared, then parity set on every point of an odd frame). ``last_t_us``:
    the previous point's time (None: the first point counts from itself).

    Returns (points, t_abs_us): POINT_DTYPE array with relative timestamps filled and
    NO_RETURN filler points (channel 0, the previous frame's parity where they precede the
    frame's first point) wherever a gap exceeds 255 us, and every point's absolute time.
    Points whose position does not fit the fields (behind the sensor, beyond 163 m
    sideways or 327 m forward) are sent as NO_RETURN. Raises ValueError on times that go
    backwards.
    """
    t = np.asarray(t_us, np.int64)
    n = len(t)
    if n and np.any(np.diff(t) < 0):
        raise ValueError('point times must not decrease (the wire follows the firing order)')
    prev = int(t[0]) if last_t_us is None and n else last_t_us
    if n and t[0] < prev:
        raise ValueError(f'the frame starts at {int(t[0])} us, before the previous point '
                         f'({prev} us)')
    fl = np.asarray(flags, np.int64) & ~(cepton.FRAME_PARITY | cepton.FRAME_BOUNDARY)
    q, fits = quantise_position(xyz_m)
    no_ret = ((fl & cepton.NO_RETURN) != 0) | ~fits
    fl = np.where(no_ret, (fl | cepton.NO_RETURN) & ~cepton.SATURATED, fl)
    q[no_ret] = 0
    par = cepton.FRAME_PARITY if parity else 0
    gaps = np.diff(np.concatenate([[prev], t])) if n else np.zeros(0, np.int64)
    fillers = np.maximum((gaps - 1) // MAX_RELATIVE_US, 0)     # 255-us steps before each point
    total = n + int(fillers.sum())
    out = np.zeros(total, POINT_DTYPE)
    t_abs = np.empty(total, np.int64)
    # Real point k lands after its fillers: index k + fillers[:k+1].sum().
    pos = np.arange(n) + np.cumsum(fillers)
    is_real = np.zeros(total, bool)
    is_real[pos] = True
    out['x'][pos], out['y'][pos], out['z'][pos] = q[:, 0], q[:, 1], q[:, 2]
    out['reflectivity'][pos] = np.where(no_ret, 0, reflectivity_code(reflectivity))
    out['channel_id'][pos] = np.asarray(channel).astype(np.uint8)
    out['flags'][pos] = (fl | par).astype(np.uint8)
    out['relative_timestamp_us'][pos] = gaps - fillers * MAX_RELATIVE_US
    t_abs[pos] = t
    if total > n:
        fill = np.flatnonzero(~is_real)
        owner = np.repeat(np.arange(n), fillers)                 # the real point each precedes
        start = np.concatenate([[prev], t[:-1]])[owner]
        step = fill - (pos[owner] - fillers[owner]) + 1          # 1, 2, ... within a gap
        t_abs[fill] = start + step * MAX_RELATIVE_US
        out['relative_timestamp_us'][fill] = MAX_RELATIVE_US
        first_gap = owner == 0
        out['flags'][fill] = cepton.NO_RETURN | np.where(
            first_gap & (last_t_us is not None), cepton.FRAME_PARITY - par, par)
    return out, t_abs


def packets(points: np.ndarray, t_abs_us: np.ndarray, state: WireStream) -> list[Packet]:
    """A point stream (``stream_points``) cut into STDV packets of at most 144 points.

    Each header's timestamp is the time the packet's first relative timestamp counts
    from (the previous point's time), so the absolute time of point k of a packet is the
    header timestamp plus the relative timestamps of points 0..k. Advances
    ``state.sequence_id`` (wrapping at 2^32); the packet's send time is its last point's.
    """
    out = []
    for k in range(0, len(points), MAX_POINTS):
        chunk = points[k:k + MAX_POINTS]
        header = np.zeros(1, HEADER_DTYPE)
        header['signature'] = SIGNATURE
        header['header_version'] = HEADER_VERSION
        header['header_size'] = HEADER_SIZE
        header['timestamp_us'] = int(t_abs_us[k]) - int(chunk['relative_timestamp_us'][0])
        header['point_version'] = POINT_VERSION
        header['point_size'] = POINT_SIZE
        header['point_count'] = len(chunk)
        header['sequence_id'] = state.sequence_id
        state.sequence_id = (state.sequence_id + 1) % 2**32
        out.append(Packet(int(t_abs_us[k + len(chunk) - 1]), header.tobytes() + chunk.tobytes()))
    return out


def frame_packets(driver_points: np.ndarray, state: WireStream) -> list[Packet]:
    """One frame's points in the SDK3 driver's layout (``io.cepton.SDK3_DTYPE``, as
    ``core.driver_layout.cepton_frame_points`` makes them: firing order, our axes,
    reflectivity fraction in ``intensity``) -> its STDV packets. The frame's parity is
    the parity of ``state.frames``, which this advances, with ``state.last_t_us``."""
    p = driver_points
    t_us = np.asarray(p['timestamp_s'], np.int64) * 1_000_000 + np.asarray(p['timestamp_us'], np.int64)
    xyz = np.column_stack([p['x'], p['y'], p['z']]).astype(float)
    last = state.last_t_us
    if last is not None and len(t_us) and not 0 <= int(t_us[0]) - last <= MAX_BRIDGED_GAP_US:
        last = None                    # a clock jump: the stream begins again (counted)
        state.restarts += 1
    pts, t_abs = stream_points(t_us, xyz, p['intensity'], p['channel_id'], p['flags'],
                               bool(state.frames % 2), last)
    state.frames += 1
    if len(t_abs):
        state.last_t_us = int(t_abs[-1])
    return packets(pts, t_abs, state)
