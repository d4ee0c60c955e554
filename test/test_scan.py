"""Scan model: the P-60's 8 x 3 Lissajous array, a rotating pattern and a file pattern."""
import numpy as np
import pytest

from lidar_sim_ros.core.config import ConfigError, load_sensor
from lidar_sim_ros.core.scan import (angles_from_directions, directions_from_angles,
                                     frame_shots, lissajous_lasers)
from conftest import CONFIG, sensor


@pytest.fixture(scope='module')
def p60():
    return load_sensor(CONFIG / 'cepton_vista_p60.yaml')


def test_shot_count_and_frame_period(p60):
    shots = frame_shots(p60)
    assert len(shots) == 8 * 3 * 880 == 21120  # 240 x 88 at 0.25 deg
    assert shots.t_s.min() == 0.0
    assert shots.t_s.max() < p60.frame_period_s == pytest.approx(0.1)
    assert np.all(np.diff(shots.t_s) > 0)
    # 24 lasers, each fires the same number of shots
    assert np.bincount(shots.laser).tolist() == [880] * 24


def test_fov_covered_and_tiles_overlap(p60):
    shots = frame_shots(p60)
    az, el = np.degrees(shots.az_rad), np.degrees(shots.el_rad)
    assert az.min() <= -30.0 and az.max() >= 30.0
    assert el.min() <= -11.0 and el.max() >= 11.0
    lasers = lissajous_lasers(p60.scan)
    # Neighbouring tiles overlap at their edges (paper Sec. 3): az ranges of laser 0 and 1 intersect.
    a0 = az[shots.laser == 0]
    a1 = az[shots.laser == 1]
    assert a0.max() > a1.min()
    assert np.degrees(lasers.amp_az_rad[0]) > 7.5 / 2


def test_every_fov_cell_is_visited(p60):
    """Coverage: every 1 x 1 deg cell of the 60 x 22 deg FOV receives shots."""
    shots = frame_shots(p60)
    az, el = np.degrees(shots.az_rad), np.degrees(shots.el_rad)
    h, _, _ = np.histogram2d(az, el, bins=[60, 22], range=[[-30, 30], [-11, 11]])
    assert (h > 0).mean() > 0.97


def test_pattern_is_lattice_like_and_uneven(p60):
    """Shots pile up where the curves turn and cross: density is far from uniform
    (paper: 'density of scanning rays is biased'), and at 0.25 deg there are holes
    inside the lattice cells."""
    shots = frame_shots(p60)
    az, el = np.degrees(shots.az_rad), np.degrees(shots.el_rad)
    h, _, _ = np.histogram2d(az, el, bins=[240, 88], range=[[-30, 30], [-11, 11]])
    assert (h == 0).mean() > 0.2          # holes between lattice lines
    assert h.max() >= 8 * max(h.mean(), 1)  # pile-ups at turning points/crossings


def test_lissajous_shots_closed_form():
    """Every shot of a 3 x 2 array with one laser overridden, against the tile layout
    computed by hand: laser = row * tiles_az + col, column 0 at the most negative
    azimuth, row 0 at the top; az = c_az + A_az sin(2 pi f_az t + phase_az + j step),
    el likewise; lasers fire round-robin at t = k T / (shots per frame)."""
    scan = {'type': 'lissajous_array', 'fov_az_deg': 30.0, 'fov_el_deg': 12.0,
            'tiles_az': 3, 'tiles_el': 2, 'shots_per_laser': 40, 'overlap': 0.2,
            'freq_az_hz': 70.0, 'freq_el_hz': 50.0, 'phase_az_rad': 0.3, 'phase_el_rad': 1.1,
            'phase_step_rad': 0.25,
            'lasers': [{}, {}, {}, {}, {'freq_az_hz': 90.0, 'phase_el_rad': -0.4, 'amp_el_deg': 2.0}, {}]}
    s = sensor(scan)
    shots = frame_shots(s)
    n = 6 * 40
    k = np.arange(n)
    t = k * s.frame_period_s / n
    np.testing.assert_allclose(shots.t_s, t, rtol=0, atol=1e-15)
    laser = k % 6
    np.testing.assert_array_equal(shots.laser, laser)
    col, row = laser % 3, laser // 3
    c_az, c_el = -15.0 + 10.0 * (col + 0.5), 6.0 - 6.0 * (row + 0.5)     # tiles 10 x 6 deg
    a_az, a_el = np.full(n, 5.0 * 1.2), np.full(n, 3.0 * 1.2)
    f_az, f_el = np.full(n, 70.0), np.full(n, 50.0)
    p_az, p_el = 0.3 + 0.25 * laser, np.full(n, 1.1)
    four = laser == 4
    f_az[four], p_el[four], a_el[four] = 90.0, -0.4, 2.0
    az = c_az + a_az * np.sin(2 * np.pi * f_az * t + p_az)
    el = c_el + a_el * np.sin(2 * np.pi * f_el * t + p_el)
    # float64 end to end: 1e-12 deg.
    np.testing.assert_allclose(np.degrees(shots.az_rad), az, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.degrees(shots.el_rad), el, rtol=0, atol=1e-12)


def test_laser_rows_and_columns(p60):
    lasers = lissajous_lasers(p60.scan)
    c_az = np.degrees(lasers.center_az_rad).reshape(3, 8)
    c_el = np.degrees(lasers.center_el_rad).reshape(3, 8)
    assert np.allclose(np.diff(c_az, axis=1), 7.5)
    assert np.allclose(c_el[:, 0], [22 / 3, 0, -22 / 3])


def test_rotating_pattern():
    s = sensor({'type': 'rotating', 'elevations_deg': [-10.0, 0.0, 10.0], 'shots_per_beam': 360})
    shots = frame_shots(s)
    assert len(shots) == 3 * 360
    assert np.allclose(np.unique(np.degrees(shots.el_rad)), [-10, 0, 10])
    assert np.degrees(shots.az_rad).min() == pytest.approx(-180)
    # A full turn: the last step stops one step short of +180 (= -180, already fired).
    assert np.degrees(shots.az_rad).max() == pytest.approx(180 - 1)


def test_rotating_pattern_closed_form():
    """Shot k of beam i: az = az_min + k (az_max - az_min) / N, el = elevations_deg[i],
    t = k T / N; all beams fire together at each step. Elevations deliberately unsorted."""
    elevations = [3.0, -15.0, 7.5, 0.0]
    n_steps, az_min, az_max = 16, -30.0, 50.0
    s = sensor({'type': 'rotating', 'elevations_deg': elevations, 'az_min_deg': az_min,
                'az_max_deg': az_max, 'shots_per_beam': n_steps})
    shots = frame_shots(s)
    assert len(shots) == len(elevations) * n_steps
    k = np.arange(n_steps)
    for ring, el in enumerate(elevations):
        mine = shots.laser == ring
        # float64 end to end (degrees -> radians -> degrees): 1e-12 deg.
        np.testing.assert_allclose(np.degrees(shots.el_rad[mine]), el, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.degrees(shots.az_rad[mine]), az_min + k * (az_max - az_min) / n_steps,
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(shots.t_s[mine], k * s.frame_period_s / n_steps, rtol=0, atol=1e-15)


def test_file_pattern(tmp_path):
    path = tmp_path / 'pattern.csv'
    path.write_text('t_s,az_deg,el_deg,laser\n0.02,1.0,2.0,1\n0.0,-1.0,0.5,0\n')
    shots = frame_shots(sensor({'type': 'file', 'path': str(path)}))
    assert shots.t_s.tolist() == [0.0, 0.02]
    assert np.degrees(shots.az_rad).tolist() == pytest.approx([-1.0, 1.0])
    assert shots.laser.tolist() == [0, 1]


def test_file_pattern_bad_columns(tmp_path):
    path = tmp_path / 'pattern.csv'
    path.write_text('t_s,az_deg,laser\n0.0,1.0,0\n')
    with pytest.raises(ConfigError, match='el_deg'):
        frame_shots(sensor({'type': 'file', 'path': str(path)}))


def test_angles_round_trip():
    rng = np.random.default_rng(1)
    az, el = rng.uniform(-1, 1, 100), rng.uniform(-0.5, 0.5, 100)
    d = directions_from_angles(az, el)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    a2, e2 = angles_from_directions(d * 3.0)
    assert np.allclose(a2, az) and np.allclose(e2, el)
    # REP-103: positive azimuth turns toward +y (left)
    assert directions_from_angles(np.array([np.pi / 2]), np.array([0.0]))[0] == pytest.approx([0, 1, 0], abs=1e-12)
