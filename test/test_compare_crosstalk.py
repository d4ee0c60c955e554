"""compare/model/crosstalk.py: ghost returns of the adjacent laser.

On a hand-made recording (4 lasers firing round-robin over a surface, the model's range
known on every ray): exactly the ghosts a strong return leaks into the next shot are
found, at the delay put in, with and without a walk-like residual among the real
returns; nothing without ghosts, nothing without laser ids or point times. Then on a
foreign recording with crosstalk and a walk (test/foreign_sim.py,
``crosstalk_walk``): the comparison leaves out the share made, says crosstalk, and
names the walk (before the ghosts were left out, nothing was named).
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lidar_sim_ros.compare.model import crosstalk

TEST_DIR = Path(__file__).resolve().parent
sys.path.insert(0, str(TEST_DIR))

PERIOD_S = 5e-6
SIGMA_M = 0.02


def _recording(share: float, offset_m: float, clouds: int = 3, shots: int = 6000,
               lasers: int = 4, walk_m: float = 0.0, seed: int = 0):
    """Shots round-robin over ``lasers``; every shot sees a surface 8..14 m away (its
    range varies along the scan), the model's expected range exactly that, the measured
    one that plus SIGMA_M noise (and ``walk_m`` on a fifth of the returns: a residual the
    model lacks). A return leaks into the next shot with chance ``share``, at its range
    + ``offset_m`` (a second return there). Returns range, expected, sigma, t, cloud,
    laser, and the truth mask of the ghosts."""
    rng = np.random.default_rng(seed)
    cols = []
    for c in range(clouds):
        k = np.arange(shots)
        t = c * 0.1 + k * PERIOD_S
        laser = k % lasers
        true = 11.0 + 3.0 * np.sin(k / 300.0 + c)
        meas = true + SIGMA_M * rng.standard_normal(shots)
        meas += walk_m * (rng.random(shots) < 0.2)
        leak = np.flatnonzero(rng.random(shots - 1) < share)
        g = leak + 1
        ghost_r = meas[leak] + offset_m + 0.01 * rng.standard_normal(len(leak))
        cols.append((np.concatenate([meas, ghost_r]), np.concatenate([true, true[g]]),
                     np.full(shots + len(g), SIGMA_M), np.concatenate([t, t[g]]),
                     np.full(shots + len(g), c), np.concatenate([laser, laser[g]]),
                     np.concatenate([np.zeros(shots, bool), np.ones(len(g), bool)])))
    return [np.concatenate(x) for x in zip(*cols)]


@pytest.mark.parametrize('share, offset_m', [(0.03, 0.3), (0.3, 0.1), (0.1, 1.0)])
def test_the_ghosts_of_the_next_shot_are_found_at_their_delay(share, offset_m):
    r, exp, sig, t, cloud, laser, truth = _recording(share, offset_m)
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, laser, True)
    assert xt.looked and xt.offset_m == pytest.approx(offset_m, abs=0.01)
    # Ghosts whose range happens to fall within the noise of the model's are harmless
    # and may stay; nothing real is taken.
    assert np.sum(found & ~truth) <= 0.002 * np.sum(~truth)
    assert np.sum(found & truth) >= 0.97 * truth.sum()
    assert xt.points == found.sum() and xt.clouds == 3
    assert 'crosstalk, outside the catalogue' in crosstalk.words(xt)


def test_range_errors_of_single_returns_are_no_crosstalk():
    """A fifth of the returns 15 cm long (far beyond the noise, as an unmodelled walk
    leaves them), or one laser's returns all 20 cm long: a fixed delay behind the shot
    before, but single returns on rays the model hits (an error of the return, not an
    extra one): no candidates, nothing found."""
    r, exp, sig, t, cloud, laser, truth = _recording(0.0, 0.3, walk_m=0.15)
    assert not truth.any()
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, laser, True)
    assert xt.candidates == 0
    assert not found.any() and xt.points == 0 and crosstalk.words(xt) is None
    r, exp, sig, t, cloud, laser, _ = _recording(0.0, 0.3)
    found, xt = crosstalk.crosstalk_ghosts(r + 0.2 * (laser == 2), exp, sig, t, cloud, laser,
                                           True)
    assert not found.any()


def test_ghosts_beside_a_walk_are_found():
    r, exp, sig, t, cloud, laser, truth = _recording(0.05, 0.3, walk_m=0.15, seed=2)
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, laser, True)
    assert xt.offset_m == pytest.approx(0.3, abs=0.01)
    assert np.sum(found & ~truth) <= 0.002 * np.sum(~truth)
    assert np.sum(found & truth) >= 0.95 * truth.sum()


def test_without_laser_ids_or_point_times_nothing_is_looked_for():
    r, exp, sig, t, cloud, laser, _ = _recording(0.3, 0.3)
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, np.zeros_like(laser), True)
    assert not found.any() and not xt.looked and 'laser' in xt.why_not
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, laser, False)
    assert not found.any() and not xt.looked and 'time' in xt.why_not
    found, xt = crosstalk.crosstalk_ghosts(np.zeros(0), np.zeros(0), np.zeros(0),
                                           np.zeros(0), np.zeros(0), np.zeros(0), True)
    assert found.shape == (0,) and xt.points == 0


def test_bad_values_do_not_break_it():
    r, exp, sig, t, cloud, laser, _ = _recording(0.1, 0.3)
    r = r.copy()
    r[:50] = np.nan
    r[50:60] = np.inf
    sig = sig.copy()
    sig[:20] = np.nan
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, laser, True)
    assert not found[:60].any() and xt.points > 0
    t = t.copy()
    t[100:130] = np.nan                                # a few points without a time
    r[200:210], r[210:220] = 1e300, 1e-300
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, laser, True)
    assert not found[100:130].any() and xt.points > 0.9 * found.size * 0.09
    assert xt.analysed == len(r)


def test_the_shot_period_is_the_smallest_common_step():
    t = np.concatenate([np.arange(100) * 3e-6, 1.0 + np.arange(0, 300, 3) * 3e-6])
    cloud = np.repeat([0, 1], 100)
    assert crosstalk.shot_period_s(t, cloud) == pytest.approx(3e-6, rel=1e-6)
    assert crosstalk.shot_period_s(np.zeros(5), np.zeros(5)) is None


def test_compare_leaves_crosstalk_out_and_names_the_walk(tmp_path: Path):
    """The foreign ``crosstalk_walk`` recording (2 frames): about the share of ghosts made
    is left out and said to be crosstalk, and the walk beside it is named."""
    from foreign_sim import battery, generate

    from lidar_sim_ros.compare import run

    spec = replace(battery(['crosstalk_walk'])[0], frames=2)
    ds = generate(spec, tmp_path / 'xt')
    res = run.run_compare(run.CompareOptions(bag=ds.bag, mesh=ds.mesh, out=tmp_path / 'out',
                                             config=ds.scenario, progress=False,
                                             report=False, plan=False))
    s = res.summary
    made = ds.truth['crosstalk_fraction']
    assert s['crosstalk']['fraction'] == pytest.approx(made, rel=0.2)
    assert 'crosstalk, outside the catalogue' in s['verdict']
    assert s['missing_effect'] == 'range_walk', s['verdict'][:400]
    assert s['points'] == ds.points


def test_background_light_is_judged_over_the_receivers_gate(tmp_path: Path, monkeypatch):
    """Off-target returns are background light only if they spread from the start of
    the receiver's gate (the sensor's minimum range), not from the target's nearest
    return: ghosts bunched at the target's ranges (here crosstalk, not left out) are
    not uniform there, while arrivals over the gate are."""
    from scipy.stats import kstest

    from foreign_sim import battery, generate

    from lidar_sim_ros.compare import run
    from lidar_sim_ros.compare.diagnose import diagnosis

    rng = np.random.default_rng(4)
    ghosts = rng.uniform(10.0, 16.0, 200)              # at the target's ranges
    gate = (0.5, 150.0)
    assert kstest(diagnosis.off_target_positions(ghosts, gate), 'uniform').pvalue < 1e-6
    arrivals = 0.5 + rng.exponential(40.0, 400)        # a background over the gate
    arrivals = arrivals[arrivals < 150.0]
    assert kstest(diagnosis.off_target_positions(arrivals, gate), 'uniform').pvalue > 0.01
    # The comparison hands the diagnosis the gate, not the recording's range window.
    windows = []
    real = diagnosis.off_target_positions

    def spy(range_m, window_m):
        windows.append(tuple(window_m))
        return real(range_m, window_m)

    monkeypatch.setattr(diagnosis, 'off_target_positions', spy)
    spec = replace(battery(['crosstalk'])[0], frames=1, shots_per_frame=8000)
    ds = generate(spec, tmp_path / 'xt')
    run.run_compare(run.CompareOptions(bag=ds.bag, mesh=ds.mesh, out=tmp_path / 'out',
                                       config=ds.scenario, progress=False, report=False,
                                       plan=False, candidates=['solar_background']))
    assert windows and all(w[0] <= 0.5 for w in windows), windows


def test_a_null_verdict_says_the_ghosts_were_left_out():
    from lidar_sim_ros.compare.report import verdict

    said = verdict._nothing_named({'nll_calibrated': -2.0, 'crosstalk': {'points': 5}}, None, [])
    assert 'up to noise once the crosstalk ghosts below are left out' in said
    said = verdict._nothing_named({'nll_calibrated': -2.0, 'crosstalk': {'points': 0}}, None, [])
    assert said.endswith('up to noise.')


def test_returns_off_the_target_at_a_fixed_delay_are_no_crosstalk_alone():
    """Returns off the target (a silhouette under a pose error, a flat panel's edge)
    whose partners on the next tile lie a nearly fixed 0.4 m nearer: no shot returned
    twice, so nothing is shown; with ghosts among the second returns at that delay, the
    off-target ones at it are ghosts too."""
    r, exp, sig, t, cloud, laser, _ = _recording(0.0, 0.3)
    rng = np.random.default_rng(5)
    edge = np.flatnonzero(rng.random(len(r)) < 0.02)
    edge = edge[edge % 6000 > 0]                        # each with a shot before it
    exp = exp.copy()
    exp[edge] = np.nan                                  # the model misses these rays
    r = r.copy()
    r[edge] = r[edge - 1] + 0.4 + 0.01 * rng.standard_normal(len(edge))
    found, xt = crosstalk.crosstalk_ghosts(r, exp, sig, t, cloud, laser, True)
    assert xt.candidates == 0 and not found.any()
    r2, exp2, sig2, t2, cloud2, laser2, truth = _recording(0.05, 0.4, seed=6)
    found, xt = crosstalk.crosstalk_ghosts(*(np.concatenate(x) for x in (
        (r, r2), (exp, exp2), (sig, sig2), (t, t2 + 10.0), (cloud, cloud2 + 3),
        (laser, laser2))), True)
    n = len(r)
    # (an edge point whose shot before is an edge point too lies elsewhere)
    assert found[:n][edge].mean() > 0.95 and found[:n].sum() <= len(edge)
    assert np.sum(found[n:] & truth) >= 0.97 * truth.sum()
