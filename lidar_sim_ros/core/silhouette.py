"""Where a narrow cone around a ray can see more than one surface: silhouette edges.

A beam footprint (``effects/beam_divergence.py``) lands on one connected, front-facing
sheet of the mesh unless an edge where the visible surface ends crosses it. On a
triangle mesh those edges are:

- **silhouette edges**: the two faces of the edge lie on the same side of the plane
  through the viewpoint and the edge (the surface folds away: the limb of a cylinder,
  the rim of a plate seen edge-on, the near side of every depth step);
- **boundary edges** (one face) and non-manifold edges (three or more): always.

The test is independent of the triangles' winding: for the edge a-b with opposite
vertices c1 and c2, ``s_k(o) = ((b - a) x (c_k - a)) . (o - a)`` has the sign of the
side of the plane (o, a, b) that c_k is on, and is affine in the viewpoint o. Over a
box of viewpoints (a frame's sensor positions in the body frame, which move with the
target) the interval of each s_k is exact, so an edge is kept unless it is smooth for
*every* viewpoint in the box: the candidate set is conservative.

``cones_touching_edges`` then tells, for each ray, whether any candidate edge enters
its cone (half-angle ``alpha``): the exact test of a segment against a cone is a
segment against a disc of radius tan(alpha) in the ray's own gnomonic plane, done in
a compiled loop over the edges binned on a coarse angular grid.

``MeshEdges`` also carries the face adjacency that lets a sub-ray be followed from
one facet to the next across the sheet (``face_neighbour``, ``face_edge_normal``).
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from numba import njit

from lidar_sim_ros.core.memory import release_freed_memory

WELD_M = 1e-6           # vertices closer than this are one vertex (OBJ groups repeat them)
REGION_LINES = 8        # most edge lines a flat region keeps (more: its faces stand alone)
COPLANAR_RAD = 1e-5     # faces folded by less than this are one plane (a sub-ray moves < 1 um per 0.1 m)
SIGN_GROUP = 16         # edges per bounded group in the silhouette classification (``_sign_groups``)
# numba fastmath flags for the compiled loops that allow it: reassociation, FMA, reciprocals
# (~5 % faster); never nnan / ninf, which would let the compiler drop inf and NaN handling.
FAST_ALGEBRA = {'contract', 'arcp', 'reassoc', 'nsz'}


@dataclass(frozen=True, eq=False)
class MeshEdges:
    """The undirected edges and face adjacency of a triangle mesh.

    Indices are int32 (a mesh holds at most ``geometry.MAX_TRIANGLES`` faces), and only
    what the footprint kernels read per shot is stored; the per-edge geometry is computed
    from the welded vertices when asked (a 2-million-triangle mesh: 3 M edges, 73 MB per
    (E, 3) float64 array).

    vertex_m (V, 3): the welded vertices (m) that the index tables below point into;
    edge_vertices (E, 2): the two vertices a, b of each edge, a -> b as its first face
    winds; edge_opposite (E, 2): the third vertex of that face and of the second one (-1:
    no second face, or more than two); edge_faces (E, 2): the two faces (the first twice
    when there is no second); always (E,): boundary or non-manifold edge; coplanar (E,):
    two faces folded by less than COPLANAR_RAD.
    a_m, b_m (E, 3): endpoints (m); n1, n2 (E, 3): normals of the two faces, both
    oriented along a -> b (``(b - a) x (c_k - a)``, unnormalised; zero for a missing
    face): properties, computed on each access.
    face_vertices (F, 3): each face's welded vertices; face_edge (F, 3): the edge k
    (vertices k, k + 1) of each face; face_neighbour (F, 3): the face across edge k, -1 at
    a boundary or non-manifold edge.
    face_planes (F, 4, 4) float64, per face for compiled loops: rows (n, offset), (m_0,
    c_0), (m_1, c_1), (m_2, c_2), viewed as face_normal (F, 3): unit face normals (the
    faces' own winding); face_plane_offset (F,): n . p on the face's plane (m);
    face_edge_normal (F, 3, 3): unit vectors in the face's plane, perpendicular to edge
    k, pointing inside; face_edge_offset (F, 3): a point p of the plane is inside the face
    when face_edge_normal[f, k] . p >= face_edge_offset[f, k] for every k (the margin is
    the distance to edge k, m).
    face_region (F,): the flat region of several faces a face belongs to (-1: none, the
    face stands alone), region_lines (R, REGION_LINES, 4) its bounding lines (``flat_regions``).
    vertex_tilt_rad, vertex_reach_m (V,): how far each vertex's star bends and reaches
    (``vertex_stars``); crossing_a_m, crossing_b_m (C, 3): where the mesh passes through
    itself (``intersection_segments``).
    """

    always: np.ndarray
    coplanar: np.ndarray
    face_edge: np.ndarray
    face_neighbour: np.ndarray
    face_planes: np.ndarray
    face_region: np.ndarray
    region_lines: np.ndarray
    edge_vertices: np.ndarray
    edge_opposite: np.ndarray
    edge_faces: np.ndarray
    face_vertices: np.ndarray
    median_edge_m: float = 0.0
    vertex_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    vertex_tilt_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vertex_reach_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    crossing_a_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    crossing_b_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def __len__(self) -> int:
        return len(self.edge_vertices)

    # Views of the packed planes (no second copy).
    @property
    def face_normal(self) -> np.ndarray:
        return self.face_planes[:, 0, :3]

    @property
    def face_plane_offset(self) -> np.ndarray:
        return self.face_planes[:, 0, 3]

    @property
    def face_edge_normal(self) -> np.ndarray:
        return self.face_planes[:, 1:4, :3]

    @property
    def face_edge_offset(self) -> np.ndarray:
        return self.face_planes[:, 1:4, 3]

    # Per-edge geometry, from the welded vertices on each access.
    @property
    def a_m(self) -> np.ndarray:
        return self.vertex_m[self.edge_vertices[:, 0]]

    @property
    def b_m(self) -> np.ndarray:
        return self.vertex_m[self.edge_vertices[:, 1]]

    @property
    def n1(self) -> np.ndarray:
        return self.edge_normals(slice(None))[0]

    @property
    def n2(self) -> np.ndarray:
        return self.edge_normals(slice(None))[1]

    def edge_normals(self, rows) -> tuple[np.ndarray, np.ndarray]:
        """n1, n2 (M, 3) of the edges ``rows`` (index array or slice)."""
        return _edge_normals(self.vertex_m, self.edge_vertices[rows], self.edge_opposite[rows])

    def candidates(self, origin_lo_m: np.ndarray, origin_hi_m: np.ndarray) -> np.ndarray:
        """Indices of the edges that may be a silhouette or a boundary for some viewpoint
        in the box [origin_lo_m, origin_hi_m] (body frame, m)."""
        lo = np.asarray(origin_lo_m, float)
        hi = np.asarray(origin_hi_m, float)
        return np.flatnonzero(self.candidate_mask(lo, hi))

    def candidate_segments(self, candidate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End points (M, 3), (M, 3) of the edges in the mask ``candidate`` followed by the
        self-intersection segments: everything a footprint cannot be followed across (views
        of one (M, 6) array: each segment's end points gathered together)."""
        # Only non-coplanar edges can be candidates; (M, 2) vertex ids gather (M, 2, 3) points.
        edge = np.flatnonzero(candidate & ~self.coplanar)
        ends = np.concatenate([self.vertex_m[self.edge_vertices[edge]].reshape(-1, 6),
                               self._crossing_ends])
        return ends[:, :3], ends[:, 3:]

    @cached_property
    def _crossing_ends(self) -> np.ndarray:
        return np.ascontiguousarray(np.hstack([self.crossing_a_m, self.crossing_b_m]))

    def candidate_mask(self, origin_lo_m: np.ndarray, origin_hi_m: np.ndarray) -> np.ndarray:
        """``candidates`` as a mask over the edges."""
        return self.candidates_with_segments(origin_lo_m, origin_hi_m)[0]

    def candidates_with_segments(self, origin_lo_m: np.ndarray, origin_hi_m: np.ndarray
                                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``candidate_mask`` and, from the same pass, ``candidate_segments`` of that mask:
        (E,) bool, end points (M, 3), (M, 3) (m; views of one (M, 6) array). One compiled
        loop instead of three passes over the E edges and a gather (a frame's footprint
        reads both)."""
        lo = np.asarray(origin_lo_m, float)
        hi = np.asarray(origin_hi_m, float)
        # The planes and the sums are float32 (the loop runs twice as wide): s_k is exact to
        # ~3e-7 |n_k| |o| (~3e-6 |n_k| at 10 m); widen the box by more than that.
        centre = 0.5 * (lo + hi)
        widen = 1e-5 + 1e-6 * float(np.abs(centre).max() + np.abs(hi - lo).max())
        groups, group_size = self._sign_groups
        mask, ends = _maybe_silhouette(self._sign_planes, self._sign_always, groups,
                                       group_size, self._sign_edge, len(self), centre,
                                       0.5 * (hi - lo) + widen, self.edge_vertices,
                                       self.vertex_m, self._crossing_ends)
        return mask, ends[:, :3], ends[:, 3:]

    @cached_property
    def face_star(self) -> np.ndarray:
        """(F, 16) float32 per face, one cache line for compiled loops: the altitudes of
        vertices 0-2 over their opposite edges (m), the squared lengths of edges 0-2 (m^2),
        and of the stars of vertices 0-2 the reach (m), tan(tilt) and 1 / cos(tilt) (inf
        from a right angle on)."""
        out = np.zeros((len(self.face_vertices), 16), np.float32)
        for part in _face_chunks(len(out)):      # bounded temporaries
            corners = self.face_vertices[part]
            tri = self.vertex_m[corners]
            edge = np.roll(tri, -1, axis=1) - tri
            out[part, 0:3] = _altitudes(tri)
            out[part, 3:6] = np.einsum('fkj,fkj->fk', edge, edge)
            out[part, 6:9] = self.vertex_reach_m[corners]
            tilt = self.vertex_tilt_rad[corners]
            acute = tilt < 0.5 * np.pi
            tilt = np.where(acute, tilt, 0.0)
            out[part, 9:12] = np.where(acute, np.tan(tilt), np.inf)
            out[part, 12:15] = np.where(acute, 1.0 / np.cos(tilt), np.inf)
        return out

    @cached_property
    def face_bounds(self) -> np.ndarray:
        """(F, 10) float32 per face: how far a point of the face lies inside its flat region
        (or, for a face in none, inside the face). Rows 0-2, 3-5, 6-8: for the three boundary
        lines nearest to the face (its own edges where it stands alone), the line's signed
        distance at vertices 0-2 (m), so that the distance of a point with barycentric
        weights w is w . row; column 9: a lower bound on the distance of any point of the
        face to the region's other lines (m; inf: none). A face that touches more than three
        of its region's lines keeps its own edges where they leave more room at its centre
        (either way, the minimum over the rows and the bound never exceeds the distance)."""
        out = np.empty((len(self.face_vertices), 10), np.float32)
        _face_bounds(self.face_vertices, self.vertex_m, self.face_region, self.region_lines,
                     self.face_star, out)
        return out

    @cached_property
    def face_crease(self) -> np.ndarray:
        """(F, 3, 7) float32 per face and edge k (vertices k, k + 1): tan and 1 / cos of the
        fold to the face beyond (inf: none, or a right angle or more), sin and cos of that
        face's angles at vertex k and at vertex k + 1, and the edge's length (m)."""
        corners = self.face_vertices
        n_faces = len(corners)
        out = np.zeros((n_faces, 3, 7), np.float32)
        out[:, :, 0:2] = np.inf
        for part, k in ((part, k) for part in _face_chunks(n_faces) for k in range(3)):
            face = part.start + np.flatnonzero(self.face_neighbour[part, k] >= 0)
            beyond = self.face_neighbour[face, k]
            n1, n2 = self.edge_normals(self.face_edge[face, k])
            with np.errstate(invalid='ignore', divide='ignore'):
                cos_fold = -np.einsum('ij,ij->i', n1, n2) / (np.linalg.norm(n1, axis=1)
                                                           * np.linalg.norm(n2, axis=1))
            start, end = corners[face, k], corners[face, (k + 1) % 3]
            others = corners[beyond]
            third = (others != start[:, None]) & (others != end[:, None])
            far = others[np.arange(len(face)), np.argmax(third, axis=1)]
            ok = (cos_fold > 0.0) & third.any(axis=1)
            a, b, w = self.vertex_m[start], self.vertex_m[end], self.vertex_m[far]
            row = out[face[ok], k]
            row[:, 0] = np.sqrt(np.clip(1.0 - cos_fold[ok] ** 2, 0.0, None)) / cos_fold[ok]
            row[:, 1] = 1.0 / cos_fold[ok]
            row[:, 2:4] = _sin_cos_between(b - a, w - a)[ok]
            row[:, 4:6] = _sin_cos_between(a - b, w - b)[ok]
            row[:, 6] = np.linalg.norm(b - a, axis=1)[ok]
            out[face[ok], k] = row
        return out

    @cached_property
    def _sign_planes(self) -> np.ndarray:
        """(8, M) float32 rows n1, n1 . a, n2, n2 . a of the non-coplanar edges: s_k(o) =
        n_k . o - n_k . a, one row per component so the classification loop vectorises."""
        keep = self._sign_edge
        out = np.empty((8, len(keep)), np.float32)
        for lo in range(0, len(keep), FACE_CHUNK):        # bounded temporaries
            rows = keep[lo:lo + FACE_CHUNK]
            part = slice(lo, lo + len(rows))
            a = self.vertex_m[self.edge_vertices[rows, 0]]
            n1, n2 = self.edge_normals(rows)
            out[0:3, part], out[3, part] = n1.T, np.einsum('ij,ij->i', n1, a)
            out[4:7, part], out[7, part] = n2.T, np.einsum('ij,ij->i', n2, a)
        return out

    @cached_property
    def _sign_always(self) -> np.ndarray:
        return np.ascontiguousarray(self.always[self._sign_edge])

    @cached_property
    def _sign_edge(self) -> np.ndarray:
        """The non-coplanar edges (only they can be silhouettes), ordered so that each run of
        SIGN_GROUP holds edges close together with similar normals: a Morton order of their
        midpoints within coarse bins of their first face's normal (``_sign_groups``)."""
        edge = np.flatnonzero(~self.coplanar).astype(np.int32)
        if len(edge) == 0:
            return edge
        origin = self.vertex_m.min(axis=0)
        cell = max(float(np.ptp(self.vertex_m, axis=0).max()), 1e-9) / 1023.0
        key = np.empty(len(edge), np.int64)
        for lo in range(0, len(edge), FACE_CHUNK):        # bounded temporaries
            rows = edge[lo:lo + FACE_CHUNK]
            ends = self.vertex_m[self.edge_vertices[rows]]                # (m, 2, 3)
            grid = np.clip(((ends.mean(axis=1) - origin) / cell).astype(np.int64), 0, 1023)
            n1 = self.edge_normals(rows)[0]
            with np.errstate(invalid='ignore', divide='ignore'):
                unit = n1 / np.linalg.norm(n1, axis=1, keepdims=True)
            bins = np.clip(np.nan_to_num((unit + 1.0) * 2.0), 0, 3).astype(np.int64)
            key[lo:lo + len(rows)] = (((bins[:, 0] * 4 + bins[:, 1]) * 4 + bins[:, 2]) << 30
                                      | _morton3(grid))
        return edge[np.argsort(key, kind='stable')]

    @cached_property
    def _sign_groups(self) -> tuple[np.ndarray, int]:
        """Bounds per run of ``group`` (SIGN_GROUP) rows of ``_sign_planes``, each plane
        scaled to a unit normal, and ``group``: (G, 17) float64, the least and greatest
        components of n1 (columns 0-2, 3-5) and of its offset (6, 7), the same for n2 (8-13,
        14, 15), and 1 in column 16 where the run holds a boundary edge or a plane without a
        normal (such a run is never classified as a whole)."""
        group, m = SIGN_GROUP, len(self._sign_edge)
        out = np.zeros(((m + group - 1) // group, 17))
        step = -(-FACE_CHUNK // group) * group              # whole runs per block
        for lo in range(0, m, step):                        # bounded temporaries
            part = slice(lo, min(lo + step, m))
            planes = self._sign_planes[:, part].astype(np.float64)
            bad = self._sign_always[part].copy()
            rows = slice(lo // group, (part.stop + group - 1) // group)
            padded = (rows.stop - rows.start) * group
            for k, col in ((0, 0), (4, 8)):
                length = np.linalg.norm(planes[k:k + 3], axis=0)
                bad |= length == 0.0
                unit = planes[k:k + 4] / np.where(length > 0.0, length, 1.0)
                # Pad the last run with copies of its last row (no effect on least/greatest).
                unit = np.concatenate([unit, np.repeat(unit[:, -1:], padded - unit.shape[1], axis=1)],
                                      axis=1).reshape(4, -1, group)
                out[rows, col:col + 3] = unit[:3].min(axis=2).T
                out[rows, col + 3:col + 6] = unit[:3].max(axis=2).T
                out[rows, col + 6], out[rows, col + 7] = unit[3].min(axis=1), unit[3].max(axis=1)
            out[rows, 16] = np.concatenate([bad, np.zeros(padded - len(bad), bool)]
                                           ).reshape(-1, group).any(axis=1)
        return out, group


def _edge_normals(vertex_m: np.ndarray, ends: np.ndarray, opposite: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """n_k = (b - a) x (c_k - a) (M, 3) for edges a -> b (``ends`` (M, 2)) with opposite
    vertices c_1, c_2 (``opposite`` (M, 2); -1: no face, n = 0)."""
    pa = vertex_m[ends[:, 0]]
    span = vertex_m[ends[:, 1]] - pa
    n1 = np.cross(span, vertex_m[opposite[:, 0]] - pa)
    second = opposite[:, 1]
    n2 = np.where((second >= 0)[:, None], np.cross(span, vertex_m[np.maximum(second, 0)] - pa), 0.0)
    return n1, n2


def _morton3(grid: np.ndarray) -> np.ndarray:
    """Morton (Z-order) codes (int64, 30 bits) of integer points (N, 3) in 0..1023."""
    out = np.zeros(len(grid), np.int64)
    for axis in range(3):
        v = grid[:, axis].astype(np.int64) & 0x3FF
        v = (v | (v << 16)) & 0x30000FF
        v = (v | (v << 8)) & 0x300F00F
        v = (v | (v << 4)) & 0x30C30C3
        v = (v | (v << 2)) & 0x9249249
        out |= v << axis
    return out


@njit(cache=True, nogil=True, error_model='numpy')
def _face_bounds(face_vertices, vertex_m, face_region, region_lines, face_star, out):
    """Fills ``MeshEdges.face_bounds`` (out (F, 10) float32), face by face (the altitudes
    from ``face_star``)."""
    n_lines = region_lines.shape[1]
    dist = np.empty((n_lines, 3))
    reach = np.empty(n_lines)
    for f in range(face_vertices.shape[0]):
        # Alone: the edge facing vertex k lies h_k from it and 0 from the other two.
        for c in range(9):
            out[f, c] = 0.0
        for k in range(3):
            out[f, 4 * k] = face_star[f, k]
        out[f, 9] = np.inf
        g = face_region[f]
        if g < 0:
            continue
        for line in range(n_lines):
            for k in range(3):
                v = face_vertices[f, k]
                dist[line, k] = (region_lines[g, line, 0] * vertex_m[v, 0]
                                 + region_lines[g, line, 1] * vertex_m[v, 1]
                                 + region_lines[g, line, 2] * vertex_m[v, 2]
                                 - region_lines[g, line, 3])    # padded rows: inf
            reach[line] = min(dist[line, 0], dist[line, 1], dist[line, 2])
        order = np.argsort(reach, kind='mergesort')
        bound = reach[order[3]] if n_lines > 3 else np.inf
        # At the centre: the region's margin against the face's own (a third of the
        # smallest altitude).
        centre = bound
        for r in range(min(3, n_lines)):
            line = order[r]
            centre = min(centre, (dist[line, 0] + dist[line, 1] + dist[line, 2]) / 3.0)
        if not centre > min(face_star[f, 0], face_star[f, 1], face_star[f, 2]) / 3.0:
            continue
        for r in range(3):
            for k in range(3):
                out[f, 3 * r + k] = dist[order[r], k] if r < n_lines else np.inf
        out[f, 9] = bound


@njit(cache=True, nogil=True, error_model='numpy')
def _maybe_silhouette(planes, always, groups, group_size, edge, n_edges, centre, half,
                      edge_vertices, vertex_m, crossing_ends):
    """Edges not smooth for every viewpoint o in the box centre +- half: s_k(o) =
    n_k . o - n_k . a over the box is [mid - rad, mid + rad] with rad = |n_k| . half.
    planes (8, M), always (M,): the non-coplanar edges ``edge`` (M,)
    (``MeshEdges._sign_planes``); a run of ``group_size`` of them whose bounds (``groups``)
    keep both planes' signs fixed and opposite over the box is smooth as a whole (most of
    the mesh: no edge of it is tested). Returns a mask over all n_edges edges and the end
    points (K, 6) of the edges kept (``vertex_m`` rows of their ``edge_vertices``), in row
    order, followed by ``crossing_ends``."""
    m = planes.shape[1]
    # The per-edge loop runs in float32 (twice as wide); the group bounds in float64.
    cx, cy, cz = np.float32(centre[0]), np.float32(centre[1]), np.float32(centre[2])
    hx, hy, hz = np.float32(half[0]), np.float32(half[1]), np.float32(half[2])
    out = np.zeros(n_edges, np.bool_)
    kept_rows = np.empty(m, np.int64)
    kept = 0
    for g in range(groups.shape[0]):
        if groups[g, 16] == 0.0:
            lo1, hi1 = _plane_range(groups, g, 0, centre, half)
            lo2, hi2 = _plane_range(groups, g, 8, centre, half)
            if (lo1 > 0.0 and hi2 < 0.0) or (hi1 < 0.0 and lo2 > 0.0):
                continue
        for r in range(g * group_size, min((g + 1) * group_size, m)):
            mid1 = planes[0, r] * cx + planes[1, r] * cy + planes[2, r] * cz - planes[3, r]
            rad1 = abs(planes[0, r]) * hx + abs(planes[1, r]) * hy + abs(planes[2, r]) * hz
            mid2 = planes[4, r] * cx + planes[5, r] * cy + planes[6, r] * cz - planes[7, r]
            rad2 = abs(planes[4, r]) * hx + abs(planes[5, r]) * hy + abs(planes[6, r]) * hz
            smooth = ((((mid1 - rad1) > 0.0) & ((mid2 + rad2) < 0.0))
                      | (((mid1 + rad1) < 0.0) & ((mid2 - rad2) > 0.0)))
            if always[r] or not smooth:
                out[edge[r]] = True
                kept_rows[kept] = r
                kept += 1
    segments = np.empty((kept + crossing_ends.shape[0], 6))
    for row in range(kept):
        e = edge[kept_rows[row]]
        va, vb = edge_vertices[e, 0], edge_vertices[e, 1]
        for c in range(3):
            segments[row, c] = vertex_m[va, c]
            segments[row, 3 + c] = vertex_m[vb, c]
    segments[kept:] = crossing_ends
    return out, segments


@njit(cache=True, nogil=True, inline='always', error_model='numpy')
def _plane_range(groups, g, col, centre, half):
    """Least and greatest n . o - d over unit normals n and offsets d within the bounds of
    group g (columns col..col + 7 of ``MeshEdges._sign_groups``) and o in centre +- half."""
    lo, hi = -groups[g, col + 7], -groups[g, col + 6]
    for c in range(3):
        n_lo, n_hi = groups[g, col + c], groups[g, col + 3 + c]
        o_lo, o_hi = centre[c] - half[c], centre[c] + half[c]
        a, b, p, q = n_lo * o_lo, n_lo * o_hi, n_hi * o_lo, n_hi * o_hi
        lo += min(min(a, b), min(p, q))
        hi += max(max(a, b), max(p, q))
    return lo, hi


def _sin_cos_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 2) sin and cos of the angles between vectors u and v (N, 3); 0, 1 if either is 0."""
    norm = np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1)
    safe = np.where(norm > 0, norm, 1.0)
    sin = np.where(norm > 0, np.linalg.norm(np.cross(u, v), axis=1) / safe, 0.0)
    cos = np.where(norm > 0, np.einsum('ij,ij->i', u, v) / safe, 1.0)
    return np.column_stack([sin, cos])


_EDGES: 'weakref.WeakKeyDictionary[object, MeshEdges]' = weakref.WeakKeyDictionary()


def mesh_edges(target) -> MeshEdges:
    """The edge table of a ``geometry.Target`` (built once per target, ~0.1 s for 50k faces)."""
    edges = _EDGES.get(target)
    if edges is None:
        edges = build_mesh_edges(target.vertices_m, target.faces)
        edges = replace(edges, **dict(zip(('crossing_a_m', 'crossing_b_m'),
                                          intersection_segments(edges, target.intersect))))
        release_freed_memory()          # the build's temporaries (2 M faces: ~0.4 GB)
        _EDGES[target] = edges
    return edges


def intersection_segments(edges: MeshEdges, intersect, max_hits: int = 16,
                          step_m: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """Segments (C, 3), (C, 3) (m) where the mesh passes through itself.

    Parts that interpenetrate (a blanket dipping into the hull, a nozzle buried in a
    dome) meet along curves that are no mesh edge. Two triangles intersect along a
    segment whose ends are points where an edge of one pierces the other, so every mesh
    edge is cast as a ray from one end to the other through ``intersect`` (the target's
    Embree query: float32 rays -> face id, distance), continuing past each hit; a hit
    on a face sharing no vertex with the edge is a piercing point; the segments join the
    points on each face (a lone point: a segment of zero length). Edges are cast in
    blocks (bounded memory); the points are then taken in the order of a single pass.
    """
    found_edge, found_face, found_point, found_round = [], [], [], []
    for lo in range(0, len(edges), FACE_CHUNK):
        rows = np.arange(lo, min(lo + FACE_CHUNK, len(edges)))
        a = edges.vertex_m[edges.edge_vertices[rows, 0]]
        span = edges.vertex_m[edges.edge_vertices[rows, 1]] - a
        length = np.linalg.norm(span, axis=1)
        ok = length > 10 * step_m
        direction = np.divide(span, length[:, None], out=np.zeros_like(span), where=ok[:, None])
        todo = np.flatnonzero(ok)
        start = np.zeros(len(a))
        for hit_round in range(max_hits):
            if len(todo) == 0:
                break
            origin = a[todo] + start[todo, None] * direction[todo]
            face, t = intersect(origin.astype(np.float32), direction[todo].astype(np.float32))
            t_at = start[todo] + t
            hit = (face >= 0) & (t_at < length[todo] - step_m)
            todo, face, t_at = todo[hit], face[hit], t_at[hit]
            ends = edges.edge_vertices[rows[todo]]
            corners = edges.face_vertices[face]
            shares = (corners == ends[:, :1]).any(axis=1) | (corners == ends[:, 1:]).any(axis=1)
            found_edge.append(rows[todo[~shares]])
            found_face.append(face[~shares])
            found_point.append(a[todo[~shares]] + t_at[~shares, None] * direction[todo[~shares]])
            found_round.append(np.full(np.count_nonzero(~shares), hit_round))
            start[todo] = t_at + step_m
    if not found_edge or not sum(len(e) for e in found_edge):
        return np.zeros((0, 3)), np.zeros((0, 3))
    edge_id, pierced, point, hit_round = (np.concatenate(x) for x in
                                          (found_edge, found_face, found_point, found_round))
    # Round by round, edges in order: the order one pass over every edge finds them in.
    order = np.lexsort((edge_id, hit_round))
    edge_id, pierced, point = edge_id[order], pierced[order], point[order]
    # Every point lies on the pierced face and on both faces of the piercing edge. The
    # curve crosses each face between the points on it (a piercing point on a pierced
    # face's own edge is credited to one side only, so pair faces, not face pairs).
    own = edges.edge_faces[edge_id]
    face = np.concatenate([pierced, own[:, 0], own[:, 1]])
    point = np.concatenate([point, point, point])
    keys, first = np.unique(np.column_stack([face, np.round(point / step_m)]), axis=0,
                            return_index=True)
    face, point = keys[:, 0], point[first]
    seg_a, seg_b = [], []
    for f in np.unique(face):
        p = point[face == f]
        if len(p) == 1:
            seg_a.append(p[0])
            seg_b.append(p[0])
        for i in range(len(p)):
            for j in range(i + 1, len(p)):
                seg_a.append(p[i])
                seg_b.append(p[j])
    seg_a, seg_b = np.array(seg_a), np.array(seg_b)
    # The same piece lies on both faces it separates: keep one.
    ends = np.sort(np.stack([seg_a, seg_b], axis=1).reshape(len(seg_a), 6).reshape(-1, 2, 3), axis=1)
    _, unique = np.unique(np.round(ends.reshape(len(seg_a), 6) / step_m), axis=0, return_index=True)
    return seg_a[np.sort(unique)], seg_b[np.sort(unique)]


def build_mesh_edges(vertices_m: np.ndarray, faces: np.ndarray) -> MeshEdges:
    """Edge table of a triangle mesh; vertices within WELD_M are merged first.

    Per-face and per-edge temporaries are computed in blocks of FACE_CHUNK (a
    2-million-triangle mesh would otherwise hold several 150 MB arrays at once)."""
    vertices_m = np.asarray(vertices_m, float)
    faces = np.asarray(faces, np.int64)
    key = np.round(vertices_m / WELD_M).astype(np.int64)
    _, weld = np.unique(key, axis=0, return_inverse=True)
    del key
    weld = weld.reshape(-1).astype(np.int32)
    position = np.empty((weld.max() + 1 if len(weld) else 0, 3))
    position[weld] = vertices_m
    f = weld[faces]
    del weld
    n_faces = len(f)
    # Directed edges (a, b) = face vertices (k, k + 1), with the third vertex c.
    a = f[:, [0, 1, 2]].T.reshape(-1)
    b = f[:, [1, 2, 0]].T.reshape(-1)
    c = f[:, [2, 0, 1]].T.reshape(-1)
    face = np.tile(np.arange(n_faces, dtype=np.int32), 3)
    slot = np.repeat(np.arange(3, dtype=np.int32), n_faces)
    ok = (a != b) & (b != c) & (c != a)           # degenerate faces have no edges
    a, b, c, face, slot = a[ok], b[ok], c[ok], face[ok], slot[ok]
    undirected = np.minimum(a, b).astype(np.int64) * len(position) + np.maximum(a, b)
    order = np.argsort(undirected, kind='stable')
    undirected, a, b, c = undirected[order], a[order], b[order], c[order]
    face, slot = face[order], slot[order]
    del order
    new_edge = np.r_[True, undirected[1:] != undirected[:-1]]
    del undirected
    first = np.flatnonzero(new_edge)
    count = np.diff(np.r_[first, len(a)])
    pair = count == 2
    second = np.where(pair, first + 1, first)
    edge_vertices = np.column_stack([a[first], b[first]])
    edge_opposite = np.column_stack([c[first], np.where(pair, c[second], -1)]).astype(np.int32)
    edge_faces = np.column_stack([face[first], face[second]])
    del c
    edge_id = (np.cumsum(new_edge) - 1).astype(np.int32)
    del new_edge
    face_edge = np.full((n_faces, 3), -1, np.int32)
    face_edge[face, slot] = edge_id
    del edge_id
    neighbour = np.full((n_faces, 3), -1, np.int32)
    neighbour[face[first[pair]], slot[first[pair]]] = face[second[pair]]
    neighbour[face[second[pair]], slot[second[pair]]] = face[first[pair]]
    # Per face, packed for the compiled loops: the plane (n, n . p) and the in-plane inward
    # edge normals n x (v_{k+1} - v_k) (the face's own winding) with their offsets.
    planes = np.empty((n_faces, 4, 4))
    for part in _face_chunks(n_faces):
        _face_geometry(position[f[part]], planes[part])
    # Coplanar: the opposite vertices on opposite sides and both on the other face's plane.
    span = np.empty(len(first))
    cos_fold = np.empty(len(first))
    for lo in range(0, len(first), FACE_CHUNK):
        part = slice(lo, lo + FACE_CHUNK)
        ends = edge_vertices[part]
        span[part] = np.linalg.norm(position[ends[:, 1]] - position[ends[:, 0]], axis=1)
        n1, n2 = _edge_normals(position, ends, edge_opposite[part])
        len1, len2 = np.linalg.norm(n1, axis=1), np.linalg.norm(n2, axis=1)
        with np.errstate(invalid='ignore', divide='ignore'):
            cos_fold[part] = -np.einsum('ij,ij->i', n1, n2) / (len1 * len2)
    # Within 1e-5 rad: OBJ files round vertices (1e-6 m), which tilts thin flat quads.
    coplanar = pair & (cos_fold > np.cos(COPLANAR_RAD)) & (span > 0)
    region, lines = flat_regions(position, f, face_edge, coplanar, neighbour,
                                 planes[:, 1:4, :3], planes[:, 1:4, 3])
    fold = np.where(pair, np.arccos(np.clip(np.nan_to_num(cos_fold, nan=-1.0), -1.0, 1.0)), np.pi)
    del cos_fold
    tilt, reach = vertex_stars(position, f, a, b, face, slot, first, second, pair, fold)
    return MeshEdges(always=~pair, coplanar=coplanar, face_edge=face_edge,
                     face_neighbour=neighbour, face_planes=planes, face_region=region,
                     region_lines=lines, edge_vertices=edge_vertices,
                     edge_opposite=edge_opposite, edge_faces=edge_faces, face_vertices=f,
                     median_edge_m=float(np.median(span[~coplanar])) if np.any(~coplanar) else 0.0,
                     vertex_m=position, vertex_tilt_rad=tilt, vertex_reach_m=reach)


def _face_geometry(tri: np.ndarray, planes: np.ndarray) -> None:
    """For triangles tri (N, 3, 3) (m), writes planes (N, 4, 4) (``MeshEdges.face_planes``)."""
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    edge = np.roll(tri, -1, axis=1) - tri
    inward = np.cross(normal[:, None, :], edge)
    length = np.linalg.norm(inward, axis=2, keepdims=True)
    inward = np.divide(inward, length, out=np.zeros_like(inward), where=length > 0)
    offset = np.einsum('fkj,fkj->fk', inward, tri)
    offset[(length[..., 0] == 0).any(axis=1)] = np.inf       # degenerate: nothing is inside
    planes[:, 0, :3], planes[:, 0, 3] = normal, np.einsum('ij,ij->i', normal, tri[:, 0])
    planes[:, 1:4, :3], planes[:, 1:4, 3] = inward, offset


def _altitudes(tri: np.ndarray) -> np.ndarray:
    """Each vertex's distance to the opposite edge (N, 3) float32 (m) of triangles tri
    (N, 3, 3): twice the area over that edge's length (0 for a degenerate face)."""
    edge = np.roll(tri, -1, axis=1) - tri
    double_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    opposite = np.linalg.norm(np.roll(edge, -1, axis=1), axis=2)
    return np.divide(double_area[:, None], opposite, out=np.zeros_like(opposite),
                     where=opposite > 0).astype(np.float32)


def vertex_stars(position, faces, a, b, face, slot, first, second, pair, fold
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per welded vertex v, how far its star (the faces around it) bends and reaches.

    tilt (V,) rad: a bound on the angle between the normals of any two faces of the star,
    half the sum of the fold angles of the edges at v (going around a closed fan from one
    face to another crosses folds adding up to at most half of the total one way or the
    other); inf unless the star is one closed fan of non-degenerate faces (every edge at
    v has two faces and they join in a single cycle). reach (V,) m: the shortest distance
    from v to the far edge of a face of its star, so every surface path from v shorter
    than that stays inside the star.
    a, b, face, slot, first, second, pair: the directed edges of ``build_mesh_edges``
    (sorted by undirected edge; ``first``/``second`` the two faces of each pair); fold
    (E,): fold angle of each undirected edge (pi where not a pair).
    """
    n_vertices, n_faces = len(position), len(faces)
    tilt = np.zeros(n_vertices)
    np.add.at(tilt, a[first], fold)
    np.add.at(tilt, b[first], fold)
    tilt *= 0.5
    # Corners (face, slot of the vertex) of the same vertex joined across each paired edge.
    p1, p2 = first[pair], second[pair]

    def corner(k, vertex):
        return face[k] * 3 + np.where(a[k] == vertex, slot[k], (slot[k] + 1) % 3)

    src = np.concatenate([corner(p1, a[p1]), corner(p1, b[p1])])
    dst = np.concatenate([corner(p2, a[p1]), corner(p2, b[p1])])
    n_labels, label = connected_components(3 * n_faces, src, dst)
    del src, dst
    vertex = faces.reshape(-1).astype(np.int64)
    fans = np.bincount(np.unique(vertex * n_labels + label) // n_labels, minlength=n_vertices)
    tilt[fans != 1] = np.inf
    # Far edge of each corner: the point-to-segment distance from the corner's vertex.
    reach = np.full(n_vertices, np.inf)
    for part in _face_chunks(n_faces):     # bounded temporaries (~150 MB per array at 2M faces)
        tri = position[faces[part]]
        v = tri.reshape(-1, 3)
        p, q = np.roll(tri, -1, axis=1).reshape(-1, 3), np.roll(tri, -2, axis=1).reshape(-1, 3)
        span = q - p
        length2 = np.einsum('ij,ij->i', span, span)
        t = np.clip(np.einsum('ij,ij->i', v - p, span) / np.where(length2 > 0, length2, 1.0),
                    0.0, 1.0)
        dist = np.linalg.norm(p + t[:, None] * span - v, axis=1)
        corners = faces[part].reshape(-1)
        np.minimum.at(reach, corners, dist)
        degenerate = np.repeat(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                              axis=1) == 0, 3)
        tilt[corners[degenerate]] = np.inf
    return tilt, reach


def connected_components(n_nodes: int, src: np.ndarray, dst: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of the undirected graph on n_nodes nodes with edges src[i] -
    dst[i]: their number and each node's label (int32), labels numbered in the order of
    each component's first node (as ``scipy.sparse.csgraph.connected_components``), by
    union-find: one int32 per node where a sparse matrix of millions of edges costs
    hundreds of MB."""
    return _union_find(int(n_nodes), np.asarray(src, np.int64), np.asarray(dst, np.int64))


@njit(cache=True, nogil=True)
def _union_find(n, src, dst):
    parent = np.arange(n, dtype=np.int32)
    for e in range(src.shape[0]):
        a, b = _root(parent, src[e]), _root(parent, dst[e])
        if a < b:
            parent[b] = a
        elif b < a:
            parent[a] = b
    # Every root is its component's first node: number the components in that order.
    label = np.empty(n, np.int32)
    count = 0
    for i in range(n):
        r = _root(parent, i)
        if r == i:
            label[i] = count
            count += 1
        else:
            label[i] = label[r]
    return count, label


@njit(cache=True, nogil=True, inline='always')
def _root(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]       # path halving
        i = parent[i]
    return i


FACE_CHUNK = 131_072
"""Faces per block where a per-face temporary would otherwise span the whole mesh."""


def _face_chunks(n_faces: int):
    return (slice(lo, min(lo + FACE_CHUNK, n_faces)) for lo in range(0, n_faces, FACE_CHUNK))


def flat_regions(position, faces, face_edge, coplanar, neighbour, inward, offset
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Group faces into flat regions: faces joined across coplanar edges (the quads of a
    cylinder's column, a flat disc), kept when the region is convex and bounded by at most
    REGION_LINES lines (collinear edges are one line). A footprint that stays inside its
    region lies on one plane. Returns face -> region (F,) int32 and the regions' lines
    (R, REGION_LINES, 4); region -1: the face is in no such region of several faces, its
    own three edges bound it (``face_planes``: no second copy of them is kept).
    """
    n_faces = len(faces)
    i, k = np.nonzero(coplanar[np.maximum(face_edge, 0)] & (face_edge >= 0) & (neighbour >= 0))
    n_labels, label = connected_components(n_faces, i, neighbour[i, k])
    del i, k
    # Regions of several faces only (group: their number), the faces in them (member).
    size = np.bincount(label, minlength=n_labels)
    several = np.flatnonzero(size > 1)
    group = np.full(n_labels, -1, np.int64)
    group[several] = np.arange(len(several))
    member = np.flatnonzero(size[label] > 1)
    face_group = group[label[member]]
    # Boundary edges of each region: face edges whose neighbour is in another region;
    # one line per distinct (region, direction, offset), so collinear edges merge.
    nb = neighbour[member]
    fi, ki = np.nonzero((nb < 0) | (label[np.maximum(nb, 0)] != label[member][:, None]))
    del nb
    m, c, lab = inward[member[fi], ki], offset[member[fi], ki], face_group[fi]
    key = np.column_stack([lab, np.round(m / 1e-9), np.round(c / 1e-9)])
    _, first = np.unique(key, axis=0, return_index=True)
    first = first[np.argsort(lab[first], kind='stable')]
    m, c, lab = m[first], c[first], lab[first]
    n_groups = len(several)
    count = np.bincount(lab, minlength=n_groups)
    start = np.r_[0, np.cumsum(count)]
    good = (count >= 3) & (count <= REGION_LINES)
    # Padded per-region lines; convex when every corner of its faces is on the inner side.
    lines = np.zeros((n_groups, REGION_LINES, 4))
    lines[:, :, 3] = -np.inf
    slot = np.arange(len(lab)) - start[lab]
    keep = good[lab]
    lines[lab[keep], slot[keep], :3], lines[lab[keep], slot[keep], 3] = m[keep], c[keep]
    worst = np.full(n_groups, np.inf)
    for part in _face_chunks(len(member)):     # (F, L, 4) at once cost ~1 GB per million faces
        own = lines[face_group[part]]                           # (n, L, 4)
        corner_margin = (np.einsum('flj,fvj->fvl', own[:, :, :3], position[faces[member[part]]])
                         - own[:, None, :, 3])
        np.minimum.at(worst, face_group[part], corner_margin.min(axis=(1, 2)))
    good &= worst > -1e-7
    kept = np.flatnonzero(good)
    renumber = np.full(n_groups, -1, np.int32)
    renumber[kept] = np.arange(len(kept))
    region = np.full(n_faces, -1, np.int32)
    region[member] = renumber[face_group]
    return region, lines[kept]


def origin_box(origins_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (3,) of the bounding box of points (N, 3)."""
    return _box(np.ascontiguousarray(origins_m))


@njit(cache=True, nogil=True, error_model='numpy')
def _box(p):
    x0, y0, z0 = np.inf, np.inf, np.inf
    x1, y1, z1 = -np.inf, -np.inf, -np.inf
    for i in range(p.shape[0]):
        x, y, z = np.float64(p[i, 0]), np.float64(p[i, 1]), np.float64(p[i, 2])
        x0, y0, z0 = min(x0, x), min(y0, y), min(z0, z)
        x1, y1, z1 = max(x1, x), max(y1, y), max(z1, z)
    return np.array([x0, y0, z0]), np.array([x1, y1, z1])


def cones_touching_edges(origins_m: np.ndarray, directions: np.ndarray, tan_half_angle: float,
                         a_m: np.ndarray, b_m: np.ndarray,
                         depth_limit_m: np.ndarray | None = None) -> np.ndarray:
    """For each ray, whether any segment [a_m, b_m] enters its cone (exact test).

    origins_m, directions (N, 3): rays (unit directions); tan_half_angle: tan of the
    cone's half-angle; a_m, b_m (M, 3): segments in the same frame (m);
    depth_limit_m (N,): count only the parts of segments up to this depth along each
    ray (m; inf: all; < 0: skip the ray). Returns a bool mask (N,).
    """
    n = len(origins_m)
    if depth_limit_m is None:
        depth_limit_m = np.full(n, np.inf)
    if n == 0 or len(a_m) == 0:
        return np.zeros(n, bool)
    # End points may be row views of one (M, 6) array (``MeshEdges.candidate_segments``).
    return _cones_touching_edges(np.ascontiguousarray(origins_m), np.ascontiguousarray(directions),
                                 float(tan_half_angle), _float64_rows(a_m), _float64_rows(b_m),
                                 np.ascontiguousarray(depth_limit_m, dtype=np.float64))


def _float64_rows(points: np.ndarray) -> np.ndarray:
    """(M, 3) float64 points, as given when their rows are already contiguous."""
    points = np.asarray(points, dtype=np.float64)
    return points if points.strides[1] == 8 else np.ascontiguousarray(points)


_Z_MIN_M = 1e-3     # segment parts closer than this in front of the viewpoint are ignored
COARSE_CELLS = 64   # cells across the rays' image in the cone test's first screen


@njit(cache=True, nogil=True, error_model='numpy')
def _segment_in_cone(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, z_hi, tan_a):
    """Whether the segment a-b meets the cone (apex o, unit axis d, tan half-angle tan_a)
    at depths in [_Z_MIN_M, z_hi] along d: the segment's central projection on the plane
    at unit depth must pass within tan_a of the axis."""
    ax -= ox
    ay -= oy
    az -= oz
    bx -= ox
    by -= oy
    bz -= oz
    za = ax * dx + ay * dy + az * dz
    zb = bx * dx + by * dy + bz * dz
    if (za < _Z_MIN_M and zb < _Z_MIN_M) or (za > z_hi and zb > z_hi):
        return False
    # Clip the segment a + t (b - a), t in [0, 1], to the depth slab.
    t0, t1 = 0.0, 1.0
    if za != zb:
        ta, tb = (_Z_MIN_M - za) / (zb - za), (z_hi - za) / (zb - za)
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        if t0 > t1:
            return False
    px, py, pz = ax + t0 * (bx - ax), ay + t0 * (by - ay), az + t0 * (bz - az)
    qx, qy, qz = ax + t1 * (bx - ax), ay + t1 * (by - ay), az + t1 * (bz - az)
    zp = max(px * dx + py * dy + pz * dz, _Z_MIN_M)
    zq = max(qx * dx + qy * dy + qz * dz, _Z_MIN_M)
    # Points on the unit-depth plane, relative to the axis (vectors perpendicular to d).
    px, py, pz = px / zp - dx, py / zp - dy, pz / zp - dz
    qx, qy, qz = qx / zq - dx, qy / zq - dy, qz / zq - dz
    ex, ey, ez = qx - px, qy - py, qz - pz
    ee = ex * ex + ey * ey + ez * ez
    s = 0.0
    if ee > 0.0:
        s = min(max(-(px * ex + py * ey + pz * ez) / ee, 0.0), 1.0)
    cx, cy, cz = px + s * ex, py + s * ey, pz + s * ez
    # A relative margin for float32 rays: never decides a physical case.
    r = tan_a * (1.0 + 1e-4) + 1e-7
    return cx * cx + cy * cy + cz * cz <= r * r


@njit(cache=True, nogil=True, error_model='numpy', fastmath=FAST_ALGEBRA)
def _rays_near_segments(binned_rays, count, track, ray_z, seg, seg_z, binned, gx0, gy0, gx1, gy1,
                        pad):
    """Keeps (in place, in order) the binned rays that some segment may reach: one whose
    projection, grown by the pad, overlaps the ray's track on a coarse grid and that lies
    no deeper than the ray's cone counts to. Returns how many are kept."""
    inv = COARSE_CELLS / max(gx1 - gx0, gy1 - gy0, 1e-12)
    mx = int((gx1 - gx0) * inv) + 1
    my = int((gy1 - gy0) * inv) + 1
    nearest = np.full(mx * my, np.inf)      # per coarse cell: the nearest segment's depth
    for k in range(seg.shape[0]):
        if not binned[k]:
            continue
        x0, x1 = min(seg[k, 0], seg[k, 2]) - pad, max(seg[k, 0], seg[k, 2]) + pad
        y0, y1 = min(seg[k, 1], seg[k, 3]) - pad, max(seg[k, 1], seg[k, 3]) + pad
        if x1 < gx0 or x0 > gx1 or y1 < gy0 or y0 > gy1:
            continue
        i0, i1 = max(int((x0 - gx0) * inv), 0), min(int((x1 - gx0) * inv), mx - 1)
        j0, j1 = max(int((y0 - gy0) * inv), 0), min(int((y1 - gy0) * inv), my - 1)
        for ci in range(i0, i1 + 1):
            for cj in range(j0, j1 + 1):
                nearest[ci * my + cj] = min(nearest[ci * my + cj], seg_z[k])
    kept = 0
    for q in range(count):
        i = binned_rays[q]
        i0, i1 = int((track[i, 0] - gx0) * inv), min(int((track[i, 2] - gx0) * inv), mx - 1)
        j0, j1 = int((track[i, 1] - gy0) * inv), min(int((track[i, 3] - gy0) * inv), my - 1)
        near = np.inf
        for ci in range(i0, i1 + 1):
            for cj in range(j0, j1 + 1):
                near = min(near, nearest[ci * my + cj])
        if near <= ray_z[i] * (1.0 + 1e-6) + 1e-6:
            binned_rays[kept] = i
            kept += 1
    return kept


# Reassociation and FMA only (no finite-math flags: inf limits, -inf cell depths).
@njit(cache=True, nogil=True, error_model='numpy', fastmath=FAST_ALGEBRA)
def _cones_touching_edges(o, d, tan_a, a, b, z_limit):
    """Rays binned on a gnomonic grid seen from the centre c of their origins' box, about
    their mean direction f (each ray over the depth range of the segments, as it moves
    across the grid with its offset from c); each segment then tests the rays in the
    cells its dilated projection covers."""
    n, m = o.shape[0], a.shape[0]
    out = np.zeros(n, np.bool_)
    lo, hi = _box(o)
    cx, cy, cz = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])
    # Every origin lies within the box's half-diagonal of c.
    spread = 0.5 * np.sqrt((hi[0] - lo[0]) ** 2 + (hi[1] - lo[1]) ** 2 + (hi[2] - lo[2]) ** 2)
    fx, fy, fz = 0.0, 0.0, 0.0
    for i in range(0, n, 8):                  # a sample is enough for a central direction
        fx += d[i, 0]
        fy += d[i, 1]
        fz += d[i, 2]
    norm = np.sqrt(fx * fx + fy * fy + fz * fz)
    if norm == 0.0:
        fx, fy, fz = 1.0, 0.0, 0.0
    else:
        fx, fy, fz = fx / norm, fy / norm, fz / norm
    hx, hy, hz = (0.0, 0.0, 1.0) if abs(fz) < 0.9 else (1.0, 0.0, 0.0)
    e1x, e1y, e1z = fy * hz - fz * hy, fz * hx - fx * hz, fx * hy - fy * hx
    norm = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / norm, e1y / norm, e1z / norm
    e2x, e2y, e2z = fy * e1z - fz * e1y, fz * e1x - fx * e1z, fx * e1y - fy * e1x
    # Segments closer to c than z_floor are tested against every ray (never, in practice).
    z_floor = max(10.0 * spread, 1e-2)
    seg = np.empty((m, 4))
    seg_z = np.empty(m)                  # nearest depth along f
    binned = np.zeros(m, np.bool_)
    z_lo, z_hi = np.inf, -np.inf
    for k in range(m):
        ax, ay, az = a[k, 0] - cx, a[k, 1] - cy, a[k, 2] - cz
        bx, by, bz = b[k, 0] - cx, b[k, 1] - cy, b[k, 2] - cz
        za = ax * fx + ay * fy + az * fz
        zb = bx * fx + by * fy + bz * fz
        if za < z_floor or zb < z_floor:
            continue
        binned[k] = True
        seg_z[k] = min(za, zb)
        seg[k, 0] = (ax * e1x + ay * e1y + az * e1z) / za
        seg[k, 1] = (ax * e2x + ay * e2y + az * e2z) / za
        seg[k, 2] = (bx * e1x + by * e1y + bz * e1z) / zb
        seg[k, 3] = (bx * e2x + by * e2y + bz * e2z) / zb
        z_lo, z_hi = min(z_lo, za, zb), max(z_hi, za, zb)
    # Rays: their projected track over [z_lo, min(z_hi, limit)], undilated.
    track = np.empty((n, 4))
    ray_z = np.empty(n)                  # farthest depth along f the cone counts to
    brute = z_limit >= 0.0               # tested against every segment (unless binned)
    widest = 0.0                         # max over binned rays of stretch (1 + 1/zd) / zd
    binned_rays = np.empty(n, np.int64)  # the rays binned, in order
    # The grid over the binned rays' tracks (their box and mean size, gathered on the way).
    gx0, gy0, gx1, gy1 = np.inf, np.inf, -np.inf, -np.inf
    size, count = 0.0, 0
    if z_hi >= z_lo:
        inv_lo = 1.0 / z_lo
        for i in range(n):
            if z_limit[i] < 0.0:
                continue
            dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
            rx, ry, rz = o[i, 0] - cx, o[i, 1] - cy, o[i, 2] - cz
            zo = rx * fx + ry * fy + rz * fz
            zd = dx * fx + dy * fy + dz * fz
            if zd <= 0.1:
                continue                      # more than 84 deg off the mean: brute force
            # The cone up to the depth limit reaches at most this far along f.
            z_end = min(z_hi, zo + z_limit[i] * (zd + tan_a))
            ray_z[i] = z_end
            brute[i] = False
            if z_end < z_lo:
                continue                      # stops in front of every binned segment
            inv_zd = 1.0 / zd
            # Seen from c, the ray's point at depth z along f is u + w / z: u the direction's
            # point, w = (o - c)_perp - zo u (z_lo >= z_floor lies past the origin's zo).
            ux = (dx * e1x + dy * e1y + dz * e1z) * inv_zd
            uy = (dx * e2x + dy * e2y + dz * e2z) * inv_zd
            wx = rx * e1x + ry * e1y + rz * e1z - zo * ux
            wy = rx * e2x + ry * e2y + rz * e2z - zo * uy
            u0, v0 = ux + wx * inv_lo, uy + wy * inv_lo
            inv_end = 1.0 / z_end
            u1, v1 = ux + wx * inv_end, uy + wy * inv_end
            x0, x1 = min(u0, u1), max(u0, u1)
            y0, y1 = min(v0, v1), max(v0, v1)
            track[i, 0], track[i, 1], track[i, 2], track[i, 3] = x0, y0, x1, y1
            binned_rays[count] = i
            count += 1
            gx0, gy0, gx1, gy1 = min(gx0, x0), min(gy0, y0), max(gx1, x1), max(gy1, y1)
            size += max(x1 - x0, y1 - y0)
            stretch = 1.0 + max(x0 * x0, x1 * x1) + max(y0 * y0, y1 * y1)
            widest = max(widest, stretch * (1.0 + inv_zd) * inv_zd)
    # A point of the cone lies within t tan_a of the axis point at its own distance t, and
    # within (1 + 1/zd) t tan_a of the axis point at its depth along f; seen from c (at
    # least z_lo - spread away) and stretched by the gnomonic map.
    pad = 0.0
    if widest > 0.0:
        pad = 1.25 * tan_a * widest * (1.0 + 2.0 * spread / z_lo)
    pad += 1e-9
    if count > 0:
        count = _rays_near_segments(binned_rays, count, track, ray_z, seg, seg_z, binned,
                                    gx0, gy0, gx1, gy1, pad)
    # Cells a few times a track plus the pad (the 2-D pre-check makes rays cheap; cell
    # visits are what costs).
    if count > 0:
        size = 2.5 * max(size / count, pad, (gx1 - gx0) / 2048.0, (gy1 - gy0) / 2048.0, 1e-9)
        inv_size = 1.0 / size
        nx = int((gx1 - gx0) * inv_size) + 1
        ny = int((gy1 - gy0) * inv_size) + 1
        start = np.zeros(nx * ny + 1, np.int64)
        cells = np.empty((count, 4), np.int32)     # each binned ray's cell ranges
        for q in range(count):
            i = binned_rays[q]
            i0, i1 = int((track[i, 0] - gx0) * inv_size), int((track[i, 2] - gx0) * inv_size)
            j0, j1 = int((track[i, 1] - gy0) * inv_size), int((track[i, 3] - gy0) * inv_size)
            cells[q, 0], cells[q, 1], cells[q, 2], cells[q, 3] = i0, i1, j0, j1
            for ci in range(i0, i1 + 1):
                for cj in range(j0, j1 + 1):
                    start[ci * ny + cj + 1] += 1
        for cell in range(nx * ny):
            start[cell + 1] += start[cell]
        fill = start[:-1].copy()
        cell_ray = np.empty(start[-1], np.int32)
        # Per entry, the ray's track centre, half-diagonal (+ float32 rounding) and depth
        # reach (rounded up): read in order, half the bytes of float64.
        cell_track = np.empty((start[-1], 4), np.float32)
        cell_z = np.full(nx * ny, -np.inf)   # farthest depth any ray of the cell counts to
        for q in range(count):
            i = binned_rays[q]
            mid_x, mid_y = 0.5 * (track[i, 0] + track[i, 2]), 0.5 * (track[i, 1] + track[i, 3])
            half_diagonal = (0.5 * (track[i, 2] - track[i, 0] + track[i, 3] - track[i, 1])
                             + 1e-6 * (1.0 + abs(mid_x) + abs(mid_y)))
            reach_z = ray_z[i] * (1.0 + 1e-6) + 1e-6
            for ci in range(cells[q, 0], cells[q, 1] + 1):
                for cj in range(cells[q, 2], cells[q, 3] + 1):
                    entry = fill[ci * ny + cj]
                    cell_ray[entry] = i
                    cell_track[entry, 0], cell_track[entry, 1] = mid_x, mid_y
                    cell_track[entry, 2], cell_track[entry, 3] = half_diagonal, reach_z
                    fill[ci * ny + cj] += 1
                    cell_z[ci * ny + cj] = max(cell_z[ci * ny + cj], ray_z[i])
        # Each segment visits the cells within pad of its projection, each cell once: the
        # cells of its grown box when that is small, else those near points sampled every
        # half cell (each point grown by pad + half a cell).
        stamp = np.full(nx * ny, -1, np.int64)
        reach = pad + 0.5 * size
        for k in range(m):
            if not binned[k]:
                continue
            x0, y0, x1, y1 = seg[k, 0], seg[k, 1], seg[k, 2], seg[k, 3]
            if (max(x0, x1) + reach < gx0 or min(x0, x1) - reach > gx1
                    or max(y0, y1) + reach < gy0 or min(y0, y1) - reach > gy1):
                continue
            ex, ey = x1 - x0, y1 - y0
            inv_len2 = 1.0 / (ex * ex + ey * ey) if ex * ex + ey * ey > 0.0 else 0.0
            i0 = min(max(int((min(x0, x1) - pad - gx0) / size), 0), nx - 1)
            i1 = min(max(int((max(x0, x1) + pad - gx0) / size), 0), nx - 1)
            j0 = min(max(int((min(y0, y1) - pad - gy0) / size), 0), ny - 1)
            j1 = min(max(int((max(y0, y1) + pad - gy0) / size), 0), ny - 1)
            # One box of cells when the grown box is small, else a box around every
            # sampled point (the stamp keeps each cell to one visit per segment).
            small = (i1 - i0 + 1) * (j1 - j0 + 1) <= 9
            steps = 0 if small else int(np.sqrt(ex * ex + ey * ey) / (0.5 * size)) + 1
            for step in range(steps + 1):
                if not small:
                    x = x0 + (x1 - x0) * step / steps
                    y = y0 + (y1 - y0) * step / steps
                    i0 = min(max(int((x - reach - gx0) / size), 0), nx - 1)
                    i1 = min(max(int((x + reach - gx0) / size), 0), nx - 1)
                    j0 = min(max(int((y - reach - gy0) / size), 0), ny - 1)
                    j1 = min(max(int((y + reach - gy0) / size), 0), ny - 1)
                for ci in range(i0, i1 + 1):
                    for cj in range(j0, j1 + 1):
                        cell = ci * ny + cj
                        if stamp[cell] == k:
                            continue
                        stamp[cell] = k
                        if seg_z[k] > cell_z[cell]:
                            continue             # behind every lit surface of the cell
                        for p in range(start[cell], start[cell + 1]):
                            if seg_z[k] > cell_track[p, 3]:
                                continue
                            i = cell_ray[p]
                            if out[i]:
                                continue
                            # The gnomonic projections first: the track's centre within
                            # pad + its half-diagonal of the segment's projection.
                            tx, ty = cell_track[p, 0] - x0, cell_track[p, 1] - y0
                            h = min(max((tx * ex + ty * ey) * inv_len2, 0.0), 1.0)
                            gx, gy = tx - h * ex, ty - h * ey
                            slack = pad + cell_track[p, 2]
                            if gx * gx + gy * gy > slack * slack:
                                continue
                            if _segment_in_cone(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1],
                                                d[i, 2], a[k, 0], a[k, 1], a[k, 2], b[k, 0],
                                                b[k, 1], b[k, 2], z_limit[i], tan_a):
                                out[i] = True
    # Rays not binned (far off the mean direction) against every segment, and segments
    # too near c against every ray: never, in practice.
    loose = np.flatnonzero(~binned)
    for i in range(n):
        if out[i] or z_limit[i] < 0.0 or not (brute[i] or loose.shape[0] > 0):
            continue
        for q in range(m if brute[i] else loose.shape[0]):
            k = q if brute[i] else loose[q]
            if _segment_in_cone(o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                a[k, 0], a[k, 1], a[k, 2], b[k, 0], b[k, 1], b[k, 2],
                                z_limit[i], tan_a):
                out[i] = True
                break
    return out
