"""Reflection model (paper Sec. 5): modified Phong BRDF and received power, Eqs. 1-5.

Symbols and units (paper notation in brackets):
  P_o  peak transmitted power (W)            tau_t, tau_r  transmit/receive efficiency (-)
  r    range to the surface (m)              dtheta  full beam divergence angle (rad)
  theta  incidence angle = theta_o for the monostatic sensor (rad)
  D    receiver aperture diameter (m)        f_BRDF  BRDF (1/sr)
  E_laser  irradiance across the beam (W/m^2) L_laser  reflected radiance (W/(sr m^2))
  A(r) illuminated footprint on the surface (m^2)   P_r  received power (W)
"""
from __future__ import annotations

import functools

import numpy as np

from lidar_sim_ros.core.config import OpticsConfig

_MIN_COS = 1e-9


def phong_brdf(alpha_rad, kd, ks, n):
    """Modified Phong BRDF (1/sr), paper Eq. 5 (Lafortune & Willems normalisation).

    f = kd/pi + ks (n+2)/(2 pi) cos^n(alpha); alpha is the angle between the mirror
    direction and the outgoing direction. The lobe is zero beyond alpha = pi/2.
    With kd + ks <= 1 the directional albedo never exceeds 1.
    """
    return phong_brdf_cos(np.cos(alpha_rad), kd, ks, n)


def phong_brdf_cos(cos_alpha, kd, ks, n):
    """``phong_brdf`` from cos(alpha) (-) instead of alpha (1/sr)."""
    cos_a = np.clip(cos_alpha, 0.0, 1.0)
    return np.asarray(kd) / np.pi + np.asarray(ks) * (np.asarray(n) + 2.0) / (2.0 * np.pi) * cos_a ** np.asarray(n)


def monostatic_alpha(incidence_rad):
    """alpha (rad) for a co-located emitter and receiver: the mirror ray is 2*theta off the return."""
    return 2.0 * np.asarray(incidence_rad)


def monostatic_cos_alpha(cos_incidence):
    """cos(alpha) = cos(2 theta) = 2 cos^2(theta) - 1 for the monostatic sensor (-)."""
    cos_t = np.asarray(cos_incidence)
    return 2.0 * cos_t * cos_t - 1.0


def specular_alpha(theta_in_rad, phi_in_rad, theta_out_rad, phi_out_rad):
    """alpha (rad) between the mirror direction of (theta_in, phi_in) and (theta_out, phi_out).

    Angles are the goniometer's: polar from the surface normal, azimuth about it.
    The mirror direction of incoming light from (theta_in, phi_in) leaves at
    (theta_in, phi_in + pi).
    """
    cos_a = (np.cos(theta_in_rad) * np.cos(theta_out_rad)
             + np.sin(theta_in_rad) * np.sin(theta_out_rad) * np.cos(phi_out_rad - phi_in_rad - np.pi))
    return np.arccos(np.clip(cos_a, -1.0, 1.0))


def laser_irradiance_w_m2(range_m, peak_power_w, tau_t, divergence_rad):
    """E_laser = P_o tau_t / (pi (r dtheta / 2)^2), paper Eq. 2 (W/m^2)."""
    return peak_power_w * tau_t / (np.pi * (np.asarray(range_m) * divergence_rad / 2.0) ** 2)


@functools.lru_cache(maxsize=64)
def flood_solid_angle_sr(field_az_rad: float, field_el_rad: float) -> float:
    """Omega_illum (sr) of a flood lighting a rectangular field of full angles a x b:
    4 asin(sin(a/2) sin(b/2))."""
    return float(4.0 * np.arcsin(np.sin(field_az_rad / 2.0) * np.sin(field_el_rad / 2.0)))


def flood_irradiance_w_m2(range_m, peak_power_w, tau_t, illuminated_sr):
    """E = P_o tau_t / (Omega_illum r^2) (W/m^2): Eq. 2 for one pulse spread evenly over the
    illuminated solid angle (a flash LiDAR); Eq. 2 itself is this with Omega = pi (dtheta/2)^2."""
    return peak_power_w * tau_t / (illuminated_sr * np.asarray(range_m) ** 2)


def laser_radiance(f_brdf, irradiance_w_m2, cos_theta):
    """L_laser = f_BRDF E_laser cos(theta_o), paper Eq. 1 (W/(sr m^2))."""
    return f_brdf * irradiance_w_m2 * cos_theta


def footprint_area_m2(range_m, divergence_rad, cos_theta):
    """A(r): the beam's cross-section pi (r dtheta/2)^2 stretched by 1/cos(theta) on the surface."""
    return np.pi * (np.asarray(range_m) * divergence_rad / 2.0) ** 2 / np.maximum(cos_theta, _MIN_COS)


def pixel_footprint_area_m2(range_m, pixel_sr, cos_theta):
    """A(r) of a flood-lit surface seen by one pixel: its field of view Omega_pix r^2
    stretched by 1/cos(theta) on the surface (m^2); the beam's spot is wider than it."""
    return np.asarray(pixel_sr) * np.asarray(range_m) ** 2 / np.maximum(cos_theta, _MIN_COS)


def received_power_w(radiance, tau_r, area_m2, cos_theta, aperture_diameter_m, range_m):
    """P_r = L tau_r A(r) cos(theta_o) 4 pi [pi (D/2)^2 / (4 pi r^2)], paper Eq. 3 (W)."""
    aperture_fraction = np.pi * (aperture_diameter_m / 2.0) ** 2 / (4.0 * np.pi * np.asarray(range_m) ** 2)
    return radiance * tau_r * area_m2 * cos_theta * 4.0 * np.pi * aperture_fraction


def return_power_w(range_m, incidence_rad, kd, ks, n, optics: OpticsConfig, cos_incidence=None,
                   pixel_sr=None):
    """Received power (W) of a monostatic shot hitting a surface: Eqs. 1-3 with Eq. 5.

    ``kd, ks, n`` are per-shot arrays (or scalars) of the material hit;
    ``cos_incidence``: cos(incidence_rad) if the caller has it (saves two cosines).
    A flood-lit sensor (``optics.flood``, a flash array) needs ``pixel_sr``: each shot's
    pixel field of view (sr; 0 where the flood does not light it, ``scan_flash.pixel_view_sr``).
    The irradiance is then the pulse spread over the flood's solid angle and the surface
    seen is the pixel's footprint, not the beam's: the same Eqs. 1, 3 and 5, so that
    P_r = P_o tau_t tau_r f cos(theta) pi (D/2)^2 / r^2 x Omega_pix / Omega_illum.
    """
    cos_t = np.cos(incidence_rad) if cos_incidence is None else np.asarray(cos_incidence)
    f = phong_brdf_cos(monostatic_cos_alpha(cos_t), kd, ks, n)
    if optics.flood is None:
        e = laser_irradiance_w_m2(range_m, optics.peak_power_w, optics.transmit_efficiency,
                                  optics.beam_divergence_rad)
        area = footprint_area_m2(range_m, optics.beam_divergence_rad, cos_t)
    else:
        if pixel_sr is None:
            raise ValueError('a flood-lit sensor needs each shot\'s pixel solid angle (pixel_sr)')
        illuminated = flood_solid_angle_sr(np.radians(optics.flood.field_az_deg),
                                           np.radians(optics.flood.field_el_deg))
        e = flood_irradiance_w_m2(range_m, optics.peak_power_w, optics.transmit_efficiency,
                                  illuminated)
        area = pixel_footprint_area_m2(range_m, pixel_sr, cos_t)
    radiance = laser_radiance(f, e, cos_t)
    return received_power_w(radiance, optics.receive_efficiency, area, cos_t,
                            optics.aperture_diameter_m, range_m)
