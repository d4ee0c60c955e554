"""campaign/series.py: which runs keep their time series, against a sort of every run
(the independent reference), whatever the order results arrive in; bounded in runs."""
from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

from lidar_sim_ros.campaign.series import SERIES_DIR, SeriesKeeper, read_series, series_path
from lidar_sim_ros.campaign.spec import SeriesSpec


def row(run_id: int, value: float | None, status: str = 'ok') -> dict:
    t = np.arange(3) * 0.15
    return {'run_id': run_id, 'seed': 100 + run_id, 'status': status,
            'metrics': {'hold_error_m': value, 'losses': 0},
            'series': {'t_s': t, 'range_m': t + run_id, 'phase': ['approach'] * 3}}


def on_disk(out) -> list[int]:
    return sorted(int(p.stem[4:]) for p in (out / SERIES_DIR).glob('run_*.npz'))


def worst_by_sorting(values: dict[int, float | None], k: int, high: bool = True) -> list[int]:
    """Reference: every run sorted, worst first (no value worst of all, ties: larger id)."""
    def key(i):
        v = values[i]
        missing = v is None or not math.isfinite(v)
        return (missing, 0.0 if missing else (v if high else -v), i)
    return sorted(sorted(values, key=key, reverse=True)[:k])


@pytest.mark.parametrize('worst_is', ['high', 'low'])
def test_the_worst_k_whatever_the_order(tmp_path, worst_is):
    rng = np.random.default_rng(4)
    values = {i: float(v) for i, v in enumerate(rng.choice([0.1, 0.2, 0.3, 0.4], 40))}  # many ties
    values[7] = None                                                                     # never held
    spec = SeriesSpec(worst=5, by='hold_error_m', worst_is=worst_is, runs=[2])
    expected = sorted(set(worst_by_sorting(values, 5, worst_is == 'high')) | {2})
    for trial in range(3):
        out = tmp_path / str(trial)
        keeper = SeriesKeeper(out, spec)
        for i in rng.permutation(40):
            keeper.offer(row(int(i), values[int(i)]))
        assert keeper.kept == expected and on_disk(out) == expected
    assert 7 in expected  # the run without a value ranks worst


def test_a_file_holds_the_series_and_why(tmp_path):
    keeper = SeriesKeeper(tmp_path, SeriesSpec(worst=1, by='hold_error_m'))
    keeper.offer(row(3, 0.25))
    series, meta = read_series(series_path(tmp_path, 3))
    assert series['range_m'].tolist() == pytest.approx([3.0, 3.15, 3.3])
    assert series['phase'].tolist() == ['approach'] * 3
    assert meta == {'run_id': 3, 'seed': 103, 'asked': False, 'by': 'hold_error_m', 'worst_is': 'high',
                    'metrics': {'hold_error_m': 0.25, 'losses': 0}}


def test_failed_runs_and_rows_without_series_keep_nothing(tmp_path):
    keeper = SeriesKeeper(tmp_path, SeriesSpec(worst=3, by='hold_error_m', runs=[0]))
    failed = row(0, 9.0, status='failed')
    assert not keeper.offer(failed) and 'series' not in failed  # taken out of the row all the same
    assert not keeper.offer({'run_id': 1, 'status': 'ok'})
    assert keeper.kept == [] and on_disk(tmp_path) == []


def test_resume_and_rerun(tmp_path):
    """A second call ranks the kept files again; --run of a kept run replaces its rank; a run
    asked for by id (--run) stays, whatever its rank."""
    spec = SeriesSpec(worst=2, by='hold_error_m')
    first = SeriesKeeper(tmp_path, spec)
    for i, v in enumerate([0.5, 0.1, 0.4, 0.2]):
        first.offer(row(i, v))
    assert on_disk(tmp_path) == [0, 2]
    again = SeriesKeeper.open(tmp_path, spec)
    assert again.kept == [0, 2]
    again.offer(row(4, 0.45))                 # displaces run 2 (0.4)
    assert on_disk(tmp_path) == [0, 4]
    # Run 0 again, now the best: still among the 2 worst the keeper knows of (run 2 was
    # dropped, its rank forgotten: memory is K ranks), so kept, with its new series and rank.
    again.offer(row(0, 0.05))
    assert on_disk(tmp_path) == [0, 4]
    assert read_series(series_path(tmp_path, 0))[1]['metrics']['hold_error_m'] == 0.05
    again.offer(row(5, 0.3))                  # displaces run 0 now: its file goes
    assert on_disk(tmp_path) == [4, 5]
    again.offer(row(1, 0.1), asked=True)      # --run 1: kept though it is not among the worst
    assert 1 in on_disk(tmp_path)
    assert read_series(series_path(tmp_path, 1))[1]['asked'] is True
    third = SeriesKeeper.open(tmp_path, spec)
    for i in range(10, 20):
        third.offer(row(i, 1.0 + i))
    assert on_disk(tmp_path) == [1, 18, 19]  # run 1 asked: kept, outside the 2 worst


@pytest.mark.parametrize('damage', ['empty', 'no meta', 'meta not JSON', 'pickled meta',
                                    'run id a string', 'metrics a list'])
def test_resume_refuses_a_damaged_series_file_naming_it(tmp_path, damage):
    """Before: an EOFError or AttributeError traceback, or a line naming no file (KeyError
    'meta is not a file in the archive', a JSON message, int('1e9'))."""
    import json
    SeriesKeeper(tmp_path, SeriesSpec(worst=2, by='hold_error_m')).offer(row(0, 0.5))
    path = series_path(tmp_path, 3)
    meta = {'run_id': 3, 'metrics': {'hold_error_m': 1.0}, 'asked': False}
    with open(path, 'wb') as f:
        if damage == 'no meta':
            np.savez(f, t_s=np.zeros(3))
        elif damage == 'meta not JSON':
            np.savez(f, meta=np.array('{'))
        elif damage == 'pickled meta':
            np.savez(f, meta=np.array([meta], dtype=object))
        elif damage == 'run id a string':
            np.savez(f, meta=np.array(json.dumps({**meta, 'run_id': '1e9'})))
        elif damage == 'metrics a list':
            np.savez(f, meta=np.array(json.dumps({**meta, 'metrics': [1.0]})))
    with pytest.raises(ValueError, match=f'{path}: .*remove it to resume'):
        SeriesKeeper.open(tmp_path, SeriesSpec(worst=2, by='hold_error_m'))
    path.unlink()
    assert SeriesKeeper.open(tmp_path, SeriesSpec(worst=2, by='hold_error_m')).kept == [0]


def test_memory_and_files_stay_bounded_over_100000_runs(tmp_path):
    """100,000 runs through one keeper: K files, K ranks, and the Python heap of the keeper
    no larger than after 1,000 runs (tracemalloc)."""
    spec = SeriesSpec(worst=5, by='hold_error_m', runs=[17])
    rng = np.random.default_rng(1)
    values = rng.random(100_000)
    keeper = SeriesKeeper(tmp_path, spec)
    light = {'t_s': np.zeros(2)}
    tracemalloc.start()
    for i, v in enumerate(values):
        keeper.offer({'run_id': i, 'status': 'ok', 'metrics': {'hold_error_m': float(v)}, 'series': light})
        if i == 999:
            after_1000 = tracemalloc.get_traced_memory()[0]
    grown = tracemalloc.get_traced_memory()[0] - after_1000
    tracemalloc.stop()
    expected = sorted(set(np.argsort(values)[-5:].tolist()) | {17})
    assert keeper.kept == expected and on_disk(tmp_path) == expected
    assert len(keeper._worst) == 5 and grown < 50_000, grown
