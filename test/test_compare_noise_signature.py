"""A noise effect's signature (compare/diagnose/diagnosis.py ``core_veto``,
``driver_veto``): it widens the core of the residual distribution, and it explains the
residual's driver when that is another feature than the power it follows. Hand-made
diagnoses whose held-out per-point NLLs are computed in closed form (Gaussian densities
with and without the extra noise), not by the comparison's likelihood."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lidar_sim_ros.compare.diagnose import diagnosis as dg
from lidar_sim_ros.compare.diagnose import far_returns as fr
from lidar_sim_ros.core.effects import get_effect_class, make_effect

from test_compare_naming import Hand

N = 12000
SIGMA = 0.02
FLOOR = 1e-5
WINDOW_M = 10.0


def _nll(r, s):
    """Per-point NLL of a Gaussian with an outlier floor (the held-out likelihood's form)."""
    g = np.exp(-0.5 * (r / s) ** 2) / (s * np.sqrt(2 * np.pi))
    return -np.log((1 - FLOOR) * g + FLOOR / WINDOW_M)


class Noise(Hand):
    def __init__(self, residual, sigma_cand):
        super().__init__()
        self.rays = SimpleNamespace(matched=np.arange(N), unmatched=np.arange(0),
                                    measured_power_w=np.ones(N))
        self.fold_order = np.arange(N)
        self.blocks = np.arange(N) // 20
        self._z_crit = 3.0
        self._core = np.abs(residual) <= fr.CORE_SIGMAS * SIGMA
        self.base = _nll(residual, SIGMA)
        self.cand = dg.Candidate('snr_noise', effect=make_effect('snr_noise', {'c_m': 0.1}))
        self.cand.heldout_nll = _nll(residual, sigma_cand)

    def base_heldout(self):
        return self.base


def test_noise_widening_the_core_at_low_power_passes():
    """A quarter of the points (the weakest) with 3x the noise, the candidate's sigma
    3x there: its gain lies in the core."""
    rng = np.random.default_rng(0)
    low = np.arange(N) < N // 4
    s = np.where(low, 3 * SIGMA, SIGMA)
    d = Noise(rng.normal(0.0, 1.0, N) * s, s)
    assert d.core_veto(d.cand) is None


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_few_points_at_far_offsets_are_no_noise(seed):
    """Dual returns: 1 % of the points 0.3-2 m behind the surface, weak; a candidate
    that widens the weak points' sigma to 0.3 m gains on them, but loses on the core."""
    rng = np.random.default_rng(seed)
    r = rng.normal(0.0, SIGMA, N)
    second = rng.random(N) < 0.01
    r[second] = rng.uniform(0.3, 2.0, second.sum())
    weak = second | (rng.random(N) < 0.01)
    s = np.where(weak, 0.3, SIGMA)
    d = Noise(r, s)
    assert np.sum(d.base - d.cand.heldout_nll) / N > dg.MIN_PRACTICAL_GAIN   # it gains
    why = d.core_veto(d.cand)
    assert why is not None and 'core' in why and 'far offsets' in why


def test_core_veto_is_for_noise_effects_only():
    assert dg.is_noise_effect(get_effect_class('snr_noise'))
    for name in ('range_walk', 'incidence_angle', 'solar_background', 'beam_divergence',
                 'time_offset', 'laser_bias', 'multipath', 'range_scale'):
        assert not dg.is_noise_effect(get_effect_class(name)), name


def _attribution(driver, names=('range', 'intensity', 'incidence')):
    feats = [SimpleNamespace(name=n, score=0.009 if n == driver else 0.0,
                             score_z=3.6 if n == driver else -0.9) for n in names]
    return SimpleNamespace(significant=True, driver=driver, features=feats)


@pytest.mark.parametrize('driver, power, names, vetoed', [
    ('range', True, ('range', 'intensity', 'incidence'), True),      # sigma_r2
    ('intensity', True, ('range', 'intensity', 'incidence'), False),  # its own feature
    (None, True, ('range', 'intensity', 'incidence'), False),        # no driver
    ('range', False, ('range', 'intensity', 'incidence'), False),    # model power: reads range
    ('range', True, ('range', 'incidence'), False),                  # power not attributed
])
def test_a_power_driven_noise_must_explain_another_driver(driver, power, names, vetoed):
    """Noise growing with the range, not the power (the residual depends most on range
    given the measured power): snr_noise follows the power alone and cannot explain it."""
    d = Hand()
    d.rays = SimpleNamespace(measured_power_w=np.ones(3) if power else None)
    c = dg.Candidate('snr_noise', effect=make_effect('snr_noise', {'c_m': 0.1}))
    why = d.driver_veto(c, _attribution(driver, names))
    assert (why is not None) == vetoed
    if vetoed:
        assert 'depends most on range' in why and 'measured power alone' in why
    walk = dg.Candidate('range_walk', effect=make_effect('range_walk', {'k_m': 0.01}))
    assert d.driver_veto(walk, _attribution(driver, names)) is None   # a bias: share rule


def test_a_weak_real_widening_keeps_a_decisive_core_gain():
    """A weak SNR noise (the weakest 10 % of the points with 1.6x the noise): part of
    its gain lies beyond 4 sigma, what lies in the core is decisive: it passes."""
    rng = np.random.default_rng(3)
    low = np.arange(N) < N // 10
    s = np.where(low, 1.6 * SIGMA, SIGMA)
    d = Noise(rng.normal(0.0, 1.0, N) * s, s)
    assert d.core_veto(d.cand) is None
