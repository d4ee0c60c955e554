"""Relative pose of the target body in the lidar frame, as a function of time.

Convention everywhere: ``p_lidar = R @ p_body + position_m`` (the target body pose
expressed in the lidar frame, as carried by ``/target/pose``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from lidar_sim_ros.core.config import ScenarioConfig


class PoseCoverageError(ValueError):
    """Requested times fall outside what the pose history can answer."""


@dataclass(frozen=True)
class Poses:
    """Poses at N times: rotation (N,) and position (N, 3) in metres."""

    rotation: Rotation
    position_m: np.ndarray

    def to_body(self, points_lidar: np.ndarray) -> np.ndarray:
        """Lidar-frame points or origins (N, 3) into the body frame."""
        return self.rotation.inv().apply(points_lidar - self.position_m)

    def vector_to_body(self, vec_lidar: np.ndarray) -> np.ndarray:
        return self.rotation.inv().apply(vec_lidar)

    def to_lidar(self, points_body: np.ndarray) -> np.ndarray:
        return self.rotation.apply(points_body) + self.position_m

    def vector_to_lidar(self, vec_body: np.ndarray) -> np.ndarray:
        return self.rotation.apply(vec_body)


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
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        los = self.position0_m / np.linalg.norm(self.position0_m)
        pos = self.position0_m[None, :] - (self.approach_speed_mps * t)[:, None] * los[None, :]
        spin = Rotation.from_rotvec((self.tumble_rate_rad_s * t)[:, None] * self.tumble_axis[None, :])
        return Poses(spin * self.rotation0, pos)


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
        self._slerp = Slerp(t, self.rotation) if len(t) > 1 else None
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
        if len(t) == 0:
            return Poses(Rotation.identity(0) if hasattr(Rotation, 'identity') else
                         Rotation.from_quat(np.zeros((0, 4))), np.zeros((0, 3)))
        eps = 1e-9
        if t.min() < self.start_s - eps or t.max() > self.end_s + self.max_extrapolation_s + eps:
            raise PoseCoverageError(
                f'times [{t.min():.6f}, {t.max():.6f}] s outside pose coverage '
                f'[{self.start_s:.6f}, {self.end_s:.6f}] s + {self.max_extrapolation_s:g} s extrapolation')
        inside = np.clip(t, self.start_s, self.end_s)
        if self._slerp is None:
            rot = Rotation.from_quat(np.repeat(self.rotation.as_quat(), len(t), axis=0))
            pos = np.repeat(self.position_m, len(t), axis=0)
        else:
            rot = self._slerp(inside)
            pos = np.column_stack([np.interp(inside, self.t_s, self.position_m[:, i]) for i in range(3)])
        ahead = np.maximum(t - self.end_s, 0.0)
        if np.any(ahead > 0):
            pos = pos + ahead[:, None] * self._v_end[None, :]
            rot = Rotation.from_rotvec(ahead[:, None] * self._w_end[None, :]) * rot
        return Poses(rot, pos)
