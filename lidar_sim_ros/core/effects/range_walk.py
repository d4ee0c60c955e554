"""Range walk: leading-edge timing makes strong returns read short.

A leading-edge discriminator fires when the pulse crosses a fixed threshold. A
stronger pulse of the same shape crosses it earlier, so the measured range shortens
as the received power P grows; for a Gaussian-like leading edge the advance grows
with the logarithm of P over the threshold power:

    bias = offset_m - k_m * ln(P / P_ref)        P_ref = the detection threshold by default

A constant offset (or a different P_ref, which is the same thing) cannot be told
apart from the per-material range bias of the paper's model, so the fit never
estimates it: ``offset_m`` stays 0 and the slope ``k_m`` is measured from how the
residual varies with ln P within each material (the material offsets are nuisance
parameters of every fit). The material biases then absorb the walk's mean.

``power`` says which P the comparison reads for the walk: the sensor's own measure of
the pulse (``measured``, its intensity mapped to power) or the model's predicted power
(``model``). A sensor whose intensity is not the power its discriminator saw (a
reflectivity compensated for range and incidence) misreads P at grazing incidence;
the comparison fits both and keeps the better. The simulator always uses its own power.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

# Physical limits of the parameters (docs/effects.md, "Parameter bounds"): a walk of 2 m
# per e-fold is ten times any discriminator's; the offset is a range error (MAX_RANGE_ERROR_M).
MAX_K_M = 2.0
MAX_OFFSET_M = 100.0
MAX_REFERENCE_POWER_W = 1e3


def log_power_ratio(ctx: ReturnContext, reference_power_w: float | None = None) -> np.ndarray:
    """ln(P / P_ref) per shot (-); 0 where the shot has no power (a miss)."""
    ref = reference_power_w or ctx.threshold_power_w
    power = np.asarray(ctx.power_w, float)
    if not ref or ref <= 0:
        raise ValueError(f'range_walk needs a positive reference power, got {ref!r} W')
    out = np.zeros(power.shape)
    return np.log(power / ref, out=out, where=power > 0)


@register
class RangeWalk(Effect):
    """Range bias -k_m ln(P / P_ref): strong returns (high power) read short."""

    name = 'range_walk'
    bounds = {'k_m': (-0.5, 0.5)}
    initial = {'k_m': 0.0}
    linear_bias = ('k_m',)      # closed form: robust weighted least squares on -ln(P/P_ref)
    power_driven = True

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        k_m: float = Field(0.0, ge=-MAX_K_M, le=MAX_K_M,
                           description='range advance per e-fold of received power (m)')
        offset_m: float = Field(0.0, ge=-MAX_OFFSET_M, le=MAX_OFFSET_M,
                                description='constant offset (m); not fitted, see module doc')
        reference_power_w: float | None = Field(
            None, gt=0.0, le=MAX_REFERENCE_POWER_W,
            description='P_ref (W); None = detection threshold')
        power: Literal['measured', 'model'] = Field(
            'measured', description="the power compare reads for P: the measured "
                                    "intensity's or the model's (module doc)")

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray:
        p = self.params
        return p.offset_m - p.k_m * log_power_ratio(ctx, p.reference_power_w)
