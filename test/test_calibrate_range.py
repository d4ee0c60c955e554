"""Tests for lidar_sim_ros/calibrate/range_errors.py: bias and sigma per material and distance.

The lab data is made by the simulator itself: a flat plate of two materials with
KNOWN bias/sigma, static at 5, 10 and 15 m (paper Sec. 6: 2-25 m, Table 2 at 5 and
15 m), 4 frames each, plus stray points that miss the target. Stated tolerances:
per distance bin, bias and sigma within 4 standard errors of the truth (at most
~5 mm and 11 % with the ~1800 points of a material at 15 m); the written
(bin-averaged) bias_m within 2 mm and sigma_m within 5 %.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros import cli
from lidar_sim_ros.calibrate.range_errors import (CalibrationInputError, distance_bins,
                                                  run_range_errors)
from lidar_sim_ros.core.config import MaterialsConfig, load_materials, load_sensor, parse
from lidar_sim_ros.core.geometry import MeshMaterialError, load_target
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import PoseTrack
from lidar_sim_ros.io.bag import BagWriter
from lidar_sim_ros.io.pointcloud import make_points
from lidar_sim_ros.paths import config_path

TRUTH = {'PLATE_A': dict(kd=0.5, ks=0.0, n=1.0, bias_m=-0.14, sigma_m=0.025),
         'PLATE_B': dict(kd=0.3, ks=0.1, n=5.0, bias_m=-0.11, sigma_m=0.04)}
DISTANCES_M = (5.0, 10.0, 15.0)
FRAMES_PER_DISTANCE = 4
STRAY_PER_FRAME = 40
TILT = Rotation.from_euler('z', 20, degrees=True)  # keeps specular PLATE_B off saturation


def write_plate(folder: Path) -> Path:
    """2 m x 2 m plate in the body y-z plane: PLATE_A at y > 0, PLATE_B at y < 0."""
    obj = ['mtllib plate.mtl', 'v 0 -1 -1', 'v 0 0 -1', 'v 0 0 1', 'v 0 -1 1', 'v 0 1 -1', 'v 0 1 1',
           'o PLATE_B', 'g PLATE_B', 'usemtl PLATE_B', 'f 1 2 3', 'f 1 3 4',
           'o PLATE_A', 'g PLATE_A', 'usemtl PLATE_A', 'f 2 5 6', 'f 2 6 3']
    (folder / 'plate.obj').write_text('\n'.join(obj) + '\n')
    (folder / 'plate.mtl').write_text('newmtl PLATE_A\nKd 0.8 0.8 0.8\nnewmtl PLATE_B\nKd 0.4 0.4 0.4\n')
    return folder / 'plate.obj'


def materials_yaml(folder: Path) -> Path:
    lines = ['materials:'] + [
        f'  - {{name: {k}, kd: {v["kd"]}, ks: {v["ks"]}, n: {v["n"]}, bias_m: 0.0, sigma_m: 0.01}}'
        for k, v in TRUTH.items()]
    (folder / 'materials.yaml').write_text('\n'.join(lines) + '\n')
    return folder / 'materials.yaml'


def simulate_frames(mesh: Path):
    """(stamp_ns, pose, points) of every frame; the simulator adds the known errors."""
    mats = parse(MaterialsConfig, {'materials': [{'name': k, **v} for k, v in TRUTH.items()]}, 'truth')
    sim = Simulator(load_sensor(config_path('cepton_vista_p60.yaml')), mats,
                    load_target(mesh, mats.names), seed=11)
    rng = np.random.default_rng(4)
    q = TILT.as_quat()
    frames, index = [], 0
    for seg, d in enumerate(DISTANCES_M):
        t_seg = 10.0 * (seg + 1)
        track = PoseTrack([t_seg], [[d, 0.0, 0.0]], [q], max_extrapolation_s=5.0)
        for k in range(FRAMES_PER_DISTANCE):
            t = t_seg + 0.1 * (k + 1)
            fr = sim.simulate_frame(t, track, index)
            index += 1
            # stray returns from the lab (walls left and right of the plate): miss the mesh
            az = np.radians(rng.uniform(15.0, 28.0, STRAY_PER_FRAME)) * rng.choice([-1, 1], STRAY_PER_FRAME)
            el = np.radians(rng.uniform(-10.0, 10.0, STRAY_PER_FRAME))
            stray = 30.0 * np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            xyz = np.vstack([fr.xyz_m, stray])
            pts = make_points(xyz, np.concatenate([fr.intensity, np.full(STRAY_PER_FRAME, 0.01)]),
                              np.concatenate([fr.t_s, np.zeros(STRAY_PER_FRAME)]),
                              np.concatenate([fr.ring, np.zeros(STRAY_PER_FRAME, np.uint16)]),
                              np.concatenate([fr.material, np.full(STRAY_PER_FRAME, 255, np.uint8)]))
            frames.append((int(round(t * 1e9)), (int(t_seg * 1e9), [d, 0.0, 0.0], q), pts))
    return frames


def write_bag(path: Path, frames, slope_material: int | None = None, slope: float = 0.0,
              poses: bool = True) -> Path:
    """The bag; optionally a range error growing by ``slope`` m per m for one material."""
    with BagWriter(path) as bag:
        bag.write_cloud('/lidar/points', frames[0][2][:10], 10**9, 'lidar')  # before any pose
        written = set()
        for stamp, (pose_ns, pos, q), pts in frames:
            if poses and pose_ns not in written:
                bag.write_pose('/target/pose', pose_ns, 'lidar', pos, q)
                written.add(pose_ns)
            if slope_material is not None:
                pts = pts.copy()
                sel = pts['material'] == slope_material
                xyz = np.column_stack([pts['x'], pts['y'], pts['z']])[sel].astype(float)
                r = np.linalg.norm(xyz, axis=1)
                scaled = xyz * ((r + slope * r) / r)[:, None]
                pts['x'][sel], pts['y'][sel], pts['z'][sel] = scaled.T
            bag.write_cloud('/lidar/points', pts, stamp, 'lidar')
    return path


@pytest.fixture(scope='module')
def lab(tmp_path_factory):
    folder = tmp_path_factory.mktemp('range')
    mesh = write_plate(folder)
    frames = simulate_frames(mesh)
    return dict(folder=folder, mesh=mesh, materials=materials_yaml(folder), frames=frames,
                bag=write_bag(folder / 'static', frames))


@pytest.fixture(scope='module')
def calibrated(lab):
    return run_range_errors(lab['bag'], lab['mesh'], lab['folder'] / 'out.yaml',
                            materials=lab['materials'])


def test_bias_and_sigma_recovered_per_material_and_distance(calibrated):
    assert set(calibrated.per_bin) == set(TRUTH)
    for name, rows in calibrated.per_bin.items():
        assert [round(r.distance_m) for r in rows] == [5, 10, 15]
        sigma = TRUTH[name]['sigma_m']
        for r in rows:
            assert r.n > 1000
            # 4 standard errors of each estimator, from the true sigma and the bin's n
            se_median, se_mean = 1.2533 * sigma / np.sqrt(r.n), sigma / np.sqrt(r.n)
            assert abs(r.bias_median_m - TRUTH[name]['bias_m']) <= 4 * se_median, (name, r)
            assert abs(r.bias_mean_m - TRUTH[name]['bias_m']) <= 4 * se_mean, (name, r)
            assert abs(r.sigma_robust_m / sigma - 1) <= 4 * 1.166 / np.sqrt(r.n), (name, r)
            assert abs(r.sigma_std_m / sigma - 1) <= 4 * 0.7071 / np.sqrt(r.n), (name, r)
            # the reported 95 % interval covers the truth (at 2 x, for 12 intervals)
            assert abs(r.bias_median_m - TRUTH[name]['bias_m']) <= 2 * r.bias_ci_m


def test_materials_yaml_written_with_measured_errors(calibrated):
    mats = load_materials(calibrated.out)
    for name, truth in TRUTH.items():
        m = mats.materials[mats.index(name)]
        assert abs(m.bias_m - truth['bias_m']) <= 0.002
        assert abs(m.sigma_m / truth['sigma_m'] - 1) <= 0.05
        assert (m.kd, m.ks, m.n) == (truth['kd'], truth['ks'], truth['n'])  # untouched


def test_ray_matching_finds_the_simulated_material_and_drops_strays(calibrated, lab):
    c = calibrated.matched.counts
    n_frames = len(DISTANCES_M) * FRAMES_PER_DISTANCE
    assert c['frames'] == n_frames + 1 and c['frames_no_pose'] == 1
    assert c['points_missed'] == n_frames * STRAY_PER_FRAME
    simulated = np.concatenate([f[2]['material'][:-STRAY_PER_FRAME] for f in lab['frames']])
    assert c['points_used'] + c['points_gated'] == len(simulated)
    assert c['points_gated'] < 0.001 * len(simulated)
    # the materials decoded by casting each point's ray agree with what the simulator hit
    per_material = np.bincount(calibrated.matched.material, minlength=2)
    np.testing.assert_allclose(per_material, np.bincount(simulated, minlength=2), rtol=0.01)


def test_verdict_no_distance_dependence(calibrated):
    for test in calibrated.tests.values():
        assert test.bias_depends is False and test.sigma_depends is False
        assert test.slope_ci_m_per_m > 0 and abs(test.slope_m_per_m) < 0.001
    assert "the paper's conclusion holds" in calibrated.report


def test_verdict_detects_a_distance_dependent_bias(lab, tmp_path):
    """PLATE_B's error grows 4 mm per metre (4 cm over 5-15 m): dependence declared, A not."""
    bag = write_bag(tmp_path / 'walk', lab['frames'], slope_material=1, slope=0.004)
    cal = run_range_errors(bag, lab['mesh'], tmp_path / 'out.yaml', materials=lab['materials'])
    b = cal.tests['PLATE_B']
    assert b.bias_depends is True
    assert abs(b.slope_m_per_m - 0.004) < 3 * b.slope_ci_m_per_m + 1e-4
    assert abs(b.bias_change_m - 0.04) < 0.005
    assert cal.tests['PLATE_A'].bias_depends is False
    assert 'does NOT hold for PLATE_B' in cal.report
    assert any('PLATE_B' in w and 'depends on distance' in w for w in cal.warnings)


def test_distance_bins_split_on_gaps():
    np.testing.assert_array_equal(distance_bins(np.array([5.0, 15.2, 5.1, 14.9, 10.0]), 1.0),
                                  [0, 2, 0, 2, 1])


def test_cli_with_figure(lab, tmp_path, capsys):
    out, png = tmp_path / 'm.yaml', tmp_path / 'range.png'
    rc = cli.main(['calibrate', 'range-errors', str(lab['bag']), '--mesh', str(lab['mesh']),
                   '--materials', str(lab['materials']), '--out', str(out), '--figure', str(png)])
    assert rc == 0 and png.read_bytes()[:4] == b'\x89PNG' and png.stat().st_size > 10_000
    text = capsys.readouterr().out
    assert 'does the range error depend on distance?' in text and 'PLATE_A' in text
    assert load_materials(out).names == list(TRUTH)


# ----------------------------------------------------------------- bad input
def test_missing_pose_topic_names_topic(lab, tmp_path):
    bag = write_bag(tmp_path / 'nopose', lab['frames'][:2], poses=False)
    with pytest.raises(CalibrationInputError, match="no topic '/target/pose'") as err:
        run_range_errors(bag, lab['mesh'], tmp_path / 'o.yaml', materials=lab['materials'])
    # the same hint as lidar-sim compare's
    assert str(err.value).endswith('(choose the topics with --cloud-topic / --pose-topic)')


def test_mesh_with_unknown_materials_is_an_error(lab, tmp_path):
    with pytest.raises(MeshMaterialError, match=r"PLATE_A.*--materials"):
        run_range_errors(lab['bag'], lab['mesh'], tmp_path / 'o.yaml')  # default materials


def test_wrong_pose_means_no_hits(lab, tmp_path):
    frames = [(s, (p, [-d for d in pos], q), pts) for s, (p, pos, q), pts in lab['frames'][:3]]
    bag = write_bag(tmp_path / 'behind', frames)
    with pytest.raises(CalibrationInputError, match='no point hits the mesh'):
        run_range_errors(bag, lab['mesh'], tmp_path / 'o.yaml', materials=lab['materials'])


def test_too_few_points_is_an_error(lab, tmp_path):
    frames = [(s, pose, pts[:20]) for s, pose, pts in lab['frames'][:2]]
    bag = write_bag(tmp_path / 'few', frames)
    with pytest.raises(CalibrationInputError, match='record more frames'):
        run_range_errors(bag, lab['mesh'], tmp_path / 'o.yaml', materials=lab['materials'])


def test_one_bag_per_distance_gives_the_same_result(lab, tmp_path, calibrated):
    bags = []
    for i in range(len(DISTANCES_M)):
        part = lab['frames'][i * FRAMES_PER_DISTANCE:(i + 1) * FRAMES_PER_DISTANCE]
        bags.append(write_bag(tmp_path / f'd{i}', part))
    cal = run_range_errors(bags, lab['mesh'], tmp_path / 'o.yaml', materials=lab['materials'])
    assert cal.written == calibrated.written
    assert cal.matched.counts['points_used'] == calibrated.matched.counts['points_used']


def test_frame_with_the_target_moving_is_skipped(lab, tmp_path):
    frames = lab['frames'][:FRAMES_PER_DISTANCE]
    (pose_ns, pos, q) = frames[0][1]
    with BagWriter(tmp_path / 'moving') as bag:
        bag.write_pose('/target/pose', pose_ns, 'lidar', pos, q)
        for stamp, _, pts in frames:
            bag.write_cloud('/lidar/points', pts, stamp, 'lidar')
        # the target is pushed 0.5 m during the last frame
        bag.write_pose('/target/pose', frames[-1][0] + 50_000_000, 'lidar',
                       [pos[0] + 0.5, pos[1], pos[2]], q)
    cal = run_range_errors(tmp_path / 'moving', lab['mesh'], tmp_path / 'o.yaml',
                           materials=lab['materials'])
    assert cal.matched.counts['frames_moving'] == 1
    assert len(np.unique(cal.matched.frame)) == FRAMES_PER_DISTANCE - 1


def test_per_laser_offsets_from_a_cepton_layout_bag(lab, tmp_path):
    """The P-60's 24 lasers each read long or short by their own offset; the bag is in the
    Cepton driver's layout (channel_id, timestamp_s + timestamp_us, NO_RETURN points)."""
    from lidar_sim_ros.io.cepton import NO_RETURN, cepton_points
    offsets = 0.02 * np.sin(np.arange(24) * 1.7)
    offsets -= offsets.mean()
    path = tmp_path / 'cepton_static'
    with BagWriter(path) as bag:
        written = set()
        for stamp, (pose_ns, pos, q), pts in lab['frames']:
            if pose_ns not in written:
                bag.write_pose('/target/pose', pose_ns, 'cepton3', pos, q)
                written.add(pose_ns)
            xyz = np.column_stack([pts['x'], pts['y'], pts['z']]).astype(float)
            r = np.linalg.norm(xyz, axis=1)
            xyz *= ((r + offsets[pts['ring']]) / r)[:, None]
            xyz = np.vstack([xyz, np.zeros((5, 3))])           # five shots with no return
            n = len(xyz)
            t_ns = stamp + np.round(np.append(pts['t'], np.zeros(5)) * 1e9).astype(np.int64)
            flags = np.append(np.zeros(len(pts), np.uint16), np.full(5, NO_RETURN, np.uint16))
            bag.write_cloud('/cepton_pcl2', cepton_points(
                xyz, np.full(n, 0.3), t_ns, flags, np.append(pts['ring'], np.zeros(5, np.uint16))),
                stamp, 'cepton3')
    cal = run_range_errors(path, lab['mesh'], tmp_path / 'out.yaml', materials=lab['materials'],
                           cloud_topic='/cepton_pcl2')
    # The plate fills the central tiles only: the lasers that saw it.
    seen = [x.laser for x in cal.lasers]
    assert len(seen) >= 4 and all(x.n >= 100 for x in cal.lasers), [(x.laser, x.n) for x in cal.lasers]
    n = np.array([x.n for x in cal.lasers])
    got = np.array([x.offset_m for x in cal.lasers])
    true = offsets[seen]
    # Their common mean sits in the material biases: compare about the point-weighted mean.
    err = (got - np.average(got, weights=n)) - (true - np.average(true, weights=n))
    assert np.all(np.abs(err) < 0.01), err
    assert np.all(np.abs(err) <= 2 * np.array([x.ci_m for x in cal.lasers])), err
    assert 'range offset per laser' in cal.report and '{name: laser_bias' in cal.report
    assert 'point layout: cepton sdk3 driver' in cal.report
    assert 'channel_id (UINT16): laser id' in cal.report
