"""Range drift: the sensor's range offset changes slowly over the recording.

A time-of-flight sensor's range offset (the delay of its electronics and the
threshold crossing of its detector) depends on temperature. As the sensor warms up
or cools down over a recording, every range it reads shifts by the same amount at a
time, slowly (seconds to minutes; a lab's thermal drift: 0 to +4 cm over a minute):

    bias = rate_m_per_s * (t - t0_s)        (m; t the shot's absolute time, s)

Within one cloud (0.1 s) it is a constant range offset; across clouds it changes. Its
mean over the recording is a per-material offset, which every fit profiles out, so
only the change from cloud to cloud is evidence: the same on every ray, whatever the
surface or direction. A reference pose that is off along the line of sight moves a
cloud's ranges too, so on a narrow target the two are confounded (docs/compare.md,
"Range errors of the sensor against the reference pose"). Fit: closed form (the bias
is linear in ``rate_m_per_s``), as ``range_walk``.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext


@register
class RangeDrift(Effect):
    """Range bias rate * (t - t0): a range offset drifting linearly in time."""

    name = 'range_drift'
    # 10 cm/s: 1 cm within one 0.1 s cloud, beyond which the offset is no longer constant
    # over a scan (a lab's thermal drift is about 1e-3 m/s; a short recording's steep
    # warm-up is steeper: 8 cm in 2 s was clipped at the old 1 cm/s).
    bounds = {'rate_m_per_s': (-0.1, 0.1)}
    initial = {'rate_m_per_s': 0.0}
    linear_bias = ('rate_m_per_s',)    # closed form: robust weighted least squares on t

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        rate_m_per_s: float = Field(0.0, ge=-1.0, le=1.0,
                                    description='range offset change per second (m/s)')
        t0_s: float = Field(0.0, ge=-1e5, le=1e5,
                            description='time at which the offset is zero (s, on the run\'s '
                                        'clock: a comparison counts from its first stamp)')

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray:
        # Without a clock (a caller with no shot times) there is nothing to drift over.
        if ctx.time_s is None:
            return np.zeros(len(ctx))
        t = np.asarray(ctx.time_s, float) - self.params.t0_s
        return np.where(ctx.hit, self.params.rate_m_per_s * t, 0.0)
