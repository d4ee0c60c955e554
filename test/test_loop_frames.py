"""loop/frames.py, guidance.py, control.py, config.py: numpy only, hand computations."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.loop import frames
from lidar_sim_ros.loop.config import GuidanceConfig, MountConfig, load_loop_config
from lidar_sim_ros.loop.control import cw_acceleration, limit_force
from lidar_sim_ros.loop.guidance import GuidanceState, NavState, guidance_step, nav_update
from lidar_sim_ros.paths import config_path

RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +90 deg about z


def test_target_in_lidar_by_hand():
    """Chaser at the origin turned +90 deg about z (body x = inertial y, body y = inertial -x);
    lidar 1 m along body x, turned +90 deg about body x (lidar y = body z, lidar z = body -y).
    So lidar x, y, z = inertial y, z, x, and the lidar sits at inertial (0, 1, 0). A target at
    inertial (0, 11, 0), unrotated: 10 m along lidar x; its body x (inertial x) is lidar z,
    its body z (inertial z) lidar y."""
    RX90 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    mount = MountConfig(position_m=(1.0, 0.0, 0.0), quat_xyzw=tuple(Rotation.from_matrix(RX90).as_quat()))
    R_BL, t_B = frames.mount_transform(mount)
    origin, R_NL = frames.lidar_pose(np.zeros(3), RZ90, R_BL, t_B)
    np.testing.assert_allclose(origin, [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(R_NL, [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)
    R_LT, t_L = frames.target_in_lidar(np.zeros(3), RZ90, R_BL, t_B, np.array([0.0, 11.0, 0.0]), np.eye(3))
    np.testing.assert_allclose(t_L, [10.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(R_LT @ [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(R_LT @ [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], atol=1e-12)
    # A target body turned +90 deg about inertial z: its body x is inertial y = lidar x.
    R_LT2, _ = frames.target_in_lidar(np.zeros(3), RZ90, R_BL, t_B, np.array([0.0, 11.0, 0.0]), RZ90)
    np.testing.assert_allclose(R_LT2 @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], atol=1e-12)
    # The sun along inertial +z is lidar +y; along inertial +y, lidar +x.
    np.testing.assert_allclose(frames.sun_in_lidar(np.array([0.0, 0.0, 3.0]), RZ90, R_BL), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(frames.sun_in_lidar(np.array([0.0, 2.0, 0.0]), RZ90, R_BL), [1, 0, 0], atol=1e-12)
    # Back from the estimate: the chaser relative to the target (R_HB = R_NB: LVLH = inertial here).
    np.testing.assert_allclose(frames.chaser_from_estimate(t_L, RZ90, R_BL, t_B), [0.0, -11.0, 0.0], atol=1e-12)


def test_lvlh_round_trip_and_rate():
    r = np.array([7.0e6, 1.0e5, -2.0e5])
    v = np.array([-50.0, 7500.0, 300.0])
    R_NH, omega = frames.lvlh_basis(r, v)
    np.testing.assert_allclose(R_NH.T @ R_NH, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R_NH), 1.0)
    np.testing.assert_allclose(R_NH[:, 0], r / np.linalg.norm(r))
    assert omega == pytest.approx(np.linalg.norm(np.cross(r, v)) / (r @ r))
    rho, rho_dot = np.array([1.0, -30.0, 2.0]), np.array([0.01, 0.02, -0.03])
    rc, vc = frames.inertial_from_lvlh(r, v, rho, rho_dot)
    back = frames.relative_lvlh(rc, vc, r, v)
    np.testing.assert_allclose(back[0], rho, atol=1e-9)
    np.testing.assert_allclose(back[1], rho_dot, atol=1e-12)
    # A point fixed in LVLH moves in inertial with omega x rho (the transport term).
    rc0, vc0 = frames.inertial_from_lvlh(r, v, rho, np.zeros(3))
    np.testing.assert_allclose(vc0 - v, R_NH @ np.cross([0, 0, omega], rho), atol=1e-12)


def test_pointing_laws():
    r_t, v_t = np.array([7.0e6, 0.0, 0.0]), np.array([0.0, 7500.0, 0.0])
    R_NH, _ = frames.lvlh_basis(r_t, v_t)
    hold = frames.attitude_hold_lvlh(R_NH)
    np.testing.assert_allclose(hold, [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)
    mount = MountConfig(position_m=(0.8, 0.3, 0.2), quat_xyzw=tuple(Rotation.from_euler('z', 20, degrees=True).as_quat()))
    R_BL, t_B = frames.mount_transform(mount)
    r_c = r_t + R_NH @ [2.0, -20.0, 1.0]
    R_NB = frames.attitude_point_at_target(r_c, r_t, R_NH, R_BL, t_B)
    _, t_L = frames.target_in_lidar(r_c, R_NB, R_BL, t_B, r_t, np.eye(3))
    assert abs(t_L[1]) < 1e-6 and abs(t_L[2]) < 1e-6 and t_L[0] > 19  # boresight on the target


def test_guidance_moves_on_after_the_hold_and_stops_on_the_next():
    cfg = GuidanceConfig(hold_ranges_m=[30.0, 15.0], hold_time_s=5.0)
    g, t = GuidanceState(), 0.0
    g, ref = guidance_step(cfg, g, t, np.array([0, -30.05, 0]), np.zeros(3))
    assert ref.phase == 'hold' and ref.settled
    ys = []
    for t in np.arange(0.1, 200.0, 0.1):
        # A perfect follower: the estimate is the reference.
        g, ref = guidance_step(cfg, g, t, ref.rho_m, ref.rho_dot_mps)
        ys.append(ref.rho_m[1])
        assert ref.rho_dot_mps[1] <= cfg.approach_speed_mps + 1e-12
    ys = np.array(ys)
    assert np.all(np.diff(ys) >= -1e-12)                 # never backs off
    assert ys[int(4.9 / 0.1)] == -30.0 and ys[-1] == -15.0  # held 5 s, ended on the next hold
    assert ref.settled


def test_nav_filter_converges_on_a_constant_velocity():
    cfg = GuidanceConfig()
    nav = NavState()
    for k in range(300):
        t = 0.1 * k
        nav = nav_update(cfg, nav, t, np.array([0.0, -30.0 + 0.2 * t, 1.0]))
    np.testing.assert_allclose(nav.rho_dot_mps, [0.0, 0.2, 0.0], atol=1e-3)


def test_limits_and_cw():
    np.testing.assert_allclose(limit_force([30.0, -1.0, 0.5], 20.0, 0.02), [20.0, -1.0, 0.5])
    np.testing.assert_allclose(limit_force([0.01, 0.01, 0.0], 20.0, 0.02), 0.0)
    n = 1e-3
    np.testing.assert_allclose(cw_acceleration(np.array([1.0, 5.0, 2.0]), np.array([0.1, 0.2, 0.0]), n),
                               [3e-6 + 4e-4, -2e-4, -2e-6])


def test_config_loads_and_names_bad_keys(tmp_path):
    cfg, scenario = load_loop_config(config_path('loop.yaml'))
    assert scenario.is_file() and cfg.substeps == 10
    bad = tmp_path / 'loop.yaml'
    text = config_path('loop.yaml').read_text().replace('hold_ranges_m: [30.0, 15.0, 8.0]',
                                                        'hold_ranges_m: [15.0, 30.0]')
    bad.write_text(text.replace('scenario: scenario_all_effects.yaml',
                                f'scenario: {config_path("scenario_all_effects.yaml")}'))
    with pytest.raises(ConfigError, match='guidance.hold_ranges_m'):
        load_loop_config(bad)


def test_hold_windows_are_the_dwells_before_each_departure_and_at_the_end():
    from lidar_sim_ros.loop.metrics import hold_windows
    t = np.arange(0.0, 40.0, 1.0)
    y = np.full(len(t), -30.0)
    y[10:20] = np.linspace(-29.0, -16.0, 10)      # leaves the first hold after t = 9
    y[20:] = -15.0                                # then stands at the next to the end
    y[15] = y[14]                                 # a repeated sample mid-transfer: no hold
    mask = hold_windows(t, y, hold_time_s=5.0)
    assert np.flatnonzero(mask).tolist() == [5, 6, 7, 8, 9, 35, 36, 37, 38, 39]


def test_earth_shadow_by_hand():
    """A cylinder of the Earth's radius (6378.1366 km) behind the Earth from the sun (+x)."""
    sun = np.array([2.0, 0.0, 0.0])  # not a unit vector: normalised
    km = 1000.0
    cases = {(-7000 * km, 0.0, 0.0): True,             # on the axis behind the Earth
             (-7000 * km, 6300 * km, 0.0): True,       # 6300 km off the axis: inside
             (-7000 * km, 0.0, -6400 * km): False,     # 6400 km off the axis: outside
             (7000 * km, 0.0, 0.0): False,             # on the sunward side
             (-1.0, 3000 * km, 4000 * km): True}       # just behind, 5000 km off the axis
    for r, shadow in cases.items():
        assert frames.in_earth_shadow(np.array(r), sun) is shadow, r
    many = frames.in_earth_shadow(np.array(list(cases)), sun)
    assert many.tolist() == list(cases.values())


@pytest.mark.parametrize('old, new, key', [
    ('tumble_rate_dps: 3.0', 'tumble_rate_dps: 1000000.0', 'target.tumble_rate_dps'),
    ('position_m: [0.0, -30.0, 0.0]', 'position_m: [1.0e+300, -30.0, 0.0]', 'initial.position_m'),
    ('velocity_mps: [0.0, 0.0, 0.0]', 'velocity_mps: [0.0, 1.0e+5, 0.0]', 'initial.velocity_mps'),
    ('quat_xyzw_lvlh: [0.0, 0.0, 0.0, 1.0]', 'quat_xyzw_lvlh: [0.0, 0.0, 0.0, 0.0]', 'target.quat_xyzw_lvlh'),
    ('tumble_axis_body: [1.0, 0.2, 0.3]', 'tumble_axis_body: [1.0e+300, 1.0e+300, 0.0]',
     'target.tumble_axis_body'),
    ('direction_inertial: [0.3, 0.9, 0.3]', 'direction_inertial: [1.0e+300, 1.0e+300, 0.0]',
     'sun.direction_inertial'),
])
def test_absurd_loop_values_are_refused_naming_file_key_value(tmp_path, old, new, key):
    """1e6 deg/s failed every run with "sun direction is NaN"; 1e300 m overflowed unnamed."""
    text = config_path('loop.yaml').read_text()
    assert old in text
    bad = tmp_path / 'loop.yaml'
    bad.write_text(text.replace(old, new).replace('scenario: scenario_all_effects.yaml',
                                                  f'scenario: {config_path("scenario_all_effects.yaml")}'))
    with pytest.raises(ConfigError) as err:
        load_loop_config(bad)
    assert str(bad) in str(err.value) and key in str(err.value)
