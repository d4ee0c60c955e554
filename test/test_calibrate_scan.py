"""Tests for lidar_sim_ros/calibrate/scan_pattern.py: per-laser Lissajous fit from measured shots.

Measured data is the scan model itself (core.scan.frame_shots) with KNOWN perturbed
per-laser parameters (frequencies +-4 / +-2 Hz, random phases, centres +-0.2 deg,
amplitudes +-5 %), 0.01 deg angular noise per axis and 20 % dropped shots, three
frames. Stated tolerances (about 10x the estimation error): centres and amplitudes
within 0.005 deg, frequencies within 0.01 Hz, phases within 0.005 rad; the angular
error per shot of the fit is the injected noise (RMS within 10 % of
0.01 deg x sqrt(2)).
"""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from lidar_sim_ros import cli
from lidar_sim_ros.calibrate.scan_pattern import (CalibrationInputError, fit_sine,
                                                  read_scan_samples, run_scan)
from lidar_sim_ros.core.config import SensorConfig, load_sensor, parse, read_yaml
from lidar_sim_ros.core.scan import (directions_from_angles, frame_shots, lissajous_angles,
                                     lissajous_lasers)
from lidar_sim_ros.io.bag import BagWriter
from lidar_sim_ros.io.pointcloud import FLOAT32, make_points, ns_to_stamp
from lidar_sim_ros.paths import config_path

NOISE_DEG = 0.01
KEYS = ('center_az_deg', 'center_el_deg', 'amp_az_deg', 'amp_el_deg', 'freq_az_hz', 'freq_el_hz',
        'phase_az_rad', 'phase_el_rad')
TOL = {'center_az_deg': 0.005, 'center_el_deg': 0.005, 'amp_az_deg': 0.005, 'amp_el_deg': 0.005,
       'freq_az_hz': 0.01, 'freq_el_hz': 0.01, 'phase_az_rad': 0.005, 'phase_el_rad': 0.005}
T0_NS = 1_700_000_000_000_000_000


def truth_document(seed: int = 5) -> dict:
    """The shipped sensor with every laser's Lissajous parameters perturbed."""
    doc = read_yaml(config_path('cepton_vista_p60.yaml'))
    base = lissajous_lasers(load_sensor(config_path('cepton_vista_p60.yaml')).scan)
    rng = np.random.default_rng(seed)
    doc['scan']['lasers'] = [
        {'center_az_deg': float(np.degrees(base.center_az_rad[i]) + rng.normal(0, 0.2)),
         'center_el_deg': float(np.degrees(base.center_el_rad[i]) + rng.normal(0, 0.2)),
         'amp_az_deg': float(np.degrees(base.amp_az_rad[i]) * rng.uniform(0.95, 1.05)),
         'amp_el_deg': float(np.degrees(base.amp_el_rad[i]) * rng.uniform(0.95, 1.05)),
         'freq_az_hz': float(170.0 + rng.uniform(-4, 4)),
         'freq_el_hz': float(40.0 + rng.uniform(-2, 2)),
         'phase_az_rad': float(rng.uniform(0, 2 * np.pi)),
         'phase_el_rad': float(rng.uniform(0, 2 * np.pi))} for i in range(24)]
    return doc


def measured_frames(sensor: SensorConfig, n_frames: int = 3, seed: int = 9):
    """(stamp_ns, points) per frame: the pattern plus angular noise, 80 % of shots detected."""
    shots = frame_shots(sensor)
    rng = np.random.default_rng(seed)
    frames = []
    for f in range(n_frames):
        keep = rng.random(len(shots)) > 0.2
        az = shots.az_rad[keep] + np.radians(NOISE_DEG) * rng.standard_normal(keep.sum())
        el = shots.el_rad[keep] + np.radians(NOISE_DEG) * rng.standard_normal(keep.sum())
        xyz = directions_from_angles(az, el) * rng.uniform(5.0, 30.0, keep.sum())[:, None]
        pts = make_points(xyz, 0.5, shots.t_s[keep], shots.laser[keep], 0)
        frames.append((T0_NS + f * int(sensor.frame_period_s * 1e9), pts))
    return frames


def xyzt_msg(typestore, pts: np.ndarray, stamp_ns: int):
    """A PointCloud2 with only x, y, z, t (float32): a sensor driver without a ring field."""
    types = typestore.types
    arr = np.zeros(len(pts), dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('t', '<f4')])
    for k in 'xyzt':
        arr[k] = pts[k]
    field = types['sensor_msgs/msg/PointField']
    return types['sensor_msgs/msg/PointCloud2'](
        header=types['std_msgs/msg/Header'](
            stamp=ns_to_stamp(stamp_ns, types['builtin_interfaces/msg/Time']), frame_id='lidar'),
        height=1, width=len(arr), is_bigendian=False, point_step=16, row_step=16 * len(arr),
        fields=[field(name=k, offset=4 * i, datatype=FLOAT32, count=1) for i, k in enumerate('xyzt')],
        data=np.frombuffer(arr.tobytes(), np.uint8), is_dense=True)


def write_bag(path: Path, frames, ring: bool = True) -> Path:
    with BagWriter(path) as bag:
        for stamp, pts in frames:
            if ring:
                bag.write_cloud('/lidar/points', pts, stamp, 'lidar')
            else:
                cdr = bag.typestore.serialize_cdr(xyzt_msg(bag.typestore, pts, stamp),
                                                  'sensor_msgs/msg/PointCloud2')
                bag.write_raw('/lidar/points', 'sensor_msgs/msg/PointCloud2', stamp, cdr)
    return path


@pytest.fixture(scope='module')
def lab(tmp_path_factory):
    folder = tmp_path_factory.mktemp('scan')
    doc = truth_document()
    sensor = parse(SensorConfig, doc, 'truth')
    frames = measured_frames(sensor)
    return dict(folder=folder, doc=doc, sensor=sensor, frames=frames,
                ring_bag=write_bag(folder / 'ring', frames),
                xyzt_bag=write_bag(folder / 'xyzt', frames, ring=False))


def assert_lasers_recovered(out: Path, truth: dict) -> None:
    fitted = yaml.safe_load(out.read_text())['scan']['lasers']
    for key in KEYS:
        got = np.array([f[key] for f in fitted])
        want = np.array([t[key] for t in truth['scan']['lasers']])
        err = got - want
        if key.startswith('phase'):
            err = np.angle(np.exp(1j * err))
        assert np.abs(err).max() <= TOL[key], (key, np.abs(err).max())


def assert_noise_level(cal) -> None:
    expected = NOISE_DEG * np.sqrt(2)  # two independent axes of 0.01 deg
    assert abs(cal.rms_deg / expected - 1) < 0.10, cal.rms_deg
    # Rayleigh p95 = sqrt(-2 ln 0.05) sigma = 2.448 sigma
    assert abs(cal.p95_deg / (2.448 * NOISE_DEG) - 1) < 0.10, cal.p95_deg


@pytest.fixture(scope='module')
def ring_fit(lab):
    return run_scan(lab['ring_bag'], lab['folder'] / 'ring.yaml', figure=lab['folder'] / 'scan.png')


def test_ring_bag_recovers_every_laser(ring_fit, lab):
    assert_lasers_recovered(ring_fit.out, lab['doc'])
    assert_noise_level(ring_fit)
    assert ring_fit.tiles == (8, 3) and ring_fit.shots_per_laser == 880
    assert abs(ring_fit.frame_period_s - 0.1) < 1e-9  # integer-ns stamps: exact to 1 ns
    # the input (unperturbed) config is degrees off: the fit is what makes the pattern match
    assert np.sqrt(np.mean(ring_fit.prior_error_deg ** 2)) > 1.0
    assert 'angular error per shot (fitted pattern): RMS' in ring_fit.report


def test_written_sensor_reproduces_the_pattern(ring_fit, lab):
    """load_sensor accepts the file and frame_shots turns it into the measured pattern."""
    fitted = frame_shots(load_sensor(ring_fit.out))
    truth = frame_shots(lab['sensor'])
    np.testing.assert_array_equal(fitted.laser, truth.laser)
    np.testing.assert_allclose(fitted.t_s, truth.t_s, atol=1e-12)  # float64, same closed form
    cos = np.einsum('ij,ij->i', fitted.directions(), truth.directions())
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.005
    # everything but the scan (and frame rate) is copied from the input sensor
    written = yaml.safe_load(ring_fit.out.read_text())
    shipped = read_yaml(config_path('cepton_vista_p60.yaml'))
    assert {k: v for k, v in written.items() if k != 'scan'} == \
        {k: v for k, v in shipped.items() if k != 'scan'}


def test_figure_written(ring_fit, lab):
    png = lab['folder'] / 'scan.png'
    assert png.read_bytes()[:4] == b'\x89PNG' and png.stat().st_size > 20_000


def test_xyzt_bag_assigns_points_to_tiles(lab):
    """No ring field: tiles from the angle grid, then nearest curve at the point's time."""
    cal = run_scan(lab['xyzt_bag'], lab['folder'] / 'xyzt.yaml')
    assert read_scan_samples(lab['xyzt_bag']).laser is None
    ring = read_scan_samples(lab['ring_bag']).laser
    assert np.mean(cal.laser == ring) > 0.999
    assert_lasers_recovered(cal.out, lab['doc'])
    assert_noise_level(cal)
    assert 'assigned by clustering' in cal.report


def test_frame_rate_from_stamps(lab, tmp_path):
    """A sensor at 12.5 Hz recorded with a 10 Hz config: the bag's stamps win, with a warning."""
    doc = copy.deepcopy(lab['doc'])
    doc['frame_rate_hz'] = 12.5
    frames = measured_frames(parse(SensorConfig, doc, 'truth'), 2, seed=3)
    cal = run_scan(write_bag(tmp_path / 'b', frames), tmp_path / 's.yaml')
    assert abs(load_sensor(cal.out).frame_rate_hz - 12.5) < 1e-6
    assert any('frame period' in w for w in cal.warnings)
    assert_lasers_recovered(cal.out, doc)


def test_fit_sine_closed_form():
    """Irregular, gappy samples of a known sine: parameters back to numerical precision."""
    rng = np.random.default_rng(0)
    t = np.sort(rng.choice(np.arange(2000) * 5e-5, 400, replace=False))
    y = 0.3 + 0.07 * np.sin(2 * np.pi * 123.4 * t + 2.0)
    fit = fit_sine(t, y, 5.0, 5000.0)
    # Noise-free float64 samples: the least-squares optimum is the truth; the bounds are
    # the optimiser's convergence, the frequency and phase being the least constrained.
    assert (abs(fit.center - 0.3) < 1e-9 and abs(fit.amp - 0.07) < 1e-9
            and abs(fit.freq_hz - 123.4) < 1e-6 and abs(fit.phase_rad - 2.0) < 1e-7)


def test_cli_prints_report(lab, tmp_path, capsys):
    out = tmp_path / 's.yaml'
    assert cli.main(['calibrate', 'scan', str(lab['ring_bag']), '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'p95' in text and f'wrote {out}' in text


# ----------------------------------------------------------------- bad input
def test_missing_time_field_is_an_error(lab, tmp_path):
    stamp, pts = lab['frames'][0]
    bare = make_points(np.column_stack([pts['x'], pts['y'], pts['z']]), 0.5, 0.0, 0, 0)
    with BagWriter(tmp_path / 'b') as bag:
        types = bag.typestore.types
        msg = xyzt_msg(bag.typestore, bare, stamp)
        msg = types['sensor_msgs/msg/PointCloud2'](
            header=msg.header, height=1, width=msg.width, fields=msg.fields[:3],
            is_bigendian=False, point_step=16, row_step=msg.row_step, data=msg.data, is_dense=True)
        bag.write_raw('/lidar/points', 'sensor_msgs/msg/PointCloud2', stamp,
                      bag.typestore.serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2'))
    with pytest.raises(CalibrationInputError, match=r"topic '/lidar/points'.*\['t'\] missing"):
        run_scan(tmp_path / 'b', tmp_path / 's.yaml')


def test_missing_topic_is_an_error(lab, tmp_path):
    with pytest.raises(CalibrationInputError, match="no topic '/velodyne_points'") as err:
        run_scan(lab['ring_bag'], tmp_path / 's.yaml', topic='/velodyne_points')
    assert str(err.value).endswith('(choose the topic with --cloud-topic)')


def test_uncovered_laser_keeps_the_config_curve(lab, tmp_path):
    """A target that misses laser 7: its curve stays the input config's, with a warning."""
    stamp, pts = lab['frames'][0]
    bag = write_bag(tmp_path / 'no7', [(stamp, pts[pts['ring'] != 7])])
    cal = run_scan(bag, tmp_path / 's.yaml')
    assert any('laser(s) [7]' in w and 'kept from' in w for w in cal.warnings)
    fitted = lissajous_lasers(load_sensor(cal.out).scan)
    shipped = lissajous_lasers(load_sensor(config_path('cepton_vista_p60.yaml')).scan)
    assert abs(fitted.freq_az_hz[7] - shipped.freq_az_hz[7]) < 1e-6
    assert abs(fitted.center_az_rad[7] - shipped.center_az_rad[7]) < 1e-9
    truth = lab['doc']['scan']['lasers'][8]
    assert abs(fitted.freq_az_hz[8] - truth['freq_az_hz']) < 0.05  # one frame: looser
    assert 'kept from config' in cal.report


def test_too_few_points_is_an_error(lab, tmp_path):
    stamp, pts = lab['frames'][0]
    sparse = [(stamp, pts[::60])]  # ~12 points per laser
    with pytest.raises(CalibrationInputError, match='no laser has 40 points'):
        run_scan(write_bag(tmp_path / 'sparse', sparse), tmp_path / 's.yaml')
    with pytest.raises(CalibrationInputError, match=r'laser \d+ has \d+ points; at least 40'):
        run_scan(write_bag(tmp_path / 'sparse_xyzt', sparse, ring=False), tmp_path / 's.yaml')


def test_cepton_layout_bag_recovers_every_laser(lab, tmp_path):
    """The same frames in the Cepton driver's layout: time from timestamp_s + timestamp_us
    (microseconds), the laser from channel_id, NO_RETURN points left out by their flag
    (here not at the origin: 300 a frame, scattered, that would spoil the fit)."""
    from lidar_sim_ros.io.cepton import NO_RETURN, cepton_points
    rng = np.random.default_rng(12)
    path = tmp_path / 'cepton'
    n_miss = 300
    with BagWriter(path) as bag:
        for stamp, pts in lab['frames']:
            miss = rng.normal(size=(n_miss, 3)) + [20.0, 0.0, 0.0]
            xyz = np.vstack([np.column_stack([pts['x'], pts['y'], pts['z']]), miss])
            t_ns = stamp + np.round(np.append(pts['t'], rng.uniform(0, 0.09, n_miss))
                                    * 1e9).astype(np.int64)
            flags = np.append(np.zeros(len(pts), np.uint16), np.full(n_miss, NO_RETURN, np.uint16))
            ring = np.append(pts['ring'], rng.integers(0, 24, n_miss).astype(np.uint16))
            bag.write_cloud('/cepton_pcl2', cepton_points(xyz, np.full(len(xyz), 0.5), t_ns,
                                                          flags, ring), stamp, 'cepton3')
    out = tmp_path / 'cepton.yaml'
    cal = run_scan(path, out, topic='/cepton_pcl2')
    assert_lasers_recovered(out, lab['doc'])
    assert_noise_level(cal)


def test_a_pattern_the_fit_cannot_match_stops_without_writing(lab, tmp_path, capsys):
    """Each frame's directions shuffled among its points (times and ring ids kept): the
    fit left RMS 18.5 deg and calibrate scan wrote the sensor file, rc 0. It now stops at
    MAX_FIT_RMS_DEG (the risley fit's limit, one constant) naming the error, rc 2."""
    import re
    from lidar_sim_ros.calibrate.common import MAX_FIT_RMS_DEG
    rng = np.random.default_rng(1)
    shuffled = []
    for stamp, pts in lab['frames']:
        p, perm = pts.copy(), rng.permutation(len(pts))
        for k in 'xyz':
            p[k] = pts[k][perm]
        shuffled.append((stamp, p))
    bag = write_bag(tmp_path / 'shuffled', shuffled)
    assert cli.main(['calibrate', 'scan', str(bag), '--out', str(tmp_path / 'fit.yaml')]) == 2
    err = capsys.readouterr().err
    rms = re.search(r'shuffled.*the best Lissajous curves found \(24 lasers\) leaves an angular '
                    rf'error of RMS ([\d.]+) deg, more than {MAX_FIT_RMS_DEG:g} deg', err)
    assert rms and float(rms.group(1)) > 10, err
    assert not (tmp_path / 'fit.yaml').exists()


def simultaneous_frames(sensor: SensorConfig, n_frames: int = 2, seed: int = 11):
    """(stamp_ns, points) per frame of a lab whose lasers fire together (not round-robin),
    880 instants per frame half a shot later than ours: t_j = (j + 1/2) T / 880."""
    lasers = lissajous_lasers(sensor.scan)
    n_las, per = len(lasers.center_az_rad), sensor.scan.shots_per_laser
    t = np.repeat((np.arange(per) + 0.5) * sensor.frame_period_s / per, n_las)
    laser = np.tile(np.arange(n_las), per)
    az, el = lissajous_angles(lasers, laser, t)
    rng = np.random.default_rng(seed)
    frames = []
    for f in range(n_frames):
        keep = rng.random(len(t)) > 0.2
        xyz = directions_from_angles(az[keep], el[keep]) * rng.uniform(5.0, 30.0, keep.sum())[:, None]
        pts = make_points(xyz, 0.5, t[keep], laser[keep].astype(np.uint16), 0)
        frames.append((T0_NS + f * int(sensor.frame_period_s * 1e9), pts))
    return frames


@pytest.mark.parametrize('ring', [True, False])
def test_lasers_firing_together_give_the_shots_per_laser_recorded(lab, tmp_path, ring):
    """24 lasers at the same 880 instants: 880 shots per laser (the spacing of all shots
    over 24 lasers said 37)."""
    bag = write_bag(tmp_path / 'together', simultaneous_frames(lab['sensor']), ring=ring)
    cal = run_scan(bag, tmp_path / 'together.yaml')
    assert cal.shots_per_laser == 880
    assert yaml.safe_load((tmp_path / 'together.yaml').read_text())['scan']['shots_per_laser'] == 880
