"""Surface offset: the real target's surfaces lie off its mesh (as-built vs CAD).

Not a sensor effect: the target the sensor sees differs from the mesh the model
raycasts. Two common forms, both a displacement of each surface along its normal:

* the whole target is ``1 + scale`` times the mesh about the body origin (a CAD model
  drawn to nominal size, a scale slip in an export);
* every surface stands ``standoff_m`` proud of the mesh (blankets and tape over the
  structure the CAD shows), or only the surfaces of some materials
  (``material_standoff_m``).

The forward model is exact: the sensor's rays are cast against the real surface, a
copy of the mesh scaled by ``1 + scale`` about the body origin whose every face then
moves ``standoff`` (m) along its outward normal (the mesh's winding). Each vertex
moves to the point that keeps every face around it on its own offset plane (a mitred
offset: the least-squares solution of ``v . n_f = standoff_f`` over its faces, exact
where at most three distinct planes meet, a box's corner, a cone's apex, a faceted
cylinder's edge), so flat faces move by exactly ``standoff``: a plate's range changes
by ``-standoff / cos(theta)``, a cylinder of radius R seen at impact parameter b by
``sqrt(R^2 - b^2) - sqrt((R + s)^2 - b^2)``, bounded by ``sqrt(2 R s)`` at the limb
where ``s / cos(theta)`` grows without bound, and rays that pass within ``s`` of the
mesh's silhouette now hit. Where faces of different standoffs meet on a smooth surface
(a blanket's edge) the vertices between them take the faces' mean (a one-facet ramp).

To first order (``first_order_columns``) a surface moved out by ``delta`` shortens the
range along a ray meeting it at incidence theta by ``delta / cos(theta)``:

    bias ~ -(standoff_m + scale * d) / cos(theta)

with ``d = n . (p - o)`` (m), n the surface normal toward the sensor, p the hit point
and o the body origin, all in the lidar frame. That is what tells it from a sensor's
footprint effect (``incidence_angle``, ``r div tan(theta)``): it does not grow with
range, and after the material intercepts a standoff leaves ``standoff (1 / cos(theta)
- 1)``, growing as theta^2 / 2 from normal incidence where a footprint grows as theta.
The fit (compare/model/fit.py) selects the free parameters on these columns and then
refines them on the exact surface (a Gauss-Newton step per re-cast).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext

if TYPE_CHECKING:
    from lidar_sim_ros.core.geometry import Target

MAX_SCALE = 0.1          # a target 10 % off its mesh is another target
MAX_STANDOFF_M = 1.0
MAX_MATERIALS = 256      # entries of material_standoff_m
# A vertex's faces whose normals lie within about 6 deg of each other count as one plane
# in its mitre (eigenvalues of sum n n^T below this share of the largest are dropped): a
# finely faceted curved surface moves along its mean normal, and faces of different
# standoffs meeting on it (a blanket's edge) do not throw the vertex far along the crease.
MITRE_RCOND = 0.01
WELD_TOL_M = 1e-6        # vertices of separate parts this close are one (a seam)


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


def standoff_table_m(material_names, standoff_m: float,
                     by_material_m: dict[str, float]) -> np.ndarray:
    """Per material id, how far (m) its faces stand proud: ``standoff_m`` plus the
    standoff the material has in ``by_material_m`` (a name the target lacks: nothing);
    one more entry, ``standoff_m``, for faces of no listed material."""
    return np.array([standoff_m + by_material_m.get(n, 0.0) for n in material_names]
                    + [standoff_m])


def by_material_id(table: np.ndarray, material_id) -> np.ndarray:
    """``table``'s entry per material id (``standoff_table_m``'s layout): an id outside
    the listed materials (-1: none) takes the last entry."""
    mat = np.asarray(material_id, np.int64)
    last = len(table) - 1
    return table[np.where((mat >= 0) & (mat < last), mat, last)]


def face_offsets_m(target: 'Target', standoff_m: float,
                   by_material_m: dict[str, float]) -> np.ndarray:
    """Per face of ``target``, how far (m) it stands proud (``standoff_table_m``)."""
    return by_material_id(standoff_table_m(target.material_names, standoff_m, by_material_m),
                          target.face_material)


def mitred_offset_m(vertices_m: np.ndarray, faces: np.ndarray, face_normals: np.ndarray,
                    face_offset_m: np.ndarray, rcond: float = MITRE_RCOND) -> np.ndarray:
    """Per vertex, the displacement (m, (V, 3)) that moves every face around it onto its
    own plane offset by ``face_offset_m`` along its unit normal: the least-squares
    solution of ``v . n_f = offset_f`` over the vertex's faces, minimum norm (directions
    the faces' normals do not span, or span within ``rcond`` of the largest eigenvalue of
    ``sum n n^T``, stay put). Exact where at most three distinct planes meet: a flat
    face then moves by exactly its offset. Degenerate faces (zero normal) have no say."""
    v = np.asarray(vertices_m, float)
    f = np.asarray(faces, np.int64)
    n = np.asarray(face_normals, float)
    s = np.asarray(face_offset_m, float)
    nv = len(v)
    corner = f.reshape(-1)
    outer = (n[:, :, None] * n[:, None, :]).reshape(-1, 9)
    a = np.empty((nv, 9))
    for k in range(9):
        a[:, k] = np.bincount(corner, np.repeat(outer[:, k], 3), minlength=nv)
    rhs = np.column_stack([np.bincount(corner, np.repeat(n[:, k] * s, 3), minlength=nv)
                           for k in range(3)])
    w, q = np.linalg.eigh(a.reshape(nv, 3, 3))
    keep = w > rcond * np.maximum(w[:, -1:], 1e-300)
    inv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    proj = np.einsum('vji,vj->vi', q, rhs) * inv
    return np.einsum('vij,vj->vi', q, proj)


def weld_vertices(vertices_m: np.ndarray, tol_m: float = WELD_TOL_M
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(unique vertices, index of each vertex among them): vertices within ``tol_m`` of
    each other on a grid of that pitch are one."""
    v = np.asarray(vertices_m, float)
    _, first, index = np.unique(np.round(v / tol_m).astype(np.int64), axis=0,
                                return_index=True, return_inverse=True)
    return v[first], index.reshape(-1)


def offset_target(target: 'Target', scale: float, face_offset_m: np.ndarray) -> 'Target':
    """The real surface: ``target`` scaled by ``1 + scale`` about the body origin, each
    face then ``face_offset_m`` (m) proud along its outward normal (``mitred_offset_m``);
    same faces, materials and threads (face ids and material ids carry over)."""
    from lidar_sim_ros.core.geometry import Target
    v = np.asarray(target.vertices_m, float) * (1.0 + scale)
    if np.any(face_offset_m):
        # Parts exported apart (one object per material) repeat the vertices of their
        # seams: each copy would follow its own part's faces and the seam open a slit
        # that rays pass through into the body. Welded, a seam's vertex takes the mitre
        # of the faces on both sides.
        welded, index = weld_vertices(v)
        v = v + mitred_offset_m(welded, index[target.faces], target.face_normals,
                                face_offset_m)[index]
    return Target(v, target.faces, target.face_material, target.material_names,
                  target.threads)


def first_order_columns(ctx: ReturnContext, max_incidence_deg: float = 85.0
                        ) -> dict[str, np.ndarray]:
    """The range change (m) per unit of each parameter, to first order at the surface hit:
    ``'standoff_m'`` -1 / cos(theta) and ``'scale'`` -d / cos(theta) (``plane_offset_m``),
    theta clipped at ``max_incidence_deg``; 0 on a miss. A standoff of one material's own
    is the standoff's column over that material's hits."""
    hit = np.asarray(ctx.hit, bool) & np.isfinite(np.asarray(ctx.range_m, float))
    theta = np.fmax(np.nan_to_num(np.asarray(ctx.incidence_rad, float)), 0.0)
    inv_cos = np.where(hit, 1.0 / np.cos(np.minimum(theta, np.radians(max_incidence_deg))), 0.0)
    return {'standoff_m': -inv_cos, 'scale': -plane_offset_m(ctx) * inv_cos}


@register
class SurfaceOffset(Effect):
    """The target's surfaces off its mesh: the rays are cast against the real surface
    (``seen_target``), the mesh scaled by 1 + scale and each face standing proud."""

    name = 'surface_offset'
    bounds = {'scale': (-0.02, 0.02), 'standoff_m': (-0.2, 0.2)}
    # A material's own standoff is searched in the common standoff's box.
    entry_bounds = {'material_standoff_m': bounds['standoff_m']}
    initial = {'scale': 0.0, 'standoff_m': 0.0}
    needs_repredict = True                   # the rays meet another surface: re-cast

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
                                         description='the fit\'s first-order columns clip '
                                                     '1 / cos(theta) here (grazing)')

        @field_validator('material_standoff_m')
        @classmethod
        def _finite_and_bounded(cls, v: dict[str, float]) -> dict[str, float]:
            bad = {k: x for k, x in v.items() if not np.isfinite(x) or abs(x) > MAX_STANDOFF_M}
            if bad:
                raise ValueError(f'material standoffs must be finite and within '
                                 f'+-{MAX_STANDOFF_M} m, got {dict(list(bad.items())[:3])}')
            return v

    def standoffs_by_material_m(self, material_names) -> np.ndarray:
        """How far (m) the faces of each material id stand proud (``standoff_table_m``),
        one more entry for faces of no listed material."""
        return standoff_table_m(material_names, self.params.standoff_m,
                                self.params.material_standoff_m)

    def first_order_shift_m(self, ctx: ReturnContext, material_names) -> np.ndarray:
        """The range change (m) to first order on the surface each ray meets on the mesh
        (``first_order_columns``): its own face's plane moved, whatever the moved mesh's
        edges do; 0 on a miss."""
        cols = first_order_columns(ctx, self.params.max_incidence_deg)
        standoff = by_material_id(self.standoffs_by_material_m(material_names), ctx.material)
        return standoff * cols['standoff_m'] + self.params.scale * cols['scale']

    def seen_target(self, target: 'Target') -> 'Target | None':
        """The real surface (``offset_target``), built once per mesh; None at zero offset."""
        cache = self.__dict__.setdefault('_seen', {})
        key = id(target)
        if key not in cache:
            p = self.params
            offsets = face_offsets_m(target, p.standoff_m, p.material_standoff_m)
            moved = (None if p.scale == 0.0 and not np.any(offsets)
                     else offset_target(target, p.scale, offsets))
            # The mesh is kept beside its copy: its id stays its own while cached.
            cache.clear()
            cache[key] = (target, moved)
        return cache[key][1]
