"""The edge table of core/silhouette.py: its compact storage against direct constructions.

(The silhouette test and the footprint kernels that read the table are checked in
test_beam_divergence.py.)
"""
from __future__ import annotations

from collections import deque

import numpy as np
import pytest
import trimesh

from lidar_sim_ros.core import silhouette
from lidar_sim_ros.core.silhouette import build_mesh_edges, connected_components, intersection_segments


def bfs_labels(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Component labels by breadth-first search, numbered in the order of first nodes."""
    adjacent = [[] for _ in range(n)]
    for s, d in zip(src, dst):
        adjacent[s].append(d)
        adjacent[d].append(s)
    label = np.full(n, -1)
    count = 0
    for start in range(n):
        if label[start] >= 0:
            continue
        label[start] = count
        todo = deque([start])
        while todo:
            for nxt in adjacent[todo.popleft()]:
                if label[nxt] < 0:
                    label[nxt] = count
                    todo.append(nxt)
        count += 1
    return label


@pytest.mark.parametrize('n, m', [(1, 0), (12, 5), (300, 200), (300, 600)])
def test_connected_components_match_a_breadth_first_search(n, m):
    rng = np.random.default_rng(n + m)
    src, dst = rng.integers(0, n, m), rng.integers(0, n, m)
    count, label = connected_components(n, src, dst)
    expected = bfs_labels(n, src, dst)
    assert count == expected.max() + 1
    np.testing.assert_array_equal(label, expected)


def _mesh_with_a_flipped_face():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    faces = mesh.faces.copy()
    faces[3] = faces[3, ::-1]
    return np.asarray(mesh.vertices), faces


def test_edge_geometry_equals_a_face_by_face_construction():
    vertices, faces = _mesh_with_a_flipped_face()
    edges = build_mesh_edges(vertices, faces)
    # Every undirected edge once, with the faces that hold it: a -> b as the first face
    # winds, n_k = (b - a) x (c_k - a) for the third vertex c_k of face k; faces taken slot
    # by slot (edge k of every face, then k + 1). (The table numbers the welded vertices
    # its own way: edges are keyed by their end points.)
    found = {}
    for f, tri in enumerate(faces):
        for k in range(3):
            a, b, c = tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]
            key = frozenset((tuple(vertices[a]), tuple(vertices[b])))
            found.setdefault(key, []).append((k, f, a, b, c))
    assert len(edges) == len(found)
    for e in range(len(edges)):
        key = frozenset(tuple(edges.vertex_m[v]) for v in edges.edge_vertices[e])
        (_, f1, a, b, c1), (_, f2, _, _, c2) = sorted(found[key])
        np.testing.assert_array_equal(edges.a_m[e], vertices[a])
        np.testing.assert_array_equal(edges.b_m[e], vertices[b])
        np.testing.assert_allclose(edges.n1[e], np.cross(vertices[b] - vertices[a], vertices[c1] - vertices[a]),
                                   rtol=0, atol=1e-15)
        np.testing.assert_allclose(edges.n2[e], np.cross(vertices[b] - vertices[a], vertices[c2] - vertices[a]),
                                   rtol=0, atol=1e-15)
        assert set(edges.edge_faces[e]) == {f1, f2}
        k1 = list(edges.face_edge[f1]).index(e)
        assert edges.face_neighbour[f1, k1] == f2
    assert edges.face_edge.dtype == edges.face_neighbour.dtype == edges.edge_vertices.dtype == np.int32


def test_a_boundary_edge_has_no_second_normal():
    edges = build_mesh_edges(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    assert edges.always.all()
    np.testing.assert_array_equal(edges.n2, 0.0)
    np.testing.assert_array_equal(np.abs(edges.n1[:, 2]), 1.0)


def test_lone_faces_have_no_region_and_flat_regions_keep_their_outline():
    # A unit square of two triangles (one flat region, four lines) and a triangle folded up
    # along its far edge (a face of its own: bounded by its own edges, no region).
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 1.5, 0.5]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4]])
    edges = build_mesh_edges(vertices, faces)
    assert edges.face_region[0] == edges.face_region[1] >= 0
    assert edges.face_region[2] == -1
    lines = edges.region_lines[edges.face_region[0]]
    used = lines[np.isfinite(lines[:, 3])]
    assert len(used) == 4
    # The centre is 0.5 m inside each line; a corner lies on two of them.
    np.testing.assert_allclose(used[:, :3] @ [0.5, 0.5, 0.0] - used[:, 3], 0.5)
    np.testing.assert_allclose(np.sort(used[:, :3] @ [1.0, 1.0, 0.0] - used[:, 3]), [0, 0, 1, 1],
                               atol=1e-12)


def _polygon_fan(sides: int, rings: int = 1):
    """A flat regular polygon (radius 1 m) split into a fan of triangles about its centre,
    each spoke cut into ``rings`` segments: one flat region with ``sides`` lines."""
    angles = 2.0 * np.pi * np.arange(sides) / sides
    rim = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(sides)])
    vertices, faces = [np.zeros(3)], []
    for r in range(1, rings + 1):
        vertices += list(rim * r / rings)
    for k in range(sides):
        k1 = (k + 1) % sides
        faces.append([0, 1 + k, 1 + k1])
        for r in range(1, rings):
            a, b = 1 + (r - 1) * sides + k, 1 + (r - 1) * sides + k1
            c, d = 1 + r * sides + k, 1 + r * sides + k1
            faces += [[a, c, d], [a, d, b]]
    return np.array(vertices), np.array(faces)


def _rocket_edges():
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.geometry import load_target
    from conftest import CONFIG
    scenario = load_scenario(CONFIG / 'scenario.yaml')
    target = load_target(scenario.mesh_path, scenario.materials.names)
    return build_mesh_edges(target.vertices_m, target.faces)


@pytest.mark.parametrize('mesh', ['square', 'hexagon', 'hexagon_rings', 'octagon_rings',
                                  'rocket'])
def test_face_bounds_never_exceed_the_distance_to_the_region_outline(mesh):
    # The facets' pass takes a footprint as flat when min(w . row, bound) >= its spread:
    # that must never exceed the distance to the flat region's outline, and never fall
    # below the distance to the facet's own edges. A square's two triangles touch all
    # four of its lines; the octagon's inner faces see eight at different distances.
    if mesh == 'rocket':
        edges = _rocket_edges()
    else:
        vertices, faces = {'square': (np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]),
                                      np.array([[0, 1, 2], [0, 2, 3]])),
                           'hexagon': _polygon_fan(6), 'hexagon_rings': _polygon_fan(6, 3),
                           'octagon_rings': _polygon_fan(8, 4)}[mesh]
        vertices = vertices @ np.array([[0.6, 0.8, 0.0], [-0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
        edges = build_mesh_edges(vertices + [3.0, -1.0, 2.0], faces)
        assert (edges.face_region >= 0).all()
    region = np.flatnonzero(edges.face_region >= 0)
    bounds = edges.face_bounds[region]
    rng = np.random.default_rng(3)
    w = rng.dirichlet([1.0, 1.0, 1.0], size=(len(region), 400 if mesh != 'rocket' else 20))
    corner = edges.vertex_m[edges.face_vertices[region]]                     # (F, 3, 3)
    point = np.einsum('fsk,fkj->fsj', w, corner)
    rows = bounds[:, :9].reshape(-1, 3, 3).astype(float)                     # (F, line, vertex)
    inside = np.minimum(np.einsum('fsk,flk->fsl', w, rows).min(axis=2), bounds[:, None, 9])
    lines = edges.region_lines[edges.face_region[region]]                    # (F, L, 4)
    used = np.isfinite(lines[:, :, 3])
    to_outline = np.where(used[:, None, :], np.einsum('flj,fsj->fsl', lines[:, :, :3], point)
                          - lines[:, None, :, 3], np.inf).min(axis=2)
    assert np.all(inside <= to_outline + 1e-6)
    star = edges.face_star[region, :3].astype(float)
    own = (w * star[:, None, :]).min(axis=2)
    assert np.all(inside >= own - 1e-6)
    # Away from the rim, the region's answer is the larger one.
    if mesh != 'square':
        assert np.mean(inside > own + 1e-3) > 0.1


def _interpenetrating_boxes():
    a = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    b = trimesh.creation.box(extents=(0.6, 0.6, 1.6))
    b.apply_translation([0.31, 0.17, 0.05])
    b = b.subdivide()
    vertices = np.vstack([a.vertices, b.vertices])
    faces = np.vstack([a.faces, b.faces + len(a.vertices)])
    return vertices, faces


def _tables(edges):
    return {k: v for k, v in edges.__dict__.items() if isinstance(v, np.ndarray)}


def test_tables_built_in_blocks_equal_one_block(monkeypatch):
    vertices, faces = _interpenetrating_boxes()
    whole = build_mesh_edges(vertices, faces)
    cached = ('face_star', 'face_crease', 'face_bounds', '_sign_planes', '_sign_edge', '_sign_groups')
    one = _tables(whole) | {k: getattr(whole, k) for k in cached}
    monkeypatch.setattr(silhouette, 'FACE_CHUNK', 7)
    blocks = build_mesh_edges(vertices, faces)
    many = _tables(blocks) | {k: getattr(blocks, k) for k in cached}
    assert one.keys() == many.keys()
    for key in one:
        np.testing.assert_equal(one[key], many[key], err_msg=key)


def test_intersection_segments_do_not_depend_on_the_block_size(monkeypatch):
    from lidar_sim_ros.core.geometry import Target
    vertices, faces = _interpenetrating_boxes()
    target = Target(vertices, faces, np.zeros(len(faces), np.int16), ['x'])
    edges = build_mesh_edges(vertices, faces)
    whole = intersection_segments(edges, target.intersect)
    assert len(whole[0]) > 4                  # the two boxes cross along a closed curve
    monkeypatch.setattr(silhouette, 'FACE_CHUNK', 5)
    blocks = intersection_segments(edges, target.intersect)
    for a, b in zip(whole, blocks):
        np.testing.assert_array_equal(a, b)


def test_candidate_segments_come_with_the_mask():
    # The footprint reads the candidate mask and the segments of the same pass: the edges
    # kept (non-coplanar, end points a then b; grouped as the classification visits them,
    # which the cone test does not depend on) and then every crossing, in order.
    from lidar_sim_ros.core.geometry import Target
    vertices, faces = _interpenetrating_boxes()
    target = Target(vertices, faces, np.zeros(len(faces), np.int16), ['x'])
    edges = silhouette.mesh_edges(target)
    assert len(edges.crossing_a_m) > 4
    for lo, hi in (([5.0, 0.3, 0.2], [5.0, 0.3, 0.2]), ([-4.0, 3.0, 1.0], [-3.5, 3.2, 1.1])):
        mask, a_m, b_m = edges.candidates_with_segments(np.array(lo), np.array(hi))
        np.testing.assert_array_equal(mask, edges.candidate_mask(np.array(lo), np.array(hi)))
        kept = [e for e in range(len(edges)) if mask[e] and not edges.coplanar[e]]
        assert 0 < len(kept) < len(edges)
        want_a = [edges.vertex_m[edges.edge_vertices[e, 0]] for e in kept] + list(edges.crossing_a_m)
        want_b = [edges.vertex_m[edges.edge_vertices[e, 1]] for e in kept] + list(edges.crossing_b_m)
        n = len(kept)
        got = np.hstack([a_m, b_m])
        want = np.hstack([np.array(want_a), np.array(want_b)])
        np.testing.assert_array_equal(got[n:], want[n:])
        np.testing.assert_array_equal(np.unique(got[:n], axis=0), np.unique(want[:n], axis=0))
        assert len(got) == len(want)


def _exact_candidates(edges, lo, hi):
    """Non-coplanar edges not smooth for some viewpoint in the box [lo, hi], in float64 from
    the welded vertices (the classification's definition, without its float32 margin)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    n1, n2 = edges.edge_normals(slice(None))
    a = edges.vertex_m[edges.edge_vertices[:, 0]]
    mid1, rad1 = n1 @ centre - np.einsum('ij,ij->i', n1, a), np.abs(n1) @ half
    mid2, rad2 = n2 @ centre - np.einsum('ij,ij->i', n2, a), np.abs(n2) @ half
    smooth = (((mid1 - rad1) > 0) & ((mid2 + rad2) < 0)) | (((mid1 + rad1) < 0) & ((mid2 - rad2) > 0))
    return ~edges.coplanar & (edges.always | ~smooth)


@pytest.mark.parametrize('group', [1, 5, 16])
def test_grouped_classification_keeps_every_possible_silhouette(monkeypatch, group):
    # Runs of edges whose bounds keep both planes' signs fixed are skipped as a whole: the
    # mask must still hold every edge that is a silhouette for some viewpoint of the box,
    # and nothing that is smooth by a clear margin.
    monkeypatch.setattr(silhouette, 'SIGN_GROUP', group)
    edges = _rocket_edges()
    rng = np.random.default_rng(7)
    skipped = 0
    for distance, size in ((10.0, 0.0), (10.0, 0.3), (3.0, 0.05), (40.0, 1.0), (6.0, 2.0)):
        direction = rng.normal(size=3)
        lo = distance * direction / np.linalg.norm(direction)
        hi = lo + size * rng.random(3)
        mask = edges.candidate_mask(lo, hi)
        exact = _exact_candidates(edges, lo, hi)
        assert np.all(mask[exact]), 'a possible silhouette was dropped'
        # Smooth by a margin 100x the classification's float32 widening: never kept.
        widen = 100 * (1e-5 + 1e-6 * (np.abs(0.5 * (lo + hi)).max() + np.abs(hi - lo).max()))
        loose = _exact_candidates(edges, lo - widen, hi + widen)
        assert not np.any(mask & ~loose & ~edges.coplanar)
        groups, size_used = edges._sign_groups
        assert size_used == group
        skipped += int(np.count_nonzero(~exact & ~edges.coplanar))
    assert skipped > 0
