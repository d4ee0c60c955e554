"""Solar background: sunlight photons trigger the detector at random ranges.

Sunlit surfaces (and the sun itself) put a steady background on the detector.
Now and then a background photon burst crosses the threshold while the receiver
listens, and the first-return detector reports it instead of the target echo:
each shot, hit or miss, with probability ``probability`` returns a point at a range
uniform over the listening window [min_range_m, max_range_m] (the sensor's range
gate by default), with threshold intensity. Shots that miss the target thus make
points off the target too.

Likelihood: a measured range is (1 - p) N(expected, sigma) + p / W (``outlier_fraction``).
Fit: p by a 1-D maximum-likelihood search on the mixture likelihood (concave in p).
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

# The window lies within any lidar's reach (docs/effects.md, "Parameter bounds"); the
# pipeline gates the published ranges to the sensor's range gate in any case.
MAX_WINDOW_M = 100_000.0


@register
class SolarBackground(Effect):
    """Each shot is replaced, with probability p, by a uniform random range."""

    name = 'solar_background'
    bounds = {'probability': (0.0, 0.5)}
    initial = {'probability': 0.0}

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        probability: float = Field(0.0, ge=0.0, le=1.0, description='false returns per shot (-)')
        min_range_m: float | None = Field(None, ge=0.0, le=MAX_WINDOW_M,
                                          description='window start (m); None = range gate')
        max_range_m: float | None = Field(None, gt=0.0, le=MAX_WINDOW_M,
                                          description='window end (m); None = range gate')

    def window_m(self, ctx: ReturnContext) -> tuple[float, float]:
        lo = self.params.min_range_m if self.params.min_range_m is not None else ctx.min_range_m
        hi = self.params.max_range_m if self.params.max_range_m is not None else ctx.max_range_m
        if hi <= lo:
            raise ValueError(f'solar_background: window [{lo}, {hi}] m is empty')
        return float(lo), float(hi)

    def false_returns(self, ctx: ReturnContext, rng: np.random.Generator):
        p = self.params.probability
        if p <= 0:
            return None   # draw nothing: the other random streams stay as they were
        lo, hi = self.window_m(ctx)
        n = len(ctx)
        mask = rng.random(n) < p
        range_m = np.full(n, np.nan)
        range_m[mask] = rng.uniform(lo, hi, np.count_nonzero(mask))   # only where used
        return mask, range_m

    def outlier_fraction(self, ctx: ReturnContext) -> float:
        return self.params.probability
