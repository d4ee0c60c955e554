"""Robustness of the diagnosis (compare/diagnosis.py, compare/materials.py) on data
that is not exactly the model's shape: heavy noise tails, unknown point times, an
effect added with --fit whose extra noise varies from point to point."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lidar_sim_ros.compare.materials import material_sigma_m
from lidar_sim_ros.compare.run import CompareOptions, run_compare
from lidar_sim_ros.core.effects import make_effect

from datasets import make_dataset
from foreign_sim import ForeignSpec, generate


def _foreign(spec: ForeignSpec, root: Path) -> dict:
    ds = generate(replace(spec, frames=2), root / spec.name)
    return run_compare(CompareOptions(bag=ds.bag, mesh=ds.mesh, out=root / spec.name / 'out',
                                      config=ds.scenario, report=False)).summary


def test_material_sigma_with_varying_effect_noise_is_unbiased():
    rng = np.random.default_rng(0)
    extra = rng.uniform(0.0, 0.06, 100_000)      # effect noise varying point to point
    res = rng.standard_normal(100_000) * np.sqrt(0.03 ** 2 + extra ** 2)
    assert material_sigma_m(res, extra ** 2) == pytest.approx(0.03, rel=0.03)
    assert material_sigma_m(rng.standard_normal(50_000) * 0.02, 0.0) == pytest.approx(0.02,
                                                                                    rel=0.03)
    assert material_sigma_m(res * 0.0, extra ** 2) == 0.0


def test_heavy_tailed_clean_data_is_not_solar_background(tmp_path):
    """Student t (6 dof) noise: outlier-tolerant fits gain on the tails, but no point lies
    metres off the surface, so solar background is vetoed and the verdict is null."""
    s = _foreign(ForeignSpec('heavy', None, seed=7, noise='student6'), tmp_path)
    assert s['missing_effect'] is None, s['candidates'][:2]
    solar = next(c for c in s['candidates'] if c['name'] == 'solar_background')
    assert not solar['significant'] or 'heavy noise tails' in solar['vetoed']


def test_real_false_returns_are_still_solar_background(tmp_path):
    s = _foreign(ForeignSpec('solar', 'solar_background',
                             {'fraction': 0.006, 'mean_range_m': 25.0}, seed=16, distance_m=15.0),
                 tmp_path)
    assert s['missing_effect'] == 'solar_background', s['candidates'][:2]
    assert 'vetoed' not in s['candidates'][0]


def test_absolute_timestamp_field_is_used_and_clean_data_stays_null(tmp_path):
    """Hesai-style absolute float64 "timestamp": read, so no half-scan time offset."""
    s = _foreign(ForeignSpec('ts', None, seed=4, point_time='timestamp', spin_dps=12.0),
                 tmp_path)
    assert s['point_times'] == 'field'
    assert s['point_time_field']['name'] == 'timestamp'
    assert s['point_time_field']['read_as'] == ['absolute s']
    assert s['missing_effect'] is None, s['candidates'][:2]


def test_fitted_true_effect_leaves_nothing_missing(tmp_path):
    """Our simulator with a strong incidence effect; adding it with --fit gives null
    (the refit material sigma no longer absorbs part of the effect's noise)."""
    effect = make_effect('incidence_angle', {'bias_gain': 2.0, 'sigma_gain': 1.0})
    ds = make_dataset(tmp_path, 'inc', [effect], seed=109)
    out = tmp_path / 'fit'
    s = run_compare(CompareOptions(bag=ds.bag, mesh=ds.mesh, out=out, config=ds.scenario,
                                   effects=['incidence_angle'], fit=True, report=False)).summary
    assert s['missing_effect'] is None, s['candidates'][:2]
    assert not any(m['sigma_mismatch'] for m in s['materials'].values()), s['materials']
    assert json.loads((out / 'summary.json').read_text())['missing_effect'] is None


@pytest.mark.parametrize('stamp_offset_s', [0.0, 0.05, 0.1])
def test_unknown_point_times_give_their_spread_whatever_the_stamp(stamp_offset_s):
    """Points measured uniformly over a 0.1 s frame, stamped at its start, middle or
    end: the residual is range_rate x (t - stamp); the fitted spread of the unknown
    times is the uniform's 0.1 / sqrt(12) s whatever the constant shift, and 0 when
    the residual does not follow the motion."""
    from lidar_sim_ros.compare.point_times import time_spread_s
    rng = np.random.default_rng(3)
    n = 20000
    rr = rng.normal(0.0, 0.4, n)                        # m/s along each ray
    material = rng.integers(0, 3, n)
    sigma = np.full(n, 0.01)
    tau = rng.uniform(0.0, 0.1, n) - stamp_offset_s
    residual = rr * tau + sigma * rng.standard_normal(n) + 0.02 * material
    assert time_spread_s(residual, sigma, material, rr, 0.1) == pytest.approx(
        0.1 / np.sqrt(12), rel=0.15)
    still = sigma * rng.standard_normal(n)
    assert time_spread_s(still, sigma, material, rr, 0.1) < 0.005
