"""Compiled per-hit loops of the reflection model and the detector (numba), for a plain
frame's hits (``Simulator._plain_frame``: each part of the cast on its own thread).

``reflection.return_power_w`` and ``detection.detected_mask`` (numpy) are the model and
the reference: ``test/test_reflection_kernels.py`` checks these loops against them bit
for bit. They are the same operations in the same order (no fast-math), split in two
around the Phong lobe's power cos(alpha)^n, which stays numpy's (``lobe_of``): numpy's
``power`` on this machine's AVX-512 differs from libm's ``pow`` (what a compiled loop
calls) in the last bit of ~5 % of values. Together: one pass over the hits, numpy's
power, one pass, where the numpy form took ~25 passes and as many temporary arrays a
part (a flash frame's ~19,000 hits in four parts).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from lidar_sim_ros.core.reflection import _MIN_COS


@njit(cache=True, nogil=True)
def lobe_base_of(cos_incidence, material, n_of):
    """Per hit, cos(alpha) of the monostatic sensor clipped to [0, 1] (-) and the Phong
    exponent of its material (``n_of[material]``): the base and the exponent of the lobe
    (``reflection.phong_brdf_cos``, ``monostatic_cos_alpha``)."""
    h = cos_incidence.shape[0]
    cos_a = np.empty(h)
    n = np.empty(h)
    for k in range(h):
        c = cos_incidence[k]
        a = 2.0 * c * c - 1.0
        # np.clip(a, 0, 1): NaN stays NaN.
        if a < 0.0:
            a = 0.0
        elif a > 1.0:
            a = 1.0
        cos_a[k] = a
        n[k] = n_of[material[k]]
    return cos_a, n


def lobe_of(cos_incidence: np.ndarray, material: np.ndarray, n_of: np.ndarray) -> np.ndarray:
    """cos(alpha)^n per hit (-): the Phong lobe, numpy's power on ``lobe_base_of``."""
    cos_a, n = lobe_base_of(cos_incidence, material, n_of)
    return np.power(cos_a, n, out=cos_a)


def brdf_terms_of(kd: np.ndarray, ks: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per material, the BRDF's diffuse term kd / pi (1/sr) and the factor of its lobe
    ks (n + 2) / (2 pi) (1/sr), as ``reflection.phong_brdf_cos`` computes them for each hit
    (the same operations on the same numbers: the same bits)."""
    kd, ks, n = np.asarray(kd, float), np.asarray(ks, float), np.asarray(n, float)
    return kd / np.pi, ks * (n + 2.0) / (2.0 * np.pi)


@njit(cache=True, nogil=True)
def plain_returns_of(range_m, cos_incidence, material, lobe, rows, pixel_sr, diffuse_of,
                     specular_of, bias_of, sigma_of, flood, irradiance_num, illuminated_sr,
                     divergence_rad, tau_r, aperture_m2, threshold_w, saturation_w,
                     min_range_m, max_range_m):
    """Received power (W), the material's range bias and sigma (m) and the detector's mask
    of each hit: ``reflection.return_power_w`` and ``detection.detected_mask``, number for
    number.

    range_m, cos_incidence, material (H,): the hits (``HitRows``); lobe (H,):
    ``lobe_of``; rows (H,): each hit's row of ``pixel_sr`` (sr per ray, a flood-lit
    sensor's pixel field of view; read only with ``flood``); per material:
    ``brdf_terms_of``'s two terms, the range bias and sigma. irradiance_num = P_o tau_t
    (W); ``flood``: E = irradiance_num / (illuminated_sr r^2) over the pixel's footprint,
    else Eq. 2's beam of full divergence ``divergence_rad`` over its footprint; tau_r
    (-); aperture_m2 = pi (D/2)^2; the detector's window: threshold_w <= power <
    saturation_w, min_range_m <= r <= max_range_m.
    """
    h = range_m.shape[0]
    power = np.empty(h)
    bias = np.empty(h)
    sigma = np.empty(h)
    detected = np.empty(h, np.bool_)
    four_pi = 4.0 * np.pi
    for k in range(h):
        r, c, m = range_m[k], cos_incidence[k], material[k]
        # phong_brdf_cos
        f = diffuse_of[m] + specular_of[m] * lobe[k]
        r2 = r * r
        # np.maximum(cos, _MIN_COS): NaN stays NaN.
        c_min = _MIN_COS if c < _MIN_COS else c
        if flood:
            e = irradiance_num / (illuminated_sr * r2)                 # flood_irradiance_w_m2
            area = pixel_sr[rows[k]] * r2 / c_min                      # pixel_footprint_area_m2
        else:
            spot = r * divergence_rad / 2.0
            e = irradiance_num / (np.pi * (spot * spot))               # laser_irradiance_w_m2
            area = np.pi * (spot * spot) / c_min                       # footprint_area_m2
        radiance = f * e * c                                           # laser_radiance
        aperture_fraction = aperture_m2 / (four_pi * r2)               # received_power_w
        p = radiance * tau_r * area * c * 4.0 * np.pi * aperture_fraction
        power[k] = p
        bias[k] = bias_of[m]
        sigma[k] = sigma_of[m]
        detected[k] = ((p >= threshold_w) & (p < saturation_w)
                       & (r >= min_range_m) & (r <= max_range_m))
    return power, bias, sigma, detected
