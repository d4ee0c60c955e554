"""A recording's shots for the scan fits (``scan_pattern.py``: Lissajous lasers,
``scan_risley.py``: a rosette's prisms): each point's direction, time since its frame stamp,
laser and frame."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar_sim_ros.calibrate.common import CalibrationInputError
from lidar_sim_ros.compare.recording.fields import FieldError, resolve_fields
from lidar_sim_ros.compare.recording.measurements import (field_time_since_stamp_s,
                                                          find_time_field, laser_ids,
                                                          usable_points)
from lidar_sim_ros.core.scan import angles_from_directions
from lidar_sim_ros.io.bag import CLOUD_TOPIC, BagContentError, read_clouds


@dataclass(frozen=True)
class ScanSamples:
    """Measured shots: time since frame start (s), pointing (rad), unit direction, laser, frame."""

    t_s: np.ndarray
    az_rad: np.ndarray
    el_rad: np.ndarray
    direction: np.ndarray
    laser: np.ndarray | None
    frame: np.ndarray
    frame_period_s: float | None
    source: str
    frame_start_s: np.ndarray | None = None   # each cloud's stamp, s since the first one

    def __len__(self) -> int:
        return len(self.t_s)


def read_scan_samples(bag: str | Path, topic: str = CLOUD_TOPIC,
                      fields: dict | None = None) -> ScanSamples:
    """Points of every cloud with their time since the frame stamp (and laser id, if present).

    Fields are read as ``lidar-sim compare`` reads them (``compare/recording/fields.py``): ``t`` or
    another driver's time field, the Cepton pair ``timestamp_s`` + ``timestamp_us``;
    ``ring``, ``channel_id`` or an alias; NO_RETURN and ``valid`` = 0 points dropped;
    ``fields`` names them (--time-field, --laser-field). Raises CalibrationInputError
    naming bag, topic and fields when x, y, z or the time is missing or no finite point
    is left. The frame period is the median header stamp step (None with a single cloud).
    """
    try:
        clouds = read_clouds(bag, topic)
    except BagContentError as exc:
        raise CalibrationInputError(f'{exc} (choose the topic with --cloud-topic)') from None
    src = f'bag {bag}, topic {topic!r}'
    if not clouds:
        raise CalibrationInputError(f'{src}: no messages')
    names = clouds[0].points.dtype.names or ()
    try:
        fmap = resolve_fields(clouds[0].points.dtype, find_time=find_time_field,
                              **(fields or {}))
    except FieldError as exc:
        raise CalibrationInputError(f'{src}: {exc}') from None
    missing = [f for f in ('x', 'y', 'z') if f not in names] + ([] if fmap.time else ['t'])
    if missing:
        raise CalibrationInputError(f'{src}: point field(s) {missing} missing (fields: '
                                    f'{list(names)}); the scan fit needs x, y, z and the per-point '
                                    'time t since the frame stamp (or the Cepton timestamp_s + '
                                    'timestamp_us, or --time-field)')
    ring_field = fmap.laser
    cols = {k: [] for k in ('x', 'y', 'z', 't', 'ring', 'frame')}
    for i, c in enumerate(clouds):
        p = c.points[usable_points(c.points, fmap)]
        for k in ('x', 'y', 'z'):
            cols[k].append(np.asarray(p[k], dtype=float))
        try:
            cols['t'].append(field_time_since_stamp_s(p, fmap.time, c.stamp_ns)[0]
                             if len(p) else np.zeros(0))
        except FieldError as exc:
            raise CalibrationInputError(f'{src}, cloud #{i}: {exc}') from None
        if ring_field:
            cols['ring'].append(laser_ids(p[ring_field], ring_field, bag, topic, i))
        cols['frame'].append(np.full(len(p), i))
    a = {k: np.concatenate(v) for k, v in cols.items() if v}
    xyz = np.column_stack([a['x'], a['y'], a['z']])
    norm = np.linalg.norm(xyz, axis=1)
    ok = np.isfinite(norm) & (norm > 0) & np.isfinite(a['t'])
    if ok.sum() == 0:
        raise CalibrationInputError(f'{src}: no finite non-zero point')
    direction = xyz[ok] / norm[ok, None]
    az, el = angles_from_directions(direction)
    stamps = np.array([c.stamp_ns for c in clouds], dtype=float)
    period = float(np.median(np.diff(np.sort(stamps)))) * 1e-9 if len(clouds) > 1 else None
    starts = np.array([(c.stamp_ns - clouds[0].stamp_ns) * 1e-9 for c in clouds])
    return ScanSamples(a['t'][ok], az, el, direction, a['ring'][ok] if ring_field else None,
                       a['frame'][ok], period if period and period > 0 else None, src, starts)
