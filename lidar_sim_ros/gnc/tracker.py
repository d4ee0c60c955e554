"""Frame-to-frame pose tracking of the target (``PoseTracker``) on the registration of
``gnc.registration``: the capture without a guess (``gnc.acquire``: from the cloud alone),
where each frame starts (by default the last pose with its position carried on at the
last velocity: the roll of a body of revolution is weakly observed, and extrapolating it
feeds its drift back as velocity) and loss detection.

The registration's names (``TrackerConfig``, ``TargetModel``, ``build_model``,
``Estimate``, ``register``, ``pose_matrix``, ``pose_parts``, the predictions) are
re-exported here, where callers have always imported them from.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.gnc.acquire import Acquisition, AcquisitionConfig, acquire
from lidar_sim_ros.gnc.registration import (Estimate, TargetModel, TrackerConfig, build_model,  # noqa: F401
                                            pose_matrix, pose_parts, predict_constant_velocity,
                                            predict_position, register)


# ----------------------------------------------------------------- tracking
class PoseTracker:
    """Frame-to-frame tracking: capture (from a guess, or by acquisition from the cloud
    alone), then predict (``config.prediction``) and refine each frame.

    ``update`` returns the frame's ``Estimate``; an unacceptable one (too few points
    on the model) drops the track, and the next frame is captured again: from the
    guess it is given, or else acquired from the cloud (``gnc.acquire``, settings
    ``acquisition``; ``last_acquisition`` holds the result while that frame's is the
    last update, None otherwise).
    """

    def __init__(self, model: TargetModel, config: TrackerConfig = TrackerConfig(),
                 acquisition: AcquisitionConfig | None = None):
        self.model, self.config = model, config
        self.acquisition = acquisition if acquisition is not None else AcquisitionConfig()
        self.last_acquisition: Acquisition | None = None
        self._track: list[tuple[float, np.ndarray]] = []  # the last two accepted (t_s, pose)

    @property
    def tracking(self) -> bool:
        return bool(self._track)

    def reset(self) -> None:
        """Forget the track (e.g. the clock went back); the next update captures again."""
        self._track = []

    def update(self, t_s: float, xyz_m: np.ndarray, guess: np.ndarray | None = None) -> Estimate:
        """Estimate the pose at ``t_s`` (s) from the cloud. When not tracking, capture from
        ``guess`` (4 x 4) if given, else acquire the pose from the cloud alone."""
        self.last_acquisition = None
        if self._track and t_s <= self._track[-1][0]:
            self.reset()  # time went back: the motion model no longer applies
        if self._track:
            start = self._track[-1][1]
            if len(self._track) == 2 and self.config.prediction != 'previous_pose':
                (t0, T0), (t1, T1) = self._track
                if self.config.prediction == 'constant_velocity':
                    start = predict_constant_velocity(T0, t0, T1, t1, t_s)
                else:  # 'translation': the position moves on, the attitude starts where it was
                    start = start.copy()
                    start[:3, 3] = predict_position(T0[:3, 3], t0, T1[:3, 3], t1, t_s)
            estimate = register(self.model, xyz_m, start, [self.config.tracking_gate_m], self.config)
        elif guess is not None:
            estimate = register(self.model, xyz_m, guess, list(self.config.capture_gates_m), self.config)
        else:
            estimate = self._acquire(xyz_m)
        if estimate.acceptable(self.config):
            self._track = (self._track + [(t_s, estimate.pose)])[-2:]
        else:
            self._track = []
        return estimate

    def _acquire(self, xyz_m: np.ndarray) -> Estimate:
        self.last_acquisition = acquire(self.model, xyz_m, self.acquisition, self.config)
        estimate = self.last_acquisition.estimate
        if self.last_acquisition.success:
            return estimate
        return Estimate(estimate.pose, estimate.points, estimate.inliers, estimate.iterations,
                        estimate.converged, rejected=True)
