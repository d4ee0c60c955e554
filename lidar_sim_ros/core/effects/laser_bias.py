"""Laser bias: each laser of a multi-laser sensor carries its own range offset.

A multi-laser sensor (the P-60 fires 24 lasers, one per Lissajous tile) times each
laser's pulses through its own emitter, detector channel and fibre path; what the
factory calibration leaves of their differences is a constant range offset per laser:

    bias = offsets_m[laser]          (0 for a laser beyond the list)

The offsets are one free parameter per laser, so the generic per-parameter fit does not
apply: ``compare/model/fit.py`` estimates them in closed form (robust weighted means of the
residual per laser, with one intercept per material). A common offset of all lasers is
the same thing as a per-material range bias, so the fitted offsets average to zero over
the points and the material biases carry their mean.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from lidar_sim_ros.core.config import MAX_LASERS
from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

MAX_OFFSET_M = 1.0


@register
class LaserBias(Effect):
    """Range bias offsets_m[laser] (m), one per laser id."""

    name = 'laser_bias'
    # One bound for every element of the vector: the generic fit never runs for this
    # class (compare/model/fit.py registers its own), but the comparison reads ``bounds`` to
    # know which parameters are fitted.
    bounds = {'offsets_m': (-MAX_OFFSET_M, MAX_OFFSET_M)}

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        offsets_m: list[float] = Field(default_factory=list, max_length=MAX_LASERS,
                                       description='range offset (m) of laser i, i = list index')

        @field_validator('offsets_m')
        @classmethod
        def _finite_and_bounded(cls, v: list[float]) -> list[float]:
            bad = [x for x in v if not np.isfinite(x) or abs(x) > MAX_OFFSET_M]
            if bad:
                raise ValueError(f'offsets must be finite and within +-{MAX_OFFSET_M} m, got {bad[:3]}')
            return v

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray | float:
        off = np.asarray(self.params.offsets_m, float)
        if not len(off):
            return 0.0
        laser = np.asarray(ctx.laser, np.int64)
        inside = laser < len(off)
        return np.where(inside, off[np.minimum(laser, len(off) - 1)], 0.0)
