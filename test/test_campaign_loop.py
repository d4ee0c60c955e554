"""campaign/loop_case.py: closed-loop campaign runs (dispersions into the loop, the run, the summary).

Cheap by design: the runs are 0.3 s of loop on the plain scenario with the truth cloud,
through the engine's seam (``run.run_one``) in this process; resuming is checked with
every run finished, so no cluster starts.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import CONFIG
from lidar_sim_ros.campaign.spec import load_campaign
from lidar_sim_ros.core.config import ConfigError

pytest.importorskip('Basilisk')

LOOP = str(CONFIG / 'loop.yaml')


def write_loop_campaign(path: Path, loop_file: str = LOOP, **overrides) -> Path:
    spec = {'scenario': str(CONFIG / 'scenario.yaml'), 'seed': 5, 'runs': 2, 'duration_s': 0.3,
            'loop': {'config': loop_file, 'cloud': 'truth'},
            'dispersions': {
                'tumble_rate_dps': {'dist': 'uniform', 'low': 1.0, 'high': 5.0},
                'tumble_axis': {'dist': 'cone', 'half_angle_deg': 30.0},
                'initial_attitude': {'dist': 'small_rotation', 'sigma_deg': 10.0},
                'initial_distance_m': {'dist': 'uniform', 'low': 20.0, 'high': 25.0},
                'mounting_misalignment': {'dist': 'small_rotation', 'sigma_deg': 0.2},
                'materials': {'PIF': {'bias_m': {'dist': 'uniform', 'low': -0.15, 'high': -0.13}}}}}
    spec.update(overrides)
    path.write_text(yaml.safe_dump(spec))
    return path


def test_dispersions_reach_the_loop_config(tmp_path):
    from lidar_sim_ros.campaign.loop_case import sample_loop_case
    from lidar_sim_ros.campaign.sample import run_seed
    from lidar_sim_ros.loop.dynamics import Dynamics
    campaign = load_campaign(write_loop_campaign(tmp_path / 'c.yaml'))
    case = sample_loop_case(campaign, 1)
    again = sample_loop_case(campaign, 1)
    assert case.params == again.params and case.loop == again.loop      # pure in (seed, run)
    p, cfg = case.params, case.loop
    assert cfg.seed == case.seed == run_seed(5, 1)
    assert cfg.target.tumble_rate_dps == p['tumble_rate_dps'] and 1.0 <= p['tumble_rate_dps'] <= 5.0
    assert cfg.target.tumble_axis_body == pytest.approx([p[f'tumble_axis_{a}'] for a in 'xyz'])
    # The cone is about loop.yaml's tumble axis (not the scenario's): within 30 deg of it.
    nominal = np.array([1.0, 0.2, 0.3]) / np.linalg.norm([1.0, 0.2, 0.3])
    assert math.degrees(math.acos(nominal @ np.array(cfg.target.tumble_axis_body))) <= 30.0
    assert cfg.target.quat_xyzw_lvlh == pytest.approx([p[f'initial_quat_{a}'] for a in 'xyzw'])
    assert cfg.initial.position_m == pytest.approx([0.0, -p['initial_distance_m'], 0.0])
    # The start the manifest records is the one Basilisk starts from (loop.yaml's sigmas, run seed).
    rho, rho_dot = Dynamics(cfg).state().relative_lvlh()
    assert rho == pytest.approx([p[f'initial_rho_m_{a}'] for a in 'xyz'], abs=1e-6)
    assert rho_dot == pytest.approx([p[f'initial_rho_dot_mps_{a}'] for a in 'xyz'], abs=1e-9)
    assert case.scenario.materials.materials[0].bias_m == p['material.PIF.bias_m']
    assert case.misalignment_xyzw == pytest.approx([p[f'misalignment_quat_{a}'] for a in 'xyzw'])


@pytest.mark.parametrize('change, key, words', [
    ({'dispersions': {'approach_speed_mps': {'dist': 'uniform', 'low': 0.0, 'high': 0.1}}},
     'dispersions.approach_speed_mps', 'not used by a closed-loop'),
    ({'duration_s': 0.25}, 'duration_s', 'whole number of control periods'),
    ({'save': 'bags'}, 'save', 'not bags'),
    ({'loop': {'config': 'nowhere.yaml'}}, 'loop.config', 'file not found'),
    ({'loop': {'config': LOOP, 'config_sha256': 'abc'}}, 'loop.config_sha256', 'leave it out'),
])
def test_bad_loop_spec_names_key(tmp_path, change, key, words):
    with pytest.raises(ConfigError) as info:
        load_campaign(write_loop_campaign(tmp_path / 'c.yaml', **change))
    assert info.value.key == key and words in str(info.value)


def test_misaligned_mount_is_unknown_to_the_navigation():
    """The truth sees the lidar where it is; the GNC turns the estimate into LVLH with the
    mount it believes: the relative position it gets is off by |t_L| x angle."""
    from lidar_sim_ros.loop.config import load_loop_config
    from lidar_sim_ros.loop.step import build_context, run_steps
    config = load_loop_config(LOOP)[0]
    gaps = {}
    for angle_deg in (0.0, 1.0):
        m = [0.0, 0.0, math.sin(math.radians(angle_deg) / 2), math.cos(math.radians(angle_deg) / 2)]
        ctx = build_context(config, None, None, misalignment_xyzw=m)
        series = run_steps(ctx, 0.3).series
        gaps[angle_deg] = (series['rho_est_m'] - series['rho_true_m'], series['range_m'])
    gap0, _ = gaps[0.0]
    assert np.abs(gap0).max() < 2e-3  # estimate (mid-period) and truth (period end): ~0.1 mm apart
    gap1, range_m = gaps[1.0]
    # Hand: pointing puts the target on the real lidar's +x = LVLH +y (V-bar, behind the
    # target), its z radial (LVLH +x), so its y = LVLH +z. M = 1 deg about z: in the frame
    # the GNC believes, the target sits at M^T (r, 0, 0) = (r cos, -r sin, 0); taking it at
    # (r, 0, 0) puts the target r sin(1 deg) too far along +y (LVLH +z), so the chaser
    # (rho = chaser - target) r sin(1 deg) too far along LVLH -z: 0.52 m at 30 m.
    assert gap1[:, 2] == pytest.approx(-range_m * math.sin(math.radians(1.0)), abs=5e-3)
    assert np.abs(gap1[:, :2]).max() < 0.02  # second order: r (1 - cos 1 deg) = 5 mm


def test_percentile_row_by_hand():
    from lidar_sim_ros.campaign.summary import metric_row
    row = metric_row('x', [3.0, None, 1.0, float('nan'), 2.0])
    assert (row['runs'], row['missing']) == (3, 2)
    # numpy's default (linear) percentile of 1, 2, 3: p5 = 1 + 0.05 * 2, p95 = 1 + 0.95 * 2.
    assert (row['min'], row['p5'], row['p50'], row['p95'], row['max'], row['mean']) == \
        pytest.approx((1.0, 1.1, 2.0, 2.9, 3.0, 2.0))
    assert metric_row('y', [None])['p50'] is None


def test_runs_write_metrics_series_verdicts_summary_and_resume(tmp_path, capsys):
    """Three closed-loop runs through the engine (a local scheduler with one in-process
    worker thread), then the command's summary: the series kept are the worst by the
    spec's metric plus the run asked for, as sorting every run's loop.json says; the pass
    counts are a hand count over the loop.json files; --run reproduces a run and keeps its
    series; a resume runs nothing; a changed loop file is refused."""
    import dask
    from dask.distributed import LocalCluster

    from lidar_sim_ros.campaign.command import _loop_summary
    from lidar_sim_ros.campaign.engine import run_campaign
    from lidar_sim_ros.campaign.loop_case import LOOP_METRICS, read_result
    from lidar_sim_ros.campaign.series import read_series, series_path
    from lidar_sim_ros.campaign.spec import LOOP_METRIC_NAMES
    from lidar_sim_ros.campaign.summary import CRITERIA_TABLE, SERIES_FIGURE, VS_FIGURE
    from lidar_sim_ros.cli import main as cli_main
    loop = tmp_path / 'loop.yaml'
    loop.write_text(Path(LOOP).read_text().replace('scenario: scenario_all_effects.yaml',
                                                   f'scenario: {CONFIG / "scenario_all_effects.yaml"}'))
    criteria = ['min_range_m > 22.5', 'losses == 0']
    path = write_loop_campaign(tmp_path / 'c.yaml', loop_file=str(loop), runs=3, criteria=criteria,
                               series={'worst': 1, 'by': 'min_range_m', 'worst_is': 'low', 'runs': [2]})
    campaign = load_campaign(path)
    out = tmp_path / 'out'
    with dask.config.set({'distributed.worker.profile.enabled': False}), \
            LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as local:
        report = run_campaign(campaign, out, address=local.scheduler_address, progress=False)
    assert (report.ok, report.failed) == (3, 0)
    results = {i: read_result(out, i)['metrics'] for i in range(3)}
    first = results[0]
    assert set(LOOP_METRICS) <= set(LOOP_METRIC_NAMES) <= set(first)  # every name criteria may use
    assert first['periods'] == 3 and first['losses'] == 0
    assert first['acquired_at_s'] == pytest.approx(0.15)  # the truth cloud, the 2nd period
    # Series: the closest approach (worst_is: low) and run 2, asked for.
    closest = min(results, key=lambda i: results[i]['min_range_m'])
    assert sorted(int(p.stem[4:]) for p in (out / 'series').glob('run_*.npz')) == sorted({closest, 2})
    series, meta = read_series(series_path(out, closest))
    assert float(series['range_m'].min()) == pytest.approx(results[closest]['min_range_m'])
    assert meta['metrics']['min_range_m'] == results[closest]['min_range_m']
    assert len(series['t_s']) == results[closest]['periods'] == 3
    # The summary's tables, as the command writes and prints them.
    summary = _loop_summary(out, campaign)
    printed = capsys.readouterr().out
    assert summary.runs == 3 and summary.figure.is_file()
    with summary.summary_table.open(newline='') as fh:
        table = {r['metric']: r for r in csv.DictReader(fh)}
    ranges = [results[i]['min_range_m'] for i in range(3)]
    assert float(table['min_range_m']['p50']) == pytest.approx(np.median(ranges))
    with summary.runs_table.open(newline='') as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r['min_range_m']) for r in rows] == pytest.approx(ranges)
    assert float(rows[1]['param.tumble_rate_dps']) == json.loads(
        (out / 'runs' / 'run_00001' / 'loop.json').read_text())['params']['tumble_rate_dps']
    # The verdicts: a hand count over the runs' loop.json.
    near = [results[i]['min_range_m'] > 22.5 for i in range(3)]
    clean = [results[i]['losses'] == 0 for i in range(3)]
    both = [a and b for a, b in zip(near, clean)]
    with (out / CRITERIA_TABLE).open(newline='') as fh:
        verdicts = {r['criterion']: r for r in csv.DictReader(fh)}
    assert [int(verdicts[c]['passed']) for c in criteria + ['all criteria']] == [sum(near), sum(clean), sum(both)]
    assert float(verdicts['all criteria']['pass_rate']) == sum(both) / 3
    assert f'pass {sum(both):>6d} of 3' in printed and 'all criteria' in printed
    assert [r['pass'] for r in rows] == [str(int(b)) for b in both]
    assert (out / VS_FIGURE).stat().st_size > 10_000 and (out / SERIES_FIGURE).is_file()
    # --run: one case again here, its metrics compared with its loop.json (identical: rc 0),
    # and its series kept: asked for by id.
    assert cli_main(['campaign', str(path), '--out', str(out), '--run', '1']) == 0
    assert 'run 1: metrics identical to the last result' in capsys.readouterr().out
    assert read_series(series_path(out, 1))[1]['asked'] is True
    # Resume: every run is finished, so nothing runs (no cluster starts) ...
    report = run_campaign(campaign, out, progress=False)
    assert (report.skipped, report.ran) == (3, 0)
    # ... and a changed loop file is another campaign: refused, not mixed.
    loop.write_text(loop.read_text().replace('thrust_limit_n: 20.0', 'thrust_limit_n: 10.0'))
    with pytest.raises(ValueError, match='different campaign'):
        run_campaign(load_campaign(tmp_path / 'c.yaml'), out, progress=False)


def test_frame_campaigns_keep_their_fingerprint():
    """A spec without ``loop`` dumps as before the key existed (the manifest fingerprints the
    dump), so campaign directories written before resume; a loop spec's dump holds it."""
    spec = load_campaign(CONFIG / 'campaign_example.yaml').spec
    assert '"loop"' not in spec.model_dump_json() and 'loop' not in spec.model_dump()
    loop = load_campaign(CONFIG / 'campaign_loop.yaml').spec
    assert f'"config_sha256":"{loop.loop.config_sha256}"' in loop.model_dump_json()
    assert len(loop.loop.config_sha256) == 64
