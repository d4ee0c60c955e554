"""SNR noise: range jitter grows as the signal falls toward the threshold.

Timing jitter of a threshold detector is the noise voltage over the slope of the
pulse edge; the slope scales with the signal, so the range noise scales as an
inverse power of the received power P (exponent 1/2 for shot-noise-limited
detection, 1 for a fixed amplifier noise):

    sigma_extra = c_m * (P_threshold / P) ** exponent

c_m is the extra noise at the threshold; it adds in quadrature to the material
sigma. Fitted by the generic bounded maximum likelihood (c_m and the exponent), c_m
searched up to its physical limit MAX_C_M: c_m is the noise extrapolated to the
threshold, where few points lie, so a footprint's weak edge returns or a steep
exponent can put it well above the typical noise, and a search box narrower than the
limit left such a fit at its edge (never named, ``fit.at_bounds``). A fit at MAX_C_M
is still at its bound: no detector ranges with 10 m of noise.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

# Physical limits (docs/effects.md, "Parameter bounds"): 10 m of noise at the threshold
# is no ranging at all; exponents beyond 4 are no detector's.
MAX_C_M = 10.0
MAX_EXPONENT = 4.0


def threshold_power_ratio(ctx: ReturnContext) -> np.ndarray:
    """P_threshold / P per shot (-); 0 on a miss."""
    power = np.asarray(ctx.power_w, float)
    out = np.zeros(power.shape)
    return np.divide(ctx.threshold_power_w, power, out=out, where=power > 0)


@register
class SnrNoise(Effect):
    """Extra range noise c_m (P_threshold / P)^exponent."""

    name = 'snr_noise'
    bounds = {'c_m': (0.0, MAX_C_M), 'exponent': (0.1, 2.0)}
    initial = {'c_m': 0.0, 'exponent': 0.5}
    power_driven = True

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        c_m: float = Field(0.0, ge=0.0, le=MAX_C_M,
                           description='extra range noise at the threshold power (m)')
        exponent: float = Field(0.5, gt=0.0, le=MAX_EXPONENT,
                                description='power-law exponent (-); 0.5 = shot-noise limited')

    def range_sigma_m(self, ctx: ReturnContext) -> np.ndarray:
        return self.params.c_m * threshold_power_ratio(ctx) ** self.params.exponent
