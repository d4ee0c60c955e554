"""Pose estimates against the truth: per-frame errors and their summary (numpy only).

The truth is the pose stream the simulator ran on (``/target/pose``), interpolated to
each estimate's stamp. Besides the totals, the errors are split the way a GNC engineer
reads them: the translation error along the line of sight (a range bias shows there)
and the rotation error into the pointing error of the body's symmetry axis and the
roll about it (weakly observable on a body of revolution).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.pose import PoseTrack

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class TrackingErrors:
    """Errors of N estimates (estimate minus truth), lidar frame.

    t_s: estimate stamps (s, since the first truth pose); translation_m (N, 3);
    los_m (N,): translation error along the line of sight (negative = toward the
    sensor); rotation_deg (N,): angle of R_true^T R_est; axis_deg (N,): angle between
    the estimated and true symmetry axes; roll_deg (N,): twist of the rotation error
    about the symmetry axis.
    """

    t_s: np.ndarray
    translation_m: np.ndarray
    los_m: np.ndarray
    rotation_deg: np.ndarray
    axis_deg: np.ndarray
    roll_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)

    def summary(self) -> dict:
        """RMS figures (m, deg) and the frame count, for gnc.json."""
        rms = lambda x: float(np.sqrt(np.mean(np.square(x)))) if len(x) else float('nan')  # noqa: E731
        return {'frames': len(self),
                'trans_rms_m': rms(np.linalg.norm(self.translation_m, axis=1)),
                'rot_rms_deg': rms(self.rotation_deg),
                'trans_los_mean_m': float(np.mean(self.los_m)) if len(self) else float('nan'),
                'trans_los_rms_m': rms(self.los_m),
                'axis_rms_deg': rms(self.axis_deg),
                'roll_rms_deg': rms(self.roll_deg)}


def tracking_errors(est_stamp_ns: np.ndarray, est_position_m: np.ndarray, est_quat_xyzw: np.ndarray,
                    truth_stamp_ns: np.ndarray, truth_position_m: np.ndarray,
                    truth_quat_xyzw: np.ndarray, symmetry_axis_body=(0.0, 0.0, 1.0)) -> TrackingErrors:
    """Errors of the estimates whose stamps the truth covers (others are left out).

    Stamps are integer ns; positions (N, 3) m; quaternions (N, 4) xyzw.
    ``symmetry_axis_body`` is the body's axis of (near) revolution (the rocket's long axis).
    """
    epoch = int(truth_stamp_ns[0])
    truth = PoseTrack((np.asarray(truth_stamp_ns) - epoch) / NS_PER_S, truth_position_m, truth_quat_xyzw)
    t = (np.asarray(est_stamp_ns, dtype=np.int64) - epoch) / NS_PER_S
    inside = (t >= truth.start_s) & (t <= truth.end_s)
    t = t[inside]
    est_position = np.asarray(est_position_m, dtype=float).reshape(-1, 3)[inside]
    est_rotation = Rotation.from_quat(np.asarray(est_quat_xyzw, dtype=float).reshape(-1, 4)[inside])
    if not len(t):
        empty = np.zeros(0)
        return TrackingErrors(empty, np.zeros((0, 3)), empty, empty, empty, empty)
    true = truth.at(t)
    d = est_position - true.position_m
    los = true.position_m / np.linalg.norm(true.position_m, axis=1, keepdims=True)
    error = true.rotation.inv() * est_rotation  # body-frame rotation error
    axis = np.asarray(symmetry_axis_body, dtype=float)
    axis = axis / np.linalg.norm(axis)
    cos_axis = np.einsum('ij,ij->i', true.rotation.apply(axis), est_rotation.apply(axis))
    # Swing-twist split: the twist about the axis is 2 atan2(v . axis, w) of the error quaternion.
    q = error.as_quat()
    twist = 2.0 * np.arctan2(q[:, :3] @ axis, q[:, 3])
    twist = (twist + np.pi) % (2 * np.pi) - np.pi
    return TrackingErrors(t, d, np.einsum('ij,ij->i', d, los), np.degrees(error.magnitude()),
                          np.degrees(np.arccos(np.clip(cos_axis, -1.0, 1.0))), np.degrees(twist))
