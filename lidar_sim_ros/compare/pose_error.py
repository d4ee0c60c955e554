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

The linear range change holds on smooth surfaces only: near a silhouette or a depth
step a moved target changes which surface a ray meets (or whether it meets one). So a
fitted correction is applied to the pose itself (``CorrectedPoses``: each cloud's rigid
motion composed with the recorded pose, ``PoseCorrection``) and the model is raycast
again; the fit is repeated on the re-matched residual and composed (Gauss-Newton,
``iterate``), until the step is small.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, TypeVar

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.pose import Poses

from lidar_sim_ros.compare import likelihood as lk
from lidar_sim_ros.compare.features import block_mean_se

OUTLIER_SIGMAS = 5.0      # residuals beyond this many sigma are not fitted (edges, outliers)
MIN_COS = 0.2             # |n.u| below this: grazing rays, range too sensitive to the pose
MIN_CLOUD_POINTS = 60     # a cloud needs this many usable points for its six parameters
RIDGE = 1e-2              # relative ridge of the correction applied: damps motions the data barely see (about a cylinder's long axis)
TEST_RIDGE = 1e-6         # relative ridge of the held-out test (the rule's footing, as before the re-cast)


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
    centroid_m: np.ndarray | None = None   # (C, 3) lidar frame: each cloud's rotation centre
    passes: int = 0               # re-casts with the corrected pose (0: linear correction only)
    last_step: tuple[float, float] = (0.0, 0.0)   # the last pass's largest step (m, deg)

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
                                                 self.rotation_deg)],
                'recast_passes': self.passes,
                'last_step_m_deg': [round(float(x), 6) for x in self.last_step]}

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
               cloud: np.ndarray, use: np.ndarray, clouds: np.ndarray,
               prior: np.ndarray | None = None, ridge: float = RIDGE) -> np.ndarray:
    """(C, 6) weighted least-squares correction per cloud (zeros where too few points).
    The ridge pulls the total correction, ``prior`` (C, 6: already applied) plus the
    step returned, toward zero: a Gauss-Newton pass damps the same motions as the first."""
    out = np.zeros((len(clouds), 6))
    x0 = np.zeros((len(clouds), 6)) if prior is None else np.asarray(prior, float)
    for k, c in enumerate(clouds):
        sel = use & (cloud == c)
        if sel.sum() < MIN_CLOUD_POINTS:
            continue
        w = 1.0 / sigma_m[sel]
        aw = a[sel] * w[:, None]
        ata = aw.T @ aw
        lam = ridge * np.trace(ata) / 6
        ata += lam * np.eye(6)
        out[k] = np.linalg.solve(ata, aw.T @ (residual_m[sel] * w) - lam * x0[k])
    return out


@dataclass(frozen=True)
class PoseCorrection:
    """A rigid correction per cloud of the recorded target pose, lidar frame:
    ``p' = R[c] p + t[c]`` for every point p of the target during cloud c. Clouds are
    told apart by time: each cloud's span of point times ``[t0_s, t1_s]``, split half-way
    between neighbours (``CorrectedPoses``)."""

    clouds: np.ndarray            # (K,) cloud indices, in time order
    t0_s: np.ndarray              # (K,) first point time of each cloud (s)
    t1_s: np.ndarray              # (K,) last point time (s)
    rotation: Rotation            # (K,) R[c]
    translation_m: np.ndarray     # (K, 3) t[c] (m)
    centroid_m: np.ndarray = field(default=None)   # (K, 3) reference point for reports

    @classmethod
    def identity(cls, cloud: np.ndarray, t_s: np.ndarray) -> 'PoseCorrection':
        """No correction, for the clouds of the points ``cloud``/``t_s``."""
        clouds = np.unique(cloud)
        t0 = np.array([t_s[cloud == c].min() for c in clouds])
        t1 = np.array([t_s[cloud == c].max() for c in clouds])
        order = np.argsort(t0)
        k = len(clouds)
        return cls(clouds[order], t0[order], t1[order], Rotation.identity(k),
                   np.zeros((k, 3)), np.full((k, 3), np.nan))

    def compose(self, step: PoseError) -> tuple['PoseCorrection', tuple[float, float]]:
        """This correction followed by ``step``'s (a fit on the re-cast model: translation
        d and rotation w about its cloud's centroid g, ``p' = R_w (p - g) + g + d``); and
        the step's largest translation (m) and rotation (deg)."""
        pos = np.searchsorted(self.clouds, step.clouds)
        ok = (pos < len(self.clouds))
        ok[ok] = self.clouds[pos[ok]] == step.clouds[ok]
        rotvec = np.zeros((len(self.clouds), 3))
        move = np.zeros((len(self.clouds), 3))
        g = np.array(self.centroid_m, float, copy=True)
        rotvec[pos[ok]] = np.radians(step.rotation_deg[ok])
        rw = Rotation.from_rotvec(rotvec)
        if step.centroid_m is not None:
            g_step = np.zeros((len(self.clouds), 3))
            g_step[pos[ok]] = step.centroid_m[ok]
            move[pos[ok]] = step.translation_m[ok]
            move += g_step - rw.apply(g_step)
            first = ~np.isfinite(g[:, 0])
            g[first] = g_step[first]
        out = replace(self, rotation=rw * self.rotation,
                      translation_m=rw.apply(self.translation_m) + move, centroid_m=g)
        size = (float(np.max(np.linalg.norm(step.translation_m, axis=1), initial=0.0)),
                float(np.max(np.linalg.norm(step.rotation_deg, axis=1), initial=0.0)))
        return out, size

    def at_time(self, t_s: np.ndarray) -> np.ndarray:
        """(N,) row of each time's cloud: the cloud whose span holds it, else the nearer
        neighbour (split half-way between one cloud's last and the next one's first time)."""
        edges = 0.5 * (self.t1_s[:-1] + self.t0_s[1:])
        return np.searchsorted(edges, np.asarray(t_s, float), side='right')

    def moved(self) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) motion of each cloud's reference point (m) and (K, 3) rotation vector
        (deg): the correction as the report states it (the target is really here + this)."""
        g = np.nan_to_num(np.asarray(self.centroid_m, float))
        return (self.rotation.apply(g) + self.translation_m - g,
                np.degrees(self.rotation.as_rotvec()))

    def params(self, clouds: np.ndarray) -> np.ndarray:
        """(len(clouds), 6) this correction as a fit's parameters (``moved``: translation
        of the reference point, m; rotation vector, rad); zeros for clouds it lacks."""
        out = np.zeros((len(clouds), 6))
        moved, rotvec = self.moved()
        pos = np.clip(np.searchsorted(self.clouds, clouds), 0, max(len(self.clouds) - 1, 0))
        have = (self.clouds[pos] == clouds) if len(self.clouds) else np.zeros(len(clouds), bool)
        out[have] = np.hstack([moved, np.radians(rotvec)])[pos[have]]
        return out


class CorrectedPoses:
    """A pose source (``core.pose.PoseSource``): ``base`` with ``correction`` applied,
    so that the model can be raycast with the corrected reference pose."""

    def __init__(self, base, correction: PoseCorrection):
        self.base, self.correction = base, correction

    def __getattr__(self, name):          # coverage, sample times: the base track's
        if name in ('base', 'correction'):   # not set yet (copy, unpickling)
            raise AttributeError(name)
        return getattr(self.base, name)

    def at(self, t_s: np.ndarray) -> Poses:
        poses = self.base.at(t_s)
        k = self.correction.at_time(np.atleast_1d(t_s))
        rot = self.correction.rotation[k]
        position = np.broadcast_to(poses.position_m.reshape(-1, 3), (len(k), 3)).copy()
        return Poses(rot * poses.rotation, rot.apply(position) + self.correction.translation_m[k])


S = TypeVar('S')
RECAST_PASSES = 3            # re-casts at most (Gauss-Newton passes after the first fit)
RECAST_STEP_M = 5e-4         # a step below this and RECAST_STEP_DEG: converged
RECAST_STEP_DEG = 0.01


def iterate(first: PoseError, start: PoseCorrection, rematch: Callable[[PoseCorrection], S],
            refit: Callable[[S, PoseCorrection], PoseError]
            ) -> tuple[S, PoseCorrection, PoseError]:
    """Gauss-Newton on the re-cast model: apply ``first`` (a fit on the model with the
    recorded pose) to the pose, ``rematch`` (raycast again), ``refit`` on the re-matched
    residual, compose, until the step is below RECAST_STEP_M and RECAST_STEP_DEG or
    after RECAST_PASSES re-casts. Returns the last re-match, the composed correction and
    ``first`` with the composed sizes (its test, gain and z, are the first fit's).
    ``refit(state, corr)`` fits the step on the model re-cast with ``corr`` applied."""
    corr, step = start.compose(first)
    passes = 0
    while True:
        state = rematch(corr)
        passes += 1
        if passes >= RECAST_PASSES or (step[0] < RECAST_STEP_M and step[1] < RECAST_STEP_DEG):
            break
        corr, step = corr.compose(refit(state, corr))
    moved, rotvec = corr.moved()
    rows = np.searchsorted(corr.clouds, first.clouds)
    report = replace(first, translation_m=moved[rows], rotation_deg=rotvec[rows],
                     correction_m=np.zeros_like(first.correction_m), passes=passes,
                     last_step=step)
    return state, corr, report


def heldout_gain(residual_m: np.ndarray, correction_m: np.ndarray,
                 sigma_m: np.ndarray) -> np.ndarray:
    """Nats per point the correction gains on held-out points: the Gaussian log density of
    the corrected residual minus the uncorrected one's, (r^2 - (r - c)^2) / (2 s^2)."""
    r = np.asarray(residual_m, float)
    return (r ** 2 - (r - correction_m) ** 2) / (2 * np.asarray(sigma_m, float) ** 2)


def fit_reference_pose(data: lk.FitData, cloud: np.ndarray, t_s: np.ndarray,
                       blocks: np.ndarray, z_crit: float, min_gain: float, seed: int = 0,
                       effects: list | None = None,
                       applied: 'PoseCorrection | None' = None) -> PoseError:
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
    prior = None if applied is None else applied.params(clouds)
    # The test (held-out halves) keeps the light ridge it was validated with: a damped
    # fit generalises better, so the stronger ridge would make the test more eager,
    # e.g. on top of a fitted time offset; the correction applied is the damped one.
    half = np.random.default_rng([seed, 61]).integers(0, 2, len(r))
    gain = np.zeros(len(r))
    for k in (0, 1):
        x = fit_clouds(a, r, s, cloud, use & (half == k), clouds, prior, TEST_RIDGE)
        corr = np.einsum('ij,ij->i', a, x[np.searchsorted(clouds, cloud)])
        test = use & (half != k)
        gain[test] = heldout_gain(r[test], corr[test], s[test])
    mean, se = block_mean_se(gain[use], blocks[use]) if use.sum() > 1 else (0.0, np.inf)
    per_point = float(np.sum(gain[use]) / max(len(r), 1))
    z = float(mean / se) if se > 0 and np.isfinite(se) else 0.0
    x = fit_clouds(a, r, s, cloud, use, clouds, prior)
    correction = np.einsum('ij,ij->i', a, x[np.searchsorted(clouds, cloud)])
    t_mean = np.array([float(np.mean(t_s[cloud == c])) for c in clouds])
    p = ctx.direction * np.where(ok, model.expected_range_m, 0.0)[:, None]
    centroid = np.array([p[use & (cloud == c)].mean(axis=0) if np.any(use & (cloud == c))
                         else np.zeros(3) for c in clouds])
    return PoseError(clouds, t_mean, x[:, :3], np.degrees(x[:, 3:]), per_point, z,
                     bool(z >= z_crit and per_point >= min_gain), correction, centroid)


def corrected(data: lk.FitData, correction_m: np.ndarray) -> lk.FitData:
    """``data`` with the pose correction's range change (m, per matched point) in the
    baseline's range bias: the model as the corrected reference pose would predict it."""
    corr = np.asarray(correction_m, float)

    def shift(pred):
        return replace(pred, bias_m=np.asarray(pred.bias_m) + corr)
    cast = data.cast
    return replace(data, baseline=shift(data.baseline),
                   cast=lk.PredictionCache(lambda effects: shift(cast(effects))))
