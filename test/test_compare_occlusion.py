"""compare/model/occlusion.py: returns of an object between the sensor and the target.

On a hand-made scene (a target of two depth levels, a pillar in front of part of it, a
stray false return, ghosts behind, a depth-step strip): exactly the pillar's returns on
the target's rays are occlusion. Then on a foreign recording with a pillar
(test/foreign_sim.py, ``occluder``): the comparison leaves out about the share the
pillar hid, and the verdict says so.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lidar_sim_ros.compare.model import occlusion

TEST_DIR = Path(__file__).resolve().parent
sys.path.insert(0, str(TEST_DIR))

THRESHOLD_M = 0.5


def _scene(clouds: int = 2, n: int = 40):
    """Rays on an n x n grid (0.2 deg apart) per cloud; the target plane at 10 m with a
    near box at 9 m on columns 25..34 (its own depth span 9..10 m), rays past row 35 off
    the target. Returns directions, cloud, expected range (NaN off the target) and the
    measured range without anything in front."""
    a = np.radians(0.2) * (np.arange(n) - n / 2)
    az, el = np.meshgrid(a, a, indexing='ij')             # [column, row]
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    depth = np.full((n, n), 10.0)
    depth[25:35, :] = 9.0
    expected = depth / d[..., 0]
    expected[:, 35:] = np.nan                             # rows off the target
    measured = np.where(np.isfinite(expected), expected, 15.0)   # a wall behind
    rng = np.random.default_rng(0)
    out = []
    for c in range(clouds):
        noise = 0.01 * rng.standard_normal((n, n))
        out.append((d.reshape(-1, 3), np.full(n * n, c), expected.ravel().copy(),
                    (measured + noise).ravel()))
    return [np.concatenate(x) for x in zip(*out)], n


def test_a_pillar_in_front_is_occlusion_and_nothing_else():
    (d, cloud, expected, measured), n = _scene()
    idx = np.arange(len(d)).reshape(-1, n, n)             # [cloud, column, row]
    pillar = idx[:, 5:11, :].ravel()                      # six columns at 6 m, all rows
    measured[pillar] = 6.0 / d[pillar, 0] + 0.01 * np.random.default_rng(1).standard_normal(len(pillar))
    stray = idx[0, 20, 10]                                # one false return at 4 m
    measured[stray] = 4.0
    ghosts = idx[1, 15:18, 5:8].ravel()                   # a patch 2 m behind (multipath)
    measured[ghosts] += 2.0
    step = idx[:, 35, :20].ravel()                        # next to the box: at 9 m, not 10
    measured[step] = 9.0 / d[step, 0]                     # (a pose error, a mixed pixel)
    found = occlusion.occluded(measured, expected, np.full(len(d), THRESHOLD_M), d, cloud)
    want = np.zeros(len(d), bool)
    want[pillar] = np.isfinite(expected[pillar])          # off the target: unmatched, not occlusion
    assert want.sum() == 2 * 6 * 35
    np.testing.assert_array_equal(found, want)
    occ = occlusion.summarise(found, measured, expected, cloud, 2)
    assert occ.points == 2 * 6 * 35 and occ.clouds == 2
    assert occ.range_median_m == pytest.approx(6.0, abs=0.05)
    assert occ.shortfall_median_m == pytest.approx(4.0, abs=0.05)
    assert 'occluding object at about 6.0 m' in occlusion.words(occ)


def test_a_pillar_in_one_cloud_only():
    (d, cloud, expected, measured), n = _scene(clouds=3)
    idx = np.arange(len(d)).reshape(-1, n, n)
    patch = idx[2, 0:4, 0:4].ravel()
    measured[patch] = 3.0
    found = occlusion.occluded(measured, expected, np.full(len(d), THRESHOLD_M), d, cloud)
    assert set(np.flatnonzero(found)) == set(patch)


def test_scattered_false_returns_in_front_are_kept():
    """Solar background: 1 % of the points at random ranges short of the target are no
    surface (two side by side at the same range are rare): almost none is occlusion."""
    (d, cloud, expected, measured), n = _scene(clouds=4)
    rng = np.random.default_rng(3)
    false = np.flatnonzero(rng.random(len(d)) < 0.01)
    measured[false] = rng.uniform(0.5, 8.5, len(false))
    found = occlusion.occluded(measured, expected, np.full(len(d), THRESHOLD_M), d, cloud)
    assert found.sum() <= 0.02 * len(false)


def test_no_target_no_range_or_no_points():
    d = np.tile([[1.0, 0.0, 0.0]], (5, 1))
    nan = np.full(5, np.nan)
    assert not occlusion.occluded(np.full(5, 3.0), nan, np.full(5, 0.5), d, np.zeros(5)).any()
    assert not occlusion.occluded(nan, np.full(5, 10.0), np.full(5, 0.5), d, np.zeros(5)).any()
    assert not occlusion.occluded(np.full(5, 3.0), np.full(5, 10.0), nan, d, np.zeros(5)).any()
    empty = occlusion.occluded(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 3)),
                               np.zeros(0))
    assert empty.shape == (0,)
    occ = occlusion.summarise(np.zeros(5, bool), np.full(5, 3.0), nan, np.zeros(5), 1)
    assert occ.points == 0 and occlusion.words(occ) is None and occ.fraction == 0.0


def test_compare_leaves_the_pillar_out_of_a_foreign_recording(tmp_path: Path):
    """The foreign ``occluder`` recording (one small frame): the occluded share left out
    is the share the pillar hid (within 20 %), the shots count them, and the verdict
    and summary line say it."""
    from foreign_sim import battery, generate

    from lidar_sim_ros.compare import run
    from lidar_sim_ros.compare.report.verdict import verdict

    spec = replace(battery(['occluder'])[0], frames=1, shots_per_frame=8000)
    ds = generate(spec, tmp_path / 'occ')
    opts = run.CompareOptions(bag=ds.bag, mesh=ds.mesh, out=tmp_path / 'out',
                              config=ds.scenario, progress=False)
    inp = run.load_inputs(opts)
    before = len(inp.meas)
    left = run.leave_out_occluded(inp)
    occ = left.occlusion
    hidden = ds.truth['occluded_fraction']
    assert hidden > 0.1
    assert occ.fraction == pytest.approx(hidden, rel=0.2)
    assert len(left.meas) == before - occ.points
    assert left.meas.dropped['occluded'] == occ.points
    # points_analysed adds back what was left out, by the same kinds as were left out.
    assert run.left_out_points(left.meas) == before - len(left.meas)
    # What is left lies on the target or off it, never metres in front on its rays.
    m = run.match(run.geometry(left.model, left.scenario_effects), left.meas,
                  left.model.divergence_rad, edges=False)
    short = m.residual_m[m.matched] < -1.0
    assert short.mean() < 0.01
    summary = {'occlusion': occ.as_dict(), 'unmatched': {'points': 0}, 'materials': {},
               'points': before, 'points_analysed': len(left.meas)}
    text = verdict(summary, None, [], run.diagnosis.Decision(None, []))
    assert f'{occ.points} returns' in text and 'in front of the target' in text


def test_summary_line_counts_the_occluded_apart_from_max_points():
    """The headline says the occluded returns were left out, not that --max-points cut."""
    from lidar_sim_ros.compare.report.verdict import summary_lines

    s = dict(points=1000, points_analysed=1000, matched_points=700, unmatched_points=100,
             unmatched_fraction=0.125, range_rmse_m=0.02, nll_per_point=-2.0,
             range_rmse_calibrated_m=0.02, nll_calibrated=-2.0, fitted_effects=[],
             features=[], candidates=[], missing_effect=None, verdict='v',
             occlusion={'points': 200})
    lines = summary_lines(s, [])
    assert '--max-points' not in lines[0]
    assert any(line.startswith('occluded: 200 returns') for line in lines)


def test_a_film_with_the_target_behind_it_on_the_same_shots():
    """A film in front of part of the target on a dual-return receiver: each shot through
    it returns the film first and the target behind it, along one direction. The film's
    returns are occlusion (the other return of a shot shares its direction and is not a
    neighbouring ray: with it as the nearest neighbour every film return was isolated and
    nothing was occlusion), and the target's return behind each is the one kept for the
    shot (``seen_through``), the nearest on the target where a shot has two."""
    (d, cloud, expected, measured), n = _scene(clouds=1)
    film = np.zeros(n * n, bool)
    film.reshape(n, n)[:20, :20] = True                  # a corner of the plane at 10 m
    k = np.flatnonzero(film)
    rng = np.random.default_rng(1)
    film_r = 6.0 + 0.01 * rng.standard_normal(len(k))
    # Per point: the film's first returns, then every shot's target return (index 1 where
    # the film is in front, else the only return), then one shot with a third return.
    directions = np.concatenate([d[k], d, d[k[:1]]])
    ranges = np.concatenate([film_r, measured, measured[k[:1]] + 0.05])
    exp = np.concatenate([expected[k], expected, expected[k[:1]]])
    clouds = np.zeros(len(ranges), int)
    shot = np.concatenate([k, np.arange(n * n), k[:1]])
    later = np.concatenate([np.zeros(len(k), bool), film, [True]])
    threshold = np.full(len(ranges), THRESHOLD_M)
    occ = occlusion.occluded(ranges, exp, threshold, directions, clouds)
    assert np.array_equal(np.flatnonzero(occ), np.arange(len(k)))
    kept = occlusion.seen_through(ranges, exp, threshold, shot, occ, later)
    assert np.array_equal(np.flatnonzero(kept), len(k) + k)     # the nearer of the two
    # Without an occluded return on the shot, a later return is not taken for the target.
    assert not occlusion.seen_through(ranges, exp, threshold, shot, np.zeros_like(occ),
                                      later).any()


def test_compare_sees_the_target_through_a_film(tmp_path: Path):
    """The foreign ``veil`` recording (one frame; a film at 55 % of the distance, the
    target behind it as the shot's later return, a return field): the film's returns on
    the target's rays are occlusion, the target's returns behind them are kept (none is
    left out as a later return), nothing is named, and the ranges match the target (on
    main they were matched to it: a range RMSE of 2.8 m)."""
    from foreign_loop import one_frame_summary

    ds, s = one_frame_summary('veil', tmp_path)
    behind = ds.truth['second_returns']
    assert behind > 1000 and ds.truth['veil_returns'] > behind
    occ = s['occlusion']
    assert occ['points'] == pytest.approx(behind, rel=0.02)
    assert occ['target_seen_through'] == pytest.approx(behind, rel=0.02)
    assert s['multiple_returns']['points'] <= 0.02 * behind
    assert s['range_rmse_m'] < 0.1
    assert 'partly transparent' in s['verdict']
    assert s['missing_effect'] is None and s['reference_pose'].get('reported_as') is None


def test_a_film_near_the_target_is_told_on_its_own_rays():
    """A film 0.4 m in front of the plane at 10 m, in a cloud whose nearest modelled
    surface is the box at 9 m: ``occluded`` (the cloud's nearest surface less the far
    threshold) leaves it in as the target, as main read the film39 recordings (their
    material biases of -40 cm). ``veiled`` takes each such first return whose shot's
    later return lies on the model, in front of the nearest modelled surface of its own
    and its neighbouring rays. A depth step (the box's edge first, the plane behind on
    the next ray) and a first return on the target with a later echo 1 m behind
    (multipath) stay the target's."""
    (d, cloud, expected, measured), n = _scene(clouds=1)
    film = np.zeros((n, n), bool)
    film[:20, :20] = True
    k = np.flatnonzero(film.ravel())
    step = np.flatnonzero(np.isin(np.arange(n * n) // n, [24]) & np.isfinite(expected))
    echo = np.flatnonzero(np.isin(np.arange(n * n) // n, [5]) & np.isfinite(expected))[:10]
    rng = np.random.default_rng(2)
    film_r = 9.6 + 0.01 * rng.standard_normal(len(k))
    step_r = 9.0 / d[step, 0] + 0.01 * rng.standard_normal(len(step))  # the box's edge
    # Per point: the film's first returns, the depth step's first returns (the box),
    # every shot's target return (later where the film or the step is in front), and a
    # multipath echo 1 m behind a few shots off the film.
    directions = np.concatenate([d[k], d[step], d, d[echo]])
    ranges = np.concatenate([film_r, step_r, measured, measured[echo] + 1.0])
    exp = np.concatenate([expected[k], expected[step], expected, expected[echo]])
    clouds = np.zeros(len(ranges), int)
    shot = np.concatenate([k, step, np.arange(n * n), echo])
    in_front = np.zeros(n * n, bool)
    in_front[k] = in_front[step] = True
    later = np.concatenate([np.zeros(len(k) + len(step), bool), in_front,
                            np.ones(len(echo), bool)])
    tight = np.full(len(ranges), 0.1)                     # 10 sigma of the 1 cm noise
    assert not occlusion.occluded(ranges, exp, np.full(len(ranges), THRESHOLD_M),
                                  directions, clouds)[:len(k)].any()
    film_mask = occlusion.veiled(ranges, exp, tight, shot, later, directions, clouds)
    assert np.array_equal(np.flatnonzero(film_mask), np.arange(len(k)))
    kept = occlusion.seen_through(ranges, exp, tight, shot, film_mask, later)
    assert np.array_equal(np.flatnonzero(kept), len(k) + len(step) + k)
    # Without a later return on the model, nothing is a film.
    assert not occlusion.veiled(ranges, exp, tight, shot, np.zeros_like(later), directions,
                                clouds).any()
