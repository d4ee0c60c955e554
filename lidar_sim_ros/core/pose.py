"""Relative pose of the target body in the lidar frame, as a function of time.

Convention everywhere: ``p_lidar = R @ p_body + position_m`` (the target body pose
expressed in the lidar frame, as carried by ``/target/pose``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import MAX_POSITION_M, ScenarioConfig
from lidar_sim_ros.core.vectors import QUAT_NORM_TOL


def valid_pose_mask(position_m: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """(N,) bool: the pose samples with a finite position within MAX_POSITION_M (100 km) on
    every axis and a finite quaternion whose norm is within QUAT_NORM_TOL of 1 (zero and
    NaN quaternions included in the refused)."""
    pos = np.asarray(position_m, float).reshape(-1, 3)
    quat = np.asarray(quat_xyzw, float).reshape(-1, 4)
    with np.errstate(invalid='ignore', over='ignore'):
        norm = np.linalg.norm(quat, axis=1)
        return (np.isfinite(pos).all(axis=1) & (np.abs(pos) <= MAX_POSITION_M).all(axis=1)
                & np.isfinite(quat).all(axis=1) & (np.abs(norm - 1.0) <= QUAT_NORM_TOL))


def quat_multiply(q1_xyzw: np.ndarray, q2_xyzw: np.ndarray) -> np.ndarray:
    """Hamilton product q1 * q2 of (N, 4) or (4,) xyzw quaternions (broadcasts).

    scipy's ``Rotation.__mul__`` costs ~9 ms for 21k rotations here, most of a
    frame's budget; this compiled loop costs ~0.05 ms.
    """
    q1 = np.asarray(q1_xyzw, dtype=float)
    q2 = np.asarray(q2_xyzw, dtype=float)
    shape = np.broadcast_shapes(q1.shape, q2.shape)
    rows1, rows2 = q1.reshape(-1, 4), q2.reshape(-1, 4)
    return _quat_multiply_rows(np.ascontiguousarray(rows1), np.ascontiguousarray(rows2)).reshape(shape)


@njit(cache=True, inline='always')
def _hamilton(x1, y1, z1, w1, x2, y2, z2, w2):
    """The Hamilton product of two xyzw quaternions, as an (x, y, z, w) tuple."""
    return (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)


@njit(cache=True)
def _quat_multiply_rows(q1, q2):
    """Row-wise q1 * q2 of (N|1, 4) arrays; a single row applies to every row of the other."""
    n = max(q1.shape[0], q2.shape[0])
    out = np.empty((n, 4))
    one1, one2 = q1.shape[0] == 1, q2.shape[0] == 1
    for i in range(n):
        a, b = (0 if one1 else i), (0 if one2 else i)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = _hamilton(
            q1[a, 0], q1[a, 1], q1[a, 2], q1[a, 3], q2[b, 0], q2[b, 1], q2[b, 2], q2[b, 3])
    return out


def rotvec_to_quat(rotvec: np.ndarray) -> np.ndarray:
    """Rotation vectors (N, 3) (rad) to xyzw quaternions (N, 4)."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a -> 1/2 as a -> 0
    scale = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([rotvec * scale, np.cos(half)], axis=-1)


class PoseCoverageError(ValueError):
    """Requested times fall outside what the pose history can answer."""


def quat_to_matrix(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit xyzw quaternions (N, 4).

    ~3x faster than ``Rotation.from_quat(q).as_matrix()``, whose input
    normalisation alone costs ~0.7 ms for a 21k-shot frame.
    """
    x, y, z, w = np.asarray(quat_xyzw, dtype=float).T
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.empty((len(x), 3, 3))
    m[:, 0, 0] = 1 - 2 * (yy + zz)
    m[:, 0, 1] = 2 * (xy - wz)
    m[:, 0, 2] = 2 * (xz + wy)
    m[:, 1, 0] = 2 * (xy + wz)
    m[:, 1, 1] = 1 - 2 * (xx + zz)
    m[:, 1, 2] = 2 * (yz - wx)
    m[:, 2, 0] = 2 * (xz - wy)
    m[:, 2, 1] = 2 * (yz + wx)
    m[:, 2, 2] = 1 - 2 * (xx + yy)
    return m


class Poses:
    """Poses at N times: rotation (N,) and position (N, 3) in metres.

    Build from a scipy ``Rotation`` (``Poses(rotation, position_m)``) or, on hot
    paths, from unit quaternions (``Poses.from_quat``) without scipy's overhead.
    """

    def __init__(self, rotation: Rotation | None, position_m: np.ndarray,
                 *, quat_xyzw: np.ndarray | None = None):
        if rotation is None and quat_xyzw is None:
            raise ValueError('Poses needs a rotation or unit quaternions')
        self._rotation = rotation
        self._quat = None if quat_xyzw is None else np.asarray(quat_xyzw, dtype=float).reshape(-1, 4)
        self.position_m = np.asarray(position_m, dtype=float)

    @classmethod
    def from_quat(cls, quat_xyzw: np.ndarray, position_m: np.ndarray) -> 'Poses':
        """From unit xyzw quaternions (N, 4); they are not re-normalised."""
        return cls(None, position_m, quat_xyzw=quat_xyzw)

    @cached_property
    def rotation(self) -> Rotation:
        return self._rotation if self._rotation is not None else Rotation.from_quat(self._quat)

    @cached_property
    def quat_xyzw(self) -> np.ndarray:
        """Unit xyzw quaternions (N, 4), or (1, 4) for a single rotation."""
        if self._quat is not None:
            return self._quat
        return np.ascontiguousarray(self.rotation.as_quat(), dtype=float).reshape(-1, 4)

    @cached_property
    def matrix(self) -> np.ndarray:
        """Rotation matrices (N, 3, 3) (or (3, 3) for a single rotation)."""
        if self._quat is not None:
            return quat_to_matrix(self._quat)
        return self.rotation.as_matrix()

    def _apply(self, vec: np.ndarray, inverse: bool) -> np.ndarray:
        m = self.matrix
        if m.ndim == 2:
            return vec @ m if inverse else vec @ m.T
        return np.einsum('nji,nj->ni' if inverse else 'nij,nj->ni', m, vec)

    def to_body(self, points_lidar: np.ndarray) -> np.ndarray:
        """Lidar-frame points or origins (N, 3) into the body frame."""
        return self._apply(np.asarray(points_lidar, dtype=float) - self.position_m, inverse=True)

    def vector_to_body(self, vec_lidar: np.ndarray) -> np.ndarray:
        return self._apply(np.asarray(vec_lidar, dtype=float), inverse=True)

    def to_lidar(self, points_body: np.ndarray) -> np.ndarray:
        return self._apply(np.asarray(points_body, dtype=float), inverse=False) + self.position_m

    def vector_to_lidar(self, vec_body: np.ndarray) -> np.ndarray:
        return self._apply(np.asarray(vec_body, dtype=float), inverse=False)

    def take(self, index: np.ndarray) -> 'Poses':
        """The poses of rows ``index`` (a single pose stays single). Rotation matrices
        already computed are reused, so the rows transform vectors bit for bit alike."""
        quat = self.quat_xyzw
        position = self.position_m.reshape(-1, 3)
        out = Poses.from_quat(quat if len(quat) == 1 else quat[index],
                              position if len(position) == 1 else position[index])
        if 'matrix' in self.__dict__:
            m = self.__dict__['matrix']
            out.__dict__['matrix'] = m if m.ndim == 2 else m[index]
        return out


class PoseSource(Protocol):
    """Anything that gives the target pose at absolute times (s)."""

    def at(self, t_s: np.ndarray) -> Poses: ...


@dataclass(frozen=True)
class ScenarioTrajectory:
    """Closed-form approach + tumble: the scenario's relative motion.

    The target closes along its initial line of sight at ``approach_speed_mps`` and
    rotates at ``tumble_rate_rad_s`` about ``tumble_axis`` (fixed in the lidar frame).
    Time zero is the scenario epoch.
    """

    position0_m: np.ndarray
    rotation0: Rotation
    approach_speed_mps: float
    tumble_axis: np.ndarray
    tumble_rate_rad_s: float

    @classmethod
    def from_config(cls, cfg: ScenarioConfig) -> 'ScenarioTrajectory':
        axis = np.asarray(cfg.motion.tumble_axis, dtype=float)
        return cls(np.asarray(cfg.initial_pose.position_m, dtype=float),
                   Rotation.from_quat(cfg.initial_pose.quat_xyzw),
                   cfg.motion.approach_speed_mps, axis / np.linalg.norm(axis),
                   np.radians(cfg.motion.tumble_rate_dps))

    def at(self, t_s: np.ndarray) -> Poses:
        t = np.ascontiguousarray(np.atleast_1d(np.asarray(t_s, dtype=float)))
        los = self.position0_m / np.linalg.norm(self.position0_m)
        quat, pos = _approach_and_tumble(t, self.position0_m, los, float(self.approach_speed_mps),
                                         self.tumble_axis, float(self.tumble_rate_rad_s),
                                         self.rotation0.as_quat())
        return Poses.from_quat(quat, pos)


@njit(cache=True)
def _approach_and_tumble(t, position0_m, los, speed_mps, axis, rate_rad_s, quat0_xyzw):
    """ScenarioTrajectory at times t (s): quat (N, 4) = spin(axis, rate t) * quat0, and
    position (N, 3) = position0 - speed t los (m). One pass per time (compiled)."""
    n = t.shape[0]
    quat = np.empty((n, 4))
    pos = np.empty((n, 3))
    x2, y2, z2, w2 = quat0_xyzw[0], quat0_xyzw[1], quat0_xyzw[2], quat0_xyzw[3]
    for i in range(n):
        closed = speed_mps * t[i]
        for k in range(3):
            pos[i, k] = position0_m[k] - closed * los[k]
        half = 0.5 * rate_rad_s * t[i]
        s = math.sin(half)
        quat[i, 0], quat[i, 1], quat[i, 2], quat[i, 3] = _hamilton(
            s * axis[0], s * axis[1], s * axis[2], math.cos(half), x2, y2, z2, w2)
    return quat, pos


class PoseTrack:
    """Pose samples interpolated in time: linear in position, SLERP in rotation.

    Beyond the last sample the pose is extrapolated for at most
    ``max_extrapolation_s`` with the last sample's velocity (from ``velocity_mps`` /
    ``angular_velocity_rad_s`` if given, e.g. from Odometry twist, else from the last
    two samples); before the first sample or further out, PoseCoverageError.
    """

    def __init__(self, t_s: np.ndarray, position_m: np.ndarray, quat_xyzw: np.ndarray,
                 max_extrapolation_s: float = 0.0,
                 velocity_mps: np.ndarray | None = None,
                 angular_velocity_rad_s: np.ndarray | None = None):
        t = np.asarray(t_s, dtype=float)
        if t.ndim != 1 or len(t) == 0:
            raise PoseCoverageError('pose track needs at least one sample')
        if np.any(np.diff(t) <= 0):
            raise PoseCoverageError('pose sample times must be strictly increasing')
        self.t_s = t
        self.position_m = np.asarray(position_m, dtype=float).reshape(-1, 3)
        self.rotation = Rotation.from_quat(np.asarray(quat_xyzw, dtype=float).reshape(-1, 4))
        self.max_extrapolation_s = float(max_extrapolation_s)
        self._quat = self.rotation.as_quat()
        if len(t) > 1:
            # Per-segment SLERP constants, so a query costs two sines per time.
            q0, q1 = self._quat[:-1], self._quat[1:]
            dot = np.einsum('ij,ij->i', q0, q1)
            self._q1 = np.where(dot[:, None] < 0, -q1, q1)  # shortest arc
            self._theta = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))
            self._sin_theta = np.sin(self._theta)
            self._inv_dt = 1.0 / np.diff(t)
            self._small = self._sin_theta < 1e-9  # (nearly) equal rotations: linear weights
            self._inv_sin = 1.0 / np.where(self._small, 1.0, self._sin_theta)
        if velocity_mps is not None:
            self._v_end = np.asarray(velocity_mps, dtype=float)
        elif len(t) > 1:
            self._v_end = (self.position_m[-1] - self.position_m[-2]) / (t[-1] - t[-2])
        else:
            self._v_end = np.zeros(3)
        if angular_velocity_rad_s is not None:
            self._w_end = np.asarray(angular_velocity_rad_s, dtype=float)
        elif len(t) > 1:
            self._w_end = (self.rotation[-1] * self.rotation[-2].inv()).as_rotvec() / (t[-1] - t[-2])
        else:
            self._w_end = np.zeros(3)

    @property
    def start_s(self) -> float:
        return float(self.t_s[0])

    @property
    def end_s(self) -> float:
        return float(self.t_s[-1])

    def covers(self, t0_s: float, t1_s: float) -> bool:
        return t0_s >= self.start_s and t1_s <= self.end_s + self.max_extrapolation_s

    def at(self, t_s: np.ndarray) -> Poses:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        eps = 1e-9
        if t.min() < self.start_s - eps or t.max() > self.end_s + self.max_extrapolation_s + eps:
            raise PoseCoverageError(
                f'times [{t.min():.6f}, {t.max():.6f}] s outside pose coverage '
                f'[{self.start_s:.6f}, {self.end_s:.6f}] s + {self.max_extrapolation_s:g} s extrapolation')
        inside = np.clip(t, self.start_s, self.end_s)
        if len(self.t_s) == 1:
            quat = np.repeat(self._quat, len(t), axis=0)
            pos = np.repeat(self.position_m, len(t), axis=0)
        else:
            quat, pos = _slerp_track(np.ascontiguousarray(inside), self.t_s, self._quat, self._q1,
                                     self._theta, self._inv_sin, self._small, self.position_m,
                                     self._inv_dt)
        late = np.flatnonzero(t > self.end_s)
        if len(late):
            # Only the times past the last sample: dead-reckon with the end velocities.
            ahead = (t.take(late) - self.end_s)[:, None]
            pos[late] += ahead * self._v_end
            quat[late] = quat_multiply(rotvec_to_quat(ahead * self._w_end), quat.take(late, axis=0))
        return Poses.from_quat(quat, pos)


@njit(cache=True)
def _slerp_track(t, t_s, quat_s, quat_next, theta, inv_sin, small, position_s, inv_dt):
    """Per time: its segment [t_s[j], t_s[j+1]], SLERP from quat_s[j] to quat_next[j]
    (the shortest-arc copy of quat_s[j+1]) and linear position. Times must lie within t_s."""
    n, last = t.shape[0], t_s.shape[0] - 2
    quat = np.empty((n, 4))
    pos = np.empty((n, 3))
    for i in range(n):
        j = min(max(np.searchsorted(t_s, t[i], side='right') - 1, 0), last)
        f = (t[i] - t_s[j]) * inv_dt[j]
        if small[j]:
            w0, w1 = 1.0 - f, f
        else:
            w0 = math.sin((1.0 - f) * theta[j]) * inv_sin[j]
            w1 = math.sin(f * theta[j]) * inv_sin[j]
        for k in range(4):
            quat[i, k] = w0 * quat_s[j, k] + w1 * quat_next[j, k]
        for k in range(3):
            pos[i, k] = position_s[j, k] + f * (position_s[j + 1, k] - position_s[j, k])
    return quat, pos


@dataclass(frozen=True)
class StaticPose:
    """A target that does not move relative to the sensor (e.g. a lab calibration setup)."""

    position_m: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def at(self, t_s: np.ndarray) -> Poses:
        n = len(np.atleast_1d(t_s))
        quat = np.repeat(np.asarray(self.quat_xyzw, dtype=float)[None], n, axis=0)
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        return Poses.from_quat(quat, np.repeat(np.asarray(self.position_m, float)[None], n, axis=0))
