"""A second reading of `lidar-sim simulate`'s bags, written without the project's code.

Nothing here imports ``lidar_sim_ros``: the bag is read with rosbags and a PointCloud2
decoder of its own, the target's motion is the scenario YAML's closed form written out
again (scipy rotations), the mesh is loaded with trimesh (node transforms applied, each
part's glTF material / node / mesh name kept) and the rays are intersected with a
Moller-Trumbore test in float64 numpy behind a uniform grid (every cell a ray crosses,
exactly; no Embree). test/test_sensor_outputs_independent.py judges the simulator with it.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
import yaml
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

# sensor_msgs/PointField datatypes (the message definition's constants)
_POINTFIELD_DTYPES = {1: 'i1', 2: 'u1', 3: 'i2', 4: 'u2', 5: 'i4', 6: 'u4', 7: 'f4', 8: 'f8'}


# ----------------------------------------------------------------------------- the bag

@dataclass(frozen=True)
class Cloud:
    stamp_ns: int
    points: np.ndarray        # structured, the fields the message declares


def decode_pointcloud2(msg) -> np.ndarray:
    """A PointCloud2 message's points as a structured array built from its own fields."""
    order = '>' if msg.is_bigendian else '<'
    dtype = np.dtype({'names': [f.name for f in msg.fields],
                      'formats': [order + _POINTFIELD_DTYPES[f.datatype] for f in msg.fields],
                      'offsets': [f.offset for f in msg.fields],
                      'itemsize': msg.point_step})
    n = msg.width * msg.height
    return np.frombuffer(bytes(msg.data), dtype=dtype, count=n)


def read_bag(bag: Path) -> dict:
    """{topic: [Cloud | (stamp_ns, message)]} of every message, in time order."""
    out: dict = {}
    with AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.msgtype == 'sensor_msgs/msg/PointCloud2':
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                out.setdefault(conn.topic, []).append(Cloud(stamp, decode_pointcloud2(msg)))
            elif hasattr(msg, 'header'):
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                out.setdefault(conn.topic, []).append((stamp, msg))
            else:
                out.setdefault(conn.topic, []).append((None, msg))
    return out


# ----------------------------------------------------------------------------- the scenario

def read_yaml(path: Path) -> dict:
    return yaml.safe_load(Path(path).read_text())


def scenario_files(scenario_path: Path) -> dict:
    """The scenario's YAML and the sensor, materials and mesh it names (beside it)."""
    scenario_path = Path(scenario_path)
    sc = read_yaml(scenario_path)
    here = scenario_path.parent
    return {'scenario': sc, 'sensor': read_yaml(here / sc['sensor']),
            'materials': read_yaml(here / sc['materials'])['materials'],
            'mesh_path': (here / sc['mesh']).resolve()}


def target_pose(scenario: dict, t_s: np.ndarray) -> tuple[Rotation, np.ndarray]:
    """The scenario's motion at scenario times t_s (N,): the body pose in the lidar frame,
    p_lidar = R p_body + position. The target closes along its initial line of sight at
    approach_speed_mps and turns about tumble_axis (fixed in the lidar frame) at
    tumble_rate_dps, starting from initial_pose at t = 0."""
    t = np.asarray(t_s, float)
    p0 = np.asarray(scenario['initial_pose']['position_m'], float)
    q0 = Rotation.from_quat(scenario['initial_pose']['quat_xyzw'])
    motion = scenario['motion']
    axis = np.asarray(motion['tumble_axis'], float)
    axis = axis / np.linalg.norm(axis)
    spin = Rotation.from_rotvec(np.radians(motion['tumble_rate_dps']) * t[:, None] * axis)
    position = p0 - motion['approach_speed_mps'] * t[:, None] * (p0 / np.linalg.norm(p0))
    return spin * q0, position


# ----------------------------------------------------------------------------- the mesh

@dataclass(frozen=True)
class Triangles:
    corners_m: np.ndarray     # (M, 3, 3) body frame
    part: np.ndarray          # (M,) index into names
    names: list               # per part: (material name, node name, mesh name)


def load_triangles(path: Path) -> Triangles:
    """Every triangle of a mesh file placed by its scene graph (node transforms applied),
    with the names of its part: the glTF/OBJ material's, the node's and the mesh's."""
    scene = trimesh.load(str(path), force='scene')
    corners, part, names = [], [], []
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry[geom_name]
        material = getattr(getattr(geom.visual, 'material', None), 'name', None)
        verts = trimesh.transform_points(np.asarray(geom.vertices, float), transform)
        corners.append(verts[np.asarray(geom.faces)])
        part.append(np.full(len(geom.faces), len(names)))
        names.append((material, node, geom_name))
    return Triangles(np.concatenate(corners), np.concatenate(part), names)


# glTF 2.0 accessor component types and element sizes (the specification's tables)
_GLTF_COMPONENT = {5121: 'u1', 5123: 'u2', 5125: 'u4', 5126: 'f4'}
_GLTF_TYPE_SIZE = {'SCALAR': 1, 'VEC3': 3}


def read_glb(path: Path) -> Triangles:
    """A .glb read from its bytes by the glTF 2.0 specification, not by trimesh: the JSON
    and BIN chunks, every node of the default scene placed by its global transform (the
    parents' times its own; a node's own: ``matrix``, column-major, or T R S from
    ``translation``, ``rotation`` xyzw, ``scale``), triangle primitives (mode 4) from
    their POSITION and (optional) indices accessors."""
    data = Path(path).read_bytes()
    magic, _, _ = np.frombuffer(data[:12], '<u4')
    assert magic == 0x46546C67, 'not a glb'
    json_len = int(np.frombuffer(data[12:16], '<u4')[0])
    gltf = json.loads(data[20:20 + json_len])
    bin_start = 20 + json_len + 8
    binary = data[bin_start:]

    def accessor(i):
        acc = gltf['accessors'][i]
        view = gltf['bufferViews'][acc['bufferView']]
        width = _GLTF_TYPE_SIZE[acc['type']]
        dtype = np.dtype('<' + _GLTF_COMPONENT[acc['componentType']])
        start = view.get('byteOffset', 0) + acc.get('byteOffset', 0)
        stride = view.get('byteStride', width * dtype.itemsize)
        rows = [np.frombuffer(binary, dtype, width, start + k * stride) for k in range(acc['count'])] \
            if stride != width * dtype.itemsize else \
            [np.frombuffer(binary, dtype, width * acc['count'], start).reshape(-1, width)]
        return np.concatenate(rows).reshape(acc['count'], width)

    def local(node):
        if 'matrix' in node:
            return np.asarray(node['matrix'], float).reshape(4, 4).T
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(node.get('rotation', [0, 0, 0, 1])).as_matrix() \
            * np.asarray(node.get('scale', [1, 1, 1]), float)
        m[:3, 3] = node.get('translation', [0, 0, 0])
        return m

    corners, part, names = [], [], []
    stack = [(i, np.eye(4)) for i in gltf['scenes'][gltf.get('scene', 0)]['nodes']]
    while stack:
        i, parent = stack.pop()
        node = gltf['nodes'][i]
        world = parent @ local(node)
        stack += [(c, world) for c in node.get('children', [])]
        if 'mesh' not in node:
            continue
        mesh = gltf['meshes'][node['mesh']]
        for prim in mesh['primitives']:
            assert prim.get('mode', 4) == 4
            v = accessor(prim['attributes']['POSITION']).astype(float)
            v = v @ world[:3, :3].T + world[:3, 3]
            idx = (accessor(prim['indices']).reshape(-1, 3) if 'indices' in prim
                   else np.arange(len(v)).reshape(-1, 3))
            material = gltf['materials'][prim['material']].get('name') if 'material' in prim else None
            corners.append(v[idx])
            part.append(np.full(len(idx), len(names)))
            names.append((material, node.get('name'), mesh.get('name')))
    return Triangles(np.concatenate(corners), np.concatenate(part), names)


def part_materials(tris: Triangles, mesh_materials) -> list:
    """Each part's config material name: the scenario's map tried on material, node, mesh
    name in that order (a string: one material for all); no map: the material name."""
    if isinstance(mesh_materials, str):
        return [mesh_materials] * len(tris.names)
    out = []
    for names in tris.names:
        if mesh_materials is None:
            out.append(names[0])
        else:
            out.append(next((mesh_materials[n] for n in names if n in mesh_materials), None))
    return out


# ----------------------------------------------------------------------------- the raycast

class GridRaycaster:
    """First hits of rays on a triangle soup: a uniform grid over its bounding box, each
    ray visiting exactly the cells its segment crosses (sorted plane crossings), then
    Moller-Trumbore (two-sided, float64) on the triangles registered in those cells."""

    def __init__(self, corners_m: np.ndarray, cells_on_longest_axis: int = 96):
        self.tri = np.asarray(corners_m, float)
        eps = 1e-6
        self.lo = self.tri.min(axis=(0, 1)) - 1e-3
        hi = self.tri.max(axis=(0, 1)) + 1e-3
        self.h = float((hi - self.lo).max() / cells_on_longest_axis)
        self.n = np.maximum(np.ceil((hi - self.lo) / self.h).astype(int), 1)
        self.hi = self.lo + self.n * self.h
        # register each triangle in every cell its (slightly grown) bounding box touches
        c0 = np.clip(np.floor((self.tri.min(axis=1) - eps - self.lo) / self.h).astype(int), 0, self.n - 1)
        c1 = np.clip(np.floor((self.tri.max(axis=1) + eps - self.lo) / self.h).astype(int), 0, self.n - 1)
        ext = c1 - c0 + 1
        count = ext.prod(axis=1)
        tri_id = np.repeat(np.arange(len(self.tri)), count)
        local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        e = ext[tri_id]
        ix = c0[tri_id, 0] + local % e[:, 0]
        iy = c0[tri_id, 1] + (local // e[:, 0]) % e[:, 1]
        iz = c0[tri_id, 2] + local // (e[:, 0] * e[:, 1])
        cell = (ix * self.n[1] + iy) * self.n[2] + iz
        order = np.argsort(cell, kind='stable')
        self.cell_tris = tri_id[order]
        self.cell_start = np.searchsorted(cell[order], np.arange(self.n.prod() + 1))
        self.e1 = self.tri[:, 1] - self.tri[:, 0]
        self.e2 = self.tri[:, 2] - self.tri[:, 0]

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, chunk: int = 2048):
        """(range (N,) inf on a miss, triangle index (N,) -1 on a miss) of unit rays."""
        o_all = np.asarray(origins, float)
        d_all = np.asarray(directions, float)
        rng = np.full(len(o_all), np.inf)
        face = np.full(len(o_all), -1)
        for s in range(0, len(o_all), chunk):
            rng[s:s + chunk], face[s:s + chunk] = self._chunk(o_all[s:s + chunk], d_all[s:s + chunk])
        return rng, face

    def _cells(self, o, d):
        """(ray, cell) pairs: every grid cell each ray's segment inside the box crosses."""
        with np.errstate(divide='ignore', invalid='ignore'):
            inv = 1.0 / d
            ta, tb = (self.lo - o) * inv, (self.hi - o) * inv
        ta = np.where(np.isnan(ta), -np.inf, ta)
        tb = np.where(np.isnan(tb), np.inf, tb)
        t0 = np.maximum(np.minimum(ta, tb).max(axis=1), 0.0)
        t1 = np.maximum(ta, tb).min(axis=1)
        inside = t1 > t0
        crossings = [t0[:, None], t1[:, None]]
        for a in range(3):
            planes = self.lo[a] + self.h * np.arange(1, self.n[a])
            with np.errstate(divide='ignore', invalid='ignore'):
                t = (planes[None, :] - o[:, a:a + 1]) * inv[:, a:a + 1]
            t = np.where((t > t0[:, None]) & (t < t1[:, None]), t, np.inf)
            crossings.append(t)
        t = np.sort(np.concatenate(crossings, axis=1), axis=1)
        mid = 0.5 * (t[:, :-1] + t[:, 1:])
        ok = np.isfinite(mid) & inside[:, None]
        ray, k = np.nonzero(ok)
        p = o[ray] + mid[ray, k, None] * d[ray]
        idx = np.clip(np.floor((p - self.lo) / self.h).astype(int), 0, self.n - 1)
        return ray, (idx[:, 0] * self.n[1] + idx[:, 1]) * self.n[2] + idx[:, 2]

    def _chunk(self, o, d):
        ray, cell = self._cells(o, d)
        count = self.cell_start[cell + 1] - self.cell_start[cell]
        ray = np.repeat(ray, count)
        local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        tri = self.cell_tris[np.repeat(self.cell_start[cell], count) + local]
        # Moller-Trumbore, two-sided
        dd, e1, e2 = d[ray], self.e1[tri], self.e2[tri]
        pvec = np.cross(dd, e2)
        det = np.einsum('ij,ij->i', e1, pvec)
        ok = np.abs(det) > 1e-15
        inv_det = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        tvec = o[ray] - self.tri[tri, 0]
        u = np.einsum('ij,ij->i', tvec, pvec) * inv_det
        qvec = np.cross(tvec, e1)
        v = np.einsum('ij,ij->i', dd, qvec) * inv_det
        t = np.einsum('ij,ij->i', e2, qvec) * inv_det
        tol = 1e-9
        hit = ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t > 1e-9)
        rng = np.full(len(o), np.inf)
        np.minimum.at(rng, ray[hit], t[hit])
        face = np.full(len(o), -1)
        best = hit & (t == rng[ray])
        face[ray[best]] = tri[best]
        return rng, face


def face_normals(corners_m: np.ndarray) -> np.ndarray:
    n = np.cross(corners_m[:, 1] - corners_m[:, 0], corners_m[:, 2] - corners_m[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def cast_points(caster: GridRaycaster, scenario: dict, xyz_m: np.ndarray, time_s: np.ndarray):
    """Each point's own ray (sensor origin toward its xyz) cast against the mesh at the
    target pose of its own scenario time: (hit range m, triangle, cos incidence)."""
    xyz = np.asarray(xyz_m, float)
    d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    rot, pos = target_pose(scenario, time_s)
    o_body = rot.inv().apply(-pos)
    d_body = rot.inv().apply(d)
    rng, face = caster.first_hit(o_body, d_body)
    normals = face_normals(caster.tri[np.maximum(face, 0)])
    cos_i = np.abs(np.einsum('ij,ij->i', normals, d_body))
    return rng, face, cos_i
