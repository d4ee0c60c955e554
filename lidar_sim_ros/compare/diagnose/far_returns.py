"""Points far beyond the noise, and where false returns lie: the matched points whose
residual no range effect explains (after each material's offset and sigma scale), the
core of the residual distribution, and the first-arrival law of a background over the
receiver's gate that tells false returns at random ranges from bunched ones (a
neighbouring channel's ghosts, lab clutter). Ranges in m; positions in the gate 0..1.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from lidar_sim_ros.compare.model import likelihood as lk

FAR_MIN_M = 0.5             # a point "far beyond the noise": |residual| above this and ...
FAR_SIGMAS = 10.0           # ... this many predicted sigmas
MIN_FAR_POINTS = 20         # an outlier effect needs this many far or unmatched points ...
MIN_FAR_SHARE = 0.5         # ... and this share of the spurious matched returns it claims
# The core of the residual distribution: within this many sigmas of the model without a
# candidate (a Gaussian leaves 6e-5 of its points beyond 4 sigma, under one in the
# 12 000 diagnosed). A noise effect's gain must be decisive there (``Diagnosis.core_veto``).
CORE_SIGMAS = 4.0


def far_threshold_m(sigma_m: np.ndarray, scale: np.ndarray | float = 1.0) -> np.ndarray:
    """|residual| (m) beyond which a matched point is far beyond the noise:
    max(FAR_MIN_M, FAR_SIGMAS sigma), sigma the point's predicted sigma (m) times its
    material's sigma scale."""
    return np.maximum(FAR_MIN_M, FAR_SIGMAS * sigma_m * scale)


def _profiled_residual(data):
    """The model without a candidate on the matched points: (model, residual m, sigma
    m, usable points, per-material offset m, sigma scale), the nuisance as the
    likelihood profiles it (``likelihood.material_nuisance``)."""
    model = lk.model_on_rays(data, [])
    r = np.asarray(data.measured_range_m, float) - model.expected_range_m
    sigma = np.maximum(model.sigma_m, lk.MIN_SIGMA_M)
    use = model.placed & np.isfinite(r)
    offset, scale = lk.material_nuisance(
        r, sigma, np.asarray(data.baseline.ctx.material, int), use)
    return model, r, sigma, use, offset, scale


def far_from_surface(data, details: bool = False):
    """Matched points far beyond the noise: |residual| > max(FAR_MIN_M, FAR_SIGMAS sigma),
    residual and sigma after the per-material nuisance (offset, sigma scale). With
    ``details`` also the residual (m), the expected range (m) and the threshold (m)."""
    model, r, sigma, use, offset, scale = _profiled_residual(data)
    threshold = far_threshold_m(sigma, scale)
    with np.errstate(invalid='ignore'):
        far = use & (np.abs(r - offset) > threshold)
    if not details:
        return far
    return far, r - offset, model.expected_range_m + offset, threshold


def core_points(data) -> np.ndarray:
    """Matched points within CORE_SIGMAS of the model without a candidate, residual and
    sigma after the per-material nuisance (offset, sigma scale): the core of the
    residual distribution."""
    _, r, sigma, use, offset, scale = _profiled_residual(data)
    with np.errstate(invalid='ignore'):
        return use & (np.abs(r - offset) <= CORE_SIGMAS * sigma * scale)


MAX_ARRIVAL_RATE = 50.0    # background arrivals per window length fitted at most


def arrival_cdf(x: np.ndarray, rate: float) -> np.ndarray:
    """CDF of the first background arrival over the window, x = share of the window
    (0..1): a Poisson process of ``rate`` arrivals per window length triggers first at
    x with density ~ exp(-rate x), i.e. F = (1 - e^(-rate x)) / (1 - e^(-rate));
    uniform (F = x) for a weak background (rate -> 0)."""
    x = np.clip(np.asarray(x, float), 0.0, 1.0)
    if rate < 1e-9:
        return x
    return np.expm1(-rate * x) / np.expm1(-rate)


def arrival_logpdf(x: np.ndarray, rate: float) -> np.ndarray:
    """Log density of ``arrival_cdf`` at x (share of the window, 0..1), rate > 0:
    log(rate / (1 - e^(-rate))) - rate x."""
    return np.log(rate / -np.expm1(-rate)) - rate * np.asarray(x, float)


def off_target_positions(range_m: np.ndarray, window_m: tuple[float, float]) -> np.ndarray:
    """Where isolated points off the target lie in the first-arrival law, 0..1: uniform
    if they are background arrivals on shots that miss the target (each listens over
    the whole gate). The window runs from the start of the receiver's gate
    (``window_m[0]``: the sensor's minimum range, not the target's nearest return; a
    background trigger is uniform in time over the gate, whatever the target's range)
    to the farthest of them (a recording's gate may end before the configured one);
    the law's rate is fitted to them (``arrival_cdf``: evenly, or crowding the start
    for a strong background). Returns bunched within the target's range window (the
    ghosts of a neighbouring channel, lab clutter) are then not uniform."""
    r = np.asarray(range_m, float)
    lo = float(window_m[0])
    if len(r) < 2 or not np.max(r) > lo:
        return np.zeros(0)
    x = np.clip((r - lo) / (float(np.max(r)) - lo), 0.0, 1.0)

    def nll(rate: float) -> float:
        if rate < 1e-9:
            return 0.0
        return float(-np.sum(arrival_logpdf(x, rate)))

    res = minimize_scalar(nll, bounds=(0.0, MAX_ARRIVAL_RATE), method='bounded',
                          options={'xatol': 1e-3})
    rate = float(res.x) if res.fun < 0.0 else 0.0
    return arrival_cdf(x, rate)


def _far_segments(expected_m: np.ndarray, threshold_m: np.ndarray,
                  window_m: tuple[float, float], rate: float):
    """Per far point: the first-arrival probability of the window in front of its
    surface and behind it (outside the +-threshold band a far point cannot fall in),
    and the CDF at the band's two ends."""
    lo, hi = window_m
    width = max(hi - lo, 1e-9)
    f_a = arrival_cdf((expected_m - threshold_m - lo) / width, rate)
    f_b = arrival_cdf((expected_m + threshold_m - lo) / width, rate)
    return f_a, 1.0 - f_b, f_a, f_b


def background_rate(residual_m: np.ndarray, expected_m: np.ndarray, threshold_m: np.ndarray,
                    window_m: tuple[float, float]) -> float:
    """Maximum-likelihood rate (arrivals per window length, >= 0) of the first-arrival
    law ``arrival_cdf`` for the far points' ranges, each given the side of its surface
    it lies on: 0 if they are spread evenly, larger if they crowd the window's start as
    the first photons of a strong background do. Conditioned on the side because how
    many fall in front is the receiver's business, not the background's: a first-return
    receiver reports a background trigger only before the echo, so on shots that hit
    the target every false return lies in front (``far_sides`` judges the sides)."""
    lo, hi = window_m
    width = max(hi - lo, 1e-9)
    x = np.clip((expected_m + residual_m - lo) / width, 0.0, 1.0)
    in_front = residual_m < 0
    if len(x) < 2:
        return 0.0

    def nll(rate: float) -> float:
        front, behind, _, _ = _far_segments(expected_m, threshold_m, window_m, rate)
        mass = np.maximum(np.where(in_front, front, behind), 1e-300)
        if rate < 1e-9:
            return float(np.sum(np.log(mass)))
        return float(-np.sum(arrival_logpdf(x, rate) - np.log(mass)))

    res = minimize_scalar(nll, bounds=(0.0, MAX_ARRIVAL_RATE), method='bounded',
                          options={'xatol': 1e-3})
    return float(res.x) if res.fun < nll(0.0) else 0.0


def far_positions(residual_m: np.ndarray, expected_m: np.ndarray, threshold_m: np.ndarray,
                  window_m: tuple[float, float], rate: float = 0.0) -> np.ndarray:
    """Where each far point lies within its side of the surface, 0..1, in the
    first-arrival probability of ``rate`` (in front: from the window's start to the band
    around the surface; behind: from the band to the window's end): uniform if the
    ranges are background arrivals. With rate 0, the share of the side's length."""
    lo, hi = window_m
    width = max(hi - lo, 1e-9)
    front = residual_m < 0
    f = arrival_cdf((expected_m + residual_m - lo) / width, rate)
    _, _, f_a, f_b = _far_segments(expected_m, threshold_m, window_m, rate)
    start = np.where(front, 0.0, f_b)
    end = np.where(front, f_a, 1.0)
    with np.errstate(invalid='ignore', divide='ignore'):
        u = (f - start) / (end - start)
    return np.clip(u[np.isfinite(u)], 0.0, 1.0)


def far_sides(residual_m: np.ndarray, expected_m: np.ndarray, threshold_m: np.ndarray,
              window_m: tuple[float, float], rate: float = 0.0) -> tuple[int, float, float]:
    """Far points in front of the surface: how many there are, and the mean and variance
    of that count if their ranges were background arrivals over ``window_m``
    (``arrival_cdf`` of ``rate``; rate 0: uniform): each point's chance is the
    probability in front of its surface over that outside the +-threshold band a far
    point cannot fall in."""
    front, behind, _, _ = _far_segments(expected_m, threshold_m, window_m, rate)
    with np.errstate(invalid='ignore', divide='ignore'):
        p = np.where(front + behind > 0, front / (front + behind), 0.5)
    return int(np.sum(residual_m < 0)), float(p.sum()), float(np.sum(p * (1 - p)))


def no_false_returns(n_far: int, credited: float) -> str | None:
    """Why an outlier effect that claims less than one false return on the target has
    no signature of its own: fewer than MIN_FAR_POINTS matched points far beyond the
    noise and off-target points credited to it together (its gain then comes from mild
    noise tails); None when it has them."""
    if n_far + credited >= MIN_FAR_POINTS:
        return None
    return (f'its gain rests on no false return: {n_far} matched points lie far beyond the '
            f'noise (|residual| > max({FAR_MIN_M:g} m, {FAR_SIGMAS:g} sigma)) and '
            f'{credited:.0f} off the target are credited to it (at least {MIN_FAR_POINTS} '
            'needed): mild noise tails, not false returns')
