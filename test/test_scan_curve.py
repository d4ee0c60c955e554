"""Tests for compare/recording/scan_curve.py via ``with_scan_times``: point times of a
cloud without a time field whose shots sit at other instants of the configured Lissajous
curve (lasers firing together, half a shot later), and a pattern 0.5 % off in frequency
(the same closed figure, other instants drifting through the frame: ``scan_rate``)."""
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


@pytest.mark.parametrize('scale', [1.005, 0.995])
def test_a_pattern_half_a_percent_off_takes_its_times_from_the_curve(scale):
    """Frequencies x 1.005 (or 0.995): the same 11:10 closed figure, the instants drifting
    4.4 shots through the frame; the rate is fitted and each point snapped to its laser's
    drifting grid, to a small fraction of the 114 us shot interval (the old code refused
    and left every point at its cloud stamp)."""
    meas, truth = lab_cloud(False, 0.0, freq_scale=scale)
    timed = times(meas)
    interval = SENSOR.frame_period_s / SENSOR.scan.shots_per_laser
    assert timed.time_source == 'scan pattern' and timed.scan_match_fraction > 0.99
    assert abs(timed.scan_rate_error - (scale - 1.0)) < 2e-5
    assert np.mean(np.abs(timed.t_frame_s - truth) < 0.05 * interval) > 0.99
    assert any('runs 0.50 %' in n for n in timed.notes)


def test_the_retraced_start_of_a_fast_pattern_goes_to_the_end_of_the_frame():
    """eps > 0: the last 0.5 % of the frame retraces the figure's start; those shots'
    curve times are near 0 and their instants near the frame's end."""
    meas, truth = lab_cloud(False, 0.0, freq_scale=1.005, n_clouds=3, seed=5)
    timed = times(meas)
    late = truth > SENSOR.frame_period_s / 1.005
    assert late.sum() > 20
    assert np.mean(np.abs(timed.t_frame_s[late] - truth[late]) < 1e-6) > 0.9


def test_a_pattern_off_beyond_the_bound_is_still_refused():
    """Frequencies x 1.03: beyond the 2 % looked for; every point keeps its stamp."""
    meas, _ = lab_cloud(False, 0.0, freq_scale=1.03)
    timed = times(meas)
    assert timed.time_source == 'stamp' and timed.scan_match_fraction < 0.5
    assert timed.scan_rate_error is None
