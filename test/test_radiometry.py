"""Radiometry of sunlight and receiver noise (core/radiometry.py) against hand calculations,
closed forms and independent Monte Carlo."""
from __future__ import annotations

import math

import numpy as np
import pytest

from lidar_sim_ros.core import radiometry as rad
from lidar_sim_ros.core.config import ReceiverConfig, load_sensor
from lidar_sim_ros.core.reflection import phong_brdf, specular_alpha
from lidar_sim_ros.paths import config_path


def test_plate_check_value_is_about_3_nW():
    """The issue's check value, by hand: a 30 % Lambertian plate facing sun and sensor,
    20 nm band-pass, 25 mm aperture, 2 x 2 mrad field of view, receive efficiency 0.9."""
    radiance = 0.92 * 20.0 * 0.30 / math.pi * 1.0            # E dlambda rho/pi cos0 = 1.757 W/m^2/sr
    area = math.pi * 0.0125 ** 2                              # 4.909e-4 m^2
    omega = 0.002 * 0.002                                     # 4e-6 sr
    hand_w = radiance * area * omega * 0.9                    # 3.105e-9 W
    assert hand_w == pytest.approx(3.105e-9, rel=1e-3)
    normal = sun = sensor = np.array([[-1.0, 0.0, 0.0]])      # everything along the normal
    f = rad.bistatic_phong_brdf(normal, sun, sensor, 0.30, 0.0, 1.0)
    model_w = rad.collected_power_w(rad.reflected_radiance_w_m2_sr(0.92 * 20.0, f, 1.0),
                                    rad.aperture_area_m2(0.025), omega, 0.9)
    assert model_w[0] == pytest.approx(hand_w, rel=1e-12)
    assert 2.5e-9 < model_w[0] < 3.5e-9


def test_bistatic_phong_matches_the_goniometer_form_and_is_reciprocal():
    rng = np.random.default_rng(3)
    theta_i, theta_o = rng.uniform(0, 1.4, (2, 200))
    phi_i, phi_o = rng.uniform(-np.pi, np.pi, (2, 200))

    def vec(theta, phi):  # surface frame: normal +z
        return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])

    normal = np.array([0.0, 0.0, 1.0])
    s, v = vec(theta_i, phi_i), vec(theta_o, phi_o)
    alpha = specular_alpha(theta_i, phi_i, theta_o, phi_o)   # reflection.py's own form
    np.testing.assert_allclose(rad.mirror_cos_alpha(normal, s, v), np.cos(alpha), atol=1e-12)
    kd, ks, n = 0.2, 0.6, 12.0
    np.testing.assert_allclose(rad.bistatic_phong_brdf(normal, s, v, kd, ks, n),
                               phong_brdf(alpha, kd, ks, n), rtol=1e-12)
    np.testing.assert_allclose(rad.bistatic_phong_brdf(normal, s, v, kd, ks, n),
                               rad.bistatic_phong_brdf(normal, v, s, kd, ks, n), rtol=1e-12)
    # Monostatic: source = viewer at incidence theta gives cos(2 theta), the paper's case.
    np.testing.assert_allclose(rad.mirror_cos_alpha(normal, s, s), np.cos(2 * theta_i), atol=1e-12)


def test_sun_disk_overlap_with_the_field_of_view():
    r_sun, r_f = rad.SUN_ANGULAR_RADIUS_RAD, 0.002
    assert r_sun == pytest.approx(4.6505e-3, rel=1e-4)       # 959.6 arcsec
    centred, far = rad.disk_overlap_fraction(np.array([0.0, r_sun + r_f + 1e-6]), r_sun, r_f)
    assert centred == pytest.approx((r_f / r_sun) ** 2)
    assert far == 0.0
    # Two equal circles one radius apart overlap in (2 pi/3 - sqrt(3)/2) r^2.
    half = rad.disk_overlap_fraction(np.array([r_sun]), r_sun, r_sun)[0]
    assert half == pytest.approx((2 * np.pi / 3 - np.sqrt(3) / 2) / np.pi, rel=1e-9)


def test_apd_noise_by_hand():
    # sigma_i^2 = 2 q M^2 F (R P + I_db) B + i_a^2 B; sigma_P = sigma_i / (M R)
    q, m, f, r, b, ia, idb, p = 1.602176634e-19, 50.0, 3.0, 0.5, 1e8, 10e-12, 1e-9, 20e-9
    var = 2 * q * m * m * f * (r * p + idb) * b + ia * ia * b
    expected = math.sqrt(var) / (m * r)
    assert rad.apd_noise_sigma_w(p, r, m, f, b, ia, idb) == pytest.approx(expected, rel=1e-12)


def test_default_receiver_puts_the_threshold_at_5_5_sigma_of_the_dark_noise():
    """The documented design rule behind the receiver defaults (docs/sunlight.md)."""
    sensor = load_sensor(config_path('cepton_vista_p60.yaml'))
    rx = sensor.receiver
    dark = rad.apd_noise_sigma_w(0.0, rx.responsivity_a_per_w, rx.apd_gain, rx.excess_noise_factor,
                                 rx.bandwidth_hz, rx.amplifier_noise_a_per_rthz, rx.dark_current_a)
    assert sensor.detection.threshold_power_w / dark == pytest.approx(5.5, abs=0.05)
    assert rx == ReceiverConfig()   # the shipped YAML spells out the defaults


def band_limited_noise(n: int, fs_hz: float, bandwidth_hz: float, rng) -> np.ndarray:
    """Unit-variance Gaussian noise through an ideal low-pass (white spectrum cut at B)."""
    spec = np.fft.rfft(rng.standard_normal(n))
    spec[np.fft.rfftfreq(n, 1.0 / fs_hz) > bandwidth_hz] = 0.0
    x = np.fft.irfft(spec, n)
    return x / x.std()


@pytest.mark.parametrize('level', [1.0, 2.0, 3.0])
def test_rice_rate_against_simulated_band_limited_noise(level):
    """Up-crossings of u sigma counted in simulated noise vs B/sqrt(3) exp(-u^2/2)."""
    b, fs, n = 1.0, 24.0, 2 ** 22
    x = band_limited_noise(n, fs, b, np.random.default_rng(11))
    crossings = np.count_nonzero((x[:-1] < level) & (x[1:] >= level))
    expected = rad.rice_rate_hz(level, 1.0, b) * n / fs
    # Poisson spread of the count (4 sigma) plus 1 % for crossings missed between samples.
    assert abs(crossings - expected) < 4 * np.sqrt(expected) + 0.01 * expected, (crossings, expected)


def test_coincidence_rate_against_a_simulated_photon_stream():
    """k = 2 photons within tau: nu = lambda (1 - exp(-lambda tau)), counted in a Poisson stream."""
    lam, tau, duration = 2.0e6, 1e-7, 0.5
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.exponential(1 / lam, int(lam * duration * 1.1)))
    t = t[t < duration]
    fires = np.count_nonzero(np.diff(t) <= tau)   # a photon with another one tau before it
    expected = rad.coincidence_rate_hz(lam, 2, tau) * duration
    assert expected == pytest.approx(lam * (1 - np.exp(-lam * tau)) * duration)
    assert abs(fires - expected) < 4 * np.sqrt(expected)
    assert rad.coincidence_rate_hz(lam, 1, tau) == lam


def test_timing_jitter_is_rise_time_over_snr():
    b = 2.5e8
    jitter = rad.timing_jitter_range_m(np.array([1e-9, 1e-9, 1e-9]), np.array([1e-8, 1e-7, 0.0]), b)
    t_rise = 0.35 / b
    np.testing.assert_allclose(jitter[:2], 0.5 * 299_792_458.0 * t_rise * np.array([0.1, 0.01]))
    assert jitter[2] == 0.0


def test_stray_light_falls_as_theta_squared_and_vanishes_behind():
    pst = rad.stray_light_pst(np.radians([1.0, 2.0, 10.0, 95.0]), 1e-4)
    np.testing.assert_allclose(pst[:3], [1e-4, 2.5e-5, 1e-6])
    assert pst[3] == 0.0
    reach = rad.stray_light_reach_rad(1e-4, 1e-2, 1e-9)
    assert rad.stray_light_pst(reach, 1e-4) * 1e-2 == pytest.approx(1e-9)
