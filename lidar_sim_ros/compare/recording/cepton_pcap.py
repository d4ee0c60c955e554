"""A Cepton sensor's own wire as a recording: a pcap of its STDV packets (what a lab
records with Cepton's tools, or ``lidar-sim simulate --pcap`` writes), with the target
poses from a bag or a CSV file. ``compare`` and ``calibrate range-errors`` then read it
like a bag in the Cepton SDK3 driver's layout, and a lab needs no ROS.

Decoder written from Cepton's public "Cepton Sensor Communication Specifications"
(section 3, "Point Data Packet"), independently of ``io/cepton_wire.py`` (the encoder):
header version 1 (20 bytes) or 2 (24 bytes, + sequence id), point version 0 (10 bytes:
int16 x, uint16 y, int16 z in 5 mm, Cepton axes x right, y forward, z up; uint8
reflectivity code, relative timestamp in us since the previous point, channel, flags).
A point's absolute time is the header timestamp plus the relative timestamps of the
packet's points up to and including it. Frames: a new frame begins where the
frame-parity flag (bit 2) toggles. Positions go to our lidar frame (x forward, y left,
z up); the reflectivity code to a fraction (0-127: 1 % steps; 128-255: log steps from
127 % to 5000 %).

The pcap: classic libpcap (either byte order, micro- or nanosecond timestamps), link
types Ethernet (with 802.1Q tags) or raw IPv4; UDP datagrams to or from ``port`` (8808)
whose payload starts with ``STDV``; everything else is skipped and counted (INFO
packets, other traffic, IPv4 fragments, other point versions, header times at or beyond
2^31 s). pcapng is refused with a
message. Memory: frames are decoded one at a time.

Poses CSV: a header line ``t_s,x_m,y_m,z_m,qx,qy,qz,qw`` then one row per pose: the time
(s, the sensor's clock: Unix seconds for a PTP-synchronised sensor) and the target body
pose in our lidar frame (x forward, y left, z up; quaternion x, y, z, w).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Iterator

import numpy as np

from lidar_sim_ros.core.config import MAX_POSITION_M
from lidar_sim_ros.core.vectors import QUAT_NORM_TOL
from lidar_sim_ros.io import cepton
from lidar_sim_ros.io.bag import CloudFrame, PoseSeries

PCAP_MAGICS = {b'\xd4\xc3\xb2\xa1': ('<', 1000), b'\xa1\xb2\xc3\xd4': ('>', 1000),
               b'\x4d\x3c\xb2\xa1': ('<', 1), b'\xa1\xb2\x3c\x4d': ('>', 1)}
PCAPNG_MAGIC = b'\x0a\x0d\x0d\x0a'
LINK_ETHERNET, LINK_RAW, LINK_IPV4 = 1, 101, 228
STDV = b'STDV'
POINT_V0 = np.dtype([('x', '<i2'), ('y', '<u2'), ('z', '<i2'), ('code', 'u1'),
                     ('dt_us', 'u1'), ('channel', 'u1'), ('flags', 'u1')])
UNIT_M = 0.005
MAX_RECORD_BYTES = 262_144
MAX_FRAME_POINTS = 5_000_000
"""A frame (between parity toggles) longer than this is cut: memory stays bounded."""
MAX_TIME_US = 2**31 * 1_000_000
"""A point time at or beyond 2^31 s (year 2038) is no Cepton clock: the driver layout's
int32 seconds would wrap (the header's uint64 beyond 2^63 us overflowed int64)."""
POSE_COLUMNS = ('t_s', 'x_m', 'y_m', 'z_m', 'qx', 'qy', 'qz', 'qw')
MAX_HEADER_CHARS = 200
"""The poses CSV header line is read up to this many characters (a file without a newline
was read whole)."""
MAX_POSE_ROWS = 1_000_000
"""Most poses read from a CSV (2.8 h at 100 Hz; ~70 MB): 1e7 rows took 1.35 GB to read."""


class PcapError(ValueError):
    """The pcap cannot be read as a Cepton recording: names the file and what is wrong."""


def is_pcap(path: str | Path) -> bool:
    """Whether ``path`` is a file starting with a pcap or pcapng magic number."""
    p = Path(path)
    if not p.is_file():
        return False
    with open(p, 'rb') as f:
        head = f.read(4)
    return head in PCAP_MAGICS or head == PCAPNG_MAGIC


@dataclass
class PcapStats:
    """What a pass over the pcap saw: packets decoded and skipped (by reason), frames."""

    stdv_packets: int = 0
    points: int = 0
    frames: int = 0
    skipped: dict = field(default_factory=dict)

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1


def reflectivity_of_code(code: np.ndarray) -> np.ndarray:
    """Reflectivity code -> fraction: 0-127 in 1 % steps, 128-255 from 127 % to 5000 %
    evenly in log."""
    c = np.asarray(code, float)
    return np.where(c <= 127, c / 100.0, 1.27 * (50.0 / 1.27) ** ((c - 127.0) / 128.0))


def _records(f: BinaryIO, path: Path,
             stats: PcapStats | None = None) -> Iterator[tuple[int, int, bytes]]:
    """(link type, capture time ns, record bytes) of a classic pcap; a record cut short by
    the end of the file (a capture stopped mid-write) ends it, counted in ``stats``."""
    head = f.read(24)
    if head[:4] == PCAPNG_MAGIC:
        raise PcapError(f'{path} is pcapng: save it as classic pcap (Wireshark: File > Save As '
                        '> pcap; or editcap -F pcap IN OUT)')
    if len(head) < 24 or head[:4] not in PCAP_MAGICS:
        raise PcapError(f'{path} is not a pcap file (magic {head[:4].hex() or "none"})')
    order, ns_per_tick = PCAP_MAGICS[head[:4]]
    link = struct.unpack(order + 'I', head[20:24])[0] & 0xFFFF
    if link not in (LINK_ETHERNET, LINK_RAW, LINK_IPV4):
        raise PcapError(f'{path}: link type {link} (only Ethernet = 1 or raw IPv4 = 101/228)')
    while True:
        rec = f.read(16)
        if len(rec) < 16:
            if rec and stats is not None:
                stats.skip('truncated record at the end')
            return
        sec, frac, incl, _ = struct.unpack(order + 'IIII', rec)
        if incl > MAX_RECORD_BYTES:
            raise PcapError(f'{path}: a record of {incl} bytes (corrupt file?)')
        data = f.read(incl)
        if len(data) < incl:
            if stats is not None:
                stats.skip('truncated record at the end')
            return
        yield link, sec * 1_000_000_000 + frac * ns_per_tick, data


def _udp_payload(link: int, data: bytes, port: int, stats: PcapStats) -> bytes | None:
    """The UDP payload of an IPv4 datagram to or from ``port``, else None (counted)."""
    off = 0
    if link == LINK_ETHERNET:
        off, ethertype = 14, data[12:14] if len(data) >= 14 else b''
        while ethertype in (b'\x81\x00', b'\x88\xa8') and len(data) >= off + 4:
            ethertype, off = data[off + 2:off + 4], off + 4
        if ethertype != b'\x08\x00':
            stats.skip('not IPv4')
            return None
    if len(data) < off + 20 or data[off] >> 4 != 4:
        stats.skip('not IPv4')
        return None
    ihl = (data[off] & 0x0F) * 4
    if data[off + 9] != 17:
        stats.skip('not UDP')
        return None
    frag = struct.unpack('!H', data[off + 6:off + 8])[0]
    if frag & 0x3FFF:
        stats.skip('IPv4 fragment')
        return None
    u = off + ihl
    if len(data) < u + 8:
        stats.skip('truncated')
        return None
    sport, dport, ulen = struct.unpack('!HHH', data[u:u + 6])
    if port not in (sport, dport):
        stats.skip('other UDP port')
        return None
    return data[u + 8:u + max(ulen, 8)]


def _stdv_points(payload: bytes, stats: PcapStats) -> tuple[np.ndarray, np.ndarray] | None:
    """(points V0, absolute time us) of one STDV packet, or None (counted)."""
    if len(payload) < 20 or payload[:4] != STDV:
        stats.skip('not STDV (INFO or other)')
        return None
    hver, hsize, _, ts_us, pver, psize, count = struct.unpack_from('<BBHQBBH', payload, 4)
    if hver not in (1, 2) or hsize < 20 or pver != 0 or psize != POINT_V0.itemsize:
        stats.skip(f'STDV header {hver} / point version {pver}')
        return None
    if len(payload) < hsize + count * psize:
        stats.skip('STDV shorter than its point count')
        return None
    pts = np.frombuffer(payload, POINT_V0, count, hsize)
    if ts_us + 255 * count >= MAX_TIME_US:
        stats.skip('STDV timestamp beyond 2^31 s')
        return None
    t_us = np.int64(ts_us) + np.cumsum(pts['dt_us'], dtype=np.int64)
    stats.stdv_packets += 1
    return pts, t_us


def _driver_points(pts: np.ndarray, t_us: np.ndarray) -> np.ndarray:
    """Decoded points -> the SDK3 driver's layout (our axes, reflectivity fraction)."""
    out = np.zeros(len(pts), cepton.SDK3_DTYPE)
    right, fwd, up = (pts['x'] * UNIT_M, pts['y'] * UNIT_M, pts['z'] * UNIT_M)
    out['x'], out['y'], out['z'] = fwd, -right, up
    out['intensity'] = reflectivity_of_code(pts['code'])
    sec, us = np.divmod(t_us, 1_000_000)
    out['timestamp_s'], out['timestamp_us'] = sec, us
    out['flags'] = pts['flags'] & np.uint8(0xFF ^ cepton.FRAME_BOUNDARY)
    out['channel_id'] = pts['channel']
    return out


def iter_frames(path: str | Path, port: int = 8808,
                stats: PcapStats | None = None) -> Iterator[CloudFrame]:
    """The pcap's frames one at a time, as clouds in the SDK3 driver's layout: stamp =
    the frame's first point time, frame id ``cepton3``."""
    path = Path(path)
    stats = stats if stats is not None else PcapStats()
    parts: list[np.ndarray] = []
    n = 0
    parity = None

    def flush():
        nonlocal parts, n
        if parts:
            pts = np.concatenate(parts)
            stats.frames += 1
            t0 = int(pts['timestamp_s'][0]) * 1_000_000 + int(pts['timestamp_us'][0])
            parts, n = [], 0
            return CloudFrame(t0 * 1000, cepton.FRAME_ID, pts)
        return None

    with open(path, 'rb') as f:
        for link, _, data in _records(f, path, stats):
            payload = _udp_payload(link, data, port, stats)
            if payload is None:
                continue
            got = _stdv_points(payload, stats)
            if got is None:
                continue
            pts, t_us = got
            stats.points += len(pts)
            par = (pts['flags'] & cepton.FRAME_PARITY) != 0
            cuts = np.flatnonzero(np.diff(par.astype(np.int8))) + 1
            start = 0
            for cut in list(cuts) + [len(pts)]:
                if start == cut:
                    continue
                if parity is not None and bool(par[start]) != parity or n >= MAX_FRAME_POINTS:
                    frame = flush()
                    if frame is not None:
                        yield frame
                parity = bool(par[start])
                parts.append(_driver_points(pts[start:cut], t_us[start:cut]))
                n += cut - start
                start = cut
    frame = flush()
    if frame is not None:
        yield frame


def frame_count(path: str | Path, port: int = 8808) -> int:
    """Frames in the pcap (a full decoding pass; one frame in memory at a time)."""
    return sum(1 for _ in iter_frames(path, port))


def read_pose_csv(path: str | Path) -> PoseSeries:
    """Poses from a CSV (``POSE_COLUMNS``; see the module docstring), sorted by time.

    Refused naming the file, the row (its line in the file) and its values: a non-finite
    value, a time beyond 2^31 s, a position component beyond ``MAX_POSITION_M``, a
    quaternion whose norm is not within ``QUAT_NORM_TOL`` of 1 (it is then normalised),
    two rows at the same time, more than ``MAX_POSE_ROWS`` rows."""
    path = Path(path)
    # utf-8-sig: a spreadsheet's byte-order mark is no part of the header.
    with open(path, encoding='utf-8-sig') as f:
        try:
            header = [h.strip() for h in f.readline(MAX_HEADER_CHARS).split(',')]
            if header != list(POSE_COLUMNS):
                raise PcapError(f'poses CSV {path}: header must be {",".join(POSE_COLUMNS)}, '
                                f'got {",".join(header)[:MAX_HEADER_CHARS]!r}')
            rows = np.loadtxt(f, delimiter=',', ndmin=2, dtype=float, max_rows=MAX_POSE_ROWS + 1)
        except UnicodeDecodeError as exc:
            raise PcapError(f'poses CSV {path}: not UTF-8 text (a byte '
                            f'{exc.object[exc.start:exc.start + 1]!r})') from None
        except PcapError:
            raise
        except ValueError as exc:
            raise PcapError(f'poses CSV {path}: {exc} (rows counted from 0 after the header)') from None
    if rows.size == 0:
        raise PcapError(f'poses CSV {path}: no rows')
    if len(rows) > MAX_POSE_ROWS:
        raise PcapError(f'poses CSV {path}: more than {MAX_POSE_ROWS} rows')
    if rows.shape[1] != len(POSE_COLUMNS):
        raise PcapError(f'poses CSV {path}: {rows.shape[1]} columns, expected {len(POSE_COLUMNS)}')
    with np.errstate(invalid='ignore', over='ignore'):
        checks = ((~np.isfinite(rows).all(axis=1),
                   'has a non-finite value'),
                  (np.abs(rows[:, 0]) >= 2**31, 'has a time beyond 2^31 s'),
                  ((np.abs(rows[:, 1:4]) > MAX_POSITION_M).any(axis=1),
                   f'has a position component beyond {MAX_POSITION_M:g} m'),
                  (np.abs(np.linalg.norm(rows[:, 4:8], axis=1) - 1.0) > QUAT_NORM_TOL,
                   f'has a quaternion whose norm is not within {QUAT_NORM_TOL:g} of 1'))
    for bad, what in checks:
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise PcapError(f'poses CSV {path}: row {k + 2} {what}: {rows[k].tolist()}')
    order = np.argsort(rows[:, 0], kind='stable')
    stamp_ns = np.rint(rows[order, 0] * 1e9).astype(np.int64)
    same = np.flatnonzero(np.diff(stamp_ns) == 0)
    if same.size:
        a, b = sorted(int(order[i]) + 2 for i in (same[0], same[0] + 1))
        raise PcapError(f'poses CSV {path}: rows {a} and {b} have the same time '
                        f'{float(rows[a - 2, 0])!r} s (one pose per time)')
    rows = rows[order]
    quat = rows[:, 4:8] / np.linalg.norm(rows[:, 4:8], axis=1, keepdims=True)
    return PoseSeries(stamp_ns, cepton.FRAME_ID, rows[:, 1:4], quat)


def read_pose_source(path: str | Path, topic: str) -> tuple[PoseSeries, list[str] | None]:
    """Poses (and material names, from a bag) from a ``.csv`` file or a bag's ``topic``."""
    from lidar_sim_ros.io.bag import read_material_names, read_poses
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f'poses {path} do not exist')
    if path.suffix.lower() == '.csv':
        return read_pose_csv(path), None
    return read_poses(path, topic), read_material_names(path)


def side_bag(recording: str | Path, poses: str | Path | None) -> Path | None:
    """The bag that holds the poses (and sun, material names) of a recording: ``poses``
    when it is a bag, else the recording itself when it is a bag, else None."""
    if poses is not None and Path(poses).suffix.lower() != '.csv':
        return Path(poses)
    if poses is None and not is_pcap(recording):
        return Path(recording)
    return None


def pcap_recording(path: str | Path, poses: str | Path | None, pose_topic: str,
                   port: int = 8808):
    """(poses, material names, frame count, frame iterator, PcapStats) of a pcap recording;
    the stats fill as the frames are read (packets skipped by reason)."""
    if poses is None:
        raise PcapError(f'{path} is a pcap (the sensor\'s packets): give the target poses '
                        'with --poses BAG_OR_CSV')
    series, names = read_pose_source(poses, pose_topic)
    n = frame_count(path, port)
    if n == 0:
        raise PcapError(f'{path}: no Cepton STDV point packets on UDP port {port}')
    stats = PcapStats()
    return series, names, n, iter_frames(path, port, stats), stats


def skipped_line(stats: PcapStats) -> str | None:
    """One line on the packets a pass skipped (None when it skipped nothing)."""
    if not stats.skipped:
        return None
    reasons = ', '.join(f'{n} {why}' for why, n in sorted(stats.skipped.items()))
    return (f'pcap: {stats.stdv_packets} STDV packet(s) read into {stats.frames} frame(s); '
            f'skipped: {reasons}')
