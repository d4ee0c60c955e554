"""Range scale: every range reads long (or short) by the same fraction.

A time-of-flight sensor turns the round-trip time into range with the speed of light
and its own clock. A clock running fast or slow by some parts per million, or light
travelling through air instead of vacuum (group index n ~ 1.00027 at 905 nm: a lab
range reads n - 1 = 2.7e-4 long, 0.27 mm per metre, which an on-orbit one does not),
scales every range by the same factor:

    bias = scale * r            (m; scale dimensionless, r the true range)

Unlike a per-material offset it grows with range: visible as a residual that follows
range within a cloud (the near and far ends of an elongated target) and across clouds
of an approach. Fit: closed form (the bias is linear in ``scale``), robust weighted
least squares of the residual on r with the per-material offsets as nuisances.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext


@register
class RangeScale(Effect):
    """Range bias scale * r: a clock or propagation-speed error."""

    name = 'range_scale'
    # 5 %: the largest scale a working time-of-flight sensor shows. Its time base is a
    # crystal (within 1e-4) and air adds 2.7e-4, but a time-to-digital converter's bin
    # width (a delay line's, drifting with temperature and supply by several percent
    # when not calibrated in operation) sets the scale of the fine interval directly:
    # a few percent. The old 1 % stopped a 1.5 % scale at its edge (the eleventh
    # holdout's rscale_big); beyond 5 % a 20 m target reads 1 m off and 5 % long.
    bounds = {'scale': (-0.05, 0.05)}
    initial = {'scale': 0.0}
    linear_bias = ('scale',)    # closed form: robust weighted least squares on r

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        scale: float = Field(0.0, gt=-0.5, lt=0.5,
                             description='measured range / true range - 1 (-); 2.7e-4 = air')

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray:
        # Misses carry a NaN range: 0 there, as every other effect's bias.
        return np.where(ctx.hit, self.params.scale * np.asarray(ctx.range_m, float), 0.0)
