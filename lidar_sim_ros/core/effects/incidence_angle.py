"""Incidence angle: the beam footprint stretches along range on a tilted surface.

A beam of full divergence dtheta lights a spot of diameter r dtheta. On a surface
tilted by theta the spot spans ranges over a depth

    L = r * dtheta * tan(theta)          (m; tan clipped at max_incidence_deg)

so the returned pulse is smeared over L: the leading edge fires early (a negative
bias) and the timing jitters more. Both grow with L:

    bias  = bias_gain  * L               sigma_extra = sigma_gain * L

For a uniformly lit footprint and a leading-edge detector bias_gain ~ -0.5 and
sigma_gain ~ 1/sqrt(12) ~ 0.29; real beams and detectors differ, hence the fit.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

# Physical limit of the gains (docs/effects.md, "Parameter bounds"): ten times the fit's box.
MAX_GAIN = 100.0


def footprint_depth_m(ctx: ReturnContext, max_incidence_deg: float = 85.0) -> np.ndarray:
    """L = r dtheta tan(theta) (m): range extent of the footprint; 0 on a miss."""
    # fmax takes the number over NaN: a NaN incidence counts as 0 (a miss). In place: one
    # array through tan and the products.
    depth = np.fmax(np.asarray(ctx.incidence_rad, float), 0.0)
    np.minimum(depth, np.radians(max_incidence_deg), out=depth)
    np.tan(depth, out=depth)
    r = np.asarray(ctx.range_m, float)
    with np.errstate(invalid='ignore'):
        np.multiply(depth, r * ctx.divergence_rad, out=depth)
    np.copyto(depth, 0.0, where=~(ctx.hit & np.isfinite(r)))
    return depth


class _LastDepth:
    """The depth of the last context asked for: bias and sigma hooks share one."""

    def __init__(self):
        self.ctx, self.max_deg, self.depth = None, None, None

    def __call__(self, ctx: ReturnContext, max_incidence_deg: float) -> np.ndarray:
        if ctx is not self.ctx or max_incidence_deg != self.max_deg:
            self.depth = footprint_depth_m(ctx, max_incidence_deg)
            self.ctx, self.max_deg = ctx, max_incidence_deg
        return self.depth


@register
class IncidenceAngle(Effect):
    """Bias and noise proportional to the footprint depth r dtheta tan(theta)."""

    name = 'incidence_angle'
    bounds = {'bias_gain': (-10.0, 10.0), 'sigma_gain': (0.0, 10.0)}
    initial = {'bias_gain': 0.0, 'sigma_gain': 0.0}
    linear_bias = ('bias_gain',)   # closed form on L; sigma_gain by a 1-D search

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        bias_gain: float = Field(0.0, ge=-MAX_GAIN, le=MAX_GAIN,
                                 description='bias per metre of footprint depth (-)')
        sigma_gain: float = Field(0.0, ge=0.0, le=MAX_GAIN,
                                  description='extra sigma per metre of footprint depth (-)')
        max_incidence_deg: float = Field(85.0, gt=0.0, lt=90.0,
                                         description='tan(theta) is clipped here (grazing)')

    def _depth(self, ctx: ReturnContext) -> np.ndarray:
        if not hasattr(self, '_last'):
            self._last = _LastDepth()
        return self._last(ctx, self.params.max_incidence_deg)

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray:
        return self.params.bias_gain * self._depth(ctx)

    def range_sigma_m(self, ctx: ReturnContext) -> np.ndarray:
        return self.params.sigma_gain * self._depth(ctx)
