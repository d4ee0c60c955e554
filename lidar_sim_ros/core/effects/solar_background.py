"""Solar background: sunlight photons trigger the detector at random ranges.

Sunlit surfaces (and the sun itself) put a steady background on the detector.
Now and then a background photon burst crosses the threshold while the receiver
listens, and the first-return detector reports it instead of the target echo.
``probability`` is the chance of such a crossing over the whole listening window
[min_range_m, max_range_m] (the sensor's range gate by default): what a shot that
misses the target sees, which then returns a point at a range uniform over the
window, with threshold intensity. Shots that miss the target thus make points off the
target too.

A first-return receiver (``first_return``, the default) stops listening at the echo:
a crossing is recorded only if it comes before it, so a shot whose echo returns from
range r listens over (r - min) / (max - min) of the window only. Background crossings
are a Poisson process, so its chance is 1 - (1 - p)^((r - min) / (max - min)), and its
range is uniform between the window's start and the echo. A target at 20 m in a 250 m
gate sees about 8 % of the misses' rate: without the gating a rate fitted on the
target's points is that much too low, and a simulation with it makes far fewer false
returns than were measured. ``first_return: false``: every shot, hit or miss, with
probability p (a receiver that reports the strongest or last return of several).

Likelihood: a measured range is (1 - w) N(expected, sigma) + w / W, w the shot's
probability (``outlier_fraction``). Fit: p by a 1-D maximum-likelihood search on the
mixture likelihood.
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
        first_return: bool = Field(True, description='a crossing is recorded only before '
                                   'the echo (first-return receiver)')

    def window_m(self, ctx: ReturnContext) -> tuple[float, float]:
        lo = self.params.min_range_m if self.params.min_range_m is not None else ctx.min_range_m
        hi = self.params.max_range_m if self.params.max_range_m is not None else ctx.max_range_m
        if hi <= lo:
            raise ValueError(f'solar_background: window [{lo}, {hi}] m is empty')
        return float(lo), float(hi)

    def listen_share(self, ctx: ReturnContext) -> np.ndarray | float:
        """Share of the window each shot listens over (-): up to its echo for a
        first-return receiver on a shot that hits (range_m finite), else all of it."""
        if not self.params.first_return:
            return 1.0
        lo, hi = self.window_m(ctx)
        r = np.asarray(ctx.range_m, float)
        # An echo too weak to trigger does not stop the listening.
        hit = (np.asarray(ctx.hit, bool) & np.isfinite(r)
               & (np.asarray(ctx.power_w, float) >= ctx.threshold_power_w))
        with np.errstate(invalid='ignore'):
            share = np.clip((r - lo) / (hi - lo), 0.0, 1.0)
        return np.where(hit, share, 1.0)

    def false_returns(self, ctx: ReturnContext, rng: np.random.Generator):
        p = self.params.probability
        if p <= 0:
            return None   # draw nothing: the other random streams stay as they were
        lo, hi = self.window_m(ctx)
        n = len(ctx)
        share = np.broadcast_to(np.asarray(self.listen_share(ctx), float), (n,))
        mask = rng.random(n) < self.outlier_fraction(ctx) * np.ones(n)
        range_m = np.full(n, np.nan)
        # Uniform over what the shot listened to (only where used).
        range_m[mask] = lo + (hi - lo) * share[mask] * rng.random(np.count_nonzero(mask))
        return mask, range_m

    def outlier_fraction(self, ctx: ReturnContext) -> np.ndarray | float:
        """P(a recorded background crossing) per shot: 1 - (1 - p)^share (-)."""
        p = self.params.probability
        share = self.listen_share(ctx)
        if np.isscalar(share) or p <= 0:
            return p if np.isscalar(share) else np.zeros(len(ctx))
        return -np.expm1(share * np.log1p(-min(p, 1.0 - 1e-12)))
