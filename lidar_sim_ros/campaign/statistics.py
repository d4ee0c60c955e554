"""Per-run statistics, accumulated frame by frame (manifest columns ``stat.<name>``).

- ``frames``, ``shots``, ``hits`` (rays that met the target), ``points`` (published
  returns, false returns included), ``false_returns`` (points not on the target);
- dropouts by cause, which add up to ``shots - points + false_returns``:
  ``dropped_missed`` (the ray missed the target), ``dropped_below_threshold``,
  ``dropped_saturated`` (received power outside [threshold, saturation)),
  ``dropped_other`` (range gate, a non-positive measured range, or a shot that a false
  return replaced);
- range error = measured minus true range (m) of the points on the target:
  ``range_error_mean_m`` / ``range_error_std_m`` over all of them, and per material
  ``points.<M>``, ``range_error_mean_m.<M>``, ``range_error_std_m.<M>`` (NaN below
  one resp. two points);
- ``coverage`` / ``coverage_hit`` (see ``coverage.py``), means over the
  ``coverage_frames`` frames evaluated.
"""
from __future__ import annotations

import math

import numpy as np

from lidar_sim_ros.core.pipeline import NO_MATERIAL, Frame

COUNTS = ('frames', 'shots', 'hits', 'points', 'false_returns', 'dropped_missed',
          'dropped_below_threshold', 'dropped_saturated', 'dropped_other')


def stat_names(material_names: list[str]) -> list[str]:
    """Statistic names of a run, in manifest column order."""
    names = list(COUNTS) + ['range_error_mean_m', 'range_error_std_m']
    for m in material_names:
        names += [f'points.{m}', f'range_error_mean_m.{m}', f'range_error_std_m.{m}']
    return names + ['coverage', 'coverage_hit', 'coverage_frames']


class RunStatistics:
    """Sums over the frames of one run; ``summary()`` turns them into the statistics."""

    def __init__(self, material_names: list[str]):
        self.material_names = list(material_names)
        n = len(self.material_names)
        self.counts = dict.fromkeys(COUNTS, 0)
        # Per material: number, sum and sum of squares of the range errors (m, m^2).
        self.err_n, self.err_sum, self.err_sq = np.zeros(n), np.zeros(n), np.zeros(n)
        self.coverage: list[float] = []
        self.coverage_hit: list[float] = []

    def add_frame(self, frame: Frame) -> None:
        s, c = frame.stats, self.counts
        on_target = frame.material != NO_MATERIAL
        c['frames'] += 1
        c['shots'] += s['shots']
        c['hits'] += s['hits']
        c['points'] += len(frame)
        c['false_returns'] += int(np.count_nonzero(~on_target))
        c['dropped_missed'] += s['shots'] - s['hits']
        c['dropped_below_threshold'] += s['below_threshold']
        c['dropped_saturated'] += s['saturated']
        c['dropped_other'] += (s['hits'] - int(np.count_nonzero(on_target))
                               - s['below_threshold'] - s['saturated'])
        material = frame.material[on_target].astype(np.intp)
        err = frame.range_m[on_target] - frame.true_range_m[on_target]
        n = len(self.material_names)
        self.err_n += np.bincount(material, minlength=n)
        self.err_sum += np.bincount(material, weights=err, minlength=n)
        self.err_sq += np.bincount(material, weights=err * err, minlength=n)

    def add_coverage(self, detected: float, hit: float) -> None:
        if math.isfinite(detected):
            self.coverage.append(detected)
            self.coverage_hit.append(hit)

    def summary(self) -> dict[str, float | int]:
        out: dict[str, float | int] = dict(self.counts)
        out['range_error_mean_m'], out['range_error_std_m'] = _mean_std(
            self.err_n.sum(), self.err_sum.sum(), self.err_sq.sum())
        for i, m in enumerate(self.material_names):
            out[f'points.{m}'] = int(self.err_n[i])
            out[f'range_error_mean_m.{m}'], out[f'range_error_std_m.{m}'] = _mean_std(
                self.err_n[i], self.err_sum[i], self.err_sq[i])
        out['coverage'] = float(np.mean(self.coverage)) if self.coverage else math.nan
        out['coverage_hit'] = float(np.mean(self.coverage_hit)) if self.coverage_hit else math.nan
        out['coverage_frames'] = len(self.coverage)
        return out


def _mean_std(n: float, total: float, sq: float) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof 1) from count, sum and sum of squares."""
    n, total, sq = float(n), float(total), float(sq)
    mean = total / n if n >= 1 else math.nan
    if n < 2:
        return mean, math.nan
    return mean, math.sqrt(max(0.0, (sq - total * mean) / (n - 1)))
