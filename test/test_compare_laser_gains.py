"""Per-laser range offsets against per-laser intensity gains read through a range walk
(``compare/diagnose/laser_gains.py``), on closed forms."""
import numpy as np

from lidar_sim_ros.compare.diagnose import laser_gains
from lidar_sim_ros.compare.report import verdict


def _lasers(rng, gains, n=400):
    laser = np.repeat(np.arange(len(gains)), n)
    model = rng.uniform(1e-9, 1e-7, laser.size)
    measured = model * np.asarray(gains)[laser] * np.exp(rng.normal(0, 0.3, laser.size))
    return laser, measured, model


def test_offsets_that_are_k_ln_of_the_intensity_gains_tie_with_them_and_others_do_not():
    """A walk bias = -k ln P read from an intensity with gain g_l on laser l leaves, on
    laser l, a range residual +k ln g_l (hand: k 0.0186 m, gains e^{+-0.3}: offsets
    +-5.6 mm). The per-laser mean log ratio recovers ln g_l, and offsets of that size and
    pattern tie; offsets of their own (the ninth holdout's laser_100: no gains) do not,
    nor do offsets in the gains' pattern but ten times their size (k explains the
    pattern, not the size: the gains are then not an equally good cause)."""
    rng = np.random.default_rng(7)
    k = 0.0186
    ln_g = rng.normal(0, 0.3, 24)
    laser, measured, model = _lasers(rng, np.exp(ln_g))
    ratio = laser_gains.per_laser_log_ratio(laser, measured, model)
    got = np.array([ratio[l] for l in range(24)])
    assert np.allclose(got - got.mean(), ln_g - ln_g.mean(), atol=0.05)
    offsets = k * ln_g + rng.normal(0, 0.001, 24)
    tie = laser_gains.intensity_tie(list(offsets), ratio, k, z_crit=3.0)
    assert tie['ties'] and tie['correlation'] > 0.9 and tie['lasers'] == 24
    assert abs(tie['slope_over_k'] - 1) < 0.15
    own = rng.normal(0, 0.02, 24)
    assert not laser_gains.intensity_tie(list(own), ratio, k, 3.0)['ties']
    assert not laser_gains.intensity_tie(list(10 * offsets), ratio, k, 3.0)['ties']
    flat = laser_gains.per_laser_log_ratio(*_lasers(rng, np.ones(24)))
    assert not laser_gains.intensity_tie(list(own), flat, k, 3.0)['ties']
    assert laser_gains.intensity_tie([0.01, -0.01], {0: 0.1, 1: -0.1}, k, 3.0) is None
    same = laser_gains.per_laser_log_ratio(laser, model * 2.0, model)   # no gains at all
    assert laser_gains.intensity_tie(list(own), same, k, 3.0) is None
    text = verdict.laser_intensity_words(tie)
    assert 'per-channel intensity calibration' in text and 'cannot tell the two' in text
    assert verdict.laser_intensity_words({**tie, 'ties': False}) == ''
