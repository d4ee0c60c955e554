"""Geometric model: raycast range, incidence and material against closed forms."""
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.geometry import MeshFileError, MeshMaterialError, Target, cast_at_poses, load_target
from lidar_sim_ros.core.pose import PoseTrack
from lidar_sim_ros.core.scan import directions_from_angles
from conftest import REPO, embree_range_tol_m, plate_target, sphere_target


def _static(position, rotation=Rotation.identity()):
    return PoseTrack([0.0], [position], rotation.as_quat()[None])


def test_plate_range_and_incidence():
    # Plate normal (body +z) tilted 30 deg about y, plate 7 m ahead on x.
    tilt = Rotation.from_euler('y', -90 + 30, degrees=True)  # body +z -> toward -x, 30 deg off
    poses = _static([7.0, 0, 0], tilt).at(np.zeros(1))
    hits = cast_at_poses(plate_target(), np.array([[1.0, 0, 0]]), poses)
    assert hits.hit[0]
    assert hits.range_m[0] == pytest.approx(7.0, abs=embree_range_tol_m(7.0))  # float32 Embree
    # Normal and incidence come from float64 face normals and rays.
    assert np.degrees(hits.incidence_rad[0]) == pytest.approx(30.0, abs=1e-10)
    assert hits.normal[0] @ np.array([-1.0, 0, 0]) == pytest.approx(np.cos(np.radians(30)), abs=1e-12)


def test_sphere_range_and_incidence():
    radius, dist = 1.0, 5.0
    target = sphere_target(radius, subdivisions=6)
    beta = np.radians(np.linspace(-11, 11, 41))  # asin(1/5) = 11.54 deg is the limb
    dirs = directions_from_angles(beta, np.zeros_like(beta))
    poses = _static([dist, 0, 0]).at(np.zeros(len(beta)))
    hits = cast_at_poses(target, dirs, poses)
    assert hits.hit.all()
    expected = dist * np.cos(beta) - np.sqrt(radius ** 2 - (dist * np.sin(beta)) ** 2)
    inc = np.arcsin(np.clip(dist * np.sin(np.abs(beta)) / radius, 0, 1))
    # The mesh is a faceted sphere: flat faces dip up to depth inside it (7e-5 m here),
    # which a ray at incidence i meets up to depth / cos(i) early or late. Float32 is far below.
    depth = radius - np.linalg.norm(target.vertices_m[target.faces].mean(axis=1), axis=1).min()
    np.testing.assert_array_less(np.abs(hits.range_m - expected), 2 * depth / np.cos(inc))
    # Face normals tilt from the sphere's by up to 0.7 deg at a face's corners.
    assert np.allclose(hits.incidence_rad, inc, atol=np.radians(1.0))
    miss = cast_at_poses(target, directions_from_angles(np.radians([12.0]), np.zeros(1)),
                         _static([dist, 0, 0]).at(np.zeros(1)))
    assert not miss.hit[0] and np.isinf(miss.range_m[0]) and miss.material[0] == -1


def test_rocket_mesh_has_every_material_and_visible_faces(default_scenario):
    target = load_target(default_scenario.mesh_path, default_scenario.materials.names)
    assert set(np.unique(target.face_material)) == set(range(7))
    lo, hi = target.vertices_m.min(0), target.vertices_m.max(0)
    assert hi[2] - lo[2] == pytest.approx(10.0, abs=0.5)       # about 10 m long
    assert hi[0] - lo[0] == pytest.approx(4.0, abs=0.2)        # about 4 m diameter
    # Seen from the side, the tank's foam faces the sensor at ~8 m.
    hits = cast_at_poses(target, np.array([[1.0, 0, 0]]), _static([10.0, 0, 0],
                         Rotation.from_euler('x', -90, degrees=True)).at(np.zeros(1)))
    assert target.material_names[hits.material[0]] in ('PIF', 'MLI')
    assert hits.range_m[0] == pytest.approx(8.0, abs=0.05)


def test_mesh_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match='nope.obj'):
        load_target(tmp_path / 'nope.obj', ['PIF'])


def test_repo_mesh_path_exists():
    assert (REPO / 'meshes' / 'rocket_body.obj').is_file()


# ------------------------------------------------------------ bad mesh files
TRIANGLES = 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl PIF\nf 1 2 3\nusemtl MLI\nf 1 2 4\n'


def _mesh(folder, name, text, mtl='newmtl PIF\nKd 1 1 1\nnewmtl MLI\nKd 1 1 0\n'):
    if mtl is not None:
        (folder / 'm.mtl').write_text(mtl)
    path = folder / name
    path.write_text(text) if isinstance(text, str) else path.write_bytes(text)
    return path


def test_a_good_obj_with_its_mtl_loads(tmp_path):
    target = load_target(_mesh(tmp_path, 'm.obj', 'mtllib m.mtl\n' + TRIANGLES), ['PIF', 'MLI'])
    assert target.n_faces == 2 and sorted(target.face_material) == [0, 1]


@pytest.mark.parametrize('text, mtl', [
    (TRIANGLES, None),                              # no mtllib line (many exporters)
    ('mtllib gone.mtl\n' + TRIANGLES, None),         # its MTL file is missing
    ('mtllib m.mtl\n' + TRIANGLES, 'newmtl PIF\n'),  # the MTL lacks a name it uses
])
def test_usemtl_names_are_kept_without_their_mtl_file(tmp_path, text, mtl):
    """The names alone map faces to materials: PIF on the z = 0 face, MLI on y = 0."""
    target = load_target(_mesh(tmp_path, 'm.obj', text, mtl), ['MLI', 'PIF'])
    normal_axis = np.argmax(np.abs(target.face_normals), axis=1)
    names = [target.material_names[m] for m in target.face_material]
    assert sorted(zip(normal_axis.tolist(), names)) == [(1, 'MLI'), (2, 'PIF')]


@pytest.mark.parametrize('name, text, mtl, message', [
    ('m.mtl', None, 'newmtl PIF\nKd 1 1 1\n', r'm\.mtl: this is a material library \(\.mtl\), not a mesh'),
    ('m.stl', 'solid x\nendsolid x\n', None, r'm\.stl: no triangles found'),      # a CAD export with no faces
    ('m.3ds', 'x', None, r'm\.3ds: the mesh must be a Wavefront \.obj'),
    ('m.obj', 'mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n', 'newmtl PIF\n', r'm\.obj: no usemtl lines'),
    ('m.obj', '', None, r'm\.obj: no faces'),
    ('m.obj', 'hello\nthis is not a mesh\n', None, r'm\.obj: no faces'),
    ('m.obj', bytes(range(256)) * 4, None, r'm\.obj: not a text OBJ file'),
    ('m.obj', 'mtllib m.mtl\nv 0 0 0\nusemtl PIF\nf 1 2 x y\n', 'newmtl PIF\n',
     r'm\.obj: trimesh cannot read it'),
])
def test_bad_mesh_files_get_one_line_naming_file_and_problem(tmp_path, name, text, mtl, message):
    path = tmp_path / name
    if text is None:
        path.write_text(mtl)
    else:
        _mesh(tmp_path, name, text, mtl)
    with pytest.raises(MeshFileError, match=message) as info:
        load_target(path, ['PIF', 'MLI'])
    assert '\n' not in str(info.value)


def test_an_unknown_material_name_is_named(tmp_path):
    path = _mesh(tmp_path, 'm.obj', 'mtllib m.mtl\n' + TRIANGLES.replace('usemtl MLI', 'usemtl GOLD'),
                 'newmtl PIF\nnewmtl GOLD\n')
    with pytest.raises(MeshMaterialError, match=r"\['GOLD'\] not in the materials config"):
        load_target(path, ['PIF', 'MLI'])


def test_supporting_faces_are_those_on_the_convex_hull():
    """A cube: every face supports it. A cube on a larger plate: the cube's top and sides
    stand above the plate's plane, so the plate's upper side is not supporting, and the
    cube's sides (whose planes the plate's corners poke through) are not either."""
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    alone = Target(cube.vertices, cube.faces, np.zeros(len(cube.faces), int), ['PIF'])
    assert alone.supporting_faces.all()
    plate = trimesh.Trimesh(vertices=[[-3, -3, -0.5], [3, -3, -0.5], [3, 3, -0.5], [-3, 3, -0.5]],
                            faces=[[0, 1, 2], [0, 2, 3]])
    both = trimesh.util.concatenate([plate, cube])
    target = Target(both.vertices, both.faces, np.zeros(len(both.faces), int), ['PIF'])
    normals = target.face_normals
    top = normals[:, 2] > 0.99
    expected = np.zeros(len(normals), bool)
    expected[2:] = top[2:] | (normals[2:, 2] < -0.99)   # cube top, and its bottom on the plate
    np.testing.assert_array_equal(target.supporting_faces, expected)
