"""Model-free attribution: which variable does the range residual depend on?

For every feature (range, incidence, intensity, azimuth, elevation, time, material,
edge) the matched points are binned (quantile bins, or categories) and the
normalised residual z = (measured - expected) / predicted sigma is summarised per bin
by a robust centre (median) and spread (MAD). The score is the information a bin
carries about z, in nats per point, under a Gaussian per bin:

    0.5 * sum_b w_b (m_b - m)^2 / s^2   +   sum_b w_b (log s_b - mean log s)^2

(the conditional-mean part plus the conditional-spread part), minus the same
statistic with the feature shuffled (what noise alone gives for these bin counts).
Scores near 0 mean "no dependence beyond noise"; ``significance`` is the excess in
units of the shuffled statistic's spread.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.materials import MAD_TO_SIGMA

FEATURE_NAMES = ('range', 'incidence', 'intensity', 'azimuth', 'elevation', 'time',
                 'material', 'edge')
CATEGORICAL = ('material', 'edge')
UNITS = {'range': 'm', 'incidence': 'deg', 'intensity': 'log10', 'azimuth': 'deg',
         'elevation': 'deg', 'time': 's', 'material': '', 'edge': 'mrad'}
MIN_BIN_POINTS = 30
MAX_BINS = 16
N_SHUFFLES = 4


@dataclass(frozen=True)
class FeatureScore:
    """One feature's attribution score and its binned residual profile (for plots).

    score = mean_part + spread_part (nats/point, noise-corrected, >= 0); significance
    = excess over noise in units of the shuffle spread. Bins: edges or category
    labels, count, robust centre and spread of the residual (m) and of z.
    """

    name: str
    score: float
    mean_part: float
    spread_part: float
    significance: float
    labels: list
    centers: np.ndarray
    counts: np.ndarray
    median_m: np.ndarray
    p16_m: np.ndarray
    p84_m: np.ndarray
    z_median: np.ndarray
    z_spread: np.ndarray
    trend: str

    def as_dict(self) -> dict:
        return {'name': self.name, 'score': round(self.score, 6),
                'mean_part': round(self.mean_part, 6), 'spread_part': round(self.spread_part, 6),
                'significance': round(self.significance, 2), 'trend': self.trend}


def feature_values(matching, intensity_model: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per matched point: the eight feature values (see UNITS)."""
    m = matching.meas
    sel = matching.matched
    ctx = matching.pred.ctx
    if m.intensity is not None:
        inten = m.intensity[sel]
    else:
        inten = ctx.intensity[sel] if intensity_model is None else intensity_model
    pos = inten[np.isfinite(inten) & (inten > 0)]
    floor = np.min(pos) if len(pos) else 1e-12
    az = np.degrees(np.arctan2(m.directions[sel, 1], m.directions[sel, 0]))
    el = np.degrees(np.arcsin(np.clip(m.directions[sel, 2], -1, 1)))
    time = m.t_frame_s[sel] if m.has_point_time else (m.t_s[sel] - m.t_s.min())
    return {
        'range': np.asarray(ctx.range_m[sel], float),
        'incidence': np.degrees(np.asarray(ctx.incidence_rad[sel], float)),
        'intensity': np.log10(np.maximum(np.nan_to_num(inten, nan=floor), floor)),
        'azimuth': az, 'elevation': el, 'time': time,
        'material': np.asarray(ctx.material[sel], int),
        'edge': np.round(matching.edge_rad[sel] * 1e3, 4),
    }


def _bins(x: np.ndarray, categorical: bool, n_bins: int) -> tuple[np.ndarray, list, np.ndarray]:
    """Bin index per point, bin labels and bin centres."""
    if categorical:
        cats, idx = np.unique(x, return_inverse=True)
        return idx, [c.item() if hasattr(c, 'item') else c for c in cats], cats.astype(float)
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    if len(edges) < 3:
        return np.zeros(len(x), int), ['all'], np.array([np.median(x)])
    idx = np.clip(np.searchsorted(edges, x, side='right') - 1, 0, len(edges) - 2)
    centers = np.array([np.median(x[idx == b]) if np.any(idx == b) else np.nan
                        for b in range(len(edges) - 1)])
    labels = [f'{edges[b]:.4g}..{edges[b + 1]:.4g}' for b in range(len(edges) - 1)]
    return idx, labels, centers


def _robust_by_bin(z: np.ndarray, idx: np.ndarray,
                   n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bin: median, MAD sigma and count of z."""
    order = np.argsort(idx, kind='stable')
    zs, ids = z[order], idx[order]
    bounds = np.searchsorted(ids, np.arange(n + 1))
    med = np.full(n, np.nan)
    spr = np.full(n, np.nan)
    cnt = np.diff(bounds)
    for b in range(n):
        part = zs[bounds[b]:bounds[b + 1]]
        if len(part):
            med[b] = np.median(part)
            spr[b] = MAD_TO_SIGMA * np.median(np.abs(part - med[b]))
    return med, spr, cnt


def _information(z: np.ndarray, idx: np.ndarray, n: int) -> tuple[float, float]:
    """(mean part, spread part) of the per-bin Gaussian information, nats/point."""
    med, spr, cnt = _robust_by_bin(z, idx, n)
    ok = (cnt >= MIN_BIN_POINTS) & (spr > 0)
    if ok.sum() < 2:
        return 0.0, 0.0
    w = cnt[ok] / cnt[ok].sum()
    centre = np.median(z)
    total = MAD_TO_SIGMA * np.median(np.abs(z - centre))
    if total <= 0:
        return 0.0, 0.0
    m_bar = np.sum(w * med[ok])
    mean_part = 0.5 * np.sum(w * (med[ok] - m_bar) ** 2) / total ** 2
    log_s = np.log(spr[ok])
    spread_part = np.sum(w * (log_s - np.sum(w * log_s)) ** 2)
    return float(mean_part), float(spread_part)


def score_features(values: dict[str, np.ndarray], residual_m: np.ndarray, z: np.ndarray,
                   seed: int = 0) -> list[FeatureScore]:
    """Score every feature, best first. ``residual_m`` and ``z`` are over matched points."""
    rng = np.random.default_rng(seed)
    n_pts = len(z)
    n_bins = int(np.clip(n_pts // 150, 2, MAX_BINS))
    shuffles = [rng.permutation(n_pts) for _ in range(N_SHUFFLES)]
    out = []
    for name in FEATURE_NAMES:
        x = values[name]
        idx, labels, centers = _bins(x, name in CATEGORICAL, n_bins)
        nb = len(labels)
        mean_part, spread_part = _information(z, idx, nb)
        null = np.array([_information(z[p], idx, nb) for p in shuffles])
        null_mean = null.mean(axis=0)
        null_sd = float(np.std(null.sum(axis=1), ddof=1)) if len(null) > 1 else 0.0
        excess_mean = max(mean_part - null_mean[0], 0.0)
        excess_spread = max(spread_part - null_mean[1], 0.0)
        excess = mean_part + spread_part - null_mean.sum()
        # Few shuffles give a rough spread; a chi-square-like statistic over ~2 x bins
        # degrees of freedom has sd ~ 0.25 x its mean, which bounds it from below.
        sig = excess / max(null_sd, 0.25 * null_mean.sum(), 1e-12)
        med_m, p16, p84, zmed, zspr = _profiles(residual_m, z, idx, nb)
        cnt = np.bincount(idx, minlength=nb)
        out.append(FeatureScore(
            name=name, score=float(max(excess, 0.0)), mean_part=float(excess_mean),
            spread_part=float(excess_spread), significance=float(sig), labels=labels,
            centers=np.asarray(centers, float), counts=cnt, median_m=med_m, p16_m=p16,
            p84_m=p84, z_median=zmed, z_spread=zspr,
            trend=_trend(name, centers, med_m, p84 - p16, cnt)))
    out.sort(key=lambda f: -f.score)
    return out


def _profiles(res: np.ndarray, z: np.ndarray, idx: np.ndarray, nb: int):
    med = np.full(nb, np.nan)
    p16 = np.full(nb, np.nan)
    p84 = np.full(nb, np.nan)
    zmed, zspr, _ = _robust_by_bin(z, idx, nb)
    for b in range(nb):
        part = res[idx == b]
        if len(part):
            med[b], p16[b], p84[b] = np.median(part), *np.percentile(part, [16, 84])
    return med, p16, p84, zmed, zspr


def _trend(name: str, centers: np.ndarray, med: np.ndarray, width: np.ndarray,
           cnt: np.ndarray) -> str:
    """A plain-language description of how the residual moves along the feature."""
    ok = (cnt >= MIN_BIN_POINTS) & np.isfinite(med)
    if ok.sum() < 2:
        return 'no trend'
    c, m, w = centers[ok], med[ok], width[ok]
    if name in CATEGORICAL:
        hi, lo = int(np.argmax(m)), int(np.argmin(m))
        return (f'residual median ranges from {m[lo] * 100:+.1f} cm to {m[hi] * 100:+.1f} cm '
                f'across {name} values; spread from {w.min() * 50:.1f} to {w.max() * 50:.1f} cm')
    slope = np.polyfit(c, m, 1)[0] if np.ptp(c) > 0 else 0.0
    wslope = np.polyfit(c, w, 1)[0] if np.ptp(c) > 0 else 0.0
    unit = UNITS[name]
    parts = []
    dm = slope * np.ptp(c)
    dw = 0.5 * wslope * np.ptp(c)
    if abs(dm) > 1e-4:
        parts.append(f'residual {"grows" if dm > 0 else "falls"} by {abs(dm) * 100:.1f} cm '
                     f'over {name} {c.min():.3g}..{c.max():.3g} {unit}'.rstrip())
    if abs(dw) > 1e-4:
        parts.append(f'spread {"grows" if dw > 0 else "shrinks"} by {abs(dw) * 100:.1f} cm')
    return '; '.join(parts) or 'flat'
