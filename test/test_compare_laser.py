"""The laser in the diagnosis (issue 20): a foreign recording (test/foreign_sim.py) whose
lasers each carry their own range offset, and a clean one in the Cepton driver's layout.

Checked: ``laser`` ranks first and ``laser_bias`` is named; after ``--effect laser_bias
--fit`` the offsets are recovered within 1 cm (up to their common mean, which the
material biases carry) and nothing else is named; the clean Cepton recording has its
point times read from timestamp_s + timestamp_us, names nothing, and after --fit its
range RMSE is within 10 % of the noise the generator put in.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from foreign_sim import CEPTON_TOPIC, battery, generate
from lidar_sim_ros.cli import main
from lidar_sim_ros.compare.model.fit import laser_offsets_m

FRAMES = 2


def _compare(ds, out, *extra) -> dict:
    argv = ['compare', str(ds.bag), '--mesh', str(ds.mesh), '--config', str(ds.scenario),
            '--out', str(out), '--no-report', *extra]
    assert main(argv) == 0
    return json.loads((out / 'summary.json').read_text())


def test_laser_offsets_closed_form():
    rng = np.random.default_rng(3)
    n, lasers = 6000, 8
    laser = rng.integers(0, lasers, n)
    material = rng.integers(0, 3, n)
    true = rng.normal(0, 0.02, lasers)
    true -= np.mean(true[laser])
    y = np.array([0.1, -0.05, 0.02])[material] + true[laser] + 0.01 * rng.standard_normal(n)
    y[:30] += 20.0                      # spurious returns get no say
    off = laser_offsets_m(y, np.full(n, 0.01), material, laser, 100.0)
    # Noise-limited: 0.01 m / sqrt(750 points a laser) = 0.37 mm a laser; 4 of those.
    assert np.allclose(off, true, atol=1.5e-3)


def test_laser_bias_found_and_recovered(tmp_path):
    spec = battery(['laser_bias'])[0]
    from dataclasses import replace
    ds = generate(replace(spec, frames=FRAMES), tmp_path / 'data')
    first = _compare(ds, tmp_path / 'step0')
    assert first['features'][0]['name'] == 'laser', first['features'][:3]
    assert first['missing_effect'] == 'laser_bias', first['verdict']
    fit = _compare(ds, tmp_path / 'step1', '--effect', 'laser_bias', '--fit')
    assert fit['missing_effect'] is None, fit['verdict']
    got = np.asarray(fit['fitted_effects'][0]['params']['offsets_m'])
    true = np.asarray(ds.truth['laser_offsets_m'])
    # Lasers fire round-robin: each carries the same share of the points.
    assert np.allclose(got - got.mean(), true - true.mean(), atol=0.01), (got, true)


def test_clean_cepton_recording(tmp_path, capsys):
    from dataclasses import replace
    spec = replace(battery(['clean_cepton'])[0], frames=FRAMES)
    ds = generate(spec, tmp_path / 'data')
    s = _compare(ds, tmp_path / 'fit', '--cloud-topic', CEPTON_TOPIC, '--effect',
                 'laser_bias', '--fit')
    out = capsys.readouterr().out
    assert 'timestamp_s (INT32) + timestamp_us (INT32): point time' in out
    assert 'NO_RETURN shots: known misses' in out
    # The driver's intensity is a reflectivity: read so because the layout says so.
    assert ('range-compensated reflectivity (~ P r^2), the slope of ln I held at 1 '
            '(as the layout says)') in out
    assert s['point_time_field']['name'] == 'timestamp_s+timestamp_us'
    assert s['point_times'] == 'field' and s['missing_effect'] is None, s['verdict']
    # The noise the generator put in, over the matched points of each material.
    errors = ds.truth['material_errors_m']
    pts = {k: v['points'] for k, v in s['materials'].items() if v['points']}
    noise = np.sqrt(sum(pts[k] * errors[k][1] ** 2 for k in pts) / sum(pts.values()))
    assert s['range_rmse_m'] == pytest.approx(noise, rel=0.1), (s['range_rmse_m'], noise)
