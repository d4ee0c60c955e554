"""campaign/manifest.py: the run ids a manifest may hold, and which row of a run id wins.

No cluster: the manifest is written by hand, and read back through ``Manifest`` alone.
"""
from __future__ import annotations

import csv
from pathlib import Path

import pytest
import yaml

from conftest import CONFIG
from lidar_sim_ros.campaign.manifest import MANIFEST, Manifest, ManifestError
from lidar_sim_ros.campaign.spec import MAX_RUNS
from lidar_sim_ros.cli import main as cli_main

HEADER = ['run_id', 'seed', 'status', 'error', 'stat.points']


def manifest_with(tmp_path: Path, lines: list[str]) -> Manifest:
    (tmp_path / MANIFEST).write_text(','.join(HEADER) + '\n' + ''.join(f'{line}\n' for line in lines))
    return Manifest(tmp_path, HEADER)


@pytest.mark.parametrize('order', [0, 1])
def test_the_last_row_of_a_run_id_wins(tmp_path, order):
    """Run 3 failed, then ``--retry-failed`` ran it again and it was ok: the ok row (the
    later one) is the run's result, whatever the order of the other rows."""
    rows = ['3,7,failed,RuntimeError: boom,', '1,5,ok,,12', '3,7,ok,,40', '0,4,failed,x,',
            '0,4,failed,y,']
    if order:
        rows = [rows[1], rows[0], rows[3], rows[2], rows[4]]
    manifest = manifest_with(tmp_path, rows)
    manifest.rewrite()
    with (tmp_path / MANIFEST).open(newline='') as fh:
        got = list(csv.reader(fh))
    # By hand: sorted by run id, one row each, the later of two rows of an id kept.
    assert got == [HEADER, ['0', '4', 'failed', 'y', ''], ['1', '5', 'ok', '', '12'],
                   ['3', '7', 'ok', '', '40']]
    assert [manifest.status(i) for i in range(4)] == ['failed', 'ok', None, 'ok']
    assert (manifest.count('ok'), manifest.count('failed')) == (2, 1)
    assert manifest.row(3)['stat.points'] == '40'


@pytest.mark.parametrize('run_id', [
    '1000000000',                       # 1e9: a status byte per id up to it was 1.26 GB
    str(MAX_RUNS),                      # the first id past the largest campaign
    '1' * 30,                           # overflowed the int64 offset index (traceback)
    '\u00b2',                           # superscript two: str.isdigit() True, int() refuses
    '\u0661',                           # Arabic-Indic one: int() reads it as 1
    '-1', '+2', ' 3', '1e3', '0x10',
])
def test_a_run_id_that_is_not_one_is_refused_naming_file_line_value(tmp_path, run_id):
    manifest = manifest_with(tmp_path, ['0,4,ok,,1', f'{run_id},5,ok,,2', '2,6,ok,,3'])
    with pytest.raises(ManifestError) as info:
        manifest.rewrite()
    message = str(info.value)
    assert str(tmp_path / MANIFEST) in message and 'line 3' in message and repr(run_id) in message
    assert len(manifest._status) <= 1  # refused before any status byte was grown for it


def test_the_largest_run_id_is_read(tmp_path):
    manifest = manifest_with(tmp_path, [f'{MAX_RUNS - 1},5,ok,,2'])
    manifest.rewrite()
    assert manifest.status(MAX_RUNS - 1) == 'ok' and manifest.count('ok') == 1


def test_a_half_written_last_line_is_still_dropped(tmp_path):
    (tmp_path / MANIFEST).write_text(','.join(HEADER) + '\n0,4,ok,,1\n1000000')
    manifest = Manifest(tmp_path, HEADER)
    manifest.rewrite()
    assert manifest.count('ok') == 1 and (tmp_path / MANIFEST).read_text().count('\n') == 2


def test_cli_refuses_a_bad_run_id_in_one_line(tmp_path, capsys):
    from lidar_sim_ros.campaign.spec import load_campaign
    spec = tmp_path / 'c.yaml'
    spec.write_text(yaml.safe_dump({'scenario': str(CONFIG / 'scenario.yaml'), 'seed': 1, 'runs': 2,
                                    'duration_s': 0.1, 'coverage_frames': 0}))
    out = tmp_path / 'out'
    manifest = Manifest.open(out, load_campaign(spec))
    manifest.append({'run_id': 0, 'seed': 1, 'status': 'ok'})
    with (out / MANIFEST).open('a', newline='') as fh:
        csv.DictWriter(fh, manifest.header).writerow({'run_id': '1' * 30, 'seed': 1, 'status': 'ok'})
    assert cli_main(['campaign', str(spec), '--out', str(out), '--run', '1']) == 2
    err = capsys.readouterr().err
    assert 'Traceback' not in err and len(err.strip().splitlines()) == 1
    assert f'{out / MANIFEST}: line 3: run_id {"1" * 30!r}' in err
