"""Detection model: dropouts exactly at threshold and saturation, bias and noise statistics."""
import numpy as np
import pytest

from lidar_sim_ros.core import detection
from conftest import sensor


def test_dropouts_exactly_at_threshold_and_saturation():
    det = sensor(threshold_power_w=1e-8, saturation_power_w=1e-3).detection
    p = np.array([np.nextafter(1e-8, 0), 1e-8, 5e-4, np.nextafter(1e-3, 0), 1e-3, 2e-3])
    mask = detection.detected_mask(p, np.full(6, 10.0), det)
    assert mask.tolist() == [False, True, True, True, False, False]


def test_range_gate():
    det = sensor(min_range_m=1.0, max_range_m=50.0).detection
    mask = detection.detected_mask(np.full(4, 1e-6), np.array([0.5, 1.0, 50.0, 50.1]), det)
    assert mask.tolist() == [False, True, True, False]


def test_bias_and_sigma_recovered_statistically():
    rng = np.random.default_rng(7)
    n = 200_000
    true = np.full(n, 15.0)
    meas = detection.measured_range_m(true, -0.1383, 0.0281, rng)
    err = meas - true
    # Standard errors: sigma/sqrt(n) for the mean, sigma/sqrt(2n) for the std.
    assert err.mean() == pytest.approx(-0.1383, abs=5 * 0.0281 / np.sqrt(n))
    assert err.std(ddof=1) == pytest.approx(0.0281, abs=5 * 0.0281 / np.sqrt(2 * n))


def test_intensity_round_trip():
    det = sensor(saturation_power_w=2e-4).detection
    p = np.array([1e-9, 1e-6, 1e-4])
    assert np.allclose(detection.power_from_intensity(detection.intensity_from_power(p, det), det), p)
    assert detection.intensity_from_power(2e-4, det) == pytest.approx(1.0)
