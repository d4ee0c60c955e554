"""Detection model (paper Secs. 6-7): dropouts, range bias and noise, intensity.

A return is detected when threshold <= P_r < saturation (weaker returns are lost
in the detector, saturated ones are omitted, as the paper does). The measured
range is true range + bias + N(0, sigma^2); bias is measured minus true.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.core.config import DetectionConfig


def detected_mask(power_w: np.ndarray, range_m: np.ndarray, det: DetectionConfig) -> np.ndarray:
    """Which returns the detector reports: inside [threshold, saturation) and the range gate."""
    power_w = np.asarray(power_w)
    range_m = np.asarray(range_m)
    return ((power_w >= det.threshold_power_w) & (power_w < det.saturation_power_w)
            & (range_m >= det.min_range_m) & (range_m <= det.max_range_m))


def in_range_gate(measured_range_m: np.ndarray, det: DetectionConfig) -> np.ndarray:
    """Which measured ranges (m) the sensor can report: finite, positive and inside the
    range gate [min_range_m, max_range_m]. Applied after bias, noise and every effect
    (``detected_mask`` gates the true range): no effect parameter publishes a point
    beyond the gate (a range walk of k_m = -1e6 put points 12 km to 6,680 km away)."""
    r = np.asarray(measured_range_m, float)
    with np.errstate(invalid='ignore'):
        return np.isfinite(r) & (r > 0) & (r >= det.min_range_m) & (r <= det.max_range_m)


def measured_range_m(true_range_m: np.ndarray, bias_m: np.ndarray, sigma_m: np.ndarray,
                     rng: np.random.Generator | np.ndarray) -> np.ndarray:
    """True range plus bias plus zero-mean Gaussian noise of std sigma (all metres).

    ``rng``: the generator to draw the noise from, or the standard normal draws themselves
    (one per range: a frame draws them once, then measures its shots in parts).
    """
    true_range_m = np.asarray(true_range_m, dtype=float)
    noise = rng.standard_normal(true_range_m.shape) if isinstance(rng, np.random.Generator) else rng
    return true_range_m + bias_m + sigma_m * noise


def intensity_from_power(power_w: np.ndarray, det: DetectionConfig) -> np.ndarray:
    """Reported intensity: received power as a fraction of saturation power (-), in (0, 1)."""
    return np.asarray(power_w) / det.saturation_power_w


def power_from_intensity(intensity: np.ndarray, det: DetectionConfig) -> np.ndarray:
    """Inverse of intensity_from_power (W)."""
    return np.asarray(intensity) * det.saturation_power_w
