"""Reference-pose errors: is the target's recorded pose off, rigidly, per cloud?

In a lab the target's pose comes from a tracking system or an extrinsic calibration
(the paper's Fig. 1: a target on a crane). Their errors move whole clouds rigidly, and
read as a sensor effect (an incidence or footprint effect) they would be the wrong
diagnosis. This module tests for them on the matched points.

A small rigid motion of the target, translation ``d`` (m) and rotation ``w`` (rad, about
the cloud's centroid ``g``), moves the surface point ``p = e u`` (expected range ``e``
along the unit ray ``u``) of a plane with normal ``n`` to a range
``e + n.(d + w x (p - g)) / (n.u)``: a range residual linear in the six parameters,
``a_d = n / (n.u)`` and ``a_w = ((p - g) x n) / (n.u)``. Per cloud these are fitted by
weighted least squares to the residual (per-material offset and sigma scale profiled,
points beyond OUTLIER_SIGMAS and grazing rays left out), and judged by the rule of
every candidate (``diagnosis``): the held-out gain (fitted on one half of each cloud's
points, scored on the other, both ways) in Gaussian nats per matched point, its z
over neighbourhood blocks, decisive at the family's z and at least MIN_PRACTICAL_GAIN.

A correct pose gains nothing (6 parameters per cloud against thousands of points).
The simulator never applies a pose error: it is a reference error, not a sensor effect.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lidar_sim_ros.compare import likelihood as lk
from lidar_sim_ros.compare.features import block_mean_se

OUTLIER_SIGMAS = 5.0      # residuals beyond this many sigma are not fitted (edges, outliers)
MIN_COS = 0.2             # |n.u| below this: grazing rays, range too sensitive to the pose
MIN_CLOUD_POINTS = 60     # a cloud needs this many usable points for its six parameters
RIDGE = 1e-6              # relative ridge: unobservable motions (e.g. about a plane's normal) stay 0


@dataclass(frozen=True)
class PoseError:
    """Per-cloud rigid corrections of the reference pose and their held-out gain."""

    clouds: np.ndarray            # (C,) cloud indices
    t_s: np.ndarray               # (C,) mean point time of each cloud (s, recording clock)
    translation_m: np.ndarray     # (C, 3) lidar frame: the target is really here + this
    rotation_deg: np.ndarray      # (C, 3) rotation vector (deg), lidar frame, about the centroid
    gain: float                   # held-out nats per matched point
    z: float
    significant: bool             # z >= z_crit and gain >= the practical margin
    correction_m: np.ndarray      # (N,) range correction per matched point (fit on all)

    @property
    def size_cm(self) -> float:
        """RMS over clouds of the translation's length (cm)."""
        return float(100 * np.sqrt(np.mean(np.sum(self.translation_m ** 2, axis=1))))

    @property
    def size_deg(self) -> float:
        """RMS over clouds of the rotation angle (deg)."""
        return float(np.sqrt(np.mean(np.sum(self.rotation_deg ** 2, axis=1))))

    @property
    def span_s(self) -> float:
        return float(np.ptp(self.t_s)) if len(self.t_s) else 0.0

    def as_dict(self) -> dict:
        return {'gain_per_matched_point': round(self.gain, 6), 'z': round(self.z, 3),
                'significant': self.significant, 'translation_rms_cm': round(self.size_cm, 3),
                'rotation_rms_deg': round(self.size_deg, 4), 'span_s': round(self.span_s, 3),
                'clouds': [{'cloud': int(c), 't_s': round(float(t), 4),
                            'translation_m': [round(float(x), 5) for x in d],
                            'rotation_deg': [round(float(x), 5) for x in w]}
                           for c, t, d, w in zip(self.clouds, self.t_s, self.translation_m,
                                                 self.rotation_deg)]}

    def words(self) -> str:
        return (f'the reference pose is off by about {self.size_cm:.1f} cm and '
                f'{self.size_deg:.2f} deg, varying over {self.span_s:.1f} s')


def design(direction: np.ndarray, normal: np.ndarray, expected_m: np.ndarray,
           cloud: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 6) range change per unit translation (m) and rotation (rad) of the target,
    rotation about each cloud's centroid of points; and the usable rays (not grazing)."""
    u = np.asarray(direction, float)
    n = np.asarray(normal, float)
    p = u * np.asarray(expected_m, float)[:, None]
    nu = np.einsum('ij,ij->i', n, u)
    use = np.isfinite(nu) & (np.abs(nu) >= MIN_COS) & np.all(np.isfinite(p), axis=1)
    g = np.zeros_like(p)
    for c in np.unique(cloud):
        sel = (cloud == c) & use
        if sel.any():
            g[cloud == c] = p[sel].mean(axis=0)
    safe = np.where(use, nu, 1.0)[:, None]
    a = np.hstack([n / safe, np.cross(p - g, n) / safe])
    return np.where(use[:, None], a, 0.0), use


def fit_clouds(a: np.ndarray, residual_m: np.ndarray, sigma_m: np.ndarray,
               cloud: np.ndarray, use: np.ndarray, clouds: np.ndarray) -> np.ndarray:
    """(C, 6) weighted least-squares correction per cloud (zeros where too few points)."""
    out = np.zeros((len(clouds), 6))
    for k, c in enumerate(clouds):
        sel = use & (cloud == c)
        if sel.sum() < MIN_CLOUD_POINTS:
            continue
        w = 1.0 / sigma_m[sel]
        aw = a[sel] * w[:, None]
        ata = aw.T @ aw
        ata += RIDGE * np.trace(ata) / 6 * np.eye(6)
        out[k] = np.linalg.solve(ata, aw.T @ (residual_m[sel] * w))
    return out


def fit_reference_pose(data: lk.FitData, cloud: np.ndarray, t_s: np.ndarray,
                       blocks: np.ndarray, z_crit: float, min_gain: float, seed: int = 0,
                       effects: list | None = None) -> PoseError:
    """Fit and judge per-cloud rigid pose corrections on ``data``'s matched points
    (``cloud``, ``t_s``, ``blocks``: per matched point) under the model with
    ``effects`` on top of its own (module doc)."""
    model = lk.model_on_rays(data, list(effects or []))
    ctx = model.ctx
    clouds = np.unique(cloud)
    if ctx.normal is None or ctx.direction is None or len(clouds) == 0:
        return PoseError(clouds, np.zeros(len(clouds)), np.zeros((len(clouds), 3)),
                         np.zeros((len(clouds), 3)), 0.0, 0.0, False,
                         np.zeros(len(data.measured_range_m)))
    r = np.asarray(data.measured_range_m, float) - model.expected_range_m
    sigma = np.maximum(model.sigma_m, lk.MIN_SIGMA_M)
    ok = model.placed & np.isfinite(r) & np.isfinite(sigma)
    offset, scale = lk.material_nuisance(r, sigma, np.asarray(data.baseline.ctx.material, int),
                                         ok)
    r = np.where(ok, r - offset, 0.0)
    s = np.where(ok, sigma * scale, 1.0)
    a, usable = design(ctx.direction, ctx.normal, np.where(ok, model.expected_range_m, 0.0),
                       cloud)
    use = ok & usable & (np.abs(r) <= OUTLIER_SIGMAS * s)
    half = np.random.default_rng([seed, 61]).integers(0, 2, len(r))
    gain = np.zeros(len(r))
    for k in (0, 1):
        x = fit_clouds(a, r, s, cloud, use & (half == k), clouds)
        corr = np.einsum('ij,ij->i', a, x[np.searchsorted(clouds, cloud)])
        test = use & (half != k)
        gain[test] = (r[test] ** 2 - (r[test] - corr[test]) ** 2) / (2 * s[test] ** 2)
    mean, se = block_mean_se(gain[use], blocks[use]) if use.sum() > 1 else (0.0, np.inf)
    per_point = float(np.sum(gain[use]) / max(len(r), 1))
    z = float(mean / se) if se > 0 and np.isfinite(se) else 0.0
    x = fit_clouds(a, r, s, cloud, use, clouds)
    correction = np.einsum('ij,ij->i', a, x[np.searchsorted(clouds, cloud)])
    t_mean = np.array([float(np.mean(t_s[cloud == c])) for c in clouds])
    return PoseError(clouds, t_mean, x[:, :3], np.degrees(x[:, 3:]), per_point, z,
                     bool(z >= z_crit and per_point >= min_gain), correction)


def corrected(data: lk.FitData, correction_m: np.ndarray) -> lk.FitData:
    """``data`` with the pose correction's range change (m, per matched point) in the
    baseline's range bias: the model as the corrected reference pose would predict it."""
    corr = np.asarray(correction_m, float)

    def shift(pred):
        return replace(pred, bias_m=np.asarray(pred.bias_m) + corr)
    cast = data.cast
    return replace(data, baseline=shift(data.baseline),
                   cast=lk.PredictionCache(lambda effects: shift(cast(effects))))
