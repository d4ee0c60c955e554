"""A time within the exposure that the points do not carry: a residual that grows with
the row (``row_time_test``).

A flash LiDAR read out row by row (a rolling shutter) but recorded as one global
exposure gives every point of a cloud the same time, while the target moved on between
the first row and the last. On a target turning at a constant rate each row is then
rotated by the turn over its own delay: the mean delay is a clock offset, or one rigid
correction of the pose (on a constant tumble the two are the same motion), and what is
left grows with the row. Neither a pose nor a clock of the catalogue explains that
part, and a rigid correction, with six parameters against the clock's one, takes a
share of it (a turn about the line of sight shears the rows as the delay does), so it
passes on top of the clock where a pose stream that is late does not (the eleventh
holdout's flash_rolling: the pose 0.016 nats/point, z 7.3, on top of a clock of
+0.060 s, a mean row delay of 50 ms at 30 deg/s).

The test, linear on held-out halves jointly with the materials' offsets
(``fit_with_offsets``, the pose test's footing): the clock's column is the range change
the named clock offset makes at each point (``clock_m``: the model with it less the
model without, so its fitted dt is one unit), and the clock growing over the rows is
that column and the same scaled by tau, the ray's row (its elevation from the middle
row over half the rows' span). The rows pass when
* the clock's growth over the rows gains on top of the clock, and on top of the clock
  and a range offset growing with the row (the sensor's own range bias per row, which
  the rate must not be), by the rule (z at the family's bound, at least ``min_gain``
  per point, ``rate_*``); and
* one rigid correction of the pose (``pose_error.design``'s six columns) does not pass
  on top of the clock growing over the rows (``pose_*``): what the pose took beyond the
  clock was the rows' part.
Asked only where the points span no time within a cloud (``scan_clock`` found none):
where they carry times, a drift within the scan is the rate test's
(``pose_error.fit_reference_pose`` with ``rate``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.diagnose import pose_error
from lidar_sim_ros.compare.diagnose.features import block_mean_z
from lidar_sim_ros.compare.model import likelihood as lk

ROW_QUANTILE = 0.01      # a few stray rays do not stretch the rows' span


@dataclass(frozen=True)
class RowTime:
    """The row test's figures, nats per point and z (module doc)."""

    rate_gain: float            # the clock's growth over the rows on top of the clock
    rate_z: float
    beyond_range_gain: float    # ... and on top of the clock and a range line over the rows
    beyond_range_z: float
    pose_gain: float            # one rigid correction on top of the clock over the rows
    pose_z: float
    significant: bool
    # The growth over the rows on top of the clock and the pose: passing, only the rows
    # explain the data; not, the pose's turn about the line of sight shears the rows
    # alike and the two cannot be told apart.
    over_pose_gain: float = 0.0
    over_pose_z: float = 0.0
    over_pose: bool = False

    def as_dict(self) -> dict:
        return {'rate_gain_over_clock': round(self.rate_gain, 6), 'z': round(self.rate_z, 2),
                'beyond_range_over_row_gain': round(self.beyond_range_gain, 6),
                'beyond_range_over_row_z': round(self.beyond_range_z, 2),
                'pose_gain_on_top': round(self.pose_gain, 6),
                'pose_z_on_top': round(self.pose_z, 2),
                'over_clock_and_pose_gain': round(self.over_pose_gain, 6),
                'over_clock_and_pose_z': round(self.over_pose_z, 2),
                'passes_over_clock_and_pose': self.over_pose, 'significant': self.significant}


def row_tau(direction: np.ndarray, use: np.ndarray) -> np.ndarray:
    """(N,) each ray's row as tau in [-1, 1]: its elevation (lidar frame) from the middle
    of the ``use`` rays' span over half the span (quantiles ROW_QUANTILE); 0 where the
    rays span no elevation."""
    u = np.asarray(direction, float)
    el = np.arcsin(np.clip(u[:, 2], -1.0, 1.0))
    ok = use & np.isfinite(el)
    if ok.sum() < 2:
        return np.zeros(len(u))
    lo, hi = np.quantile(el[ok], [ROW_QUANTILE, 1 - ROW_QUANTILE])
    if not hi - lo > 1e-9:
        return np.zeros(len(u))
    return np.where(ok, np.clip((el - 0.5 * (lo + hi)) / (0.5 * (hi - lo)), -1.5, 1.5), 0.0)


def clock_column_m(data: lk.FitData, clock) -> np.ndarray:
    """(N,) the range change (m) the clock offset ``clock`` (an effect that moves the
    rays) makes at each matched point: the model with it less the model without; NaN
    where either does not place the point."""
    with_clock = lk.model_on_rays(data, [clock])
    without = lk.model_on_rays(data, [])
    ok = with_clock.placed & without.placed
    return np.where(ok, with_clock.expected_range_m - without.expected_range_m, np.nan)


def fit_with_offsets(cols: np.ndarray, residual_m: np.ndarray, sigma_m: np.ndarray,
                     group: np.ndarray, train: np.ndarray) -> np.ndarray:
    """(N,) the range correction (m) at every point of ``cols`` (N, K) fitted by
    weighted least squares on the ``train`` points jointly with one range offset per
    material (``group``), offsets included: the footing of the pose test's joint fit
    (``pose_error.fit_clouds`` with ``group``), for any number of columns. A relative
    ridge of ``pose_error.TEST_RIDGE`` keeps a column the points do not see at zero."""
    x, beta = coefficients_with_offsets(cols, residual_m, sigma_m, group, train)
    return x @ beta


def coefficients_with_offsets(cols: np.ndarray, residual_m: np.ndarray, sigma_m: np.ndarray,
                              group: np.ndarray, train: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray]:
    """``fit_with_offsets``'s design (N, K + materials: ``cols`` then one offset column
    per material) and its coefficients (the first K: per unit of each column)."""
    labels, col = np.unique(np.asarray(group, int), return_inverse=True)
    x = np.zeros((len(residual_m), cols.shape[1] + len(labels)))
    x[:, :cols.shape[1]] = cols
    x[np.arange(len(col)), cols.shape[1] + col] = 1.0
    w = np.where(train, 1.0 / np.asarray(sigma_m, float), 0.0)
    xw = x * w[:, None]
    ata = xw.T @ xw
    ata += np.diag(pose_error.TEST_RIDGE * np.maximum(np.diag(ata), 1e-300))
    beta = np.linalg.lstsq(ata, xw.T @ (np.asarray(residual_m, float) * w), rcond=None)[0]
    return x, beta


def row_time_test(data: lk.FitData, blocks: np.ndarray, z_crit: float, min_gain: float,
                  clock_m: np.ndarray, seed: int = 0) -> RowTime:
    """The row test (module doc) on ``data``'s matched points; ``clock_m``: the named
    clock's range change per point (``clock_column_m``); ``blocks``: each point's
    neighbourhood block (the z's)."""
    model = lk.model_on_rays(data, [])
    ctx = model.ctx
    c = np.asarray(clock_m, float)
    if ctx.normal is None or ctx.direction is None or not np.isfinite(c).any():
        return RowTime(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False)
    r, s, ok, _ = pose_error.footing(data, model)
    group = np.asarray(data.baseline.ctx.material, int)
    a, usable = pose_error.design(ctx.direction, ctx.normal,
                                  np.where(ok, model.expected_range_m, 0.0),
                                  np.zeros(len(r), int))
    # A clock that moves a ray onto another surface is no linear change there.
    lim = pose_error.OUTLIER_SIGMAS * s
    use = ok & usable & (np.abs(r) <= lim) & np.isfinite(c) & (np.abs(c) <= lim)
    c = np.where(use, c, 0.0)
    tau = row_tau(ctx.direction, use)
    models = {'clock': c[:, None], 'line': np.column_stack([c, tau]),
              'rows': np.column_stack([c, c * tau]),
              'pose': np.column_stack([c, c * tau, a]), 'clock_pose': np.column_stack([c, a])}
    half = np.random.default_rng([seed, 67]).integers(0, 2, len(r))
    gain = {k: np.zeros(len(r)) for k in models}
    for k in (0, 1):
        test, train = use & (half != k), use & (half == k)
        for name, cols in models.items():
            corr = fit_with_offsets(cols, r, s, group, train)
            gain[name][test] = pose_error.heldout_gain(r[test], corr[test], s[test])

    def judged(g: np.ndarray) -> tuple[float, float]:
        z = block_mean_z(g[use], blocks[use])[1] if use.sum() > 1 else 0.0
        return float(np.sum(g[use]) / max(len(r), 1)), float(z)

    def passes(fig: tuple[float, float]) -> bool:
        return fig[1] >= z_crit and fig[0] >= min_gain
    rate = judged(gain['rows'] - gain['clock'])
    beyond = judged(gain['rows'] - gain['line'])
    pose = judged(gain['pose'] - gain['rows'])
    rows_over_pose = judged(gain['pose'] - gain['clock_pose'])
    return RowTime(rate[0], rate[1], beyond[0], beyond[1], pose[0], pose[1],
                   bool(passes(rate) and passes(beyond) and not passes(pose)),
                   rows_over_pose[0], rows_over_pose[1], passes(rows_over_pose))
