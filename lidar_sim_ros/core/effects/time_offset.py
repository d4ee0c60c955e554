"""Time offset: the pose and LiDAR clocks disagree by a constant dt.

Motion capture (or the navigation filter) stamps the target pose on one clock,
the LiDAR stamps its points on another. An offset dt makes every point look as if
the target were where it is at t + dt: the pose is evaluated at

    t_pose = t_lidar + dt_s

Visible as residuals that grow with the target's apparent velocity (fast-moving
surfaces, far from the tumble axis) and as points beyond the leading silhouette.
Fit: 1-D bounded search of the likelihood over dt in [-0.5, 0.5] s (a grid, then
Brent), re-predicting the rays at each trial offset.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect

# A minute between the pose clock and the LiDAR clock is a setup fault, not an offset to model
# (docs/effects.md, "Parameter bounds").
MAX_DT_S = 60.0


@register
class TimeOffset(Effect):
    """Pose evaluated at LiDAR time + dt_s."""

    name = 'time_offset'
    bounds = {'dt_s': (-0.5, 0.5)}
    initial = {'dt_s': 0.0}
    needs_repredict = True
    fit_options = {'n_grid': 21}

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        dt_s: float = Field(0.0, ge=-MAX_DT_S, le=MAX_DT_S,
                            description='pose time minus LiDAR time (s)')

    def pose_time_s(self, t_s: np.ndarray) -> np.ndarray:
        return np.asarray(t_s, float) + self.params.dt_s
