"""Unit tests of the compare modules on small closed-form cases (no full pipeline)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose.features import FEATURE_NAMES, attribute, score_features
from lidar_sim_ros.compare.report.history import append_run, load_history
from lidar_sim_ros.compare.model.matching import EDGE_FAR, edge_distance_rad, predict_rays
from lidar_sim_ros.compare.recording.measurements import (Measurements, load_measurements,
                                                          padded_pose_track)
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.scan import directions_from_angles

from conftest import materials, plate_target, sensor
from datasets import EPOCH_NS, write_custom_cloud


# ------------------------------------------------------------------ features
def _feature_values(rng, n):
    return {'range': rng.uniform(8, 14, n), 'incidence': rng.uniform(0, 80, n),
            'intensity': rng.uniform(-3, 0, n), 'azimuth': rng.uniform(-30, 30, n),
            'elevation': rng.uniform(-11, 11, n), 'time': rng.uniform(0, 0.1, n),
            'material': rng.integers(0, 5, n), 'edge': rng.choice([0.75, 1.5, 24.0], n),
            'range_rate': rng.normal(0, 0.1, n),
            # its own generator: the draws of the tests after this stay as they were
            'laser': np.random.default_rng([7, n]).integers(0, 24, n)}


def test_feature_with_a_conditional_mean_ranks_first():
    rng = np.random.default_rng(3)
    values = _feature_values(rng, 6000)
    z = rng.standard_normal(6000) + 0.6 * (values['time'] - 0.05) / 0.029
    ranked = score_features(values, 0.03 * z, z)
    assert [f.name for f in ranked][0] == 'time'
    assert {f.name for f in ranked} == set(FEATURE_NAMES)
    top = ranked[0]
    # Gaussian information of a linear trend with slope 0.6 sd: 0.5 ln(1 + 0.36) ~ 0.15 nats,
    # alone (marginal) and given the others (score: nothing else carries it).
    assert top.marginal == pytest.approx(0.5 * np.log(1.36), rel=0.35)
    assert top.score == pytest.approx(0.5 * np.log(1.36), rel=0.35)
    assert top.mean_part > 10 * top.spread_part
    assert all(f.score < 0.01 for f in ranked[1:])


def test_a_feature_without_information_is_left_out_not_fatal():
    """range_rate all NaN (a target closing at 14 m/s: a foreign approach stopped
    compare with sklearn's "window shape cannot be larger than input array shape") and a
    constant elevation: both left out of the ranking; the time trend still ranks first."""
    rng = np.random.default_rng(5)
    values = _feature_values(rng, 3000)
    values['range_rate'] = np.full(3000, np.nan)
    values['elevation'] = np.full(3000, 2.5)
    z = rng.standard_normal(3000) + 0.6 * (values['time'] - 0.05) / 0.029
    att = attribute(values, 0.03 * z, z)
    names = [f.name for f in att.features]
    assert 'range_rate' not in names and 'elevation' not in names
    assert names[0] == 'time'


def test_a_per_laser_offset_ranks_laser_first():
    """A range offset per laser (24 lasers, 0.5 sigma RMS): laser explains it, given the
    others; the angles (independent of the laser here) do not."""
    rng = np.random.default_rng(8)
    values = _feature_values(rng, 6000)
    offsets = 0.5 * np.random.default_rng(9).standard_normal(24)
    z = rng.standard_normal(6000) + offsets[values['laser']]
    att = attribute(values, 0.03 * z, z)
    assert att.features[0].name == 'laser' and att.driver == 'laser'
    assert all(f.score < 0.01 for f in att.features[1:])


def test_the_driver_ranks_first_among_correlated_features():
    """Intensity drives the residual; incidence is correlated with it (rho ~ 0.9), as in
    a short pass at near-constant range. Alone both explain it; given the other, only
    the driver does, so it ranks first and is named the driver."""
    rng = np.random.default_rng(6)
    n = 8000
    values = _feature_values(rng, n)
    inc = rng.uniform(0, 80, n)
    values['incidence'] = inc
    values['intensity'] = -inc / 40.0 + rng.normal(0, 0.45, n)     # rho ~ -0.9
    z = rng.standard_normal(n) - 0.5 * (values['intensity'] - values['intensity'].mean())
    att = attribute(values, 0.03 * z, z)
    by = {f.name: f for f in att.features}
    assert att.features[0].name == 'intensity'
    assert att.driver == 'intensity'
    assert by['incidence'].marginal > 0.02             # it explains a lot alone ...
    assert by['incidence'].score < 0.2 * by['intensity'].score   # ... little given intensity


def test_features_that_stand_in_for_each_other_are_called_confounded():
    """Intensity is a function of incidence (no noise of its own): the residual's
    dependence cannot be pinned on either; the attribution says so."""
    rng = np.random.default_rng(7)
    n = 8000
    values = _feature_values(rng, n)
    inc = rng.uniform(0, 80, n)
    values['incidence'] = inc
    values['intensity'] = np.log10(np.cos(np.radians(inc)) + 0.05)
    z = rng.standard_normal(n) - 0.6 * (values['intensity'] - values['intensity'].mean()) / \
        values['intensity'].std()
    att = attribute(values, 0.03 * z, z)
    assert att.significant and att.driver is None
    assert {'intensity', 'incidence'} <= set(att.confounded)


def test_feature_with_a_conditional_spread_ranks_first():
    rng = np.random.default_rng(4)
    values = _feature_values(rng, 6000)
    # Noise growing 4 x from high to low intensity (an SNR effect).
    z = rng.standard_normal(6000) * (1.0 + (-values['intensity']))
    ranked = score_features(values, 0.03 * z, z)
    assert ranked[0].name == 'intensity'
    assert ranked[0].spread_part > 5 * ranked[0].mean_part
    assert 'spread shrinks' in ranked[0].trend


def test_pure_noise_scores_near_zero():
    rng = np.random.default_rng(5)
    values = _feature_values(rng, 6000)
    z = rng.standard_normal(6000)
    assert max(f.score for f in score_features(values, 0.03 * z, z)) < 0.004


# ---------------------------------------------------------------- edge probe
def _plate_measurements(az_rad: np.ndarray) -> tuple[Measurements, Simulator]:
    """Rays toward a 4 m plate facing the sensor 10 m away, static pose."""
    n = len(az_rad)
    q = Rotation.from_euler('y', -90, degrees=True).as_quat()     # body +z -> lidar -x
    track = padded_pose_track(np.array([0.0, 1.0]), np.array([[10.0, 0, 0]] * 2),
                              np.array([q, q]), 0.5)
    dirs = directions_from_angles(az_rad, np.zeros(n))
    meas = Measurements(bag=None, xyz_m=dirs * 10, range_m=np.full(n, 10.0), directions=dirs,
                        intensity=None, t_s=np.full(n, 0.5), t_frame_s=np.zeros(n),
                        cloud=np.zeros(n, int), laser=np.zeros(n, np.uint16),
                        has_point_time=True, cloud_stamps_s=np.zeros(1), epoch_s=0.0,
                        poses=track, material_names=None)
    sim = Simulator(sensor(), materials(), plate_target(4.0))
    return meas, sim


def test_edge_distance_on_a_plate_matches_its_geometry():
    div = 1e-3
    edge = np.arctan(0.2)                  # plate edge at y = 2 m, x = 10 m
    az = np.array([0.0, edge - 0.0025, edge + 0.0025, edge - 0.0007])
    meas, sim = _plate_measurements(az)
    pred = predict_rays(sim, meas)
    assert list(pred.ctx.hit) == [True, True, False, True]
    dist = edge_distance_rad(sim.target, meas, pred, div)
    # Rings at 0.5, 1, 2, 4, 8 mrad: the first to cross the edge 2.5 mrad away is 4 mrad,
    # 0.7 mrad away is 1 mrad; the plate centre sees no edge within 8 mrad.
    assert dist == pytest.approx([EDGE_FAR * div, 4e-3, 4e-3, 1e-3])


# ------------------------------------------------------------------- history
def test_history_appends_and_rejects_a_foreign_file(tmp_path):
    path = tmp_path / 'history.json'
    append_run(path, {'effects': [], 'range_rmse_m': 0.05})
    runs = append_run(path, {'effects': ['range_walk'], 'range_rmse_m': 0.03})
    assert [r['effects'] for r in load_history(path)] == [[], ['range_walk']] == \
        [r['effects'] for r in runs]
    assert all('timestamp' in r for r in runs)
    path.write_text('{not json')
    with pytest.raises(ValueError, match='history.json'):
        append_run(path, {})


# -------------------------------------------------------------- measurements
def _bag(tmp_path, points_per_cloud, t_values, pose_times_s, cloud_times_s, t_dtype='<f4',
         t_name='t'):
    from lidar_sim_ros.io.bag import BagWriter
    bag = tmp_path / 'bag'
    with BagWriter(bag) as w:
        for t in pose_times_s:
            w.write_pose('/target/pose', EPOCH_NS + int(round(t * 1e9)), 'lidar',
                         [10.0, 0, 0], [0, 0, 0, 1])
        for stamp in cloud_times_s:
            pts = np.zeros(points_per_cloud, dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'),
                                                    (t_name, t_dtype)])
            pts['x'] = 10.0
            pts[t_name] = t_values(stamp) if callable(t_values) else t_values
            write_custom_cloud(w, '/lidar/points', pts, EPOCH_NS + int(round(stamp * 1e9)))
    return bag


def test_poses_once_per_cloud_cover_the_last_cloud_by_extrapolation(tmp_path):
    t = np.linspace(0, 0.099, 4)
    bag = _bag(tmp_path, 4, t, [0.0, 0.1, 0.2], [0.0, 0.1, 0.2])
    meas = load_measurements(bag)
    assert len(meas) == 12
    assert meas.t_s[-1] == pytest.approx(0.2 + 0.099)
    assert any('past the last pose' in n for n in meas.notes)
    assert meas.poses.at(meas.t_s).position_m[:, 0] == pytest.approx(np.full(12, 10.0))


@pytest.mark.parametrize('poses, sparse', [
    (np.arange(0.0, 1.2, 0.01), False),                 # 100 Hz: 10 per frame
    (np.arange(0.0, 1.2, 0.02), False),                 # 50 Hz: 5 per frame, as the docs ask
    (np.arange(0.0, 1.3, 0.25), True),                  # 4 Hz
    (np.r_[np.arange(0.0, 0.3, 0.01), np.arange(1.1, 1.2, 0.01)], True),   # 0.29 -> 1.1 s: a gap
])
def test_a_pose_stream_sparser_than_five_per_frame_is_said(tmp_path, poses, sparse):
    """Holdout 10: 4 Hz poses and a 0.8 s gap in a spin-up gave a pose error blamed on
    the extrinsic calibration with no word of the stream; the interpolation made it."""
    t = np.linspace(0, 0.099, 4)
    clouds = np.arange(0.0, 1.0, 0.1)
    meas = load_measurements(_bag(tmp_path, 4, t, list(poses), list(clouds)))
    said = [n for n in meas.notes if 'sparser than 5 per frame' in n]
    assert bool(said) == sparse
    if sparse and poses[1] - poses[0] < 0.1:
        assert 'of 10 cloud(s)' in said[0] and 'longest interval between samples 810 ms' in said[0]


def test_integer_point_times_in_nanoseconds_are_read_as_seconds(tmp_path):
    t_ns = np.array([0, 25_000_000, 50_000_000, 75_000_000], np.uint32)
    bag = _bag(tmp_path, 4, t_ns, [0.0, 0.2], [0.0], t_dtype='<u4')
    meas = load_measurements(bag)
    assert meas.t_frame_s == pytest.approx([0.0, 0.025, 0.05, 0.075])
    assert any('read as ns' in n for n in meas.notes)


@pytest.mark.parametrize('name, dtype, values, read_as', [
    ('time', '<f4', lambda stamp: [0.0, 0.025, 0.05, 0.075], 's since stamp'),
    ('t_ns', '<u4', lambda stamp: [0, 25_000_000, 50_000_000, 75_000_000], 'ns since stamp'),
    ('offset_time', '<u4', lambda stamp: [0, 25_000_000, 50_000_000, 75_000_000],
     'ns since stamp'),
    # Hesai/Robosense style: absolute float64 epoch seconds, stamp at scan start.
    ('timestamp', '<f8', lambda stamp: EPOCH_NS / 1e9 + stamp + np.array([0, 0.025, 0.05, 0.075]),
     'absolute s'),
    # Absolute seconds on another clock (device uptime): the earliest point is the stamp.
    ('Timestamp', '<f8', lambda stamp: 5.0e5 + stamp + np.array([0, 0.025, 0.05, 0.075]),
     'absolute s on another clock (cloud stamp = first point)'),
])
def test_point_times_under_other_field_names_and_units(tmp_path, name, dtype, values, read_as):
    bag = _bag(tmp_path, 4, values, [0.0, 0.1, 0.3], [0.0, 0.1], t_dtype=dtype, t_name=name)
    meas = load_measurements(bag)
    assert meas.time_source == 'field'
    assert meas.time_field['name'] == name and meas.time_field['read_as'] == [read_as]
    assert meas.t_frame_s == pytest.approx([0.0, 0.025, 0.05, 0.075] * 2, abs=1e-6)
    assert meas.t_s[4:] == pytest.approx(0.1 + np.array([0.0, 0.025, 0.05, 0.075]), abs=1e-6)


@pytest.mark.parametrize('name, dtype, step', [('timestamp', '<f4', '128 s'),
                                                ('time_ms', '<f4', '131.072 s')])
def test_absolute_times_in_a_type_too_coarse_are_refused(tmp_path, name, dtype, step):
    # FLOAT32 epoch seconds step by 128 s at 1.7e9: read as times they were extrapolated
    # 30 s past the poses and crashed the pose re-cast (a holdout), rc 1.
    from lidar_sim_ros.compare.recording.measurements import MeasurementError
    scale = 1e3 if name.endswith('_ms') else 1.0
    bag = _bag(tmp_path, 4, lambda stamp: scale * (EPOCH_NS / 1e9 + stamp
                                                   + np.array([0, 0.025, 0.05, 0.075])),
               [0.0, 0.1, 0.3], [0.0, 0.1], t_dtype=dtype, t_name=name)
    with pytest.raises(MeasurementError, match=f"cloud #0: {name} holds absolute clock "
                       rf"readings .* in float32, whose steps there are {step}"):
        load_measurements(bag)


def test_absolute_times_spread_beyond_one_frame_are_refused(tmp_path):
    from lidar_sim_ros.compare.recording.measurements import MeasurementError
    bag = _bag(tmp_path, 4, lambda stamp: EPOCH_NS / 1e9 + stamp + np.array([0, 0.025, 0.05, 30.0]),
               [0.0, 0.1, 0.3], [0.0, 0.1], t_dtype='<f8', t_name='timestamp')
    with pytest.raises(MeasurementError, match='spread over 30 s in one cloud'):
        load_measurements(bag)


def test_cloud_without_a_time_field_keeps_the_stamp_and_says_so(tmp_path):
    bag = _bag(tmp_path, 4, [0.0, 1.0, 2.0, 3.0], [0.0, 0.2], [0.0], t_name='intensity')
    meas = load_measurements(bag)
    assert meas.time_source == 'stamp' and meas.time_field is None
    assert meas.t_frame_s == pytest.approx(np.zeros(4))
    assert any('no per-point time field' in n for n in meas.notes)


def test_every_feature_the_attribution_can_rank_is_plottable():
    """The report plots the top features: each one ranked first draws (range_rate crashed it)."""
    from lidar_sim_ros.compare.diagnose.features import LABELS
    from lidar_sim_ros.compare.report.page import features_figure
    assert set(LABELS) == set(FEATURE_NAMES)
    rng = np.random.default_rng(5)
    values = _feature_values(rng, 3000)
    z = rng.standard_normal(3000)
    ranked = score_features(values, 0.03 * z, z)
    assert {f.name for f in ranked} == set(FEATURE_NAMES)
    for first in ranked:
        order = [first] + [f for f in ranked if f is not first]
        png = features_figure(order, values, 0.03 * z, ['PIF', 'MLI', 'PAF', 'PSS', 'NOZZLE'], top=2)
        assert png[:8] == b'\x89PNG\r\n\x1a\n', first.name


def test_headline_says_how_many_points_were_analysed():
    from lidar_sim_ros.compare.report.verdict import summary_lines
    s = dict(points=438420, points_analysed=300000, matched_points=300000,
             unmatched_points=0, unmatched_fraction=0.0, range_rmse_m=0.01, nll_per_point=-1.0,
             range_rmse_calibrated_m=0.01, nll_calibrated=-1.0, fitted_effects=[],
             features=[], candidates=[], missing_effect=None, verdict='v')
    assert summary_lines(s, [])[0].startswith('points: 438420, 300000 analysed (--max-points)')
    s['points'] = 300000
    assert summary_lines(s, [])[0] == 'points: 300000 (300000 matched, 0 unmatched = 0.00 %)'


def test_history_keeps_one_basis_for_runs_with_and_without_fit():
    """A run's history entry carries the calibrated figures (materials profiled in every
    run), and the figure draws runs recorded before that on their headline."""
    from lidar_sim_ros.compare.report import history
    from lidar_sim_ros.compare.report.page import history_figure
    summary = dict(points=10, range_rmse_m=0.05, nll_per_point=-1.2,
                   range_rmse_calibrated_m=0.03, nll_calibrated=-1.8, materials_refit=False,
                   unmatched_fraction=0.0, missing_effect=None)
    entry = history.run_entry(summary, [], 'out', 'bag')
    assert entry['nll_calibrated'] == -1.8 and entry['range_rmse_calibrated_m'] == 0.03
    old = {k: v for k, v in entry.items() if 'calibrated' not in k}
    png = history_figure([old, entry, {**entry, 'effects': ['range_walk']}])
    assert png[:8] == b'\x89PNG\r\n\x1a\n'
