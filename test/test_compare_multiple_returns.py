"""compare/model/multiple_returns.py and the return-index field: a shot's later returns.

A multi-return receiver's later returns (a depth step in the footprint) are counted and
left out of the fit, told by a return-index field (0- or 1-based) or, without one, by
the shot they share (cloud, laser, time, direction); they are not crosstalk. Crosstalk
ghosts (also later returns of the shot they leak into) are still found at their fixed
delay; delays that only fill the window are not a fixed delay. A return index that
cannot be one is refused naming the field and the value.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lidar_sim_ros.compare.model import crosstalk, multiple_returns as mret
from lidar_sim_ros.compare.recording.fields import (MAX_RETURN_INDEX, FieldError,
                                                    resolve_fields, return_indices)
from lidar_sim_ros.compare.recording.measurements import (MeasurementError, find_time_field,
                                                          load_measurements)
from lidar_sim_ros.io.bag import BagWriter

TEST_DIR = Path(__file__).resolve().parent
sys.path.insert(0, str(TEST_DIR))

PERIOD_S = 5e-6
SIGMA_M = 0.02


def _shots(clouds=2, shots=4000, lasers=4, seed=0):
    """Shots round-robin over ``lasers`` sweeping azimuth, a surface 8..14 m away (the
    model's range exactly that), measured with SIGMA_M noise. Per shot: range, expected,
    t since the cloud stamp, cloud, laser, direction."""
    rng = np.random.default_rng(seed)
    cols = []
    for c in range(clouds):
        k = np.arange(shots)
        az = np.radians(-20 + 40 * k / shots) + 0.01 * (k % lasers)
        d = np.column_stack([np.cos(az), np.sin(az), 0.01 * (k % lasers)])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        true = 11.0 + 3.0 * np.sin(k / 300.0 + c)
        cols.append((true + SIGMA_M * rng.standard_normal(shots), true, k * PERIOD_S,
                     np.full(shots, c), k % lasers, d))
    return [np.concatenate(x) for x in zip(*cols)]


def _with_second(share, behind, seed=1, base=0):
    """The shots plus a second return on a ``share`` of them at ``behind(n)`` m farther
    (same time, laser, direction); returns the arrays (second returns appended), the
    return index (``base`` first) and the truth mask."""
    r, exp, t, cloud, laser, d = _shots(seed=seed)
    rng = np.random.default_rng(seed + 10)
    g = np.flatnonzero(rng.random(len(r)) < share)
    r2 = r[g] + behind(len(g), rng)
    cat = lambda a, b: np.concatenate([a, b])         # noqa: E731
    idx = cat(np.full(len(r), base), np.full(len(g), base + 1))
    truth = cat(np.zeros(len(r), bool), np.ones(len(g), bool))
    return (cat(r, r2), cat(exp, np.full(len(g), np.nan)), cat(t, t[g]), cat(cloud, cloud[g]),
            cat(laser, laser[g]), np.vstack([d, d[g]]), idx, truth, r2 - r[g])


@pytest.mark.parametrize('base', [0, 1])
def test_a_return_field_tells_the_later_returns(base):
    r, exp, t, cloud, laser, d, idx, truth, behind = _with_second(
        0.05, lambda n, rng: rng.uniform(0.4, 2.5, n), base=base)
    later, mr = mret.later_returns(r, t, cloud, laser, d, idx, True, 0.0, "the field 'return'")
    assert np.array_equal(later, truth)
    assert mr.points == truth.sum() and mr.with_first == truth.sum()
    # The range behind the first return, as made (uniform 0.4..2.5 m).
    assert mr.behind_first_m == pytest.approx(np.percentile(behind, [5, 50, 95]), abs=1e-3)
    assert 0.4 < mr.behind_first_m[0] < mr.behind_first_m[2] < 2.5
    assert mr.lasers == 4 and mr.clouds == 2
    said = mret.words(mr)
    assert 'later returns of the same shot' in said and 'not crosstalk' in said
    # Without point times the field alone tells them; no range behind is known.
    later, mr = mret.later_returns(r, t, cloud, laser, d, idx, False, 0.0, 'f')
    assert np.array_equal(later, truth) and mr.behind_first_m is None


def test_shared_shot_times_tell_the_later_returns_without_a_field():
    r, exp, t, cloud, laser, d, _, truth, _ = _with_second(
        0.05, lambda n, rng: rng.uniform(0.4, 2.5, n))
    later, mr = mret.later_returns(r, t, cloud, laser, d, None, True, 7.5e-9, None)
    assert np.array_equal(later, truth) and 'shared shot time' in mr.source
    # The nearer of two returns is the first, whichever the recording lists first.
    order = np.random.default_rng(3).permutation(len(r))
    later, _ = mret.later_returns(r[order], t[order], cloud[order], laser[order], d[order],
                                  None, True, 7.5e-9, None)
    assert np.array_equal(later, truth[order])
    # A flash array: every pixel of a row shares the time and the laser id, each its own
    # direction: no shot returns twice.
    n = 500
    az = np.linspace(-0.2, 0.2, n)
    flash = np.column_stack([np.cos(az), np.sin(az), np.zeros(n)])
    later, mr = mret.later_returns(np.full(n, 10.0), np.zeros(n), np.zeros(n, int),
                                   np.zeros(n, int), flash, None, True, 0.0, None)
    assert not later.any() and mr.points == 0 and mret.words(mr) is None
    # Without times or a field nothing can be told.
    later, mr = mret.later_returns(r, t, cloud, laser, d, None, False, 0.0, None)
    assert not later.any() and not mr.looked and 'cannot be told' in mr.why_not


def test_later_returns_filling_the_delay_window_are_no_crosstalk():
    """Second returns a nearly fixed 1.7 m behind the shot before's return, but spread
    evenly over the crosstalk window (the scene's geometry, as a dual-return receiver's
    depth steps gave holdout 10): the peak stands above its sidebands, yet its delays
    are not fixed; the same returns 1 cm about the delay are crosstalk."""
    r, exp, t, cloud, laser, d = _shots()
    rng = np.random.default_rng(4)
    h = crosstalk.HALF_WIDTH_SIGMAS * np.sqrt(2.0) * SIGMA_M
    g = np.flatnonzero(rng.random(len(r) - 1) < 0.05) + 1
    g = g[cloud[g] == cloud[g - 1]]

    def found(spread):
        r2 = r[g - 1] + 1.7 + spread
        cat = lambda a, b: np.concatenate([a, b])     # noqa: E731
        return crosstalk.crosstalk_ghosts(cat(r, r2), cat(exp, np.full(len(g), np.nan)),
                                          np.full(len(r) + len(g), SIGMA_M),
                                          cat(t + 10 * cloud, t[g] + 10 * cloud[g]),
                                          cat(cloud, cloud[g]), cat(laser, laser[g]), True)

    mask, xt = found(rng.uniform(-h, h, len(g)))
    assert xt.z > xt.z_crit and xt.spread_m > crosstalk.FIXED_SPREAD * xt.half_width_m
    assert not mask.any() and xt.points == 0
    mask, xt = found(0.01 * rng.standard_normal(len(g)))
    assert xt.points >= 0.95 * len(g) and xt.offset_m == pytest.approx(1.7, abs=0.01)


def test_crosstalk_ghosts_are_counted_as_crosstalk_not_as_later_returns():
    """Ghosts leaked into the next shot share its time, laser and direction: later
    returns of that shot, but crosstalk finds them first; left out there, they are not
    counted again, and the echo of a shot whose ghost lies nearer stays its first."""
    r, exp, t, cloud, laser, d = _shots(seed=5)
    rng = np.random.default_rng(6)
    g = np.flatnonzero(rng.random(len(r) - 1) < 0.05) + 1
    g = g[cloud[g] == cloud[g - 1]]
    r2 = r[g - 1] + 0.3 + 0.01 * rng.standard_normal(len(g))
    cat = lambda a, b: np.concatenate([a, b])         # noqa: E731
    R, T, C, L = cat(r, r2), cat(t, t[g]), cat(cloud, cloud[g]), cat(laser, laser[g])
    D = np.vstack([d, d[g]])
    ghost, xt = crosstalk.crosstalk_ghosts(R, cat(exp, np.full(len(g), np.nan)),
                                           np.full(len(R), SIGMA_M), T + 10 * C, C, L, True)
    assert ghost[len(r):].mean() > 0.97 and not ghost[:len(r)].any()
    later, mr = mret.later_returns(R, T, C, L, D, None, True, 0.0, None, exclude=ghost)
    assert not later[:len(r)].any()                      # no echo left out as later
    assert mr.points == int(later.sum()) <= 0.03 * len(g)
    assert mr.crosstalk == int(ghost.sum())


@pytest.mark.parametrize('value, dtype', [(-1, '<i2'), (2.5, '<f4'), (np.nan, '<f4'),
                                          (np.inf, '<f4'), (1e300, '<f8'),
                                          (MAX_RETURN_INDEX + 1, 'u1'), (60000, '<u2')])
def test_a_return_index_that_cannot_be_one_is_refused(tmp_path, value, dtype):
    v = np.zeros(10, dtype)
    v[3] = value
    with pytest.raises(FieldError, match=r"return field 'return' = "):
        return_indices(v, 'return')
    with pytest.raises(MeasurementError, match=r"cloud #0: return field 'echo' = "):
        load_measurements(_bag(tmp_path / 'b', 'echo', dtype, bad=value))


def test_return_fields_are_recognised_and_return_type_is_not_an_index(tmp_path):
    for name in ('return', 'return_id', 'return_idx', 'return_index', 'return_number',
                 'Echo'):
        dt = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), (name, 'u1')])
        fm = resolve_fields(dt, find_time=find_time_field)
        assert fm.returns == name and name not in fm.ignored
    dt = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('return_type', 'u1')])
    fm = resolve_fields(dt, find_time=find_time_field)
    assert fm.returns is None and 'not a return index' in fm.ignored['return_type']
    meas = load_measurements(_bag(tmp_path / 'ok', 'return_id', 'u1'))
    assert meas.return_index is not None and set(meas.return_index) == {1, 2}
    assert any('return index of a multi-return' in line for line in meas.field_lines)
    assert meas.time_quantum_s == pytest.approx(np.spacing(np.float32(0.09)), rel=0.01)


def _bag(path, name, dtype, bad=None):
    """One cloud of 200 points with a float32 ``t`` and a return field ``name`` (1 first,
    2 on every tenth point), ``bad`` written into point 3; poses around it."""
    t0 = 1_700_000_000_000_000_000
    rec = np.zeros(200, [('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('t', '<f4'),
                         ('ring', '<u2'), (name, dtype)])
    rec['x'] = np.linspace(9, 11, 200)
    rec['y'] = np.linspace(-1, 1, 200)
    rec['t'] = np.linspace(0, 0.09, 200)
    rec['ring'] = np.arange(200) % 4
    rec[name] = 1 + (np.arange(200) % 10 == 0)
    if bad is not None:
        rec[name][3] = bad
    with BagWriter(path) as bag:
        for k in range(-1, 4):
            bag.write_pose('/target/pose', t0 + k * 50_000_000, 'lidar', [10.0, 0, 0],
                           [0, 0, 0, 1])
        bag.write_cloud('/lidar/points', rec, t0, 'lidar')
    return path


@pytest.mark.parametrize('name', ['dual_return', 'dual_return_nofield'])
def test_compare_leaves_a_dual_return_receivers_later_returns_out(tmp_path: Path, name):
    """The foreign dual-return recordings (1 frame): every second return made is counted
    in ``multiple_returns`` and left out, none is called crosstalk, nothing is named."""
    from foreign_loop import one_frame_summary

    ds, s = one_frame_summary(name, tmp_path)
    made = ds.truth['second_returns']
    assert made > 30
    mr = s['multiple_returns']
    assert mr['points'] == pytest.approx(made, rel=0.02)
    assert mr['at_model_multipath_ghost'] <= mr['points']
    assert s['crosstalk']['points'] == 0
    assert 'later returns of the same shot' in s['verdict'] and 'crosstalk' not in \
        s['verdict'].replace('not crosstalk', '')
    assert s['missing_effect'] is None and s['points'] == ds.points


def test_later_returns_at_the_models_multipath_ghost_are_counted():
    """A later return within the z bound of the ghost the model casts on its ray is
    counted (and said: multipath and a depth step past a grazing edge give one range);
    one off it, or on a ray without a ghost, is not."""
    r = np.array([10.0, 10.62, 10.0, 11.5, 10.0, 10.6])
    ghost_index = np.array([1, 3])                   # rays with a model ghost
    ghost_range = np.array([10.60, 10.60])
    ghost_sigma = np.array([0.02, 0.02])
    at = mret.at_ghost_range(r, ghost_index, ghost_range, ghost_sigma, 5.0)
    assert at.tolist() == [False, True, False, False, False, False]
    assert not mret.at_ghost_range(r, np.zeros(0, int), np.zeros(0), np.zeros(0), 5.0).any()
    mr = mret.MultipleReturns(2, 6, 1, 1, source='f', shots=2, lasers=1, at_model_ghost=1)
    said = mret.words(mr)
    assert 'left out of the fit' in said and '1 of them lie where the catalogue' in said
    assert mret.words(replace(mr, points=0)) is None
