"""The compiled per-hit reflection and detector loops (``core/reflection_kernels.py``)
against the numpy model they stand for (``reflection.return_power_w``,
``detection.detected_mask``): the same numbers to the bit, for a beam and a flood."""
import numpy as np
import pytest

from lidar_sim_ros.core import detection, reflection, reflection_kernels
from lidar_sim_ros.core.config import load_sensor
from lidar_sim_ros.paths import config_path
from conftest import sensor

KD = np.array([0.45, 0.05, 0.15, 0.0, 0.83])
KS = np.array([0.02, 0.90, 0.45, 0.7, 0.0])
N = np.array([1.0, 20.0, 10.0, 500.0, 5.0])
BIAS = np.array([-0.1383, -0.1349, 0.0, 0.05, -0.12])
SIGMA = np.sqrt(np.array([0.0281, 0.03075, 0.0, 0.05, 0.04]) ** 2)


def _hits(rng, h, det):
    """Hits spread over every case: grazing (cos below reflection._MIN_COS), normal, the
    lobe's clip at cos(alpha) < 0, ranges across the gate, each material."""
    cos = np.concatenate([rng.random(h - 6), [0.0, 1e-12, 1e-9, 0.5 ** 0.5, 1.0, 0.999999]])
    range_m = np.concatenate([rng.uniform(0.5 * det.min_range_m, 1.2 * det.max_range_m, h - 2),
                              [det.min_range_m, det.max_range_m]])
    return range_m, cos, rng.integers(0, len(KD), h).astype(np.int16)


@pytest.mark.parametrize('flood', [False, True])
def test_plain_returns_are_the_numpy_models_numbers_to_the_bit(flood):
    s = load_sensor(config_path('flash_256.yaml')) if flood else sensor()
    optics, det = s.optics, s.detection
    rng = np.random.default_rng(7)
    h = 20_000
    range_m, cos, material = _hits(rng, h, det)
    rows = rng.permutation(3 * h)[:h]
    pixel_sr = rng.uniform(1e-7, 2e-6, 3 * h)
    sr = pixel_sr.take(rows) if flood else None
    power = reflection.return_power_w(range_m, None, KD.take(material), KS.take(material),
                                      N.take(material), optics, cos, sr)
    # Thresholds that cut through the powers drawn, so both sides of each are tested.
    thr, sat = np.quantile(power, [0.2, 0.9])
    det = det.model_copy(update={'threshold_power_w': float(thr), 'saturation_power_w': float(sat)})
    illuminated = (reflection.flood_solid_angle_sr(np.radians(optics.flood.field_az_deg),
                                                   np.radians(optics.flood.field_el_deg))
                   if flood else 1.0)
    lobe = reflection_kernels.lobe_of(cos, material, N)
    got = reflection_kernels.plain_returns_of(
        range_m, cos, material, lobe, rows, pixel_sr if flood else np.zeros(0),
        *reflection_kernels.brdf_terms_of(KD, KS, N), BIAS, SIGMA, flood,
        optics.peak_power_w * optics.transmit_efficiency, illuminated,
        optics.beam_divergence_rad, optics.receive_efficiency,
        np.pi * (optics.aperture_diameter_m / 2.0) ** 2, det.threshold_power_w,
        det.saturation_power_w, det.min_range_m, det.max_range_m)
    want = (power, BIAS.take(material), SIGMA.take(material),
            detection.detected_mask(power, range_m, det))
    for g, w in zip(got, want):
        assert g.dtype == w.dtype
        assert g.tobytes() == w.tobytes()
    detected = want[3]
    assert 0 < np.count_nonzero(detected) < h        # the window cuts both ways
    assert np.count_nonzero(cos < 0.5 ** 0.5) > 0     # and the lobe's clip is reached


def test_the_lobe_is_numpys_power_not_libms():
    """cos(alpha)^n is numpy's power on the clipped cos(alpha) of 2 cos^2 - 1 (the numbers
    ``phong_brdf_cos`` raises), whatever libm's pow would give."""
    cos = np.linspace(0.0, 1.0, 5001)
    material = (np.arange(len(cos)) % len(N)).astype(np.int16)
    n = N.take(material)
    want = np.clip(reflection.monostatic_cos_alpha(cos), 0.0, 1.0) ** n
    assert reflection_kernels.lobe_of(cos, material, N).tobytes() == want.tobytes()
