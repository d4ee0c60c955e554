"""Measured intensity as received power (compare/recording/intensity.py), and power-driven effects
fitted against it (compare/model/likelihood.py: Effect.power_driven)."""
from __future__ import annotations

import numpy as np
import pytest

from lidar_sim_ros.compare.model.fit import fit_effect
from lidar_sim_ros.compare.recording.intensity import calibrate_intensity
from lidar_sim_ros.compare.model.likelihood import FitData
from lidar_sim_ros.core.effects import ReturnContext, get_effect_class
from lidar_sim_ros.core.geometry import Hits
from lidar_sim_ros.core.pipeline import Prediction

P_TH = 1e-7


def _powers(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return 10 ** rng.uniform(-6.5, -3.5, n), rng.uniform(8.0, 14.0, n)


def test_intensity_proportional_to_power_gives_the_gain_and_the_power():
    p, r = _powers(5000)
    cal = calibrate_intensity(3.0e6 * p, r, p)
    assert cal.gain == pytest.approx(3.0e6, rel=1e-6)
    assert cal.range_exponent == 0.0 and cal.explained > 0.999
    assert cal.power_w(3.0e6 * p, r) == pytest.approx(p, rel=0.05)


def test_range_compensated_reflectivity_is_recognised():
    p, r = _powers(5000, 1)
    cal = calibrate_intensity(p * r ** 2, r, p)
    assert cal.range_exponent == -2.0
    assert cal.power_w(p * r ** 2, r) == pytest.approx(p, rel=0.05)


def test_log_compressed_counts_map_back_to_power_within_a_count():
    p, r = _powers(20000, 2)
    u = np.log(p / P_TH) / np.log(1e-3 / P_TH)
    counts = np.clip(np.round(1 + 254 * u ** 0.85), 1, 255)
    back = calibrate_intensity(counts, r, p).power_w(counts, r)
    # One count spans d ln P = ln(1e-3 / P_th) / (254 * 0.85 u^-0.15): about 0.05 here.
    assert np.median(np.abs(np.log(back / p))) < 0.05


def test_unrelated_intensity_is_not_used():
    p, r = _powers(5000, 3)
    noise = np.random.default_rng(9).uniform(1, 100, 5000)
    assert not calibrate_intensity(noise, r, p).usable


def _walk_data(k_m: float, seed: int = 4) -> tuple[FitData, np.ndarray]:
    """Points whose bias is -k ln(P_true / P_th); the model's power is off by a factor
    per material (wrong reflectance numbers), the sensor measured the true power."""
    rng = np.random.default_rng(seed)
    n = 6000
    material = rng.integers(0, 2, n)
    p_true = 10 ** rng.uniform(-6.5, -4.0, n)
    p_model = p_true * np.where(material == 0, 4.0, 0.25) * 10 ** rng.normal(0, 0.3, n)
    sigma = 0.02
    rng_m = np.full(n, 10.0)
    measured = rng_m - k_m * np.log(p_true / P_TH) + sigma * rng.standard_normal(n)
    ctx = ReturnContext(range_m=rng_m, incidence_rad=np.zeros(n), material=material,
                        power_w=p_model, intensity=p_model, t_s=np.zeros(n),
                        az_rad=np.zeros(n), el_rad=np.zeros(n), laser=np.zeros(n, int),
                        divergence_rad=0.002, hit=np.ones(n, bool), threshold_power_w=P_TH)
    hits = Hits(np.ones(n, bool), rng_m, np.zeros((n, 3)), np.zeros(n), material,
                np.zeros(n, int))
    pred = Prediction(ctx, hits, np.tile([1.0, 0, 0], (n, 1)), np.zeros(n), np.full(n, sigma))
    data = FitData(measured_range_m=measured, baseline=pred, cast=lambda e: pred,
                   unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                   range_window_m=(0.0, 100.0))
    return data, p_true


def test_range_walk_is_fitted_against_the_measured_power():
    from dataclasses import replace
    data, p_true = _walk_data(0.02)
    walk = get_effect_class('range_walk')
    measured = fit_effect(walk, replace(data, measured_power_w=p_true))
    modelled = fit_effect(walk, data)
    assert measured.params['k_m'] == pytest.approx(0.02, abs=0.001)
    # Against the model's own power the slope is diluted by its reflectance errors
    # (errors-in-variables: var ln P / (var ln P + var error) = 1.66^2 / (1.66^2 + 0.69^2)).
    assert modelled.params['k_m'] == pytest.approx(0.02 * 0.85, abs=0.001)
    assert measured.nll_per_point < modelled.nll_per_point - 0.05


def test_a_clipped_scale_is_found_and_its_points_take_the_models_power():
    """An intensity clipped at the top of its scale (holdout 10's 8-bit reflectivity, most
    points at 255) says only that the power reached the clip: the map is fitted below it
    and the clipped points take the larger of the model's power and the clip's level."""
    p, r = _powers(8000, 5)
    cap = np.quantile(3.0e6 * p, 0.6)
    counts = np.minimum(3.0e6 * p, cap)
    cal = calibrate_intensity(counts, r, p)
    assert cal.clip_log_i == pytest.approx(np.log(cap))
    assert cal.clipped_share == pytest.approx(0.4, abs=0.01)
    back = cal.power_w(counts, r, p)
    assert back == pytest.approx(p, rel=0.05)
    # Without the model's power the clipped points sit at the clip's level (the old
    # reading: every clipped point alike).
    flat = cal.power_w(counts, r)
    assert np.ptp(np.log(flat[counts >= cap])) < 0.05


@pytest.mark.parametrize('seed', [2, 6])
def test_a_scale_that_is_not_clipped_has_no_clip(seed):
    """Counts that reach the top of the scale as often as any value near it (a log scale
    over the whole range of powers), and float intensities: no clip."""
    p, r = _powers(20000, seed)
    u = np.log(p / p.min()) / np.log(p.max() / p.min())
    counts = np.clip(np.round(1 + 254 * u), 1, 255)
    assert calibrate_intensity(counts, r, p).clip_log_i is None
    assert calibrate_intensity(3.0e6 * p, r, p).clip_log_i is None


def test_range_walk_read_through_a_clipped_scale_keeps_its_slope():
    """The walk fitted on the power read from a clipped intensity: the clipped points at
    the model's power keep the slope (diluted as the model's power dilutes it: 0.016 here,
    as in the test above); all at the clip's level steepen it to fit the unclipped half
    alone (0.026)."""
    from dataclasses import replace
    data, p_true = _walk_data(0.02)
    counts = np.minimum(1e7 * p_true, np.quantile(1e7 * p_true, 0.5))
    p_model = data.baseline.ctx.power_w
    cal = calibrate_intensity(counts, data.baseline.ctx.range_m, p_model)
    walk = get_effect_class('range_walk')
    kept = fit_effect(walk, replace(data, measured_power_w=cal.power_w(
        counts, data.baseline.ctx.range_m, p_model)))
    flat = fit_effect(walk, replace(data, measured_power_w=cal.power_w(
        counts, data.baseline.ctx.range_m)))
    assert abs(kept.params['k_m'] - 0.02) < abs(flat.params['k_m'] - 0.02)
    assert kept.nll_per_point < flat.nll_per_point
