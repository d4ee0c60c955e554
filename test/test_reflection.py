"""Reflection model against closed forms (paper Eqs. 1-3 and 5)."""
import numpy as np
import pytest
from scipy import integrate

from lidar_sim_ros.core import reflection
from conftest import sensor


def test_plate_power_matches_eqs_1_to_3_by_hand():
    optics = sensor().optics
    r, theta = 12.0, np.radians(30.0)
    kd, ks, n = 0.3, 0.4, 12.0
    # By hand, straight from the paper's symbols.
    f = kd / np.pi + ks * (n + 2) / (2 * np.pi) * np.cos(2 * theta) ** n
    e = optics.peak_power_w * optics.transmit_efficiency / (np.pi * (r * optics.beam_divergence_rad / 2) ** 2)
    radiance = f * e * np.cos(theta)
    area = np.pi * (r * optics.beam_divergence_rad / 2) ** 2 / np.cos(theta)
    p = radiance * optics.receive_efficiency * area * np.cos(theta) * 4 * np.pi \
        * np.pi * (optics.aperture_diameter_m / 2) ** 2 / (4 * np.pi * r ** 2)
    got = reflection.return_power_w(r, theta, kd, ks, n, optics)
    assert got == pytest.approx(p, rel=1e-12)
    # And the lidar equation it collapses to: P_o tau_t tau_r f cos(theta) pi (D/2)^2 / r^2.
    lidar_eq = (optics.peak_power_w * optics.transmit_efficiency * optics.receive_efficiency
                * f * np.cos(theta) * np.pi * (optics.aperture_diameter_m / 2) ** 2 / r ** 2)
    assert got == pytest.approx(lidar_eq, rel=1e-12)


def test_power_falls_as_inverse_square_of_range():
    optics = sensor().optics
    p = reflection.return_power_w(np.array([5.0, 10.0, 20.0]), 0.0, 0.5, 0.0, 1.0, optics)
    assert p[0] / p[1] == pytest.approx(4.0)
    assert p[1] / p[2] == pytest.approx(4.0)


def test_ks_zero_is_lambertian():
    alpha = np.linspace(0, np.pi, 50)
    assert np.allclose(reflection.phong_brdf(alpha, 0.6, 0.0, 30.0), 0.6 / np.pi)
    optics = sensor().optics
    theta = np.radians([0, 20, 40, 60, 80])
    p = reflection.return_power_w(10.0, theta, 0.6, 0.0, 5.0, optics)
    assert np.allclose(p / p[0], np.cos(theta))  # Lambert's cosine law


def _albedo(theta_in, kd, ks, n):
    """Directional-hemispherical reflectance: integral of f cos(theta_out) d omega."""
    def integrand(phi_out, theta_out):
        alpha = reflection.specular_alpha(theta_in, 0.0, theta_out, phi_out)
        return reflection.phong_brdf(alpha, kd, ks, n) * np.cos(theta_out) * np.sin(theta_out)
    val, _ = integrate.dblquad(integrand, 0, np.pi / 2, 0, 2 * np.pi, epsabs=1e-6)
    return val


@pytest.mark.parametrize('kd,ks,n', [(0.5, 0.5, 10.0), (0.0, 1.0, 50.0), (1.0, 0.0, 1.0)])
def test_brdf_energy_conservation(kd, ks, n):
    for theta_in in np.radians([0.0, 30.0, 60.0]):
        albedo = _albedo(theta_in, kd, ks, n)
        assert albedo <= 1.0 + 1e-3
    # At normal incidence the Lafortune-Willems normalisation makes the albedo kd + ks exactly.
    assert _albedo(0.0, kd, ks, n) == pytest.approx(kd + ks, rel=2e-3)


def test_monostatic_specular_peak_at_normal_incidence():
    f = reflection.phong_brdf(reflection.monostatic_alpha(np.radians([0, 5, 30, 60])), 0.05, 0.9, 20.0)
    assert np.all(np.diff(f) < 0)
    assert f[0] == pytest.approx(0.05 / np.pi + 0.9 * 22 / (2 * np.pi))
    assert f[-1] == pytest.approx(0.05 / np.pi)  # alpha = 120 deg: the lobe is gone
    # The pipeline's path from cos(incidence) gives the same BRDF and power.
    theta = np.radians([0, 5, 30, 44, 60, 85])
    from_cos = reflection.phong_brdf_cos(reflection.monostatic_cos_alpha(np.cos(theta)), 0.05, 0.9, 20.0)
    assert np.allclose(from_cos, reflection.phong_brdf(reflection.monostatic_alpha(theta), 0.05, 0.9, 20.0),
                       rtol=1e-12, atol=0)


def test_specular_alpha_mirror_direction():
    assert reflection.specular_alpha(0.4, 0.0, 0.4, np.pi) == pytest.approx(0.0, abs=1e-7)
    assert reflection.specular_alpha(0.4, 0.0, 0.4, 0.0) == pytest.approx(0.8)
