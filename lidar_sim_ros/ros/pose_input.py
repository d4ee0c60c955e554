"""Pose input of the node, free of rclpy: validate samples, keep a bounded history.

A pose sample is the target body pose in the lidar frame (``p_lidar = R p_body +
position``, see ``core.pose``) at a header stamp, from ``geometry_msgs/PoseStamped``
or ``nav_msgs/Odometry``. ``check_pose`` accepts it or names why not; accepted
samples go into a ``PoseHistory``, from which the node builds the ``PoseTrack`` that
every shot of a frame is posed with.
"""
from __future__ import annotations

import time

from collections import deque
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import MAX_APPROACH_SPEED_MPS, MAX_POSITION_M, MAX_TUMBLE_RATE_DPS
from lidar_sim_ros.core.pose import QUAT_NORM_TOL, PoseTrack  # noqa: F401 - one tolerance

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class PoseSample:
    """One pose at ``stamp_ns`` (node clock, ns).

    velocity_mps / angular_velocity_rad_s: optional rates in the lidar frame (from
    Odometry twist) used to extrapolate past the newest sample.
    """

    stamp_ns: int
    frame_id: str
    position_m: np.ndarray
    quat_xyzw: np.ndarray
    velocity_mps: np.ndarray | None = None
    angular_velocity_rad_s: np.ndarray | None = None

    @property
    def t_s(self) -> float:
        return self.stamp_ns / NS_PER_S


class Rejection(NamedTuple):
    """Why a sample was dropped: ``kind`` is a short key (for throttling), ``reason`` the text."""

    kind: str
    reason: str


def check_pose(sample: PoseSample, frame_id: str, last_stamp_ns: int | None, now_ns: int,
               stale_timeout_s: float) -> tuple[PoseSample | None, Rejection | None]:
    """Validate a sample; return (sample with unit quaternion, None) or (None, rejection).

    Rejected: wrong frame_id; non-finite position, quaternion or twist; a position beyond
    MAX_POSITION_M (100 km), a twist beyond 10 km/s or 3600 deg/s per axis; a quaternion
    whose norm is off 1 by more than QUAT_NORM_TOL (zero included); a stamp not after
    ``last_stamp_ns`` (the newest accepted one); a stamp more than ``stale_timeout_s``
    behind ``now_ns`` (stale) or ahead of it (from the future).
    """
    if sample.frame_id != frame_id:
        return None, Rejection('frame_id', f'frame_id {sample.frame_id!r} is not the node '
                                           f'frame_id {frame_id!r}')
    pos = np.asarray(sample.position_m, dtype=float)
    if pos.shape != (3,) or not np.isfinite(pos).all():
        return None, Rejection('position', f'position {pos.tolist()} is not finite')
    if np.abs(pos).max() > MAX_POSITION_M:
        return None, Rejection('position', f'position {pos.tolist()} is beyond '
                                           f'{MAX_POSITION_M:g} m')
    quat = np.asarray(sample.quat_xyzw, dtype=float)
    if quat.shape != (4,) or not np.isfinite(quat).all():
        return None, Rejection('quaternion', f'quaternion {quat.tolist()} is not finite')
    norm = float(np.linalg.norm(quat))
    if norm == 0.0:
        return None, Rejection('quaternion_zero', 'quaternion is zero')
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        return None, Rejection('quaternion_norm', f'quaternion norm {norm:.6g} is far from 1 '
                                                  f'(tolerance {QUAT_NORM_TOL:g})')
    for name, limit in (('velocity_mps', MAX_APPROACH_SPEED_MPS),
                        ('angular_velocity_rad_s', np.radians(MAX_TUMBLE_RATE_DPS))):
        rate = getattr(sample, name)
        if rate is None:
            continue
        rate = np.asarray(rate, dtype=float)
        if not np.isfinite(rate).all():
            return None, Rejection('twist', f'{name} {rate.tolist()} is not finite')
        if np.abs(rate).max() > limit:
            return None, Rejection('twist', f'{name} {rate.tolist()} is beyond {limit:.6g} '
                                            'per axis')
    if last_stamp_ns is not None and sample.stamp_ns <= last_stamp_ns:
        return None, Rejection('stamp_order', f'stamp {_fmt_ns(sample.stamp_ns)} s is not after '
                                              f'the last accepted stamp {_fmt_ns(last_stamp_ns)} s')
    age_s = (now_ns - sample.stamp_ns) / NS_PER_S
    if age_s > stale_timeout_s:
        return None, Rejection('stale', f'stale: stamp {_fmt_ns(sample.stamp_ns)} s is {age_s:.3f} s '
                                        f'old (stale_pose_timeout_s {stale_timeout_s:g})')
    if -age_s > stale_timeout_s:
        return None, Rejection('future', f'stamp {_fmt_ns(sample.stamp_ns)} s is {-age_s:.3f} s '
                                         f'ahead of the clock (limit {stale_timeout_s:g} s)')
    return replace(sample, position_m=pos, quat_xyzw=quat / norm), None


def twist_to_lidar(quat_xyzw: np.ndarray, linear_body_mps: np.ndarray,
                   angular_body_rad_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Odometry twist (child = target body frame, nav_msgs convention) -> lidar frame."""
    rot = Rotation.from_quat(np.asarray(quat_xyzw, dtype=float))
    return rot.apply(np.asarray(linear_body_mps, dtype=float)), rot.apply(
        np.asarray(angular_body_rad_s, dtype=float))


def _fmt_ns(ns: int) -> str:
    sec, rem = divmod(int(ns), NS_PER_S)
    return f'{sec}.{rem:09d}'


class PoseHistory:
    """Accepted samples in stamp order, bounded to the newest ``keep_s`` seconds.

    ``track(epoch_ns, ...)`` returns a ``PoseTrack`` whose times are seconds since
    ``epoch_ns``: seconds since the epoch of a wall clock (~1.7e9) would cost float64
    resolution in the interpolation, so the node passes the frame start.
    """

    def __init__(self, keep_s: float = 5.0, max_samples: int = 5000):
        self.keep_ns = int(keep_s * NS_PER_S)
        self._samples: deque[PoseSample] = deque(maxlen=max_samples)

    def __len__(self) -> int:
        return len(self._samples)

    @property
    def start_ns(self) -> int | None:
        return self._samples[0].stamp_ns if self._samples else None

    @property
    def end_ns(self) -> int | None:
        return self._samples[-1].stamp_ns if self._samples else None

    def add(self, sample: PoseSample) -> None:
        """Append a sample checked by ``check_pose`` (stamps strictly increasing)."""
        if self._samples and sample.stamp_ns <= self._samples[-1].stamp_ns:
            raise ValueError(f'pose stamp {sample.stamp_ns} ns is not after {self.end_ns} ns')
        self._samples.append(sample)
        oldest = sample.stamp_ns - self.keep_ns
        while len(self._samples) > 2 and self._samples[1].stamp_ns <= oldest:
            self._samples.popleft()

    def clear(self) -> None:
        self._samples.clear()

    def covers(self, start_ns: int, end_ns: int, max_extrapolation_s: float) -> bool:
        """Whether [start_ns, end_ns] lies within the samples plus the extrapolation."""
        if not self._samples:
            return False
        return (start_ns >= self.start_ns
                and end_ns <= self.end_ns + round(max_extrapolation_s * NS_PER_S))

    def max_gap_ns(self, start_ns: int, end_ns: int) -> int:
        """Longest interval between consecutive samples that overlaps [start_ns, end_ns]."""
        stamps = np.array([s.stamp_ns for s in self._samples], dtype=np.int64)
        if len(stamps) < 2:
            return 0
        gaps = np.diff(stamps)
        overlaps = (stamps[1:] > start_ns) & (stamps[:-1] < end_ns)
        return int(gaps[overlaps].max()) if overlaps.any() else 0

    def track(self, epoch_ns: int, max_extrapolation_s: float,
              from_ns: int | None = None) -> PoseTrack:
        """The samples (from the last one at or before ``from_ns`` on) as a PoseTrack."""
        samples = list(self._samples)
        if not samples:
            raise ValueError('pose history is empty')
        first = 0
        if from_ns is not None:
            stamps = np.array([s.stamp_ns for s in samples], dtype=np.int64)
            first = max(int(np.searchsorted(stamps, from_ns, side='right')) - 1, 0)
        samples = samples[first:]
        last = samples[-1]
        t_s = np.array([(s.stamp_ns - epoch_ns) / NS_PER_S for s in samples])
        return PoseTrack(t_s, np.array([s.position_m for s in samples]),
                         np.array([s.quat_xyzw for s in samples]),
                         max_extrapolation_s=max_extrapolation_s,
                         velocity_mps=last.velocity_mps,
                         angular_velocity_rad_s=last.angular_velocity_rad_s)


class ReasonThrottle:
    """At most one log line per kind of problem per ``period_s``, counting the rest."""

    def __init__(self, period_s: float = 1.0):
        self.period_s = period_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def allow(self, kind: str, now_s: float) -> tuple[bool, int]:
        """(log now?, how many of this kind were suppressed since the last line)."""
        last = self._last.get(kind)
        if last is not None and now_s - last < self.period_s:
            self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
            return False, 0
        self._last[kind] = now_s
        return True, self._suppressed.pop(kind, 0)


class DropCounter:
    """Inputs dropped, counted by cause (``counts``); one warning a second per cause, with
    the count so far, so a flood of one cause never hides another."""

    def __init__(self, causes, period_s: float = 1.0):
        self.counts: dict[str, int] = dict.fromkeys(causes, 0)
        self._throttle = ReasonThrottle(period_s)

    def drop(self, cause: str, text: str, warn) -> None:
        """Count one input dropped for ``cause``; ``warn(line)`` when this cause may speak."""
        self.counts[cause] = self.counts.get(cause, 0) + 1
        if self._throttle.allow(cause, time.monotonic())[0]:
            warn(f'{text} [{cause}: {self.counts[cause]} dropped so far]')
