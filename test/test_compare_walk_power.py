"""Which power a range walk reads in the comparison: the measured intensity's or the
model's (``range_walk``'s ``power`` option, ``likelihood.reads_measured_power``), chosen
by the fit as any discrete option is (``variants.fit_best_variant``). Hand-made matched
points at 10 m; the fits are the comparison's own."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import ahead_fit_data

from lidar_sim_ros.compare.diagnose import diagnosis as dg, fit_data, variants
from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.core.effects import get_effect_class, make_effect

P_TH = 1e-7      # detection threshold (W)
SIGMA = 0.01     # range noise (m)
K_M = 0.035      # the true walk (m per e-fold of power)


def _points(p_model: np.ndarray, measured_m: np.ndarray, p_measured: np.ndarray) -> lk.FitData:
    """Matched points on two materials at 10 m: the model's power ``p_model`` (W), the
    measured ranges (m) and the power read from the measured intensity (W)."""
    data = ahead_fit_data(np.arange(len(p_model)) % 2, p_model, measured_m, SIGMA, P_TH)
    return replace(data, measured_power_w=p_measured)


def _recording(seed: int, intensity: str) -> lk.FitData:
    """A walk -K_M ln(P_true / P_TH) plus noise. The true power falls as cos(theta)
    (theta 0-80 deg) with a reflectance spread; ``intensity``: 'lambert' reads
    P_true / cos(theta) (a reflectivity compensated for incidence; the model's power is
    the true one within 10 %), 'speckle' reads P_true itself, whose shot-to-shot
    spread (ln sd 0.7) the model does not have."""
    rng = np.random.default_rng(seed)
    n = 4000
    cos_t = np.cos(np.radians(rng.uniform(0.0, 80.0, n)))
    reflect = np.exp(rng.normal(0.0, 0.5, n))
    p_true = 3e-5 * cos_t * reflect
    if intensity == 'lambert':
        p_model, p_meas = p_true * np.exp(rng.normal(0.0, 0.1, n)), p_true / cos_t
    else:
        p_true = p_true * np.exp(rng.normal(0.0, 0.7, n))
        p_model, p_meas = 3e-5 * cos_t * reflect, p_true
    measured = 10.0 - K_M * np.log(p_true / P_TH) + SIGMA * rng.standard_normal(n)
    return _points(p_model, measured, p_meas)


def test_a_walk_on_the_model_power_reads_the_model_not_the_intensity():
    """``power: model`` drives the walk by the model's power even where the measured
    intensity gives one; ``measured`` (the default) by the measured one."""
    p_model = np.array([1e-6, 1e-5, 1e-4])
    data = _points(p_model, np.full(3, 10.0), p_model * 4.0)
    on_model = make_effect('range_walk', {'k_m': 0.02, 'power': 'model'})
    on_meas = make_effect('range_walk', {'k_m': 0.02})
    base = lk.model_on_rays(data, []).expected_range_m
    got_model = lk.model_on_rays(data, [on_model]).expected_range_m - base
    got_meas = lk.model_on_rays(data, [on_meas]).expected_range_m - base
    np.testing.assert_allclose(got_model, -0.02 * np.log(p_model / P_TH), atol=1e-9)
    np.testing.assert_allclose(got_meas, -0.02 * np.log(4.0 * p_model / P_TH), atol=1e-9)
    assert lk.reads_measured_power(on_meas) and not lk.reads_measured_power(on_model)


@pytest.mark.parametrize('seed', [0, 1])
def test_the_fit_keeps_the_model_power_where_the_intensity_is_compensated_for_incidence(seed):
    """Read through P / cos(theta), the walk misses -k ln cos(theta); the fit tries both
    powers and keeps the model's, with the walk's slope within 10 %."""
    fit, _ = variants.fit_best_variant(get_effect_class('range_walk'), _recording(seed, 'lambert'))
    assert fit.effect.params.power == 'model'
    assert abs(fit.effect.params.k_m - K_M) < 0.1 * K_M


@pytest.mark.parametrize('seed', [0, 1])
def test_the_fit_keeps_the_measured_power_where_it_carries_the_shot_to_shot_spread(seed):
    """Where the intensity is the power the walk followed, shot by shot (speckle the
    model cannot know), the measured one is kept."""
    fit, _ = variants.fit_best_variant(get_effect_class('range_walk'), _recording(seed, 'speckle'))
    assert fit.effect.params.power == 'measured'
    assert abs(fit.effect.params.k_m - K_M) < 0.1 * K_M


@pytest.mark.parametrize('power', ['measured', 'model'])
def test_the_range_alone_test_reads_the_power_the_named_walk_reads(monkeypatch, power):
    """``run.named_range_alone`` weighs a named walk against a bias of range alone on the
    power the walk was fitted on: the model's for ``power: model``."""
    from lidar_sim_ros.compare import run
    p_model = np.array([1e-6, 1e-5, 1e-4, 3e-5])
    data = _points(p_model, np.full(4, 10.0), p_model * 4.0)
    seen = {}

    def record(named, residual_m, sigma_m, range_m, power_w, *rest):
        seen['power_w'] = np.asarray(power_w)
    monkeypatch.setattr(run.range_alone, 'weigh_range_alone', record)
    walk = make_effect('range_walk', {'k_m': 0.02, 'power': power})
    run.named_range_alone('range_walk', walk, data, np.zeros(4, int), 3.0, 0)
    np.testing.assert_allclose(seen['power_w'], p_model * (4.0 if power == 'measured' else 1.0))


def _lasers_beside_walk(power: str) -> dict | None:
    """``run.laser_intensity`` where laser_bias is named beside a walk in the model that
    reads ``power``: four lasers whose measured power is off the model's by a per-laser
    gain, the offsets k times its log: what the lasers take back of a walk that reads
    the measured power."""
    from types import SimpleNamespace

    from lidar_sim_ros.compare import run
    n, k = 4000, K_M
    laser = np.arange(n) % 4
    gain = np.array([-0.4, -0.1, 0.2, 0.5])
    p_model = np.full(n, 3e-5)
    rays = fit_data.RaySet(SimpleNamespace(laser=laser), np.arange(n), np.zeros(0, int),
                     measured_power_w=p_model * np.exp(gain[laser]))
    pred = SimpleNamespace(ctx=SimpleNamespace(power_w=p_model))
    walk = make_effect('range_walk', {'k_m': k, 'power': power})
    lasers = dg.Candidate('laser_bias', score=0.1, z=20.0, significant=True, practical=True,
                          params={f'laser_{i}_m': float(k * g) for i, g in enumerate(gain)})
    return run.laser_intensity(dg.Decision('laser_bias', []), [lasers], [walk], rays, pred, 3.0)


def test_the_lasers_intensity_tie_is_read_only_through_a_walk_on_the_measured_power():
    """Per-laser offsets equal to k times each laser's log intensity gain are what a walk
    on the measured power makes of gains (summary.json's laser_intensity says so); a walk
    on the model's power reads no laser's intensity, so there is nothing to tie."""
    tie = _lasers_beside_walk('measured')
    assert tie is not None and tie['ties'], tie
    assert _lasers_beside_walk('model') is None
