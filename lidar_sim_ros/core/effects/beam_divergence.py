"""Beam divergence: the beam is a cone, not a ray.

The paper's raycast follows the beam axis. A real beam lights a footprint, so a
shot whose axis just misses the target still returns if enough of the footprint
lands on it (points beyond the geometric silhouette), and a footprint straddling a
depth step returns a mix of the two ranges (points between the surfaces).

Forward model (the ``cast`` hook): K sub-rays cover a cone of full angle
``footprint_scale * divergence``: the axis plus ``rings`` rings at radii rho = i /
rings of the cone's half-angle, 6 i rays on ring i (K = 7, 19, 37 for 1, 2, 3
rings; a fixed pattern, so the model stays deterministic). Each carries the
Gaussian beam's share of energy, e_j ~ exp(-2 rho_j^2) (1/e^2 at the cone edge).
The shot hits if any sub-ray does; its received power is the full-beam power at the
strongest hit sub-ray times the hit energy fraction f = sum_hit e_j / sum e_j (the
detector threshold then decides), and its range is the energy-weighted mean of the
hit sub-rays' ranges (``range_mode: mean``) or the nearest one (``first``).
Reflectance differences between sub-rays are ignored in the weights.

How it is computed (``sampling: edges``, the default): casting K rays for every
shot costs K times the raycast (~19x, 0.13 s a P-60 frame), yet most footprints lie
on one connected, front-facing sheet of the mesh, where the sub-rays' answers follow
from the axis ray's. So the axis ray is cast for every shot, then:

- shots whose cone may hold a silhouette or boundary edge (``silhouette.py``: the
  limb, a rim, the near side of a depth step; taken over every sensor position of
  the call, since the target moves during a frame, so the set is conservative) cast
  all K sub-rays, as ``sampling: all`` does;
- every other shot sees one connected, front-facing sheet: all sub-rays hit it if the
  axis does, none if the axis misses (power fraction 1 or 0). A footprint inside the
  axis facet (or its flat region) has the plane's closed-form mean range. One that
  crosses slight creases only takes the plane's answer too when a bound on the error
  (``_footprints_in_facets``) is within ``crease_tol_m`` (CREASE_TOL_M = 1 mm): the one
  approximation. Any other footprint is walked: each sub-ray is intersected with the
  plane of the axis facet and, where it leaves that facet, followed across the shared
  edge to the next one (at most WALK_STEPS facets), so creases and curved, tessellated
  surfaces give the ranges Embree would. A footprint the walk cannot place (more
  facets away, or seen edge-on) is cast after all.

The hit/miss decisions and power fractions are the full sampling's; ranges are too, up
to float32 rounding of the rays (~1e-5 m), except across slight creases, within
crease_tol_m (0: walk every footprint; seen on the rocket body: 0.3 mm at most). The
tests check it on plate edges, creases, a pyramid's apex, a cylinder and the tumbling
rocket body. What it can miss: nothing the full sampling sees, as long as the
viewpoints of one call lie within a box (sensor positions are split into blocks of at
most BLOCK_SPREAD_M); its cost grows with the number of shots near silhouettes, i.e.
with the footprint (scale 30 samples most shots).
``sampling: all`` casts every sub-ray of every shot (the reference the tests use).

Fit: 1-D search of footprint_scale on the likelihood of matched points plus the
unmatched points it puts back on the target; the smallest scale within 2 nats of
the best (the likelihood goes flat once every edge point is explained).
"""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import Literal

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect
from lidar_sim_ros.core.geometry import BodyRays, Hits, Target, body_rays, split_over_threads
from lidar_sim_ros.core.geometry_kernels import _rotate
from lidar_sim_ros.core.silhouette import (FAST_ALGEBRA, cones_touching_edges, mesh_edges,
                                          origin_box)

WALK_STEPS = 8          # facets a sub-ray is followed across before the shot is cast instead
BLOCK_SPREAD_M = 0.25   # sensor positions (body frame) per silhouette set, at most this apart
SERIES_LIMIT = 0.01     # tan(a) tan(theta) below which the plane sum's series is exact enough
OCCLUDER_MARGIN_M = 0.002   # occluders this far behind the footprint's farthest sub-ray count
WIDE_FOOTPRINT = 0.8    # footprint radius / median mesh edge above which every shot is cast
CREASE_TOL_M = 1e-3     # range error allowed where a footprint crosses only slight creases
MAX_FOOTPRINT_SCALE = 100.0  # cone / divergence; docs/effects.md, "Parameter bounds"


@lru_cache(maxsize=8)
def footprint_pattern(rings: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-ray layout: normalised radius rho (0..1), azimuth phi (rad), energy weight
    (read-only arrays, computed once per ring count)."""
    rho, phi = [0.0], [0.0]
    for i in range(1, rings + 1):
        k = 6 * i
        rho += [i / rings] * k
        # Stagger alternate rings so sub-rays do not line up radially.
        phi += list(2 * np.pi * (np.arange(k) + 0.5 * (i % 2)) / k)
    rho, phi = np.array(rho), np.array(phi)
    out = rho, phi, np.exp(-2.0 * rho ** 2)
    for a in out:
        a.flags.writeable = False
    return out


@lru_cache(maxsize=64)
def footprint_rings(half_angle_rad: float, rings: int) -> tuple[np.ndarray, np.ndarray]:
    """Per ring of the pattern (axis excluded): how far its sub-rays land on a plane
    relative to the outer ring's (tan of its angle off the axis over tan of the
    half-angle), and its share of the beam's energy."""
    rho, _, energy = footprint_pattern(rings)
    radius = np.arange(1, rings + 1) / rings
    share = np.array([energy[rho == r].sum() for r in radius]) / energy.sum()
    out = np.tan(half_angle_rad * radius) / np.tan(half_angle_rad), share
    for a in out:
        a.flags.writeable = False
    return out


def perpendicular_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) perpendicular to unit vectors d and to each other."""
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(d, u)


def sample_footprint(target: Target, directions_lidar: np.ndarray, poses, half_angle_rad: float,
                     rings: int = 2, range_mode: str = 'mean') -> Hits:
    """The full model: K sub-rays for every shot (module docstring); normals in the lidar frame."""
    d = np.asarray(directions_lidar, float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    rays = body_rays(d, poses)
    return _cast_subrays(target, rays, np.arange(len(d)), half_angle_rad, rings, range_mode)


def footprint_cast(target: Target, directions_lidar: np.ndarray, poses, half_angle_rad: float,
                   rings: int = 2, range_mode: str = 'mean',
                   crease_tol_m: float = CREASE_TOL_M) -> Hits:
    """The same model as ``sample_footprint``; sub-rays cast only where a silhouette may
    cross the footprint (module docstring). ``crease_tol_m``: range error allowed where a
    footprint crosses only slight creases (0: follow every sub-ray across them)."""
    rays = body_rays(directions_lidar, poses)   # no cast order: rows in input order
    axis = target.cast_body_rays(rays, barycentric=True)    # fresh arrays: updated in place
    if _wider_than_facets(target, axis, half_angle_rad):
        return _cast_subrays(target, rays, np.arange(len(rays)), half_angle_rad, rings, range_mode)
    sample = _footprints_on_sheets(target, rays, axis, half_angle_rad, rings, range_mode,
                                   crease_tol_m)
    fraction = axis.hit.astype(float)
    idx = np.flatnonzero(sample)
    if len(idx):
        sub = _cast_subrays(target, rays, idx, half_angle_rad, rings, range_mode)
        for name in ('hit', 'range_m', 'normal', 'incidence_rad', 'cos_incidence', 'material', 'face'):
            getattr(axis, name)[idx] = getattr(sub, name)
        fraction[idx] = sub.power_fraction
    return replace(axis, power_fraction=fraction)


def _wider_than_facets(target: Target, axis: Hits, half_angle_rad: float) -> bool:
    """Footprints wider than WIDE_FOOTPRINT x the mesh's median edge (at the median range):
    nearly every shot would be walked far or cast anyway, so cast them all."""
    ranges = np.sort(axis.range_m[::64][axis.hit[::64]])  # a sample is enough for a median
    if len(ranges) == 0:
        return False
    radius = float(ranges[len(ranges) // 2]) * np.tan(half_angle_rad)
    return radius > WIDE_FOOTPRINT * mesh_edges(target).median_edge_m


def sampled_shots(target: Target, directions_lidar: np.ndarray, poses, half_angle_rad: float,
                  rings: int = 2, range_mode: str = 'mean',
                  crease_tol_m: float = CREASE_TOL_M) -> np.ndarray:
    """The shots ``footprint_cast`` casts sub-rays for (bool mask); the others follow from
    their axis ray."""
    rays = body_rays(directions_lidar, poses)
    axis = target.cast_body_rays(rays, barycentric=True)
    if _wider_than_facets(target, axis, half_angle_rad):
        return np.ones(len(rays), bool)
    return _footprints_on_sheets(target, rays, axis, half_angle_rad, rings, range_mode,
                                 crease_tol_m)


def _footprints_on_sheets(target: Target, rays: BodyRays, axis: Hits, half_angle_rad: float,
                          rings: int, range_mode: str, crease_tol_m: float) -> np.ndarray:
    """Ranges of the footprints that lie on one sheet of facets, written into
    ``axis.range_m``; returns the shots whose sub-rays must be cast instead."""
    edges = mesh_edges(target)
    tan_a = np.tan(half_angle_rad)
    rho, phi, energy = footprint_pattern(rings)
    tilt = np.tan(half_angle_rad * rho)
    sample = np.zeros(len(rays), bool)
    for block, lo, hi in _blocks(rays.origins_m):
        o, dirs = rays.origins_m[block], rays.directions[block]
        candidate, a_m, b_m = edges.candidates_with_segments(lo, hi)
        hits = np.flatnonzero(axis.hit) if isinstance(block, slice) else block[axis.hit[block]]
        # Ranges of the footprints on one sheet (in place), the shots to cast instead, and
        # how deep an occluder may sit for each (misses: any depth). Most footprints lie
        # inside the axis facet: that takes the hit's barycentric coordinates only.
        limit = np.full(len(rays), np.inf)
        if range_mode == 'mean':
            ring_reach, ring_share = footprint_rings(half_angle_rad, rings)
            hits = np.concatenate(split_over_threads(
                len(hits), target.threads, lambda part: _footprints_in_facets(
                    hits[part], axis.range_m, axis.cos_incidence, axis.face, axis.barycentric,
                    edges.face_bounds, edges.face_star, edges.face_crease,
                    tilt, energy, ring_reach, ring_share, crease_tol_m, limit)))
        split_over_threads(len(hits), target.threads, lambda part: _sheet_footprint_ranges(
            rays.origins_m, rays.directions, hits[part], axis.face, tilt, np.cos(phi), np.sin(phi),
            energy, rings, range_mode == 'first', edges.face_planes, edges.face_region,
            edges.region_lines, edges.face_neighbour, edges.face_edge, candidate, WALK_STEPS,
            axis.range_m, limit, sample))
        limit = limit[block]
        # Silhouettes that may be (a_m, b_m), and curves where parts of the mesh pass
        # through each other.
        sample[block] |= np.concatenate(split_over_threads(len(o), target.threads, lambda part: (
            cones_touching_edges(o[part], dirs[part], tan_a, a_m, b_m, limit[part]))))
    return sample


def footprint_surfaces(target: Target, directions_lidar: np.ndarray, poses, half_angle_rad: float,
                       rings: int, index: np.ndarray, min_separation_m: float) -> dict:
    """The separate surfaces in the footprints of shots ``index``: a multi-return receiver's
    view of a depth step. Each shot's hit sub-rays, sorted by range, split where consecutive
    ranges differ by more than ``min_separation_m`` (m); shots with two or more groups give
    one row per group: ``shot``, ``range_m`` (energy-weighted mean of the group, m),
    ``fraction`` (the group's share of the beam's energy, -), and the ``face``, ``material``
    and ``cos_incidence`` of the group's strongest sub-ray."""
    rho, phi, energy = footprint_pattern(rings)
    k = len(rho)
    rays = body_rays(np.asarray(directions_lidar, float), poses)
    o_sub, d_sub = _subrays(rays.origins_m, rays.directions, index, np.tan(half_angle_rad * rho),
                            np.cos(phi), np.sin(phi))
    face, tfar = target.intersect(o_sub, d_sub)
    face, rng = face.reshape(-1, k), np.where(face >= 0, tfar, np.inf).reshape(-1, k)
    order = np.argsort(rng, axis=1, kind='stable')
    rng = np.take_along_axis(rng, order, 1)
    face = np.take_along_axis(face, order, 1)
    e = energy[order]
    hit = np.isfinite(rng)
    step = np.zeros_like(hit)
    with np.errstate(invalid='ignore'):
        step[:, 1:] = hit[:, 1:] & (np.diff(rng, axis=1) > min_separation_m)
    group = np.cumsum(step, axis=1)
    split = np.flatnonzero(group[:, -1] > 0)
    if len(split) == 0:
        return {'shot': np.zeros(0, np.int64)}
    rows, cols = np.nonzero(hit[split])
    key = rows * k + group[split][rows, cols]                 # (shot, group), in order
    uniq, start = np.unique(key, return_index=True)
    w = e[split][rows, cols]
    e_sum = np.add.reduceat(w, start)
    r_mean = np.add.reduceat(w * rng[split][rows, cols], start) / e_sum
    # The group's strongest sub-ray: the largest energy (first of equals) within each group.
    best = np.lexsort((-w, key))[start]
    f = face[split][rows, cols][best]
    d = np.take_along_axis(d_sub.reshape(-1, k, 3)[split], order[split][:, :, None], 1)
    d = d[rows, cols][best].astype(float)
    cos_i = np.abs(np.einsum('ij,ij->i', target.face_normals[f], d / np.linalg.norm(d, axis=1)[:, None]))
    return {'shot': index[split][uniq // k], 'range_m': r_mean, 'fraction': e_sum / energy.sum(),
            'face': f.astype(np.int64), 'material': target.face_material[f].astype(np.int16),
            'cos_incidence': cos_i}


def _cast_subrays(target: Target, rays: BodyRays, index: np.ndarray, half_angle_rad: float,
                  rings: int, range_mode: str) -> Hits:
    """Cast the K sub-rays of shots ``index`` (rows of ``rays``) and combine them."""
    rho, phi, energy = footprint_pattern(rings)
    tilt = np.tan(half_angle_rad * rho)
    o_sub, d_sub = _subrays(rays.origins_m, rays.directions, index, tilt, np.cos(phi), np.sin(phi))
    face_k, tfar_k = target.intersect(o_sub, d_sub)
    hit, range_m, fraction, normal, cos_i, face = _combine_subrays(
        face_k, tfar_k, d_sub, index, energy, range_mode == 'first', target.face_normals,
        rays.quat_xyzw)
    material = np.where(hit, target.face_material[np.maximum(face, 0)], -1).astype(np.int16)
    return Hits(hit, range_m, normal, np.arccos(cos_i), material, face, power_fraction=fraction,
                cos_incidence=cos_i)


@njit(cache=True, nogil=True, error_model='numpy')
def _subrays(origins, directions, index, tilt, cos_phi, sin_phi):
    """Body-frame sub-rays (float32, K per shot, shot-major) of shots ``index``: sub-ray j
    is d + tan(a rho_j) (cos phi_j u + sin phi_j v), unit, from the shot's origin."""
    k = tilt.shape[0]
    m = index.shape[0]
    o_sub = np.empty((m * k, 3), np.float32)
    d_sub = np.empty((m * k, 3), np.float32)
    for q in range(m):
        i = index[q]
        dx, dy, dz, ux, uy, uz, vx, vy, vz = _axis_basis(directions[i, 0], directions[i, 1],
                                                         directions[i, 2])
        for j in range(k):
            t = tilt[j]
            scale = 1.0 / np.sqrt(1.0 + t * t)
            cp, sp = cos_phi[j] * t, sin_phi[j] * t
            row = q * k + j
            o_sub[row, 0], o_sub[row, 1], o_sub[row, 2] = origins[i, 0], origins[i, 1], origins[i, 2]
            d_sub[row, 0] = (dx + cp * ux + sp * vx) * scale
            d_sub[row, 1] = (dy + cp * uy + sp * vy) * scale
            d_sub[row, 2] = (dz + cp * uz + sp * vz) * scale
    return o_sub, d_sub


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _axis_basis(dx, dy, dz):
    """Unit d and two unit vectors u, v perpendicular to it (as ``perpendicular_basis``)."""
    dx, dy, dz = np.float64(dx), np.float64(dy), np.float64(dz)
    norm = np.sqrt(dx * dx + dy * dy + dz * dz)
    dx, dy, dz = dx / norm, dy / norm, dz / norm
    ux, uy, uz, vx, vy, vz = _perpendicular_pair(dx, dy, dz)
    return dx, dy, dz, ux, uy, uz, vx, vy, vz


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _perpendicular_pair(dx, dy, dz):
    """u = unit(d x h) (h = z, or x when d is near z) and v = d x u, for a unit d."""
    hx, hy, hz = (0.0, 0.0, 1.0) if abs(dz) < 0.9 else (1.0, 0.0, 0.0)
    ux, uy, uz = dy * hz - dz * hy, dz * hx - dx * hz, dx * hy - dy * hx
    norm = np.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / norm, uy / norm, uz / norm
    return ux, uy, uz, dy * uz - dz * uy, dz * ux - dx * uz, dx * uy - dy * ux


@njit(cache=True, nogil=True, error_model='numpy')
def _combine_subrays(face_k, tfar_k, d_sub, index, energy, first, face_normals, quat_xyzw):
    """Per shot: hit (any sub-ray), range (energy-weighted mean or nearest), power
    fraction, and the strongest hit sub-ray's normal (lidar frame, toward the sensor),
    cos(incidence) and face."""
    k = energy.shape[0]
    m = index.shape[0]
    total = 0.0
    for j in range(k):
        total += energy[j]
    hit = np.zeros(m, np.bool_)
    range_m = np.full(m, np.inf)
    fraction = np.zeros(m)
    normal = np.zeros((m, 3))
    cos_i = np.full(m, np.nan)
    face = np.full(m, -1, np.int64)
    one_q = quat_xyzw.shape[0] == 1
    for q in range(m):
        e_hit, weighted, low, best, rep = 0.0, 0.0, np.inf, -1.0, -1
        for j in range(k):
            row = q * k + j
            if face_k[row] < 0:
                continue
            e = energy[j]
            e_hit += e
            weighted += e * tfar_k[row]
            low = min(low, np.float64(tfar_k[row]))
            if e > best:
                best, rep = e, row
        if rep < 0:
            continue
        hit[q] = True
        fraction[q] = e_hit / total
        range_m[q] = low if first else weighted / e_hit
        f = face_k[rep]
        nx, ny, nz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
        c = -(nx * d_sub[rep, 0] + ny * d_sub[rep, 1] + nz * d_sub[rep, 2])
        if c < 0.0:                         # two-sided surfaces: the normal faces the sensor
            nx, ny, nz, c = -nx, -ny, -nz, -c
        iq = 0 if one_q else index[q]
        normal[q, 0], normal[q, 1], normal[q, 2] = _rotate(
            quat_xyzw[iq, 0], quat_xyzw[iq, 1], quat_xyzw[iq, 2], quat_xyzw[iq, 3], nx, ny, nz)
        cos_i[q] = min(c, 1.0)
        face[q] = f
    return hit, range_m, fraction, normal, cos_i, face


def _blocks(origins_m: np.ndarray) -> list:
    """Ray rows (a slice, or index arrays) split until each block's sensor positions lie
    within BLOCK_SPREAD_M, each with the corners of its positions' box: one block per
    frame in the simulator, a few in a comparison spanning many frames."""
    lo, hi = origin_box(origins_m)
    if len(origins_m) == 0 or np.linalg.norm(hi - lo) <= BLOCK_SPREAD_M:
        return [(slice(None), lo, hi)]
    out, todo = [], [np.arange(len(origins_m))]
    while todo:
        idx = todo.pop()
        lo, hi = origin_box(origins_m[idx])
        if len(idx) < 64 or np.linalg.norm(hi - lo) <= BLOCK_SPREAD_M:
            out.append((idx, lo, hi))
            continue
        split = np.argsort(origins_m[idx, int(np.argmax(hi - lo))], kind='stable')
        half = len(idx) // 2
        todo += [idx[split[:half]], idx[split[half:]]]
    return out


# Reassociation and FMA only (no finite-math flags: inf marks a missing star or crease).
@njit(cache=True, nogil=True, error_model='numpy', fastmath=FAST_ALGEBRA)
def _footprints_in_facets(index, range_m, cos_incidence, face, barycentric, face_bounds,
                          face_star, face_crease, tilt, energy, ring_reach, ring_share,
                          crease_tol, limit):
    """The energy-weighted mean range of shots whose footprint lies on the axis facet's
    plane, or within ``crease_tol`` (m) of it, from the axis hit alone (range_m,
    cos_incidence, barycentric (u, v) on the facet, ``MeshEdges.face_bounds``, and for
    footprints that reach past the facet's flat region ``face_star`` (the facet's
    altitudes among them) and ``face_crease``); returns the others (the shots of
    ``index`` to walk), in order.

    The cone meets the facet's plane within spread = r0 sin a / cos(theta + a) of the
    axis point p. The distance of p to each boundary line of the facet's flat region (the
    facet's own edges where it stands alone) is the barycentric mix of the line's
    distances at the facet's vertices (``face_bounds``): a footprint farther than the
    spread from all of them lies on one plane (on a cylinder's column of quads, most of
    the footprints that cross a diagonal). Otherwise p lies w_k h_k from the facet's edge
    facing vertex k. On the plane, the sub-rays' ranges average to
    r0 (1 + sum_j e_j t_j^2 (1 + tan^2 theta) / (2 sum_j e_j))
    to second order in t tan(theta) (off by < (t tan theta)^4 / 2 relative: used below
    SERIES_LIMIT).

    A footprint that leaves the facet but stays in the star of one of its vertices v (the
    faces around v, normals within tau of each other: ``MeshEdges.vertex_tilt_rad``) gets
    the plane's answer when that is within crease_tol of the mean of the sub-rays' ranges
    on the star. Over the facet's plane the star is a surface through p that is the
    plane itself up to the facet's edges (``margin`` from p) and rises at slope
    <= tan(tau) beyond. Sub-ray j, at incidence <= theta' (theta plus the half-angle),
    meets the plane at x'_j, |x'_j - p| <= s_j = spread t_j / t_max, and the star at x_j
    with |x_j - x'_j| (cot theta' - tan tau) <= tan tau |x'_j - p|, so
    |x_j - p| <= s_j / (1 - lean), lean = tan tau tan theta'. The star lies within
    tan tau (|x_j - p| - margin) of the plane there, which moves the range by at most
    that over cos theta': at most ``worst`` for any sub-ray, and the energy-weighted
    mean of the bounds over the rings (ring_reach, ring_share: each ring's t_j / t_max and
    share of the energy) for their mean. This holds while the footprint stays in the star:
    |p - v| (from the barycentric coordinates and the edge lengths) plus its length over
    the surface, spread / ((1 - lean) cos(tau)), within the star's reach. A footprint
    that reaches a single edge of the facet is bounded the same way with tau the fold of
    that edge (``MeshEdges.face_crease``) while it stays on the facet beyond: p's
    distances to that facet's two other edges, unfolded across the crease, exceed its
    length over the surface.
    """
    k = energy.shape[0]
    total, moment2 = 0.0, 0.0
    for j in range(k):
        total += energy[j]
        moment2 += energy[j] * tilt[j] * tilt[j]
    t_max = tilt[k - 1]
    lift = np.sqrt(1.0 + t_max * t_max)
    half_moment = 0.5 * moment2 / total
    beyond = np.empty(index.shape[0], np.int64)
    count = 0
    for q in range(index.shape[0]):
        i = index[q]
        r0 = range_m[i]
        cos_i = min(cos_incidence[i], 1.0)
        sin_i = np.sqrt(1.0 - cos_i * cos_i)
        if sin_i * t_max >= SERIES_LIMIT * cos_i:
            beyond[count] = i
            count += 1
            continue
        inv_cos = 1.0 / cos_i
        # cos a / cos(theta + a) <= inv_cos x above: bounds from above, one division less.
        above = far_secant_bound(1.0, sin_i * t_max * inv_cos)
        inv_far = inv_cos * above                 # >= 1 / (cos_i - sin_i t_max)
        spread = 1.01 * r0 * t_max * inv_far + 1e-6
        f = face[i]
        w1, w2 = np.float64(barycentric[i, 0]), np.float64(barycentric[i, 1])
        w0 = 1.0 - w1 - w2
        # Inside the facet's flat region (or the facet) by more than the spread: on one
        # plane. Rows are indexed in place: a view per shot costs reference counting.
        inside = min(w0 * face_bounds[f, 0] + w1 * face_bounds[f, 1] + w2 * face_bounds[f, 2],
                     w0 * face_bounds[f, 3] + w1 * face_bounds[f, 4] + w2 * face_bounds[f, 5],
                     w0 * face_bounds[f, 6] + w1 * face_bounds[f, 7] + w2 * face_bounds[f, 8],
                     np.float64(face_bounds[f, 9]))
        worst, mean_err = 0.0, 0.0
        if inside < spread:
            # Distances to edges 1, 2, 0 (vertices k + 1, k + 2: facing vertex k).
            m0, m1, m2 = w0 * face_star[f, 0], w1 * face_star[f, 1], w2 * face_star[f, 2]
            margin = min(m0, m1, m2)
            worst, mean_err = np.inf, np.inf
            if crease_tol > 0.0:
                tan_far = (sin_i + cos_i * t_max) * inv_far         # tan(theta')
                sec_far = lift * inv_far                            # 1 / cos(theta')
                l01 = np.float64(face_star[f, 3])
                l12, l20 = np.float64(face_star[f, 4]), np.float64(face_star[f, 5])
                for c in range(3):
                    # Only the star of a vertex on every edge the footprint crosses can hold
                    # it: not if it reaches the edge facing vertex c.
                    if (m0 if c == 0 else (m1 if c == 1 else m2)) < spread:
                        continue
                    tan_tau = np.float64(face_star[f, 9 + c])
                    lean = tan_tau * tan_far
                    if not lean < 0.5:                 # also inf: not one closed fan
                        continue
                    grow = spread * (1.0 + lean + 2.0 * lean * lean)   # >= spread / (1 - lean)
                    room = face_star[f, 6 + c] - grow * face_star[f, 12 + c]
                    if room <= 0.0:
                        continue
                    if c == 0:
                        d2 = w1 * w1 * l01 + w2 * w2 * l20 + w1 * w2 * (l01 + l20 - l12)
                    elif c == 1:
                        d2 = w0 * w0 * l01 + w2 * w2 * l12 + w0 * w2 * (l01 + l12 - l20)
                    else:
                        d2 = w0 * w0 * l20 + w1 * w1 * l12 + w0 * w1 * (l20 + l12 - l01)
                    if d2 > room * room:
                        continue
                    slope = tan_tau * sec_far
                    mean_bound = 0.0
                    for r in range(ring_reach.shape[0]):
                        mean_bound += ring_share[r] * max(grow * ring_reach[r] - margin, 0.0)
                    if slope * mean_bound < mean_err:
                        mean_err = slope * mean_bound
                        worst = min(worst, slope * (grow - margin))
                near = (m0 < spread) + (m1 < spread) + (m2 < spread)
                if not mean_err <= crease_tol and near == 1:
                    # One crease: across edge e only, into the facet beyond it.
                    e = 0 if m2 < spread else (1 if m0 < spread else 2)
                    tan_tau = np.float64(face_crease[f, e, 0])
                    lean = tan_tau * tan_far
                    if lean < 0.5:
                        grow = spread * (1.0 + lean + 2.0 * lean * lean)
                        slope = tan_tau * sec_far
                        mean_bound = 0.0
                        for r in range(ring_reach.shape[0]):
                            mean_bound += ring_share[r] * max(grow * ring_reach[r] - margin, 0.0)
                        # Where p lies along the edge (from vertex e), from the Gram matrix.
                        w_next, w_far = (w1, w2) if e == 0 else ((w2, w0) if e == 1 else (w0, w1))
                        span2 = np.float64(face_star[f, 3 + e])
                        side_next = np.float64(face_star[f, 3 + (e + 1) % 3])
                        side_far = np.float64(face_star[f, 3 + (e + 2) % 3])
                        span = np.float64(face_crease[f, e, 6])
                        along = (w_next * span2
                                 + 0.5 * w_far * (side_far + span2 - side_next)) / span
                        # Distances of p to the facet's two other edges, unfolded.
                        room = min(along * face_crease[f, e, 2] + margin * face_crease[f, e, 3],
                                   (span - along) * face_crease[f, e, 4]
                                   + margin * face_crease[f, e, 5])
                        if slope * mean_bound <= crease_tol and room >= grow * face_crease[f, e, 1]:
                            mean_err = slope * mean_bound
                            worst = slope * (grow - margin)
            if not mean_err <= crease_tol:
                beyond[count] = i
                count += 1
                continue
        tan2 = sin_i * sin_i * inv_cos * inv_cos
        range_m[i] = r0 * (1.0 + half_moment * (1.0 + tan2))
        limit[i] = _occluder_limit(r0 * lift * above + worst, r0)
    return beyond[:count]


@njit(cache=True, nogil=True, error_model='numpy', fastmath=FAST_ALGEBRA)
def _sheet_footprint_ranges(origins, directions, index, face, tilt, cos_phi, sin_phi, energy,
                            rings, first_mode, planes, region, region_lines, neighbour,
                            face_edge, silhouette, max_steps, range_m, limit, sample):
    """Energy-weighted mean (or nearest) sub-ray range (m) of shots whose footprint stays
    on one sheet of facets.

    origins, directions (N, 3): body-frame rays as cast (float32); index: the shots to
    do; face: their axis facets; tilt, cos_phi, sin_phi, energy: the sub-ray pattern
    (``footprint_pattern``, ``rings`` rings of 6 i equally spaced rays, odd rings turned
    by half a step); planes (F, 4, 4): ``MeshEdges.face_planes``.

    Each sub-ray is intersected with the axis facet's plane; one that lands outside the
    facet is followed across the edge it leaves by to the next facet, and so on. The
    walk fails (the shot is cast instead) at an edge marked in ``silhouette`` (indexed by
    ``face_edge``), at a boundary, or after max_steps facets. On the axis facet's plane
    the sum over a ring has a closed form (below), so only the sub-rays that leave the
    facet are computed one by one.
    Writes, per shot i of ``index``: range_m[i] (the mean or nearest sub-ray range) and
    limit[i] (how far along the axis an occluder of the footprint may sit: past the
    farthest sub-ray hit, with a margin for an occluder touching the sheet, e.g. a
    blanket lying on the tank), or sample[i] = True and limit[i] = -1 (cast the shot).
    """
    m = index.shape[0]
    k = energy.shape[0]
    total = 0.0
    for j in range(k):
        total += energy[j]
    lifts = np.sqrt(1.0 + tilt * tilt)
    scale = 1.0 / lifts
    moment2 = 0.0                            # sum_j e_j t_j^2
    for j in range(k):
        moment2 += energy[j] * tilt[j] * tilt[j]
    ct, st = cos_phi * tilt * scale, sin_phi * tilt * scale
    t_max = tilt[k - 1]
    # Per facet in use (the axis facet, slot 0, and its neighbours across edge e, slot
    # 1 + e): the plane and edge-distance coefficients against (1, d, u, v) of the shot.
    coef = np.empty((4, 4, 4))
    ready = np.zeros(4, np.bool_)
    ns_sub, worst_sub = np.empty(k), np.empty(k)
    leave_sub = np.empty(k, np.int64)
    for q in range(m):
        i = index[q]
        ox, oy, oz = np.float64(origins[i, 0]), np.float64(origins[i, 1]), np.float64(origins[i, 2])
        dx, dy, dz = (np.float64(directions[i, 0]), np.float64(directions[i, 1]),
                      np.float64(directions[i, 2]))
        norm = np.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = dx / norm, dy / norm, dz / norm
        f0 = face[i]
        # The axis ray's range on the facet's plane (n . p = w), its incidence, and the
        # distance of its hit point to the facet's edges: no sub-ray needed yet.
        nx, ny, nz, w = planes[f0, 0, 0], planes[f0, 0, 1], planes[f0, 0, 2], planes[f0, 0, 3]
        nd = nx * dx + ny * dy + nz * dz
        num = w - (nx * ox + ny * oy + nz * oz)
        r0 = num / nd
        cos_i = abs(nd)                      # unit normal, unit d
        sin_i = np.sqrt(max(1.0 - cos_i * cos_i, 0.0))
        if r0 <= 0.0 or cos_i <= sin_i * t_max:
            sample[i], limit[i] = True, -1.0  # the plane cannot hold the footprint
            continue
        grad = sin_i / cos_i                 # tan(incidence)
        a_max = grad * t_max
        # Footprint wholly inside the axis facet? The cone meets the plane within
        # r0 sin a / cos(theta + a) of the axis point; compare with its distance to the edges.
        spread = footprint_spread_m(r0, cos_i, sin_i, t_max)
        px, py, pz = ox + r0 * dx, oy + r0 * dy, oz + r0 * dz
        near0 = _margin(planes, f0, 1, px, py, pz) < spread
        near1 = _margin(planes, f0, 2, px, py, pz) < spread
        near2 = _margin(planes, f0, 3, px, py, pz) < spread
        if near0 or near1 or near2:
            # Still inside the flat region of the facet (a cylinder's column of quads)?
            # (-1: the facet is a region of its own, bounded by the edges just tested.)
            g = region[f0]
            inside_region = g >= 0
            for row in range(region_lines.shape[1] if inside_region else 0):
                if (region_lines[g, row, 0] * px + region_lines[g, row, 1] * py
                        + region_lines[g, row, 2] * pz - region_lines[g, row, 3]) < spread:
                    inside_region = False
                    break
            if inside_region:
                near0, near1, near2 = False, False, False
        if a_max < SERIES_LIMIT and not (near0 or near1 or near2) and not first_mode:
            # The common case: to second order the ring mean of sqrt(1 + t^2) /
            # (1 + a cos x) is 1 + (t^2 + a^2) / 2, off by < a^4 / 2 + t^4 (relative,
            # below float32), and the footprint never leaves the facet.
            far = r0 * lifts[k - 1] / (1.0 - a_max)
            range_m[i] = r0 * (1.0 + 0.5 * moment2 * (1.0 + grad * grad) / total)
            limit[i] = _occluder_limit(far, r0)
            continue
        ux, uy, uz, vx, vy, vz = _perpendicular_pair(dx, dy, dz)
        _facet_coefficients(planes, f0, ox, oy, oz, dx, dy, dz, ux, uy, uz, vx, vy, vz, coef, 0)
        ready[:] = False
        ready[0] = True
        nu, nv = coef[0, 0, 2], coef[0, 0, 3]
        if a_max < SERIES_LIMIT:
            plane_sum = r0 * (total + 0.5 * moment2 * (1.0 + grad * grad))
            plane_reach = r0 * lifts[k - 1] / (1.0 - a_max)
        else:
            plane_sum, plane_reach = _plane_ring_sums(r0, nu / nd, nv / nd, grad, tilt, lifts,
                                                      energy, rings)
        inside = not (near0 or near1 or near2)
        if inside and not first_mode:
            range_m[i], limit[i] = plane_sum / total, _occluder_limit(plane_reach, r0)
            continue
        # Sub-ray by sub-ray: sign(nd) * (distance to edge e) * (n . s_j) needs no division;
        # straight loops over the pattern per near edge (vectorised), then the leavers.
        sign = 1.0 if nd > 0.0 else -1.0
        for j in range(k):
            ns_sub[j] = nd * scale[j] + nu * ct[j] + nv * st[j]
            worst_sub[j] = -1e-9 * abs(ns_sub[j])
            leave_sub[j] = -1
        for e in range(3):
            if not (near0 if e == 0 else (near1 if e == 1 else near2)):
                continue
            c0, cd, cu, cv = sign * coef[0, 1 + e, 0], sign * num * coef[0, 1 + e, 1], \
                sign * num * coef[0, 1 + e, 2], sign * num * coef[0, 1 + e, 3]
            for j in range(k):
                h = c0 * ns_sub[j] + cd * scale[j] + cu * ct[j] + cv * st[j]
                if h < worst_sub[j]:
                    worst_sub[j], leave_sub[j] = h, e
        correction, low, high, walked = 0.0, np.inf, 0.0, True
        for j in range(k):
            ns = ns_sub[j]
            leave = leave_sub[j]
            if leave < 0:
                if first_mode:
                    low = min(low, num / ns)
                continue
            r_plane = num / ns
            r = -1.0
            if not silhouette[face_edge[f0, leave]] and neighbour[f0, leave] >= 0:
                f1 = neighbour[f0, leave]
                slot = 1 + leave
                if not ready[slot]:
                    _facet_coefficients(planes, f1, ox, oy, oz, dx, dy, dz, ux, uy, uz, vx, vy,
                                        vz, coef, slot)
                    ready[slot] = True
                ns1 = coef[slot, 0, 1] * scale[j] + coef[slot, 0, 2] * ct[j] + coef[slot, 0, 3] * st[j]
                if ns1 != 0.0:
                    r = coef[slot, 0, 0] / ns1
                    onward = _leaving_edge(_edge_margin(coef, slot, 0, r, scale[j], ct[j], st[j]),
                                           _edge_margin(coef, slot, 1, r, scale[j], ct[j], st[j]),
                                           _edge_margin(coef, slot, 2, r, scale[j], ct[j], st[j]))
                    if r <= 0.0:
                        r = -1.0
                    elif onward >= 0:
                        r = _walk(ox, oy, oz, dx * scale[j] + ux * ct[j] + vx * st[j],
                                  dy * scale[j] + uy * ct[j] + vy * st[j],
                                  dz * scale[j] + uz * ct[j] + vz * st[j], f1, onward,
                                  planes, neighbour, face_edge, silhouette, max_steps - 2)
            if r <= 0.0:
                walked = False
                break
            correction += energy[j] * (r - r_plane)
            low = min(low, r)
            high = max(high, r)
        if walked:
            range_m[i] = low if first_mode else (plane_sum + correction) / total
            limit[i] = _occluder_limit(max(plane_reach, high), r0)
        else:
            sample[i], limit[i] = True, -1.0


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def footprint_spread_m(r0, cos_i, sin_i, t_max):
    """How far (m) from the axis point a footprint spreads on a plane, at most: the
    cone of half-angle a (tan a = t_max) at range r0 meets a plane at incidence theta
    (cos_i, sin_i) within r0 sin a / cos(theta + a) of the axis point (law of sines in
    the triangle sensor, axis point, farthest rim point) = r0 t_max / (cos_i - sin_i
    t_max); 1 % and 1 um of margin for rounding."""
    return 1.01 * r0 * t_max / (cos_i - sin_i * t_max) + 1e-6


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def far_secant_bound(inv_cos, a):
    """An upper bound of cos a' / cos(theta + a') = 1 / (cos theta - sin theta tan a')
    without a division, for a = tan(theta) tan(a') <= 0.5 (``inv_cos`` = 1 / cos theta):
    it is inv_cos / (1 - a), and 1 / (1 - a) <= 1 + a + 2 a^2."""
    return inv_cos * (1.0 + a + 2.0 * a * a)


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _occluder_limit(farthest, axis_range):
    """Depth (m) along the axis up to which an edge in the cone may hide part of the
    footprint: the farthest sub-ray hit plus its spread past the axis hit (edges between
    the sampled azimuths), 1e-3 of the range and OCCLUDER_MARGIN_M (an occluder lying on
    the surface, like a blanket on the tank)."""
    return 2.0 * farthest - axis_range + 1e-3 * farthest + OCCLUDER_MARGIN_M


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _margin(planes, f, row, px, py, pz):
    """Signed distance (m) of the point p to the edge line of ``planes[f, row]`` (> 0 inside)."""
    return planes[f, row, 0] * px + planes[f, row, 1] * py + planes[f, row, 2] * pz - planes[f, row, 3]


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _plane_ring_sums(r0, a_u, a_v, grad, tilt, lifts, energy, rings):
    """sum_j e_j r_j over the pattern on one plane, and a bound on max_j r_j (m).

    On a plane, r_j = r0 sqrt(1 + t^2) / (1 + t (A cos phi_j + B sin phi_j)) with
    (A, B) = (n.u, n.v) / n.d = tan(theta) (cos psi, sin psi). Over a ring of M equally
    spaced azimuths phi_k = phi_0 + 2 pi k / M (M even), with a = t tan(theta),
    rho = a / (1 + sqrt(1 - a^2)) and the Poisson-kernel series of 1 / (1 + a cos x),
        sum_k 1 / (1 + a cos(phi_k - psi))
            = M / sqrt(1 - a^2) (1 - rho^2M) / (1 - 2 rho^M cos(M (phi_0 - psi)) + rho^2M).
    Ring i has M = 6 i and M phi_0 = pi (i odd) or 0, so cos(M (phi_0 - psi)) = +-cos(M psi).
    """
    total = energy[0] * r0                  # the axis sub-ray
    bound = r0
    cos_psi, sin_psi = (a_u / grad, a_v / grad) if grad > 0.0 else (1.0, 0.0)
    # w6 = (cos psi + i sin psi)^6, then w6^i for ring i.
    re2, im2 = cos_psi * cos_psi - sin_psi * sin_psi, 2.0 * cos_psi * sin_psi
    re3, im3 = re2 * cos_psi - im2 * sin_psi, re2 * sin_psi + im2 * cos_psi
    re6, im6 = re3 * re3 - im3 * im3, 2.0 * re3 * im3
    re_m, im_m = 1.0, 0.0
    j = 1
    for ring in range(1, rings + 1):
        count = 6 * ring
        t = tilt[j]
        re_m, im_m = re_m * re6 - im_m * im6, re_m * im6 + im_m * re6
        a = t * grad
        root = np.sqrt(1.0 - a * a)
        rho = a / (1.0 + root)
        rho2 = rho * rho
        rho6 = rho2 * rho2 * rho2
        rho_m = rho6
        for _ in range(ring - 1):
            rho_m *= rho6
        cos_m = re_m if ring % 2 == 0 else -re_m
        ring_sum = count / root * (1.0 - rho_m * rho_m) / (1.0 - 2.0 * rho_m * cos_m + rho_m * rho_m)
        lift = lifts[j]
        total += energy[j] * r0 * lift * ring_sum
        bound = max(bound, r0 * lift / (1.0 - a))
        j += count
    return total, bound


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _leaving_edge(g0, g1, g2):
    """The edge (0-2) a point leaves a facet by (the most negative signed distance), or -1
    if it is inside; on an edge counts as inside (both facets give the same range)."""
    leave, worst = -1, -1e-9
    if g0 < worst:
        leave, worst = 0, g0
    if g1 < worst:
        leave, worst = 1, g1
    if g2 < worst:
        leave = 2
    return leave


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _edge_margin(coef, slot, e, r, scale, ct, st):
    """Signed distance (m) to edge e of facet ``slot`` of the sub-ray point at range r."""
    return coef[slot, 1 + e, 0] + r * (coef[slot, 1 + e, 1] * scale + coef[slot, 1 + e, 2] * ct
                                       + coef[slot, 1 + e, 3] * st)


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _facet_coefficients(planes, f, ox, oy, oz, dx, dy, dz, ux, uy, uz, vx, vy, vz, coef, slot):
    """coef[slot, row] = (w - a . o, a . d, a . u, a . v) for each row (a, w) of planes[f]:
    the plane (row 0: range numerator and denominator terms) and the three edges (rows
    1-3: signed distance at range r along s is coef0 + r (a . s))."""
    for row in range(4):
        ax, ay, az, w = planes[f, row, 0], planes[f, row, 1], planes[f, row, 2], planes[f, row, 3]
        a_o = ax * ox + ay * oy + az * oz
        coef[slot, row, 0] = (w - a_o) if row == 0 else (a_o - w)
        coef[slot, row, 1] = ax * dx + ay * dy + az * dz
        coef[slot, row, 2] = ax * ux + ay * uy + az * uz
        coef[slot, row, 3] = ax * vx + ay * vy + az * vz


@njit(cache=True, nogil=True, error_model='numpy', fastmath=FAST_ALGEBRA)
def _walk(ox, oy, oz, sx, sy, sz, f, leave, planes, neighbour, face_edge, silhouette, max_steps):
    """Range (m) at which the ray o + r s meets the sheet, starting from facet f which it
    leaves by edge ``leave``; -1 if the walk meets a silhouette, a boundary or runs out."""
    for step in range(max_steps):
        if silhouette[face_edge[f, leave]]:
            return -1.0
        f = neighbour[f, leave]
        if f < 0:
            return -1.0
        ns = planes[f, 0, 0] * sx + planes[f, 0, 1] * sy + planes[f, 0, 2] * sz
        if ns == 0.0:
            return -1.0
        dist = (planes[f, 0, 3] - (planes[f, 0, 0] * ox + planes[f, 0, 1] * oy
                                   + planes[f, 0, 2] * oz)) / ns
        if dist <= 0.0:
            return -1.0
        hx, hy, hz = ox + dist * sx, oy + dist * sy, oz + dist * sz
        leave = _leaving_edge(
            planes[f, 1, 0] * hx + planes[f, 1, 1] * hy + planes[f, 1, 2] * hz - planes[f, 1, 3],
            planes[f, 2, 0] * hx + planes[f, 2, 1] * hy + planes[f, 2, 2] * hz - planes[f, 2, 3],
            planes[f, 3, 0] * hx + planes[f, 3, 1] * hy + planes[f, 3, 2] * hz - planes[f, 3, 3])
        if leave < 0:
            return dist
    return -1.0


@register
class BeamDivergence(Effect):
    """Footprint sampled by K sub-rays: returns beyond silhouettes, mixed depths."""

    name = 'beam_divergence'
    bounds = {'footprint_scale': (0.0, 30.0)}
    initial = {'footprint_scale': 0.0}
    needs_repredict = True
    # The likelihood goes flat once every edge point is explained: the smallest scale
    # within 2 nats of the best.
    fit_options = {'n_grid': 16, 'prefer_low': 2.0}

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        footprint_scale: float = Field(
            0.0, ge=0.0, le=MAX_FOOTPRINT_SCALE, description='cone full angle / beam divergence (-); 0 = single ray')
        rings: int = Field(2, ge=1, le=5, description='sub-ray rings (K = 1 + 3 rings (rings + 1))')
        range_mode: Literal['mean', 'first'] = 'mean'
        sampling: Literal['edges', 'all'] = Field(
            'edges', description="'edges': sub-rays only where the footprint may see more than "
                                 "one surface (same model, a fraction of the cost); 'all': every shot")

    def extra_returns(self, ctx, shots: np.ndarray | None = None):
        """A multi-return receiver (``shots`` None) sees a footprint across a depth step as
        separate returns: one per surface farther apart than its ``min_separation_m``, each
        with its share of the beam's energy, in place of the shot's mixed echo. Only shots
        whose footprint may cross an edge (``sampled_shots``) are looked at."""
        half = 0.5 * self.params.footprint_scale * ctx.divergence_rad
        if shots is not None or half <= 0 or ctx.scene is None or ctx.direction is None:
            return None
        from lidar_sim_ros.core import reflection
        from lidar_sim_ros.core.effects.base import ExtraReturns
        from lidar_sim_ros.core.scan_flash import pixel_view_sr
        scene = ctx.scene
        sep = scene.sensor.detection.returns.min_separation_m
        index = np.flatnonzero(sampled_shots(scene.target, ctx.direction, scene.poses, half,
                                             self.params.rings) & ctx.hit)
        if len(index) == 0:
            return None
        g = footprint_surfaces(scene.target, ctx.direction, scene.poses, half, self.params.rings,
                               index, sep)
        if len(g['shot']) == 0:
            return None
        kd, ks, n = (scene.materials.column(c) for c in ('kd', 'ks', 'n'))
        m = g['material']
        pixel_sr = pixel_view_sr(scene.sensor, ctx.direction[g['shot']])
        power = g['fraction'] * reflection.return_power_w(
            g['range_m'], np.arccos(np.clip(g['cos_incidence'], 0.0, 1.0)), kd.take(m), ks.take(m),
            n.take(m), scene.sensor.optics, g['cos_incidence'], pixel_sr)
        return ExtraReturns(shot=g['shot'], range_m=g['range_m'], power_w=power, material=m,
                            face=g['face'], via_material=np.full(len(m), -1, np.int16),
                            source=self.name, replaces_echo=True)

    def cast_reach_rad(self, divergence_rad: float) -> float:
        """Half-angle of the cone (rad): rays farther from an edge see one plane only."""
        return 0.5 * self.params.footprint_scale * divergence_rad

    def cast(self, target, directions_lidar: np.ndarray, poses,
             divergence_rad: float) -> Hits | None:
        half_angle = 0.5 * self.params.footprint_scale * divergence_rad
        if half_angle <= 0:
            return None
        method = footprint_cast if self.params.sampling == 'edges' else sample_footprint
        return method(target, directions_lidar, poses, half_angle, self.params.rings,
                      self.params.range_mode)
