"""Compiled per-ray loops (core/geometry_kernels.py) against a numpy reference.

The reference rotates the rays with rotation matrices (``Poses.to_body`` /
``vector_to_body``), asks Embree directly, and builds normals and incidence with
plain numpy: a second implementation of what ``cast_at_poses`` does in one pass.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.geometry import cast_at_poses, coherent_order
from lidar_sim_ros.core.pose import Poses
from lidar_sim_ros.core.scan import angles_from_directions, directions_from_angles
from conftest import EMBREE_RTOL, sphere_target


def reference_cast(target, directions, poses, origin=np.zeros(3)):
    n = len(directions)
    o = poses.to_body(np.broadcast_to(origin, (n, 3)))
    d = poses.vector_to_body(directions)
    face, tfar = target.intersect(o.astype(np.float32), d.astype(np.float32))
    hit = face >= 0
    normal_body = np.where(hit[:, None], target.face_normals[np.where(hit, face, 0)], 0.0)
    normal = poses.vector_to_lidar(normal_body)
    cos_i = -np.sum(normal * directions, axis=1)
    normal[cos_i < 0] *= -1
    material = np.where(hit, target.face_material[np.where(hit, face, 0)], -1)
    return hit, np.where(hit, tfar, np.inf), normal, np.arccos(np.minimum(np.abs(cos_i), 1.0)), material


def rays(n, seed):
    rng = np.random.default_rng(seed)
    return directions_from_angles(rng.uniform(-0.2, 0.2, n), rng.uniform(-0.2, 0.2, n))


def check(hits, ref):
    hit, range_m, normal, incidence, material = ref
    assert hit.any() and (~hit).any()
    np.testing.assert_array_equal(hits.hit, hit)
    # Both ask Embree with float32 rays built in different float64 orders (quaternion vs
    # matrix), which can round differently: allow EMBREE_RTOL. The rest is float64.
    np.testing.assert_allclose(hits.range_m[hit], range_m[hit], rtol=EMBREE_RTOL)
    assert np.all(np.isinf(hits.range_m[~hit]))
    np.testing.assert_allclose(hits.normal[hit], normal[hit], atol=1e-9)
    np.testing.assert_allclose(hits.incidence_rad[hit], incidence[hit], atol=1e-7)
    assert np.all(np.isnan(hits.incidence_rad[~hit]))
    np.testing.assert_allclose(hits.cos_incidence[hit], np.cos(incidence[hit]), atol=1e-9)
    np.testing.assert_array_equal(hits.material, material)
    assert np.all(hits.face[~hit] == -1) and np.all(hits.face[hit] >= 0)


def test_a_pose_per_ray_matches_the_matrix_reference():
    target = sphere_target(1.0, subdivisions=4)
    n = 4000
    rng = np.random.default_rng(3)
    d = rays(n, 4)
    # Target 6-7 m ahead, a different orientation (and position) for every ray.
    position = np.column_stack([rng.uniform(6, 7, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n)])
    poses = Poses.from_quat(Rotation.random(n, random_state=5).as_quat(), position)
    check(cast_at_poses(target, d, poses), reference_cast(target, d, poses))


def test_one_pose_for_all_rays_and_an_offset_origin():
    target = sphere_target(1.0, subdivisions=4)
    d = rays(3000, 6)
    rotation = Rotation.from_euler('xyz', [20, -35, 50], degrees=True)
    poses = Poses(rotation, np.array([6.5, 0.2, -0.1]))  # scipy form, a single pose
    origin = np.array([0.05, -0.1, 0.02])
    check(cast_at_poses(target, d, poses, origin_lidar_m=origin),
          reference_cast(target, d, poses, origin))


def test_cast_order_does_not_change_the_answers():
    target = sphere_target(1.0, subdivisions=4)
    d = rays(3000, 7)
    poses = Poses.from_quat(Rotation.random(len(d), random_state=8).as_quat(),
                            np.tile([6.0, 0.0, 0.0], (len(d), 1)))
    az, el = angles_from_directions(d)
    plain = cast_at_poses(target, d, poses)
    ordered = cast_at_poses(target, d, poses, order=coherent_order(az, el, np.radians(0.5)))
    for field in ('hit', 'range_m', 'normal', 'incidence_rad', 'material', 'face'):
        np.testing.assert_array_equal(getattr(ordered, field), getattr(plain, field))


def test_a_bad_cast_order_is_refused():
    target = sphere_target(1.0, subdivisions=2)
    d = rays(10, 9)
    poses = Poses.from_quat(np.tile([0.0, 0, 0, 1], (10, 1)), np.tile([6.0, 0, 0], (10, 1)))
    with pytest.raises(ValueError, match='cast order'):
        cast_at_poses(target, d, poses, order=np.arange(5))


@pytest.mark.parametrize('n_planes', [1, 255, 256, 700])
def test_support_over_planes_matches_the_matrix_product(n_planes):
    from lidar_sim_ros.core.geometry_kernels import support_over_planes
    rng = np.random.default_rng(n_planes)
    points = rng.normal(0.0, 2.0, (300, 3))
    normals = rng.normal(size=(n_planes, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    base = rng.normal(size=n_planes)
    expected = (points @ normals.T - base).max(axis=0)
    np.testing.assert_allclose(support_over_planes(points, normals, base), expected, rtol=0, atol=1e-12)
    # A unit cube's corners lie at most sqrt(3) / 2 in front of a plane through its centre.
    corners = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    diagonal = np.full((1, 3), 1 / np.sqrt(3))
    assert support_over_planes(corners, diagonal, diagonal @ [0.5, 0.5, 0.5])[0] == pytest.approx(np.sqrt(3) / 2)


def test_rays_left_out_by_the_bounding_box_are_misses_for_embree_too(monkeypatch):
    """``cast_at_poses`` casts only the rays whose line meets the mesh's box: aim rays at
    the box's faces, edges and corners, just inside and just outside, parallel to its
    axes, and from inside it; every answer must be Embree's own on every ray."""
    from lidar_sim_ros.core import geometry
    monkeypatch.setattr(geometry, 'CULL_WORTH', 0.0)         # always test the box
    target = sphere_target(1.0, subdivisions=3)
    lo, hi = target.box_lo_m, target.box_hi_m
    rng = np.random.default_rng(11)
    n = 6000
    # Points on and near the box's surface (corners and edges included), seen from 5 m.
    corner = np.where(rng.random((n, 3)) < 0.5, lo, hi)
    point = np.where(rng.random((n, 3)) < 0.4, corner, rng.uniform(lo, hi, (n, 3)))
    point += rng.normal(0.0, 1e-4, (n, 3)) * rng.choice([0.0, 1.0, 100.0], (n, 1))
    origin = rng.normal(0.0, 1.0, (n, 3))
    origin = 5.0 * origin / np.linalg.norm(origin, axis=1, keepdims=True)
    origin[:500] = rng.uniform(0.5 * lo, 0.5 * hi, (500, 3))          # inside the box
    d = point - origin
    d[500:1000, 1:] = 0.0                                               # along the x axis
    origin[500:1000, 1:] = point[500:1000, 1:]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    poses = Poses.from_quat(np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)))
    hits = cast_at_poses(target, d, poses, origin_lidar_m=origin)
    face, tfar = target.intersect(origin.astype(np.float32), d.astype(np.float32))
    assert 0 < np.count_nonzero(face >= 0) < n
    np.testing.assert_array_equal(hits.face, face)
    np.testing.assert_array_equal(hits.range_m[face >= 0], tfar[face >= 0])


@pytest.mark.parametrize('one_pose', [True, False])
@pytest.mark.parametrize('cull', [0.0, 2.0])
def test_answers_do_not_depend_on_the_thread_count(one_pose, cull, monkeypatch):
    """Parts of the rays on 1, 2 and 3 threads, with the bounding-box test (CULL_WORTH 0)
    and without it (2: never worth it): the same answers."""
    from lidar_sim_ros.core import geometry
    monkeypatch.setattr(geometry, 'CULL_WORTH', cull)
    target = sphere_target(1.0, subdivisions=4)
    d = rays(20000, 12)
    n = 1 if one_pose else len(d)
    poses = Poses.from_quat(Rotation.random(n, random_state=13).as_quat(), np.tile([6.0, 0.1, 0.0], (n, 1)))
    az, el = angles_from_directions(d)
    order = coherent_order(az, el, np.radians(0.5))
    length = np.random.default_rng(14).uniform(5.0, 8.0, len(d))
    answers = []
    for threads in (1, 2, 3):
        target.threads = threads
        answers.append(cast_at_poses(target, d, poses, order=order, length_m=length))
    target.threads = 1
    assert answers[0].hit.any() and (~answers[0].hit).any()
    for other in answers[1:]:
        for field in ('hit', 'range_m', 'normal', 'incidence_rad', 'cos_incidence', 'material', 'face'):
            np.testing.assert_array_equal(getattr(other, field), getattr(answers[0], field))


def test_one_pose_and_origin_leave_out_the_same_rays_as_a_pose_per_ray(monkeypatch):
    """A global exposure (one pose, one origin) moves one origin into the body frame and
    rotates only the directions: the rays kept by the box and every answer are those of the
    same pose given once per ray, and Embree's own on every ray."""
    from lidar_sim_ros.core import geometry, geometry_kernels as kernels
    monkeypatch.setattr(geometry, 'CULL_WORTH', 0.0)
    target = sphere_target(1.0, subdivisions=3)
    d = rays(8000, 21)
    quat = Rotation.random(1, random_state=22).as_quat()
    position, origin = np.array([[5.5, 0.2, -0.1]]), np.array([[0.01, -0.02, 0.03]])
    order = np.random.default_rng(23).permutation(len(d))
    one = kernels.rays_to_body_in_box(quat, position, origin, d, order, target.box_lo_m, target.box_hi_m)
    each = kernels.rays_to_body_in_box(np.repeat(quat, len(d), 0), np.repeat(position, len(d), 0),
                                       np.repeat(origin, len(d), 0), d, order, target.box_lo_m,
                                       target.box_hi_m)
    assert 0 < np.count_nonzero(one[2] >= 0) < len(d)
    for a, b in zip(one, each):
        np.testing.assert_array_equal(a, b)
    assert len(kernels.rays_to_body_in_box(quat, position, origin, d[:0], order[:0],
                                           target.box_lo_m, target.box_hi_m)[2]) == 0
    poses = Poses.from_quat(quat, position)
    hits = cast_at_poses(target, d, poses, origin_lidar_m=origin)
    o32, d32 = kernels.rays_to_body(quat, position, origin, d, np.arange(len(d)))
    face, tfar = target.intersect(o32, d32)
    np.testing.assert_array_equal(hits.face, face)
    np.testing.assert_array_equal(hits.range_m[face >= 0], tfar[face >= 0])


@pytest.mark.parametrize('n, threads', [(100_000, 2), (65_536, 3), (4_099, 2)])
def test_parts_of_equal_cost_cover_every_item_once(n, threads):
    """``split_over_threads`` with a cost per block: contiguous parts, in order, covering
    range(n) once, none empty; with the cost all in the middle (a flash frame's hits) the
    parts hold near-equal cost, not equal counts."""
    from lidar_sim_ros.core.geometry import CULL_SAMPLE, split_over_threads
    blocks = -(-n // CULL_SAMPLE)
    cost = np.ones(blocks)
    cost[blocks // 3: blocks // 2] = 40.0
    parts = split_over_threads(n, threads, lambda part: part, min_per_thread=1024, cost=cost)
    assert parts[0].start == 0 and parts[-1].stop == n
    assert all(a.stop == b.start for a, b in zip(parts[:-1], parts[1:]))
    assert all(p.stop > p.start for p in parts)
    per_item = np.repeat(cost, CULL_SAMPLE)[:n]
    share = np.array([per_item[p].sum() for p in parts]) / per_item.sum()
    if len(parts) > 1:
        assert share.max() < 2.0 / len(parts)
        assert max(p.stop - p.start for p in parts) > 3 * min(p.stop - p.start for p in parts)


def test_a_pool_thread_not_yet_started_is_not_waited_for():
    """``split_over_threads``: when the OS has not run a pool thread by the time the
    calling thread has taken every part (a busy machine), the call returns without it
    (it waited for the thread to start and find nothing left)."""
    import threading
    from lidar_sim_ros.core.geometry import _pool, split_over_threads
    busy, done = threading.Event(), []
    blocker = _pool(2).submit(busy.wait, 30.0)        # the pool's one thread, held
    caller = threading.Thread(target=lambda: done.append(
        split_over_threads(8192, 2, lambda part: part, min_per_thread=1024)))
    caller.start()
    caller.join(10.0)
    finished = not caller.is_alive()
    busy.set()
    blocker.result()
    caller.join()
    assert finished
    assert [(p.start, p.stop) for p in done[0]] == [(0, 2048), (2048, 4096), (4096, 6144),
                                                    (6144, 8192)]


@pytest.mark.parametrize('one_pose', [True, False])
@pytest.mark.parametrize('cull', [0.0, 2.0])
def test_the_hits_alone_are_the_hit_rows_of_the_full_cast(one_pose, cull, monkeypatch):
    """``cast_hits_at_poses`` (the hits as compact rows, a plain frame's cast) gives, on 1,
    2 and 3 threads, with and without the bounding-box test, exactly the rows of
    ``cast_at_poses`` that hit and their range, cosine, material and face."""
    from lidar_sim_ros.core import geometry
    from lidar_sim_ros.core.geometry import cast_hits_at_poses
    monkeypatch.setattr(geometry, 'CULL_WORTH', cull)
    target = sphere_target(1.0, subdivisions=4)
    d = rays(20000, 15)
    n = 1 if one_pose else len(d)
    poses = Poses.from_quat(Rotation.random(n, random_state=16).as_quat(), np.tile([6.0, 0.1, 0.0], (n, 1)))
    full = cast_at_poses(target, d, poses)
    hit = np.flatnonzero(full.hit)
    assert 0 < len(hit) < len(d)
    for threads in (1, 2, 3):
        target.threads = threads
        seen = []
        parts = cast_hits_at_poses(target, d, poses, lambda part, hits: (part, hits))
        for part, hits in parts:
            assert np.all((hits.rows >= part.start) & (hits.rows < part.stop))
            seen.append(hits)
        rows = np.concatenate([h.rows for h in seen])
        np.testing.assert_array_equal(rows, hit)
        for field in ('range_m', 'cos_incidence', 'material', 'face'):
            got = np.concatenate([getattr(h, field) for h in seen])
            assert got.dtype == getattr(full, field).dtype
            np.testing.assert_array_equal(got, getattr(full, field)[hit], err_msg=field)
    target.threads = 1
