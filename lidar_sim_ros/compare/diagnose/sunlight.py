"""Sunlight in a recording: fit the receiver's unknown factor from its false returns.

When a recording carries the sun direction (``/sun/direction``, ``geometry_msgs/
Vector3Stamped`` in the lidar frame), the ``sunlight`` effect predicts for every measured
ray what its receiver saw (a sunlit or a shadowed surface, empty space) and the chance
that background noise crossed the threshold before the echo. The receiver's band-pass,
field of view and filter transmission are not public, so one factor g multiplies every
background power (``Sunlight.Params.background_scale``); it is fitted here by maximum
likelihood from which measured points are false returns:

    p_i(g) = 1 - exp(-nu(g P_bg,i) T_i)        T_i: listening time before the echo
    log L(g) = sum_false log p_i + sum_other log(1 - p_i)

Sunlit and shadowed rays constrain it together: the dark (shadowed) rate anchors the
receiver noise, the sunlit excess measures g. Recordings without a sun direction keep
the phenomenological ``solar_background`` effect (a constant probability per shot).

``lidar-sim compare`` (``run.py``) reads the track (``read_sun_track``), predicts every
measured ray with it, marks the points short of the model's range by FALSE_RETURN_SIGMAS
sigma (``short_points``; only the listening time before that mark counts), tells lab
clutter in front of the target from the crowded false returns of a bright patch
and leaves out the rays near blinding (``fit_sunlight``), fits g
(``fit_background_scale``, with its profile-likelihood intervals) and writes ``summary_section`` under ``sunlight`` in summary.json. The data support sunlight-driven false returns (``supported``) when the
rate on sunlit rays is above the rate on shadowed ones by a one-sided binomial test at
SUPPORT_ALPHA, with at least MIN_SUNLIT_FALSE false returns on sunlit rays.

The diagnosis tests ``solar_background`` (false returns at random ranges) like any
candidate; when it is named on a recording whose false returns are shown to follow the
sun, ``sunlit_decision`` names ``sunlight`` instead: the same false returns, with the
physics that the sun test showed.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import brentq, minimize_scalar
from scipy.stats import binomtest

from lidar_sim_ros.compare.model import neighbours
from lidar_sim_ros.compare.diagnose.diagnosis import Decision
from lidar_sim_ros.compare.model.likelihood import material_nuisance
from lidar_sim_ros.core import detection
from lidar_sim_ros.core.config import SunConfig
from lidar_sim_ros.core.effects.base import ReturnContext
from lidar_sim_ros.core.effects.sunlight import (MAX_OUTLIER_FRACTION, Background,
                                                 background_of, crossing_rate_hz)
from lidar_sim_ros.core.radiometry import SPEED_OF_LIGHT_M_S, crossing_probability
from lidar_sim_ros.core.sun import SunTrack
from lidar_sim_ros.io.bag import SUN_TOPIC, read_vectors

FALSE_RETURN_SIGMAS = 5.0     # a point this many sigma short of the expected range is false
# Clutter in front of the target (a cable, a jig) is a surface: at least SURFACE_NEIGHBOURS
# neighbouring rays see it at the range of the point, within the noise of two ranges and
# the slope of a surface seen at up to 75 deg incidence. The comparison's looser rule
# (``neighbours.isolated``: one neighbour within 0.2 m or 2 %) would take the false returns
# of a bright patch, which crowd near the start of the range gate, for a surface.
SURFACE_NEIGHBOURS = 2
SURFACE_NOISE_SIGMAS = 3.0 * np.sqrt(2.0)
SURFACE_SLOPE = float(np.tan(np.radians(75.0)))
CLUTTER_MAX_PROBABILITY = 0.05   # a surface of short points where sunlight rarely crosses
NEAR_BLINDING = 0.5           # rays with this share of the blinding power are left out
MAX_PASSES = 4                # of fit_sunlight
# Profile-likelihood intervals of g: -log L within these of its minimum (chi2(1)/2 at 68.3 %
# and 95 %).
DELTA_NLL_68 = 0.5
DELTA_NLL_95 = 1.920729
SUPPORT_ALPHA = 0.01          # one-sided test: sunlit false-return rate above the shadowed one
MIN_SUNLIT_FALSE = 20         # ... with at least this many false returns on sunlit rays


@dataclass(frozen=True)
class SunFit:
    """The fitted receiver factor and the evidence behind it.

    background_scale: g (-); nll: negative log-likelihood at g; nll_unit: at g = 1 (the
    sensor file's receiver as it is); counts and measured rates (false returns per point)
    on rays that see sunlit and shadowed surfaces, with the model's mean rates at g.
    """

    background_scale: float
    nll: float
    nll_unit: float
    sunlit_points: int
    shadowed_points: int
    sunlit_false: int
    shadowed_false: int
    predicted_sunlit_rate: float
    predicted_shadowed_rate: float
    # Profile-likelihood intervals of g (68.3 % and 95 %), clipped to the fit's bounds,
    # and -log L at g = 0 (no background light: the receiver's dark noise alone).
    interval_68: tuple[float, float] = (float('nan'), float('nan'))
    interval_95: tuple[float, float] = (float('nan'), float('nan'))
    nll_zero: float = float('nan')
    clutter_points: int = 0       # short points left out as clutter (``fit_sunlight``)
    bright_rays: int = 0          # rays left out as near blinding (``fit_sunlight``)

    @property
    def sigma(self) -> float:
        """1-sigma uncertainty of g (-): half the 68.3 % interval."""
        return 0.5 * (self.interval_68[1] - self.interval_68[0])

    @property
    def excess_p_value(self) -> float:
        """One-sided p-value of "sunlit rays give no more false returns than shadowed ones":
        given the false returns on both, the sunlit count is binomial with the sunlit
        share of the rays under equal rates."""
        k = self.sunlit_false + self.shadowed_false
        n = self.sunlit_points + self.shadowed_points
        if k == 0 or self.sunlit_points == 0 or self.shadowed_points == 0:
            return 1.0
        return float(binomtest(self.sunlit_false, k, self.sunlit_points / n,
                               alternative='greater').pvalue)

    @property
    def supported(self) -> bool:
        """The data show sunlight-driven false returns: the sunlit rate clearly above the
        shadowed one (module doc)."""
        return self.sunlit_false >= MIN_SUNLIT_FALSE and self.excess_p_value < SUPPORT_ALPHA

    @property
    def sunlit_rate(self) -> float:
        return self.sunlit_false / max(self.sunlit_points, 1)

    @property
    def shadowed_rate(self) -> float:
        return self.shadowed_false / max(self.shadowed_points, 1)

    @property
    def yaml_snippet(self) -> str:
        return f'- {{name: sunlight, params: {{background_scale: {self.background_scale:.6g}}}}}'


def read_sun_track(bag: str | Path, sun: SunConfig | None = None,
                   topic: str = SUN_TOPIC, epoch_s: float = 0.0) -> SunTrack | None:
    """The recording's sun directions as a sun source (times in s of the bag clock minus
    ``epoch_s``: compare's measurements count from their own epoch), or None when the bag
    has no such topic. ``sun`` supplies the irradiance and Earth (default AM0)."""
    series = read_vectors(bag, topic)
    if series is None or len(series.stamp_ns) == 0:
        return None
    config = sun or SunConfig(direction=tuple(series.vector[0]))
    return SunTrack(config, series.stamp_ns / 1e9 - epoch_s, series.vector)


def false_return_mask(measured_range_m, expected_range_m, sigma_m,
                      sigmas: float = FALSE_RETURN_SIGMAS) -> np.ndarray:
    """Points measured well short of the model's range: a threshold crossing before the echo."""
    return (np.asarray(measured_range_m, float)
            < np.asarray(expected_range_m, float) - sigmas * np.maximum(sigma_m, 1e-3))


@dataclass(frozen=True)
class ShortPoints:
    """Measured points short of the model's echo (arrays over the measured points).

    short: measured below ``counted_below_m`` (m; NaN where the ray misses the target),
    the expected range less FALSE_RETURN_SIGMAS sigma; on_surface: short points that
    neighbouring rays see at the same range (clutter in front of the target, or the
    crowded false returns of a bright patch: ``fit_sunlight`` tells them apart).
    """

    short: np.ndarray
    counted_below_m: np.ndarray
    on_surface: np.ndarray


def short_points(range_m: np.ndarray, residual_m: np.ndarray, sigma_m: np.ndarray,
                 material: np.ndarray, directions: np.ndarray, cloud: np.ndarray) -> ShortPoints:
    """The points measured short of the model's range, candidates for false returns.

    range_m: measured ranges (m); residual_m, sigma_m: measured minus expected range and the
    model's sigma (m, NaN where the ray misses the target); material: the model's material
    id per point; directions (N, 3), cloud (N,): for the neighbour test. Short means by
    FALSE_RETURN_SIGMAS sigma after each material's offset and sigma scale
    (``likelihood.material_nuisance``: a calibration mismatch makes no false returns). On a
    surface: SURFACE_NEIGHBOURS neighbouring rays within reach see the same range
    (``neighbours.isolated`` with a tolerance of the noise and the slope of a surface).
    """
    range_m = np.asarray(range_m, float)
    residual = np.asarray(residual_m, float)
    sigma = np.maximum(np.nan_to_num(np.asarray(sigma_m, float), nan=0.0), 1e-6)
    use = np.isfinite(residual)
    offset, scale = material_nuisance(np.where(use, residual, 0.0), sigma,
                                      np.asarray(material, int), use)
    expected = np.where(use, range_m - (residual - offset), np.nan)
    below = expected - FALSE_RETURN_SIGMAS * np.maximum(sigma * scale, 1e-3)
    short = use & (range_m < np.where(use, below, -np.inf))
    found = np.flatnonzero(short)
    surface = np.zeros(len(range_m), bool)
    surface[found] = ~neighbours.isolated(directions, range_m, cloud, found,
                                          SURFACE_NOISE_SIGMAS * (sigma * scale)[found],
                                          SURFACE_SLOPE, SURFACE_NEIGHBOURS)
    return ShortPoints(short, below, surface)


def fit_sunlight(ctx: ReturnContext, points: ShortPoints,
                 bounds: tuple[float, float] = (0.0, 30.0)) -> SunFit:
    """The receiver factor g from the short points of a prediction ``ctx`` made with the
    recording's sun: ``fit_background_scale`` on the rays that speak for it, in passes
    until the rays left out no longer change (at most MAX_PASSES).

    Left out, by what the fitted model predicts for them (never by their outcome, which
    would bias g):

    * clutter: a false return of a bright patch and a piece of clutter may both have
      neighbours at the same range (the false returns crowd near the start of the range
      gate where the crossing rate is high), so a short point on a surface counts as
      clutter only where the fitted sunlight makes a crossing unlikely
      (P < CLUTTER_MAX_PROBABILITY); its ray, whose echo the clutter hides, says nothing
      about sunlight;
    * rays near blinding: where the background reaches NEAR_BLINDING of the blinding
      power, the crossing rate changes by orders of magnitude for a few per cent of
      power and blinding switches the ray off, so a per-cent error of the model's glint
      power (pose, BRDF) would decide g.
    """
    bg = background_of(ctx)
    if bg is None:
        raise ValueError("the prediction has no sun: give the simulator the recording's sun track")
    blinding_w = ctx.scene.sensor.receiver.blinding_power_w
    n = len(points.short)
    out = np.zeros(n, bool)
    for _ in range(MAX_PASSES):
        fit = fit_background_scale(ctx, points.short, bounds, points.counted_below_m, ~out, bg)
        g = fit.background_scale
        nll = FalseReturnLikelihood(ctx, points.short, points.counted_below_m, None, bg)
        p = np.ones(n)
        p[nll.use] = nll.probability(g)
        clutter = points.on_surface & (p < CLUTTER_MAX_PROBABILITY)
        bright = ctx.hit & (g * bg.power_w >= NEAR_BLINDING * blinding_w)
        if np.array_equal(clutter | bright, out):
            break
        out = clutter | bright
    return replace(fit, clutter_points=int(clutter.sum()), bright_rays=int(bright.sum()))


class FalseReturnLikelihood:
    """-log L(g) of which measured points are false returns, for the prediction ``ctx`` of
    the measured rays (one entry per measured point, made with the recording's sun).

    Only rays whose echo the model detects are used: on the others every recorded point
    is false by construction. The background is computed once (shadow rays included);
    each g rescales it."""

    def __init__(self, ctx: ReturnContext, is_false: np.ndarray,
                 counted_below_m: np.ndarray | None = None, keep: np.ndarray | None = None,
                 background: Background | None = None):
        """``counted_below_m`` (N,): the range (m) below which a point was counted false
        (``is_false``), if it lies short of the echo: a crossing between it and the echo
        passes for the echo, so only the time before it counts. ``keep`` (N,): the rays
        to use (default all). ``background``: ``background_of(ctx)`` if already made."""
        bg = background if background is not None else background_of(ctx)
        if bg is None:
            raise ValueError("the prediction has no sun: give the simulator the recording's sun track")
        self.sensor = ctx.scene.sensor
        det = self.sensor.detection
        echo = ctx.hit & detection.detected_mask(ctx.power_w, ctx.range_m, det)
        if keep is not None:
            echo = echo & np.asarray(keep, bool)
        self.use = np.flatnonzero(echo)
        self.power_w, self.listen_s = bg.power_w.take(self.use), bg.listen_s.take(self.use)
        if counted_below_m is not None:
            counted_s = (np.asarray(counted_below_m, float).take(self.use) - det.min_range_m) \
                / (0.5 * SPEED_OF_LIGHT_M_S)
            self.listen_s = np.clip(np.nan_to_num(counted_s, nan=0.0), 0.0, self.listen_s)
        self.is_false = np.asarray(is_false, bool).take(self.use)
        self.sunlit, self.shadowed = bg.sunlit.take(self.use), bg.shadowed.take(self.use)

    def probability(self, g: float) -> np.ndarray:
        """P(false return) per used point at receiver factor g (-)."""
        scaled = g * self.power_w
        rate, _ = crossing_rate_hz(scaled, self.sensor)
        p = np.where(scaled >= self.sensor.receiver.blinding_power_w, 1.0,
                     crossing_probability(rate, self.listen_s))
        return np.clip(p, 1e-300, MAX_OUTLIER_FRACTION)

    def __call__(self, g: float) -> float:
        p = self.probability(g)
        return float(-np.sum(np.where(self.is_false, np.log(p), np.log1p(-p))))


def fit_background_scale(ctx: ReturnContext, is_false: np.ndarray,
                         bounds: tuple[float, float] = (0.0, 30.0),
                         counted_below_m: np.ndarray | None = None,
                         keep: np.ndarray | None = None,
                         background: Background | None = None) -> SunFit:
    """Maximum-likelihood receiver factor g (``FalseReturnLikelihood``): a log grid over
    ``bounds``, then Brent's method around the best grid point; its profile-likelihood
    intervals."""
    nll = FalseReturnLikelihood(ctx, is_false, counted_below_m, keep, background)
    lo, hi = bounds
    grid = np.concatenate([[lo], np.geomspace(max(lo, 1e-3), hi, 40)])
    values = [nll(g) for g in grid]
    best = int(np.argmin(values))
    a, b = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    res = minimize_scalar(nll, bounds=(a, b), method='bounded', options={'xatol': 1e-4})
    g = float(res.x) if res.fun <= values[best] else float(grid[best])
    p = nll.probability(g)
    y, sunlit, shadowed = nll.is_false, nll.sunlit, nll.shadowed
    at_g = nll(g)
    return SunFit(g, at_g, nll(1.0), int(sunlit.sum()), int(shadowed.sum()),
                  int((y & sunlit).sum()), int((y & shadowed).sum()),
                  float(p[sunlit].mean()) if sunlit.any() else 0.0,
                  float(p[shadowed].mean()) if shadowed.any() else 0.0,
                  profile_interval(nll, g, at_g, DELTA_NLL_68, bounds),
                  profile_interval(nll, g, at_g, DELTA_NLL_95, bounds), nll(0.0))


def profile_interval(nll, g: float, nll_min: float, delta: float,
                     bounds: tuple[float, float]) -> tuple[float, float]:
    """The g where -log L rises ``delta`` above its minimum ``nll_min`` (at ``g``), each
    side found by Brent's root finder; a side whose bound stays within ``delta`` is the
    bound (the data do not limit g there)."""
    def rise(x: float) -> float:
        return nll(x) - nll_min - delta

    ends = []
    for edge in bounds:
        if edge == g or rise(edge) <= 0:
            ends.append(float(edge))
        else:
            ends.append(float(brentq(rise, *sorted((g, edge)), xtol=1e-6 * max(g, 1e-3))))
    return ends[0], ends[1]


def summary_section(fit: SunFit, topic: str, samples: int,
                    model_scale: float | None) -> dict:
    """The ``sunlight`` entry of summary.json (docs/compare.md); ``model_scale``: the
    background_scale of the model's own ``sunlight`` effect (None: not in the model)."""
    def num(x: float) -> float | None:
        return None if not np.isfinite(x) else round(float(x), 6)

    ratio = fit.sunlit_rate / fit.shadowed_rate if fit.shadowed_rate > 0 else None
    return {
        'topic': topic, 'sun_samples': int(samples),
        'background_scale': num(fit.background_scale),
        'background_scale_sigma': num(fit.sigma),
        'background_scale_interval_68': [num(x) for x in fit.interval_68],
        'background_scale_interval_95': [num(x) for x in fit.interval_95],
        'sunlit_points': fit.sunlit_points, 'shadowed_points': fit.shadowed_points,
        'sunlit_false_returns': fit.sunlit_false, 'shadowed_false_returns': fit.shadowed_false,
        'clutter_points': fit.clutter_points, 'near_blinding_rays': fit.bright_rays,
        'sunlit_rate': num(fit.sunlit_rate), 'shadowed_rate': num(fit.shadowed_rate),
        'rate_ratio': num(ratio) if ratio is not None else None,
        'predicted_sunlit_rate': num(fit.predicted_sunlit_rate),
        'predicted_shadowed_rate': num(fit.predicted_shadowed_rate),
        'excess_p_value': float(f'{fit.excess_p_value:.3g}'),
        'supported': bool(fit.supported),
        'nll_gain_vs_sensor_file_nats': num(fit.nll_unit - fit.nll),
        'nll_gain_vs_no_background_nats': num(fit.nll_zero - fit.nll),
        'model_background_scale': None if model_scale is None else float(model_scale),
        'effect_yaml': fit.yaml_snippet,
    }


def sunlit_decision(decision: Decision, section: dict | None) -> Decision:
    """``sunlight`` in place of a named ``solar_background`` when the recording's false
    returns follow the sun (``section``: summary.json's ``sunlight``, ``supported``) and
    the model's own sunlight does not already account for them (absent, or its
    background_scale outside the fitted 95 % interval). Otherwise ``decision`` as it is:
    background light that does not follow the sun stays phenomenological."""
    if decision.missing != 'solar_background' or not section or not section['supported']:
        return decision
    in_model = section.get('model_background_scale')
    lo, hi = section['background_scale_interval_95']
    if in_model is not None and lo <= in_model <= hi:
        return decision
    return replace(decision, missing='sunlight', evidence='solar_background')
