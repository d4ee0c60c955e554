"""The sunlight effect (core/effects/sunlight.py) on closed-form scenes: plates and a box in
the sun, false returns against the analytic Rice rate, the sun behind the sensor or the
target, the Earth, the seed; and its compiled surface pass against the numpy formulas."""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core import radiometry as rad
from lidar_sim_ros.core.config import MaterialConfig, MaterialsConfig, SensorConfig, SunConfig, parse
from lidar_sim_ros.core.effects import make_effect
from lidar_sim_ros.core.effects.sunlight import background_of, sunward_surfaces
from lidar_sim_ros.core.geometry import Target
from lidar_sim_ros.core.pipeline import NO_MATERIAL, Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory, StaticPose
from lidar_sim_ros.core.scan import directions_from_angles
from lidar_sim_ros.core.sun import ScenarioSun
from conftest import plate_target

C = 299_792_458.0
Q = 1.602176634e-19
FACING = Rotation.from_euler('y', -90, degrees=True)   # body +z (plate normal) toward the sensor (-x)
BEHIND_SENSOR = (-1.0, 0.0, 0.0)                       # toward the sun: the sun shines along +x
NO_STRAY = {'stray_light_pst_at_1deg': 0.0}


def sun_sensor(elevations_deg=(0.0,), az_deg=1.0, shots=200, receiver=None, **det) -> SensorConfig:
    data = {
        'name': 'sun test', 'frame_rate_hz': 10.0,
        'scan': {'type': 'rotating', 'elevations_deg': list(elevations_deg), 'az_min_deg': -az_deg,
                 'az_max_deg': az_deg, 'shots_per_beam': shots},
        'optics': {'peak_power_w': 40.0, 'transmit_efficiency': 0.9, 'receive_efficiency': 0.9,
                   'beam_divergence_rad': 0.0015, 'aperture_diameter_m': 0.025},
        'detection': {'threshold_power_w': 3.796875e-08, 'saturation_power_w': 3e-4,
                      'min_range_m': 0.5, 'max_range_m': 250.0, **det},
        'receiver': receiver or {},
    }
    return parse(SensorConfig, data, '<test>')


def lambertian(kd: float, names=('PIF',)) -> MaterialsConfig:
    return MaterialsConfig(materials=[MaterialConfig(name=n, kd=kd, ks=0.0, n=1.0, bias_m=0.0,
                                                     sigma_m=0.0) for n in names])


def sunlit_sim(sensor, materials, target, sun_source, seed=0) -> Simulator:
    return Simulator(sensor, materials, target, seed=seed, effects=[make_effect('sunlight')],
                     sun=sun_source)


def sun(direction, **extra) -> ScenarioSun:
    return ScenarioSun(SunConfig(direction=tuple(direction), **extra))


def frame_background(sim: Simulator, pose):
    shots = sim.shots
    pred = sim.predict(shots.t_s, sim.directions, pose, shots.t_s)
    return pred.ctx, background_of(pred.ctx)


def plate_power_w(sensor: SensorConfig, kd: float, cos_sun: float) -> float:
    """Hand formula: Lambertian radiance E dlambda kd/pi cos, times A_rx Omega tau."""
    rx, optics = sensor.receiver, sensor.optics
    radiance = 0.92 * rx.bandpass_nm * kd / math.pi * cos_sun
    return radiance * math.pi * (optics.aperture_diameter_m / 2) ** 2 * rx.ifov_sr * optics.receive_efficiency


# ------------------------------------------------------------------ closed forms
def test_plate_facing_sun_and_sensor_gets_the_check_value():
    """The issue's check value through the whole model: 30 % Lambertian plate, 20 nm,
    25 mm, 2 x 2 mrad: about 3 nW on every shot that sees the plate."""
    s = sun_sensor(receiver={'bandpass_nm': 20.0, 'ifov_sr': 4e-6})
    sim = Simulator(s, lambertian(0.3), plate_target(4.0), sun=sun(BEHIND_SENSOR))
    ctx, bg = frame_background(sim, StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat())))
    assert ctx.hit.all() and bg.sunlit.all()
    hand = 0.92 * 20 * 0.3 / math.pi * math.pi * 0.0125 ** 2 * 4e-6 * 0.9
    np.testing.assert_allclose(bg.power_w, hand, rtol=1e-9)
    assert 2.5e-9 < hand < 3.5e-9


def box_on_plate() -> Target:
    """A 6 m plate (body z = 0, normal +z) with a 1 m cube standing on it (z 0..1)."""
    plate = trimesh.Trimesh(vertices=[[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]],
                            faces=[[0, 1, 2], [0, 2, 3]])
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    cube.apply_translation((0.0, 0.0, 0.5))
    mesh = trimesh.util.concatenate([plate, cube])
    return Target(mesh.vertices, mesh.faces, np.zeros(len(mesh.faces), int), ['PIF'])


def in_cube_shadow(points_body: np.ndarray, sun_body: np.ndarray) -> np.ndarray:
    """Slab test: does the ray from each point toward the sun cross the cube [-.5,.5]^2 x [0,1]?"""
    lo, hi = np.array([-0.5, -0.5, 0.0]), np.array([0.5, 0.5, 1.0])
    with np.errstate(divide='ignore', invalid='ignore'):
        t0, t1 = (lo - points_body) / sun_body, (hi - points_body) / sun_body
    t_near = np.nanmax(np.minimum(t0, t1), axis=1)
    t_far = np.nanmin(np.maximum(t0, t1), axis=1)
    return (t_far >= np.maximum(t_near, 1e-6))


def test_box_shadow_on_the_plate_gets_no_solar_background():
    s = sun_sensor(elevations_deg=np.linspace(-4, 4, 17), az_deg=5.0, shots=101, receiver=NO_STRAY)
    sun_dir = np.array([-np.cos(np.radians(40)), np.sin(np.radians(40)), 0.0])  # behind-left
    sim = Simulator(s, lambertian(0.45), box_on_plate(), sun=sun(sun_dir))
    pose = StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat()))
    ctx, bg = frame_background(sim, pose)
    points_body = pose.at(np.zeros(len(ctx))).to_body(ctx.direction * ctx.range_m[:, None])
    on_plate = ctx.hit & (np.abs(points_body[:, 2]) < 1e-3)
    on_cube_front = ctx.hit & (np.abs(points_body[:, 2] - 1.0) < 1e-3)
    shadow = on_plate & in_cube_shadow(points_body, FACING.inv().apply(sun_dir))
    lit_plate = on_plate & ~shadow
    assert shadow.sum() > 100 and lit_plate.sum() > 100 and on_cube_front.sum() > 50
    np.testing.assert_array_equal(bg.shadowed[on_plate], shadow[on_plate])
    assert np.all(bg.power_w[shadow] == 0.0)                      # no sun, no stray, dark sky
    expected = plate_power_w(s, 0.45, np.cos(np.radians(40)))
    np.testing.assert_allclose(bg.power_w[lit_plate], expected, rtol=1e-9)
    np.testing.assert_allclose(bg.power_w[on_cube_front], expected, rtol=1e-9)
    # The cube's face turned away from the sun (-y side) would be dark too; none is seen here.
    assert np.all(bg.power_w[~ctx.hit] == 0.0)


# ---------------------------------------------------------- false returns, Rice
def analytic_false_probability(sensor: SensorConfig, background_w: float, listen_s: np.ndarray):
    """1 - exp(-nu T), nu = B/sqrt(3) exp(-u^2/2 sigma^2), sigma from the APD noise equation."""
    rx = sensor.receiver
    m, r = rx.apd_gain, rx.responsivity_a_per_w
    var = (2 * Q * m * m * rx.excess_noise_factor * (r * background_w + rx.dark_current_a)
           * rx.bandwidth_hz + rx.amplifier_noise_a_per_rthz ** 2 * rx.bandwidth_hz)
    sigma = math.sqrt(var) / (m * r)
    u = sensor.detection.threshold_power_w
    nu = rx.bandwidth_hz / math.sqrt(3) * math.exp(-u * u / (2 * sigma * sigma))
    return 1 - np.exp(-nu * listen_s), nu, sigma


@pytest.mark.parametrize('z', [2.6, 3.0, 3.4])
def test_false_return_rate_matches_the_rice_rate(z):
    """Threshold at z sigma of a sunlit plate's noise: the share of shots that report a false
    return before the echo equals 1 - exp(-nu T) within the binomial spread (4 sigma)."""
    kd, frames = 0.45, 6
    probe = sun_sensor(shots=2000, receiver=NO_STRAY)
    p_bg = plate_power_w(probe, kd, 1.0)
    _, _, sigma = analytic_false_probability(probe, p_bg, np.zeros(1))
    s = sun_sensor(shots=2000, receiver=NO_STRAY, threshold_power_w=z * sigma)
    sim = sunlit_sim(s, lambertian(kd), plate_target(6.0), sun(BEHIND_SENSOR), seed=17)
    pose = StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat()))
    false_ranges, p_expected, listen = [], [], None
    for k in range(frames):
        frame = sim.simulate_frame(k * 0.1, pose, k)
        assert len(frame) == len(sim.shots)          # every shot returns: echo or false
        false_ranges.append(frame.range_m[frame.material == NO_MATERIAL])
        true_range = 10.0 / np.cos(sim.shots.az_rad)
        listen = 2 * (true_range - 0.5) / C
        p, nu, _ = analytic_false_probability(s, p_bg, listen)
        p_expected.append(p)
    p_expected = np.concatenate(p_expected)
    observed = sum(len(r) for r in false_ranges)
    spread = np.sqrt(np.sum(p_expected * (1 - p_expected)))
    assert abs(observed - p_expected.sum()) < 4 * spread, (observed, p_expected.sum(), spread)
    # Ranges of the first crossing: an exponential delay cut at the echo, from min_range.
    r = np.concatenate(false_ranges)
    assert r.min() >= 0.5 and r.max() < 10.0 / np.cos(sim.shots.az_rad).min()
    t_max = 2 * (10.0 - 0.5) / C
    mean_delay = 1 / nu - t_max / np.expm1(nu * t_max)     # E[t | t < T] (near-axis shots)
    delays = 2 * (r - 0.5) / C
    assert abs(delays.mean() - mean_delay) < 4 * delays.std() / np.sqrt(len(delays)) + 0.01 * mean_delay


def test_shadowed_plate_keeps_the_dark_rate():
    """The same plate facing away from the sun: only the dark noise, at its own Rice rate."""
    s = sun_sensor(shots=2000, receiver=NO_STRAY)
    sim = Simulator(s, lambertian(0.45), plate_target(6.0), sun=sun((1.0, 0.0, 0.0)))
    ctx, bg = frame_background(sim, StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat())))
    assert bg.shadowed.all() and np.all(bg.power_w == 0.0)
    p, _, _ = analytic_false_probability(s, 0.0, bg.listen_s)
    np.testing.assert_allclose(bg.false_return_probability, p, rtol=1e-9)


# ---------------------------------------------- sun behind the sensor vs target
def test_sun_behind_the_sensor_lights_the_target_behind_the_target_blinds():
    """A 1.05 m plate at 10 m (+-3 deg) on a +-6 deg line of shots.
    Sun behind the sensor: the plate is lit (closed form), nothing is blinded.
    Sun behind the target, 3.5 deg off the axis: the plate's face is in its own shadow,
    and the shots within the stray-light blinding angle of the sun return nothing."""
    s = sun_sensor(az_deg=6.0, shots=1201)
    pose = StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat()))
    behind_sensor = sunlit_sim(s, lambertian(0.45), plate_target(1.05), sun(BEHIND_SENSOR))
    ctx, bg = frame_background(behind_sensor, pose)
    assert ctx.hit.sum() > 400 and bg.sunlit[ctx.hit].all() and not bg.blinded.any()
    np.testing.assert_allclose(bg.surface_power_w[ctx.hit], plate_power_w(s, 0.45, 1.0), rtol=1e-9)
    frame = behind_sensor.simulate_frame(0.0, pose, 0)
    assert np.count_nonzero(frame.material == 0) >= ctx.hit.sum() - np.count_nonzero(
        frame.material == NO_MATERIAL)

    sun_az = np.radians(3.5)
    toward = (np.cos(sun_az), np.sin(sun_az), 0.0)
    behind_target = sunlit_sim(s, lambertian(0.45), plate_target(1.05), sun(toward))
    ctx, bg = frame_background(behind_target, pose)
    assert bg.shadowed[ctx.hit].all() and np.all(bg.surface_power_w == 0.0)
    # Stray light blinds where PST(theta) E dlambda A tau >= the blinding power:
    # theta_blind = 1 deg sqrt(PST(1 deg) P_in / P_blind).
    rx = s.receiver
    p_in = 0.92 * rx.bandpass_nm * math.pi * 0.0125 ** 2 * 0.9
    theta_blind = math.radians(1.0) * math.sqrt(rx.stray_light_pst_at_1deg * p_in / rx.blinding_power_w)
    off_axis = np.abs(behind_target.shots.az_rad - sun_az)
    clear = np.abs(off_axis - theta_blind) > 1e-3            # away from the edge
    np.testing.assert_array_equal(bg.blinded[clear], (off_axis < theta_blind)[clear])
    frame = behind_target.simulate_frame(0.0, pose, 0)
    az_points = np.arctan2(frame.xyz_m[:, 1], frame.xyz_m[:, 0])
    assert not np.any(np.abs(az_points - sun_az) < theta_blind - 1e-3)
    blinded_plate = ctx.hit & bg.blinded
    assert blinded_plate.sum() > 20                          # echoes lost near the sun


def test_earth_behind_the_target_and_eclipse():
    s = sun_sensor(az_deg=6.0, shots=601, receiver=NO_STRAY)
    pose = StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat()))
    earth = {'direction': (1.0, 0.0, 0.0), 'angular_radius_deg': 70.0, 'albedo': 0.3}
    # Sun behind the sensor, 60 deg from the Earth's anti-direction: Earth's sub-point lit.
    sun_dir = (-np.cos(np.radians(60)), 0.0, np.sin(np.radians(60)))
    sim = Simulator(s, lambertian(0.45), plate_target(1.05), sun=sun(sun_dir, earth=earth))
    ctx, bg = frame_background(sim, pose)
    miss = ~ctx.hit
    l_earth = 0.3 * 0.92 * np.cos(np.radians(60)) / np.pi * s.receiver.bandpass_nm
    expected = l_earth * np.pi * 0.0125 ** 2 * s.receiver.ifov_sr * 0.9
    np.testing.assert_allclose(bg.power_w[miss], expected, rtol=1e-9)
    # Eclipse: the sun behind the Earth disk; no sunlight, and the Earth's night side is dark.
    sim.sun = sun((np.cos(np.radians(20)), np.sin(np.radians(20)), 0.0), earth=earth)
    ctx, bg = frame_background(sim, pose)
    assert np.all(bg.power_w == 0.0) and not bg.sunlit.any()


# ------------------------------------------------------------------ noise, seed
def test_range_noise_grows_as_the_signal_falls():
    s = sun_sensor(receiver=NO_STRAY)
    eff = make_effect('sunlight')
    sim = Simulator(s, lambertian(0.45), plate_target(60.0), sun=sun(BEHIND_SENSOR), effects=[eff])
    sigma = []
    for distance in (10.0, 40.0):
        pose = StaticPose((distance, 0.0, 0.0), tuple(FACING.as_quat()))
        pred = sim.predict(np.zeros(1), directions_from_angles(np.zeros(1), np.zeros(1)), pose)
        bg = eff.background(pred.ctx)
        extra = math.sqrt(bg.noise_sigma_w[0] ** 2 - bg.dark_sigma_w ** 2)
        hand = 0.5 * C * 0.35 / s.receiver.bandwidth_hz * extra / pred.ctx.power_w[0]
        assert pred.sigma_m[0] == pytest.approx(hand, rel=1e-9)   # material sigma is 0 here
        sigma.append(pred.sigma_m[0])
    # Same background (a Lambertian plate's radiance does not depend on range), 16x less signal.
    assert sigma[1] == pytest.approx(16 * sigma[0], rel=1e-6)


def test_false_returns_are_reproducible_from_the_seed():
    from lidar_sim_ros.core.scenario import load_scenario
    from conftest import CONFIG
    scenario = load_scenario(CONFIG / 'scenario_sunlit.yaml')
    traj = ScenarioTrajectory.from_config(scenario.config)
    a = Simulator.from_scenario(scenario).simulate_frame(0.9, traj, 9)
    b = Simulator.from_scenario(scenario).simulate_frame(0.9, traj, 9)
    np.testing.assert_array_equal(a.xyz_m, b.xyz_m)
    np.testing.assert_array_equal(a.material, b.material)
    assert np.count_nonzero(a.material == NO_MATERIAL) > 0
    other = Simulator.from_scenario(scenario)
    other.seed += 1
    c = other.simulate_frame(0.9, traj, 9)
    assert not np.array_equal(a.t_s[a.material == NO_MATERIAL], c.t_s[c.material == NO_MATERIAL])


def test_no_sun_draws_nothing():
    s = sun_sensor(receiver=NO_STRAY)
    pose = StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat()))
    plain = Simulator(s, lambertian(0.45), plate_target(4.0), seed=2).simulate_frame(0.0, pose, 0)
    with_effect = Simulator(s, lambertian(0.45), plate_target(4.0), seed=2,
                            effects=[make_effect('sunlight')]).simulate_frame(0.0, pose, 0)
    np.testing.assert_array_equal(plain.xyz_m, with_effect.xyz_m)


# --------------------------------------------------------------- compiled pass
def test_sunward_surfaces_matches_the_numpy_formulas():
    rng = np.random.default_rng(4)
    n = 500
    d = rad.unit(rng.normal(size=(n, 3)) + [4, 0, 0])
    normal = rad.unit(-d + 0.6 * rng.normal(size=(n, 3)))
    normal *= np.sign(np.einsum('ij,ij->i', normal, -d))[:, None]     # toward the sensor
    s = rad.unit(rng.normal(size=(n, 3)))
    material = rng.integers(0, 3, n).astype(np.int16)
    kd, ks, n_exp = np.array([0.45, 0.05, 0.2]), np.array([0.02, 0.9, 0.35]), np.array([1.0, 20.0, 8.0])
    e_band = np.full(n, 36.8)
    on = np.flatnonzero(rng.random(n) < 0.8)
    rng_m = rng.uniform(5, 15, n)
    rot = Rotation.random(n, random_state=7)
    position = rng.normal(size=(n, 3)) + [10, 0, 0]
    # Each shot hits its own face, seen from outside (face normal = the sensor-facing one,
    # in the body frame) or from inside. A third of the faces lie on the hull (clearance
    # <= 0), the rest have 0.5 m in front: hits seen from outside need no ray or a ray of
    # (0.5 - 0.002 + 0.001) / cos(theta_sun); from inside, an unbounded one.
    face = rng.permutation(n)
    clearance = np.where(np.arange(n) % 3 == 0, -0.1, 0.5)
    outward = rng.random(n) < 0.5
    face_normals = np.empty((n, 3))
    face_normals[face] = rot.inv().apply(normal) * np.where(outward, 1.0, -1.0)[:, None]
    facing, radiance, shots, o_body, d_body, length = sunward_surfaces(
        on, d, rng_m, normal, material, s, e_band, kd, ks, n_exp, 0.002, rot.as_quat(), position,
        face, clearance, face_normals)
    cos_sun = np.einsum('ij,ij->i', normal, s)
    np.testing.assert_array_equal(np.flatnonzero(facing), on[cos_sun[on] > 0])
    on_hull = clearance[face] < 0
    np.testing.assert_array_equal(shots, np.flatnonzero(facing & ~(on_hull & outward)))
    expected_length = np.where(outward, (0.5 - 0.002 + 0.001) / cos_sun, np.inf)[shots]
    np.testing.assert_allclose(length, expected_length.astype(np.float32), rtol=1e-6)
    facing = shots
    f = rad.bistatic_phong_brdf(normal, s, -d, kd[material], ks[material], n_exp[material])
    ref = np.where(cos_sun > 0, rad.reflected_radiance_w_m2_sr(e_band, f, cos_sun), 0.0)
    np.testing.assert_allclose(radiance[on], ref[on], rtol=1e-12, atol=0)
    assert np.all(radiance[np.setdiff1d(np.arange(n), on)] == 0)
    # Shadow rays in the body frame: p_body = R^T (p_lidar - t), float32 as Embree takes them.
    origin = d * rng_m[:, None] + 0.002 * normal
    ref_o = rot[facing].inv().apply(origin[facing] - position[facing])
    np.testing.assert_allclose(o_body, ref_o, atol=1e-5)
    np.testing.assert_allclose(d_body, rot[facing].inv().apply(s[facing]), atol=1e-6)


def test_apd_response_matches_the_numpy_formulas():
    from lidar_sim_ros.core import detection
    from lidar_sim_ros.core.effects.sunlight import apd_response
    s = sun_sensor(receiver={'apd_gain': 60.0, 'excess_noise_factor': 3.5})
    rx, det = s.receiver, s.detection
    rng = np.random.default_rng(8)
    n = 400
    power = np.where(rng.random(n) < 0.3, 0.0, 10 ** rng.uniform(-10, -6, n))
    hit = rng.random(n) < 0.7
    signal = np.where(hit, 10 ** rng.uniform(-9, -3, n), 0.0)
    range_m = np.where(hit, rng.uniform(0.1, 300, n), np.nan)
    sigma, rate, listen = apd_response(
        power, hit, signal, range_m, det.threshold_power_w, det.saturation_power_w, det.min_range_m,
        det.max_range_m, rx.responsivity_a_per_w, rx.apd_gain, rx.excess_noise_factor,
        rx.bandwidth_hz, rx.amplifier_noise_a_per_rthz, rx.dark_current_a)
    ref_sigma = rad.apd_noise_sigma_w(power, rx.responsivity_a_per_w, rx.apd_gain,
                                      rx.excess_noise_factor, rx.bandwidth_hz,
                                      rx.amplifier_noise_a_per_rthz, rx.dark_current_a)
    np.testing.assert_allclose(sigma, ref_sigma, rtol=1e-12)
    np.testing.assert_allclose(rate, rad.rice_rate_hz(det.threshold_power_w, ref_sigma, rx.bandwidth_hz),
                               rtol=1e-9)
    echo = hit & detection.detected_mask(signal, range_m, det)
    window = 2 * (det.max_range_m - det.min_range_m) / C
    expected = np.where(echo, 2 * (np.nan_to_num(range_m) - det.min_range_m) / C, window)
    np.testing.assert_allclose(listen, expected, rtol=1e-12)
    assert 0 < echo.sum() < n


def test_first_crossings_are_exact_poisson_first_arrivals():
    """Per shot: crossed with probability 1 - exp(-nu T), first delay truncated-exponential;
    checked by groups of equal hazard (binomial spread, 4 sigma), busy shots included."""
    from lidar_sim_ros.core.effects.sunlight import first_crossings
    rng = np.random.default_rng(21)
    hazards = np.array([1e-4, 0.01, 0.3, 2.0, 40.0])
    n_per = 40_000
    nu = np.repeat([1e4, 1e6, 3e6, 2e7, 1e8], n_per)
    listen = np.repeat(hazards, n_per) / nu
    shots, delay = first_crossings(nu, listen, rng)
    assert len(np.unique(shots)) == len(shots) and np.all(delay >= 0) and np.all(delay < listen[shots])
    for g, h in enumerate(hazards):
        mine = (shots >= g * n_per) & (shots < (g + 1) * n_per)
        p = -np.expm1(-h)
        assert abs(mine.sum() - n_per * p) < 4 * np.sqrt(n_per * p * (1 - p)) + 1, (h, mine.sum())
        if mine.sum() > 100:   # E[t | t < T] for an exponential of rate nu cut at T
            t, rate_g, t_max = delay[mine], nu[g * n_per], listen[g * n_per]
            mean = 1 / rate_g - t_max / np.expm1(rate_g * t_max)
            assert abs(t.mean() - mean) < 4 * t.std() / np.sqrt(len(t)), h


def test_photon_counting_receiver_fires_at_the_poisson_rate():
    """A Geiger-mode receiver: detections at eta P lambda/(h c) + DCR, 2-photon coincidence."""
    rx = {'detector': 'photon_counting', 'photon_detection_efficiency': 0.05,
          'dark_count_rate_hz': 2e3, 'coincidence_photons': 2, 'coincidence_window_s': 2e-9,
          'stray_light_pst_at_1deg': 0.0}
    s = sun_sensor(receiver=rx)
    sim = sunlit_sim(s, lambertian(0.45), plate_target(4.0), sun(BEHIND_SENSOR))
    ctx, bg = frame_background(sim, StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat())))
    photon_j = 6.62607015e-34 * C / 905e-9
    lam = 0.05 * plate_power_w(s, 0.45, 1.0) / photon_j + 2e3
    nu = lam * (1 - np.exp(-lam * 2e-9))                  # P[Poisson(lam tau) >= 1]
    np.testing.assert_allclose(bg.rate_hz, nu, rtol=1e-9)
    np.testing.assert_allclose(bg.false_return_probability, 1 - np.exp(-nu * bg.listen_s), rtol=1e-9)
    assert np.isnan(bg.dark_sigma_w)
