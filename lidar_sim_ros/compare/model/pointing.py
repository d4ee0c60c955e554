"""Per-laser pointing offsets fitted through the range gradient across the surface.

A laser whose beam leaves off its configured direction by (a, e) (azimuth, elevation,
rad) measures the range of a neighbouring spot of the surface (``core/effects/
laser_pointing.py``). On a surface with unit normal n (toward the sensor) hit at range
r along the unit direction u, a ray turned by du meets the surface's plane at

    r' = r (n . u) / (n . (u + du)),   so   dr = -r (n . du) / (n . u)   (first order),

with du = a du/daz + e du/del: r tan(theta) along the surface's slope direction. The
residual of a shot of laser l is then g . delta_l, with g = (dr/daz, dr/del) from the
raycast's normal and range, linear in the laser's two offsets: a weighted least-squares
fit of every laser's offsets and one intercept per material jointly, robust inlier
weights (Gaussian vs a uniform floor) as ``fit.laser_offsets_m``. Each offset has a prior
N(0, tau^2), tau^2 the lasers' spread fitted from the data (``shrunk_offsets_rad``): a
laser that barely sees the surface's slope keeps what its points can tell, not noise.

A common turn of every beam is a turn of the whole sensor (its mount: an extrinsic, the
same as the reference pose turned about the sensor), not a laser's own offset. The fit
keeps it (the lasers' mean pointing is part of their calibration, and left out it would
read as a reference pose off on exact poses). With ``turn_only`` the offsets are that
turn alone (three rotations of the sensor, ``common_turn_rad``, fitted by least squares
on the points themselves, each laser weighing as its points do): the lasers' own offsets
are what the full fit gains over it, which must pass the rule for the lasers to be named
(``Diagnosis.own_part_veto``: a mount tilted with every laser right is the pose's
finding; a few lasers off, the rest exact, are no turn). Pure functions over numpy arrays.
"""
from __future__ import annotations

import math

import numpy as np

from lidar_sim_ros.compare.model.likelihood import MIN_SIGMA_M, ROBUST_FLOOR, material_nuisance
from lidar_sim_ros.core.effects.laser_pointing import LaserPointing

MAX_TAN_INCIDENCE = math.tan(math.radians(85.0))   # the gradient's r tan(theta) clipped here
MIN_POINTS_PER_LASER = 20                          # fewer: the laser's offsets stay 0
# The least spread of the lasers' offsets (``laser_spread_rad2``): none off.
LASER_SPREAD_FLOOR_RAD = math.radians(1e-3)
MAX_FIT_RAD = math.radians(LaserPointing.bounds['az_offsets_deg'][1])   # the fit's box


def direction_basis(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """du/daz and du/del (N, 3) of unit directions (lidar frame, ``core/shots.py``'s
    azimuth and elevation): (-cos el sin az, cos el cos az, 0) and
    (-sin el cos az, -sin el sin az, cos el)."""
    d = np.asarray(directions, float)
    az = np.arctan2(d[:, 1], d[:, 0])
    el = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))
    ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
    d_az = np.stack([-ce * sa, ce * ca, np.zeros_like(az)], axis=1)
    d_el = np.stack([-se * ca, -se * sa, ce], axis=1)
    return d_az, d_el


def range_gradient_m_per_rad(range_m: np.ndarray, directions: np.ndarray,
                             normals: np.ndarray) -> np.ndarray:
    """(N, 2): dr/daz and dr/del (m per rad) of rays hitting a surface of unit normal
    ``normals`` (toward the sensor) at ``range_m`` along ``directions`` (module doc),
    the incidence's tan clipped at MAX_TAN_INCIDENCE; 0 where a ray misses."""
    r = np.asarray(range_m, float)
    u = np.asarray(directions, float)
    n = np.asarray(normals, float)
    d_az, d_el = direction_basis(u)
    cos_t = -np.einsum('ij,ij->i', n, u)
    ok = np.isfinite(r) & (cos_t > 0)
    cos_c = np.where(ok, np.maximum(cos_t, 1.0 / math.sqrt(1.0 + MAX_TAN_INCIDENCE ** 2)), 1.0)
    g = np.stack([np.einsum('ij,ij->i', n, d_az), np.einsum('ij,ij->i', n, d_el)], axis=1)
    out = np.where(ok[:, None], np.where(ok, r, 0.0)[:, None] * g / cos_c[:, None], 0.0)
    # |g| / cos is tan(theta) at most (g is n's part across u): keep the clip exact.
    size = np.hypot(out[:, 0], out[:, 1])
    limit = np.where(ok, r, 0.0) * MAX_TAN_INCIDENCE
    over = size > limit
    out[over] *= (limit[over] / size[over])[:, None]
    return out


def rotation_columns(mean_directions: np.ndarray) -> np.ndarray:
    """(2 L, 3): the (az, el) offsets (rad) a small turn w (rad, about the lidar axes) of
    the whole sensor gives each laser of mean direction ``mean_directions[l]``: du = w x u,
    read on du/daz (over its length squared) and du/del."""
    u = np.asarray(mean_directions, float)
    d_az, d_el = direction_basis(u)
    cols = []
    for axis in np.eye(3):
        du = np.cross(axis, u)
        a = np.einsum('ij,ij->i', du, d_az) / np.maximum(np.einsum('ij,ij->i', d_az, d_az), 1e-12)
        e = np.einsum('ij,ij->i', du, d_el)
        cols.append(np.column_stack([a, e]).ravel())
    return np.column_stack(cols)


def common_turn_rad(normal: np.ndarray, rhs: np.ndarray, mean_directions: np.ndarray,
                    fitted: np.ndarray) -> np.ndarray:
    """(L, 2): the (az, el) offsets (rad) of every laser under the one turn of the whole
    sensor that fits the points best: each laser's normal equations on its two offsets
    (``normal`` (L, 2, 2) and ``rhs`` (L, 2), rad^-2 and rad^-1, sums over its points of
    w g g^T and w g r) summed through ``rotation_columns`` over the ``fitted`` lasers and
    solved for the three rotations. A laser weighs as its points do: one that barely sees
    the surface's slope adds little, whatever its own solve would be. 0 where none is
    fitted."""
    out = np.zeros((len(rhs), 2))
    if not np.any(fitted):
        return out
    cols = rotation_columns(mean_directions).reshape(len(rhs), 2, 3)
    r = cols[fitted]
    a = np.einsum('lji,ljk,lkm->im', r, np.asarray(normal, float)[fitted], r)
    b = np.einsum('lji,lj->i', r, np.asarray(rhs, float)[fitted])
    w = np.linalg.pinv(a, rcond=1e-10, hermitian=True) @ b
    out[fitted] = np.einsum('lij,j->li', r, w)
    return out


def _centre_by(v: np.ndarray, group: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per point, the weighted mean of ``v`` over its group."""
    g = np.unique(group, return_inverse=True)[1]
    wsum = np.bincount(g, weights=weight)
    mean = np.bincount(g, weights=weight * v) / np.maximum(wsum, 1e-300)
    return mean[g]


def laser_pointing_rad(residual_m: np.ndarray, gradient_m_per_rad: np.ndarray,
                       sigma_m: np.ndarray, material: np.ndarray, laser: np.ndarray,
                       directions: np.ndarray, window_width_m: float,
                       turn_only: bool = False,
                       iterations: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """ML pointing offsets (L, 2: az, el in rad) of each laser id 0..max(laser): the
    residual on ``gradient_m_per_rad`` . offset of the point's laser, one intercept per
    material, robust weighted least squares, each laser shrunk by its information
    (``shrunk_offsets_rad``; module doc); with ``turn_only``
    the offsets one turn of the whole sensor gives (``common_turn_rad``); lasers with
    fewer than
    MIN_POINTS_PER_LASER points get 0. Also each laser's information on its offsets
    (L, 2, 2, rad^-2, with the last robust weights; ``marginal_information``): how well
    the points determine them, and in which direction."""
    y = np.asarray(residual_m, float)
    g = np.asarray(gradient_m_per_rad, float)
    sigma = np.maximum(np.asarray(sigma_m, float), MIN_SIGMA_M)
    group = np.asarray(material, int)
    lz = np.asarray(laser, np.int64)
    n_lasers = int(lz.max()) + 1 if len(lz) else 0
    off = np.zeros((n_lasers, 2))
    a = np.zeros((n_lasers, 2, 2))
    if len(y) < MIN_POINTS_PER_LASER:
        return off, a
    enough = np.bincount(lz, minlength=n_lasers) >= MIN_POINTS_PER_LASER
    mean_dir = np.zeros((n_lasers, 3))
    for k in range(3):
        mean_dir[:, k] = np.bincount(lz, weights=directions[:, k], minlength=n_lasers)
    mean_dir /= np.maximum(np.linalg.norm(mean_dir, axis=1, keepdims=True), 1e-12)
    q = np.ones(len(y))
    s = sigma
    for _ in range(iterations):
        wt = q / s ** 2
        pred = np.einsum('ij,ij->i', g, off[lz])
        c = _centre_by(y - pred, group, wt)
        r = y - c
        a = np.zeros((n_lasers, 2, 2))
        b = np.zeros((n_lasers, 2))
        for i in range(2):
            b[:, i] = np.bincount(lz, weights=wt * g[:, i] * r, minlength=n_lasers)
            for j in range(2):
                a[:, i, j] = np.bincount(lz, weights=wt * g[:, i] * g[:, j], minlength=n_lasers)
        if turn_only:
            off = np.clip(common_turn_rad(a, b, mean_dir, enough & (a[:, 0, 0] + a[:, 1, 1] > 0)),
                          -MAX_FIT_RAD, MAX_FIT_RAD)
        else:
            off, c = shrunk_offsets_rad(g, y, wt, group, lz, n_lasers, enough)
        e = y - c - np.einsum('ij,ij->i', g, off[lz])
        _, scale = material_nuisance(e, sigma, group, np.ones(len(e), bool))
        s = sigma * scale
        dens = (1 - ROBUST_FLOOR) * np.exp(-0.5 * (e / s) ** 2) / (s * math.sqrt(2 * math.pi))
        q = dens / (dens + ROBUST_FLOOR / window_width_m)
    info = marginal_information(g, q / sigma ** 2, group, lz, n_lasers)
    return np.where(enough[:, None], off, 0.0), np.where(enough[:, None, None], info, 0.0)


def joint_normal(gradient_m_per_rad: np.ndarray, weight: np.ndarray, material: np.ndarray,
                 laser: np.ndarray, n_lasers: int,
                 residual_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The joint linear model's normal matrix (M + 2 L square: the M materials'
    intercepts, m^-2, then each laser's (az, el) offsets, rad^-2) and right-hand side
    (sums of w y against the same columns; 0 without ``residual_m``)."""
    g = np.asarray(gradient_m_per_rad, float)
    w = np.asarray(weight, float)
    y = np.zeros(len(w)) if residual_m is None else np.asarray(residual_m, float)
    mats, m_idx = np.unique(np.asarray(material), return_inverse=True)
    n_m, n_p = len(mats), 2 * n_lasers
    size = n_m + n_p
    normal = np.zeros((size, size))
    rhs = np.zeros(size)
    normal[np.arange(n_m), np.arange(n_m)] = np.bincount(m_idx, weights=w, minlength=n_m)
    rhs[:n_m] = np.bincount(m_idx, weights=w * y, minlength=n_m)
    cell = m_idx * n_lasers + laser
    for i in range(2):
        cross = np.bincount(cell, weights=w * g[:, i], minlength=n_m * n_lasers).reshape(n_m, n_lasers)
        normal[:n_m, n_m + i:size:2] = cross
        normal[n_m + i:size:2, :n_m] = cross.T
        rhs[n_m + i:size:2] = np.bincount(laser, weights=w * g[:, i] * y, minlength=n_lasers)
        for j in range(2):
            normal[n_m + np.arange(n_lasers) * 2 + i, n_m + np.arange(n_lasers) * 2 + j] = \
                np.bincount(laser, weights=w * g[:, i] * g[:, j], minlength=n_lasers)
    return normal, rhs


def laser_spread_rad2(offsets_rad: np.ndarray, variance_rad2: np.ndarray,
                      iterations: int = 30) -> float:
    """The spread tau^2 (rad^2) of the lasers' true offsets about 0 along one axis, by
    maximum likelihood from their free estimates x_l and variances v_l (x_l ~ N(0, tau^2
    + v_l)): tau^2 = sum w^2 (x^2 - v) / sum w^2, w = 1 / (v + tau^2), iterated, at least
    LASER_SPREAD_FLOOR_RAD^2. A laser that barely sees its offsets (v large) weighs
    little; four lasers of 24 off 0.3 deg give tau ~ 0.12 deg, none off ~ 0."""
    x2 = np.minimum(np.asarray(offsets_rad, float) ** 2, MAX_FIT_RAD ** 2)
    v = np.maximum(np.asarray(variance_rad2, float), 0.0)
    floor = LASER_SPREAD_FLOOR_RAD ** 2
    if len(x2) == 0:
        return floor
    tau2 = max(float(np.mean(x2 - v)), floor)
    for _ in range(iterations):
        w2 = 1.0 / (v + tau2) ** 2
        tau2 = max(float(np.sum(w2 * (x2 - v)) / np.sum(w2)), floor)
    return tau2


def shrunk_offsets_rad(gradient_m_per_rad: np.ndarray, residual_m: np.ndarray,
                       weight: np.ndarray, material: np.ndarray, laser: np.ndarray,
                       n_lasers: int, fitted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each ``fitted`` laser's offsets (L, 2, rad) and each point's material intercept
    (m), solved jointly by weighted least squares (``weight``: 1 / variance, m^-2) under a
    prior N(0, tau^2) on every laser's offset along each axis, tau^2 the lasers' spread
    (``laser_spread_rad2``, from the free solve's offsets and their variances, the
    intercepts and the other lasers profiled out). A laser shrinks by its information:
    one well seen keeps its offsets, one that barely sees the surface's slope (few
    points, little slope across its tile, one material at one slope) keeps little, where
    its free solve would run to noise. Clipped at the fit's box."""
    normal, rhs = joint_normal(gradient_m_per_rad, weight, material, laser, n_lasers,
                               residual_m)
    m_idx = np.unique(np.asarray(material), return_inverse=True)[1]
    n_m = len(normal) - 2 * n_lasers
    lasers = np.flatnonzero(fitted)
    cols = np.concatenate([np.arange(n_m), n_m + (2 * lasers[:, None] + np.arange(2)).ravel()])
    nk = normal[np.ix_(cols, cols)]
    cov = np.linalg.pinv(nk, rcond=1e-12, hermitian=True)
    free = (cov @ rhs[cols])[n_m:].reshape(-1, 2)
    var = np.diag(cov)[n_m:].reshape(-1, 2)
    prior = np.array([1.0 / laser_spread_rad2(free[:, k], var[:, k]) for k in range(2)])
    pen = nk.copy()
    pen[np.arange(n_m, len(cols)), np.arange(n_m, len(cols))] += np.tile(prior, len(lasers))
    x = np.linalg.pinv(pen, rcond=1e-12, hermitian=True) @ rhs[cols]
    off = np.zeros((n_lasers, 2))
    off[lasers] = np.clip(x[n_m:].reshape(-1, 2), -MAX_FIT_RAD, MAX_FIT_RAD)
    return off, x[:n_m][m_idx]


def marginal_information(gradient_m_per_rad: np.ndarray, weight: np.ndarray,
                         material: np.ndarray, laser: np.ndarray, n_lasers: int) -> np.ndarray:
    """(L, 2, 2): each laser's information on its two offsets (rad^-2) in the joint linear
    model, the material intercepts and the other lasers' offsets profiled out: the
    inverse of its block of the joint covariance (``joint_normal``). A laser that sees
    each material at one slope only has its offsets along that slope taken by the
    material's intercept, however large its gradient: its information there is small."""
    normal, _ = joint_normal(gradient_m_per_rad, weight, material, laser, n_lasers)
    n_m = len(normal) - 2 * n_lasers
    cov = np.linalg.pinv(normal, rcond=1e-12, hermitian=True)
    out = np.zeros((n_lasers, 2, 2))
    for l in range(n_lasers):
        k = n_m + 2 * l
        block = cov[k:k + 2, k:k + 2]
        if np.all(np.isfinite(block)) and np.linalg.det(block) > 0:
            out[l] = np.linalg.inv(block)
    return out


class SensorTurn(LaserPointing):
    """``laser_pointing`` fitted as one turn of the whole sensor (``turn_only``: three
    rotations, every laser's offsets from them): what the lasers' own offsets are weighed
    against. Not registered: the comparison's variant, written out as
    ``laser_pointing``."""

    turn_only = True


def turn_of(effect_cls) -> type | None:
    """The variant of a ``laser_pointing`` class fitted as one turn of the whole sensor
    (``SensorTurn``), or None for any other effect (or one that is that variant)."""
    if (isinstance(effect_cls, type) and issubclass(effect_cls, LaserPointing)
            and not getattr(effect_cls, 'turn_only', False)):
        return SensorTurn
    return None
