"""lidar-sim campaign: spec errors, seeds, dispersions, statistics, and real Dask runs.

The engine tests share one real local cluster of 2 worker processes (module fixture)
and join it through ``address``, the path a user's cluster takes; runs are 1 frame.
"""
from __future__ import annotations

import csv
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from scipy.spatial.transform import Rotation

from conftest import CONFIG, materials, plate_target, sensor
from lidar_sim_ros.campaign.coverage import FaceGeometry, covered_fraction, visible_faces
from lidar_sim_ros.campaign.manifest import MANIFEST, rerun
from lidar_sim_ros.campaign.run import MountedPose
from lidar_sim_ros.campaign.sample import key_rng, run_seed, sample_run
from lidar_sim_ros.campaign.spec import Cone, Normal, load_campaign
from lidar_sim_ros.campaign.statistics import RunStatistics
from lidar_sim_ros.cli import main as cli_main
from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.core.geometry import Target
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import Poses, StaticPose
from lidar_sim_ros.io.bag import read_clouds, read_material_names

dask_distributed = pytest.importorskip('dask.distributed')

SCENARIO = str(CONFIG / 'scenario.yaml')
BOOM_EFFECT = '''
from pydantic import BaseModel
from lidar_sim_ros.core.effects import Effect

THRESHOLD = 0.5

class Boom(Effect):
    """Fails every run whose x exceeds THRESHOLD (a stand-in for a run that crashes)."""
    name = 'boom'

    class Params(BaseModel):
        x: float = 0.0

    def range_bias_m(self, ctx):
        if self.params.x > THRESHOLD:
            raise RuntimeError(f'boom at x = {self.params.x}')
        return 0.0
'''


def write_campaign(path: Path, **overrides) -> Path:
    spec = {'scenario': SCENARIO, 'seed': 11, 'runs': 4, 'duration_s': 0.1, 'coverage_frames': 1,
            'dispersions': {
                'initial_distance_m': {'dist': 'uniform', 'low': 9.0, 'high': 14.0},
                'initial_attitude': {'dist': 'small_rotation', 'sigma_deg': 10.0},
                'tumble_axis': {'dist': 'uniform_sphere'},
                'tumble_rate_dps': {'dist': 'normal', 'mean': 6.0, 'sigma': 2.0},
                'approach_speed_mps': {'dist': 'uniform', 'low': 0.0, 'high': 0.1},
                'mounting_misalignment': {'dist': 'small_rotation', 'sigma_deg': 0.1},
                'materials': {'PIF': {'bias_m': {'dist': 'uniform', 'low': -0.1417, 'high': -0.1349},
                                      'sigma_m': {'dist': 'choice', 'values': [0.0228, 0.0334]}}},
                'effects': {'range_walk': {'k_m': {'dist': 'uniform', 'low': 0.0, 'high': 0.02}}}}}
    spec.update(overrides)
    path.write_text(yaml.safe_dump(spec))
    return path


def read_manifest(out: Path) -> dict[int, dict[str, str]]:
    with (out / MANIFEST).open(newline='') as fh:
        return {int(r['run_id']): r for r in csv.DictReader(fh)}


def results(row: dict[str, str]) -> dict[str, str]:
    """What a run computes: seed, status, parameters and statistics (not its timing)."""
    return {k: v for k, v in row.items() if k not in ('compute_s', 'cpu_s', 'worker')}


# ------------------------------------------------------------------- spec
@pytest.mark.parametrize('dispersions, key, words', [
    ({'tumble_rate_dps': {'dist': 'normal', 'mean': 6, 'sigma': -2}},
     'dispersions.tumble_rate_dps.sigma', 'greater than 0'),
    ({'tumble_rate_dps': {'dist': 'gamma', 'k': 2}}, 'dispersions.tumble_rate_dps', "'gamma'"),
    ({'approach_speed_mps': {'dist': 'uniform', 'low': 1.0, 'high': 0.5}},
     'dispersions.approach_speed_mps', 'must exceed low'),
    ({'initial_distance_m': {'dist': 'normal', 'mean': 10.0, 'sigma': 1.0}},
     'dispersions.initial_distance_m', '<= 0 m'),
    ({'materials': {'FOO': {'bias_m': {'dist': 'uniform', 'low': 0, 'high': 1}}}},
     'dispersions.materials.FOO', 'not a material'),
    ({'materials': {'PIF': {'sigma_m': {'dist': 'uniform', 'low': -0.01, 'high': 0.02}}}},
     'dispersions.materials.PIF.sigma_m', 'negative sigma'),
    ({'effects': {'range_walk': {'k': {'dist': 'uniform', 'low': 0, 'high': 1}}}},
     'dispersions.effects.range_walk.k', "no parameter 'k'"),
    ({'effects': {'solar_background': {'probability': {'dist': 'uniform', 'low': 0, 'high': 2}}}},
     'dispersions.effects.solar_background.probability', 'less than or equal to 1'),
    ({'tumble_axis': {'dist': 'cone', 'half_angle_deg': 10, 'axis': [0, 0, 0]}},
     'dispersions.tumble_axis', 'non-zero'),
    ({'tumble_speed': {'dist': 'uniform', 'low': 0, 'high': 1}},
     'dispersions.tumble_speed', 'unknown key'),
])
def test_bad_dispersion_names_file_and_key(tmp_path, dispersions, key, words):
    path = write_campaign(tmp_path / 'bad.yaml', dispersions=dispersions)
    with pytest.raises(ConfigError) as err:
        load_campaign(path)
    assert err.value.key == key
    assert str(path) in str(err.value) and words in str(err.value)


def test_bad_spec_is_one_cli_line(tmp_path, capsys):
    path = write_campaign(tmp_path / 'bad.yaml', runs=0)
    assert cli_main(['campaign', str(path), '--out', str(tmp_path / 'out')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'key "runs" = 0' in err[0] and str(path) in err[0]


# -------------------------------------------------------- seeds and laws
def test_run_seed_is_the_spawned_seed_sequence_child():
    # Documented construction: child (i, 1) of the campaign seed, i.e. what
    # SeedSequence(seed).spawn(...)[i].spawn(2)[1] gives, its first 64-bit word >> 1.
    for seed, i in ((0, 0), (11, 3), (2**40 + 7, 999)):
        child = np.random.SeedSequence(seed).spawn(i + 1)[i].spawn(2)[1]
        assert run_seed(seed, i) == int(child.generate_state(1, np.uint64)[0]) >> 1
    seeds = {run_seed(11, i) for i in range(1000)}
    assert len(seeds) == 1000 and all(0 <= s < 2**63 for s in seeds)


def test_sampling_is_pure_and_keyed(tmp_path):
    campaign = load_campaign(write_campaign(tmp_path / 'c.yaml'))
    a, b = sample_run(campaign, 2), sample_run(campaign, 2)
    assert a.params == b.params and a.seed == b.seed == run_seed(11, 2)
    assert sample_run(campaign, 1).params != a.params
    # Each quantity has its own stream: removing one dispersion leaves the others' draws.
    spec = yaml.safe_load((tmp_path / 'c.yaml').read_text())
    del spec['dispersions']['tumble_axis']
    fewer = load_campaign(write_campaign(tmp_path / 'fewer.yaml', **spec))
    c = sample_run(fewer, 2)
    assert {k: v for k, v in a.params.items() if not k.startswith('tumble_axis')} == c.params
    # The drawn values land in the run's scenario.
    cfg = a.scenario.config
    assert cfg.seed == a.seed
    assert np.linalg.norm(cfg.initial_pose.position_m) == pytest.approx(a.params['initial_distance_m'])
    base_los = np.asarray(campaign.scenario.config.initial_pose.position_m)
    assert np.cross(cfg.initial_pose.position_m, base_los) == pytest.approx(np.zeros(3), abs=1e-9)
    assert cfg.motion.tumble_rate_dps == a.params['tumble_rate_dps']
    pif = a.scenario.materials.materials[a.scenario.materials.index('PIF')]
    assert pif.bias_m == a.params['material.PIF.bias_m'] and pif.sigma_m in (0.0228, 0.0334)
    assert [(e.name, e.params) for e in cfg.effects] == [('range_walk', {'k_m': a.params['effect.range_walk.k_m']})]
    with pytest.raises(ValueError, match='not in this campaign'):
        sample_run(campaign, 4)


def test_laws_stay_in_their_support():
    rng = np.random.default_rng(5)
    trunc = Normal(dist='normal', mean=1.0, sigma=2.0, low=0.5, high=2.0)
    draws = np.array([trunc.sample(rng) for _ in range(300)])
    assert draws.min() >= 0.5 and draws.max() <= 2.0
    # Uniform on a cap of half-angle a: E[cos(angle to axis)] = (1 + cos a) / 2.
    cone = Cone(dist='cone', half_angle_deg=40.0, axis=(1.0, 1.0, 0.0))
    axis = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    cos = np.array([cone.sample(rng, None) @ axis for _ in range(2000)])
    assert cos.min() >= math.cos(math.radians(40.0)) - 1e-12
    # cos is uniform on [cos a, 1]: standard error (1 - cos a) / sqrt(12 n) = 0.0015.
    assert cos.mean() == pytest.approx((1 + math.cos(math.radians(40.0))) / 2, abs=0.006)
    assert key_rng(1, 2, 'x').random() == key_rng(1, 2, 'x').random() != key_rng(1, 2, 'y').random()


def test_mounted_pose_rotates_the_lidar_frame():
    base = StaticPose((10.0, 1.0, -2.0), tuple(Rotation.from_euler('xyz', [10, 20, 30], degrees=True).as_quat()))
    m = Rotation.from_rotvec([0.01, -0.02, 0.005])
    poses = MountedPose(base, tuple(m.as_quat())).at(np.array([0.0, 0.5]))
    ref_r = m * Rotation.from_quat(base.quat_xyzw)
    assert poses.position_m == pytest.approx(np.tile(m.apply(base.position_m), (2, 1)))
    assert (Rotation.from_quat(poses.quat_xyzw) * ref_r.inv()).magnitude() == pytest.approx([0, 0], abs=1e-12)


# ------------------------------------------------- statistics and coverage
def test_range_error_and_dropout_statistics_on_a_plate():
    # A plate 10 m ahead filling the beam: every shot hits, bias 0.05 m, no noise.
    sens = sensor(scan={'type': 'rotating', 'elevations_deg': [-1.0, 0.0, 1.0],
                        'az_min_deg': -2.0, 'az_max_deg': 2.0, 'shots_per_beam': 50})
    sim = Simulator(sens, materials(bias_m=0.05, sigma_m=0.0), plate_target(4.0), seed=1)
    facing = tuple(Rotation.from_euler('y', -90, degrees=True).as_quat())  # body +z -> lidar -x
    stats = RunStatistics(['PIF'])
    stats.add_frame(sim.simulate_frame(0.0, StaticPose((10.0, 0.0, 0.0), facing), 0))
    s = stats.summary()
    assert s['shots'] == s['hits'] == s['points'] == 150 and s['dropped_missed'] == 0
    assert s['range_error_mean_m.PIF'] == pytest.approx(0.05, abs=1e-9)
    assert s['range_error_std_m.PIF'] == pytest.approx(0.0, abs=1e-6)
    # Past the range gate every hit drops as "other"; the causes add up to the shots.
    gated = Simulator(sensor(scan=sens.scan.model_dump(), max_range_m=5.0), materials(), plate_target(4.0))
    stats = RunStatistics(['PIF'])
    stats.add_frame(gated.simulate_frame(0.0, StaticPose((10.0, 0.0, 0.0), facing), 0))
    s = stats.summary()
    assert s['points'] == 0 and s['dropped_other'] == 150 and math.isnan(s['range_error_mean_m'])
    assert (s['dropped_missed'] + s['dropped_below_threshold'] + s['dropped_saturated']
            + s['dropped_other']) == s['shots'] - s['points'] + s['false_returns']


def test_frame_points_carry_their_face_and_true_range():
    # Plate at x = 10 m facing the sensor: true range 10 / d_x along unit direction d.
    sens = sensor(scan={'type': 'rotating', 'elevations_deg': [-3.0, 0.0, 2.0],
                        'az_min_deg': -4.0, 'az_max_deg': 4.0, 'shots_per_beam': 30})
    sim = Simulator(sens, materials(bias_m=0.0, sigma_m=0.02), plate_target(4.0), seed=2)
    facing = tuple(Rotation.from_euler('y', -90, degrees=True).as_quat())
    frame = sim.simulate_frame(0.0, StaticPose((10.0, 0.0, 0.0), facing), 0)
    d = frame.xyz_m / np.linalg.norm(frame.xyz_m, axis=1, keepdims=True)
    assert len(frame) == 90
    assert frame.true_range_m == pytest.approx(10.0 / d[:, 0], rel=1e-6)
    assert set(frame.face.tolist()) <= {0, 1} and set(frame.truth_face.tolist()) == {0, 1}
    # Which triangle: the plate's diagonal y = x (body frame) splits it into face 0
    # (y < x) and face 1 (y > x); each return's body point decides, not the raycast.
    body = Rotation.from_quat(facing).inv().apply(frame.xyz_m - [10.0, 0.0, 0.0])
    upper = body[:, 1] > body[:, 0]
    clear = np.abs(body[:, 1] - body[:, 0]) > 0.1  # noise moves points along the ray
    assert np.array_equal(frame.face[clear], upper[clear].astype(int))


def test_range_error_sigma_matches_the_material():
    sens = sensor(scan={'type': 'rotating', 'elevations_deg': list(np.linspace(-2, 2, 40)),
                        'az_min_deg': -2.0, 'az_max_deg': 2.0, 'shots_per_beam': 100})
    sim = Simulator(sens, materials(bias_m=-0.1, sigma_m=0.03), plate_target(4.0), seed=3)
    facing = tuple(Rotation.from_euler('y', -90, degrees=True).as_quat())
    stats = RunStatistics(['PIF'])
    for k in range(3):
        stats.add_frame(sim.simulate_frame(0.1 * k, StaticPose((10.0, 0.0, 0.0), facing), k))
    s = stats.summary()
    n = s['points.PIF']
    assert n == 12000
    # Gaussian noise: mean within 4 standard errors, sigma within 4 of its standard error.
    assert s['range_error_mean_m.PIF'] == pytest.approx(-0.1, abs=4 * 0.03 / math.sqrt(n))
    assert s['range_error_std_m.PIF'] == pytest.approx(0.03, abs=4 * 0.03 / math.sqrt(2 * n))


def test_visibility_of_a_sphere_is_its_horizon_cap():
    # Convex: a face is visible iff its centroid lies on the near side of the horizon,
    # i.e. (c - o) . c < 0 with the sensor at o (closed form of the tangent cone).
    mesh_r, d = 1.0, 6.0
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=mesh_r)
    target = Target(sphere.vertices, sphere.faces, np.zeros(len(sphere.faces), int), ['PIF'])
    faces = FaceGeometry.of(target)
    pose = Poses(Rotation.identity(1), np.array([[d, 0.0, 0.0]]))
    wide = (-math.pi, math.pi)
    visible = visible_faces(target, faces, pose, wide, (-math.pi / 2, math.pi / 2))
    o = np.array([-d, 0.0, 0.0])  # the sensor in the body frame
    expected = np.einsum('ij,ij->i', faces.centroid_m - o, faces.normal) < 0
    assert np.array_equal(visible, expected) and 0 < visible.sum() < len(visible) / 2
    # A narrow field of view sees only the faces whose centroid is inside it.
    narrow = visible_faces(target, faces, pose, (-0.05, 0.05), (-0.05, 0.05))
    assert narrow.sum() < visible.sum() and not (narrow & ~visible).any()
    assert covered_fraction(faces.area_m2, visible, np.flatnonzero(visible)) == pytest.approx(1.0)
    assert covered_fraction(faces.area_m2, visible, np.array([-1])) == 0.0


def test_an_occluded_plate_is_not_visible():
    # Two 2 m plates facing the sensor along x, the rear one 1 m behind the front one.
    front, rear = plate_target(2.0), plate_target(2.0)
    verts = np.vstack([front.vertices_m, rear.vertices_m + [0.0, 0.0, -1.0]])
    target = Target(verts, np.vstack([front.faces, rear.faces + 4]), np.zeros(4, int), ['PIF'])
    faces = FaceGeometry.of(target)
    facing = Rotation.from_euler('y', -90, degrees=True)
    pose = Poses(facing, np.array([[10.0, 0.0, 0.0]]))
    visible = visible_faces(target, faces, pose, (-1.0, 1.0), (-1.0, 1.0))
    assert visible.tolist() == [True, True, False, False]


def test_bags_hold_the_runs_frames_and_change_no_statistic(tmp_path):
    stats_only = load_campaign(write_campaign(tmp_path / 's.yaml', duration_s=0.2))
    with_bags = load_campaign(write_campaign(tmp_path / 'b.yaml', duration_s=0.2, save='bags'))
    row_s, _ = rerun(stats_only, tmp_path / 'out_s', 1)
    row_b, _ = rerun(with_bags, tmp_path / 'out_b', 1)
    assert row_b['status'] == 'ok' and results(row_b) == results(row_s)
    bag = tmp_path / 'out_b' / 'runs' / 'run_00001' / 'bag'
    clouds = read_clouds(bag)
    assert len(clouds) == 2 and sum(len(c.points) for c in clouds) == int(row_b['stat.points'])
    assert read_material_names(bag) == stats_only.scenario.materials.names
    assert not (tmp_path / 'out_s' / 'runs').exists()


# ------------------------------------------------------------ the engine
@pytest.fixture(scope='module')
def cluster():
    """A real local Dask cluster: 2 single-threaded worker processes, as the engine starts them."""
    from lidar_sim_ros.campaign.engine import local_cluster
    with local_cluster(2) as local:
        yield local.scheduler_address


@pytest.fixture(scope='module')
def finished(cluster, tmp_path_factory):
    """A 4-run campaign run to the end on the 2-worker cluster."""
    from lidar_sim_ros.campaign.engine import run_campaign
    tmp = tmp_path_factory.mktemp('campaign')
    campaign = load_campaign(write_campaign(tmp / 'c.yaml'))
    report = run_campaign(campaign, tmp / 'out', address=cluster, progress=False)
    return campaign, tmp / 'out', report


def test_four_runs_on_two_workers(finished):
    campaign, out, report = finished
    assert (report.runs, report.ran, report.ok, report.failed, report.workers) == (4, 4, 4, 0, 2)
    rows = read_manifest(out)
    assert sorted(rows) == [0, 1, 2, 3]
    assert len({r['worker'] for r in rows.values()}) == 2  # both workers took runs
    for i, row in rows.items():
        case = sample_run(campaign, i)
        assert row['status'] == 'ok' and int(row['seed']) == case.seed
        assert float(row['param.initial_distance_m']) == case.params['initial_distance_m']
        points, shots = int(row['stat.points']), int(row['stat.shots'])
        assert shots == 21120 and 1000 < points <= shots  # one P-60 frame at 9-14 m
        drops = sum(int(row[f'stat.dropped_{c}']) for c in ('missed', 'below_threshold',
                                                             'saturated', 'other'))
        assert drops == shots - points + int(row['stat.false_returns'])
        assert 0.0 < float(row['stat.coverage']) <= float(row['stat.coverage_hit']) <= 1.0
        # Range errors sit at the Table 2 biases (all about -0.1 to -0.15 m, walk adds < 0).
        assert -0.3 < float(row['stat.range_error_mean_m']) < -0.09


def _worker_state(dask_worker) -> dict:
    from lidar_sim_ros.campaign import worker
    return {'env': {k: os.environ.get(k) for k in ('MALLOC_TRIM_THRESHOLD_', 'OMP_NUM_THREADS',
                                                  'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')},
            'warm': sorted(worker._WARM),
            'profiler_callbacks': [name for name in dask_worker.periodic_callbacks
                                   if 'profile' in name]}


def test_workers_are_prepared_with_one_thread_and_glibc_defaults(finished, cluster):
    """Dask's MALLOC_TRIM_THRESHOLD_ is removed (it pins glibc's mmap threshold: every
    frame's arrays page-faulted in afresh), one BLAS / OpenMP thread per worker, no
    stack profiler, and the dispersed scenario's effect list (range_walk, added by the
    campaign) was warmed."""
    with dask_distributed.Client(cluster) as client:
        states = client.run(_worker_state)
    assert len(states) == 2
    for state in states.values():
        assert state['env'] == {'MALLOC_TRIM_THRESHOLD_': None, 'OMP_NUM_THREADS': '1',
                                'OPENBLAS_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1'}
        assert state['profiler_callbacks'] == []
        assert ('range_walk',) in state['warm']


def test_rerun_by_id_gives_identical_statistics(finished, capsys):
    campaign, out, _ = finished
    before = read_manifest(out)[2]
    row, old = rerun(campaign, out, 2)  # in this process: no worker, no cache shared
    assert results(old) == results(before) == results(row)
    run1 = read_manifest(out)[1]
    assert cli_main(['campaign', str(campaign.source), '--out', str(out), '--run', '1']) == 0
    assert 'statistics identical to the manifest row' in capsys.readouterr().out
    assert results(read_manifest(out)[1]) == results(run1)
    assert cli_main(['campaign', str(campaign.source), '--out', str(out), '--run', '4']) == 2
    assert 'the campaign has runs 0..3' in capsys.readouterr().err
    assert sorted(read_manifest(out)) == [0, 1, 2, 3]


def test_resume_skips_finished_runs(finished, cluster, tmp_path):
    from lidar_sim_ros.campaign.engine import run_campaign
    campaign, out, _ = finished
    full = read_manifest(out)
    # An interrupted campaign: runs 1 and 3 missing, and a half-written last line.
    text = (out / MANIFEST).read_text().splitlines(keepends=True)
    kept = [text[0]] + [line for line in text[1:] if line.split(',')[0] in ('0', '2')]
    (out / MANIFEST).write_text(''.join(kept) + text[2][:40])
    report = run_campaign(campaign, out, address=cluster, progress=False)
    assert (report.skipped, report.ran, report.ok) == (2, 2, 2)
    rows = read_manifest(out)
    assert {i: results(r) for i, r in rows.items()} == {i: results(r) for i, r in full.items()}
    assert rows[0]['worker'] == full[0]['worker']  # untouched, not re-run
    # Another campaign cannot resume into this directory.
    other = load_campaign(write_campaign(tmp_path / 'other.yaml', seed=12))
    with pytest.raises(ValueError, match='different campaign'):
        run_campaign(other, out, address=cluster, progress=False)


def test_failing_runs_are_recorded_and_the_others_finish(cluster, tmp_path):
    from lidar_sim_ros.campaign.engine import run_campaign
    boom = tmp_path / 'boom.py'
    boom.write_text(BOOM_EFFECT)
    path = write_campaign(tmp_path / 'c.yaml', seed=3, dispersions={
        'effects': {f'{boom}:Boom': {'x': {'dist': 'uniform', 'low': 0.0, 'high': 1.0}}}})
    campaign = load_campaign(path)
    x = {i: sample_run(campaign, i).params[f'effect.{boom}:Boom.x'] for i in range(4)}
    # The draws depend on the effect's key (its path here): fail the two largest.
    threshold = sorted(x.values())[1]
    boom.write_text(BOOM_EFFECT.replace('THRESHOLD = 0.5', f'THRESHOLD = {threshold!r}'))
    expect_failed = {i for i, v in x.items() if v > threshold}
    assert len(expect_failed) == 2, x
    report = run_campaign(campaign, tmp_path / 'out', address=cluster, progress=False)
    rows = read_manifest(tmp_path / 'out')
    assert {i for i, r in rows.items() if r['status'] == 'failed'} == expect_failed
    assert (report.ok, report.failed) == (4 - len(expect_failed), len(expect_failed))
    for i in expect_failed:
        assert 'RuntimeError: boom at x' in rows[i]['error'] and rows[i]['stat.points'] == ''
    # Failed runs are finished: a second call skips them unless asked to retry.
    again = run_campaign(campaign, tmp_path / 'out', address=cluster, progress=False)
    assert again.ran == 0
    retry = run_campaign(campaign, tmp_path / 'out', address=cluster, retry_failed=True, progress=False)
    assert retry.ran == retry.failed == len(expect_failed)


def test_interrupted_cli_campaign_resumes(cluster, tmp_path):
    """Ctrl-C in the middle of a real `lidar-sim campaign`, then the same command again."""
    # Runs of 20 frames (~0.3 s each here): an interrupt sent after the second row lands
    # with most of the 40 still to do, even if the client is slow to see it.
    path = write_campaign(tmp_path / 'c.yaml', runs=40, seed=5, duration_s=2.0)
    out = tmp_path / 'out'
    cmd = [sys.executable, '-m', 'lidar_sim_ros.cli', 'campaign', str(path), '--out', str(out),
           '--address', cluster, '--no-progress']
    # SIGINT as a foreground job has it (a suite started in the background of a
    # non-interactive shell passes it on ignored).
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if (out / MANIFEST).is_file() and len(read_manifest(out)) >= 2:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and 'Traceback' not in err, err[-2000:]
    done_before = read_manifest(out)
    assert 2 <= len(done_before) < 40, 'the campaign should have been interrupted mid-way'
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert f'{len(done_before)} already finished' in result.stdout
    rows = read_manifest(out)
    assert sorted(rows) == list(range(40)) and all(r['status'] == 'ok' for r in rows.values())
    assert all(rows[i]['compute_s'] == r['compute_s'] for i, r in done_before.items())


# ------------------------------------------------------- batches of short runs
def test_batch_sizer_by_hand():
    from lidar_sim_ros.campaign.engine import BatchSizer
    sizer = BatchSizer(task_s=0.5, max_runs=500)
    assert sizer.size(remaining=10_000, share=8) == 1           # no run timed yet
    for compute_s in (0.002, 0.004, 0.003, float('nan')):      # mean 3 ms, the NaN ignored
        sizer.observe(compute_s)
    assert sizer.size(remaining=10_000, share=8) == 166         # 0.5 s // 3 ms
    assert sizer.size(remaining=400, share=8) == 50             # an even share of the rest
    assert sizer.size(remaining=3, share=8) == 1
    fast = BatchSizer(task_s=0.5, max_runs=500)
    fast.observe(0.0)                                           # a failed sampling: no time
    assert fast.size(remaining=10_000, share=8) == 500
    slow = BatchSizer(task_s=0.5, max_runs=500)
    slow.observe(0.7)                                           # longer than a task: alone
    assert slow.size(remaining=10_000, share=8) == 1


TINY_SCAN = {'type': 'rotating', 'elevations_deg': [0.0], 'az_min_deg': -5.0, 'az_max_deg': 5.0,
             'shots_per_beam': 16}


def write_tiny_campaign(tmp: Path, runs: int, seed: int = 21, effects: list | None = None,
                        dispersions: dict | None = None) -> Path:
    """Runs of one frame of a 16-shot sensor (~1 ms each): the engine's batches, not physics."""
    sensor_cfg = yaml.safe_load((CONFIG / 'cepton_vista_p60.yaml').read_text())
    sensor_cfg['scan'] = TINY_SCAN
    (tmp / 'sensor.yaml').write_text(yaml.safe_dump(sensor_cfg))
    scenario = yaml.safe_load((CONFIG / 'scenario.yaml').read_text())
    scenario.update(sensor=str(tmp / 'sensor.yaml'), materials=str(CONFIG / 'materials.yaml'),
                    mesh=str((CONFIG / scenario['mesh']).resolve()), effects=effects or [])
    (tmp / 'scenario.yaml').write_text(yaml.safe_dump(scenario))
    return write_campaign(tmp / 'tiny.yaml', scenario=str(tmp / 'scenario.yaml'), runs=runs,
                          seed=seed, coverage_frames=0, dispersions=dispersions or {
                              'initial_distance_m': {'dist': 'uniform', 'low': 8.0, 'high': 25.0},
                              'tumble_axis': {'dist': 'uniform_sphere'}})


def test_short_runs_go_in_batches_and_give_the_rows_of_single_runs(cluster, tmp_path, capsys):
    """300 runs of ~1 ms: far fewer tasks than runs, every run exactly once, each row what
    the run gives alone in this process; a resume after losing rows redoes those only."""
    from lidar_sim_ros.campaign.engine import run_campaign
    campaign = load_campaign(write_tiny_campaign(tmp_path, 300))
    out = tmp_path / 'out'
    report = run_campaign(campaign, out, address=cluster, progress=False)
    assert (report.ran, report.ok) == (300, 300)
    assert report.tasks < 100, report.tasks
    rows = read_manifest(out)
    assert sorted(rows) == list(range(300))
    assert (out / MANIFEST).read_text().count('\n') == 301      # no run twice
    for run_id in (0, 1, 137, 299):
        alone, _ = rerun(campaign, out, run_id)
        assert results(alone) == results(rows[run_id])
    rows = read_manifest(out)  # those four rows rewritten by rerun, same results
    # Lose every third row and the end of the last one: exactly those run again.
    text = (out / MANIFEST).read_text().splitlines(keepends=True)
    kept = [text[0]] + [line for line in text[1:] if int(line.split(',')[0]) % 3]
    (out / MANIFEST).write_text(''.join(kept[:-1]) + kept[-1][:30])
    lost = {i for i in range(300) if i % 3 == 0} | {int(kept[-1].split(',')[0])}
    capsys.readouterr()
    again = run_campaign(campaign, out, address=cluster, progress=True)
    assert (again.skipped, again.ran) == (300 - len(lost), len(lost))
    bar = capsys.readouterr().err  # drawn before the manifest is read and the workers start
    assert bar.index('reading the manifest') < bar.index('starting workers') < bar.index('done ')
    after = read_manifest(out)
    assert sorted(after) == list(range(300))
    assert {i: results(r) for i, r in after.items()} == {i: results(r) for i, r in rows.items()}
    assert all(after[i]['compute_s'] == rows[i]['compute_s'] for i in range(300) if i not in lost)


def test_a_frame_campaign_with_criteria_prints_its_pass_rates(cluster, tmp_path, capsys):
    from lidar_sim_ros.campaign.summary import FRAME_CRITERIA_TABLE
    path = write_tiny_campaign(tmp_path, 20)
    spec = yaml.safe_load(path.read_text())
    spec['criteria'] = ['points >= 8', 'range_error_mean_m > -0.14']
    path.write_text(yaml.safe_dump(spec))
    out = tmp_path / 'out'
    assert cli_main(['campaign', str(path), '--out', str(out), '--address', cluster, '--no-progress']) == 0
    printed = capsys.readouterr().out
    rows = read_manifest(out).values()
    # By hand, from the manifest: each criterion and both.
    many = [int(r['stat.points']) >= 8 for r in rows]
    near = [float(r['stat.range_error_mean_m']) > -0.14 for r in rows]
    both = sum(a and b for a, b in zip(many, near))
    with (out / FRAME_CRITERIA_TABLE).open(newline='') as fh:
        passed = [int(r['passed']) for r in csv.DictReader(fh)]
    assert passed == [sum(many), sum(near), both]
    assert f'pass {both:>6d} of 20' in printed and 'all criteria' in printed


DIE_EFFECT = BOOM_EFFECT.replace(
    'if self.params.x > THRESHOLD:', 'if LOW < self.params.x < HIGH:').replace(
    "raise RuntimeError(f'boom at x = {self.params.x}')", "import os; os._exit(3)")


def test_a_run_that_kills_its_worker_fails_alone(tmp_path):
    """The worker dies in the middle of a batch: its runs are run again one at a time, and
    only the one that kills the worker is recorded as failed (Dask retries none here)."""
    import dask

    from lidar_sim_ros.campaign.engine import local_cluster, run_campaign
    die = tmp_path / 'die.py'
    die.write_text(DIE_EFFECT)
    disp = {'effects': {f'{die}:Boom': {'x': {'dist': 'uniform', 'low': 0.0, 'high': 1.0}}}}
    campaign = load_campaign(write_tiny_campaign(tmp_path, 40, dispersions=disp))
    x = np.array([sample_run(campaign, i).params[f'effect.{die}:Boom.x'] for i in range(40)])
    guilty = 25  # late enough to be in a batch of several (1 worker, 4 tasks in flight)
    gap = np.min(np.abs(np.delete(x, guilty) - x[guilty])) / 2
    die.write_text(DIE_EFFECT.replace('THRESHOLD = 0.5', f'LOW, HIGH = {float(x[guilty] - gap)!r}, '
                                                         f'{float(x[guilty] + gap)!r}'))
    with dask.config.set({'distributed.scheduler.allowed-failures': 0}), local_cluster(1) as local:
        report = run_campaign(campaign, tmp_path / 'out', address=local.scheduler_address,
                              progress=False)
    rows = read_manifest(tmp_path / 'out')
    assert sorted(rows) == list(range(40))
    assert {i for i, r in rows.items() if r['status'] == 'failed'} == {guilty}
    assert rows[guilty]['error'].startswith('engine: KilledWorker'), rows[guilty]['error']
    assert (report.ok, report.failed) == (39, 1) and report.tasks < 40


def test_core_does_not_import_the_engine():
    code = ('import sys, lidar_sim_ros.cli, lidar_sim_ros.offline, lidar_sim_ros.campaign.run; '
            'sys.exit(any(m.split(".")[0] in ("dask", "distributed", "tqdm") for m in sys.modules))')
    assert subprocess.run([sys.executable, '-c', code], env={**os.environ}).returncode == 0


# The order of campaign/__init__.py's docstring: a module imports only modules before it.
CAMPAIGN_LAYERS = ('statistics', 'coverage', 'criteria', 'spec', 'sample', 'worker', 'series',
                   'loop_case', 'run', 'manifest', 'summary', 'engine', 'command')


def test_campaign_imports_flow_one_way():
    """No circle of imports among campaign's modules, counting imports inside functions:
    read from the source (ast), not from what happens to be imported at run time."""
    import ast

    import lidar_sim_ros.campaign as package
    folder = Path(package.__file__).parent
    modules = {p.stem for p in folder.glob('*.py')} - {'__init__'}
    assert modules == set(CAMPAIGN_LAYERS), 'a new module: place it in CAMPAIGN_LAYERS and the docstring'
    for name in CAMPAIGN_LAYERS:
        tree = ast.parse((folder / f'{name}.py').read_text())
        used = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module == 'lidar_sim_ros.campaign':
                used |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and (node.module or '').startswith('lidar_sim_ros.campaign.'):
                used.add(node.module.split('.')[2])
            elif isinstance(node, ast.Import):
                used |= {a.name.split('.')[2] for a in node.names
                         if a.name.startswith('lidar_sim_ros.campaign.')}
        below = set(CAMPAIGN_LAYERS[:CAMPAIGN_LAYERS.index(name)])
        assert used <= below, f'campaign/{name}.py imports {sorted(used - below)}, which come after it'


# ------------------------------------------------------------- TLS (a shared network)
def _openssl(*args: str) -> None:
    subprocess.run(['openssl', *args], check=True, capture_output=True)


def _make_ca_and_cert(folder: Path, name: str) -> dict[str, Path]:
    """A CA and one certificate it signed (EC P-256, 2 days), as docs/campaign.md makes them."""
    folder.mkdir()
    f = {k: folder / f'{k}.pem' for k in ('ca', 'ca-key', 'cert', 'key', 'req')}
    ec = ['-newkey', 'ec', '-pkeyopt', 'ec_paramgen_curve:prime256v1', '-nodes']
    _openssl('req', '-x509', *ec, '-days', '2', '-subj', f'/CN={name}-ca', '-keyout', str(f['ca-key']),
             '-out', str(f['ca']))
    _openssl('req', *ec, '-subj', f'/CN={name}', '-keyout', str(f['key']), '-out', str(f['req']))
    _openssl('x509', '-req', '-in', str(f['req']), '-CA', str(f['ca']), '-CAkey', str(f['ca-key']),
             '-CAcreateserial', '-days', '2', '-out', str(f['cert']))
    return f


@pytest.fixture(scope='module')
def tls_cluster(tmp_path_factory):
    """A TLS scheduler with one in-process worker thread (quick to start), every endpoint
    holding a certificate of one CA; and a second CA's certificate, an intruder's."""
    import shutil

    import dask
    from distributed.security import Security
    if shutil.which('openssl') is None:
        pytest.skip('openssl not installed')
    tmp = tmp_path_factory.mktemp('tls')
    ours, theirs = _make_ca_and_cert(tmp / 'ours', 'cluster'), _make_ca_and_cert(tmp / 'theirs', 'intruder')
    pem = {f'tls_{role}_{kind}': str(ours[kind]) for role in ('scheduler', 'worker', 'client')
           for kind in ('cert', 'key')}  # client: the cluster object's own connections
    security = Security(tls_ca_file=str(ours['ca']), require_encryption=True, **pem)
    with dask.config.set({'distributed.worker.profile.enabled': False}), \
            dask_distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol='tls',
                                          security=security, dashboard_address=None) as local:
        yield local.scheduler_address, ours, theirs


def test_a_campaign_joins_a_tls_cluster_with_the_given_certificates(tls_cluster, tmp_path, capsys):
    address, ours, _ = tls_cluster
    assert address.startswith('tls://')
    path = write_tiny_campaign(tmp_path, 6)
    tls = ['--tls-ca-file', str(ours['ca']), '--tls-cert', str(ours['cert']), '--tls-key', str(ours['key'])]
    argv = ['campaign', str(path), '--out', str(tmp_path / 'out'), '--address', address, '--no-progress']
    assert cli_main(argv + tls) == 0, capsys.readouterr().err
    assert '6 ok' in capsys.readouterr().out and sorted(read_manifest(tmp_path / 'out')) == list(range(6))


def test_the_dask_config_certificates_reach_the_client(tls_cluster):
    import dask

    from lidar_sim_ros.campaign.engine import connect
    address, ours, _ = tls_cluster
    with dask.config.set({'distributed.comm.tls.ca-file': str(ours['ca']),
                          'distributed.comm.tls.client.cert': str(ours['cert']),
                          'distributed.comm.tls.client.key': str(ours['key'])}):
        with connect(address=address) as client:
            assert client.security.tls_client_cert == str(ours['cert'])
            assert client.submit(math.hypot, 3.0, 4.0).result() == 5.0


@pytest.mark.parametrize('case, words', [
    ('intruder', 'cannot reach a Dask scheduler at tls://'),       # a certificate of another CA
    ('no certificate', 'needs this client\'s certificate'),
    ('tcp address', 'the scheduler\'s address is tls://'),
    ('no address', '--tls-* secure the connection to --address'),
    ('no CA', '--tls-ca-file and --tls-cert go together'),
    ('missing file', 'no such file'),
])
def test_tls_misuse_is_one_line(tls_cluster, tmp_path, capsys, case, words):
    address, ours, theirs = tls_cluster
    path = write_tiny_campaign(tmp_path, 2)
    tls = ['--tls-ca-file', str(ours['ca']), '--tls-cert', str(ours['cert']), '--tls-key', str(ours['key'])]
    argv = ['campaign', str(path), '--out', str(tmp_path / 'out'), '--no-progress', '--address', address]
    argv += {'intruder': ['--tls-ca-file', str(ours['ca']), '--tls-cert', str(theirs['cert']),
                          '--tls-key', str(theirs['key'])],
             'no certificate': [],
             'tcp address': tls,
             'no address': tls,
             'no CA': tls[2:],
             'missing file': tls[:-1] + [str(tmp_path / 'nowhere.pem')]}[case]
    if case == 'tcp address':
        argv[argv.index(address)] = address.replace('tls://', 'tcp://')
    if case == 'no address':
        del argv[argv.index('--address'):argv.index(address) + 1]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and 'Traceback' not in err[0], err
    assert not (tmp_path / 'out' / MANIFEST).is_file() or not read_manifest(tmp_path / 'out')


def test_sensor_and_target_are_dispersable_choices(tmp_path):
    """Each run draws a sensor and a target (mesh, materials, names map); the drawn ones
    are what the run simulates; the manifest has every target's material columns."""
    from lidar_sim_ros.campaign.manifest import columns
    from lidar_sim_ros.campaign.run import run_one
    path = write_campaign(
        tmp_path / 'choices.yaml', runs=12, dispersions={
            'initial_distance_m': {'dist': 'uniform', 'low': 12.0, 'high': 14.0},
            'sensor': [str(CONFIG / 'cepton_vista_p60.yaml'), str(CONFIG / 'livox_mid40.yaml')],
            'target': [{'mesh': str(CONFIG.parent / 'meshes' / 'rocket_body.obj'),
                        'materials': str(CONFIG / 'materials.yaml')},
                       {'mesh': str(CONFIG.parent / 'meshes' / 'box_wing_satellite.glb'),
                        'materials': str(CONFIG / 'materials_box_wing.yaml'),
                        'mesh_materials': {'bus_mli': 'MLI', 'solar_cells': 'SOLAR_ARRAY',
                                           'radiator_white_paint': 'WHITE_PAINT',
                                           'antenna_aluminium': 'ALUMINIUM'}}]})
    campaign = load_campaign(path)
    cases = [sample_run(campaign, i) for i in range(12)]
    drawn = {(c.params['sensor_choice'], c.params['target_choice']) for c in cases}
    assert drawn == {(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)}
    for c in cases:
        mid40 = c.params['sensor_choice'] == 1.0
        assert c.scenario.sensor.name == ('Livox Mid-40' if mid40 else 'Cepton Vista P-60')
        assert c.scenario.mesh_path.suffix == ('.glb' if c.params['target_choice'] else '.obj')
        # The Mid-40's own range error on every material; the P-60 keeps Table 2.
        sigma = set(c.scenario.materials.column('sigma_m'))
        assert (sigma == {0.02}) if mid40 else (0.02 not in sigma)
    cols = columns(campaign)
    assert {'stat.points.PIF', 'stat.points.SOLAR_ARRAY', 'param.sensor_choice',
            'param.target_choice'} <= set(cols)
    box_mid40 = next(i for i, c in enumerate(cases)
                     if (c.params['sensor_choice'], c.params['target_choice']) == (1.0, 1.0))
    row = run_one(campaign, box_mid40)
    assert row['status'] == 'ok', row['error']
    assert row['stat.points.SOLAR_ARRAY'] > 0 and 'stat.points.PIF' not in row


def test_bad_choices_name_their_key(tmp_path):
    with pytest.raises(ConfigError, match=r'dispersions\.sensor\.1.*not found'):
        load_campaign(write_campaign(tmp_path / 'a.yaml', dispersions={
            'sensor': [str(CONFIG / 'cepton_vista_p60.yaml'), 'nope.yaml']}))
    with pytest.raises(ConfigError, match=r'dispersions\.target\.0\.mesh_materials.*GOLD'):
        load_campaign(write_campaign(tmp_path / 'b.yaml', dispersions={
            'target': [{'mesh': str(CONFIG.parent / 'meshes' / 'box_wing_satellite.glb'),
                        'materials': str(CONFIG / 'materials_box_wing.yaml'),
                        'mesh_materials': {'bus_mli': 'GOLD'}}]}))
    with pytest.raises(ConfigError, match=r'dispersions\.materials\.PIF.*every target choice'):
        load_campaign(write_campaign(tmp_path / 'c.yaml', dispersions={
            'materials': {'PIF': {'bias_m': {'dist': 'uniform', 'low': -0.1, 'high': 0.0}}},
            'target': [{'mesh': str(CONFIG.parent / 'meshes' / 'box_wing_satellite.glb'),
                        'materials': str(CONFIG / 'materials_box_wing.yaml'),
                        'mesh_materials': 'MLI'}]}))


def test_specs_and_configs_without_the_new_keys_dump_as_before(tmp_path):
    """Campaigns are fingerprinted from their dumps: keys added later (the sensor and
    target choices, a sensor's range_error and flood, a scenario's mesh_materials) are
    left out when unused, so campaigns written before them resume."""
    campaign = load_campaign(write_campaign(tmp_path / 'c.yaml'))
    assert 'sensor' not in campaign.spec.model_dump()['dispersions']
    assert 'target' not in campaign.spec.model_dump_json()
    assert 'mesh_materials' not in campaign.scenario.config.model_dump()
    dumped = campaign.scenario.sensor.model_dump()
    assert 'range_error' not in dumped and 'flood' not in dumped['optics']
    from lidar_sim_ros.core.config import load_sensor
    assert load_sensor(CONFIG / 'livox_mid40.yaml').model_dump()['range_error']['sigma_m'] == 0.02


def test_a_target_choice_whose_mesh_cannot_be_read_stops_at_load(tmp_path):
    """A target choice's mesh was first read by the runs that drew it: an STL without a
    material, or a glTF with a cycle, failed those runs one by one (rc 1 after the
    campaign) instead of stopping at load with the key."""
    import trimesh
    stl = tmp_path / 'part.stl'
    trimesh.creation.box().export(stl)
    target = {'mesh': str(stl), 'materials': str(CONFIG / 'materials_box_wing.yaml')}
    with pytest.raises(ConfigError, match=r'dispersions\.target\.1\.mesh.*part.stl.*not mapped'):
        load_campaign(write_campaign(tmp_path / 'a.yaml', dispersions={
            'target': [{**target, 'mesh_materials': 'MLI'}, target]}))
    assert load_campaign(write_campaign(tmp_path / 'b.yaml', dispersions={
        'target': [{**target, 'mesh_materials': 'MLI'}]})).targets[0].mesh_path == stl
