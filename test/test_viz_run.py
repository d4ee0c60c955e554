"""Tests for lidar_sim_ros/viz/run.py: the whole-run figures and the scenario line."""
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.io.bag import BagWriter, PoseSeries
from lidar_sim_ros.io.pointcloud import make_points
from lidar_sim_ros.viz import run as vrun
from lidar_sim_ros.viz.figures import render_bag_figures

T0_NS = 1_700_000_000_000_000_000
NAMES = ['PIF', 'MLI', 'NOZZLE']


def truth_frame(n: int = 600, seed: int = 0):
    """A truth cloud: shots on a wall at 8-12 m, rings 0-23, time in frame per shot."""
    rng = np.random.default_rng(seed)
    az = np.radians(rng.uniform(-20, 20, n))
    el = np.radians(rng.uniform(-8, 8, n))
    r = rng.uniform(8, 12, n)
    d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    t = (np.arange(n) // 24) * 1e-4  # 24 lasers fire at once: a shot is ring and time
    ring = (np.arange(n) % 24).astype(np.uint16)
    material = (np.arange(n) % 3).astype(np.uint8)
    intensity = rng.uniform(1e-3, 0.5, n)
    return d, r, t, ring, material, intensity


def test_range_error_per_material_is_the_offset_each_material_was_given():
    """Detected = a shuffled subset of the truth shots moved along their ray by a known
    offset per material; one false return (material 255) is left out of the statistics."""
    d, r, t, ring, mat, inten = truth_frame()
    truth = make_points(d * r[:, None], inten, t, ring, mat)
    offset = np.array([-0.14, 0.05, 0.30])
    keep = np.random.default_rng(1).permutation(len(r))[:400]
    meas_r = r[keep] + offset[mat[keep]]
    det_mat = mat[keep].copy()
    det_mat[0] = 255
    points = make_points(d[keep] * meas_r[:, None], inten[keep], t[keep], ring[keep], det_mat)
    run = vrun.RunRecord('x/bag', T0_NS, [vrun.CloudFrame(T0_NS, 'lidar', points)],
                         [vrun.CloudFrame(T0_NS, 'lidar', truth)], None, None)
    errors = vrun.range_errors_by_material(run)
    assert sorted(errors) == [0, 1, 2]
    assert sum(len(e) for e in errors.values()) == 399
    for m in range(3):
        np.testing.assert_allclose(errors[m], offset[m], atol=2e-5)  # float32 points


def test_match_truth_by_ring_and_time():
    d, r, t, ring, mat, inten = truth_frame(50)
    truth = make_points(d * r[:, None], inten, t, ring, mat)
    picked = np.array([7, 3, 49, 0])
    points = truth[picked]
    other = make_points(np.ones((1, 3)), 0.1, 0.5, 2, 0)  # a time no truth shot has
    idx = vrun.match_truth(np.concatenate([points, other]), truth)
    assert idx.tolist() == [7, 3, 49, 0, -1]


def test_dropouts_are_classified_by_the_truth_intensity():
    d, r, t, ring, mat, _ = truth_frame(6)
    inten = np.array([0.2, 1e-6, 1.5, 0.3, 2.0, 1e-7])  # received / saturation power
    truth = make_points(d * r[:, None], inten, t, ring, mat)
    detected = truth[[0, 3]]
    assert vrun.classify_shots(detected, truth).tolist() == [0, 1, 2, 0, 2, 1]


def test_tumble_rate_and_scenario_caption():
    """6 deg/s about a tilted axis, poses every 10 ms; target at (3, 4, 0) m; sun along +y."""
    t_s = np.arange(0, 1.0, 0.01)
    axis = np.array([0.2, 0.0, 1.0]) / np.linalg.norm([0.2, 0.0, 1.0])
    rot = Rotation.from_rotvec(np.radians(6.0) * t_s[:, None] * axis)
    stamps = T0_NS + np.rint(t_s * 1e9).astype(np.int64)
    poses = PoseSeries(stamps, 'lidar', np.tile([3.0, 4.0, 0.0], (len(t_s), 1)), rot.as_quat())
    assert vrun.tumble_rate_dps(poses) == pytest.approx(6.0, rel=1e-6)
    sun = vrun.VectorSeries(stamps[:1], 'lidar', np.array([[0.0, 2.0, 0.0]]))
    run = vrun.RunRecord('x/bag', T0_NS, [], [], poses, sun)
    caption = vrun.scenario_caption(run, T0_NS)
    assert caption == ('range 5.00 m, attitude r/p/y 0/0/0 deg, tumble 6.0 deg/s, '
                       'sun at az 90, el 0 deg')
    no_sun = vrun.RunRecord('x/bag', T0_NS, [], [], None, None)
    assert vrun.scenario_caption(no_sun, T0_NS) == 'no target pose recorded, no sun'


@pytest.fixture(scope='module')
def run_bag(tmp_path_factory) -> Path:
    """Three frames 0.1 s apart with truth and poses, poses starting 50 ms before the first
    cloud: the run starts at the first pose."""
    path = tmp_path_factory.mktemp('run') / 'flight_03' / 'bag'
    with BagWriter(path) as bag:
        bag.write_material_names('/lidar/material_names', T0_NS, NAMES)
        for k in range(8):
            bag.write_pose('/target/pose', T0_NS + k * 50_000_000, 'lidar', np.array([10.0, 0, 0]),
                           np.array([0.0, 0.0, 0.0, 1.0]))
        for i in range(3):
            d, r, t, ring, mat, inten = truth_frame(seed=i)
            inten[:5] = 2.0  # saturated: dropped
            stamp = T0_NS + 50_000_000 + i * 100_000_000
            truth = make_points(d * r[:, None], inten, t, ring, mat)
            bag.write_cloud('/lidar/points', truth[5:], stamp, 'lidar')
            bag.write_cloud('/lidar/points_truth', truth, stamp, 'lidar')
    return path


def test_bag_run_figures_and_relative_time(tmp_path, run_bag):
    paths = render_bag_figures(run_bag, tmp_path)
    assert [p.stem for p in paths][-3:] == ['run', 'range_error', 'dropouts']
    assert all(p.stat().st_size > 20_000 for p in paths)
    run = vrun.read_run(run_bag)
    assert run.source == 'flight_03'  # the recording's folder: its bag is just "bag"
    label = vrun.frame_label(run, 2)
    assert label.startswith('flight_03: frame 3 of 3, t = 0.25 s into the run\n')
    assert 'range 10.00 m' in label and 'tumble 0.0 deg/s' in label
