"""Flash array (core/scan_flash.py) and its flood-lit radiometry (core/reflection.py): the
grid's directions and pixel fields of view, and a Lambertian plate filling the field
against a hand calculation of the power in each pixel."""
import math

import numpy as np
import pytest

from lidar_sim_ros.core.config import ConfigError, load_sensor, parse, SensorConfig
from lidar_sim_ros.core.geometry import Target
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import StaticPose
from lidar_sim_ros.core.scan import frame_shots
from lidar_sim_ros.core.scan_flash import pixel_solid_angle_sr
from conftest import CONFIG, materials


def flash_sensor(rows=4, cols=6, fov=(30.0, 20.0), flood=(30.0, 20.0), readout=0.0, **det):
    data = {
        'name': 'flash', 'frame_rate_hz': 10.0,
        'scan': {'type': 'flash', 'rows': rows, 'cols': cols, 'fov_az_deg': fov[0],
                 'fov_el_deg': fov[1], 'row_readout_s': readout},
        'optics': {'peak_power_w': 1000.0, 'transmit_efficiency': 0.9, 'receive_efficiency': 0.8,
                   'beam_divergence_rad': 0.01, 'aperture_diameter_m': 0.04,
                   'flood': {'field_az_deg': flood[0], 'field_el_deg': flood[1]}},
        'detection': {'threshold_power_w': 1e-15, 'saturation_power_w': 1.0, 'min_range_m': 0.1,
                      'max_range_m': 500.0, **det},
    }
    return parse(SensorConfig, data, '<test>')


def test_grid_directions_closed_form():
    """Pixel (r, c) looks along (1, u_c, v_r), u_c = tan(15 deg) (1 - (2c + 1)/6),
    v_r = tan(10 deg) (1 - (2r + 1)/4); row 0 at the top, column 0 on the left (+y)."""
    s = flash_sensor(readout=1e-3)
    shots = frame_shots(s)
    assert len(shots) == 24
    d = shots.directions()
    for r in range(4):
        for c in range(6):
            u = math.tan(math.radians(15)) * (1 - (2 * c + 1) / 6)
            v = math.tan(math.radians(10)) * (1 - (2 * r + 1) / 4)
            np.testing.assert_allclose(d[r * 6 + c], np.array([1, u, v]) / math.sqrt(1 + u * u + v * v),
                                       atol=1e-12)
    # One exposure per row, rows read 1 ms apart; laser id = row.
    np.testing.assert_array_equal(shots.t_s, np.repeat(np.arange(4) * 1e-3, 6))
    np.testing.assert_array_equal(shots.laser, np.repeat(np.arange(4), 6))
    # The pixels tile the field: their solid angles add up to the field's, 4 asin(sin a/2 sin b/2).
    total = pixel_solid_angle_sr(s.scan, d).sum()
    assert total == pytest.approx(4 * math.asin(math.sin(math.radians(15)) * math.sin(math.radians(10))),
                                  rel=1e-12)


def plate_target(range_m: float, tilt_deg: float, half_m: float = 200.0) -> Target:
    """A square plate through (range_m, 0, 0), its normal tilted by tilt_deg about z from -x."""
    t = math.radians(tilt_deg)
    normal = np.array([-math.cos(t), -math.sin(t), 0.0])
    e1 = np.array([-math.sin(t), math.cos(t), 0.0])
    e2 = np.array([0.0, 0.0, 1.0])
    c = np.array([range_m, 0.0, 0.0])
    v = np.array([c - half_m * e1 - half_m * e2, c + half_m * e1 - half_m * e2,
                  c + half_m * e1 + half_m * e2, c - half_m * e1 + half_m * e2])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    if np.dot(np.cross(v[1] - v[0], v[2] - v[0]), normal) < 0:
        faces = faces[:, ::-1]
    return Target(v, faces, np.zeros(2, int), ['PIF'])


@pytest.mark.parametrize('tilt_deg', [0.0, 30.0])
def test_lambertian_plate_power_per_pixel_by_hand(tilt_deg):
    """A 40 % Lambertian plate filling the field, 20 m ahead, tilted 0 or 30 deg.

    By hand, for the pixel whose centre looks along d: the plate is met at
    r = R cos(t) / (d . m) (m the plate's unit normal toward the sensor's side, reversed),
    at incidence cos(i) = d . m; the pulse spreads over Omega_illum = 4 asin(sin 15 sin 10),
    E = P_o tau_t / (Omega_illum r^2); the pixel sees Omega_pix r^2 / cos(i) of the
    plate, whose radiance (rho/pi) E cos(i) reaches the aperture pi (D/2)^2 / r^2 away:
    P = (rho/pi) E cos(i) (Omega_pix r^2 / cos(i)) cos(i) tau_r pi (D/2)^2 / r^2."""
    s = flash_sensor()
    sim = Simulator(s, materials(kd=0.4, ks=0.0), plate_target(20.0, tilt_deg), seed=1)
    shots = sim.shots
    pred = sim.predict(np.zeros(len(shots)), shots.directions(), StaticPose((0.0, 0.0, 0.0)))
    assert pred.ctx.hit.all()
    t = math.radians(tilt_deg)
    m = np.array([math.cos(t), math.sin(t), 0.0])
    omega_illum = 4 * math.asin(math.sin(math.radians(15)) * math.sin(math.radians(10)))
    du, dv = 2 * math.tan(math.radians(15)) / 6, 2 * math.tan(math.radians(10)) / 4

    def rect(u0, u1, v0, v1):                  # solid angle of a rectangle on x = 1
        def f(u, v):
            return math.atan(u * v / math.sqrt(1 + u * u + v * v))
        return f(u1, v1) - f(u0, v1) - f(u1, v0) + f(u0, v0)

    for k, d in enumerate(shots.directions()):
        cos_i = float(d @ m)
        r = 20.0 * math.cos(t) / cos_i
        u, v = d[1] / d[0], d[2] / d[0]
        omega_pix = rect(u - du / 2, u + du / 2, v - dv / 2, v + dv / 2)
        e = 1000.0 * 0.9 / (omega_illum * r * r)
        p = (0.4 / math.pi) * e * cos_i * (omega_pix * r * r / cos_i) * cos_i * 0.8 \
            * math.pi * 0.02 ** 2 / r ** 2
        assert pred.ctx.range_m[k] == pytest.approx(r, rel=1e-6)
        assert pred.ctx.power_w[k] == pytest.approx(p, rel=1e-5)
    # Against a scanning beam on the same plate: each pixel gets Omega_pix / Omega_illum of it.
    centre = np.argmin(np.abs(shots.az_rad) + np.abs(shots.el_rad))
    beam = 1000.0 * 0.9 * 0.8 * 0.4 / math.pi * math.cos(math.radians(tilt_deg)) \
        * math.pi * 0.02 ** 2 / pred.ctx.range_m[centre] ** 2
    d = shots.directions()[centre]
    assert pred.ctx.power_w[centre] / beam == pytest.approx(
        rect(d[1] / d[0] - du / 2, d[1] / d[0] + du / 2, d[2] / d[0] - dv / 2, d[2] / d[0] + dv / 2)
        / omega_illum * float(d @ m) / math.cos(t), rel=1e-5)


def test_pixels_outside_the_flood_get_no_light():
    s = flash_sensor(flood=(16.0, 20.0))     # lights only the middle two of six columns
    sim = Simulator(s, materials(kd=0.4, ks=0.0), plate_target(20.0, 0.0), seed=1)
    pred = sim.predict(np.zeros(len(sim.shots)), sim.shots.directions(), StaticPose((0.0, 0.0, 0.0)))
    lit = np.abs(np.degrees(sim.shots.az_rad)) < 8.0
    assert np.all(pred.ctx.power_w[lit] > 0) and np.all(pred.ctx.power_w[~lit] == 0)


def test_flash_256_profile_threshold_and_frame():
    f = load_sensor(CONFIG / 'flash_256.yaml')
    shots = frame_shots(f)
    assert len(shots) == 65536 and np.all(shots.t_s == 0.0)
    # The threshold: a 10 % Lambertian plate at 500 m in the boresight pixels' field.
    o = f.optics
    omega_illum = 4 * math.asin(math.sin(math.radians(11)) ** 2)
    half = math.tan(math.radians(10)) / 256
    omega_pix = 4 * math.atan(half * half / math.sqrt(1 + 2 * half * half))
    p = o.peak_power_w * o.transmit_efficiency * o.receive_efficiency * 0.1 \
        * (o.aperture_diameter_m / 2) ** 2 * omega_pix / (omega_illum * 500.0 ** 2)
    assert p == pytest.approx(f.detection.threshold_power_w, rel=1e-9)


@pytest.mark.parametrize('change, words', [
    ({'optics': {'flood': None}}, 'needs optics.flood'),
    ({'scan': {'row_readout_s': 0.05}}, 'does not fit the frame period'),
    ({'scan': {'rows': 0}}, 'greater than or equal to 1'),
    ({'scan': {'fov_az_deg': float('inf')}}, 'finite'),
    ({'scan': {'rows': 1024, 'cols': 5000}}, 'exceed the limit'),
    # A row is the laser id: 2000 rows wrote rings that compare and calibrate refuse on
    # reading the simulator's own bag ("laser ids must be whole numbers in [0, 1024)").
    ({'scan': {'rows': 1025}}, 'less than or equal to 1024'),
])
def test_bad_flash_config_names_key(change, words):
    data = flash_sensor().model_dump()
    for key, sub in change.items():
        data[key] = {**data[key], **sub}
    with pytest.raises(ConfigError, match=words):
        parse(SensorConfig, data, '<test>')


def test_flood_on_a_scanning_sensor_refused():
    from conftest import sensor
    data = sensor().model_dump()
    data['optics']['flood'] = {'field_az_deg': 10.0, 'field_el_deg': 10.0}
    with pytest.raises(ConfigError, match='for a flash scan'):
        parse(SensorConfig, data, '<test>')


def test_one_pose_for_a_global_exposure_same_frame_as_a_pose_per_pixel(monkeypatch):
    """A flash frame's pixels share one exposure time: the pipeline interpolates the pose
    once and repeats it; the frame is the one a pose per pixel gives."""
    from lidar_sim_ros.core import pipeline
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    sc = load_scenario(CONFIG / 'scenario_flash.yaml')
    sim = Simulator.from_scenario(sc)
    traj = ScenarioTrajectory.from_config(sc.config)
    once = sim.simulate_frame(0.3, traj, 3)
    monkeypatch.setattr(pipeline, '_poses_at', lambda source, t: source.at(t))
    each = sim.simulate_frame(0.3, traj, 3)
    assert len(once) > 10000
    np.testing.assert_allclose(once.xyz_m, each.xyz_m, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(once.material, each.material)


def test_flash_256_threshold_sits_at_5_5_sigma_of_its_dark_noise():
    """As the P-60's receiver: a pixel's dark noise far enough below the threshold that it
    does not trigger (a receiver's noise at the P-60's level fired every pixel)."""
    from lidar_sim_ros.core.radiometry import apd_noise_sigma_w
    f = load_sensor(CONFIG / 'flash_256.yaml')
    r = f.receiver
    sigma = apd_noise_sigma_w(0.0, r.responsivity_a_per_w, r.apd_gain, r.excess_noise_factor,
                              r.bandwidth_hz, r.amplifier_noise_a_per_rthz, r.dark_current_a)
    assert f.detection.threshold_power_w / sigma == pytest.approx(5.5, abs=0.05)


@pytest.mark.parametrize('fov, flood, key', [((30.0, 20.0), (1e-300, 20.0), 'field_az_deg'),
                                             ((30.0, 1e-300), (30.0, 20.0), 'fov_el_deg')])
def test_fields_narrower_than_a_milli_degree_are_refused(fov, flood, key):
    """A 1e-300 deg flood's solid angle underflowed to 0: every pixel's power was NaN
    (divide by zero) and the frame silently empty; a 1e-300 deg array saw nothing."""
    with pytest.raises(ConfigError, match=f'{key}.*1e-300|1e-300.*{key}') as err:
        flash_sensor(fov=fov, flood=flood)
    assert 'greater than or equal to 0.001' in str(err.value)


def test_the_narrowest_field_still_has_finite_power():
    s = flash_sensor(fov=(1e-3, 1e-3), flood=(1e-3, 1e-3))
    sim = Simulator(s, materials(kd=0.4, ks=0.0), plate_target(20.0, 0.0), seed=1)
    pred = sim.predict(np.zeros(len(sim.shots)), sim.shots.directions(), StaticPose((0.0, 0.0, 0.0)))
    assert pred.ctx.hit.all() and np.all(np.isfinite(pred.ctx.power_w)) and np.all(pred.ctx.power_w > 0)
