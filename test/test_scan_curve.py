"""Tests for compare/recording/scan_curve.py via ``with_scan_times``: point times of a
cloud without a time field whose shots sit at other instants of the configured Lissajous
curve (lasers firing together, half a shot later), and a pattern 0.5 % off in frequency
(the same closed figure, other instants drifting through the frame) still refused."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lidar_sim_ros.compare.recording.measurements import Measurements, with_scan_times
from lidar_sim_ros.compare.run import scan_curve
from lidar_sim_ros.core.config import load_sensor
from lidar_sim_ros.core.scan import frame_shots, lissajous_angles, lissajous_lasers
from lidar_sim_ros.core.shots import directions_from_angles
from lidar_sim_ros.paths import config_path

SENSOR = load_sensor(config_path('cepton_vista_p60.yaml'))


def lab_cloud(together: bool, offset: float, freq_scale: float = 1.0, n_clouds: int = 2,
              seed: int = 3) -> tuple[Measurements, np.ndarray]:
    """Measurements of a lab firing the configured curve (frequencies x freq_scale) at its
    own instants, 30 % of the shots returning, stamped at frame start; and the true times."""
    lasers = lissajous_lasers(SENSOR.scan)
    n_las, per, period = len(lasers.center_az_rad), SENSOR.scan.shots_per_laser, SENSOR.frame_period_s
    k = np.arange(n_las * per)
    t = ((k // n_las + offset) * period / per if together else (k + offset) * period / len(k))
    laser = k % n_las
    scaled = replace(lasers, freq_az_hz=lasers.freq_az_hz * freq_scale,
                     freq_el_hz=lasers.freq_el_hz * freq_scale)
    rng = np.random.default_rng(seed)
    rows, cloud = [], []
    for c in range(n_clouds):
        keep = np.flatnonzero(rng.random(len(t)) < 0.3)
        rows.append(keep)
        cloud.append(np.full(len(keep), c))
    rows, cloud = np.concatenate(rows), np.concatenate(cloud)
    az, el = lissajous_angles(scaled, laser[rows], t[rows])
    d = directions_from_angles(az, el)
    stamps = np.arange(n_clouds) * period
    n = len(rows)
    meas = Measurements(bag=Path('lab'), xyz_m=10 * d, range_m=np.full(n, 10.0), directions=d,
                        intensity=None, t_s=stamps[cloud], t_frame_s=np.zeros(n), cloud=cloud,
                        laser=np.zeros(n, np.uint16), has_point_time=False,
                        cloud_stamps_s=stamps, epoch_s=0.0, poses=None, material_names=None,
                        time_source='stamp')
    return meas, t[rows]


def times(meas: Measurements) -> Measurements:
    return with_scan_times(meas, frame_shots(SENSOR), None, SENSOR.frame_period_s, (0.0,),
                           *scan_curve(SENSOR))


@pytest.mark.parametrize('together, offset', [(True, 0.5), (False, 0.37)])
def test_shots_at_other_instants_of_the_curve_take_their_times(together, offset):
    meas, truth = lab_cloud(together, offset)
    timed = times(meas)
    assert timed.time_source == 'scan pattern' and timed.scan_match_fraction > 0.99
    assert np.mean(np.abs(timed.t_frame_s - truth) < 1e-6) > 0.99


def test_the_configured_instants_keep_their_shot_times():
    meas, truth = lab_cloud(False, 0.0)
    timed = times(meas)
    assert timed.time_source == 'scan pattern'
    assert np.mean(np.abs(timed.t_frame_s - truth) < 1e-9) > 0.99


def test_a_pattern_half_a_percent_off_is_still_refused():
    """Frequencies x 1.005: the same 11:10 closed figure, but the instants drift 4.4 shots
    through the frame, off any one grid of the shot interval."""
    meas, _ = lab_cloud(False, 0.0, freq_scale=1.005)
    timed = times(meas)
    assert timed.time_source == 'stamp' and timed.scan_match_fraction < 0.5
