"""Radiometry of sunlight at the receiver and the noise it adds (the paper's future work).

Pure functions over numpy arrays, SI units (wavelength in nm where marked). The chain,
for one shot whose receiver field of view (IFOV) sees a surface point:

    f        = kd/pi + ks (n+2)/(2 pi) cos^n(alpha)      paper Eq. 5, alpha between the
               mirror direction of the SUN and the direction to the sensor (bistatic)
    L        = E_lambda dlambda f cos(theta_sun)          radiance toward the sensor (W m^-2 sr^-1)
    P_bg     = L A_rx Omega_IFOV tau_r                    background power collected (W)

Linear-mode APD receiver (current at the APD output, referred back to optical power):

    sigma_i^2 = 2 q M^2 F (R P_bg + I_db) B + i_amp^2 B   shot noise of background and bulk dark
                                                          current with excess noise, plus amplifier
    sigma_P   = sigma_i / (M R)                           noise-equivalent optical power (W)
    nu(u)     = B / sqrt(3) exp(-u^2 / (2 sigma_P^2))     Rice's up-crossing rate of level u

Rice's rate, derived: for a stationary Gaussian process with one-sided power spectrum
S(f), up-crossings of u occur at nu = (1/2pi) sqrt(m2/m0) exp(-u^2/2m0), with
m0 = int S df = sigma^2 and m2 = int (2 pi f)^2 S df (S. O. Rice, "Mathematical analysis
of random noise", Bell Syst. Tech. J. 24, 46-156 (1945), Sec. 3.3). An ideal low-pass of
bandwidth B (S flat on [0, B]) gives m2/m0 = (2 pi B)^2 / 3, hence nu = B/sqrt(3) exp(...).
This is the "standard FAR model of Rice" of lidar APD receivers (Huntington, Williams and
Lee, Opt. Eng. 57(7) 073106, 2018, who also note its Gaussian tail is optimistic for APDs).

Photon counting (Geiger-mode / SPAD receivers): background photoelectrons and dark counts
arrive as a Poisson process of rate lambda = eta P_bg lambda_0/(h c) + DCR; a detector
that needs k photons within a coincidence window tau fires at nu = lambda P[N(tau) >= k-1],
N ~ Poisson(lambda tau) (k = 1: every photon, Fouche, Appl. Opt. 42, 5388 (2003)).

Both are Poisson processes of crossings: the chance of a false return before time T is
1 - exp(-nu T) and the first crossing is exponentially distributed.
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammainc

from lidar_sim_ros.core.reflection import phong_brdf_cos

ELEMENTARY_CHARGE_C = 1.602176634e-19
PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_S = 299_792_458.0
# Solar disk seen from 1 AU: angular radius 959.6 arcsec = 4.652 mrad (IAU nominal solar
# radius 695 700 km over 1 AU); its solid angle pi r^2 = 6.80e-5 sr.
SUN_ANGULAR_RADIUS_RAD = 695_700.0 / 149_597_870.7  # km / km
# ASTM E490-00a AM0 spectrum near 905 nm, at 1 AU (W m^-2 nm^-1).
AM0_SPECTRAL_IRRADIANCE_905_W_M2_NM = 0.92
# 10-90 % rise time of a receiver of bandwidth B is about 0.35 / B (single-pole response).
RISE_TIME_BANDWIDTH_PRODUCT = 0.35


# ------------------------------------------------------------------ geometry
def unit(v: np.ndarray) -> np.ndarray:
    """Rows of v scaled to unit length (zero rows stay zero)."""
    v = np.asarray(v, dtype=float)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)


def row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (N, 3) arrays (either may be a single (3,) vector)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim == 2 and b.ndim == 2 and b.strides[0] == 0:
        return a @ b[0]      # one vector broadcast to every row (a fixed sun): a matrix-vector product
    return np.einsum('...i,...i->...', a, b)


def mirror_cos_alpha(normal: np.ndarray, to_source: np.ndarray, to_viewer: np.ndarray) -> np.ndarray:
    """cos(alpha) (-) between the mirror direction of light from ``to_source`` and ``to_viewer``.

    All unit vectors leave the surface point; the mirror direction is
    r = 2 (n.s) n - s, so cos(alpha) = r.v = 2 (n.s)(n.v) - s.v (general bistatic form;
    for a co-located source and viewer it is cos(2 theta), the paper's monostatic case).
    """
    n_s = row_dot(normal, to_source)
    return 2.0 * n_s * row_dot(normal, to_viewer) - row_dot(to_source, to_viewer)


def bistatic_phong_brdf(normal, to_source, to_viewer, kd, ks, n) -> np.ndarray:
    """Modified Phong BRDF (1/sr), paper Eq. 5, for light from ``to_source`` seen from ``to_viewer``."""
    return phong_brdf_cos(mirror_cos_alpha(normal, to_source, to_viewer), kd, ks, n)


# ---------------------------------------------------------------- radiometry
def aperture_area_m2(diameter_m: float) -> float:
    """Receiver aperture area pi (D/2)^2 (m^2)."""
    return float(np.pi * (diameter_m / 2.0) ** 2)


def reflected_radiance_w_m2_sr(irradiance_w_m2, brdf_per_sr, cos_incidence) -> np.ndarray:
    """L = f E cos(theta_i) (W m^-2 sr^-1): radiance of a surface lit by a distant source
    of irradiance E (normal to the beam) at incidence theta_i (the paper's Eq. 1 for the sun)."""
    return np.asarray(brdf_per_sr) * np.asarray(irradiance_w_m2) * np.clip(cos_incidence, 0.0, None)


def collected_power_w(radiance_w_m2_sr, aperture_area: float, ifov_sr: float, tau: float) -> np.ndarray:
    """P = L A_rx Omega_IFOV tau (W): an extended source filling the receiver's field of view."""
    return np.asarray(radiance_w_m2_sr) * aperture_area * ifov_sr * tau


def disk_irradiance_factor(angular_radius_rad: float) -> float:
    """E / L = pi sin^2(rho) (sr): irradiance at normal incidence from a uniform disk of
    radiance L and angular radius rho (a Lambertian sphere, e.g. the Earth seen from orbit).
    A tilted surface gets this times cos(angle to the disk centre) while the whole disk is
    above its horizon (an approximation beyond)."""
    return float(np.pi * np.sin(angular_radius_rad) ** 2)


def disk_overlap_fraction(separation_rad, disk_radius_rad: float, field_radius_rad: float) -> np.ndarray:
    """Fraction (-) of a disk (the sun) inside a circular field of view, small-angle geometry.

    Two circles of radii r_d (disk) and r_f (field) whose centres are d apart overlap in the
    lens-shaped area of the circle-circle intersection; the fraction is that area over pi r_d^2.
    """
    d = np.abs(np.asarray(separation_rad, float))
    r1, r2 = float(disk_radius_rad), float(field_radius_rad)
    out = np.zeros_like(d)
    inside = d <= abs(r1 - r2)
    out[inside] = min(r1, r2) ** 2 / r1 ** 2
    part = (d > abs(r1 - r2)) & (d < r1 + r2)
    if np.any(part):
        dp = d[part]
        a1 = r1 ** 2 * np.arccos(np.clip((dp ** 2 + r1 ** 2 - r2 ** 2) / (2 * dp * r1), -1, 1))
        a2 = r2 ** 2 * np.arccos(np.clip((dp ** 2 + r2 ** 2 - r1 ** 2) / (2 * dp * r2), -1, 1))
        a3 = 0.5 * np.sqrt(np.clip((-dp + r1 + r2) * (dp + r1 - r2) * (dp - r1 + r2) * (dp + r1 + r2),
                                   0, None))
        out[part] = (a1 + a2 - a3) / (np.pi * r1 ** 2)
    return out


def field_radius_rad(ifov_sr: float) -> float:
    """Half-angle (rad) of the circular field of view of solid angle Omega (small angles)."""
    return float(np.sqrt(ifov_sr / np.pi))


def stray_light_pst(off_axis_rad, pst_at_1deg: float) -> np.ndarray:
    """Point-source transmittance (-) of the receiver optics for a source off_axis from its
    axis: scattered power at the detector over the power entering the aperture.

    Clean refractive optics scatter with a power-law BSDF close to theta^-2 (Harvey-type
    roll-off), so PST(theta) = PST(1 deg) (1 deg / theta)^2, held at its value at the solar
    radius inside it and zero for a source behind the aperture plane (theta >= 90 deg).
    """
    theta = np.maximum(np.abs(np.asarray(off_axis_rad, float)), SUN_ANGULAR_RADIUS_RAD)
    pst = pst_at_1deg * (np.radians(1.0) / theta) ** 2
    return np.where(theta < np.pi / 2, pst, 0.0)


def stray_light_reach_rad(pst_at_1deg: float, into_aperture_w: float, floor_w: float) -> float:
    """Off-axis angle (rad) beyond which stray light PST(theta) P_in stays below floor_w."""
    if pst_at_1deg <= 0 or into_aperture_w <= 0:
        return 0.0
    return float(np.radians(1.0) * np.sqrt(pst_at_1deg * into_aperture_w / max(floor_w, 1e-300)))


# --------------------------------------------------------------------- noise
def photon_energy_j(wavelength_nm: float) -> float:
    """h c / lambda (J)."""
    return PLANCK_J_S * SPEED_OF_LIGHT_M_S / (wavelength_nm * 1e-9)


def apd_noise_sigma_w(background_w, responsivity_a_per_w: float, gain: float,
                      excess_noise_factor: float, bandwidth_hz: float,
                      amplifier_noise_a_per_rthz: float, dark_current_a: float) -> np.ndarray:
    """Noise of a linear-mode APD receiver as an equivalent optical power at its input (W, 1 sigma).

    sigma_i^2 = 2 q M^2 F (R P_bg + I_db) B + i_amp^2 B, sigma_P = sigma_i / (M R):
    shot noise of the background photocurrent and of the multiplied (bulk) dark current
    I_db, with excess noise factor F, plus the amplifier's input current noise density.
    The background's mean is AC-coupled away; only its fluctuations reach the threshold.
    """
    q, r, m = ELEMENTARY_CHARGE_C, responsivity_a_per_w, gain
    var_a2 = (2.0 * q * m * m * excess_noise_factor * (r * np.asarray(background_w, float) + dark_current_a)
              * bandwidth_hz + amplifier_noise_a_per_rthz ** 2 * bandwidth_hz)
    return np.sqrt(var_a2) / (m * r)


def rice_rate_hz(threshold_w, sigma_w, bandwidth_hz: float) -> np.ndarray:
    """Up-crossings per second (Hz) of level u by Gaussian noise of std sigma behind an ideal
    low-pass of bandwidth B: nu = B/sqrt(3) exp(-u^2 / (2 sigma^2)) (Rice 1945)."""
    z = np.asarray(threshold_w, float) / np.asarray(sigma_w, float)
    return bandwidth_hz / np.sqrt(3.0) * np.exp(-0.5 * z * z)


def photon_rate_hz(power_w, efficiency: float, wavelength_nm: float) -> np.ndarray:
    """Detected photons per second (Hz): eta P / (h c / lambda)."""
    return efficiency * np.asarray(power_w, float) / photon_energy_j(wavelength_nm)


def coincidence_rate_hz(event_rate_hz, photons: int, window_s: float) -> np.ndarray:
    """Firing rate (Hz) of a detector that needs ``photons`` detections within ``window_s``,
    for Poisson detections of rate lambda: nu = lambda P[Poisson(lambda tau) >= k - 1]
    (P[Poisson(mu) >= m] is the regularised lower incomplete gamma function P(m, mu))."""
    lam = np.asarray(event_rate_hz, float)
    if photons <= 1:
        return lam
    return lam * gammainc(photons - 1, lam * window_s)


def crossing_probability(rate_hz, duration_s) -> np.ndarray:
    """P(at least one crossing in duration_s) = 1 - exp(-nu T) for a Poisson process (-)."""
    return -np.expm1(-np.asarray(rate_hz, float) * np.clip(duration_s, 0.0, None))


def timing_jitter_range_m(noise_sigma_w, signal_w, bandwidth_hz: float) -> np.ndarray:
    """Range noise (m, 1 sigma) of a threshold detector: sigma_t = t_rise sigma / P_signal,
    t_rise = 0.35 / B, range = c t / 2 (the noise over the slope of the pulse edge; see
    Amann et al., "Laser ranging: a critical review...", Opt. Eng. 40(1), 10-19, 2001)."""
    signal = np.asarray(signal_w, float)
    ok = signal > 0
    ratio = np.divide(np.asarray(noise_sigma_w, float), signal, out=np.zeros_like(signal), where=ok)
    return 0.5 * SPEED_OF_LIGHT_M_S * RISE_TIME_BANDWIDTH_PRODUCT / bandwidth_hz * ratio
