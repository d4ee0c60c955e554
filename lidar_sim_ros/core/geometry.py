"""Geometric model (paper Sec. 4): target mesh with materials, and the raycast.

The paper used PANGU for true range and incidence angle; here Embree (embreex)
intersects rays with a triangle mesh whose faces each carry a material id. Rays
are cast in the target body frame, so a target that moves during a frame is
handled by transforming each ray with the pose of its own shot time.
"""
from __future__ import annotations

import itertools
import math
import re
import tempfile
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Callable, Iterator, TypeVar

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from scipy.spatial import ConvexHull, QhullError

from lidar_sim_ros.core import geometry_kernels as kernels
from lidar_sim_ros.core import mesh_files
from lidar_sim_ros.core.memory import release_freed_memory
from lidar_sim_ros.core.mesh_files import (CAD_SUFFIXES, MAX_VERTEX_M, MeshFileError,
                                           MeshMaterialError, few, load_scene, read_cad)
from lidar_sim_ros.core.pose import Poses


T = TypeVar('T')




MAX_TRIANGLES = 10_000_000
"""Triangles in one target mesh (the rocket body has 48,844; Embree's BVH costs ~100 B each)."""


def checked_mesh(vertices_m: np.ndarray, faces: np.ndarray, face_material: np.ndarray,
                 source: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh with its zero-area faces removed (no ray can hit them), after refusing
    non-finite vertices, vertices beyond MAX_VERTEX_M, more than MAX_TRIANGLES faces, and a
    mesh with no area at all
    (a NaN vertex moved the surface and compare blamed physics; an all-NaN or flat mesh
    gave 0 points and rc 0)."""
    if len(faces) > MAX_TRIANGLES:
        raise MeshFileError(f'{source}: {len(faces)} triangles exceed the limit of {MAX_TRIANGLES}')
    bad = ~np.isfinite(vertices_m).all(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise MeshFileError(f'{source}: {int(bad.sum())} of {len(vertices_m)} vertices are not '
                            f'finite, first #{k}: {vertices_m[k].tolist()}')
    far = np.abs(vertices_m).max(axis=1) > MAX_VERTEX_M if len(vertices_m) else np.zeros(0, bool)
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise MeshFileError(f'{source}: vertex #{k} {vertices_m[k].tolist()} (m) is beyond the '
                            f'limit of {MAX_VERTEX_M:g} m ({int(far.sum())} of {len(vertices_m)} '
                            'vertices are; is the file in metres?)')
    tri = vertices_m[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    scale = float(np.ptp(vertices_m, axis=0).max()) if len(vertices_m) else 0.0
    keep = area2 > (1e-12 * scale) ** 2
    if not keep.any():
        raise MeshFileError(f'{source}: all {len(faces)} triangles have zero area')
    return vertices_m, faces[keep], face_material[keep]


@dataclass(frozen=True)
class Hits:
    """Per-ray raycast result. Arrays have one row per ray.

    hit: bool mask; range_m: true range along the ray (inf on a miss);
    normal: unit face normal in the frame the rays were given in (zeros on a miss);
    incidence_rad: angle between the reversed ray and the normal, in [0, pi/2];
    material: material id (-1 on a miss); face: triangle index (-1 on a miss);
    power_fraction: share of the beam's energy that hit (-), None = the whole beam
    (set by footprint-sampling casts such as the beam_divergence effect);
    cos_incidence: cos(incidence_rad) where the raycast has it (saves recomputing it);
    barycentric: (N, 2) float32 (u, v) of each hit on its triangle, the point being
    (1 - u - v) v0 + u v1 + v v2, when asked for (``Target.cast_body_rays``).
    """

    hit: np.ndarray
    range_m: np.ndarray
    normal: np.ndarray
    incidence_rad: np.ndarray
    material: np.ndarray
    face: np.ndarray
    power_fraction: np.ndarray | None = None
    cos_incidence: np.ndarray | None = None
    barycentric: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.hit)


@dataclass(frozen=True)
class BodyRays:
    """Rays moved into the target body frame, as Embree takes them.

    origins_m, directions (N, 3) float32, in cast order (row k is ray ``order[k]``);
    quat_xyzw (N|1, 4): each ray's pose, which rotates normals back to the frame of
    ``directions_out`` (N, 3) float64, the rays' unit directions in input order.
    """

    origins_m: np.ndarray
    directions: np.ndarray
    order: np.ndarray
    quat_xyzw: np.ndarray
    directions_out: np.ndarray

    def __len__(self) -> int:
        return len(self.order)


# Rays per thread below which splitting a cast over threads costs more than it saves.
MIN_RAYS_PER_THREAD = 2048
_POOLS: dict[int, ThreadPoolExecutor] = {}


PARTS_PER_THREAD = 2     # parts a split makes per thread, which every thread takes in turn


def split_over_threads(n: int, threads: int, work: Callable[[slice], T],
                       min_per_thread: int = MIN_RAYS_PER_THREAD,
                       cost: np.ndarray | None = None) -> list[T]:
    """``work`` on contiguous parts of range(n) over ``threads`` threads, results in order.

    For GIL-free work (Embree casts, ``nogil`` kernels). The parts (PARTS_PER_THREAD per
    thread, none under ``min_per_thread``) are taken in turn by the calling thread and by
    pool threads as each comes free, so a thread held up (by the OS, by the GIL) takes
    fewer, and one not yet started when the parts are all taken is not waited for; ``work``
    must never wait on the pool (it may run on it). Fewer threads when parts
    would hold less than ``min_per_thread``. ``cost`` (None: every item alike): the relative
    cost of the blocks of ``ceil(n / len(cost))`` items in turn; the parts then hold equal
    cost, not equal counts (a flash frame's hits are in the middle of its cast order).
    """
    threads = max(1, min(int(threads), n // max(min_per_thread, 1)))
    if threads == 1:
        return [work(slice(0, n))]
    k = max(threads, min(threads * PARTS_PER_THREAD, n // max(min_per_thread, 1)))
    parts = [slice(int(a), int(b)) for a, b in zip(*_part_bounds(n, k, cost))]
    k = len(parts)
    results: list = [None] * k
    taken = itertools.count()      # next() on it is atomic under the GIL

    def drain() -> None:
        while (i := next(taken)) < k:
            results[i] = work(parts[i])
    futures = [_pool(threads).submit(drain) for _ in range(threads - 1)]
    drain()
    for f in futures:
        # A pool thread the OS has not run yet (a busy machine) has nothing left to take:
        # not waited for. One that has started ends its part.
        if not f.cancel():
            f.result()
    return results


def _part_bounds(n: int, k: int, cost: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Starts and ends of k contiguous parts of range(n): equal counts, or (``cost``, one
    value per block of ceil(n / len(cost)) items) near-equal cost, none empty."""
    if cost is None or len(cost) == 0:
        bounds = np.linspace(0, n, k + 1).astype(np.int64)
    else:
        step = -(-n // len(cost))
        cum = np.cumsum(np.asarray(cost, float))
        cut = np.searchsorted(cum, cum[-1] * np.arange(1, k) / k, side='right')
        bounds = np.unique(np.concatenate([[0], np.minimum(cut * step, n), [n]]))
    return bounds[:-1], bounds[1:]


def _pool(threads: int) -> ThreadPoolExecutor:
    """The pool of threads - 1 workers beside the calling thread."""
    if threads - 1 not in _POOLS:
        _POOLS[threads - 1] = ThreadPoolExecutor(threads - 1, thread_name_prefix='raycast')
    return _POOLS[threads - 1]


class Target:
    """A triangle mesh in the target body frame with a material id per face.

    ``threads``: how many threads a large cast is split over (embreex releases the GIL
    while it casts; each ray's answer does not depend on the split, so results are
    the same for any thread count).
    """

    def __init__(self, vertices_m: np.ndarray, faces: np.ndarray, face_material: np.ndarray,
                 material_names: list[str], threads: int = 1):
        self.vertices_m = np.ascontiguousarray(vertices_m, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.face_material = np.ascontiguousarray(face_material, dtype=np.int16)
        self.material_names = list(material_names)
        tri = self.vertices_m[self.faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(cross, axis=1, keepdims=True)
        self.face_normals = np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)
        self._scene = rtcore_scene.EmbreeScene()
        # Embree keeps its own float32 copy; the scene is static for the target's life.
        tri32 = tri.astype(np.float32)
        TriangleMesh(self._scene, tri32)
        # The bounds of what Embree sees (m, body frame): rays whose line misses them are
        # not cast (``cast_at_poses``).
        self.box_lo_m = tri32.reshape(-1, 3).min(axis=0).astype(np.float64)
        self.box_hi_m = tri32.reshape(-1, 3).max(axis=0).astype(np.float64)
        # The first query builds the BVH: do it now, so that threads never race to it.
        self._scene.run(np.zeros((1, 3), np.float32), np.array([[1.0, 0.0, 0.0]], np.float32))
        self.threads = int(threads)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def intersect(self, origins_m: np.ndarray, directions: np.ndarray,
                  barycentric: bool = False, length_m: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """Raw Embree query: face id (-1 = miss) and distance (m) per ray, float32 rays as
        given; with ``barycentric`` also the hit's (u, v) on its triangle; ``length_m``
        (float32 per ray, None = unbounded): hits farther along a ray are misses.

        Split over ``self.threads`` threads when there are enough rays.
        """
        keys = ('primID', 'tfar', 'u', 'v') if barycentric else ('primID', 'tfar')

        def work(part):
            return self._run(origins_m[part], directions[part],
                             None if length_m is None else length_m[part])
        parts = split_over_threads(len(origins_m), self.threads, work)
        if len(parts) == 1:
            return tuple(parts[0][k] for k in keys)
        return tuple(np.concatenate([p[k] for p in parts]) for k in keys)

    def _run(self, origins_m: np.ndarray, directions: np.ndarray,
             length_m: np.ndarray | None) -> dict:
        """One Embree call on float32 rays (GIL released while it casts): its output dict."""
        if length_m is None:
            return self._scene.run(origins_m, directions, output=1)
        return self._scene.run(origins_m, directions, dists=np.array(length_m, np.float32), output=1)

    def cast(self, origins_m: np.ndarray, directions: np.ndarray,
             order: np.ndarray | None = None) -> Hits:
        """Intersect rays (body frame; unit directions) with the mesh: first hit per ray.

        ``order`` optionally casts the rays in a coherent order (neighbouring
        directions together, see ``coherent_order``); results stay in input order.
        """
        d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
        origins = np.asarray(origins_m, dtype=np.float64).reshape(-1, 3)
        order = _cast_order(order, len(d))
        o32, d32 = kernels.rays_to_body(_IDENTITY, _ZERO, origins, d, order)
        return self.cast_body_rays(BodyRays(o32, d32, order, _IDENTITY, d))

    @cached_property
    def face_clearance_m(self) -> np.ndarray:
        """Per face, how far the mesh reaches in front of the face's plane, along its normal
        (m; <= 0: nothing in front, the face lies on the convex hull). A ray leaving the face
        on its normal side at elevation angle beta can only meet the mesh within
        clearance / sin(beta): shadow rays get that length. The maximum over the hull's
        vertices; computed on first use (~0.1 s for 50k faces)."""
        return self._clearance_m(1.0)

    @cached_property
    def face_clearance_back_m(self) -> np.ndarray:
        """``face_clearance_m`` on the other side of each face (against its normal): for rays
        leaving a face whose winding points away from where the light came from."""
        return self._clearance_m(-1.0)

    def _clearance_m(self, side: float) -> np.ndarray:
        try:
            hull = self.vertices_m[ConvexHull(self.vertices_m).vertices]
        except QhullError:   # a flat mesh has no 3-D hull: test against every vertex
            hull = self.vertices_m
        normals = side * self.face_normals
        base = np.einsum('ij,ij->i', normals, self.vertices_m[self.faces[:, 0]])
        out = kernels.support_over_planes(np.ascontiguousarray(hull), normals, base)
        # Degenerate faces (no normal) get no clearance bound.
        return np.where(np.any(self.face_normals != 0, axis=1), out, np.inf)

    @property
    def supporting_faces(self) -> np.ndarray:
        """Bool per face: every vertex lies on or behind its plane (the face is on the convex
        hull), so nothing can shade it from a source on its normal side."""
        return self.face_clearance_m <= 1e-6 * max(float(np.ptp(self.vertices_m, axis=0).max()), 1.0)

    def occluded(self, origins_m: np.ndarray, directions: np.ndarray,
                 length_m: np.ndarray | None = None) -> np.ndarray:
        """Whether each ray (body frame, float32 as Embree takes them) meets the mesh within
        ``length_m`` (float32 per ray; None = unbounded): Embree's occlusion query (shadow rays),
        split over ``self.threads`` threads when there are enough rays."""
        def work(part: slice) -> np.ndarray:
            return self._scene.run(origins_m[part], directions[part], query='OCCLUDED',
                                   dists=None if length_m is None else np.array(length_m[part], np.float32))
        parts = split_over_threads(len(origins_m), self.threads, work)
        return (parts[0] if len(parts) == 1 else np.concatenate(parts)) >= 0

    def cast_body_rays(self, rays: BodyRays, barycentric: bool = False,
                       length_m: np.ndarray | None = None) -> Hits:
        """First hit of each body-frame ray; normals in the frame of ``rays.directions_out``;
        with ``barycentric`` the hits' (u, v) too; ``length_m`` (m per ray, input order;
        None = unbounded) bounds each ray (Embree skips what lies beyond).

        In parts of the cast order, one per thread, each end to end (as ``cast_at_poses``),
        rays whose line misses the mesh's bounding box left out where that pays."""
        if length_m is not None:
            length_m = np.ascontiguousarray(np.asarray(length_m, np.float32).take(rays.order))
        out = _HitRows.empty(len(rays))
        bary = np.zeros((len(rays), 2), np.float32) if barycentric else None
        step = slice(None, None, CULL_SAMPLE)
        cull, cost = _culling(kernels.body_rays_in_box(
            rays.origins_m[step], rays.directions[step], self.box_lo_m, self.box_hi_m)[2])

        in_order = _in_order(rays.order)

        def work(part: slice) -> None:
            o32, d32, slot = rays.origins_m[part], rays.directions[part], _EVERY_RAY
            if cull:
                o32, d32, slot = kernels.body_rays_in_box(o32, d32, self.box_lo_m, self.box_hi_m)
            _cast_part(self, o32, d32, slot, rays.order[part],
                       None if length_m is None else length_m[part], rays.quat_xyzw,
                       rays.directions_out, out, part if in_order else None, bary)
        split_over_threads(len(rays), self.threads, work, cost=cost)
        return out.hits(barycentric=bary)


@dataclass(frozen=True)
class _HitRows:
    """The per-ray arrays of a cast, filled by ``kernels.hit_geometry_into`` (in parts)."""

    hit: np.ndarray
    range_m: np.ndarray
    normal: np.ndarray
    cos_incidence: np.ndarray
    material: np.ndarray
    face: np.ndarray
    incidence_rad: np.ndarray

    @classmethod
    def empty(cls, n: int) -> '_HitRows':
        return cls(np.empty(n, bool), np.empty(n), np.empty((n, 3)), np.empty(n),
                   np.empty(n, np.int16), np.empty(n, np.int64), np.empty(n))

    @property
    def arrays(self) -> tuple[np.ndarray, ...]:
        """The arrays ``kernels.hit_geometry_into`` fills."""
        return self.hit, self.range_m, self.normal, self.cos_incidence, self.material, self.face

    def hits(self, barycentric: np.ndarray | None = None) -> Hits:
        """The Hits these arrays are (filled by then, or to be filled part by part)."""
        return Hits(self.hit, self.range_m, self.normal, self.incidence_rad, self.material,
                    self.face, cos_incidence=self.cos_incidence, barycentric=barycentric)


_IDENTITY = np.array([[0.0, 0.0, 0.0, 1.0]])
_ZERO = np.zeros((1, 3))


def _in_order(order: np.ndarray) -> bool:
    """Whether a cast order is 0, 1, ..., n - 1."""
    n = len(order)
    return n == 0 or (order[0] == 0 and order[-1] == n - 1 and bool(np.all(np.diff(order) == 1)))


def _cast_order(order: np.ndarray | None, n: int) -> np.ndarray:
    if order is None:
        return np.arange(n, dtype=np.int64)
    order = np.asarray(order, dtype=np.int64)
    if order.shape != (n,):
        raise ValueError(f'cast order has shape {order.shape}, expected ({n},)')
    return order


def coherent_order(az_rad: np.ndarray, el_rad: np.ndarray, cell_rad: float = np.radians(1.0)) -> np.ndarray:
    """A ray order that visits neighbouring directions together (1 deg cells, row by row).

    Embree traverses its BVH faster for coherent rays: a round-robin multi-laser
    scan jumps between tiles every shot, which costs most on large meshes.
    """
    row = np.floor(np.asarray(el_rad) / cell_rad).astype(np.int64)
    col = np.floor(np.asarray(az_rad) / cell_rad).astype(np.int64)
    return np.lexsort((col, row))


def cast_at_poses(target: Target, directions_lidar: np.ndarray, poses: Poses,
                  origin_lidar_m: np.ndarray | None = None, order: np.ndarray | None = None,
                  length_m: np.ndarray | None = None,
                  then: Callable[[Hits, slice | np.ndarray], None] | None = None) -> Hits:
    """Cast lidar-frame rays, each against the target at its own pose.

    Rays go into the body frame with their pose, are cast there, and the normals
    come back to the lidar frame. Ranges are frame-independent. ``length_m``: each
    ray's length (m; None = unbounded), hits beyond it are misses.

    The rays are cast in contiguous parts of the cast order, one per thread
    (``target.threads``), each part end to end: into the body frame, Embree, and back
    (compiled loops that release the GIL, as Embree does). Rays whose line misses the
    mesh's bounding box are not cast (a flash array's pixels around the target: 60 % of
    them). Each ray's answer is the same whatever the parts. ``then(hits, rows)``: the
    work that follows on each part's own thread, once the part's rows (a slice, or indices
    when a cast order is given) of the returned ``hits`` are filled.
    """
    d = np.ascontiguousarray(directions_lidar, dtype=np.float64).reshape(-1, 3)
    origin = np.zeros((1, 3)) if origin_lidar_m is None else np.asarray(origin_lidar_m, float).reshape(-1, 3)
    quat, position = poses.quat_xyzw, poses.position_m.reshape(-1, 3)
    in_order = order is None
    order = _cast_order(order, len(d))
    if length_m is not None:
        length_m = np.asarray(length_m, np.float32)
    out = _HitRows.empty(len(d))
    hits = out.hits()
    cull, cost = _culling(kernels.rays_to_body_in_box(
        quat, position, origin, d, order[::CULL_SAMPLE], target.box_lo_m, target.box_hi_m)[2])
    lengths = None if length_m is None else length_m.take(order)

    def work(part: slice) -> None:
        rows = order[part]
        if cull:
            o32, d32, slot = kernels.rays_to_body_in_box(quat, position, origin, d, rows,
                                                         target.box_lo_m, target.box_hi_m)
        else:
            (o32, d32), slot = kernels.rays_to_body(quat, position, origin, d, rows), _EVERY_RAY
        view = part if in_order else rows
        _cast_part(target, o32, d32, slot, rows, None if lengths is None else lengths[part],
                   quat, d, out, view)
        if then is not None:
            then(hits, view)
    split_over_threads(len(d), target.threads, work, cost=cost)
    return hits


@dataclass(frozen=True)
class HitRows:
    """The hits of a cast alone (no row per miss): ``rows`` (increasing) are the rays that
    hit, with their range (m), cosine of incidence (normal toward the sensor), material id
    and face: ``Hits`` without the misses' rows, normals or incidence angles."""

    rows: np.ndarray
    range_m: np.ndarray
    cos_incidence: np.ndarray
    material: np.ndarray
    face: np.ndarray

    def __len__(self) -> int:
        return len(self.rows)


def cast_hits_at_poses(target: Target, directions_lidar: np.ndarray, poses: Poses,
                       then: Callable[[slice, HitRows], T]) -> list[T]:
    """``cast_at_poses`` from the sensor's origin, rays in their own order, for a caller
    that needs the hits alone: each part of the cast (on its own thread) gives
    ``then(part, hit_rows)`` its rays' hits as compact rows (a flash frame's ~19,000 of
    65,536 rays), and the answers of ``then`` come back in part order. Every hit's numbers
    are those ``cast_at_poses`` gives its row."""
    d = np.ascontiguousarray(directions_lidar, dtype=np.float64).reshape(-1, 3)
    origin = np.zeros((1, 3))
    quat, position = poses.quat_xyzw, poses.position_m.reshape(-1, 3)
    cull, cost = _culling(kernels.rays_to_body_in_box(
        quat, position, origin, d, np.arange(0, len(d), CULL_SAMPLE), target.box_lo_m,
        target.box_hi_m)[2])

    def work(part: slice) -> T:
        rows = np.arange(part.start, part.stop, dtype=np.int64)
        if cull:
            o32, d32, slot = kernels.rays_to_body_in_box(quat, position, origin, d, rows,
                                                         target.box_lo_m, target.box_hi_m)
        else:
            (o32, d32), slot = kernels.rays_to_body(quat, position, origin, d, rows), _EVERY_RAY
        face, tfar = _NO_RAYS[:2]
        if len(o32):
            found = target._run(o32, d32, None)
            face, tfar = found['primID'], found['tfar']
        hits = HitRows(*kernels.hit_rows_of(face, tfar, slot, part.start, len(rows),
                                            target.face_normals, target.face_material, quat, d))
        return then(part, hits)
    return split_over_threads(len(d), target.threads, work, cost=cost)


_EVERY_RAY = np.zeros(0, np.int64)     # hit_geometry_into's slot when every ray was cast
CULL_SAMPLE = 64        # every 64th ray tells whether the bounding-box test pays
CULL_WORTH = 0.25       # the share of rays it must leave out (a cast miss costs ~5x the test)


CULL_KEPT_COST = 6.0    # a ray cast costs ~6x one left out (Embree ~100 ns against ~16 ns)


def _culling(sample_slot: np.ndarray) -> tuple[bool, np.ndarray | None]:
    """Whether enough rays miss the mesh's bounding box for the test to pay (a flash array
    around the target: 60 % of its pixels; a P-60 frame filled by it: few), judged on a
    sample's slots (-1: outside, one per CULL_SAMPLE rays), and then each sampled block's
    relative cost, for ``split_over_threads`` to balance the parts (the rays cast are
    together in the middle of a flash frame). Either way every ray gets the same answer."""
    cull = (len(sample_slot) >= 16
            and np.count_nonzero(sample_slot < 0) >= CULL_WORTH * len(sample_slot))
    return cull, (1.0 + CULL_KEPT_COST * (sample_slot >= 0)) if cull else None


def _cast_part(target: Target, o32: np.ndarray, d32: np.ndarray, slot: np.ndarray,
               rows: np.ndarray, length_m: np.ndarray | None, quat: np.ndarray,
               dir_out: np.ndarray, out: _HitRows, view: slice | np.ndarray | None = None,
               bary: np.ndarray | None = None) -> None:
    """One thread's part of a cast: Embree on the body-frame rays kept (o32, d32; ``slot``
    as ``kernels.hit_geometry_into`` takes it), their answers into rows ``rows`` of ``out``
    (``view``: the same rows as a slice where they are one; and of ``bary``, the hits'
    (u, v)); ``length_m``: the part's ray lengths in cast order."""
    face, tfar, u, v = _NO_RAYS
    if len(o32):
        kept = slot >= 0 if len(slot) else slice(None)
        found = target._run(o32, d32, None if length_m is None else length_m[kept])
        face, tfar, u, v = found['primID'], found['tfar'], found['u'], found['v']
        if bary is not None:
            # Every ray of an in-order part cast: plain copies, no scatter.
            cast = view if view is not None and len(slot) == 0 else rows[kept]
            bary[cast, 0], bary[cast, 1] = u, v
    kernels.hit_geometry_into(face, tfar, slot, rows, target.face_normals, target.face_material,
                              quat, dir_out, *out.arrays)
    view = rows if view is None else view
    out.incidence_rad[view] = np.arccos(out.cos_incidence[view])


_NO_RAYS = (np.zeros(0, np.int32), np.zeros(0, np.float32), np.zeros(0, np.float32),
            np.zeros(0, np.float32))


def body_rays(directions_lidar: np.ndarray, poses: Poses, origin_lidar_m: np.ndarray | None = None,
              order: np.ndarray | None = None) -> BodyRays:
    """Lidar-frame rays (unit directions; origin default: the sensor) in the body frame,
    each with the pose of its own shot, in cast order."""
    d = np.ascontiguousarray(directions_lidar, dtype=np.float64).reshape(-1, 3)
    origin = np.zeros((1, 3)) if origin_lidar_m is None else np.asarray(origin_lidar_m, float).reshape(-1, 3)
    quat, position = poses.quat_xyzw, poses.position_m.reshape(-1, 3)
    order = _cast_order(order, len(d))
    o32, d32 = kernels.rays_to_body(quat, position, origin, d, order)
    return BodyRays(o32, d32, order, quat, d)


def occluded_at_poses(target: Target, origins_lidar_m: np.ndarray, directions_lidar: np.ndarray,
                      poses: Poses) -> np.ndarray:
    """Shadow rays: does the ray from each lidar-frame origin along its unit direction meet
    the target (at the pose of its row, or one pose for all)? Bool per ray."""
    d = np.ascontiguousarray(directions_lidar, dtype=np.float64).reshape(-1, 3)
    origins = np.ascontiguousarray(origins_lidar_m, dtype=np.float64).reshape(-1, 3)
    if len(d) == 0:
        return np.zeros(0, bool)
    o32, d32 = kernels.rays_to_body(poses.quat_xyzw, poses.position_m.reshape(-1, 3), origins, d,
                                    np.arange(len(d), dtype=np.int64))
    return target.occluded(o32, d32)


def load_target(obj_path: str | Path, material_names: list[str], threads: int = 1,
                mesh_materials: str | dict[str, str] | None = None) -> Target:
    """Load an OBJ+MTL whose ``usemtl`` names are material names from the config, or a
    CAD export (glTF, STL, PLY: ``core/mesh_files.py``): ``read_target_mesh``, then the
    raycast's BVH over it."""
    target = Target(*read_target_mesh(obj_path, material_names, mesh_materials),
                    material_names, threads)
    release_freed_memory(collect=True)      # trimesh's parse: ~180 MB for 2 M triangles
    return target


def read_target_mesh(obj_path: str | Path, material_names: list[str],
                     mesh_materials: str | dict[str, str] | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (m), faces and face material ids of a target mesh file, checked
    (``checked_mesh``), without building the BVH: what a campaign checks of each target
    choice at load.

    ``mesh_materials``: the scenario's map from the file's material/node/group names to
    config materials, or one material for the whole file (None: the names are the
    config's). Raises MeshFileError for a file that cannot be read (see
    ``check_obj_file``) and MeshMaterialError naming every group it cannot map.
    """
    obj_path = Path(obj_path)
    if not obj_path.is_file():
        raise FileNotFoundError(f'mesh file not found: {obj_path}')
    if obj_path.suffix.lower() in CAD_SUFFIXES:
        return checked_mesh(*read_cad(obj_path, list(material_names), mesh_materials, MAX_TRIANGLES),
                            obj_path)
    names_only = check_obj_file(obj_path)
    with _with_names_mtl(obj_path, names_only) as loadable:
        # The material library and its images from the OBJ's own folder only, whatever
        # trimesh's version does with absolute paths or '..'.
        scene = load_scene(obj_path, loadable, 'an OBJ')
    verts, faces, mats, unknown = [], [], [], []
    offset = 0
    for key, geom in scene.geometry.items():
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        material = getattr(getattr(geom, 'visual', None), 'material', None)
        name = getattr(material, 'name', None) or key
        if isinstance(mesh_materials, str):
            name = mesh_materials
        elif mesh_materials is not None:
            name = mesh_materials.get(name, name)
        if name not in material_names:
            unknown.append(name)
            continue
        verts.append(np.asarray(geom.vertices, dtype=float))
        faces.append(np.asarray(geom.faces, dtype=np.int64) + offset)
        mats.append(np.full(len(geom.faces), material_names.index(name)))
        offset += len(geom.vertices)
    if unknown:
        raise MeshMaterialError(
            f'{obj_path}: material group(s) {few(sorted(set(unknown)))} not in the materials config '
            f'(known: {material_names}; map them in mesh_materials: the scenario\'s, or the '
            f'node\'s mesh_materials parameter)')
    if not faces:
        raise MeshMaterialError(f'{obj_path}: no triangles found')
    del scene
    return checked_mesh(np.vstack(verts), np.vstack(faces), np.concatenate(mats), obj_path)


@contextmanager
def _with_names_mtl(obj_path: Path, names: list[str] | None) -> Iterator[Path]:
    """``obj_path`` itself, or (``names`` given) a copy beside a material library that
    defines just those names. trimesh keeps ``usemtl`` names only when the ``mtllib``
    file is there, and otherwise names the groups after the file (``x.obj``,
    ``x.obj_1``); the simulator needs the names alone (materials come from the config)."""
    if names is None:
        yield obj_path
        return
    with tempfile.TemporaryDirectory(prefix='lidar_sim_obj_') as tmp:
        lines = [line for line in obj_path.read_text(encoding='utf-8').splitlines()
                 if line.strip().partition(' ')[0] != 'mtllib']
        (Path(tmp) / 'names.mtl').write_text(''.join(f'newmtl {n}\n' for n in names))
        copy = Path(tmp) / obj_path.name
        copy.write_text('mtllib names.mtl\n' + '\n'.join(lines) + '\n', encoding='utf-8')
        yield copy


_MAYBE_NOT_FINITE = re.compile(r'[nNiI]|[eE]\+?0*\d{2}|[eE]\+?0*[5-9]|(?<![\d.])\d{6}')
"""A 'v' line that may hold a non-finite number (nan, inf, or an exponent past 1e308) or
one beyond MAX_VERTEX_M (1e5: an exponent of 5 or more, or six digits before the point)."""


def _check_obj_vertex(rest: str, vertex: int, line: int, obj_path: Path) -> None:
    """An OBJ vertex as written, refused when a coordinate is not finite or beyond
    MAX_VERTEX_M: named by its number (as the 'f' lines count, from 1), its line and its
    text; trimesh's vertices are regrouped per material, so their index is not the file's."""
    try:
        xyz = [float(x) for x in rest.split()[:3]]
    except ValueError:
        return                          # not numbers: trimesh's parse says so
    where = f'{obj_path}: vertex {vertex} (line {line}: "v {rest.strip()[:80]}")'
    if not all(math.isfinite(x) for x in xyz):
        raise MeshFileError(f'{where} is not finite')
    if max(map(abs, xyz), default=0.0) > MAX_VERTEX_M:
        raise MeshFileError(f'{where} is beyond the limit of {MAX_VERTEX_M:g} m on an axis '
                            '(is the file in metres?)')


def check_obj_file(obj_path: Path) -> list[str] | None:
    """Reject, with one line naming the file, what trimesh would report obscurely or not at all.

    A file that is not ``.obj`` (an ``.mtl`` given as the mesh raises NotImplementedError
    in trimesh); binary or garbled text; no faces; no ``usemtl`` names. Returns the
    ``usemtl`` names when no ``mtllib`` file carries them (no ``mtllib`` line, or its file
    is missing: many exporters write the names alone), else None.
    """
    suffix = obj_path.suffix.lower()
    if suffix == '.mtl':
        raise MeshFileError(f'{obj_path}: this is a material library (.mtl), not a mesh; give the '
                            f'.obj file that names it (mtllib {obj_path.name})')
    if suffix != '.obj':
        raise MeshFileError(f'{obj_path}: the mesh must be a Wavefront .obj whose usemtl names are '
                            f'materials of the config, or a CAD export ({", ".join(CAD_SUFFIXES)}), '
                            f'not {suffix or "a file without extension"}')
    size = obj_path.stat().st_size
    if size > mesh_files.MAX_TEXT_MESH_BYTES:
        raise MeshFileError(f'{obj_path}: {size} bytes of text mesh exceed the limit of '
                            f'{mesh_files.MAX_TEXT_MESH_BYTES} (export it as binary STL or PLY, '
                            'or glTF)')
    data = obj_path.read_bytes()
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise MeshFileError(f'{obj_path}: not a text OBJ file (byte {exc.start} is not UTF-8)') from None
    if '\x00' in text:
        raise MeshFileError(f'{obj_path}: not a text OBJ file (it holds NUL bytes)')
    mtllibs, usemtl, faces, vertices = [], [], 0, 0
    for number, line in enumerate(text.splitlines(), 1):
        keyword, _, rest = line.strip().partition(' ')
        if keyword == 'f':
            faces += 1
        elif keyword == 'v':
            vertices += 1
            if _MAYBE_NOT_FINITE.search(rest):
                _check_obj_vertex(rest, vertices, number, obj_path)
        elif keyword == 'usemtl' and rest.strip() and rest.strip() not in usemtl:
            usemtl.append(rest.strip())
        elif keyword == 'mtllib':
            mtllibs += rest.split()
    if faces == 0:
        raise MeshFileError(f'{obj_path}: no faces (no "f" lines): the file is empty or not an OBJ mesh')
    if faces > MAX_TRIANGLES:
        raise MeshFileError(f'{obj_path}: {faces} faces exceed the limit of {MAX_TRIANGLES} triangles')
    if not usemtl:
        raise MeshFileError(f'{obj_path}: no usemtl lines: every face needs a material name '
                            'from the materials config (usemtl NAME)')
    root = obj_path.resolve().parent
    libraries = [(root / name).resolve() for name in mtllibs]
    for name, lib in zip(mtllibs, libraries):
        if Path(name).is_absolute() or not lib.is_relative_to(root):
            raise MeshFileError(f'{obj_path}: mtllib {name!r} is not beside the mesh (absolute '
                                f'paths and paths out of {root} are not read; copy it beside)')
    if libraries and all(lib.is_file() for lib in libraries):
        defined = {line.split(None, 1)[1].strip() for lib in libraries
                   for line in lib.read_text(encoding='utf-8', errors='replace').splitlines()
                   if line.strip().startswith('newmtl ')}
        if defined.issuperset(usemtl):
            return None
    return usemtl
