"""campaign/criteria.py and the spec's ``criteria`` / ``series``: parsing by hand, the
errors naming file, key and value, and the verdict counts against a hand count."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from conftest import CONFIG
from lidar_sim_ros.campaign.criteria import Criterion, parse_criterion
from lidar_sim_ros.campaign.spec import LOOP_METRIC_NAMES, load_campaign
from lidar_sim_ros.core.config import ConfigError

NAMES = ('hold_error_m', 'min_range_m', 'losses')


@pytest.mark.parametrize('text, expected', [
    ('hold_error_m < 0.3', Criterion('hold_error_m', '<', 0.3)),
    ('hold_error_m<0.3', Criterion('hold_error_m', '<', 0.3)),
    ('  min_range_m >= -2.5e1 ', Criterion('min_range_m', '>=', -25.0)),
    ('losses == 0', Criterion('losses', '==', 0.0)),
    ('losses != 1', Criterion('losses', '!=', 1.0)),
    ('min_range_m > .5', Criterion('min_range_m', '>', 0.5)),
])
def test_criteria_parse(text, expected):
    assert parse_criterion(text, NAMES) == expected


@pytest.mark.parametrize('text, words', [
    ('hold_err < 0.3', "unknown metric 'hold_err'"),
    ('hold_error_m =< 0.3', "unknown operator '=<'"),
    ('hold_error_m <> 0.3', "unknown operator '<>'"),
    ('hold_error_m ~ 0.3', 'not a criterion'),
    ('hold_error_m < nan', "threshold 'nan' is not a decimal number"),
    ('hold_error_m < inf', "threshold 'inf' is not a decimal number"),
    ('hold_error_m < 1e400', "threshold '1e400' is not finite"),
    ('hold_error_m < \u0661', 'not a decimal number'),          # float() would read it as 1
    ('hold_error_m < 0.3 m', 'not a criterion'),
    ('hold_error_m < 0x10', 'not a decimal number'),
    ('< 0.3', 'not a criterion'),
    ('', 'not a criterion'),
])
def test_bad_criteria_say_why(text, words):
    with pytest.raises(ValueError) as info:
        parse_criterion(text, NAMES)
    assert words in str(info.value)


def test_a_run_passes_on_a_finite_value_only():
    values = [0.1, 0.3, 0.5, math.nan, math.inf, -math.inf]
    # By hand: < 0.3 holds for 0.1 and -inf, but -inf is no value; NaN passes nothing,
    # not even != (where numpy says True).
    assert Criterion('x', '<', 0.3).passes(values).tolist() == [True, False, False, False, False, False]
    assert Criterion('x', '<=', 0.3).passes(values).tolist() == [True, True, False, False, False, False]
    assert Criterion('x', '!=', 0.3).passes(values).tolist() == [True, False, True, False, False, False]
    assert Criterion('x', '>', 0.3).passes(values).tolist() == [False, False, True, False, False, False]


def write_loop_spec(tmp_path, **fields):
    spec = {'scenario': str(CONFIG / 'scenario.yaml'), 'seed': 1, 'runs': 10, 'duration_s': 0.3,
            'loop': {'config': str(CONFIG / 'loop.yaml'), 'cloud': 'truth'}, **fields}
    path = tmp_path / 'c.yaml'
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize('fields, key, value, words', [
    ({'criteria': ['hold_error_m < 0.3', 'speed < 1']}, 'criteria.1', 'speed < 1', "unknown metric 'speed'"),
    ({'criteria': ['hold_error_m => 0.3']}, 'criteria.0', 'hold_error_m => 0.3', "unknown operator '=>'"),
    ({'criteria': ['delta_v_mps < 1e999']}, 'criteria.0', 'delta_v_mps < 1e999', 'is not finite'),
    ({'criteria': ['delta_v_mps < NaN']}, 'criteria.0', 'delta_v_mps < NaN', 'not a decimal number'),
    ({'criteria': [0.3]}, 'criteria.0', 0.3, 'valid string'),
    ({'criteria': 'hold_error_m < 0.3'}, 'criteria', 'hold_error_m < 0.3', 'valid list'),
    ({'criteria': ['losses == 0'] * 101}, 'criteria', None, 'at most 100'),
    ({'series': {'worst': 3}}, 'series.by', '', 'ranks runs by a metric'),
    ({'series': {'worst': 3, 'by': 'speed'}}, 'series.by', 'speed', 'ranks runs by a metric'),
    ({'series': {'worst': 1001, 'by': 'losses'}}, 'series.worst', 1001, 'less than or equal to 1000'),
    ({'series': {'worst': -1, 'by': 'losses'}}, 'series.worst', -1, 'greater than or equal to 0'),
    ({'series': {'runs': [3, 10]}}, 'series.runs.1', 10, 'runs 0..9'),
    ({'series': {'runs': [-1]}}, 'series.runs.0', -1, 'greater than or equal to 0'),
    ({'series': {'worst': 2, 'by': 'losses', 'worst_is': 'big'}}, 'series.worst_is', 'big', "'high' or 'low'"),
])
def test_bad_criteria_and_series_name_file_key_value(tmp_path, fields, key, value, words):
    path = write_loop_spec(tmp_path, **fields)
    with pytest.raises(ConfigError) as info:
        load_campaign(path)
    err = info.value
    assert err.key == key and words in str(err) and str(path) in str(err), str(err)
    if value is not None:
        assert err.value == value


def write_frame_spec(tmp_path, **fields):
    path = tmp_path / 'f.yaml'
    path.write_text(yaml.safe_dump({'scenario': str(CONFIG / 'scenario.yaml'), 'seed': 1, 'runs': 6,
                                    'duration_s': 0.1, **fields}))
    return path


@pytest.mark.parametrize('fields, key, words', [
    ({'criteria': ['hold_error_m < 0.3']}, 'criteria.0', "unknown metric 'hold_error_m'"),
    ({'criteria': ['range_error_std_m.FOO < 0.03']}, 'criteria.0', "unknown metric 'range_error_std_m.FOO'"),
    ({'series': {'worst': 2, 'by': 'points'}}, 'series', 'closed-loop campaigns'),
])
def test_frame_campaigns_check_their_criteria_against_the_statistics(tmp_path, fields, key, words):
    with pytest.raises(ConfigError) as info:
        load_campaign(write_frame_spec(tmp_path, **fields))
    assert info.value.key == key and words in str(info.value)


def test_frame_verdicts_from_the_manifest_by_hand(tmp_path):
    """A frame campaign's criteria over manifest.csv's stat.* columns, written by hand."""
    from lidar_sim_ros.campaign.manifest import Manifest
    from lidar_sim_ros.campaign.summary import FRAME_VS_FIGURE, summarize_frames
    campaign = load_campaign(write_frame_spec(tmp_path, criteria=[
        'range_error_std_m.PIF < 0.03', 'coverage >= 0.5'], dispersions={
        'initial_distance_m': {'dist': 'uniform', 'low': 8.0, 'high': 25.0}}))
    manifest = Manifest(tmp_path, ['run_id', 'seed', 'status', 'error', 'param.initial_distance_m',
                                   'stat.points', 'stat.coverage', 'stat.range_error_mean_m',
                                   'stat.range_error_std_m', 'stat.range_error_std_m.PIF'])
    runs = [  # (status, distance, PIF std, coverage)
        ('ok', 9.0, 0.02, 0.6), ('ok', 12.0, 0.04, 0.7), ('ok', 20.0, None, 0.55),
        ('ok', 24.0, 0.01, 0.4), ('failed', None, None, None), ('ok', 10.0, 0.025, 0.5)]
    manifest.append_rows([{'run_id': i, 'seed': i, 'status': st, 'param.initial_distance_m': d,
                           'stat.points': 100, 'stat.coverage': c, 'stat.range_error_mean_m': -0.1,
                           'stat.range_error_std_m': 0.03, 'stat.range_error_std_m.PIF': sd}
                          for i, (st, d, sd, c) in enumerate(runs)])
    summary = summarize_frames(tmp_path, campaign)
    # By hand: std < 0.03 in runs 0, 3, 5; coverage >= 0.5 in 0, 1, 2, 5; both in 0 and 5;
    # 6 runs, the failed one (4) passing nothing; run 2 has no PIF std (missing).
    assert [(r['criterion'], r['passed'], r['runs'], r['missing']) for r in summary.verdicts] == [
        ('range_error_std_m.PIF < 0.03', 3, 6, 1), ('coverage >= 0.5', 4, 6, 0), ('all criteria', 2, 6, '')]
    assert (summary.runs, summary.failed) == (5, 1)
    assert summary.figure == tmp_path / FRAME_VS_FIGURE and summary.figure.stat().st_size > 5_000


def test_criteria_and_series_leave_the_fingerprint_alone(tmp_path):
    """What is made of the results does not change them: a finished campaign can be judged
    again with other criteria, and keep other series, without re-running it."""
    from lidar_sim_ros.campaign.manifest import fingerprint
    plain = load_campaign(write_loop_spec(tmp_path))
    judged = load_campaign(write_loop_spec(tmp_path, criteria=['hold_error_m < 0.3'],
                                           series={'worst': 2, 'by': 'hold_error_m', 'runs': [1]}))
    assert fingerprint(plain) == fingerprint(judged)
    assert 'criteria' not in plain.spec.model_dump() and 'series' not in plain.spec.model_dump()
    assert set(judged.spec.criteria) == {'hold_error_m < 0.3'}


def test_verdicts_by_hand():
    from lidar_sim_ros.campaign.summary import ALL, _Columns, verdict_rows
    metrics = _Columns.of(['hold_error_m', 'losses'])
    for hold, losses in ((0.1, 0), (0.5, 0), (None, 0), (0.2, 2)):
        metrics.add({'hold_error_m': hold, 'losses': losses})
    criteria = [parse_criterion('hold_error_m < 0.3', LOOP_METRIC_NAMES),
                parse_criterion('losses == 0', LOOP_METRIC_NAMES)]
    # 4 ok runs and 2 failed ones: 6 runs. hold < 0.3: runs 0 and 3; losses == 0: 0, 1, 2; both: 0.
    rows, every = verdict_rows(criteria, metrics, 4, 6)
    assert every.tolist() == [True, False, False, False]
    assert [(r['criterion'], r['passed'], r['failed'], r['missing']) for r in rows] == [
        ('hold_error_m < 0.3', 2, 4, 1), ('losses == 0', 3, 3, 0), (ALL, 1, 5, '')]
    assert [r['pass_rate'] for r in rows] == pytest.approx([2 / 6, 3 / 6, 1 / 6])
    assert np.isnan(metrics['hold_error_m'][2])
