"""Multipath (core/effects/multipath.py) and the multi-return receiver (core/returns.py).

Closed forms: a Phong mirror plate at 45 deg in front of a diffuse wall puts the ghost
exactly on the wall's mirror image (the plane x = 6 m here) with the power a hand
calculation of Eqs. 1-3 gives; the lobe integral against numerical quadrature; a
diffuse plate makes no ghost. The receiver's choice (first, last, strongest, all,
merging) on hand-made candidates. The default receiver keeps the single-return frame:
checked against the frame assembled here again from the prediction and the documented
draws (measured ranges, then false returns replacing their shots).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

from lidar_sim_ros.core import detection
from lidar_sim_ros.core.config import MaterialConfig, MaterialsConfig, ReturnsConfig
from lidar_sim_ros.core.effects import Effect, ExtraReturns, make_effect
from lidar_sim_ros.core.effects.multipath import (lobe_integral_sr, mirror_directions)
from lidar_sim_ros.core.geometry import Target
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import StaticPose
from lidar_sim_ros.core.returns import select_returns
from conftest import sensor

AT_ORIGIN = StaticPose((0.0, 0.0, 0.0))   # body frame = lidar frame
MIRROR = dict(name='MIRROR', kd=0.05, ks=0.9, n=20.0, bias_m=0.0, sigma_m=0.0)
WALL = dict(name='WALL', kd=0.5, ks=0.0, n=1.0, bias_m=0.0, sigma_m=0.0)
SCAN = {'type': 'rotating', 'elevations_deg': [0.0], 'az_min_deg': -1.0, 'az_max_deg': 1.0,
        'shots_per_beam': 8}


GLOSSY_WALL = dict(WALL, kd=0.3, ks=0.2, n=5.0)


def mirror_scene(plate: dict = MIRROR, wall: dict = WALL) -> tuple[Target, MaterialsConfig]:
    """A 1 m plate through (5, 0, 0) with normal (-1, 1, 0)/sqrt 2 (45 deg to the shots along
    +x: the mirror ray goes +y) and a diffuse wall y = 1 m facing it (x 4..7 m)."""
    u = np.array([1.0, 1.0, 0.0]) / np.sqrt(2) * 0.5            # in the plate, horizontal
    w = np.array([0.0, 0.0, 0.5])
    c = np.array([5.0, 0.0, 0.0])
    plate_v = np.array([c - u - w, c + u - w, c + u + w, c - u + w])
    wall_v = np.array([[4.0, 1.0, -1.0], [7.0, 1.0, -1.0], [7.0, 1.0, 1.0], [4.0, 1.0, 1.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    target = Target(np.vstack([plate_v, wall_v]), faces, np.array([0, 0, 1, 1]), ['P', 'WALL'])
    mats = MaterialsConfig(materials=[MaterialConfig(**plate), MaterialConfig(**wall)])
    return target, mats


def simulate(plate: dict = MIRROR, returns: dict | None = None, wall: dict = WALL, **params):
    target, mats = mirror_scene(plate, wall)
    sens = sensor(scan=SCAN, returns=returns or {})
    sim = Simulator(sens, mats, target, seed=3, effects=[make_effect('multipath', params)])
    return sim, sim.simulate_frame(0.0, AT_ORIGIN, 0)


def test_lobe_integral_matches_quadrature():
    for ks, n in ((0.9, 20.0), (0.45, 10.0), (0.3, 1.0)):
        lobe = integrate.quad(lambda a: (ks * (n + 2) / (2 * np.pi) * np.cos(a) ** n) ** 2
                              * 2 * np.pi * np.sin(a), 0.0, np.pi / 2)[0]
        assert lobe_integral_sr(ks, n) == pytest.approx(lobe, rel=1e-9)


def test_mirror_direction_of_45_deg_plate():
    n = np.array([[-1.0, 1.0, 0.0]]) / np.sqrt(2)
    np.testing.assert_allclose(mirror_directions(np.array([[1.0, 0.0, 0.0]]), n), [[0, 1, 0]], atol=1e-15)


@pytest.mark.parametrize('wall', [WALL, GLOSSY_WALL], ids=['lambertian', 'glossy'])
def test_ghost_lies_on_the_mirrored_wall_with_the_hand_calculated_power(wall):
    sim, frame = simulate(returns={'max_returns': 2}, wall=wall)
    assert len(frame) == 16                                   # 8 echoes off the plate, 8 ghosts
    ghost = frame.return_number == 2
    assert np.count_nonzero(ghost) == 8
    # The wall y = 1 mirrored in the plate is the plane x = 6: every ghost lies on it.
    np.testing.assert_allclose(frame.xyz_m[ghost, 0], 6.0, atol=2e-5)
    np.testing.assert_allclose(frame.xyz_m[~ghost, 0] - frame.xyz_m[~ghost, 1], 5.0, atol=2e-5)
    assert np.all(frame.material[ghost] == 1) and np.all(frame.material[~ghost] == 0)
    # Hand calculation for each shot (azimuth a): A on the plate y = x - 5, range 5 / (cos a -
    # sin a); the mirror ray is +y (theta_A = 45 deg - a... along the plate's normal plane)
    # and meets the wall at normal incidence after |AB| = 1 - y_A.
    o = sim.sensor.optics
    a = np.arctan2(frame.xyz_m[ghost, 1], frame.xyz_m[ghost, 0])
    r_a = 5.0 / (np.cos(a) - np.sin(a))
    y_a = r_a * np.sin(a)
    d = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    nrm = np.array([-1.0, 1.0, 0.0]) / np.sqrt(2)
    cos_a = np.abs(d @ nrm)
    mirror = d - 2 * (d @ nrm)[:, None] * nrm
    cos_b = mirror[:, 1]                                       # wall normal is -y
    path = (1.0 - y_a) / mirror[:, 1]
    lobe = 0.9 ** 2 * 22.0 ** 2 / (2 * np.pi * 41.0)           # 1/sr
    # The wall's Phong BRDF (Eq. 5) for light sent back the way it came: alpha = 2 theta_B.
    f_b = (wall['kd'] / np.pi + wall['ks'] * (wall['n'] + 2) / (2 * np.pi)
           * np.cos(2 * np.arccos(cos_b)) ** wall['n'])
    beam_sr = np.pi * (o.beam_divergence_rad / 2) ** 2
    p_hand = (o.peak_power_w * o.transmit_efficiency * o.receive_efficiency
              * np.pi * (o.aperture_diameter_m / 2) ** 2 * beam_sr * lobe * cos_a ** 2
              * f_b * cos_b / path ** 2)
    power = frame.intensity[ghost] * sim.sensor.detection.saturation_power_w
    np.testing.assert_allclose(power, p_hand, rtol=1e-5)
    np.testing.assert_allclose(frame.range_m[ghost], r_a + path, atol=2e-5)


def test_single_return_reports_the_echo_in_front_of_its_ghost():
    _, frame = simulate()
    assert len(frame) == 8 and np.all(frame.return_number == 1)
    np.testing.assert_allclose(frame.xyz_m[:, 0] - frame.xyz_m[:, 1], 5.0, atol=2e-5)
    _, last = simulate(returns={'mode': 'last'})
    np.testing.assert_allclose(last.xyz_m[:, 0], 6.0, atol=2e-5)


def test_diffuse_plate_makes_no_ghost():
    _, frame = simulate(plate=dict(MIRROR, name='PIF', kd=0.45, ks=0.0, n=1.0), returns={'max_returns': 2})
    assert len(frame) == 8 and np.all(frame.return_number == 1)
    assert frame.stats.get('multipath', 0) == 0


def test_strength_scales_ghost_power_and_zero_removes_it():
    _, one = simulate(returns={'max_returns': 2})
    _, two = simulate(returns={'max_returns': 2}, strength=2.0)
    g1, g2 = one.return_number == 2, two.return_number == 2
    np.testing.assert_allclose(two.intensity[g2], 2 * one.intensity[g1], rtol=1e-12)
    _, off = simulate(returns={'max_returns': 2}, strength=0.0)
    assert np.all(off.return_number == 1) and len(off) == 8


# ------------------------------------------------------------------- the receiver
def test_select_returns_modes():
    shot = np.array([0, 0, 0, 1, 1, 2])
    rng = np.array([5.0, 7.0, 5.1, 3.0, 9.0, 4.0])
    power = np.array([1.0, 3.0, 9.0, 2.0, 1.0, 1.0])
    cfg = ReturnsConfig(max_returns=2, min_separation_m=0.3)
    keep, num = select_returns(shot, rng, power, cfg)
    # Shot 0: 5.1 merges into 5.0 (one pulse); order by shot then range.
    assert keep.tolist() == [0, 1, 3, 4, 5] and num.tolist() == [1, 2, 1, 2, 1]
    keep, num = select_returns(shot, rng, power, ReturnsConfig(max_returns=1, mode='last'))
    assert keep.tolist() == [1, 4, 5] and num.tolist() == [1, 1, 1]
    keep, _ = select_returns(shot, rng, power, ReturnsConfig(max_returns=1, mode='strongest',
                                                              min_separation_m=0.0))
    assert keep.tolist() == [2, 3, 5]
    keep, num = select_returns(shot, rng, power, ReturnsConfig(max_returns=1, mode='all',
                                                                min_separation_m=0.0))
    assert keep.tolist() == [0, 2, 1, 3, 4, 5] and num.tolist() == [1, 2, 3, 1, 2, 1]
    keep, num = select_returns(shot, rng, power, ReturnsConfig(max_returns=1))
    assert keep.tolist() == [0, 3, 5]
    # The farthest two, reported nearest first.
    keep, num = select_returns(shot, rng, power, ReturnsConfig(max_returns=2, mode='last',
                                                                min_separation_m=0.0))
    assert keep.tolist() == [2, 1, 3, 4, 5] and num.tolist() == [1, 2, 1, 2, 1]


def test_default_receiver_keeps_the_single_return_frame(default_scenario):
    """The single-return frame, assembled again here from the prediction and the documented
    draws, equals the simulator's bit for bit (with false returns drawn: solar background)."""
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    sim = Simulator.from_scenario(default_scenario,
                                  effects=[make_effect('solar_background', {'probability': 0.02})])
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    frame = sim.simulate_frame(0.0, traj, 0)
    shots = sim._cast_shots
    pred = sim.predict(shots.t_s, sim._cast_directions, traj, shots.t_s, shots.az_rad,
                       shots.el_rad, shots.laser)
    det = sim.sensor.detection
    rng = sim.frame_rng(0)
    # The frame's first draw: one standard normal per shot with a range, in cast order.
    with_range = np.isfinite(pred.ctx.range_m)
    measured = np.full(len(with_range), np.nan)
    measured[with_range] = detection.measured_range_m(pred.ctx.range_m[with_range],
                                                      pred.bias_m[with_range],
                                                      pred.sigma_m[with_range], rng)
    ok = pred.ctx.hit & detection.detected_mask(pred.ctx.power_w, pred.ctx.range_m, det)
    mask, false_m = sim.effects[0].false_returns(pred.ctx, rng)
    measured = np.where(mask, false_m, measured)
    ok = (ok | mask) & np.isfinite(measured) & (measured > 0)
    firing = np.argsort(sim._cast_order[ok], kind='stable')
    np.testing.assert_array_equal(frame.range_m, measured[ok][firing])
    assert frame.range_m.tobytes() == measured[ok][firing].tobytes()
    assert np.all(frame.return_number == 1)


class _QuietGhosts(Effect):
    """Extra returns on every hit, all far below threshold: the multi-return path runs and
    must add nothing."""

    name = 'quiet_ghosts'

    def extra_returns(self, ctx, shots=None):
        on = np.flatnonzero(ctx.hit)
        return ExtraReturns(shot=on, range_m=ctx.range_m[on] + 1.0, power_w=np.zeros(len(on)),
                            material=ctx.material[on], face=ctx.face[on],
                            via_material=ctx.material[on], source=self.name)


def test_multi_return_path_with_one_return_is_the_default_frame(default_scenario):
    """Below-threshold extra returns send the frame through the multi-return assembly; with
    the default receiver it must give the default frame bit for bit (false returns too)."""
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    fx = [make_effect('solar_background', {'probability': 0.02})]
    plain = Simulator.from_scenario(default_scenario, effects=fx)
    multi = Simulator.from_scenario(default_scenario, effects=fx + [_QuietGhosts()])
    a, b = plain.simulate_frame(0.0, traj, 0), multi.simulate_frame(0.0, traj, 0)
    assert 'multipath' in b.stats and 'multipath' not in a.stats     # the other path ran
    for key in ('xyz_m', 'range_m', 'intensity', 't_s', 'ring', 'material', 'face',
                'true_range_m', 'return_number'):
        assert getattr(a, key).tobytes() == getattr(b, key).tobytes(), key


def test_offline_summary_names_share_mirrors_and_paths():
    from lidar_sim_ros.offline import multipath_summary
    assert multipath_summary([{'detected': 10}]) is None
    line = multipath_summary([
        {'detected': 100, 'multipath': 3, 'second_returns': 1,
         'multipath_by_mirror': {'MLI': 2, 'PSS': 1}, 'multipath_path_m': [0.1, 0.2, 0.4]},
        {'detected': 100, 'multipath': 1, 'multipath_by_mirror': {'MLI': 1},
         'multipath_path_m': [0.3]}])
    assert '4 ghost points (2 % of 200)' in line and 'MLI 75 %, PSS 25 %' in line
    assert '0.10 / 0.25 / 0.40 m' in line


def test_rocket_body_ghosts_come_from_mli(default_scenario):
    """The tumbling rocket body at 10 m, t = 40 s (MLI blankets face the sensor near
    normal incidence, their echo saturates): the ghosts that show lie a few cm behind MLI."""
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    sim = Simulator.from_scenario(default_scenario, extra_effects=[make_effect('multipath')])
    frame = sim.simulate_frame(40.0, traj, 400)
    assert frame.stats['multipath'] >= 5
    assert set(frame.stats['multipath_by_mirror']) == {'MLI'}
    path = np.asarray(frame.stats['multipath_path_m'])
    assert np.all((path >= 0.05) & (path < 0.5))


# ------------------------------------------------------- a footprint across a depth step
def test_footprint_across_a_depth_step_gives_both_surfaces():
    """A plate at x = 5 m over y > 1 mm and a wall at x = 8 m behind it, one shot along +x
    whose footprint (half-angle 10 mrad) straddles the plate's edge: a multi-return
    receiver reports the plate and the wall, each at the energy-weighted mean range of its
    sub-rays and with its share of the beam's energy; the mixed echo is gone."""
    from lidar_sim_ros.core.effects.beam_divergence import footprint_pattern
    from conftest import materials, paper_power_w
    plate = np.array([[5.0, 0.001, -1.0], [5.0, 1.0, -1.0], [5.0, 1.0, 1.0], [5.0, 0.001, 1.0]])
    wall = np.array([[8.0, -2.0, -2.0], [8.0, 2.0, -2.0], [8.0, 2.0, 2.0], [8.0, -2.0, 2.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    target = Target(np.vstack([plate, wall]), faces, np.zeros(4, int), ['PIF'])
    scan = {'type': 'rotating', 'elevations_deg': [0.0], 'az_min_deg': -0.5, 'az_max_deg': 0.5,
            'shots_per_beam': 2}                                   # azimuths -0.5 and 0 deg
    sens = sensor(scan=scan, returns={'mode': 'all', 'min_separation_m': 0.3})
    half = 0.01
    beam = make_effect('beam_divergence', {'footprint_scale': 2 * half / sens.optics.beam_divergence_rad})
    sim = Simulator(sens, materials(), target, effects=[beam])
    frame = sim.simulate_frame(0.0, AT_ORIGIN, 0)
    on_axis = np.abs(frame.xyz_m[:, 1] / frame.xyz_m[:, 0]) < 1e-9
    assert np.count_nonzero(on_axis) == 2
    near, far = np.sort(frame.range_m[on_axis])
    rho, phi, energy = footprint_pattern(2)
    t = np.tan(half * rho)
    on_plate = -t * np.cos(phi) * 5.0 > 0.001                    # sub-ray y at the plate (u = -y)
    share = energy[on_plate].sum() / energy.sum()
    assert 0.2 < share < 0.5
    assert near == pytest.approx(np.average(5.0 * np.sqrt(1 + t[on_plate] ** 2), weights=energy[on_plate]), abs=2e-5)
    assert far == pytest.approx(np.average(8.0 * np.sqrt(1 + t[~on_plate] ** 2), weights=energy[~on_plate]), abs=2e-5)
    # Power: the group's strongest sub-ray's incidence, times its energy share.
    power = frame.intensity[on_axis][np.argsort(frame.range_m[on_axis])] * sens.detection.saturation_power_w
    m = materials().materials[0]
    t_near = t[on_plate][np.argmax(energy[on_plate])]
    p_near = share * paper_power_w(near, np.arctan(t_near), m.kd, m.ks, m.n, sens.optics)
    p_far = (1 - share) * paper_power_w(far, 0.0, m.kd, m.ks, m.n, sens.optics)
    np.testing.assert_allclose(power, [p_near, p_far], rtol=1e-6)
    assert frame.return_number[on_axis].tolist() == [1, 2]
    # The single-return receiver keeps the one mixed echo.
    single = Simulator(sensor(scan=scan), materials(), target, effects=[beam]).simulate_frame(0.0, AT_ORIGIN, 0)
    mixed = single.range_m[np.abs(single.xyz_m[:, 1]) < 1e-9]
    assert len(mixed) == 1 and near < mixed[0] < far
