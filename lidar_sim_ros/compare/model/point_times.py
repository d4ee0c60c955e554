"""Clouds without per-point time: how far the unknown point times smear the residual.

A cloud without a time field gives every point its header stamp, which may sit at the
start, the middle or the end of the scan. Each point was really measured somewhat
earlier or later, while the target moved: its range is off by about

    range_rate x (true time - stamp)

(range_rate: how fast the range along the ray changes, ``matching.range_rate_mps``).
The mean of (true time - stamp) is a constant shift, the same in the data as a clock
offset between poses and points: it is left to the ``time_offset`` candidate (the
verdict says it may be the stamp's place in the scan). The spread around it is not a
physical effect: the model widens each point's sigma by range_rate x s, where the
time spread s (s) is the maximum-likelihood value of

    residual ~ N(c_m + b range_rate, (k_m sigma)^2 + (range_rate s)^2)

(per-material offset c_m and sigma scale k_m as everywhere, b the constant shift), for
s between 0 and the frame period / sqrt(3) (points spread over a whole frame).
"""
from __future__ import annotations

import math

import numpy as np

from lidar_sim_ros.compare.model.likelihood import CHI2_1_MEDIAN

GRID = 25
MIN_POINTS = 100


def time_spread_s(residual_m: np.ndarray, sigma_m: np.ndarray, material: np.ndarray,
                  range_rate_mps: np.ndarray, period_s: float) -> float:
    """The ML spread (s) of the unknown point times (module doc), on matched points
    with a finite range rate."""
    ok = np.isfinite(residual_m) & np.isfinite(sigma_m) & np.isfinite(range_rate_mps)
    if ok.sum() < MIN_POINTS or period_s <= 0:
        return 0.0
    r, sig, rr, g = residual_m[ok], np.maximum(sigma_m[ok], 1e-4), range_rate_mps[ok], \
        np.asarray(material)[ok]
    best = (math.inf, 0.0)
    for s in np.linspace(0.0, period_s / math.sqrt(3.0), GRID):
        nll = _profile_nll(r, sig, rr, g, s)
        if nll < best[0]:
            best = (nll, float(s))
    return best[1]


def _profile_nll(r: np.ndarray, sig: np.ndarray, rr: np.ndarray, group: np.ndarray,
                 s: float) -> float:
    """Gaussian NLL with the per-material offset, sigma scale and the shift b profiled."""
    extra = (rr * s) ** 2
    var = sig ** 2 + extra
    w = 1.0 / var
    # Offsets per material and a common slope b on the range rate: weighted LS.
    xc, yc = _centred(rr, group, w), _centred(r, group, w)
    b = float(np.sum(w * xc * yc) / max(np.sum(w * xc * xc), 1e-12))
    e = yc - b * xc
    total = 0.0
    for k in np.unique(group):
        sel = group == k
        e2, sig2, extra_k = e[sel] ** 2, sig[sel] ** 2, extra[sel]
        # Sigma scale of the material's own noise, the smear kept as it is.
        lo, hi = 0.05, 20.0
        for _ in range(40):
            mid = math.sqrt(lo * hi)
            if np.median(e2 / (mid ** 2 * sig2 + extra_k)) > CHI2_1_MEDIAN:
                lo = mid
            else:
                hi = mid
        v = (lo * sig[sel]) ** 2 + extra_k
        z2 = np.minimum(e2 / v, 25.0)      # robust: a far outlier counts as 5 sigma
        total += float(0.5 * np.sum(np.log(v) + z2))
    return total


def _centred(v: np.ndarray, group: np.ndarray, w: np.ndarray) -> np.ndarray:
    out = np.empty_like(v)
    for k in np.unique(group):
        sel = group == k
        out[sel] = v[sel] - np.sum(w[sel] * v[sel]) / max(np.sum(w[sel]), 1e-12)
    return out


def extra_variance_m2(range_rate_mps: np.ndarray, spread_s: float) -> np.ndarray:
    """The variance (m^2) the unknown point times add to each point; where the range rate
    is unknown (the ray hops surfaces within dt) the 95th percentile rate is taken."""
    rr = np.abs(np.asarray(range_rate_mps, float))
    finite = rr[np.isfinite(rr)]
    fill = float(np.percentile(finite, 95)) if len(finite) else 0.0
    return (np.where(np.isfinite(rr), rr, fill) * spread_s) ** 2
