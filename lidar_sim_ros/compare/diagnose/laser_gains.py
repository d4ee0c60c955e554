"""Per-laser range offsets beside a range walk read from the measured intensity: are
they a per-channel intensity calibration?

A range walk, ``bias = -k ln(P / P_ref)``, is read from the received power, which
compare takes from the measured intensity. If each laser's intensity carries its own
gain g_l (a per-channel calibration of the intensity, not of the range), the walk read
from it moves every range of laser l by -k ln(g_l), so the data, against that model,
show per-laser range offsets +k ln(g_l): the same residual as lasers with range offsets
of their own. The per-laser mean of ln(measured / model power) over the matched points
estimates ln(g_l) (up to a common factor, which the per-material offsets take), so
where the offsets laser_bias fitted follow k times it, the recording cannot tell the
two causes apart: said as a tie of causes, not as a new effect.

``intensity_tie`` weighs it: the correlation over the lasers (its Fisher z against the
rule's z), and the share of the offsets' spread that k times the log ratio explains
with no parameter fitted (at least half: the gains then explain more of the pattern
than they leave).
"""
from __future__ import annotations

import numpy as np

# k ln(g_l) must explain at least this share of the offsets' variance across the lasers
# (no parameter fitted: k is the walk's): more of the pattern than it leaves.
MIN_EXPLAINED_SHARE = 0.5
MIN_LASERS = 4            # a correlation over fewer lasers says nothing
# Lasers whose mean log intensity ratios spread less than this (RMS) have no gains to
# speak of (k times it is microns): the correlation would be of rounding.
MIN_LOG_RATIO_SPREAD = 1e-4


def per_laser_log_ratio(laser: np.ndarray, measured_w: np.ndarray,
                        model_w: np.ndarray) -> dict[int, float]:
    """Mean ln(measured / model power) per laser id over the points given (those with
    both powers finite and positive)."""
    laser = np.asarray(laser, np.int64)
    m = np.asarray(measured_w, float)
    p = np.asarray(model_w, float)
    with np.errstate(invalid='ignore', divide='ignore'):
        ok = np.isfinite(m) & np.isfinite(p) & (m > 0) & (p > 0)
        ratio = np.log(np.where(ok, m, 1.0) / np.where(ok, p, 1.0))
    return {int(l): float(np.mean(ratio[ok & (laser == l)]))
            for l in np.unique(laser[ok])}


def intensity_tie(offsets_m: list[float], log_ratio: dict[int, float], k_m: float,
                  z_crit: float) -> dict | None:
    """How well k times each laser's mean log intensity ratio (``per_laser_log_ratio``)
    reproduces the per-laser offsets (``offsets_m[l]`` of laser l), both centred over
    the lasers that have both: ``correlation``, its Fisher ``z`` (atanh(r) sqrt(n - 3)),
    ``explained_share`` (1 - sum (o - k r)^2 / sum o^2, centred, no parameter fitted),
    ``slope_over_k`` (the least-squares slope of the offsets on the log ratio, over k)
    and ``ties`` (the correlation decisive by ``z_crit`` and the share at least
    MIN_EXPLAINED_SHARE). None with fewer than MIN_LASERS lasers, offsets alike, log
    ratios within MIN_LOG_RATIO_SPREAD, or k not finite."""
    lasers = [l for l in sorted(log_ratio) if 0 <= l < len(offsets_m)]
    if len(lasers) < MIN_LASERS or not np.isfinite(k_m) or k_m == 0:
        return None
    o = np.array([offsets_m[l] for l in lasers], float)
    r = np.array([log_ratio[l] for l in lasers], float)
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(r))):
        return None
    o, r = o - o.mean(), r - r.mean()
    so, sr = float(np.sum(o * o)), float(np.sum(r * r))
    if so <= 0 or np.sqrt(sr / len(r)) < MIN_LOG_RATIO_SPREAD:
        return None
    corr = float(np.sum(o * r) / np.sqrt(so * sr))
    n = len(lasers)
    z = float(np.arctanh(np.clip(corr, -0.999999, 0.999999)) * np.sqrt(max(n - 3, 1)))
    share = float(1.0 - np.sum((o - k_m * r) ** 2) / so)
    slope = float(np.sum(o * r) / sr)
    return {'lasers': n, 'k_m': float(k_m), 'correlation': round(corr, 4), 'z': round(z, 3),
            'explained_share': round(share, 4), 'slope_over_k': round(slope / k_m, 4),
            'log_intensity_ratio_spread': round(float(np.sqrt(sr / n)), 5),
            'ties': bool(z >= z_crit and share >= MIN_EXPLAINED_SHARE)}
