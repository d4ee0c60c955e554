"""Point times of a Lissajous pattern that runs a little fast or slow, for clouds without a
time field.

A Lissajous of 110:100 Hz with both frequencies scaled by (1 + eps) traces the configured
closed figure again, only at other instants: a shot fired at t (s since the cloud stamp)
lies on the configured curve at tc = (1 + eps) t, modulo the figure's period. So on
u = tc / (1 + eps) each laser's shots sit on one grid of its shot interval per cloud, as
on the configured pattern (``scan_curve.times_on_grid``), while on tc the grid's offset
drifts through the frame (4.4 shots for eps = 0.5 % at 880 shots a frame) and the check
refuses. ``fit_rate`` finds the eps that puts the curve times of ``nearest_on_curve`` on one
grid per (cloud, laser) (the coherence of their phases on the shot interval);
``times_on_drifting_grid`` then snaps each point to its laser's grid on u. Past the
figure's period (eps > 0: the last eps of the frame retraces its start) a curve time
stands for two instants a period apart; the grid, whose offsets there differ by a
fraction of a shot, tells which.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.compare.recording.scan_curve import GRID_TOL, TIE_RAD, grid_offsets

MAX_RATE_ERROR = 0.02      # |eps| beyond this is not looked for (the pattern is refused)
COARSE_STEPS = 321         # eps grid over [-MAX, MAX] (step 1.25e-4, a tenth of 1/880)
FINE_STEPS = 101           # then over one coarse step either side
MIN_COHERENCE = 0.8        # mean phase coherence per (cloud, laser) a fitted eps must reach
FIT_POINTS = 40_000        # at most this many points enter the fit (a fixed thinning)


def coherence(t_curve_s: np.ndarray, group: np.ndarray, eps: np.ndarray,
              interval_s: float) -> np.ndarray:
    """Per eps (E,): the point-weighted mean over groups of the resultant length of the
    phases of t_curve / (1 + eps) on ``interval_s`` (1: every group on one grid, ~0: none).
    ``group`` (N,) ids of (cloud, laser)."""
    keys, inv = np.unique(group, return_inverse=True)
    out = np.zeros(len(eps))
    for i, e in enumerate(np.atleast_1d(eps)):
        z = np.exp(2j * np.pi * t_curve_s / ((1.0 + e) * interval_s))
        total = np.zeros(len(keys), complex)
        np.add.at(total, inv, z)
        out[i] = np.abs(total).sum() / max(len(t_curve_s), 1)
    return out


def fit_rate(t_curve_s: np.ndarray, group: np.ndarray, interval_s: float) -> tuple[float, float]:
    """(eps, coherence): the frequency scale error in [-MAX_RATE_ERROR, MAX_RATE_ERROR] whose
    u = t_curve / (1 + eps) puts each group's points on one grid of ``interval_s``; a
    coarse scan, then a fine one around its best."""
    if len(t_curve_s) > FIT_POINTS:
        pick = np.linspace(0, len(t_curve_s) - 1, FIT_POINTS).astype(np.int64)
        t_curve_s, group = t_curve_s[pick], group[pick]
    coarse = np.linspace(-MAX_RATE_ERROR, MAX_RATE_ERROR, COARSE_STEPS)
    c = coherence(t_curve_s, group, coarse, interval_s)
    step = coarse[1] - coarse[0]
    best = coarse[int(np.argmax(c))]
    fine = np.linspace(best - step, best + step, FINE_STEPS)
    f = coherence(t_curve_s, group, fine, interval_s)
    k = int(np.argmax(f))
    return float(fine[k]), float(f[k])


def times_on_drifting_grid(dist: np.ndarray, t_s: np.ndarray, laser: np.ndarray,
                           cloud: np.ndarray, tol_rad: float, interval_s: float,
                           period_s: float, frame_s: float,
                           eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per point, from its candidates (N, K) of ``nearest_on_curve`` (angular distance rad,
    curve time s, laser): matched, time since the stamp (s, on its laser's grid) and laser,
    for a pattern running (1 + eps) fast. Each candidate's instants u = (tc + n period_s) /
    (1 + eps), n in -1, 0, 1, within the frame ``frame_s``; the grid's offset per (cloud,
    laser) from each point's nearest candidate (n = 0); then the nearest candidate and n on
    that grid (ties, within TIE_RAD, to the first)."""
    rows = np.arange(len(dist))
    cloud = np.repeat(np.asarray(cloud, np.int64)[:, None], dist.shape[1], axis=1)
    group = cloud * (int(laser.max(initial=0)) + 1) + laser
    near = np.argmin(dist, axis=1)
    u0 = t_s / (1.0 + eps)
    mean = grid_offsets(u0[rows, near], group[rows, near], dist[rows, near] < tol_rad,
                        interval_s)
    keys = np.unique(group[rows, near])
    pos = np.clip(np.searchsorted(keys, group), 0, len(keys) - 1)
    known = keys[pos] == group
    best_ok = np.zeros(len(dist), bool)
    best_t, best_laser = np.zeros(len(dist)), np.zeros(len(dist), laser.dtype)
    best_key = np.full(len(dist), np.inf)
    for n in (0, 1, -1):
        u = (t_s + n * period_s) / (1.0 + eps)
        off = (u / interval_s - np.where(known, mean[pos], 0.0) + 0.5) % 1.0 - 0.5
        snapped = u - off * interval_s
        good = (known & (dist < tol_rad) & (np.abs(off) < GRID_TOL)
                & (snapped > -0.5 * interval_s) & (snapped < frame_s + 0.5 * interval_s))
        key = np.where(good, np.floor(dist / TIE_RAD), np.inf)
        pick = np.argmin(key, axis=1)
        better = key[rows, pick] < best_key
        best_key = np.where(better, key[rows, pick], best_key)
        best_ok |= good[rows, pick]
        best_t = np.where(better, snapped[rows, pick], best_t)
        best_laser = np.where(better, laser[rows, pick], best_laser)
    return best_ok, best_t, best_laser


def drifting_times(dist: np.ndarray, t_s: np.ndarray, laser: np.ndarray, cloud: np.ndarray,
                   tol_rad: float, interval_s: float, period_s: float,
                   frame_s: float) -> tuple[tuple | None, str]:
    """((matched, time s, laser, eps, per-cloud eps (C,)) or None, why not) from the
    candidates (N, K) of ``nearest_on_curve``: eps fitted on every cloud together
    (``fit_rate``), then on each cloud alone near it; refused if the phases do not cohere
    (MIN_COHERENCE), if eps is at the bound (MAX_RATE_ERROR), or if a cloud's eps differs
    from the whole's by more than GRID_TOL shot intervals of drift over the frame."""
    rows = np.arange(len(dist))
    near = np.argmin(dist, axis=1)
    close = dist[rows, near] < tol_rad
    cloud = np.asarray(cloud, np.int64)
    group = cloud * (int(laser.max(initial=0)) + 1) + laser[rows, near]
    if close.sum() < 100:
        return None, 'too few directions on the curve'
    eps, coh = fit_rate(t_s[rows, near][close], group[close], interval_s)
    if coh < MIN_COHERENCE:
        return None, f'no one rate puts the shots on a grid (coherence {coh:.2f})'
    if abs(eps) > MAX_RATE_ERROR - 2 * MAX_RATE_ERROR / (COARSE_STEPS - 1):
        return None, f'the best rate is at the bound, {100 * eps:+.2f} %'
    step = 2 * MAX_RATE_ERROR / (COARSE_STEPS - 1)
    fine = np.linspace(eps - step, eps + step, FINE_STEPS)
    each = np.full(int(cloud.max(initial=-1)) + 1, np.nan)
    for c in np.unique(cloud[close]):
        mine = close & (cloud == c)
        if mine.sum() >= 50:
            each[c] = fine[int(np.argmax(coherence(t_s[rows, near][mine], group[mine], fine,
                                                   interval_s)))]
    spread = np.nanmax(np.abs(each - eps)) if np.isfinite(each).any() else 0.0
    if spread * frame_s / interval_s > GRID_TOL:
        return None, (f'the clouds disagree on the rate (up to {100 * spread:.3f} % from '
                      f'{100 * eps:+.3f} %)')
    ok, t, las = times_on_drifting_grid(dist, t_s, laser, cloud, tol_rad, interval_s,
                                        period_s, frame_s, eps)
    return (ok, t, las, eps, each), ''


def figure_period_s(freqs_hz: np.ndarray) -> float:
    """The period (s) of a Lissajous figure whose axes run at ``freqs_hz`` (to 1 mHz):
    1 / their greatest common divisor; inf without a non-zero frequency."""
    milli = np.abs(np.round(np.asarray(freqs_hz, float) * 1000.0)).astype(np.int64)
    g = int(np.gcd.reduce(milli)) if len(milli) else 0
    return 1000.0 / g if g else float('inf')
