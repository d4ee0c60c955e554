"""Compiled per-ray loops of the geometric model (numba), around the Embree call.

A P-60 frame has ~21k shots, each with its own target pose. In numpy, moving the
rays into the body frame and turning Embree's face ids back into ranges, normals
and incidence angles took ~60 array passes (about twice Embree's own time); each
loop below does one shot per iteration in one pass. ``Poses.to_body`` /
``vector_to_body`` (rotation matrices, numpy) stay the reference the tests
(``test/test_geometry_kernels.py``) check these against.

Conventions (``pose.py``): ``p_lidar = R p_body + position``, R from the unit xyzw
quaternion. A quaternion or position array with one row applies to every ray.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline='always')
def _rotate(qx, qy, qz, qw, vx, vy, vz):
    """v rotated by the unit quaternion (x, y, z, w): v + w t + q_v x t, t = 2 q_v x v."""
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (vx + qw * tx + (qy * tz - qz * ty),
            vy + qw * ty + (qz * tx - qx * tz),
            vz + qw * tz + (qx * ty - qy * tx))


@njit(cache=True, inline='always')
def _ray_to_body(quat_xyzw, position_m, origin_lidar_m, dir_lidar, i):
    """Ray ``i``'s origin and direction in the body frame (float64 each; arrays as
    ``rays_to_body``: one row is every ray's)."""
    iq = 0 if quat_xyzw.shape[0] == 1 else i
    ip = 0 if position_m.shape[0] == 1 else i
    io = 0 if origin_lidar_m.shape[0] == 1 else i
    # The inverse rotation: conjugate quaternion.
    qx, qy, qz, qw = -quat_xyzw[iq, 0], -quat_xyzw[iq, 1], -quat_xyzw[iq, 2], quat_xyzw[iq, 3]
    ox, oy, oz = _rotate(qx, qy, qz, qw,
                         origin_lidar_m[io, 0] - position_m[ip, 0],
                         origin_lidar_m[io, 1] - position_m[ip, 1],
                         origin_lidar_m[io, 2] - position_m[ip, 2])
    dx, dy, dz = _rotate(qx, qy, qz, qw, dir_lidar[i, 0], dir_lidar[i, 1], dir_lidar[i, 2])
    return ox, oy, oz, dx, dy, dz


@njit(cache=True, inline='always')
def _box_of(box_lo, box_hi):
    """Centre, half-size and the widening (``rays_to_body_in_box``) of a box."""
    hx, hy, hz = ((box_hi[0] - box_lo[0]) / 2.0, (box_hi[1] - box_lo[1]) / 2.0,
                  (box_hi[2] - box_lo[2]) / 2.0)
    return box_lo[0] + hx, box_lo[1] + hy, box_lo[2] + hz, hx, hy, hz, 2e-3 * max(hx, hy, hz)


@njit(cache=True, nogil=True)
def rays_to_body(quat_xyzw, position_m, origin_lidar_m, dir_lidar, order):
    """Ray origins and directions in the body frame (float32, Embree's input), in cast order.

    quat_xyzw (N|1, 4), position_m (N|1, 3): pose per ray; origin_lidar_m (N|1, 3) (m);
    dir_lidar (N, 3) unit vectors; order (K,) int64: ray ``order[k]`` goes to row k (all
    N rays, or one thread's part of them).
    """
    n = order.shape[0]
    o_body = np.empty((n, 3), np.float32)
    d_body = np.empty((n, 3), np.float32)
    for k in range(n):
        ox, oy, oz, dx, dy, dz = _ray_to_body(quat_xyzw, position_m, origin_lidar_m, dir_lidar,
                                              order[k])
        o_body[k, 0], o_body[k, 1], o_body[k, 2] = ox, oy, oz
        d_body[k, 0], d_body[k, 1], d_body[k, 2] = dx, dy, dz
    return o_body, d_body


@njit(cache=True, inline='always')
def _misses_box(ox, oy, oz, dx, dy, dz, cx, cy, cz, hx, hy, hz, grow):
    """Whether the line o + t d misses the box of centre c and half-size h widened by
    ``grow`` plus 1e-5 of the distance (``rays_to_body_in_box``); no division."""
    wx, wy, wz = ox - cx, oy - cy, oz - cz
    pad = grow + 1e-5 * (abs(wx) + abs(wy) + abs(wz))
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    return ((abs(wy * dz - wz * dy) > (hy + pad) * az + (hz + pad) * ay)
            | (abs(wz * dx - wx * dz) > (hx + pad) * az + (hz + pad) * ax)
            | (abs(wx * dy - wy * dx) > (hx + pad) * ay + (hy + pad) * ax))


@njit(cache=True, nogil=True)
def body_rays_in_box(o_body, d_body, box_lo, box_hi):
    """``rays_to_body_in_box`` for rays already in the body frame (float32 (K, 3)): the
    rows that can meet the box, copied (o, d, float32), and slot (K,) int64 (-1: left out)."""
    n = o_body.shape[0]
    o_kept = np.empty((n, 3), np.float32)
    d_kept = np.empty((n, 3), np.float32)
    slot = np.empty(n, np.int64)
    cx, cy, cz, hx, hy, hz, grow = _box_of(box_lo, box_hi)
    kept = 0
    for k in range(n):
        ox, oy, oz = np.float64(o_body[k, 0]), np.float64(o_body[k, 1]), np.float64(o_body[k, 2])
        dx, dy, dz = np.float64(d_body[k, 0]), np.float64(d_body[k, 1]), np.float64(d_body[k, 2])
        if _misses_box(ox, oy, oz, dx, dy, dz, cx, cy, cz, hx, hy, hz, grow):
            slot[k] = -1
            continue
        slot[k] = kept
        o_kept[kept, 0], o_kept[kept, 1], o_kept[kept, 2] = o_body[k, 0], o_body[k, 1], o_body[k, 2]
        d_kept[kept, 0], d_kept[kept, 1], d_kept[kept, 2] = d_body[k, 0], d_body[k, 1], d_body[k, 2]
        kept += 1
    return o_kept[:kept], d_kept[:kept], slot


@njit(cache=True, nogil=True)
def rays_to_body_in_box(quat_xyzw, position_m, origin_lidar_m, dir_lidar, order, box_lo, box_hi):
    """``rays_to_body`` for the rays whose line can meet the box [box_lo, box_hi] (body
    frame, m; the mesh's bounds): the others cannot hit the mesh and are left out.

    Returns o_body, d_body (float32, the kept rays in cast order) and slot (N,) int64:
    the row of ray ``order[k]`` in o_body, or -1 where it was left out. The test is the
    line's (no division): with w the origin less the box's centre and h its half-size,
    |(w x d)_a| <= h_b |d_c| + h_c |d_b| on each axis a (b, c the other two); a ray
    pointing away from the box is kept (Embree finds it misses). The box is widened by
    1e-3 of its size plus 1e-5 of the ray's distance to it, far more than Embree's
    float32 rounding, so no ray that Embree would hit is left out.
    """
    n = order.shape[0]
    o_body = np.empty((n, 3), np.float32)
    d_body = np.empty((n, 3), np.float32)
    slot = np.empty(n, np.int64)
    cx, cy, cz, hx, hy, hz, grow = _box_of(box_lo, box_hi)
    # One pose and one origin (a global exposure): one origin in the body frame, and each
    # ray's direction alone rotated (a third less work a ray).
    fixed = quat_xyzw.shape[0] == 1 and position_m.shape[0] == 1 and origin_lidar_m.shape[0] == 1
    qx, qy, qz, qw = -quat_xyzw[0, 0], -quat_xyzw[0, 1], -quat_xyzw[0, 2], quat_xyzw[0, 3]
    ox, oy, oz = 0.0, 0.0, 0.0
    if fixed and dir_lidar.shape[0] > 0:
        ox, oy, oz, _, _, _ = _ray_to_body(quat_xyzw, position_m, origin_lidar_m, dir_lidar, 0)
    kept = 0
    for k in range(n):
        if fixed:
            i = order[k]
            dx, dy, dz = _rotate(qx, qy, qz, qw, dir_lidar[i, 0], dir_lidar[i, 1], dir_lidar[i, 2])
        else:
            ox, oy, oz, dx, dy, dz = _ray_to_body(quat_xyzw, position_m, origin_lidar_m,
                                                  dir_lidar, order[k])
        # The test on the float32 ray Embree gets (in float64).
        ox, oy, oz = np.float64(np.float32(ox)), np.float64(np.float32(oy)), np.float64(np.float32(oz))
        dx, dy, dz = np.float64(np.float32(dx)), np.float64(np.float32(dy)), np.float64(np.float32(dz))
        if _misses_box(ox, oy, oz, dx, dy, dz, cx, cy, cz, hx, hy, hz, grow):
            slot[k] = -1
            continue
        slot[k] = kept
        o_body[kept, 0], o_body[kept, 1], o_body[kept, 2] = ox, oy, oz
        d_body[kept, 0], d_body[kept, 1], d_body[kept, 2] = dx, dy, dz
        kept += 1
    return o_body[:kept], d_body[:kept], slot


@njit(cache=True, nogil=True)
def hit_geometry_into(face_cast, tfar_cast, slot, order, face_normals, face_material, quat_xyzw,
                      dir_out, hit, range_m, normal, cos_incidence, material, face):
    """Embree's answers back in ray order, with per-hit geometry, written into the
    output arrays (rows ``order``, which chunks of one frame share without overlapping).

    face_cast (M,) primID (-1 = miss), tfar_cast (M,) distance along the ray (m), for
    the rays cast; slot (K,): the row in them of ray ``order[k]`` (-1: not cast, a miss),
    or empty when every ray was cast (row k);
    face_normals (F, 3) unit body-frame normals; face_material (F,) ids;
    quat_xyzw (N|1, 4) rotates the normals into the frame of dir_out (N, 3), the
    rays' unit directions in that frame (identity quaternion: stay in body frame).
    Writes hit, range_m (inf on a miss), normal (toward the sensor; 0 on a miss),
    cos_incidence (NaN on a miss), material (-1 on a miss), face (-1 on a miss).
    (The arccos is left to numpy: its SIMD loop is ~10x faster than libm's per call.)
    """
    one_q = quat_xyzw.shape[0] == 1
    every = slot.shape[0] == 0
    for k in range(order.shape[0]):
        i = order[k]
        j = k if every else slot[k]
        f = face_cast[j] if j >= 0 else -1
        if f < 0:
            hit[i] = False
            range_m[i] = np.inf
            normal[i, 0], normal[i, 1], normal[i, 2] = 0.0, 0.0, 0.0
            cos_incidence[i] = np.nan
            material[i] = -1
            face[i] = -1
            continue
        iq = 0 if one_q else i
        nx, ny, nz = _rotate(quat_xyzw[iq, 0], quat_xyzw[iq, 1], quat_xyzw[iq, 2], quat_xyzw[iq, 3],
                             face_normals[f, 0], face_normals[f, 1], face_normals[f, 2])
        cos_i = -(nx * dir_out[i, 0] + ny * dir_out[i, 1] + nz * dir_out[i, 2])
        if cos_i < 0.0:  # two-sided surfaces: the normal faces the sensor
            nx, ny, nz, cos_i = -nx, -ny, -nz, -cos_i
        hit[i] = True
        range_m[i] = tfar_cast[j]
        normal[i, 0], normal[i, 1], normal[i, 2] = nx, ny, nz
        cos_incidence[i] = min(cos_i, 1.0)
        material[i] = face_material[f]
        face[i] = f


@njit(cache=True, nogil=True)
def hit_rows_of(face_cast, tfar_cast, slot, start, count, face_normals, face_material, quat_xyzw,
                dir_out):
    """``hit_geometry_into`` for the hits alone: the rays ``start .. start + count - 1`` (in
    order) whose answer is a hit, as compact arrays (no row per miss).

    face_cast, tfar_cast, slot as ``hit_geometry_into`` takes them (slot[k] for ray
    start + k; empty when every ray was cast); quat_xyzw (N|1, 4), dir_out (N, 3) indexed by
    ray. Returns rows (H,) int64 (increasing), range_m (H,), cos_incidence (H,) (the normal
    turned toward the sensor), material (H,) int16 and face (H,) int64: the same numbers
    ``hit_geometry_into`` writes into those rows.
    """
    every = slot.shape[0] == 0
    one_q = quat_xyzw.shape[0] == 1
    n_hit = 0
    for k in range(count):
        j = k if every else slot[k]
        if j >= 0 and face_cast[j] >= 0:
            n_hit += 1
    rows = np.empty(n_hit, np.int64)
    range_m = np.empty(n_hit)
    cos_incidence = np.empty(n_hit)
    material = np.empty(n_hit, np.int16)
    face = np.empty(n_hit, np.int64)
    h = 0
    for k in range(count):
        j = k if every else slot[k]
        if j < 0:
            continue
        f = face_cast[j]
        if f < 0:
            continue
        i = start + k
        iq = 0 if one_q else i
        nx, ny, nz = _rotate(quat_xyzw[iq, 0], quat_xyzw[iq, 1], quat_xyzw[iq, 2], quat_xyzw[iq, 3],
                             face_normals[f, 0], face_normals[f, 1], face_normals[f, 2])
        cos_i = -(nx * dir_out[i, 0] + ny * dir_out[i, 1] + nz * dir_out[i, 2])
        if cos_i < 0.0:  # two-sided surfaces: the normal faces the sensor
            cos_i = -cos_i
        rows[h] = i
        range_m[h] = tfar_cast[j]
        cos_incidence[h] = min(cos_i, 1.0)
        material[h] = face_material[f]
        face[h] = f
        h += 1
    return rows, range_m, cos_incidence, material, face


@njit(cache=True, nogil=True)
def picked_rows_in_order(rows, n, position):
    """The indices k of ``rows`` (distinct rows of an n-row array) in the order
    ``position`` visits them: k for each i in order where ``position[i] == rows[k]``
    (``picked_in_order`` for a few rows given by index)."""
    where = np.full(n, -1, np.int64)
    for k in range(rows.shape[0]):
        where[rows[k]] = k
    out = np.empty(rows.shape[0], np.int64)
    m = 0
    for i in range(position.shape[0]):
        k = where[position[i]]
        if k >= 0:
            out[m] = k
            m += 1
    return out[:m]


@njit(cache=True, nogil=True)
def points_along(directions, index, range_m):
    """Points (K, 3) (m) at range_m (K,) along the unit directions (N, 3) rows ``index`` (K,):
    one pass (numpy's gather then broadcast product took ~4 ns a point)."""
    n = index.shape[0]
    out = np.empty((n, 3))
    for k in range(n):
        i, r = index[k], range_m[k]
        out[k, 0] = directions[i, 0] * r
        out[k, 1] = directions[i, 1] * r
        out[k, 2] = directions[i, 2] * r
    return out


@njit(cache=True, nogil=True)
def picked_in_order(mask, position):
    """``position[i]`` for each i in order where ``mask[position[i]]`` (one pass; numpy's
    gather, flatnonzero and gather again took ~50 us for a flash frame)."""
    out = np.empty(position.shape[0], np.int64)
    n = 0
    for i in range(position.shape[0]):
        j = position[i]
        if mask[j]:
            out[n] = j
            n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def support_over_planes(points, normals, base):
    """max over points p of n_f . p - base_f for each plane f (n_f . p = base_f): how far
    the farthest point lies in front of each plane (m, along its unit normal).

    points (P, 3), normals (F, 3), base (F,). The numpy form, (points @ normals.T).max,
    writes P x F products to memory (a 2M-face mesh against its ~5k hull vertices: 220 s);
    here planes are taken in blocks that stay in cache, point by point.
    """
    n_planes, n_points = normals.shape[0], points.shape[0]
    out = np.empty(n_planes)
    block = 256
    best = np.empty(block)
    for lo in range(0, n_planes, block):
        hi = min(lo + block, n_planes)
        best[:] = -np.inf
        for p in range(n_points):
            px, py, pz = points[p, 0], points[p, 1], points[p, 2]
            for f in range(lo, hi):
                v = normals[f, 0] * px + normals[f, 1] * py + normals[f, 2] * pz
                if v > best[f - lo]:
                    best[f - lo] = v
        for f in range(lo, hi):
            out[f] = best[f - lo] - base[f]
    return out
