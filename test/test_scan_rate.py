"""Tests for compare/recording/scan_rate.py and what is said of it: a Lissajous running
(1 + eps) fast against the configuration, in clouds without a time field. The times
themselves are checked through ``with_scan_times`` in test_scan_curve.py; here the
refusals, the figure's period, the verdict and terminal words, and that
``lidar-sim calibrate scan`` fits such a rate rather than absorbing it."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lidar_sim_ros.calibrate.scan_pattern import fit_sine
from lidar_sim_ros.compare.diagnose import diagnosis as dg
from lidar_sim_ros.compare.recording.scan_curve import nearest_on_curve
from lidar_sim_ros.compare.recording.scan_rate import drifting_times, figure_period_s
from lidar_sim_ros.compare.report import verdict as vd
from lidar_sim_ros.compare.run import scan_curve
from lidar_sim_ros.core.scan import frame_shots, lissajous_angles, lissajous_lasers
from lidar_sim_ros.core.shots import directions_from_angles
from test_scan_curve import SENSOR, lab_cloud


def test_the_p60_figure_closes_every_tenth_of_a_second():
    """110 and 100 Hz: the figure repeats every 1 / gcd = 0.1 s."""
    assert figure_period_s(np.array([110.0, 100.0, 110.0])) == pytest.approx(0.1)
    assert figure_period_s(np.array([0.0])) == float('inf')


def test_clouds_running_at_different_rates_are_refused():
    """Two clouds, one 0.5 % fast and one 0.8 % fast: no one rate, so no times (the old
    message stays, with why)."""
    interval = SENSOR.frame_period_s / SENSOR.scan.shots_per_laser
    a, _ = lab_cloud(False, 0.0, freq_scale=1.005, n_clouds=1, seed=1)
    b, _ = lab_cloud(False, 0.0, freq_scale=1.008, n_clouds=1, seed=2)
    d = np.concatenate([a.directions, b.directions])
    cloud = np.concatenate([np.zeros(len(a), int), np.ones(len(b), int)])
    curve, _, period = scan_curve(SENSOR)
    dist, t, laser, _ = nearest_on_curve(d, frame_shots(SENSOR), curve, interval)
    found, why = drifting_times(dist, t, laser, cloud, 2e-4, interval, period,
                                SENSOR.frame_period_s)
    assert found is None and ('disagree' in why or 'coherence' in why)


def _summary(eps):
    return {'nll_calibrated': -2.0, 'range_rmse_calibrated_m': 0.03, 'materials': {},
            'unmatched': {'points': 0}, 'point_times': 'scan pattern',
            'scan_pattern_match': 0.996, 'scan_pattern_rate_error': eps}


def test_a_recovered_rate_is_said_and_not_as_a_pattern_that_is_off():
    """Nothing named: the verdict does not open with "The scan pattern is off" and says
    the rate; the terminal line gives it too."""
    text = vd.verdict(_summary(0.005), None, [], dg.Decision(None, []))
    assert not text.startswith('The scan pattern is off')
    assert 'runs 0.50 % fast' in text and 'x 1.00500' in text
    slow = vd.verdict(_summary(-0.005), None, [], dg.Decision(None, []))
    assert 'runs 0.50 % slow' in slow
    assert 'runs 0.50 % fast' not in vd.verdict(_summary(None), None, [], dg.Decision(None, []))


def test_calibrate_scan_fits_the_scaled_frequency():
    """A P-60 laser's azimuth at 110 x 1.005 Hz, three frames pooled on the frame clock:
    calibrate scan's sine fit gives 110.55 Hz (the rate is fitted, not absorbed)."""
    lasers = lissajous_lasers(SENSOR.scan)
    rng = np.random.default_rng(4)
    t = np.concatenate([np.sort(rng.uniform(0.0, SENSOR.frame_period_s, 600))
                        for _ in range(3)])
    az, _ = lissajous_angles(lasers, np.zeros(len(t), int), 1.005 * t)
    fit = fit_sine(t, az, 5.0, 4000.0)
    assert fit.freq_hz == pytest.approx(110.0 * 1.005, abs=0.01)
