"""A range bias that varies smoothly across the field of view: what per-laser offsets
are weighed against.

Each laser of a multi-laser sensor scans its own tile, so the lasers' offsets
(``laser_bias``) can also fit any range pattern that varies across the field: the
target's sunlit faces reading long on one side of the image, a body bent off its CAD,
the slope of a turned pose. A laser's own offsets are unrelated from tile to tile;
such a pattern is smooth over the field, and within a tile as well as across tiles.
So the offsets are weighed against a low-order surface over the shot's pointing:

    bias = a_az az + a_el el + a_azaz az^2 + a_azel az el + a_elel el^2     (m; az, el rad)

(its constant is every material's own offset). Fitted in closed form (robust
weighted least squares with one intercept per material, ``linear_bias_coefficients``).
Not registered in the catalogue: it is never named, only weighed against.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict

from lidar_sim_ros.compare.model.fit import (linear_bias_coefficients, make_result_vector,
                                             model_on_rays, register_fit)
from lidar_sim_ros.compare.model.likelihood import FitData
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

TERMS = ('az', 'el', 'azaz', 'azel', 'elel')
BOUND_M = 5.0       # per rad (or rad^2): 8 cm across a 60 deg field at the first order


def terms(az_rad: np.ndarray, el_rad: np.ndarray) -> np.ndarray:
    """(N, 5) the surface's terms at each pointing (rad)."""
    az, el = np.asarray(az_rad, float), np.asarray(el_rad, float)
    return np.column_stack([az, el, az * az, az * el, el * el])


class FieldPattern(Effect):
    """Range bias of a quadratic surface over the shot's pointing (m)."""

    name = 'field_pattern'
    bounds = {f'{t}_m': (-BOUND_M, BOUND_M) for t in TERMS}

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        az_m: float = 0.0
        el_m: float = 0.0
        azaz_m: float = 0.0
        azel_m: float = 0.0
        elel_m: float = 0.0

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray:
        p = self.params
        a = np.array([p.az_m, p.el_m, p.azaz_m, p.azel_m, p.elel_m])
        bias = terms(ctx.az_rad, ctx.el_rad) @ a
        return np.where(ctx.hit, np.nan_to_num(bias), 0.0)


@register_fit(FieldPattern)
def _fit_field_pattern(cls: type[Effect], data: FitData,
                       base_effects: Sequence[Effect] = ()):
    """Closed form: the five coefficients by ``linear_bias_coefficients`` on top of
    ``base_effects``."""
    base_effects = list(base_effects)
    model = model_on_rays(data, base_effects)
    ctx = data.baseline.ctx
    a = linear_bias_coefficients(data, model, terms(ctx.az_rad, ctx.el_rad),
                                 [(-BOUND_M, BOUND_M)] * len(TERMS))
    params = {f'{t}_m': round(float(v), 6) for t, v in zip(TERMS, a)}
    return make_result_vector(cls(params), data, base_effects, params)
