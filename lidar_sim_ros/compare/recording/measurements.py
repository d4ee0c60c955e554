"""Measured points from a rosbag2: directions, ranges, times and the target pose track.

A lab recording holds ``sensor_msgs/PointCloud2`` (x, y, z required; intensity and
per-point time optional) and ``geometry_msgs/PoseStamped`` (target body pose in the
lidar frame). This module turns it into flat per-point arrays: measured range = |xyz|,
direction = xyz / |xyz|, absolute time = cloud stamp + time since the stamp (or the
stamp when the cloud has no time field), plus a :class:`PoseTrack` that answers the
pose at every point's time.

Per-point time comes under many names (``t``, ``time``, ``timestamp``, ``t_ns``,
``offset_time``, ...; :data:`POINT_TIME_FIELDS`), in seconds or nanoseconds, relative
to the stamp or absolute: :func:`point_time_since_stamp_s` decides from the field's
name, type and magnitude against the header stamp, and the choice is recorded.
Which field is the intensity, the time (one field or a seconds + sub-seconds pair such
as the Cepton driver's ``timestamp_s`` + ``timestamp_us``), the laser and the Cepton
point flags is decided by ``compare/recording/fields.py`` (or named with ``--intensity-field``,
``--time-field``, ``--laser-field``); ``Measurements.field_lines`` says it for the
terminal. Flagged Cepton points: NO_RETURN shots are not points but known misses
(counted), SATURATED returns are kept and marked (``saturated``), NOISE and BLOCKED are
counted (``flag_counts``).
Every problem raises :class:`MeasurementError` naming the bag, topic and what is wrong.
"""
from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.recording.cepton_pcap import (PcapError, is_pcap, pcap_recording,
                                                         read_pose_source, skipped_line)
from lidar_sim_ros.compare.recording.scan_curve import Curve, nearest_on_curve, times_on_grid
from lidar_sim_ros.compare.recording.scan_rate import drifting_times
from lidar_sim_ros.compare.recording.fields import (FieldError, flag_counts, flag_lines,
                                                    point_time_ns, resolve_fields,
                                                    return_indices)
from lidar_sim_ros.io import cepton
from lidar_sim_ros.io.bag import (CLOUD_TOPIC, POSE_TOPIC, BagContentError, cloud_count,
                                  iter_clouds, read_material_names, read_poses)
from lidar_sim_ros.core.config import MAX_LASERS, MAX_POSITION_M
from lidar_sim_ros.core.pose import QUAT_NORM_TOL, PoseTrack, valid_pose_mask
from lidar_sim_ros.core.scan import Shots

NS_PER_S = 1_000_000_000
# A per-point time field larger than this cannot be seconds within one frame.
_MAX_FRAME_TIME_S = 2.0
# Per-point time field names of common drivers (matched case-insensitively, in this
# order): ours/Ouster ``t``, Velodyne ``time``, Hesai/Robosense ``timestamp``, Livox
# ``offset_time``, and variants with a unit suffix.
POINT_TIME_FIELDS = ('t', 'time', 'timestamp', 't_ns', 'time_ns', 'timestamp_ns',
                     'offset_time', 'time_offset', 'timeoffset', 't_us', 'time_us',
                     't_ms', 'time_ms', 'time_stamp', 'ts', 'stamp', 't_s', 'time_s')
_UNIT_SUFFIX = {'_ns': 1e-9, '_us': 1e-6, '_ms': 1e-3, '_s': 1.0}
# A time value (s) above this is an absolute clock reading (epoch seconds), not an
# offset within a frame; within ABSOLUTE_MATCH_S of the header stamp it is on the
# stamp's clock.
_ABSOLUTE_MIN_S = 1.0e5
ABSOLUTE_MATCH_S = 60.0
# An absolute clock reading must resolve time within a frame: a float type whose step
# at the clock's value is coarser than this (s) is refused (FLOAT32 epoch seconds step
# by 128 s; FLOAT64 by 2.4e-7 s).
_MAX_CLOCK_STEP_S = 1e-3
# Clouds without ``t``: directions matching the configured scan pattern this closely
# (rad) give each point its shot's time, if this share of the points match.
SCAN_MATCH_TOL_RAD = 2e-4
SCAN_MATCH_MIN_FRACTION = 0.9
# Prediction may evaluate poses slightly outside the recording (a fitted time offset).
PREDICTION_POSE_PAD_S = 0.5
# The pose stream a recording needs (docs/real-data.md): 5 or more samples per sensor
# frame. Around a cloud, an interval between samples longer than the frame's duration over
# MIN_POSES_PER_FRAME, by POSE_INTERVAL_SLACK (stamp jitter), is said in the notes.
MIN_POSES_PER_FRAME = 5
POSE_INTERVAL_SLACK = 1.5
MAX_POINT_RANGE_M = 10_000.0
"""A point farther than this (m) is no lidar return (x = 3e38 is a float32 marker or
garbage): dropped and counted as ``beyond_range``."""
MAX_INVALID_FRACTION = 0.5
"""More than this share of the finite points beyond MAX_POINT_RANGE_M or with a
non-finite time: the field layout is misread, and the bag is refused."""


class MeasurementError(ValueError):
    """The bag cannot be compared: names the bag, topic and what is missing or wrong."""


@dataclass(frozen=True)
class Measurements:
    """All measured points of a bag, flattened over clouds, in bag order.

    xyz_m (N, 3) lidar frame; range_m = |xyz|; directions = xyz / range (unit);
    intensity (N,) in the sensor's own units or None; t_s (N,) absolute time (s since
    ``epoch_s``); t_frame_s (N,) seconds since the point's cloud stamp (0 without a
    ``t`` field); cloud (N,) index of the cloud; laser (N,) ring/laser id (0 if absent).
    ``poses`` answers the target pose at any t_s (padded for prediction).
    """

    bag: Path
    xyz_m: np.ndarray
    range_m: np.ndarray
    directions: np.ndarray
    intensity: np.ndarray | None
    t_s: np.ndarray
    t_frame_s: np.ndarray
    cloud: np.ndarray
    laser: np.ndarray
    has_point_time: bool
    cloud_stamps_s: np.ndarray
    epoch_s: float
    poses: PoseTrack
    material_names: list[str] | None
    notes: list[str] = field(default_factory=list)
    dropped: dict = field(default_factory=dict)
    time_source: str = 'field'      # 'field' (per-point time), 'scan pattern' or 'stamp'
    time_field: dict | None = None  # the time field used: name, type, unit, reference
    saturated: np.ndarray | None = None   # (N,) bool: the sensor flagged the return SATURATED
    field_lines: list[str] = field(default_factory=list)   # what each field was read as
    fields: dict | None = None            # FieldMap.as_dict()
    flag_counts: dict = field(default_factory=dict)   # Cepton flag -> points (before thinning)
    known_misses: int = 0                 # NO_RETURN shots: fired, nothing came back
    # Clouds without a time field: the share of directions within SCAN_MATCH_TOL_RAD of a
    # shot of the configured scan pattern (``with_scan_times``); None with a time field.
    scan_match_fraction: float | None = None
    # Clouds without a time field whose Lissajous runs (1 + eps) fast against the
    # configured one (``scan_rate``): eps; None where the configured rate matched or no
    # rate was recovered.
    scan_rate_error: float | None = None
    # (N,) int: the return index the recording gives each point (a return field, or the
    # Cepton SECOND_RETURN flag: 0 first, 1 later); None without either.
    return_index: np.ndarray | None = None
    time_quantum_s: float = 0.0     # the time field's resolution (s; 0 exact or unknown)

    def __len__(self) -> int:
        return len(self.range_m)

    def subset(self, index: np.ndarray) -> 'Measurements':
        """The measurements restricted to ``index`` (bool mask or integer indices)."""
        pick = {k: getattr(self, k)[index] for k in
                ('xyz_m', 'range_m', 'directions', 't_s', 't_frame_s', 'cloud', 'laser')}
        inten = None if self.intensity is None else self.intensity[index]
        sat = None if self.saturated is None else self.saturated[index]
        ret = None if self.return_index is None else self.return_index[index]
        return Measurements(self.bag, intensity=inten, saturated=sat, return_index=ret,
                            time_quantum_s=self.time_quantum_s,
                            field_lines=self.field_lines, fields=self.fields,
                            flag_counts=self.flag_counts, known_misses=self.known_misses,
                            has_point_time=self.has_point_time,
                            cloud_stamps_s=self.cloud_stamps_s, epoch_s=self.epoch_s,
                            poses=self.poses, material_names=self.material_names,
                            notes=self.notes, dropped=self.dropped,
                            time_source=self.time_source, time_field=self.time_field,
                            scan_match_fraction=self.scan_match_fraction,
                            scan_rate_error=self.scan_rate_error, **pick)


def load_measurements(bag: str | Path, cloud_topic: str = CLOUD_TOPIC,
                      pose_topic: str = POSE_TOPIC, max_points: int | None = None,
                      seed: int = 0, intensity_field: str | None = None,
                      time_field: str | None = None,
                      laser_field: str | None = None,
                      poses_from: str | Path | None = None) -> Measurements:
    """Read clouds and poses from ``bag`` and check that they can be compared.

    ``max_points`` keeps a random (seeded) subset when the bag holds more points, so
    very long recordings stay tractable: clouds are read one at a time and each keeps
    at most its share (max_points / clouds), so the subset spans the whole recording;
    the dropped count is in ``dropped``. ``intensity_field``, ``time_field`` (one name
    or ``SECONDS,SUBSECONDS``) and ``laser_field`` name the fields where the driver's
    names are not recognised (``compare/recording/fields.py``).
    ``bag`` may also be a pcap of a Cepton sensor's packets (``compare/recording/cepton_pcap.py``),
    read as clouds in the SDK3 driver's layout; ``poses_from`` (a bag or a CSV file)
    then holds the poses (and material names), as it may for a bag.
    """
    bag = Path(bag)
    if not bag.exists():
        raise FileNotFoundError(f'bag {bag} does not exist')
    try:
        if is_pcap(bag):
            poses, names, n_clouds, clouds, pcap_stats = pcap_recording(bag, poses_from,
                                                                        pose_topic)
            cloud_topic = f'UDP {bag.name}'
        else:
            pcap_stats = None
            poses, names = (read_pose_source(poses_from, pose_topic) if poses_from
                            else (read_poses(bag, pose_topic), read_material_names(bag)))
            n_clouds = cloud_count(bag, cloud_topic)
            clouds = iter_clouds(bag, cloud_topic)
        first = next(clouds, None)
    except (BagContentError, PcapError) as exc:
        raise MeasurementError(
            f'{exc} (choose the topics with --cloud-topic / --pose-topic)') from None
    if first is None:
        raise MeasurementError(f'bag {bag}: topic {cloud_topic!r} has no messages')
    if len(poses.stamp_ns) == 0:
        raise MeasurementError(f'bag {bag}: topic {pose_topic!r} has no messages')
    notes: list[str] = []
    poses, n_bad_poses = _usable_poses(bag, pose_topic, poses, notes)
    per_cloud = (None if max_points is None
                 else int(np.ceil(max_points / max(n_clouds, 1))))

    fields = first.points.dtype.names or ()
    _check_xyz_fields(first.points.dtype, bag, cloud_topic, 0)
    try:
        fmap = resolve_fields(first.points.dtype, intensity_field, time_field, laser_field,
                              find_time_field)
    except FieldError as exc:
        raise MeasurementError(f'bag {bag}, topic {cloud_topic!r}: {exc}') from None
    t_name = fmap.time_name
    has_t = t_name is not None
    has_i = fmap.intensity is not None
    if not has_t:
        notes.append(f'clouds have no per-point time field (none of {list(POINT_TIME_FIELDS)}, '
                     'no timestamp_s + timestamp_us; name one with --time-field): '
                     'every point takes its cloud stamp')
    if not has_i:
        notes.append('clouds have no "intensity" or "reflectivity" field (name one with '
                     '--intensity-field): the intensity feature uses the model')
    if fmap.intensity not in (None, 'intensity'):
        notes.append(f'intensity read from field {fmap.intensity!r}')
    if fmap.laser not in (None, 'ring'):
        notes.append(f'laser id read from field {fmap.laser!r}')

    time_dtype = ('+'.join(fmap.dtypes[n] for n in fmap.time).lower() if has_t else None)
    cols: dict[str, list] = {k: [] for k in ('xyz', 'i', 't', 'cloud', 'laser', 'sat', 'ret')}
    stamp_ns = []
    n_nonfinite = n_zero = n_thinned = n_invalid = n_no_return = n_far = n_bad_time = 0
    t_kinds: list[str] = []
    counts: dict[str, int] = {}
    for k, c in enumerate(itertools.chain([first], clouds)):
        p = c.points
        stamp_ns.append(c.stamp_ns)
        if len(p) == 0:
            continue
        if k:
            _check_xyz_fields(p.dtype, bag, cloud_topic, k)
        xyz = np.column_stack([np.asarray(p[f], dtype=float).reshape(len(p), -1)[:, 0]
                               for f in ('x', 'y', 'z')])
        flags = (np.asarray(p[fmap.flags]).astype(np.int64) if fmap.flags
                 else np.zeros(len(p), np.int64))
        for name, n in flag_counts(flags).items():
            counts[name] = counts.get(name, 0) + n
        no_return, invalid = not_points(p, fmap)
        n_no_return += int(no_return.sum())
        n_invalid += int((invalid & ~no_return).sum())
        ok = ~(no_return | invalid)
        finite = np.isfinite(xyz).all(axis=1)
        n_nonfinite += int((ok & ~finite).sum())
        ok &= finite
        with np.errstate(over='ignore', invalid='ignore'):
            rng = np.linalg.norm(np.where(finite[:, None], xyz, 0.0), axis=1)
        zero = ok & (rng <= 1e-6)   # drivers report "no return" as (0, 0, 0)
        n_zero += int(zero.sum())
        far = ok & ~(rng <= MAX_POINT_RANGE_M)
        n_far += int(far.sum())
        ok &= ~zero & ~far
        if has_t:
            t_all = np.full(len(p), np.nan)
            try:
                t_all[ok], kind = field_time_since_stamp_s(p[ok], fmap.time, c.stamp_ns)
            except FieldError as exc:
                raise MeasurementError(f'bag {bag}, topic {cloud_topic!r}, cloud #{k}: '
                                       f'{exc}') from None
            t_kinds.append(kind)
            bad_t = ok & ~np.isfinite(t_all)
            n_bad_time += int(bad_t.sum())
            ok &= ~bad_t
        if per_cloud is not None and ok.sum() > per_cloud:
            # The cloud's share of max_points, at random (seeded per cloud).
            keep = np.flatnonzero(ok)
            keep = np.sort(np.random.default_rng([seed, k]).choice(keep, per_cloud, False))
            n_thinned += int(ok.sum()) - per_cloud
            ok = np.zeros(len(ok), bool)
            ok[keep] = True
        cols['xyz'].append(xyz[ok])
        cols['i'].append(np.asarray(p[fmap.intensity], dtype=float)[ok] if has_i
                         else np.zeros(ok.sum()))
        cols['sat'].append((flags[ok] & cepton.SATURATED) != 0)
        if fmap.returns:
            try:
                cols['ret'].append(return_indices(p[fmap.returns][ok], fmap.returns))
            except FieldError as exc:
                raise MeasurementError(f'bag {bag}, topic {cloud_topic!r}, cloud #{k}: '
                                       f'{exc}') from None
        else:
            cols['ret'].append(((flags[ok] & cepton.SECOND_RETURN) != 0).astype(np.int64))
        if has_t:
            cols['t'].append(t_all[ok])
        else:
            cols['t'].append(np.zeros(ok.sum()))
        cols['cloud'].append(np.full(ok.sum(), k))
        cols['laser'].append(laser_ids(p[fmap.laser][ok], fmap.laser, bag, cloud_topic, k)
                             if fmap.laser else np.zeros(ok.sum(), np.int64))
    if pcap_stats is not None and skipped_line(pcap_stats):
        notes.append(skipped_line(pcap_stats))
    total = sum(len(x) for x in cols['xyz'])
    invalid = n_far + n_bad_time
    if invalid > MAX_INVALID_FRACTION * (total + n_thinned + invalid):
        raise MeasurementError(
            f'bag {bag}: {invalid} of {total + n_thinned + invalid} finite points on '
            f'{cloud_topic!r} are unusable ({n_far} beyond {MAX_POINT_RANGE_M:g} m, {n_bad_time} '
            'with a non-finite time): are the field datatypes and is_bigendian right?')
    if total == 0:
        raise MeasurementError(
            f'bag {bag}: all {len(stamp_ns)} cloud(s) on {cloud_topic!r} are empty '
            f'(no finite, non-zero points; {n_nonfinite} non-finite, {n_zero} at the origin)')
    if n_far or n_bad_time:
        notes.append(f'{n_far} point(s) beyond {MAX_POINT_RANGE_M:g} m and {n_bad_time} with a '
                     f'non-finite time on {cloud_topic!r}: dropped')
    xyz = np.vstack(cols['xyz'])
    t_frame = np.concatenate(cols['t'])
    time_field = None
    time_read: list[str] = []
    if has_t:
        kinds = sorted(set(t_kinds))
        time_field = {'name': t_name, 'dtype': time_dtype, 'read_as': kinds}
        if kinds != ['s since stamp'] or t_name != 't':
            notes.append(f'per-point time from field {t_name!r} '
                         f'({time_dtype}): read as {", ".join(kinds)}')
            # On the terminal too: "on another clock" changes what the times mean.
            time_read = [f'  point time read as: {", ".join(kinds)}']
    cloud = np.concatenate(cols['cloud'])
    epoch_ns = int(min(int(poses.stamp_ns[0]), min(stamp_ns)))
    stamps_s = (np.asarray(stamp_ns, np.int64) - epoch_ns) / NS_PER_S
    t_abs = stamps_s[cloud] + t_frame

    pose_t = (poses.stamp_ns - epoch_ns) / NS_PER_S
    track = _checked_pose_track(bag, pose_topic, cloud_topic, pose_t, poses.position_m,
                                poses.quat_xyzw, t_abs, cloud, stamps_s, notes)
    intensity = np.concatenate(cols['i']) if has_i else None
    if intensity is not None and not np.any(np.isfinite(intensity) & (intensity > 0)):
        notes.append('intensity field holds no positive values: ignored')
        intensity = None
    rng = np.linalg.norm(xyz, axis=1)
    dropped = {'non_finite': n_nonfinite, 'at_origin': n_zero, 'subsampled': n_thinned,
               'beyond_range': n_far, 'bad_time': n_bad_time, 'bad_poses': n_bad_poses,
               **({'invalid': n_invalid} if fmap.valid else {}),
               **({'no_return': n_no_return} if fmap.flags else {})}
    saturated = np.concatenate(cols['sat'])
    return_index = (np.concatenate(cols['ret']) if fmap.returns or fmap.flags else None)
    lines = fmap.lines() + time_read + flag_lines(fmap, counts, n_no_return, n_invalid)
    if n_thinned:
        notes.append(f'{len(rng) + n_thinned} points in {len(stamp_ns)} clouds: at most '
                     f'{per_cloud} per cloud are analysed, at random')
    keep = np.arange(len(rng))
    if max_points is not None and len(rng) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(rng), max_points, replace=False))
        dropped['subsampled'] = n_thinned + len(rng) - max_points
        notes.append(f'{len(rng)} points: a random subset of {max_points} is analysed')
    return Measurements(
        bag=bag, xyz_m=xyz[keep], range_m=rng[keep], directions=xyz[keep] / rng[keep, None],
        intensity=None if intensity is None else intensity[keep], t_s=t_abs[keep],
        t_frame_s=t_frame[keep], cloud=cloud[keep],
        laser=np.concatenate(cols['laser'])[keep].astype(np.uint16), has_point_time=has_t,
        cloud_stamps_s=stamps_s, epoch_s=epoch_ns / NS_PER_S, poses=track,
        material_names=names, notes=notes, dropped=dropped,
        time_source='field' if has_t else 'stamp', time_field=time_field,
        saturated=saturated[keep] if fmap.flags else None, field_lines=lines,
        fields=fmap.as_dict(), flag_counts=counts, known_misses=n_no_return,
        return_index=None if return_index is None else return_index[keep],
        time_quantum_s=time_quantum_s(first.points, fmap.time) if has_t else 0.0)


def time_quantum_s(points: np.ndarray, time: tuple[str, ...]) -> float:
    """The resolution (s) of the point-time field(s) in ``points`` (the first cloud): a
    pair's sub-seconds unit; an integer field's unit (its name's suffix, else ns); a
    float field's spacing at its largest value (FLOAT32 seconds near 0.1 s: 7.5 ns).
    Two returns of one shot carry one time, up to this."""
    if len(time) == 2:
        sub = time[1].lower()
        return next((1.0 / u for k, u in (('_ms', 1e3), ('_us', 1e6), ('_ns', 1e9))
                     if sub.endswith(k)), 1e-3)
    raw = np.asarray(points[time[0]])
    suffix = next((sfx for sfx in _UNIT_SUFFIX if time[0].lower().endswith(sfx)
                   and time[0].lower() != sfx.lstrip('_')), None)
    if raw.dtype.kind in 'iu':
        return _UNIT_SUFFIX[suffix] if suffix else 1e-9
    scale = _UNIT_SUFFIX[suffix] if suffix else 1.0
    finite = raw[np.isfinite(raw)]
    top = float(np.max(np.abs(finite))) if len(finite) else 0.0
    return float(np.spacing(raw.dtype.type(top))) * scale


def laser_ids(values: np.ndarray, name: str, bag: Path, topic: str, k: int) -> np.ndarray:
    """One cloud's laser field as int64 ids, each a whole number in [0, MAX_LASERS);
    MeasurementError naming the bag, topic, cloud, field and value otherwise (a channel_id
    of 60000 gave laser_bias 60,024 offsets; -1 wrapped to 65535)."""
    v = np.asarray(values)
    if v.dtype.kind == 'f':
        bad = ~np.isfinite(v) | (v != np.round(v))
        v = np.where(bad, -1, v)
    else:
        bad = np.zeros(len(v), bool)
    ids = v.astype(np.int64)
    bad |= (ids < 0) | (ids >= MAX_LASERS)
    if bad.any():
        first = np.asarray(values)[bad][0]
        raise MeasurementError(
            f'bag {bag}, topic {topic!r}, cloud #{k}: laser field {name!r} = {first} '
            f'({int(bad.sum())} point(s)): laser ids must be whole numbers in [0, {MAX_LASERS}) '
            '(name another field with --laser-field)')
    return ids


def _check_xyz_fields(dtype: np.dtype, bag: Path, topic: str, k: int) -> None:
    """x, y, z must be present and floating point (metres): ``x`` declared uint8 read
    the bytes of a float as small integers, and compare blamed range_rate."""
    fields = dtype.names or ()
    missing = [f for f in ('x', 'y', 'z') if f not in fields]
    if missing:
        raise MeasurementError(
            f'bag {bag}: clouds on {topic!r} lack field(s) {missing}; fields present: '
            f'{list(fields)} (x, y, z in metres, lidar frame, are required)')
    not_float = [f'{f} ({dtype[f].base})' for f in ('x', 'y', 'z') if dtype[f].kind != 'f']
    if not_float:
        raise MeasurementError(
            f'bag {bag}: cloud #{k} on {topic!r} declares {", ".join(not_float)}: x, y, z must '
            'be FLOAT32 or FLOAT64 (metres)')


def _usable_poses(bag: Path, topic: str, poses, notes: list[str]):
    """The pose samples with a finite position within 100 km and a unit quaternion (within
    QUAT_NORM_TOL, then normalised); the others are dropped, counted and noted."""
    ok = valid_pose_mask(poses.position_m, poses.quat_xyzw)
    n_bad = int((~ok).sum())
    if n_bad == len(ok):
        raise MeasurementError(
            f'bag {bag}: none of the {len(ok)} pose(s) on {topic!r} is usable (finite position '
            f'within {MAX_POSITION_M:g} m, quaternion norm within {QUAT_NORM_TOL:g} of 1); '
            f'first: position '
            f'{poses.position_m[0].tolist()}, quat_xyzw {poses.quat_xyzw[0].tolist()}')
    if n_bad:
        k = int(np.flatnonzero(~ok)[0])
        notes.append(f'{n_bad} of {len(ok)} pose(s) on {topic!r} dropped (non-finite, a '
                     f'position beyond {MAX_POSITION_M:g} m, or quaternion norm not within '
                     f'{QUAT_NORM_TOL:g} of 1), first #{k}: position '
                     f'{poses.position_m[k].tolist()}, quat_xyzw {poses.quat_xyzw[k].tolist()}')
    quat = poses.quat_xyzw[ok]
    return replace(poses, stamp_ns=poses.stamp_ns[ok], position_m=poses.position_m[ok],
                   quat_xyzw=quat / np.linalg.norm(quat, axis=1, keepdims=True)), n_bad


def with_scan_times(meas: Measurements, shots: Shots,
                    shots_of_frame: Callable[[int], Shots] | None = None,
                    frame_period_s: float | None = None,
                    clocks_s: tuple[float, ...] = (0.0,),
                    curve: Curve | None = None, interval_s: float | None = None,
                    figure_period_s: float | None = None) -> Measurements:
    """Point times from the sensor's scan pattern, for clouds without a time field.

    Each measured direction is matched to the nearest shot of the configured frame
    pattern; if nearly all match within SCAN_MATCH_TOL_RAD (the recording comes from
    that pattern, stamped at frame start), the points take their shots' times (and
    lasers). Otherwise the cloud stamp stays every point's time. A pattern that differs
    from frame to frame (the Risley rosette) gives ``shots_of_frame`` and the frame
    period: each cloud is matched to the shots of its own frame, round((stamp - clock) /
    period), on the clock (one of ``clocks_s``, s) whose frames match the first cloud best:
    the node counts frames from ROS time 0, ``lidar-sim simulate`` from its epoch.
    A pattern with a continuous ``curve`` (laser, t) -> (az, el) and a shot interval per
    laser ``interval_s`` is matched to the curve, not only to our sampled shots
    (``scan_curve``): shots fired at other instants of it (a start phase, lasers firing
    together) take the time on the curve, if each laser's times in a cloud sit on one
    grid of that interval. If they do not, a pattern running a little fast or slow
    (frequencies x (1 + eps), the same closed figure of period ``figure_period_s``) is
    looked for (``scan_rate.drifting_times``): its times come from the curve, and eps is
    kept in ``scan_rate_error`` and the notes.
    """
    if meas.time_source != 'stamp' or len(shots) == 0:
        return meas
    rate, rate_note = None, ''
    if (shots_of_frame is None or not frame_period_s) and curve is not None and interval_s:
        cands = nearest_on_curve(meas.directions, shots, curve, interval_s)
        ok, t_shot, laser_shot = times_on_grid(*cands, meas.cloud, SCAN_MATCH_TOL_RAD,
                                               interval_s)
        if ok.mean() < SCAN_MATCH_MIN_FRACTION and frame_period_s:
            dist, t_curve, laser_c, _ = cands
            found, why = drifting_times(dist, t_curve, laser_c, meas.cloud, SCAN_MATCH_TOL_RAD,
                                        interval_s, figure_period_s or float('inf'),
                                        frame_period_s)
            if found is not None and found[0].mean() >= SCAN_MATCH_MIN_FRACTION:
                ok, t_shot, laser_shot, rate, each = found
                spread = float(np.nanmax(np.abs(each - rate))) if np.isfinite(each).any() else 0.0
                rate_note = (f'the pattern runs {100 * abs(rate):.2f} % '
                             f'{"fast" if rate > 0 else "slow"}: times from its curve (its '
                             f'frequencies x {1 + rate:.5f} trace the configured figure; the '
                             f'clouds agree within {100 * spread:.4f} %); ')
            elif found is None:
                rate_note = f' (no rate error recovers it: {why})'
    elif shots_of_frame is None or not frame_period_s:
        dist, idx = cKDTree(shots.directions()).query(meas.directions)
        ok = dist < SCAN_MATCH_TOL_RAD
        t_shot, laser_shot = shots.t_s[idx], shots.laser[idx]
    else:
        first = np.flatnonzero(meas.cloud == meas.cloud.min())
        clock = max(clocks_s, key=lambda c: _match_each_frame(meas, shots_of_frame, frame_period_s,
                                                              c, first)[0].mean())
        ok, t_shot, laser_shot = _match_each_frame(meas, shots_of_frame, frame_period_s, clock)
    if ok.mean() < SCAN_MATCH_MIN_FRACTION and shots_of_frame is None \
            and np.ptp(shots.t_s) == 0.0:
        # One global exposure (a flash without a row readout): every shot is at the
        # frame's start, so each point's time is its cloud stamp whatever its direction;
        # a pixel grid that differs from the configured one says nothing about timing.
        return replace(meas, t_frame_s=np.zeros(len(meas.cloud)),
                       t_s=meas.cloud_stamps_s[meas.cloud].astype(float),
                       has_point_time=True, time_source='scan pattern',
                       notes=[n for n in meas.notes if 'no per-point time field' not in n] + [
                           'clouds have no per-point time field; the scan pattern is one '
                           'global exposure, so every point is at its cloud stamp (only '
                           f'{100 * ok.mean():.0f} % of the directions match a pixel of the '
                           'configured grid: the lasers stay as recorded)'])
    if ok.mean() < SCAN_MATCH_MIN_FRACTION:
        return replace(meas, scan_match_fraction=float(ok.mean()), notes=meas.notes + [
            f'clouds have no per-point time field and only {100 * ok.mean():.0f} % of the '
            'directions match the configured scan pattern: every point takes its cloud stamp'
            + rate_note])
    t_frame = np.where(ok, t_shot, np.median(t_shot[ok]))
    laser = np.where(ok, laser_shot, meas.laser).astype(np.uint16)
    notes = [n for n in meas.notes if 'no per-point time field' not in n] + [
        f'clouds have no per-point time field: {rate_note}point times taken from the scan '
        f'pattern ({100 * ok.mean():.1f} % of directions match a shot within '
        f'{np.degrees(SCAN_MATCH_TOL_RAD):g} deg)']
    return replace(meas, t_frame_s=t_frame, t_s=meas.cloud_stamps_s[meas.cloud] + t_frame,
                   laser=laser, has_point_time=True, time_source='scan pattern', notes=notes,
                   scan_match_fraction=float(ok.mean()), scan_rate_error=rate)


def _match_each_frame(meas: Measurements, shots_of_frame: Callable[[int], Shots],
                      frame_period_s: float, clock_s: float,
                      only: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per point (of ``only``, None: all): matched within tolerance, its shot's time (s) and
    laser, each cloud against the shots of frame round((stamp - clock_s) / period)."""
    cloud = meas.cloud if only is None else meas.cloud[only]
    directions = meas.directions if only is None else meas.directions[only]
    n = len(cloud)
    ok, t_shot, laser_shot = np.zeros(n, bool), np.zeros(n), np.zeros(n, np.uint16)
    for c in np.unique(cloud):
        rows = np.flatnonzero(cloud == c)
        k = int(round(((meas.epoch_s - clock_s) + float(meas.cloud_stamps_s[c])) / frame_period_s))
        shots = shots_of_frame(k)
        dist, idx = cKDTree(shots.directions()).query(directions[rows])
        ok[rows] = dist < SCAN_MATCH_TOL_RAD
        t_shot[rows], laser_shot[rows] = shots.t_s[idx], shots.laser[idx]
    return ok, t_shot, laser_shot


def field_time_since_stamp_s(points: np.ndarray, time: tuple[str, ...],
                             stamp_ns: int) -> tuple[np.ndarray, str]:
    """Seconds since the stamp from the time field(s) of ``FieldMap.time``: one field
    (``point_time_since_stamp_s``) or a seconds + sub-seconds pair (exact integer ns)."""
    if len(time) == 2:
        raw_ns, sub_unit = point_time_ns(points, time)
        t_rel, kind = point_time_since_stamp_s(raw_ns, 'time_ns', stamp_ns)
        return t_rel, kind.replace('ns', f's + {sub_unit}', 1)
    return point_time_since_stamp_s(points[time[0]], time[0], stamp_ns)


def not_points(points: np.ndarray, fmap) -> tuple[np.ndarray, np.ndarray]:
    """Bool per point: a NO_RETURN shot (Cepton flags: a known miss, not a point), and
    ``valid`` = 0 (SDK2)."""
    none = np.zeros(len(points), bool)
    no_return = ((np.asarray(points[fmap.flags]).astype(np.int64) & cepton.NO_RETURN) != 0
                 if fmap.flags else none)
    invalid = np.asarray(points[fmap.valid]) == 0 if fmap.valid else none
    return no_return, invalid


def usable_points(points: np.ndarray, fmap) -> np.ndarray:
    """Bool per point: neither a NO_RETURN shot nor ``valid`` = 0 (``not_points``)."""
    no_return, invalid = not_points(points, fmap)
    return ~(no_return | invalid)


def find_time_field(fields) -> str | None:
    """The per-point time field among ``fields`` (POINT_TIME_FIELDS, any case), or None."""
    by_lower = {f.lower(): f for f in fields}
    return next((by_lower[n] for n in POINT_TIME_FIELDS if n in by_lower), None)


def point_time_since_stamp_s(raw: np.ndarray, name: str,
                             stamp_ns: int) -> tuple[np.ndarray, str]:
    """One cloud's per-point time field as seconds since its header stamp, and how it
    was read (e.g. ``'ns since stamp'``, ``'absolute s'``).

    Unit: a ``_ns``/``_us``/``_ms``/``_s`` suffix of the name, else integer = ns and
    float = s. Absolute or relative by magnitude: a value above a day's worth of
    seconds is a clock reading; on the stamp's clock (within ABSOLUTE_MATCH_S) the
    stamp is subtracted, on another clock the cloud's earliest point is taken as the
    stamp. Relative values too large for one frame are read in a finer unit. An absolute
    reading in a float type too coarse at its value (``_MAX_CLOCK_STEP_S``) is a
    FieldError.
    """
    raw = np.asarray(raw)
    if len(raw) == 0:
        return np.zeros(0), 's since stamp'
    integer = raw.dtype.kind in 'iu'
    suffix = next((sfx for sfx in _UNIT_SUFFIX if name.lower().endswith(sfx)
                   and name.lower() != sfx.lstrip('_')), None)
    scale = _UNIT_SUFFIX[suffix] if suffix else (1e-9 if integer else 1.0)
    unit = {1e-9: 'ns', 1e-6: 'us', 1e-3: 'ms', 1.0: 's'}[scale]
    finite = np.isfinite(raw.astype(float))
    typical_s = float(np.median(np.abs(raw[finite].astype(float)))) * scale if finite.any() else 0.0
    if typical_s > _ABSOLUTE_MIN_S:
        step_s = 0.0 if integer else float(np.spacing(raw.dtype.type(typical_s / scale))) * scale
        if step_s > _MAX_CLOCK_STEP_S:
            raise FieldError(f'{name} holds absolute clock readings (about {typical_s:.6g} s) in '
                             f'{raw.dtype.name}, whose steps there are {step_s:g} s: the points\' '
                             'times cannot be read (write them as FLOAT64, integer ns, or '
                             'time since the cloud stamp)')
        if integer and scale == 1e-9:     # exact integer arithmetic: ns clocks exceed float64
            since = (raw.astype(np.int64) - np.int64(stamp_ns)).astype(float) * 1e-9
        else:
            since = raw.astype(float) * scale - stamp_ns / NS_PER_S
        span_s = float(np.nanmax(since) - np.nanmin(since)) if finite.any() else 0.0
        if span_s > _MAX_FRAME_TIME_S:
            raise FieldError(f'{name} holds absolute clock readings spread over {span_s:.6g} s '
                             f'in one cloud: one frame lasts at most {_MAX_FRAME_TIME_S:g} s')
        if np.nanmedian(np.abs(since)) <= ABSOLUTE_MATCH_S:
            return since, f'absolute {unit}'
        first = np.nanmin(raw[finite].astype(float)) if finite.any() else 0.0
        return ((raw.astype(float) - first) * scale,
                f'absolute {unit} on another clock (cloud stamp = first point)')
    t = raw.astype(float) * scale
    span = float(np.nanmax(np.abs(t))) if finite.any() else 0.0
    if span <= _MAX_FRAME_TIME_S:
        return t, f'{unit} since stamp'
    for finer, finer_unit in ((1e-3, 'ms'), (1e-6, 'us'), (1e-9, 'ns')):
        if finer < scale and span * finer / scale <= _MAX_FRAME_TIME_S:
            return t * finer / scale, f'{finer_unit} since stamp'
    return t * 1e-9 / scale, 'ns since stamp'


def _checked_pose_track(bag: Path, pose_topic: str, cloud_topic: str, pose_t: np.ndarray,
                        position_m: np.ndarray, quat_xyzw: np.ndarray, t_abs: np.ndarray,
                        cloud: np.ndarray, stamps_s: np.ndarray, notes: list[str]) -> PoseTrack:
    """The pose track, after checking it covers every cloud; padded for prediction.

    A cloud is covered when its stamp lies within the pose samples; its points may run
    past the last pose by at most the cloud's own duration (poses stamped once per
    cloud are common), where the pose is extrapolated with the last velocity.
    """
    pose_t, first = np.unique(pose_t, return_index=True)
    position_m, quat_xyzw = position_m[first], quat_xyzw[first]
    if len(pose_t) == 1:
        notes.append(f'only one pose on {pose_topic!r}: the target is taken as static')
        lo, hi = min(t_abs.min(), pose_t[0]), max(t_abs.max(), pose_t[0])
        pose_t = np.array([lo - 1.0, hi + 1.0])
        position_m = np.repeat(position_m, 2, axis=0)
        quat_xyzw = np.repeat(quat_xyzw, 2, axis=0)
    start, end = float(pose_t[0]), float(pose_t[-1])
    n_clouds = len(stamps_s)
    t_lo = np.full(n_clouds, np.inf)
    t_hi = np.full(n_clouds, -np.inf)
    np.minimum.at(t_lo, cloud, t_abs)
    np.maximum.at(t_hi, cloud, t_abs)
    eps = 1e-6
    # Points before the first pose, or a cloud starting after the last pose.
    bad = np.isfinite(t_lo) & ((t_lo < start - eps) | (np.minimum(stamps_s, t_lo) > end + eps))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise MeasurementError(
            f'bag {bag}: poses on {pose_topic!r} cover [{start:.6f}, {end:.6f}] s but '
            f'{int(bad.sum())} of {n_clouds} cloud(s) on {cloud_topic!r} fall outside, first '
            f'cloud #{k} with points at [{t_lo[k]:.6f}, {t_hi[k]:.6f}] s '
            f'(times relative to the earliest stamp in the bag)')
    over = float(max(0.0, t_abs.max() - end))
    if over > 0:
        notes.append(f'last cloud runs {over * 1e3:.1f} ms past the last pose: extrapolated')
    sparse = sparse_pose_note(pose_t, t_lo, t_hi, pose_topic)
    if sparse:
        notes.append(sparse)
    return padded_pose_track(pose_t, position_m, quat_xyzw, PREDICTION_POSE_PAD_S + over)


def sparse_pose_note(pose_t: np.ndarray, t_lo: np.ndarray, t_hi: np.ndarray,
                     pose_topic: str) -> str | None:
    """A note when the pose samples around some cloud are sparser than MIN_POSES_PER_FRAME
    per frame (an interval between consecutive samples overlapping the cloud's points longer
    than the median cloud duration over MIN_POSES_PER_FRAME, by POSE_INTERVAL_SLACK): the
    pose there is interpolated, and a pose error the comparison finds may be the
    interpolation's. None when every cloud is covered densely enough, or with one pose."""
    seen = np.isfinite(t_lo) & np.isfinite(t_hi)
    if len(pose_t) < 2 or not seen.any():
        return None
    frame_s = float(np.median(t_hi[seen] - t_lo[seen]))
    if frame_s <= 0:
        return None
    limit = POSE_INTERVAL_SLACK * frame_s / MIN_POSES_PER_FRAME
    step = np.diff(pose_t)
    # Interval k runs from pose_t[k] to pose_t[k + 1]; the cloud's points lie in the
    # intervals first .. last (clipped to the samples: extrapolation is noted apart).
    first = np.clip(np.searchsorted(pose_t, t_lo[seen], 'right') - 1, 0, len(step) - 1)
    last = np.clip(np.searchsorted(pose_t, t_hi[seen], 'left') - 1, 0, len(step) - 1)
    longest = np.array([step[a:b + 1].max() for a, b in zip(first, np.maximum(first, last))])
    sparse = longest > limit
    if not sparse.any():
        return None
    clouds = np.flatnonzero(seen)
    k = int(np.argmax(longest))
    return (f'poses on {pose_topic!r} are sparser than {MIN_POSES_PER_FRAME} per frame around '
            f'{int(sparse.sum())} of {len(clouds)} cloud(s) (the longest interval between '
            f'samples {longest[k] * 1e3:.0f} ms, around cloud #{int(clouds[k])}; frames last '
            f'{frame_s * 1e3:.0f} ms): the pose is interpolated there, and a pose error found '
            'may be the interpolation\'s, not the tracking system\'s')


def padded_pose_track(t_s: np.ndarray, position_m: np.ndarray, quat_xyzw: np.ndarray,
                      pad_s: float) -> PoseTrack:
    """A PoseTrack that also answers up to ``pad_s`` before the first and after the last
    sample, extrapolating with the end velocities (a fitted clock offset needs this)."""
    t = np.asarray(t_s, float)
    pos = np.asarray(position_m, float)
    rot = Rotation.from_quat(quat_xyzw)
    if len(t) >= 2 and pad_s > 0:
        dt = t[1] - t[0]
        v0 = (pos[1] - pos[0]) / dt
        w0 = (rot[1] * rot[0].inv()).as_rotvec() / dt
        pre_rot = Rotation.from_rotvec(-w0 * pad_s) * rot[0]
        t = np.concatenate([[t[0] - pad_s], t])
        pos = np.vstack([pos[0] - v0 * pad_s, pos])
        quat = np.vstack([pre_rot.as_quat()[None, :], rot.as_quat()])
    else:
        quat = rot.as_quat()
    return PoseTrack(t, pos, quat, max_extrapolation_s=pad_s)
