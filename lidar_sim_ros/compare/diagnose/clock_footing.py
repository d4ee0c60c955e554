"""A clock offset weighed against the reference pose on the pose test's own rays
(``clock_on_pose_footing``).

A clock offset between the pose and LiDAR stamps reads the target's pose at another
time; a reference pose that drifts within each cloud (a tracking system's lag) moves it
by the same motion, velocity x time, on a rigid target. The two are nearly the same
correction, and they were judged on different rays: the clock's held-out gain on every
matched point, the per-cloud pose test only on the rays a linear correction may use
(not grazing, within ``pose_error.OUTLIER_SIGMAS``). On a small drift within each cloud
(``pose_drift_within_small``) the clock took 0.0142 of its 0.0206 nats/point on the
grazing rays the pose test leaves out and 0.0008 on its footing: the clock was named
where only the rays the pose cannot be weighed on showed it.

So the named clock is fitted linearly on the pose test's footing and halves (the same
rays, the same random halves, jointly with one range offset per material:
``row_clock.fit_with_offsets``), its column the range change the named clock makes at
each point (``row_clock.clock_column_m``), beside the per-cloud rigid correction (with
its rate within the cloud where the points carry their own times) on the same rays:
* the clock alone (held out, nats per matched point, z over blocks);
* the per-cloud pose alone;
* each on top of the other (nested, the same halves).
* where the points carry their own times, the clock growing over each cloud's scan on
  top of the clock (its column and the same scaled by tau, the point's time within its
  cloud), and on top of the clock and a range offset growing over the scan (the
  sensor's own, which the growth must not be): a pose read later and later over each
  scan (a tracking lag tied to the motion) is a clock offset at its mean and this
  growth, which no constant clock offset makes (``drift_*``).
The clock stands (``stands``) where it passes the rule on that footing (z at the
family's bound, at least ``min_gain``), the pose does not pass on top of it and the
clock's growth over the scan does not either: then it
is shown where the pose is weighed too, and the pose adds nothing there. Else the clock
is shown only on rays where the pose cannot be weighed, or the pose does as well: the
two cannot be told apart on this recording (a tie, ``Diagnosis.clock_off_footing``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.diagnose import pose_error, row_clock
from lidar_sim_ros.compare.diagnose.features import block_mean_z
from lidar_sim_ros.compare.model import likelihood as lk


@dataclass(frozen=True)
class ClockFooting:
    """The clock and the per-cloud pose on the pose test's rays: held-out nats per
    matched point and z (module doc)."""

    clock_gain: float
    clock_z: float
    pose_gain: float
    pose_z: float
    clock_over_pose_gain: float     # the clock on top of the per-cloud pose
    clock_over_pose_z: float
    pose_over_clock_gain: float     # the per-cloud pose on top of the clock
    pose_over_clock_z: float
    rays: int                       # rays on the footing
    matched: int                    # matched points the gains are divided by
    rate: bool                      # the pose with its rate within each cloud
    clock_passes: bool
    pose_passes_over_clock: bool
    drift_gain: float = 0.0         # the clock growing over the scan, on top of the clock
    drift_z: float = 0.0
    drift_beyond_range_gain: float = 0.0   # ... and on top of a range line over the scan
    drift_beyond_range_z: float = 0.0
    drift_passes: bool = False
    # The clock's column scaled by this in the fit with the pose on every ray of the
    # footing: the clock offset beside the pose is this times the one fitted alone.
    clock_scale: float = float('nan')
    constant: bool = False          # one rigid pose for the recording, not one per cloud
    z_crit: float = float('inf')    # the rule the parts were judged by
    min_gain: float = float('inf')

    @property
    def clock_decisive_over_pose(self) -> bool:
        """The clock's part on top of the pose is decisive (z at the bound), whether or
        not it is as large as matters."""
        return bool(self.clock_over_pose_z >= self.z_crit)

    @property
    def clock_passes_over_pose(self) -> bool:
        """The clock has a part of its own on top of the pose, by the rule (whether or
        not it passes alone: beside a constant pose offset the clock fitted alone
        fights the offset)."""
        return bool(self.clock_over_pose_z >= self.z_crit
                    and self.clock_over_pose_gain >= self.min_gain)

    @property
    def stands(self) -> bool:
        """The clock is shown where the pose is weighed, and neither the pose nor the
        clock's growth over the scan adds anything."""
        return bool(self.clock_passes and not self.pose_passes_over_clock
                    and not self.drift_passes)

    def as_dict(self) -> dict:
        return {'clock_gain': round(self.clock_gain, 6), 'clock_z': round(self.clock_z, 2),
                'pose_gain': round(self.pose_gain, 6), 'pose_z': round(self.pose_z, 2),
                'clock_over_pose_gain': round(self.clock_over_pose_gain, 6),
                'clock_over_pose_z': round(self.clock_over_pose_z, 2),
                'pose_over_clock_gain': round(self.pose_over_clock_gain, 6),
                'pose_over_clock_z': round(self.pose_over_clock_z, 2),
                'rays': self.rays, 'matched': self.matched, 'rate': self.rate,
                'clock_passes': self.clock_passes,
                'pose_passes_over_clock': self.pose_passes_over_clock,
                'drift_gain': round(self.drift_gain, 6), 'drift_z': round(self.drift_z, 2),
                'drift_beyond_range_gain': round(self.drift_beyond_range_gain, 6),
                'drift_beyond_range_z': round(self.drift_beyond_range_z, 2),
                'drift_passes': self.drift_passes,
                'stands': self.stands,
                **({'constant': True, 'clock_scale': round(self.clock_scale, 4),
                    'clock_passes_over_pose': self.clock_passes_over_pose,
                    'clock_decisive_over_pose': self.clock_decisive_over_pose}
                   if self.constant else {})}


def per_cloud_columns(a: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """(N, C K) the per-point columns ``a`` (N, K) placed in their cloud's block: one
    correction per cloud as columns of one least-squares fit."""
    clouds, row = np.unique(np.asarray(cloud), return_inverse=True)
    k = a.shape[1]
    out = np.zeros((len(a), len(clouds) * k))
    for j in range(k):
        out[np.arange(len(a)), row * k + j] = a[:, j]
    return out


def clock_on_pose_footing(data: lk.FitData, cloud: np.ndarray, t_s: np.ndarray,
                          blocks: np.ndarray, z_crit: float, min_gain: float,
                          clock_m: np.ndarray, seed: int = 0,
                          rate: bool = False, constant: bool = False) -> ClockFooting:
    """The clock (``clock_m``: its range change per matched point of ``data``, m,
    ``row_clock.clock_column_m``) and the per-cloud pose (``rate``: with its rate over
    each cloud, ``pose_error.rate_columns``) on the pose test's rays and halves (module
    doc); ``cloud``, ``t_s``, ``blocks``: per matched point. ``constant``: one rigid
    pose for the recording instead (six parameters, rotation about the centroid of all
    the points, no rate; ``clock_beside_constant_pose``)."""
    if constant:
        cloud, rate = np.zeros(len(np.asarray(cloud)), int), False
    model = lk.model_on_rays(data, [])
    ctx = model.ctx
    c = np.asarray(clock_m, float)
    n = len(c)
    empty = ClockFooting(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, n, rate, False, False)
    if ctx.normal is None or ctx.direction is None or not np.isfinite(c).any():
        return empty
    r, s, ok, _ = pose_error.footing(data, model)
    group = np.asarray(data.baseline.ctx.material, int)
    cloud = np.asarray(cloud)
    a, usable = pose_error.design(ctx.direction, ctx.normal,
                                  np.where(ok, model.expected_range_m, 0.0), cloud)
    # The pose test's rays; a clock that moves a ray onto another surface is no linear
    # change there either.
    lim = pose_error.OUTLIER_SIGMAS * s
    use = ok & usable & (np.abs(r) <= lim) & np.isfinite(c) & (np.abs(c) <= lim)
    if use.sum() < 2:
        return empty
    c = np.where(use, c, 0.0)[:, None]
    tau = None
    if rate:
        tau, _, h_c = pose_error.time_scale(t_s, cloud, np.unique(cloud))
        rate = bool(np.any(h_c > 1e-9))
        if rate:
            a = pose_error.rate_columns(a, tau)
    p = per_cloud_columns(np.where(use[:, None], a, 0.0), cloud)
    models = {'clock': c, 'pose': p, 'both': np.hstack([c, p])}
    if rate:
        line = np.where(use, tau, 0.0)[:, None]
        models.update({'drift': np.hstack([c, c * line]), 'line': np.hstack([c, line]),
                       'drift_line': np.hstack([c, line, c * line])})
    half = np.random.default_rng([seed, pose_error.HALVES_SEED]).integers(0, 2, n)
    gain = {k: np.zeros(n) for k in models}
    for k in (0, 1):
        test, train = use & (half != k), use & (half == k)
        for name, cols in models.items():
            corr = row_clock.fit_with_offsets(cols, r, s, group, train)
            gain[name][test] = pose_error.heldout_gain(r[test], corr[test], s[test])

    def judged(g: np.ndarray) -> tuple[float, float]:
        z = block_mean_z(g[use], np.asarray(blocks)[use])[1]
        return float(np.sum(g[use]) / max(n, 1)), float(z)

    def passes(fig: tuple[float, float]) -> bool:
        return fig[1] >= z_crit and fig[0] >= min_gain
    clock, pose = judged(gain['clock']), judged(gain['pose'])
    clock_over = judged(gain['both'] - gain['pose'])
    pose_over = judged(gain['both'] - gain['clock'])
    drift = beyond = (0.0, 0.0)
    if rate:
        drift = judged(gain['drift'] - gain['clock'])
        beyond = judged(gain['drift_line'] - gain['line'])
    scale = float(row_clock.coefficients_with_offsets(models['both'], r, s, group, use)[1][0])
    return ClockFooting(clock[0], clock[1], pose[0], pose[1], clock_over[0], clock_over[1],
                        pose_over[0], pose_over[1], int(use.sum()), n, rate,
                        passes(clock), passes(pose_over), drift[0], drift[1], beyond[0],
                        beyond[1], bool(rate and passes(drift) and passes(beyond)),
                        scale, constant, z_crit, min_gain)
