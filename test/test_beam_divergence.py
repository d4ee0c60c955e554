"""The beam footprint (core/effects/beam_divergence.py) and its silhouette test (core/silhouette.py).

Two kinds of check: the footprint model against closed forms for a Gaussian beam on a
half-plane edge (power fraction and the mixed range at a depth step), and the fast path
(``sampling: edges``: sub-rays cast only near silhouettes, the plane's answer or a walk
across facets elsewhere) against the full sampling of every shot (``sampling: all``) on
plates, a thin strip, creases, a cylinder and the tumbling rocket body: identical hit/miss
decisions and power fractions everywhere, ranges to float32 rounding on flat plates and
within the stated crease tolerance (CREASE_TOL_M) where footprints cross creases.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy import integrate, special

from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.effects import make_effect
from lidar_sim_ros.core.effects.beam_divergence import (CREASE_TOL_M, footprint_cast,
                                                        sample_footprint)
from lidar_sim_ros.core.geometry import Target
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory, StaticPose
from lidar_sim_ros.core.scan import directions_from_angles
from lidar_sim_ros.core.silhouette import build_mesh_edges, cones_touching_edges
from conftest import materials, sensor

REPO = Path(__file__).resolve().parents[1]
AT_ORIGIN = StaticPose((0.0, 0.0, 0.0))      # body frame = lidar frame: meshes built in place


def wall(x_m: float, y_range: tuple[float, float], z_half: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle in the plane x = x_m (lidar frame) facing the sensor at the origin."""
    y0, y1 = y_range
    v = np.array([[x_m, y0, -z_half], [x_m, y1, -z_half], [x_m, y1, z_half], [x_m, y0, z_half]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def target_of(*parts) -> Target:
    verts, faces, offset = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    faces = np.vstack(faces)
    return Target(np.vstack(verts), faces, np.zeros(len(faces), int), ['PIF'])


def cast(target: Target, az_rad, el_rad, half_angle_rad: float, sampling: str = 'edges',
         rings: int = 2, range_mode: str = 'mean', pose=AT_ORIGIN, **fast):
    az = np.atleast_1d(np.asarray(az_rad, float))
    el = np.broadcast_to(np.asarray(el_rad, float), az.shape)
    d = directions_from_angles(az, el)
    if sampling != 'edges':
        return sample_footprint(target, d, pose.at(np.zeros(len(d))), half_angle_rad, rings,
                                range_mode)
    return footprint_cast(target, d, pose.at(np.zeros(len(d))), half_angle_rad, rings,
                          range_mode, **fast)


# --------------------------------------------------------------- closed forms
def gaussian_share_beyond(x0: float) -> float:
    """Share of a Gaussian beam exp(-2 rho^2), truncated at its 1/e^2 radius rho = 1, that
    falls on the half-plane x > x0 (x in units of that radius):
    int_{x0}^{1} e^{-2x^2} sqrt(pi/2) erf(sqrt(2 (1 - x^2))) dx / (pi (1 - e^{-2}) / 2)."""
    inner = integrate.quad(lambda x: np.exp(-2 * x * x) * np.sqrt(np.pi / 2)
                           * special.erf(np.sqrt(2 * max(1 - x * x, 0.0))), x0, 1.0)[0]
    return inner / (np.pi * (1 - np.exp(-2)) / 2)


def uniform_share_beyond(x0: float) -> float:
    """The same for a uniformly lit disc: the circular segment's area over pi."""
    return (np.arccos(x0) - x0 * np.sqrt(1 - x0 * x0)) / np.pi


def half_wall(x_m: float, offset_m: float, psi_rad: float, beyond: bool = True):
    """The part of the plane x = x_m (6 m square) with (y cos psi + z sin psi) > offset_m
    (``beyond``) or < offset_m: a half-plane whose edge is turned by psi about the x axis."""
    s0, s1 = (offset_m, 3.0) if beyond else (-3.0, offset_m)
    c, sn = np.cos(psi_rad), np.sin(psi_rad)
    corners = [(s_, t_) for s_, t_ in ((s0, -3.0), (s1, -3.0), (s1, 3.0), (s0, 3.0))]
    v = np.array([[x_m, s_ * c - t_ * sn, s_ * sn + t_ * c] for s_, t_ in corners])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


# 91 sub-rays (5 rings) sample the disc uniformly by area. Averaged over the edge's
# orientation (24 turns) their energy share beyond an edge is a quadrature of the
# truncated Gaussian's integral to within 0.02 for any edge offset (0.016 seen); a
# uniform count of sub-rays lands >= 0.08 away from it at the offsets tested.
PATTERN_TOL = 0.02
HALF_ANGLE = 0.01                                         # rad: 0.1 m radius at 10 m
TURNS = np.arange(24) * 2 * np.pi / 24 + 0.1


@pytest.mark.parametrize('sampling', ['edges', 'all'])
@pytest.mark.parametrize('x0', [-0.5, -0.3, 0.3, 0.5])
def test_power_fraction_on_a_half_plane_is_the_gaussian_share(sampling, x0):
    # A wall at 10 m beyond an edge at x0 of the footprint radius from the axis (+x).
    # Sub-rays are straight lines from the origin: the edge sits at 10 tan(a) x0.
    fractions = [cast(target_of(half_wall(10.0, x0 * 10.0 * np.tan(HALF_ANGLE), psi)), 0.0, 0.0,
                      HALF_ANGLE, sampling, rings=5).power_fraction[0] for psi in TURNS]
    expected = gaussian_share_beyond(x0)
    assert np.mean(fractions) == pytest.approx(expected, abs=PATTERN_TOL)
    # The closed forms differ by more than the tolerance: a uniform count would fail.
    assert abs(uniform_share_beyond(x0) - expected) > 3 * PATTERN_TOL


@pytest.mark.parametrize('sampling', ['edges', 'all'])
@pytest.mark.parametrize('x0', [-0.5, 0.3, 0.5])
def test_mixed_range_at_a_depth_step_is_the_energy_weighted_mean(sampling, x0):
    # A near half-wall at 8 m short of an edge at x0 (of the footprint radius, seen at
    # 8 m), a full wall at 10 m behind: the sub-rays beyond the edge carry the Gaussian
    # share f of the energy to 10 m, so the mean range is 8 (1 - f) + 10 f (+ < 1 mm for
    # the sub-rays' slant).
    target_at = [target_of(half_wall(8.0, x0 * 8.0 * np.tan(HALF_ANGLE), psi, beyond=False),
                           wall(10.0, (-3.0, 3.0))) for psi in TURNS]
    ranges = [cast(t, 0.0, 0.0, HALF_ANGLE, sampling, rings=5).range_m[0] for t in target_at]
    f = gaussian_share_beyond(x0)
    tol = 2.0 * PATTERN_TOL + 1e-3
    assert np.mean(ranges) == pytest.approx(8.0 * (1 - f) + 10.0 * f, abs=tol)
    assert abs(uniform_share_beyond(x0) - f) * 2.0 > 2 * tol
    for t in target_at[:3]:                   # the nearest sub-ray: the near wall
        first = cast(t, 0.0, 0.0, HALF_ANGLE, sampling, rings=5, range_mode='first')
        assert first.range_m[0] == pytest.approx(8.0, abs=1e-3)


def test_full_footprint_on_a_tilted_plane_averages_the_sub_ray_ranges():
    # Wall tilted by 60 deg about z: the sub-rays' ranges on the plane are known exactly;
    # the fast path (no sub-ray cast) must give their energy-weighted mean and nearest.
    theta = np.radians(60.0)
    normal = np.array([-np.cos(theta), -np.sin(theta), 0.0])          # toward the sensor
    p0 = np.array([10.0, 0.0, 0.0])
    along = np.array([-np.sin(theta), np.cos(theta), 0.0])
    corners = [p0 + a * along + b * np.array([0, 0, 1.0]) for a, b in
               ((-3, -3), (3, -3), (3, 3), (-3, 3))]
    target = Target(np.array(corners), np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(2, int), ['PIF'])
    for half in (0.003, 0.02):                        # series and closed-form ring sums
        fast = cast(target, 0.0, 0.0, half)
        full = cast(target, 0.0, 0.0, half, 'all')
        # Reference: each sub-ray's range to the plane, from the documented pattern
        # (axis + ring i at angle a i / 2 with 6 i rays, odd rings turned half a step).
        # The pattern's azimuth origin is the code's business; a ring's mean depends on it
        # only at order (t tan theta)^6 / 64 < 1e-10 here, so any basis will do.
        d = np.array([1.0, 0, 0])
        u, v = np.array([0, 0, 1.0]), np.array([0, 1.0, 0])
        ranges, weights = [10.0], [1.0]
        for i in (1, 2):
            for k in range(6 * i):
                phi = 2 * np.pi * (k + 0.5 * (i % 2)) / (6 * i)
                s = d + np.tan(half * i / 2) * (np.cos(phi) * u + np.sin(phi) * v)
                s /= np.linalg.norm(s)
                ranges.append(normal @ p0 / (normal @ s))
                weights.append(np.exp(-2 * (i / 2) ** 2))
        ranges, weights = np.array(ranges), np.array(weights)
        assert fast.range_m[0] == pytest.approx(np.sum(weights * ranges) / weights.sum(), abs=2e-6)
        assert fast.range_m[0] == pytest.approx(full.range_m[0], abs=2e-5)
        assert fast.power_fraction[0] == full.power_fraction[0] == 1.0
        assert fast.range_m[0] > 10.0 + 1e-5          # the far side of the spot outweighs the near


# ------------------------------------------------------- fast path vs full sampling
def assert_same_footprint(fast, full, range_tol_m: float = 1e-4):
    """Identical hit/miss decisions and power fractions; ranges within range_tol_m (float32
    ray rounding by default)."""
    np.testing.assert_array_equal(fast.hit, full.hit)
    np.testing.assert_array_equal(fast.power_fraction, full.power_fraction)
    hit = full.hit
    np.testing.assert_allclose(fast.range_m[hit], full.range_m[hit], rtol=0, atol=range_tol_m)
    np.testing.assert_array_equal(fast.material, full.material)
    np.testing.assert_allclose(fast.cos_incidence[hit], full.cos_incidence[hit], atol=1e-5)


@pytest.mark.parametrize('yaw_deg', [0.0, 50.0])
@pytest.mark.parametrize('scale', [1.0, 8.0])
def test_fast_path_equals_full_sampling_across_a_plate_edge_and_corner(yaw_deg, scale):
    # A 2 m plate at 10 m turned by yaw: shots on a fine grid across its right edge and a
    # corner, from well inside to well outside the footprint's reach.
    s = sensor()
    half = 0.5 * scale * s.optics.beam_divergence_rad
    c, sn = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    corners = np.array([[10.0 - sn * a, c * a, b] for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    target = Target(corners, np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(2, int), ['PIF'])
    edge_az = np.arctan2(c, 10.0 - sn)
    edge_el = np.arctan2(1.0, np.hypot(10.0 - sn, c))
    reach = 3 * half
    az, el = np.meshgrid(edge_az + np.linspace(-reach, reach, 41),
                         np.concatenate([np.linspace(-0.02, 0.02, 5), edge_el + np.linspace(-reach, reach, 21)]))
    fast = cast(target, az.ravel(), el.ravel(), half)
    full = cast(target, az.ravel(), el.ravel(), half, 'all')
    assert_same_footprint(fast, full)
    partial = (full.power_fraction > 0) & (full.power_fraction < 1)
    assert partial.sum() > 50                      # the edge was crossed, not avoided
    assert np.any(full.hit & ~cast(target, az.ravel(), el.ravel(), 1e-9, 'all').hit)


def test_fast_path_sees_a_strip_thinner_than_the_footprint():
    # A 2 mm strip at 10 m between shots: axis rays miss it, footprints catch it.
    half = 0.002                                   # 20 mm radius at 10 m
    target = target_of(wall(10.0, (-0.001, 0.001)))
    az = np.linspace(-0.004, 0.004, 81)
    fast = cast(target, az, 0.0, half)
    full = cast(target, az, 0.0, half, 'all')
    assert_same_footprint(fast, full)
    axis_hits = cast(target, az, 0.0, 1e-9, 'all').hit
    assert np.sum(full.hit & ~axis_hits) > 10


def test_fast_path_equals_full_sampling_on_a_tessellated_cylinder_at_grazing_incidence():
    # Footprints cross the cylinder's creases up to its limb: the plane's answer within
    # the crease tolerance, or sub-rays walked across the facets (exact with no tolerance).
    mesh = trimesh.creation.cylinder(radius=1.0, height=4.0, sections=96)
    target = Target(mesh.vertices + [8.0, 0.0, 0.0], mesh.faces, np.zeros(len(mesh.faces), int), ['PIF'])
    limb = np.arcsin(1.0 / 8.0)
    az, el = np.meshgrid(np.linspace(-limb - 0.01, limb + 0.01, 301), [0.0, 0.05])
    for half in (0.0015, 0.006):
        full = cast(target, az.ravel(), el.ravel(), half, 'all')
        assert_same_footprint(cast(target, az.ravel(), el.ravel(), half), full,
                              range_tol_m=CREASE_TOL_M)
        assert_same_footprint(cast(target, az.ravel(), el.ravel(), half, crease_tol_m=0.0), full)


def folded_plate(fold_rad: float, yaw_rad: float = 0.0) -> Target:
    """Two 2 m x 2 m plates at 10 m meeting along a vertical crease through (10, 0, 0), the
    right one folded back by fold_rad, the pair turned by yaw_rad about the crease."""
    def turn(angle, y, z):                 # a point y along a plate turned by angle from +y
        return [10.0 + y * np.sin(angle), y * np.cos(angle), z]
    left = [turn(yaw_rad, y, z) for y, z in ((-2, -1), (0, -1), (0, 1), (-2, 1))]
    right = [turn(yaw_rad + fold_rad, y, z) for y, z in ((0, -1), (2, -1), (2, 1), (0, 1))]
    quads = np.array([[0, 1, 2], [0, 2, 3]])
    return target_of((np.array(left), quads), (np.array(right), quads))


def low_pyramid(slope_rad: float, sides: int = 6) -> Target:
    """A low pyramid at 10 m, apex toward the sensor, its faces sloping by slope_rad: the
    footprints near the apex lie on the star of one vertex."""
    angle = 2 * np.pi * np.arange(sides) / sides
    rim = np.column_stack([np.full(sides, 10.0), np.cos(angle), np.sin(angle)])
    apex = [[10.0 - np.tan(slope_rad), 0.0, 0.0]]
    faces = np.array([[sides, k, (k + 1) % sides] for k in range(sides)])
    return target_of((np.vstack([rim, apex]), faces))


@pytest.mark.parametrize('shape', ['crease', 'crease turned', 'vertex'])
def test_plane_answer_across_slight_creases_is_within_the_tolerance_asked(shape):
    # Shots over a crease folded by 2 deg (seen head-on and at ~50 deg) and over the apex
    # of a pyramid sloping by 2 deg, at several footprint sizes: the fast path keeps the
    # full sampling's hits and power fractions, its ranges stay within each tolerance
    # asked, and the looser ones are used (ranges differ from the exact walk's).
    target = {'crease': folded_plate(np.radians(2.0)),
              'crease turned': folded_plate(np.radians(2.0), np.radians(50.0)),
              'vertex': low_pyramid(np.radians(2.0))}[shape]
    crease_az = 0.0 if shape == 'vertex' else np.arctan2(0.0, 10.0)
    s = sensor()
    approximated = 0
    for scale in (1.0, 4.0, 16.0):
        half = 0.5 * scale * s.optics.beam_divergence_rad
        az, el = np.meshgrid(crease_az + np.linspace(-3, 3, 25) * half, np.linspace(-3, 3, 7) * half)
        full = cast(target, az.ravel(), el.ravel(), half, 'all')
        exact = cast(target, az.ravel(), el.ravel(), half, crease_tol_m=0.0)
        assert_same_footprint(exact, full)
        for tol in (1e-5, 1e-4, CREASE_TOL_M):
            fast = cast(target, az.ravel(), el.ravel(), half, crease_tol_m=tol)
            assert_same_footprint(fast, full, range_tol_m=tol + 2e-6)
            approximated += np.count_nonzero(np.abs(fast.range_m - exact.range_m)[full.hit] > 1e-6)
    assert approximated > 20


def test_steep_creases_are_walked_at_the_default_tolerance():
    # A 40 deg fold bends too much for the plane's answer within CREASE_TOL_M: footprints
    # over the crease are walked (or cast), exact to float32 rounding; a looser tolerance
    # takes the plane's answer, still within it.
    target = folded_plate(np.radians(40.0))
    half = 0.5 * 4.0 * sensor().optics.beam_divergence_rad
    az, el = np.meshgrid(np.linspace(-3, 3, 25) * half, [0.0, half])
    full = cast(target, az.ravel(), el.ravel(), half, 'all')
    assert_same_footprint(cast(target, az.ravel(), el.ravel(), half), full)
    loose = cast(target, az.ravel(), el.ravel(), half, crease_tol_m=0.02)
    assert_same_footprint(loose, full, range_tol_m=0.02)
    assert np.abs(loose.range_m - full.range_m)[full.hit].max() > 1e-4


def test_a_lone_facet_is_bounded_by_its_own_edges_not_by_a_flat_region():
    # A tent of two single triangles folded by 40 deg along a vertical crease at 10 m (each
    # a facet of its own: no flat region), and a flat square of two triangles behind it at
    # 20 m, the one region of the mesh, whose outline contains the crease seen along x.
    # Footprints over the crease are walked across it, as full sampling sees them; read
    # against the square's outline they would take the plane's answer (1-2 mm off).
    fold = np.radians(40.0)
    tent = (np.array([[10.0, 0.0, -1.0], [10.0, 0.0, 1.0], [10.0, -2.0, 0.0],
                      [10.0 + 2.0 * np.sin(fold), 2.0 * np.cos(fold), 0.0]]),
            np.array([[0, 1, 2], [1, 0, 3]]))
    target = target_of(tent, wall(20.0, (-1.5, 1.5), 1.5))
    half = 0.5 * 4.0 * sensor().optics.beam_divergence_rad
    az = np.linspace(-3, 3, 25) * half
    full = cast(target, az, 0.0, half, 'all')
    fast = cast(target, az, 0.0, half, crease_tol_m=0.0)
    assert_same_footprint(fast, full)
    plane = 10.0 / np.cos(az)                       # the left facet's plane, x = 10 m
    assert np.abs(full.range_m - plane).max() > 1e-3


@pytest.mark.parametrize('scale', [1.0, 6.0])
def test_fast_path_equals_full_sampling_on_the_tumbling_rocket(default_scenario, scale):
    sim = Simulator.from_scenario(default_scenario, effects=[])
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    half = 0.5 * scale * sim.sensor.optics.beam_divergence_rad
    poses = traj.at(0.7 + sim.shots.t_s)
    fast = footprint_cast(sim.target, sim.directions, poses, half)
    full = sample_footprint(sim.target, sim.directions, poses, half)
    assert_same_footprint(fast, full, range_tol_m=CREASE_TOL_M)
    # The blankets and the nozzle pass through the hull: where a footprint straddles such
    # an intersection the walk stays on one surface (module docstring); here < 0.5 mm.
    exact = footprint_cast(sim.target, sim.directions, poses, half, crease_tol_m=0.0)
    assert_same_footprint(exact, full, range_tol_m=5e-4)
    assert np.count_nonzero((full.power_fraction > 0) & (full.power_fraction < 1)) > 100


def test_frames_do_not_depend_on_the_thread_count():
    scenario = load_scenario(REPO / 'config' / 'scenario_all_effects.yaml')
    traj = ScenarioTrajectory.from_config(scenario.config)
    frames = [Simulator.from_scenario(scenario, threads=n).simulate_frame(0.3, traj, 3)
              for n in (1, 3)]
    assert len(frames[0]) > 10000
    for key in ('xyz_m', 'intensity', 'material', 't_s', 'ring'):
        np.testing.assert_array_equal(getattr(frames[0], key), getattr(frames[1], key))


def test_all_effects_scenario_names_every_effect_with_the_documented_examples():
    scenario = load_scenario(REPO / 'config' / 'scenario_all_effects.yaml')
    effects = {e.name: e.params for e in scenario.config.effects}
    assert effects['beam_divergence'] == {'footprint_scale': 1.0}
    for name, params in effects.items():
        make_effect(name, params)                  # valid names and parameters
    docs = (REPO / 'docs' / 'effects.md').read_text()
    for name in effects:
        assert f'`{name}`' in docs


# ---------------------------------------------------------------- silhouettes
def test_silhouette_candidates_of_a_cube_are_its_outline_whatever_the_winding():
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    faces = mesh.faces.copy()
    faces[::3] = faces[::3, ::-1]                  # flip a third of the triangles
    viewpoint = np.array([3.0, 2.5, 2.0])          # sees three faces: a hexagonal outline
    for f in (mesh.faces, faces):
        edges = build_mesh_edges(mesh.vertices, f)
        cand = edges.candidates(viewpoint, viewpoint)
        assert len(cand) == 6
        # Each outline edge joins a face the viewpoint sees (+x, +y, +z) and one it does
        # not: its midpoint has one coordinate +0.5, one -0.5 and one 0.
        mid = np.round(0.5 * (edges.a_m[cand] + edges.b_m[cand]), 6)
        np.testing.assert_array_equal(np.sort(mid, axis=1), np.tile([-0.5, 0.0, 0.5], (6, 1)))
    # A box of viewpoints straddling the plane of a face adds that face's edges.
    wide = edges.candidates(viewpoint - [0, 0, 2.0], viewpoint)       # z from 0 to 2
    assert len(wide) > 6


def test_cone_segment_test_matches_dense_sampling():
    rng = np.random.default_rng(5)
    o = rng.normal(0, 0.05, (400, 3))
    d = np.column_stack([np.ones(400), rng.normal(0, 0.2, (400, 2))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = np.column_stack([rng.uniform(5, 12, 60), rng.uniform(-2, 2, (60, 2))])
    b = a + rng.normal(0, 0.15, (60, 3))
    tan_a = 0.01
    got = cones_touching_edges(o, d, tan_a, a, b)
    # Reference: the smallest angle from each axis to 2001 points along each segment.
    t = np.linspace(0, 1, 2001)
    pts = a[None, :, :] + t[:, None, None] * (b - a)[None, :, :]       # (T, M, 3)
    ref = np.zeros(400, bool)
    margin = np.zeros(400, bool)
    for i in range(400):
        rel = pts - o[i]
        along = rel @ d[i]
        perp = np.linalg.norm(rel - along[..., None] * d[i], axis=-1)
        ratio = np.where(along > 0, perp / np.maximum(along, 1e-12), np.inf).min()
        ref[i] = ratio <= tan_a
        margin[i] = abs(ratio - tan_a) < 2e-4 * tan_a + 1e-5       # too close to call by sampling
    assert 20 < ref.sum() < 380
    np.testing.assert_array_equal(got[~margin], ref[~margin])
