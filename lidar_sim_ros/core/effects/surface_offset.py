"""Surface offset: the real target's surfaces lie off its mesh (as-built vs CAD).

Not a sensor effect: the target the sensor sees differs from the mesh the model
raycasts. Two common forms, both a displacement of each surface along its normal:

* the whole target is ``1 + scale`` times the mesh about the body origin (a CAD model
  drawn to nominal size, a scale slip in an export): a surface whose plane lies ``d``
  from the origin moves out by ``scale * d``;
* every surface stands ``standoff_m`` proud of the mesh (blankets and tape over the
  structure the CAD shows).

A surface moved out by ``delta`` toward the sensor shortens the range along a ray that
meets it at incidence theta by ``delta / cos(theta)``:

    bias = -(standoff_m + scale * d) / cos(theta)        (m; theta clipped at
                                                           max_incidence_deg)

with ``d = n . (p - o)`` (m), n the surface normal toward the sensor, p the hit point
and o the body origin, all in the lidar frame (``d = -r cos(theta) - n . o``). A
sphere of radius R seen head-on: ``d = R``, bias ``-scale R``. Its constant part per
material is a per-material range bias; what tells it apart is how it follows
``1 / cos(theta)`` and, for the scale, where on the body a surface lies. A sensor's
footprint effects (``incidence_angle``) grow with range; this does not. Both free
parameters are fitted (jointly, in closed form: compare/model/fit.py); after the
material intercepts a standoff leaves ``standoff (1 / cos(theta) - 1)``, growing as
theta^2 / 2 from normal incidence where a footprint's ``r div tan(theta)`` grows as
theta.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

MAX_SCALE = 0.1          # a target 10 % off its mesh is another target
MAX_STANDOFF_M = 1.0
MAX_MATERIALS = 256      # entries of material_standoff_m


def plane_offset_m(ctx: ReturnContext) -> np.ndarray:
    """d = n . (p - o) (m) per shot: how far the plane of the surface hit lies from the
    body origin along its normal toward the sensor; 0 on a miss or without a pose."""
    out = np.zeros(len(ctx.range_m))
    if ctx.normal is None or ctx.direction is None or ctx.scene is None:
        return out
    hit = np.asarray(ctx.hit, bool) & np.isfinite(np.asarray(ctx.range_m, float))
    if not hit.any():
        return out
    n = np.asarray(ctx.normal, float)[hit]
    u = np.asarray(ctx.direction, float)[hit]
    r = np.asarray(ctx.range_m, float)[hit]
    origin = np.asarray(ctx.scene.poses.position_m, float).reshape(-1, 3)
    if len(origin) > 1:
        origin = origin[hit]
    out[hit] = r * np.einsum('ij,ij->i', n, u) - np.einsum('ij,ij->i', n, origin)
    return out


def material_standoff(ctx: ReturnContext, by_name: dict[str, float]) -> np.ndarray:
    """Per shot, the standoff (m) ``by_name`` gives the material it hit (0 for a miss,
    a material not named, or without the target's material names)."""
    out = np.zeros(len(ctx.range_m))
    names = getattr(getattr(ctx.scene, 'target', None), 'material_names', None)
    if not by_name or not names:
        return out
    table = np.array([by_name.get(n, 0.0) for n in names] + [0.0])   # id -1: a miss
    mat = np.asarray(ctx.material, np.int64)
    inside = (mat >= 0) & (mat < len(names))
    return np.where(inside, table[np.where(inside, mat, -1)], 0.0)


@register
class SurfaceOffset(Effect):
    """Range bias -(standoff_m + scale d) / cos(theta): the target's surfaces off its mesh."""

    name = 'surface_offset'
    bounds = {'scale': (-0.02, 0.02), 'standoff_m': (-0.2, 0.2)}
    initial = {'scale': 0.0, 'standoff_m': 0.0}
    linear_bias = ('scale', 'standoff_m')   # closed form, jointly (compare/model/fit.py)

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        scale: float = Field(0.0, ge=-MAX_SCALE, le=MAX_SCALE,
                             description='real size / mesh size - 1 about the body origin (-)')
        standoff_m: float = Field(0.0, ge=-MAX_STANDOFF_M, le=MAX_STANDOFF_M,
                                  description='every surface this far proud of the mesh (m)')
        material_standoff_m: dict[str, float] = Field(
            default_factory=dict, max_length=MAX_MATERIALS,
            description='material name -> its surfaces this much further proud (m): '
                        'blankets over some materials only; a name the target lacks moves '
                        'nothing')
        max_incidence_deg: float = Field(85.0, gt=0.0, lt=90.0,
                                         description='1 / cos(theta) is clipped here (grazing)')

        @field_validator('material_standoff_m')
        @classmethod
        def _finite_and_bounded(cls, v: dict[str, float]) -> dict[str, float]:
            bad = {k: x for k, x in v.items() if not np.isfinite(x) or abs(x) > MAX_STANDOFF_M}
            if bad:
                raise ValueError(f'material standoffs must be finite and within '
                                 f'+-{MAX_STANDOFF_M} m, got {dict(list(bad.items())[:3])}')
            return v

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray:
        p = self.params
        extra = material_standoff(ctx, p.material_standoff_m)
        if p.scale == 0.0 and p.standoff_m == 0.0 and not np.any(extra):
            return np.zeros(len(ctx.range_m))
        theta = np.fmax(np.asarray(ctx.incidence_rad, float), 0.0)
        cos_t = np.cos(np.minimum(theta, np.radians(p.max_incidence_deg)))
        delta = p.standoff_m + extra + (p.scale * plane_offset_m(ctx) if p.scale else 0.0)
        hit = np.asarray(ctx.hit, bool) & np.isfinite(np.asarray(ctx.range_m, float))
        with np.errstate(invalid='ignore', divide='ignore'):
            return np.where(hit, -delta / cos_t, 0.0)
