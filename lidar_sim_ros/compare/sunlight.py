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

This module is self-contained (no other compare module imports it yet): the comparison
hands it the measured ranges and the model's prediction for the same rays made with the
recording's sun (``read_sun_track`` -> ``Simulator.sun``), see ``fit_background_scale``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from lidar_sim_ros.core import detection
from lidar_sim_ros.core.config import SunConfig
from lidar_sim_ros.core.effects.base import ReturnContext
from lidar_sim_ros.core.effects.sunlight import MAX_OUTLIER_FRACTION, background_of, crossing_rate_hz
from lidar_sim_ros.core.radiometry import crossing_probability
from lidar_sim_ros.core.sun import SunTrack
from lidar_sim_ros.io.bag import SUN_TOPIC, read_vectors

FALSE_RETURN_SIGMAS = 5.0     # a point this many sigma short of the expected range is false


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
                   topic: str = SUN_TOPIC) -> SunTrack | None:
    """The recording's sun directions as a sun source (times in s of the bag clock), or None
    when the bag has no such topic. ``sun`` supplies the irradiance and Earth (default AM0)."""
    series = read_vectors(bag, topic)
    if series is None or len(series.stamp_ns) == 0:
        return None
    config = sun or SunConfig(direction=tuple(series.vector[0]))
    return SunTrack(config, series.stamp_ns / 1e9, series.vector)


def false_return_mask(measured_range_m, expected_range_m, sigma_m,
                      sigmas: float = FALSE_RETURN_SIGMAS) -> np.ndarray:
    """Points measured well short of the model's range: a threshold crossing before the echo."""
    return (np.asarray(measured_range_m, float)
            < np.asarray(expected_range_m, float) - sigmas * np.maximum(sigma_m, 1e-3))


class FalseReturnLikelihood:
    """-log L(g) of which measured points are false returns, for the prediction ``ctx`` of
    the measured rays (one entry per measured point, made with the recording's sun).

    Only rays whose echo the model detects are used: on the others every recorded point
    is false by construction. The background is computed once (shadow rays included);
    each g rescales it."""

    def __init__(self, ctx: ReturnContext, is_false: np.ndarray):
        bg = background_of(ctx)
        if bg is None:
            raise ValueError("the prediction has no sun: give the simulator the recording's sun track")
        self.sensor = ctx.scene.sensor
        echo = ctx.hit & detection.detected_mask(ctx.power_w, ctx.range_m, self.sensor.detection)
        self.use = np.flatnonzero(echo)
        self.power_w, self.listen_s = bg.power_w.take(self.use), bg.listen_s.take(self.use)
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
                         bounds: tuple[float, float] = (0.0, 30.0)) -> SunFit:
    """Maximum-likelihood receiver factor g (``FalseReturnLikelihood``): a log grid over
    ``bounds``, then Brent's method around the best grid point."""
    nll = FalseReturnLikelihood(ctx, is_false)
    lo, hi = bounds
    grid = np.concatenate([[lo], np.geomspace(max(lo, 1e-3), hi, 40)])
    values = [nll(g) for g in grid]
    best = int(np.argmin(values))
    a, b = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    res = minimize_scalar(nll, bounds=(a, b), method='bounded', options={'xatol': 1e-4})
    g = float(res.x) if res.fun <= values[best] else float(grid[best])
    p = nll.probability(g)
    y, sunlit, shadowed = nll.is_false, nll.sunlit, nll.shadowed
    return SunFit(g, nll(g), nll(1.0), int(sunlit.sum()), int(shadowed.sum()),
                  int((y & sunlit).sum()), int((y & shadowed).sum()),
                  float(p[sunlit].mean()) if sunlit.any() else 0.0,
                  float(p[shadowed].mean()) if shadowed.any() else 0.0)
