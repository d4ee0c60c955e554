"""One test per mutation that survived the suite (issue 22, part 5), each against an
independent reference: a closed form, a hand calculation or a second implementation.

The mutation each test guards is named in its docstring; each was applied, seen to fail
this test, and reverted.
"""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest
import yaml
from scipy import integrate
from scipy.spatial.transform import Rotation

from conftest import CONFIG, plate_target
from lidar_sim_ros.core import radiometry as rad
from lidar_sim_ros.core.config import SunConfig
from lidar_sim_ros.core.pose import PoseTrack
from lidar_sim_ros.core.sun import ScenarioSun


def test_disk_irradiance_factor_is_the_integral_of_cos_over_the_disk():
    """Mutation: Earth's irradiance on a lit surface loses its factor pi (radiometry.py).
    E / L = integral of cos(theta) over the cap of angular radius rho, by quadrature."""
    for rho_deg in (10.0, 45.0, 70.2):
        rho = math.radians(rho_deg)
        inner, _ = integrate.quad(lambda th: math.cos(th) * math.sin(th), 0.0, rho)
        assert rad.disk_irradiance_factor(rho) == pytest.approx(2 * math.pi * inner, rel=1e-9)


def test_sun_orbits_right_handed_about_its_axis():
    """Mutation: the sun's orbit turns backwards (sun.py; every test sun had rate 0).
    Closed form: +x turning 90 deg/s about +z is +y after 1 s, -x after 2 s."""
    sun = ScenarioSun(SunConfig(direction=(1.0, 0.0, 0.0), orbit_rate_dps=90.0,
                                orbit_axis=(0.0, 0.0, 1.0)), epoch_s=10.0)
    d = sun.direction_at(np.array([10.0, 11.0, 12.0]))
    np.testing.assert_allclose(d, [[1, 0, 0], [0, 1, 0], [-1, 0, 0]], atol=1e-12)


def test_time_spread_variance_is_range_rate_times_spread_squared():
    """Mutation: the time-spread variance rr*s^2 instead of (rr*s)^2 (point_times.py).
    Hand calculation: rr = 2 m/s, s = 0.3 s -> (0.6 m)^2 = 0.36 m^2; and the ML spread of
    residuals drawn as rr * N(0, s0) comes back as s0."""
    from lidar_sim_ros.compare.model.point_times import extra_variance_m2, time_spread_s
    np.testing.assert_allclose(extra_variance_m2(np.array([2.0, -4.0]), 0.3), [0.36, 1.44])
    rng = np.random.default_rng(5)
    n, s0, period = 4000, 0.02, 0.1
    rr = rng.uniform(-20.0, 20.0, n)
    residual = rr * rng.normal(0.0, s0, n) + rng.normal(0.0, 0.005, n)
    s = time_spread_s(residual, np.full(n, 0.005), np.zeros(n, int), rr, period)
    step = period / math.sqrt(3.0) / 24
    assert abs(s - s0) <= 1.5 * step


def test_per_material_std_is_the_sample_std():
    """Mutation: the per-material std with ddof 0 (campaign statistics, calibrate range
    errors). Hand calculation: errors (0, 1) -> mean 0.5, sample std sqrt(1/2)."""
    from lidar_sim_ros.calibrate.range_errors import error_stats
    from lidar_sim_ros.campaign.statistics import RunStatistics
    assert error_stats('PIF', 5.0, np.array([0.0, 1.0])).sigma_std_m == pytest.approx(math.sqrt(0.5))
    stats = RunStatistics(['PIF', 'MLI'])
    stats.err_n[:], stats.err_sum[:], stats.err_sq[:] = [2, 3], [1.0, 6.0], [1.0, 14.0]
    out = stats.summary()   # PIF: (0, 1); MLI: (1, 2, 3) -> std 1
    assert out['range_error_std_m.PIF'] == pytest.approx(math.sqrt(0.5))
    assert out['range_error_std_m.MLI'] == pytest.approx(1.0)
    assert out['range_error_std_m'] == pytest.approx(np.std([0, 1, 1, 2, 3], ddof=1))


def test_misalignment_angle_for_quaternions_with_negative_w(tmp_path):
    """Mutation: the rotation error 2 acos(w) without abs (campaign/sample.py; every test
    quaternion had w > 0). Reference: scipy's rotation magnitude of the drawn quaternion."""
    from lidar_sim_ros.campaign.sample import sample_run
    from lidar_sim_ros.campaign.spec import load_campaign
    path = tmp_path / 'c.yaml'
    path.write_text(yaml.safe_dump({'scenario': str(CONFIG / 'scenario.yaml'), 'seed': 3, 'runs': 12,
                                    'duration_s': 0.1, 'dispersions': {
                                        'mounting_misalignment': {'dist': 'uniform_attitude'}}}))
    campaign = load_campaign(path)
    negative = 0
    for k in range(12):
        case = sample_run(campaign, k)
        q = np.array(case.misalignment_xyzw)
        negative += q[3] < 0
        assert case.params['misalignment_deg'] == pytest.approx(
            math.degrees(Rotation.from_quat(q).magnitude()), abs=1e-6)
    assert negative > 0    # the draw did include quaternions with w < 0


def test_header_stamp_of_big_endian_cdr():
    """Mutation: the recorder ignores the CDR endianness flag (ros/recorder.py).
    Hand-built CDR: encapsulation 0x0000 (big endian) then sec, nanosec."""
    from lidar_sim_ros.ros.recorder import header_stamp_ns
    big = b'\x00\x00\x00\x00' + struct.pack('>iI', 1_700_000_000, 123) + b'\x00' * 8
    little = b'\x00\x01\x00\x00' + struct.pack('<iI', 1_700_000_000, 123) + b'\x00' * 8
    assert header_stamp_ns(big) == header_stamp_ns(little) == 1_700_000_000_000_000_123


def test_aperture_in_the_targets_shadow_gets_no_stray_light():
    """Mutation: the aperture-shadow ray cast toward -sun (core/effects/sunlight.py).
    A 1.05 m plate at 10 m spans +-3.0 deg. With the sun 2.5 deg off the axis it is behind
    the plate: the aperture is in shadow and the shots that miss the plate collect nothing
    (no sky, no Earth). With the sun at 3.5 deg (clear of the plate) the same shots
    collect stray light: the check is not vacuous."""
    from test_sunlight import FACING, frame_background, lambertian, sun, sun_sensor, sunlit_sim
    from lidar_sim_ros.core.pose import StaticPose
    s = sun_sensor(az_deg=6.0, shots=1201)
    pose = StaticPose((10.0, 0.0, 0.0), tuple(FACING.as_quat()))
    powers = {}
    for az_deg in (2.5, 3.5):
        a = math.radians(az_deg)
        sim = sunlit_sim(s, lambertian(0.45), plate_target(1.05), sun((math.cos(a), math.sin(a), 0.0)))
        ctx, bg = frame_background(sim, pose)
        # Misses near the sun but beyond its disk in the field (no direct sunlight).
        near = ~ctx.hit & (np.abs(sim.shots.az_rad - a) > math.radians(0.5)) \
            & (np.abs(sim.shots.az_rad - a) < math.radians(2.0))
        assert near.sum() > 20
        powers[az_deg] = bg.power_w[near]
    assert np.all(powers[2.5] == 0.0)
    assert np.all(powers[3.5] > 0.0)


def test_pose_track_extrapolates_with_the_lidar_frame_rate():
    """Mutation: the angular rate from two samples taken in the body frame (core/pose.py).
    Closed form: a body turned 90 deg about z tumbling about the lidar x axis at 1 rad/s is
    R(t) = Rx(t) Rz(90 deg); past the last sample the track continues that law."""
    r0 = Rotation.from_euler('z', 90, degrees=True)
    law = lambda t: Rotation.from_rotvec([t, 0.0, 0.0]) * r0  # noqa: E731
    t = np.array([0.0, 0.1])
    track = PoseTrack(t, np.zeros((2, 3)), np.vstack([law(x).as_quat() for x in t]),
                      max_extrapolation_s=0.2)
    got = track.at(np.array([0.25])).rotation
    assert (got * law(0.25).inv()).magnitude()[0] < 1e-9


def test_gnc_prediction_turns_about_the_lidar_frame_axis():
    """The tracker's constant-velocity prediction, the same closed form as above."""
    from lidar_sim_ros.gnc.tracker import predict_constant_velocity
    r0 = Rotation.from_euler('z', 90, degrees=True)
    law = lambda t: (Rotation.from_rotvec([t, 0.0, 0.0]) * r0).as_matrix()  # noqa: E731
    T = lambda t: np.block([[law(t), np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]])  # noqa: E731
    np.testing.assert_allclose(predict_constant_velocity(T(0.0), 0.0, T(0.1), 0.1, 0.3)[:3, :3],
                               law(0.3), atol=1e-12)


def test_odometry_angular_twist_is_rotated_body_to_lidar():
    """Mutation: an Odometry twist rotated the wrong way (ros/pose_input.py; the unit test
    spun only about z, where both frames agree). Body turned 90 deg about z: body +x is
    lidar +y, so a spin about body x is a spin about lidar y."""
    from lidar_sim_ros.ros.pose_input import twist_to_lidar
    quat = Rotation.from_euler('z', 90, degrees=True).as_quat()
    _, w = twist_to_lidar(quat, np.zeros(3), np.array([0.3, 0.0, 0.0]))
    np.testing.assert_allclose(w, [0.0, 0.3, 0.0], atol=1e-15)


def test_campaign_coverage_is_evaluated_at_the_mid_frame_pose(tmp_path):
    """Mutation: campaign coverage evaluated at the frame-start pose (campaign/run.py).
    A 2 m plate at 10 m lies edge-on at t = 0 (body z = lidar z, normal across the line
    of sight) and tumbles at -900 deg/s about lidar y: at mid-frame (t = 0.05 s) its
    normal has turned 45 deg toward the sensor (hand calculation), so its faces are
    visible there; at the frame start they are not (no face looks toward the sensor)."""
    from lidar_sim_ros.campaign.run import simulate_case
    from lidar_sim_ros.campaign.sample import RunCase
    from lidar_sim_ros.core.scenario import load_scenario
    (tmp_path / 'plate.obj').write_text('usemtl PIF\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n'
                                        'f 1 2 3\nf 1 3 4\n')
    sensor = yaml.safe_load((CONFIG / 'cepton_vista_p60.yaml').read_text())
    sensor['scan'] = {'type': 'rotating', 'elevations_deg': [float(e) for e in np.linspace(-8.0, 8.0, 17)],
                      'az_min_deg': -8.0, 'az_max_deg': 8.0, 'shots_per_beam': 40}
    (tmp_path / 'sensor.yaml').write_text(yaml.safe_dump(sensor))
    (tmp_path / 'materials.yaml').write_text(yaml.safe_dump({'materials': [
        {'name': 'PIF', 'kd': 0.5, 'ks': 0.0, 'n': 1.0, 'bias_m': 0.0, 'sigma_m': 0.0}]}))
    (tmp_path / 'scenario.yaml').write_text(yaml.safe_dump({
        'seed': 1, 'mesh': 'plate.obj', 'sensor': 'sensor.yaml', 'materials': 'materials.yaml',
        'initial_pose': {'position_m': [10.0, 0.0, 0.0], 'quat_xyzw': [0.0, 0.0, 0.0, 1.0]},
        'motion': {'tumble_axis': [0.0, 1.0, 0.0], 'tumble_rate_dps': -900.0}}))
    scenario = load_scenario(tmp_path / 'scenario.yaml')
    case = RunCase(0, 1, 1, {}, scenario, None, 'stats', 'mcap', 1)
    stats = simulate_case(case)
    assert stats['points'] > 0
    assert stats['coverage_frames'] == 1 and 0.0 < stats['coverage'] <= 1.0


# ---------------------------------------------------------------- issue 29's survivors
def _pose_step(translation_m, rotation_deg, centroid_m):
    """A one-cloud PoseError holding only what ``PoseCorrection.compose`` reads."""
    from lidar_sim_ros.compare.diagnose.pose_error import PoseError
    return PoseError(np.array([0]), np.array([0.5]), np.atleast_2d(translation_m),
                     np.atleast_2d(rotation_deg), 0.0, 0.0, True, np.zeros(4),
                     np.atleast_2d(centroid_m))


def test_pose_correction_gain_is_the_gaussian_log_likelihood_difference():
    """Mutation: the held-out gain without its 1/2 (compare/diagnose/pose_error.py; only z was tested,
    and z does not change when the gain is scaled). Reference: scipy's Gaussian log density,
    log N(r - c; 0, s) - log N(r; 0, s) per point, nats."""
    from scipy.stats import norm
    from lidar_sim_ros.compare.diagnose.pose_error import heldout_gain
    rng = np.random.default_rng(29)
    r, c, s = rng.normal(0, 0.01, 50), rng.normal(0, 0.01, 50), rng.uniform(0.002, 0.02, 50)
    np.testing.assert_allclose(heldout_gain(r, c, s),
                               norm.logpdf(r - c, scale=s) - norm.logpdf(r, scale=s),
                               rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize('translation_m, rotation_deg, passes', [
    ([0.0, 0.0, 0.0], [0.0, 0.0, 0.5], 3),      # translation converged, rotation not
    ([0.01, 0.0, 0.0], [0.0, 0.0, 0.0], 3),     # rotation converged, translation not
    ([1e-4, 0.0, 0.0], [0.0, 0.0, 0.001], 1),   # both below RECAST_STEP_M / _DEG
])
def test_gauss_newton_stops_only_when_both_steps_are_small(translation_m, rotation_deg, passes):
    """Mutation: Gauss-Newton stopping when either step is small (compare/diagnose/pose_error.py).
    Every fit returns the same step; hand count: it re-casts until RECAST_PASSES (3) unless
    both the translation (< 0.5 mm) and the rotation (< 0.01 deg) are small."""
    from lidar_sim_ros.compare.diagnose import pose_error as pe
    step = _pose_step(translation_m, rotation_deg, [10.0, 0.0, 0.0])
    start = pe.PoseCorrection.identity(np.zeros(4, int), np.linspace(0, 1, 4))
    casts = []
    _, _, report = pe.iterate(step, start, lambda corr: casts.append(corr) or corr,
                              lambda state, corr: step)
    assert pe.RECAST_PASSES == 3
    assert report.passes == len(casts) == passes


def test_pose_correction_applies_the_step_after_the_correction():
    """Mutation: the step's rotation composed on the wrong side (compare/diagnose/pose_error.py).
    Hand composition of the two rigid maps on a point: the first fit moves p to
    p1 = R1 (p - g1) + g1 + d1, the step, fitted on the re-cast model, moves that to
    R2 (p1 - g2) + g2 + d2. Rotations of 30 deg about x and 40 deg about z do not commute."""
    from lidar_sim_ros.compare.diagnose import pose_error as pe
    g1, d1, w1 = np.array([10.0, 1.0, 0.0]), np.array([0.1, -0.2, 0.05]), [30.0, 0.0, 0.0]
    g2, d2, w2 = np.array([9.0, 0.0, 1.0]), np.array([-0.03, 0.02, 0.1]), [0.0, 0.0, 40.0]
    start = pe.PoseCorrection.identity(np.zeros(4, int), np.linspace(0, 1, 4))
    corr1, _ = start.compose(_pose_step(d1, w1, g1))
    corr2, size = corr1.compose(_pose_step(d2, w2, g2))
    r1, r2 = (Rotation.from_euler('xyz', w, degrees=True) for w in (w1, w2))
    p = np.array([[11.0, 0.5, -0.3], [9.5, -1.0, 0.7]])
    p1 = r1.apply(p - g1) + g1 + d1
    expected = r2.apply(p1 - g2) + g2 + d2
    got = corr2.rotation[0].apply(p) + corr2.translation_m[0]
    np.testing.assert_allclose(got, expected, atol=1e-12)
    assert size == pytest.approx((np.linalg.norm(d2), 40.0))


def _plan_stubs(monkeypatch, ways):
    """compare/diagnose/plan.py's separation with its two flown stages replaced by fixed numbers per
    way: ``ways[name] = (points in the recording, points diagnosed, margin, z of them)``."""
    from lidar_sim_ros.compare.diagnose import plan
    from lidar_sim_ros.core.effects import make_effect
    monkeypatch.setattr(plan, 'simulate_measurements',
                        lambda model, materials, effects, rec, seed, first_frame, max_points:
                        (effects[-1].name, ways[effects[-1].name][0]))
    monkeypatch.setattr(plan, 'one_way', lambda model, base, true, other, meas, seed, z_crit: {
        'n': ways[true.name][1], 'margin': ways[true.name][2], 'z': ways[true.name][3],
        'gain_true': 0.0, 'gain_other': 0.0, 'fitted_true': {}, 'fitted_other': {}})
    a = plan.Hypothesis(make_effect('range_walk', {'k_m': 0.02}), None)
    b = plan.Hypothesis(make_effect('snr_noise', {'c_m': 0.01}), None)
    rec = plan.Recording('recorded', 'as recorded', (10.0, 0.0, 0.0), (0, 0, 0, 1.0), 0.0,
                         (0.0, 0.0, 1.0), 0.0, 4, 0.1)
    return plan, a, b, rec


def test_separation_z_is_the_weaker_way_scaled_by_the_root_of_the_points(monkeypatch):
    """Mutations: z of the stronger way instead of the weaker; z scaled by n instead of
    sqrt(n) (compare/diagnose/plan.py). Hand calculation: range_walk's recording holds 16 000
    points, 4 000 diagnosed at z 6, so compare (at most 10 000 diagnosed) would see
    z = 6 sqrt(10 000 / 4 000) = 9.487; snr_noise's 9 000 points, 1 000 diagnosed at z 4:
    4 sqrt(9) = 12 (its margin 0.02 the smaller). The plan's z is the weaker, 9.487."""
    plan, a, b, rec = _plan_stubs(monkeypatch, {'range_walk': (16_000, 4_000, 0.03, 6.0),
                                                'snr_noise': (9_000, 1_000, 0.02, 4.0)})
    row = plan.separation(None, [], a, b, rec, seed=0, z_crit=3.0, max_diagnosed=10_000)
    assert row['ways']['range_walk']['z'] == pytest.approx(6 * math.sqrt(2.5))
    assert row['ways']['snr_noise']['z'] == pytest.approx(12.0)
    assert row['z'] == pytest.approx(9.486833, abs=1e-6)
    assert row['weaker_way'] == 'range_walk' and row['margin'] == pytest.approx(0.02)
    assert row['separates'] and row['points'] == 16_000


def test_acquisition_rolls_spread_over_a_whole_turn():
    """Mutation: roll hypotheses spread over half a turn instead of a whole one
    (gnc/acquire.py). Hand: 4 hypotheses per direction are rolled 0, 90, 180 and 270 deg
    about the direction from the alignment of the body axis with it."""
    from lidar_sim_ros.gnc.acquire import AcquisitionConfig, hypotheses
    rng = np.random.default_rng(4)
    model = np.column_stack([rng.uniform(-0.5, 0.5, 400), rng.uniform(-0.5, 0.5, 400),
                             rng.uniform(-2.0, 2.0, 400)])           # a bar along body z
    axis = np.array([0.0, 0.0, 1.0])
    direction = np.array([0.0, 1.0, 0.0])
    cloud = np.column_stack([rng.uniform(9.8, 10.0, 300), rng.uniform(-2.0, 2.0, 300),
                             rng.uniform(-0.5, 0.5, 300)])          # the bar seen across y
    poses = hypotheses(model, axis, cloud, direction[None], AcquisitionConfig(roll_hypotheses=4))
    align, _ = Rotation.align_vectors([direction], [axis])
    rolls = set()
    for T in poses:
        rotvec = (Rotation.from_matrix(T[:3, :3]) * align.inv()).as_rotvec()
        assert np.linalg.norm(np.cross(rotvec, direction)) < 1e-9     # about the direction
        rolls.add(round(float(np.degrees(rotvec @ direction)) % 360.0, 6))
    assert sorted(rolls) == [0.0, 90.0, 180.0, 270.0]


@pytest.mark.parametrize('theta_deg', [0.0, 30.0, 60.0, 80.0, 85.0])
@pytest.mark.parametrize('half_angle_rad', [1e-3, 5e-3, 0.02])
def test_footprint_spread_bounds_the_cone_on_the_plane(theta_deg, half_angle_rad):
    """Mutation: the footprint spread bound with 1/cos(theta) instead of 1/cos(theta + a)
    (core/effects/beam_divergence.py; hidden in the frames by the 1 mm crease tolerance).
    Second implementation: 720 rays on the cone's rim intersected with a plane at incidence
    theta, 10 m along the axis; the farthest lands r0 sin a / cos(theta + a) from the axis
    point. The bound is that (plus its 1 % and 1 um margin), and the cheaper factor of the
    series path (reach = r0 tan a x factor) is at least cos a / cos(theta + a) wherever that
    path is taken."""
    from lidar_sim_ros.core.effects.beam_divergence import (SERIES_LIMIT, far_secant_bound,
                                                            footprint_spread_m)
    r0, theta, a = 10.0, np.radians(theta_deg), half_angle_rad
    if np.tan(theta) * np.tan(a) >= 1.0:
        pytest.skip('the cone does not meet the plane on every side')
    normal = np.array([-np.cos(theta), np.sin(theta), 0.0])           # toward the sensor
    axis_point = np.array([r0, 0.0, 0.0])
    phi = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    rim = np.column_stack([np.full(720, np.cos(a)), np.sin(a) * np.cos(phi), np.sin(a) * np.sin(phi)])
    t = (axis_point @ normal) / (rim @ normal)
    reach = float(np.max(np.linalg.norm(rim * t[:, None] - axis_point, axis=1)))
    closed = r0 * np.sin(a) / np.cos(theta + a)
    assert reach == pytest.approx(closed, rel=1e-5)
    spread = footprint_spread_m(r0, np.cos(theta), np.sin(theta), np.tan(a))
    assert spread == pytest.approx(1.01 * closed + 1e-6, rel=1e-9)
    if np.tan(theta) * np.tan(a) < SERIES_LIMIT:
        bound = far_secant_bound(1.0 / np.cos(theta), np.tan(theta) * np.tan(a))
        exact = np.cos(a) / np.cos(theta + a)          # r0 tan a x this = the reach
        assert exact <= bound <= exact * 1.001
