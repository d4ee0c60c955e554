"""The effect catalogue's forward models against closed forms, and the effect registry."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import trimesh
import pytest
import yaml
from scipy import stats
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import EffectConfig
from lidar_sim_ros.core.effects import (Effect, ReturnContext, catalogue, get_effect_class,
                                        make_effect)
from lidar_sim_ros.core.effects.beam_divergence import footprint_pattern
from lidar_sim_ros.core.geometry import Target
from lidar_sim_ros.core.pipeline import NO_MATERIAL, Simulator
from lidar_sim_ros.core.pose import Poses, StaticPose
from lidar_sim_ros.core.scan import directions_from_angles
from conftest import embree_range_tol_m, materials, paper_power_w, plate_target, sensor

REPO = Path(__file__).resolve().parents[1]
DRIFT_FILE = REPO / 'examples' / 'drift_effect.py'
FACING = Rotation.from_euler('y', -90, degrees=True)   # plate normal (body +z) toward the sensor


def facing_plate(distance_m: float, yaw_deg: float = 0.0) -> StaticPose:
    """Plate centred on the lidar x axis, turned by yaw about lidar z (incidence = |yaw|)."""
    rot = Rotation.from_euler('z', yaw_deg, degrees=True) * FACING
    return StaticPose((distance_m, 0.0, 0.0), tuple(rot.as_quat()))


def line_sensor(az_deg: float = 1.0, shots: int = 400, **det):
    return sensor({'type': 'rotating', 'elevations_deg': [0.0], 'az_min_deg': -az_deg,
                   'az_max_deg': az_deg, 'shots_per_beam': shots}, **det)


def predict_on_axis(sim: Simulator, pose, az_rad=(0.0,), el_rad=None):
    az = np.asarray(az_rad, float)
    el = np.zeros_like(az) if el_rad is None else np.asarray(el_rad, float)
    return sim.predict(np.zeros(len(az)), directions_from_angles(az, el), pose)


def context(**arrays) -> ReturnContext:
    n = len(arrays['power_w'])
    base = dict(range_m=np.full(n, 10.0), incidence_rad=np.zeros(n), material=np.zeros(n, int),
                intensity=np.zeros(n), t_s=np.zeros(n), az_rad=np.zeros(n), el_rad=np.zeros(n),
                laser=np.zeros(n, int), divergence_rad=0.002, hit=np.ones(n, bool),
                threshold_power_w=1e-9, max_range_m=200.0)
    base.update(arrays)
    return ReturnContext(**base)


# ------------------------------------------------------------------------ neutrality
def test_catalogue_has_the_nine_effects_and_their_defaults_change_nothing(default_scenario):
    names = list(catalogue())
    assert names == ['range_walk', 'incidence_angle', 'snr_noise', 'solar_background',
                     'beam_divergence', 'time_offset', 'laser_bias', 'multipath',
                     'laser_pointing']
    # sunlight and range_scale load by name (sunlight needs a sun; range_scale is a test
    # the user asks for): no default diagnosis candidates; their defaults change nothing
    # either. multipath's default is the model's ghosts (strength 1): at strength 0 it
    # changes nothing.
    names += ['sunlight', 'range_scale']
    neutral = {'multipath': {'strength': 0.0}}
    plain = Simulator.from_scenario(default_scenario, effects=[])
    with_all = Simulator.from_scenario(default_scenario, effects=[make_effect(n, neutral.get(n))
                                                                  for n in names])
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    a, b = plain.simulate_frame(0.2, traj, 2), with_all.simulate_frame(0.2, traj, 2)
    assert len(a) > 10000
    np.testing.assert_array_equal(a.xyz_m, b.xyz_m)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    np.testing.assert_array_equal(a.material, b.material)


# ----------------------------------------------------------------------- range scale
def test_range_scale_lengthens_every_range_by_the_same_fraction(default_scenario):
    # Closed form: the bias is scale x true range, so a frame's measured ranges are the
    # plain frame's times (1 + scale) with the same noise draw.
    scale = make_effect('range_scale', {'scale': 2.7e-4})
    ctx = context(range_m=np.array([1.0, 10.0, 100.0, np.nan]), power_w=np.ones(4),
                  hit=np.array([True, True, True, False]))
    np.testing.assert_allclose(scale.range_bias_m(ctx), [2.7e-4, 2.7e-3, 2.7e-2, 0.0])
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    plain = Simulator.from_scenario(default_scenario, effects=[])
    scaled = Simulator.from_scenario(default_scenario, effects=[make_effect('range_scale',
                                                                             {'scale': 0.01})])
    a, b = plain.simulate_frame(0.3, traj, 3), scaled.simulate_frame(0.3, traj, 3)
    np.testing.assert_array_equal(a.true_range_m, b.true_range_m)
    np.testing.assert_allclose(b.range_m - a.range_m, 0.01 * a.true_range_m, atol=1e-9)


# ------------------------------------------------------------------------ surface offset
@pytest.mark.parametrize('yaw_deg', [0.0, 35.0, 60.0])
def test_surface_offset_is_the_raycast_of_the_scaled_or_standing_off_surface(yaw_deg):
    """A plate whose plane lies 1.5 m from the body origin, turned by yaw: the bias of
    surface_offset is the range change a raycast of the real surface gives, the mesh
    scaled by 1 + scale about the body origin (the plane moves out by scale x 1.5 m) or
    standing off by standoff_m, both over cos(incidence), to Embree's float32."""
    s = line_sensor()
    h, d0, scale, standoff = 4.0, 1.5, 0.004, 0.02
    verts = np.array([[-h, -h, d0], [h, -h, d0], [h, h, d0], [-h, h, d0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    mesh = Target(verts, faces, np.zeros(2, int), ['PIF'])
    pose = facing_plate(12.0, yaw_deg)
    ranges = {}
    for name, target, effects in [
            ('model', mesh, []),
            ('scaled', Target(verts * (1 + scale), faces, np.zeros(2, int), ['PIF']), []),
            ('standing', Target(verts + [0.0, 0.0, standoff], faces, np.zeros(2, int),
                                ['PIF']), []),
            ('by_scale', mesh, [make_effect('surface_offset', {'scale': scale})]),
            ('by_standoff', mesh, [make_effect('surface_offset', {'standoff_m': standoff})]),
            ('by_material', mesh, [make_effect('surface_offset',
                                               {'material_standoff_m': {'PIF': standoff}})]),
            ('other_material', mesh, [make_effect('surface_offset',
                                                  {'material_standoff_m': {'MLI': standoff}})])]:
        sim = Simulator(s, materials(), target, effects=effects)
        ranges[name] = predict_on_axis(sim, pose).expected_range_m[0]
    tol = float(12.0 * 8 * np.finfo(np.float32).eps)
    cos_t = np.cos(np.radians(yaw_deg))
    assert ranges['scaled'] - ranges['model'] == pytest.approx(-scale * d0 / cos_t, abs=tol)
    assert ranges['by_scale'] == pytest.approx(ranges['scaled'], abs=tol)
    assert ranges['standing'] - ranges['model'] == pytest.approx(-standoff / cos_t, abs=tol)
    assert ranges['by_standoff'] == pytest.approx(ranges['standing'], abs=tol)
    # A standoff of the plate's own material is the same; another material's moves nothing.
    assert ranges['by_material'] == pytest.approx(ranges['standing'], abs=tol)
    assert ranges['other_material'] == ranges['model']
    for bad in (float('nan'), float('inf'), 1e300):
        with pytest.raises(ValueError, match='material_standoff_m'):
            make_effect('surface_offset', {'material_standoff_m': {'PIF': bad}})
    # A zero offset sees the mesh itself; the effect adds no bias of its own (the geometry
    # carries it).
    assert make_effect('surface_offset', {}).seen_target(mesh) is None
    ctx = context(power_w=np.ones(2), hit=np.array([False, True]))
    assert make_effect('surface_offset', {'standoff_m': 0.01}).range_bias_m(ctx) == 0.0


def cylinder_target(radius_m: float, sections: int, height_m: float = 4.0) -> Target:
    """A closed faceted cylinder about the body z axis (trimesh), one material."""
    cyl = trimesh.creation.cylinder(radius=radius_m, height=height_m, sections=sections)
    return Target(np.asarray(cyl.vertices, float), np.asarray(cyl.faces),
                  np.zeros(len(cyl.faces), int), ['PIF'])


@pytest.mark.parametrize('standoff_m', [0.03, -0.02])
def test_surface_offset_of_a_cylinder_is_its_closed_form_to_the_limb_and_beyond(standoff_m):
    """A cylinder of radius R (1 m, 512 facets, axis across the scan plane) 10 m away,
    rays in the plane at impact parameter b from its axis: the range to the surface
    standing s proud (or s < 0 inside) changes by sqrt(R^2 - b^2) - sqrt((R + s)^2 - b^2) exactly (the
    first-order -s / cos(theta) overstates it toward the limb: 0.151 against 0.118 m at
    b = 0.98 R, s = 3 cm), and rays with R < b < R + s, which miss the mesh, hit the
    proud surface at D cos(az) - sqrt((R + s)^2 - b^2) (with s < 0, rays beyond R + s now
    miss). Tolerance: the facets' sagitta
    R (1 - cos(pi / 512)) = 19 um, magnified by R / sqrt(R^2 - b^2) toward the limb."""
    radius, dist, sections = 1.0, 10.0, 512
    mesh = cylinder_target(radius, sections)
    pose = StaticPose((dist, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    b = radius * np.array([0.0, 0.3, 0.6, 0.8, 0.9, 0.95, 0.98, 0.99])
    if standoff_m > 0:
        b = np.append(b, [radius + 0.3 * standoff_m, radius + 0.7 * standoff_m])
    az = np.arcsin(b / dist)
    plain = predict_on_axis(Simulator(line_sensor(), materials(), mesh), pose, az)
    proud = predict_on_axis(Simulator(line_sensor(), materials(), mesh, effects=[
        make_effect('surface_offset', {'standoff_m': standoff_m})]), pose, az)
    seen, inside = b < radius + standoff_m, b < radius
    outer = np.sqrt(np.clip((radius + standoff_m) ** 2 - b ** 2, 0, None))
    expected = np.sqrt(np.clip(radius ** 2 - b ** 2, 0, None)) - outer
    sagitta = radius * (1 - np.cos(np.pi / sections))
    tol = 4 * sagitta * (radius + abs(standoff_m)) / np.fmax(outer, 1e-3) + 2e-5 * dist
    assert proud.ctx.hit.tolist() == seen.tolist() and plain.ctx.hit.tolist() == inside.tolist()
    both = seen & inside
    np.testing.assert_array_less(np.abs(proud.expected_range_m[both] - plain.expected_range_m[both]
                                        - expected[both]), tol[both])
    # Beyond the mesh's silhouette, rays that now hit: the range to the proud surface.
    new = seen & ~inside
    np.testing.assert_array_less(np.abs(proud.expected_range_m[new]
                                        - (dist * np.cos(az[new]) - outer[new])), tol[new])
    assert new.sum() == (2 if standoff_m > 0 else 0)
    # The first-order change overstates the grazing rays by centimetres.
    cos_t = np.sqrt(1 - (b[both] / radius) ** 2)
    assert np.max(np.abs(-standoff_m / cos_t - expected[both])) > 0.2 * abs(standoff_m)


def test_surface_offset_mitre_moves_every_face_of_a_box_by_its_own_standoff():
    """A box's corners: each face's plane moves by its own standoff (one material 3 cm,
    the others 0 or 1 cm), the faces' normals unchanged: the mitre is exact where three
    planes meet; a face of zero standoff stays on its plane."""
    from lidar_sim_ros.core.effects.surface_offset import face_offsets_m, offset_target
    box = trimesh.creation.box(extents=[3.0, 2.0, 1.2])
    material = np.argmax(np.abs(box.face_normals), axis=1)
    mesh = Target(np.asarray(box.vertices, float), np.asarray(box.faces), material,
                  ['PIF', 'MLI', 'PAF'])
    offsets = face_offsets_m(mesh, 0.01, {'MLI': 0.02, 'PAF': -0.01, 'NOPE': 0.5})
    np.testing.assert_allclose(offsets, np.choose(material, [0.01, 0.03, 0.0]))
    moved = offset_target(mesh, 0.0, offsets)
    np.testing.assert_allclose(moved.face_normals, mesh.face_normals, atol=1e-12)
    plane = np.einsum('ij,ij->i', mesh.face_normals, mesh.vertices_m[mesh.faces[:, 0]])
    for corner in range(3):
        shifted = np.einsum('ij,ij->i', moved.face_normals, moved.vertices_m[moved.faces[:, corner]])
        np.testing.assert_allclose(shifted - plane, offsets, atol=1e-12)
    # The same box exported face by face (every vertex repeated per face, as parts split
    # by material repeat their seams'): the copies of a corner stay together (no slit a ray
    # could pass through into the body), and the faces move as before.
    apart = box.copy()
    apart.unmerge_vertices()
    split = Target(np.asarray(apart.vertices, float), np.asarray(apart.faces), material,
                   ['PIF', 'MLI', 'PAF'])
    moved_apart = offset_target(split, 0.0, offsets)
    np.testing.assert_allclose(moved_apart.vertices_m[moved_apart.faces],
                               moved.vertices_m[moved.faces], atol=1e-12)


# ------------------------------------------------------------------------ range walk
def test_range_walk_bias_is_minus_k_per_efold_of_power():
    walk = make_effect('range_walk', {'k_m': 0.03})
    ctx = context(power_w=1e-9 * np.array([1.0, np.e, np.e ** 2, 0.0]),
                  hit=np.array([True, True, True, False]))
    bias = walk.range_bias_m(ctx)
    # float64 end to end: k ln(e^j) is exact to a few 1e-17 m.
    np.testing.assert_allclose(bias[:3], [0.0, -0.03, -0.06], atol=1e-12)
    assert np.isfinite(bias[3])
    # A reference power is a constant offset: k ln(P_th / P_ref).
    shifted = make_effect('range_walk', {'k_m': 0.03, 'reference_power_w': 1e-9 * np.e})
    np.testing.assert_allclose(shifted.range_bias_m(ctx)[:3], bias[:3] + 0.03, atol=1e-12)


def test_range_walk_in_the_simulator_matches_the_power_closed_form():
    s = line_sensor()
    mat = materials(kd=0.4, ks=0.2, n=4.0, bias_m=-0.05, sigma_m=0.0)
    k = 0.021
    sim = Simulator(s, mat, plate_target(3.0), seed=3,
                    effects=[make_effect('range_walk', {'k_m': k})])
    pose = facing_plate(9.0)
    frame = sim.simulate_frame(0.0, pose, 0)
    az = np.arctan2(frame.xyz_m[:, 1], frame.xyz_m[:, 0])
    true_range = 9.0 / np.cos(az)
    power = paper_power_w(true_range, np.abs(az), 0.4, 0.2, 4.0, s.optics)
    expected = true_range - 0.05 - k * np.log(power / s.detection.threshold_power_w)
    assert len(frame) > 300
    # The simulated range is Embree's float32 one; its power error (2 x 8 float32 ulps
    # relative) moves k ln P by < 1e-7 m.
    np.testing.assert_allclose(frame.range_m, expected, atol=embree_range_tol_m(true_range) + 1e-7)


# ------------------------------------------------------------------- incidence angle
@pytest.mark.parametrize('yaw_deg', [0.0, 40.0, 60.0])
def test_incidence_angle_bias_and_sigma_grow_with_footprint_depth(yaw_deg):
    s = line_sensor()
    b, g, sigma_m = -0.7, 0.45, 0.02
    eff = make_effect('incidence_angle', {'bias_gain': b, 'sigma_gain': g})
    sim = Simulator(s, materials(sigma_m=sigma_m, bias_m=-0.1), plate_target(4.0), effects=[eff])
    pred = predict_on_axis(sim, facing_plate(12.0, yaw_deg))
    depth = 12.0 * s.optics.beam_divergence_rad * np.tan(np.radians(yaw_deg))
    # Incidence comes from float64 normals; arccos near 0 turns a 1e-16 cosine error into
    # ~1.5e-8 rad, hence 1e-6 rather than 1e-12.
    assert pred.ctx.incidence_rad[0] == pytest.approx(np.radians(yaw_deg), abs=1e-6)
    # Embree intersects in float32: the 12 m range is exact only to a few ulps (8 ulps of
    # 12 m ~ 1e-5 m allowed), and the depth inherits that error times dtheta tan(theta).
    depth_tol = 12.0 * 8 * np.finfo(np.float32).eps * s.optics.beam_divergence_rad \
        * np.tan(np.radians(yaw_deg))
    assert pred.bias_m[0] == pytest.approx(-0.1 + b * depth, abs=abs(b) * depth_tol + 1e-12)
    assert pred.sigma_m[0] == pytest.approx(np.hypot(sigma_m, g * depth), abs=g * depth_tol + 1e-12)


def test_incidence_angle_clips_tan_at_grazing():
    eff = make_effect('incidence_angle', {'bias_gain': 1.0, 'max_incidence_deg': 80.0})
    ctx = context(power_w=np.ones(2), incidence_rad=np.radians([80.0, 89.99]))
    bias = eff.range_bias_m(ctx)
    assert bias[1] == pytest.approx(bias[0]) == pytest.approx(10.0 * 0.002 * np.tan(np.radians(80)))


# ----------------------------------------------------------------------- SNR noise
def test_snr_noise_sigma_closed_form_and_simulated_spread():
    s = line_sensor(az_deg=0.5, shots=3000, threshold_power_w=2e-8)
    c, base_sigma = 0.05, 0.01
    eff = make_effect('snr_noise', {'c_m': c, 'exponent': 0.5})
    sim = Simulator(s, materials(kd=0.05, sigma_m=base_sigma), plate_target(3.0), seed=9,
                    effects=[eff])
    pose = facing_plate(40.0)
    pred = predict_on_axis(sim, pose)
    ratio = s.detection.threshold_power_w / pred.ctx.power_w[0]
    assert 0.05 < ratio < 1.0                      # a weak return: the effect matters
    # The ratio is taken from the predicted power itself: float64 arithmetic from here on.
    assert pred.sigma_m[0] == pytest.approx(np.hypot(base_sigma, c * np.sqrt(ratio)), rel=1e-9)
    frame = sim.simulate_frame(0.0, pose, 0)
    az = np.arctan2(frame.xyz_m[:, 1], frame.xyz_m[:, 0])
    err = frame.range_m - 40.0 / np.cos(az)
    n = len(err)
    assert n > 2500
    # Sample std vs predicted: chi-square 99.99 % band on n - 1 degrees of freedom.
    lo, hi = (np.sqrt(stats.chi2.ppf(q, n - 1) / (n - 1)) for q in (5e-5, 1 - 5e-5))
    assert lo < np.std(err) / pred.sigma_m[0] < hi
    assert np.std(err) > 1.5 * base_sigma


# ---------------------------------------------------------------- solar background
def test_solar_background_rate_and_uniform_ranges():
    s = line_sensor(az_deg=20.0, shots=20000)
    p, lo, hi = 0.03, 2.0, 150.0
    eff = make_effect('solar_background', {'probability': p, 'min_range_m': lo, 'max_range_m': hi,
                                            'first_return': False})
    sim = Simulator(s, materials(), plate_target(4.0), seed=4, effects=[eff])
    frame = sim.simulate_frame(0.0, facing_plate(10.0), 0)
    false = frame.material == NO_MATERIAL
    n = frame.stats['shots']
    k = int(false.sum())
    assert abs(k - p * n) < 4.0 * np.sqrt(n * p * (1 - p))          # binomial
    assert stats.kstest(frame.range_m[false], 'uniform', args=(lo, hi - lo)).pvalue > 1e-3
    # Shots that miss the plate (|az| > atan(2/10)) return false points as often as the rest.
    off_target = np.abs(np.arctan2(frame.xyz_m[:, 1], frame.xyz_m[:, 0])) > np.arctan(0.2)
    share_off = np.mean(np.abs(sim.shots.az_rad) > np.arctan(0.2))
    assert np.sum(false & off_target) / k == pytest.approx(share_off, abs=4 * np.sqrt(0.25 / k))
    assert not np.any(off_target & ~false)
    assert eff.outlier_fraction(None) == p


def test_solar_background_first_return_is_gated_by_the_echo():
    """A first-return receiver (the default) records a background crossing only before
    the echo: on a shot hitting the plate at range r (10 m / cos az) with probability
    1 - (1 - p)^((r - lo) / (hi - lo)), its range uniform over [lo, r]; a shot that
    misses listens over the whole gate, probability p, uniform over [lo, hi]."""
    s = line_sensor(az_deg=20.0, shots=20000)
    p, lo, hi = 0.3, 2.0, 150.0
    eff = make_effect('solar_background', {'probability': p, 'min_range_m': lo,
                                            'max_range_m': hi})
    sim = Simulator(s, materials(), plate_target(4.0), seed=5, effects=[eff])
    frame = sim.simulate_frame(0.0, facing_plate(10.0), 0)
    az_shot = sim.shots.az_rad
    on = np.abs(az_shot) < np.arctan(0.2) - 1e-3
    off = np.abs(az_shot) > np.arctan(0.2) + 1e-3
    r_on = 10.0 / np.cos(az_shot[on])
    p_on = 1.0 - (1.0 - p) ** ((r_on - lo) / (hi - lo))
    false = frame.material == NO_MATERIAL
    az = np.arctan2(frame.xyz_m[:, 1], frame.xyz_m[:, 0])
    f_on = false & (np.abs(az) < np.arctan(0.2) - 1e-3)
    f_off = false & (np.abs(az) > np.arctan(0.2) + 1e-3)
    assert abs(f_on.sum() - p_on.sum()) < 4.0 * np.sqrt(np.sum(p_on * (1 - p_on)))
    n_off = int(off.sum())
    assert abs(f_off.sum() - p * n_off) < 4.0 * np.sqrt(n_off * p * (1 - p))
    u = (frame.range_m[f_on] - lo) / (10.0 / np.cos(az[f_on]) - lo)
    assert u.max() < 1.0 and stats.kstest(u, 'uniform').pvalue > 1e-3
    assert stats.kstest(frame.range_m[f_off], 'uniform', args=(lo, hi - lo)).pvalue > 1e-3


def test_solar_background_window_defaults_to_range_gate():
    eff = make_effect('solar_background', {'probability': 1.0, 'first_return': False})
    ctx = context(power_w=np.ones(5000), max_range_m=80.0, min_range_m=1.0)
    mask, ranges = eff.false_returns(ctx, np.random.default_rng(0))
    assert mask.all() and ranges.min() >= 1.0 and ranges.max() <= 80.0
    assert make_effect('solar_background').false_returns(ctx, np.random.default_rng(0)) is None


# ----------------------------------------------------------------- beam divergence
def test_footprint_pattern_is_fixed_and_gaussian():
    rho, phi, energy = footprint_pattern(2)
    assert len(rho) == 19 and rho[0] == 0 and rho.max() == 1.0
    np.testing.assert_allclose(energy, np.exp(-2 * rho ** 2))
    # Ring i (rho = i/2) holds 6 i sub-rays evenly spaced in azimuth, so the footprint's
    # energy centroid sits on the beam axis (no pointing bias).
    for i in (1, 2):
        ring = np.sort(np.mod(phi[rho == i / 2], 2 * np.pi))
        assert len(ring) == 6 * i
        np.testing.assert_allclose(np.diff(ring), 2 * np.pi / (6 * i), rtol=1e-12)
    centroid = np.sum(energy * rho * np.exp(1j * phi)) / energy.sum()
    assert abs(centroid) < 1e-12


def test_beam_divergence_returns_beyond_the_silhouette_only_within_the_footprint():
    s = line_sensor()
    scale = 10.0
    half_angle = 0.5 * scale * s.optics.beam_divergence_rad          # 10 mrad
    sim = Simulator(s, materials(), plate_target(2.0), effects=[
        make_effect('beam_divergence', {'footprint_scale': scale})])
    plain = Simulator(s, materials(), plate_target(2.0))
    pose = facing_plate(10.0)
    edge = np.arctan2(1.0, 10.0)                                      # plate edge at y = 1 m
    az = edge + np.array([-0.5, 0.3, 0.8, 1.5]) * half_angle
    pred, geo = predict_on_axis(sim, pose, az), predict_on_axis(plain, pose, az)
    np.testing.assert_array_equal(geo.ctx.hit, [True, False, False, False])
    np.testing.assert_array_equal(pred.ctx.hit, [True, True, True, False])
    detected = pred.ctx.power_w >= s.detection.threshold_power_w
    assert detected[:3].all()
    # Partly on the plate: less power than a full beam, less the further out.
    full = geo.ctx.power_w[0]
    assert pred.ctx.power_w[1] < full and pred.ctx.power_w[2] < pred.ctx.power_w[1]
    # Deterministic: the same rays give the same answer.
    again = predict_on_axis(sim, pose, az)
    np.testing.assert_array_equal(pred.ctx.range_m, again.ctx.range_m)


def test_beam_divergence_mixes_ranges_at_a_depth_step():
    # Front plate (y < 0 half) at 8 m, back plate at 10 m: a beam on the step sees both.
    front = np.array([[-2, -2, 0], [2, -2, 0], [2, 0, 0], [-2, 0, 0]], float)
    back = front.copy()
    back[:, 1] += 2.0
    back[:, 2] = -2.0                                       # body -z = further from the sensor
    verts = np.vstack([front, back])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    target = Target(verts, faces, np.zeros(4, int), ['PIF'])
    s = line_sensor()
    pose = StaticPose((8.0, 0.0, 0.0), tuple(FACING.as_quat()))
    # Body y maps to lidar y under FACING; the step sits at lidar y = 0, i.e. az = 0.
    az = np.array([0.0, -0.05, 0.05])
    def beam(mode):
        eff = make_effect('beam_divergence', {'footprint_scale': 10.0, 'range_mode': mode})
        return predict_on_axis(Simulator(s, materials(), target, effects=[eff]), pose, az)

    mean, first = beam('mean'), beam('first')
    assert 8.2 < mean.ctx.range_m[0] < 9.8                  # mixed: between the surfaces
    assert first.ctx.range_m[0] == pytest.approx(8.0, abs=1e-3)
    np.testing.assert_allclose(mean.ctx.range_m[1:], [8.0 / np.cos(0.05), 10.0 / np.cos(0.05)],
                               rtol=1e-4)                   # far from the step: unmixed


# -------------------------------------------------------------------- time offset
@dataclass(frozen=True)
class ApproachingPlate:
    speed_mps: float = 3.0

    def at(self, t_s):
        t = np.atleast_1d(np.asarray(t_s, float))
        pos = np.column_stack([10.0 - self.speed_mps * t, np.zeros_like(t), np.zeros_like(t)])
        return Poses(Rotation.from_quat(np.repeat(FACING.as_quat()[None], len(t), 0)), pos)


def test_time_offset_points_match_the_pose_at_t_plus_dt():
    s = line_sensor()
    dt = 0.06
    motion = ApproachingPlate()
    sim = Simulator(s, materials(), plate_target(3.0), seed=1,
                    effects=[make_effect('time_offset', {'dt_s': dt})])
    frame = sim.simulate_frame(0.5, motion, 5)
    t_abs = frame.stamp_s + frame.t_s
    on_plane = frame.xyz_m[:, 0]                                      # plate plane x = x(t)
    np.testing.assert_allclose(on_plane, motion.at(t_abs + dt).position_m[:, 0],
                               atol=embree_range_tol_m(frame.range_m))  # float32 Embree range
    assert np.abs(on_plane - motion.at(t_abs).position_m[:, 0]).min() > 0.17


# ----------------------------------------------------------------------- registry
def test_user_effect_loads_from_a_file_once_and_round_trips_through_yaml():
    cls = get_effect_class(f'{DRIFT_FILE}:DriftInFrame')
    assert cls is get_effect_class(f'{DRIFT_FILE}:DriftInFrame')
    assert issubclass(cls, Effect)
    eff = cls({'rate_m_per_s': 0.25})
    snippet = eff.to_yaml_snippet()
    assert snippet.startswith('- {name: ')
    entry = EffectConfig(**yaml.safe_load(snippet)[0])
    again = make_effect(entry.name, entry.params)
    assert type(again) is cls and again.params.rate_m_per_s == 0.25
    ctx = context(power_w=np.ones(3), t_s=np.array([0.0, 0.05, 0.1]))
    np.testing.assert_allclose(again.range_bias_m(ctx), [0.0, 0.0125, 0.025])


@pytest.mark.parametrize('name,params', [
    ('range_walk', {'k_m': 0.0123}), ('incidence_angle', {'bias_gain': -0.6, 'sigma_gain': 0.2}),
    ('snr_noise', {'c_m': 0.1, 'exponent': 0.75}), ('solar_background', {'probability': 0.004}),
    ('beam_divergence', {'footprint_scale': 3.5}), ('time_offset', {'dt_s': -0.012})])
def test_catalogue_yaml_snippets_load_back(name, params):
    snippet = make_effect(name, params).to_yaml_snippet()
    assert snippet.startswith(f'- {{name: {name}, params: {{')
    entry = EffectConfig(**yaml.safe_load(snippet)[0])
    eff = make_effect(entry.name, entry.params)
    for k, v in params.items():
        assert getattr(eff.params, k) == pytest.approx(v)


def test_scenario_effects_accept_a_user_file(default_scenario):
    from copy import copy
    scenario = copy(default_scenario)
    scenario.config = default_scenario.config.model_copy(update={'effects': [
        EffectConfig(name=f'{DRIFT_FILE}:DriftInFrame', params={'rate_m_per_s': 1.0})]})
    sim = Simulator.from_scenario(scenario)
    assert type(sim.effects[0]).__name__ == 'DriftInFrame'


def test_registry_errors_name_the_problem(tmp_path):
    with pytest.raises(KeyError, match='no_such_effect'):
        get_effect_class('no_such_effect')
    with pytest.raises(FileNotFoundError, match='missing.py'):
        get_effect_class(str(tmp_path / 'missing.py') + ':X')
    bad = tmp_path / 'bad.py'
    bad.write_text('class NotAnEffect:\n    pass\n')
    with pytest.raises(TypeError, match='NotAnEffect'):
        get_effect_class(f'{bad}:NotAnEffect')
    with pytest.raises(ValueError):
        make_effect('range_walk', {'no_such_param': 1.0})


# ------------------------------------------------------------------------ laser bias
def test_laser_bias_is_the_offset_of_each_shots_laser():
    bias = make_effect('laser_bias', {'offsets_m': [0.01, -0.02, 0.005]})
    ctx = context(power_w=np.full(5, 1e-9), hit=np.ones(5, bool))
    ctx = replace(ctx, laser=np.array([0, 1, 2, 1, 7], np.uint16))
    # A laser beyond the list has no offset.
    np.testing.assert_array_equal(bias.range_bias_m(ctx), [0.01, -0.02, 0.005, -0.02, 0.0])
    with pytest.raises(ValueError, match='within'):
        make_effect('laser_bias', {'offsets_m': [0.0, 2.0]})


def test_only_the_package_s_own_names_are_not_plugin_specs():
    """An allow-list: no spelling of a path or module passes for a catalogue name."""
    from lidar_sim_ros.core.effects import builtin_classes, builtin_names, is_plugin_spec
    assert set(builtin_classes()) == set(builtin_names())
    for name in builtin_names():
        assert not is_plugin_spec(name)
    for spec in ('/tmp/a=b/evil.py:Evil', 'a=b:C', 'range_walk=/x/e.py:E', 'os.path:join',
                 'evil.py', 'range_walk ', 'Range_Walk', 'range_walk={k_m: 1}'):
        assert is_plugin_spec(spec), spec
