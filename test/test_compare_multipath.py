"""Multipath in the comparison: the ghost component of the likelihood (compare/model/likelihood.py),
the fit of its strength (compare/model/fit.py) and its signature (``likelihood.ghost_points``).

Closed forms on test_multipath's scene (a Phong mirror plate at 45 deg in front of a
diffuse wall y = 1 m): the ghosts the likelihood expects lie on the wall's mirror
image, the plane x = 6 m, plus the wall's material bias; a point's NLL is the hand-made
three-part mixture; ghosts drawn with each shot's share g = 1 - exp(-s P / P_th) give back
s; a recording without ghosts fits strength 0 and shows no ghost points.
"""
from __future__ import annotations

import numpy as np
import pytest

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.model.fit import fit_effect
from lidar_sim_ros.core.effects import make_effect
from lidar_sim_ros.core.effects.multipath import Multipath
from lidar_sim_ros.core.pipeline import Simulator
from conftest import sensor
from test_multipath import AT_ORIGIN, MIRROR, WALL, mirror_scene

PLATE = dict(MIRROR, bias_m=-0.01, sigma_m=0.01)
BACK = dict(WALL, bias_m=0.03, sigma_m=0.01)


def plate_rays(n_az: int = 40, n_el: int = 25) -> np.ndarray:
    """Unit rays on a grid over the plate (az -3..3 deg, el -4..4 deg)."""
    az, el = np.meshgrid(np.radians(np.linspace(-3.0, 3.0, n_az)),
                         np.radians(np.linspace(-4.0, 4.0, n_el)))
    az, el = az.ravel(), el.ravel()
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)


def fit_data(ghost_share_of, seed: int = 0):
    """(FitData, ghost mask, prediction): echo ranges with the plate's bias and noise; the
    shots drawn as ghosts (probability ``ghost_share_of(ghosts)`` per ray) report the
    ghost at the range the mirror geometry gives (x = 6 m) with the wall's bias and noise."""
    target, mats = mirror_scene(PLATE, BACK)
    sim = Simulator(sensor(), mats, target, seed=3, effects=[])
    d = plate_rays()
    pred = sim.predict(np.zeros(len(d)), d, AT_ORIGIN)
    assert pred.ctx.hit.all() and np.all(pred.ctx.material == 0)
    rng = np.random.default_rng(seed)
    measured = pred.ctx.range_m - 0.01 + 0.01 * rng.standard_normal(len(d))
    probe = lk.ghosts_on(pred, Multipath())
    share = np.zeros(len(d))
    share[probe.index] = ghost_share_of(probe)
    ghost = rng.random(len(d)) < share
    true_ghost = 6.0 / d[:, 0]                       # on the wall's mirror image x = 6 m
    measured = np.where(ghost, true_ghost + 0.03 + 0.01 * rng.standard_normal(len(d)), measured)
    data = lk.FitData(measured_range_m=measured, baseline=pred, cast=lambda e: pred,
                      unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                      range_window_m=(0.0, 20.0))
    return data, ghost, pred


def test_ghosts_lie_on_the_mirrored_wall_plus_its_bias():
    data, _, pred = fit_data(lambda g: 0.0)
    gh = lk.ghosts_on(pred, Multipath())
    d = pred.directions[gh.index]
    assert len(gh.index) > 500
    np.testing.assert_allclose(gh.range_m, 6.0 / d[:, 0] + BACK['bias_m'], atol=1e-4)
    path = 6.0 / d[:, 0] - pred.ctx.range_m[gh.index]
    np.testing.assert_allclose(gh.sigma_m, np.hypot(0.01, lk.GHOST_SPREAD * path), rtol=1e-4)
    # Power per unit strength: the simulator's own ghosts at strength 1.
    one = Multipath({'strength': 1.0}).extra_returns(pred.ctx)
    at = np.searchsorted(gh.index, one.shot)
    np.testing.assert_allclose(gh.power_per_scale_w[at], one.power_w, rtol=1e-9)


def test_point_nll_is_the_three_part_mixture():
    data, _, pred = fit_data(lambda g: 0.0)
    s = 0.01
    eff = make_effect('multipath', {'strength': s})
    model = lk.model_on_rays(data, [eff])
    nll, _ = lk.point_nll(data, model, 0.0, profile_materials=False)
    gh = lk.ghosts_on(pred, Multipath())
    k = gh.index[7]
    g = 1.0 - np.exp(-s * gh.power_per_scale_w[7] / pred.ctx.threshold_power_w)
    assert 0.01 < g < 0.99
    r = data.measured_range_m[k]

    def normal(x, mu, sd):
        return np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi))

    w = lk.MODEL_FLOOR
    echo = normal(r, pred.ctx.range_m[k] - 0.01, 0.01)
    ghost = normal(r, gh.range_m[7], gh.sigma_m[7])
    hand = (1 - w) * ((1 - g) * echo + g * ghost) + w / 20.0
    assert nll[k] == pytest.approx(-np.log(hand), rel=1e-9)


def test_fit_recovers_the_strength_the_ghosts_were_drawn_with():
    # s0 such that the median shot's ghost share is 0.2 (each shot its own share).
    _, _, pred = fit_data(lambda g: 0.0)
    ratio = lk.ghosts_on(pred, Multipath()).power_per_scale_w / pred.ctx.threshold_power_w
    s0 = -np.log(1 - 0.2) / np.median(ratio)
    data, ghost, _ = fit_data(lambda g: -np.expm1(-s0 * g.power_per_scale_w / g.threshold_w),
                              seed=1)
    assert 150 < ghost.sum() < 300
    fit = fit_effect(Multipath, data)
    # ~200 ghosts among 1000 shots: a binomial share known to ~7 %, the strength to ~10 %.
    assert fit.params['strength'] == pytest.approx(s0, rel=0.25)
    assert fit.nll_gain_per_point > 0.5
    assert lk.ghost_points(data, [fit.effect]) == pytest.approx(ghost.sum(), abs=3)


def test_no_ghosts_fit_strength_zero_and_show_no_ghost_points():
    data, ghost, _ = fit_data(lambda g: 0.0, seed=2)
    assert not ghost.any()
    fit = fit_effect(Multipath, data)
    assert fit.nll_gain_per_point < 1e-3
    assert lk.ghost_points(data, [make_effect('multipath')]) == 0
