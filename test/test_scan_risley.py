"""Risley-prism scan (core/scan_risley.py): the rosette's period and petals from the prism
rates, the circular field, the shot rate, and the Mid-40 profile's published numbers."""
import numpy as np
import pytest

from lidar_sim_ros.core.config import ConfigError, load_sensor, parse, SensorConfig
from lidar_sim_ros.core.scan import frame_shots, varies_by_frame
from lidar_sim_ros.core.scan_risley import (field_half_angle_rad, petals_per_period,
                                           rosette_period_s, risley_shots)
from conftest import CONFIG, sensor


def risley(rates=(10.0, -7.0), dev=(5.0, 5.0), rate_hz=20000.0, frame_rate_hz=1.0, phase=(0.0, 0.0)):
    return sensor({'type': 'risley', 'prism_rates_hz': list(rates), 'prism_deviation_deg': list(dev),
                   'prism_phase_rad': list(phase), 'shot_rate_hz': rate_hz}) if frame_rate_hz == 10.0 \
        else parse(SensorConfig, {**sensor().model_dump(), 'frame_rate_hz': frame_rate_hz,
                                  'scan': {'type': 'risley', 'prism_rates_hz': list(rates),
                                           'prism_deviation_deg': list(dev),
                                           'prism_phase_rad': list(phase),
                                           'shot_rate_hz': rate_hz}}, '<test>')


def off_axis_rad(shots):
    d = shots.directions()
    return np.arccos(np.clip(d[:, 0], -1, 1))


def petal_tips(theta):
    """Local maxima of the off-axis angle along the (closed) track."""
    return int(np.sum((theta > np.roll(theta, 1)) & (theta >= np.roll(theta, -1))))


@pytest.mark.parametrize('rates, period, petals', [
    ((10.0, -7.0), 1.0, 17),     # counter-rotating: |10 + 7| tips a second, closes after 1 s
    ((12.0, 8.0), 0.25, 1),      # co-rotating 3:2: gcd 4 rev/s, |12 - 8| / 4 = 1 tip
    ((9.0, -6.0), 1 / 3, 5),     # 3:-2 at gcd 3 rev/s: 15 / 3 = 5 tips
])
def test_rosette_period_and_petals_closed_form(rates, period, petals):
    assert rosette_period_s(rates) == pytest.approx(period)
    assert petals_per_period(rates) == petals
    # The simulated track over exactly one period: that many petal tips, and it closes.
    s = risley(rates, frame_rate_hz=1.0 / period, rate_hz=40000.0 / period)
    a = frame_shots(s, frame_index=0)
    assert petal_tips(off_axis_rad(a)) == petals
    b = frame_shots(s, frame_index=1)              # one period later: the same shots
    np.testing.assert_allclose(b.directions(), a.directions(), atol=1e-9)
    half = risley(rates, frame_rate_hz=2.0 / period, rate_hz=40000.0 / period)
    c = frame_shots(half, frame_index=1)           # half a period later: elsewhere
    assert np.max(np.abs(c.directions() - a.directions()[:len(c)])) > 1e-2


def test_shot_directions_closed_form():
    """Prisms at 0 and 90 deg: the deviation vector (d1, d2) points to arg = atan2(d2, d1)."""
    s = risley(rates=(10.0, -7.0), dev=(6.0, 3.0), phase=(0.0, np.pi / 2))
    shot = frame_shots(s)
    d = shot.directions()[0]
    theta = np.hypot(np.radians(6.0), np.radians(3.0))
    psi = np.arctan2(3.0, 6.0)
    np.testing.assert_allclose(d, [np.cos(theta), np.sin(theta) * np.cos(psi),
                                   np.sin(theta) * np.sin(psi)], atol=1e-12)


def test_all_shots_in_circular_field_and_reach_its_rim():
    s = risley(rates=(121.5667, -77.7333), dev=(9.6, 9.6), rate_hz=100000.0, frame_rate_hz=10.0)
    th = off_axis_rad(frame_shots(s))
    half = np.radians(19.2)
    assert field_half_angle_rad(s.scan) == pytest.approx(half)
    assert th.max() <= half + 1e-12
    assert th.max() > half * 0.999                  # petal tips touch the rim
    assert th.min() < half * 0.05                   # and the track passes the centre


def test_mid40_profile_published_numbers():
    mid = load_sensor(CONFIG / 'livox_mid40.yaml')
    assert varies_by_frame(mid)
    shots = [frame_shots(mid, frame_index=k) for k in range(3)]
    # 100,000 shots per second: 10,000 a 100 ms frame, 10 us apart, inside the frame.
    for sh in shots:
        assert len(sh) == 10000
        np.testing.assert_allclose(np.diff(sh.t_s), 1e-5, rtol=1e-9)
        assert sh.t_s[0] == 0.0 and sh.t_s[-1] < mid.frame_period_s
        assert off_axis_rad(sh).max() <= np.radians(38.4 / 2) + 1e-12
    # Consecutive frames continue the prisms' turn: frame 1's first shot is where the
    # prisms are 100 ms after frame 0's first.
    direct = risley_shots(mid.scan, 0.1001, 0)       # a frame just longer than 0.1 s
    np.testing.assert_allclose(shots[1].directions()[0], direct.directions()[10000], atol=1e-9)
    assert not np.allclose(shots[1].directions(), shots[0].directions(), atol=1e-3)
    # Its own range errors, not the P-60's Table 2: 2 cm at 1 sigma, no published bias.
    assert (mid.range_error.sigma_m, mid.range_error.bias_m) == (0.02, 0.0)
    # The threshold puts a 10 % Lambertian plate exactly at 90 m (published), and the
    # published 20 % @ 130 m and 80 % @ 260 m within 5 % of it.
    o, det = mid.optics, mid.detection
    def power(rho, r):
        return o.peak_power_w * o.transmit_efficiency * o.receive_efficiency * rho \
            * (o.aperture_diameter_m / 2) ** 2 / r ** 2
    assert power(0.1, 90.0) == pytest.approx(det.threshold_power_w)
    assert power(0.2, 130.0) / det.threshold_power_w == pytest.approx(1.0, abs=0.05)
    assert power(0.8, 260.0) / det.threshold_power_w == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize('scan, words', [
    ({'prism_rates_hz': [10.0, 10.0]}, 'different rates'),
    ({'prism_rates_hz': [0.0, 3.0]}, 'both prisms must turn'),
    ({'prism_deviation_deg': [50.0, 45.0]}, 'less than 90'),
    ({'prism_deviation_deg': [float('nan'), 1.0]}, 'finite'),
    ({'shot_rate_hz': 1e300}, 'exceed the limit'),
    ({'shot_rate_hz': 1e-300}, 'fires no shot'),
    ({'prism_rates_hz': [1e300, 3.0]}, 'less than or equal to 10000'),
    ({'prism_rates_hz': [3.0]}, 'prism_rates_hz'),
    ({'prism_phase_rad': [float('inf'), 0.0]}, 'finite'),
    ({'prism_phase_rad': [0.0, 1e300]}, 'less than or equal to 10000'),  # arbitrary angle, once rc 0
])
def test_bad_risley_config_names_key(scan, words):
    base = {'type': 'risley', 'prism_rates_hz': [10.0, -7.0], 'prism_deviation_deg': [5.0, 5.0],
            'shot_rate_hz': 1000.0, **scan}
    with pytest.raises(ConfigError, match=words) as err:
        sensor(base)
    assert 'key "scan' in str(err.value)


def test_mid40_scenario_uses_its_own_range_error_not_table_2():
    """Loaded with the Mid-40, every material carries 2 cm / no bias; the P-60 scenario
    keeps Table 2's per-material values."""
    from lidar_sim_ros.core.scenario import load_scenario
    mid = load_scenario(CONFIG / 'scenario_mid40.yaml')
    assert set(mid.materials.column('sigma_m')) == {0.02}
    assert set(mid.materials.column('bias_m')) == {0.0}
    p60 = load_scenario(CONFIG / 'scenario.yaml')
    assert p60.materials.column('bias_m')[1] == pytest.approx(-0.1349)
    assert mid.materials.names == p60.materials.names


def test_coverage_grows_with_integration_time_unless_the_rosette_closes():
    """The Mid-40's rates have no small ratio: the field fills (0.28 deg cells: ~20 % in
    100 ms, >90 % in 1 s); rates 10 and -7 rev/s close after 1 s and cover no more after."""
    from lidar_sim_ros.core.scan_risley import field_coverage
    mid = load_sensor(CONFIG / 'livox_mid40.yaml').scan
    cell = np.radians(0.28)
    cover = [field_coverage(mid, t, cell) for t in (0.1, 0.2, 0.5, 1.0)]
    assert all(b > a for a, b in zip(cover, cover[1:]))
    assert 0.1 < cover[0] < 0.35 and cover[-1] > 0.9
    closed = risley(rates=(10.0, -7.0), dev=(9.6, 9.6), rate_hz=100000.0).scan
    one, two = field_coverage(closed, 1.0, cell), field_coverage(closed, 2.0, cell)
    assert two == one < 0.9


def _angle_between_rad(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum('ij,ij->i', a, b))


def test_frames_at_wall_clock_indices_keep_their_precision():
    """The node numbers its frames on the wall clock (k ~ 1.8e10 at 10 Hz, t ~ 1.8e9 s):
    2 pi f (k T + t) at 1e12 rad holds ~1e-4 rad in float64, and k T + t holds 2.4e-7 s.
    Closed form: prisms at 100 and -72.25 rev/s with T = 0.125 s have both turned whole
    revolutions at k = 1.8e10 (t = 2.25e9 s), so that frame's shots are frame 0's, to
    1e-6 rad. And on the Mid-40's own rates, frame k against each shot's turns in 40-digit
    decimal arithmetic."""
    from decimal import Decimal, getcontext
    from lidar_sim_ros.core.scan_risley import (deviation_rad, directions_from_deviation,
                                               risley_frame)
    cfg = risley(rates=(100.0, -72.25), rate_hz=20000.0, frame_rate_hz=8.0)
    k = 18_000_000_000
    (_, d0), (_, dk) = risley_frame(cfg.scan, 0.125, 0), risley_frame(cfg.scan, 0.125, k)
    assert _angle_between_rad(d0, dk).max() < 1e-6
    mid40 = load_sensor(CONFIG / 'livox_mid40.yaml')
    scan, period = mid40.scan, mid40.frame_period_s
    k = int(1.8e9 / period)
    shots, dk = risley_frame(scan, period, k)
    getcontext().prec = 40
    pick = np.arange(0, len(shots), 997)
    turns = [[float((Decimal(f) * (k * Decimal(period) + Decimal(float(t)))) % 1)
              for t in shots.t_s[pick]] for f in scan.prism_rates_hz]
    phi = [p + 2 * np.pi * np.array(u) for p, u in zip(scan.prism_phase_rad, turns)]
    exact = directions_from_deviation(*deviation_rad(scan, *phi))
    assert _angle_between_rad(exact, dk[pick]).max() < 1e-6
