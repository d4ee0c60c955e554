"""CAD targets (core/mesh_files.py): glTF/GLB, STL and PLY through the scenario's materials map."""
import numpy as np
import pytest
import trimesh
from trimesh.visual.material import PBRMaterial
from trimesh.visual.texture import TextureVisuals

from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.geometry import MeshFileError, MeshMaterialError, load_target
from lidar_sim_ros.core.pipeline import Simulator
from conftest import CONFIG, REPO

MESH_DIR = CONFIG.parent / 'meshes'
NAMES = ['MLI', 'SOLAR_ARRAY', 'WHITE_PAINT', 'ALUMINIUM']


def two_part_glb(path, offset=(0.0, 0.0, 5.0)):
    """Two unit boxes: node 'panel' (material 'blue_cells'), node 'body' (material 'foil')
    placed by a node transform ``offset`` away."""
    scene = trimesh.Scene()
    a = trimesh.creation.box(extents=[1, 1, 1])
    a.visual = TextureVisuals(material=PBRMaterial(name='blue_cells'))
    b = trimesh.creation.box(extents=[1, 1, 1])
    b.visual = TextureVisuals(material=PBRMaterial(name='foil'))
    scene.add_geometry(a, node_name='panel', geom_name='panel_mesh')
    scene.add_geometry(b, node_name='body', geom_name='body_mesh',
                       transform=trimesh.transformations.translation_matrix(offset))
    path.write_bytes(scene.export(file_type='glb'))
    return path


def test_glb_parts_by_material_name_and_node_transform(tmp_path):
    glb = two_part_glb(tmp_path / 'two.glb')
    t = load_target(glb, NAMES, mesh_materials={'blue_cells': 'SOLAR_ARRAY', 'foil': 'MLI'})
    assert t.n_faces == 24
    mli = t.face_material == NAMES.index('MLI')
    # The node's translation is applied: the foil box is centred at z = 5, the panel at 0.
    assert t.vertices_m[t.faces[mli]].reshape(-1, 3).mean(axis=0) == pytest.approx([0, 0, 5])
    assert t.vertices_m[t.faces[~mli]].reshape(-1, 3).mean(axis=0) == pytest.approx([0, 0, 0])
    assert set(t.face_material[~mli]) == {NAMES.index('SOLAR_ARRAY')}
    # A node name maps too (the material name is tried first, then the node's).
    t2 = load_target(glb, NAMES, mesh_materials={'panel': 'ALUMINIUM', 'body': 'WHITE_PAINT'})
    assert sorted(np.bincount(t2.face_material, minlength=4).tolist()) == [0, 0, 12, 12]


def test_unmapped_names_stop_with_one_line_naming_them(tmp_path):
    glb = two_part_glb(tmp_path / 'two.glb')
    with pytest.raises(MeshMaterialError) as err:
        load_target(glb, NAMES, mesh_materials={'blue_cells': 'SOLAR_ARRAY'})
    msg = str(err.value)
    assert "['foil']" in msg and 'two.glb' in msg and '\n' not in msg
    with pytest.raises(MeshMaterialError, match="'nope'.*not in the materials config"):
        load_target(glb, NAMES, mesh_materials={'blue_cells': 'nope', 'foil': 'MLI'})
    with pytest.raises(MeshMaterialError, match='blue_cells'):  # no map: names must be config's
        load_target(glb, NAMES)


def test_stl_and_ply_one_material_for_the_whole_file(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=2.0)
    for suffix in ('stl', 'ply'):
        path = tmp_path / f'ball.{suffix}'
        mesh.export(path)
        t = load_target(path, NAMES, mesh_materials='ALUMINIUM')
        assert t.n_faces == len(mesh.faces)
        assert set(t.face_material) == {NAMES.index('ALUMINIUM')}
        assert np.linalg.norm(t.vertices_m, axis=1) == pytest.approx(2.0, rel=1e-6)
        with pytest.raises(MeshMaterialError, match='not mapped'):
            load_target(path, NAMES)


@pytest.mark.parametrize('suffix, data', [('glb', b'glTF\x02\x00\x00\x00garbage'),
                                          ('stl', b''), ('gltf', b'{"asset": 3}'),
                                          ('ply', b'ply\nformat ascii 1.0\nend_header\n')])
def test_broken_cad_files_one_line(tmp_path, suffix, data):
    path = tmp_path / f'bad.{suffix}'
    path.write_bytes(data)
    with pytest.raises((MeshFileError, MeshMaterialError)) as err:
        load_target(path, NAMES, mesh_materials='MLI')
    assert 'bad.' + suffix in str(err.value) and '\n' not in str(err.value)


def test_box_wing_scenario_from_its_gltf():
    sc = load_scenario(CONFIG / 'scenario_box_wing.yaml')
    assert sc.mesh_path.suffix == '.glb'
    sim = Simulator.from_scenario(sc)
    counts = np.bincount(sim.target.face_material, minlength=4)
    assert counts.tolist() == [12, 24, 12, 1104 + 96 + 2 * 64]   # bus, 2 wings, radiator, Al parts
    from lidar_sim_ros.core.pose import StaticPose
    frame = sim.simulate_frame(0.0, StaticPose(sc.config.initial_pose.position_m,
                                               sc.config.initial_pose.quat_xyzw), 0)
    assert set(np.unique(frame.material)) == {0, 1, 2, 3}      # every material seen


def test_mesh_materials_naming_an_unknown_material_is_a_config_error(tmp_path):
    text = (CONFIG / 'scenario_box_wing.yaml').read_text().replace('antenna_aluminium: ALUMINIUM',
                                                                  'antenna_aluminium: ALUMINUM')
    bad = tmp_path / 'scenario.yaml'
    bad.write_text(text.replace('../meshes/', str(MESH_DIR) + '/').replace(
        'materials: materials_box_wing.yaml', f'materials: {CONFIG / "materials_box_wing.yaml"}'))
    with pytest.raises(ConfigError, match='mesh_materials.antenna_aluminium.*ALUMINUM'):
        load_scenario(bad)


def gltf_with_buffer(path, uri):
    """A one-triangle glTF (material 'foil') whose buffer is the file ``uri`` names."""
    import json
    doc = {'asset': {'version': '2.0'}, 'scene': 0, 'scenes': [{'nodes': [0]}],
           'nodes': [{'mesh': 0, 'name': 'part'}], 'materials': [{'name': 'foil'}],
           'meshes': [{'primitives': [{'attributes': {'POSITION': 0}, 'indices': 1,
                                       'material': 0}]}],
           'buffers': [{'uri': uri, 'byteLength': 44}],
           'bufferViews': [{'buffer': 0, 'byteOffset': 0, 'byteLength': 36},
                           {'buffer': 0, 'byteOffset': 36, 'byteLength': 6}],
           'accessors': [{'bufferView': 0, 'componentType': 5126, 'count': 3, 'type': 'VEC3',
                          'min': [0, 0, 0], 'max': [1, 1, 0]},
                         {'bufferView': 1, 'componentType': 5123, 'count': 3, 'type': 'SCALAR'}]}
    path.write_text(json.dumps(doc))
    return path


def triangle_bytes(scale=1.0):
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32) * scale
    return tri.tobytes() + np.array([0, 1, 2], np.uint16).tobytes() + b'\0\0'


def one_buffer_gltf(data, vertex_count=3, index_count=3, nodes=None, primitive=None):
    """A glTF 2.0 document over one buffer ``data``: POSITION (float VEC3, ``vertex_count``)
    at byte 0, uint16 indices (``index_count``) right after; material 'foil'."""
    return {'asset': {'version': '2.0'}, 'scene': 0,
            'scenes': [{'nodes': list(range(len(nodes))) if nodes else [0]}],
            'nodes': nodes or [{'mesh': 0, 'name': 'part'}], 'materials': [{'name': 'foil'}],
            'meshes': [{'primitives': [primitive or {'attributes': {'POSITION': 0}, 'indices': 1,
                                                     'material': 0}]}],
            'buffers': [{'byteLength': len(data)}],
            'bufferViews': [{'buffer': 0, 'byteOffset': 0, 'byteLength': 12 * vertex_count},
                            {'buffer': 0, 'byteOffset': 12 * vertex_count,
                             'byteLength': 2 * index_count}],
            'accessors': [{'bufferView': 0, 'componentType': 5126, 'count': vertex_count,
                           'type': 'VEC3'},
                          {'bufferView': 1, 'componentType': 5123, 'count': index_count,
                           'type': 'SCALAR'}]}


def write_glb(path, doc, data):
    """``doc`` and ``data`` as a binary glTF (glTF 2.0 spec, section 'GLB File Format')."""
    import json
    import struct
    text = json.dumps(doc).encode()
    text += b' ' * (-len(text) % 4)
    data += b'\0' * (-len(data) % 4)
    chunks = struct.pack('<I4s', len(text), b'JSON') + text + struct.pack('<I4s', len(data), b'BIN\0') + data
    path.write_bytes(b'glTF' + struct.pack('<II', 2, 12 + len(chunks)) + chunks)
    return path


@pytest.mark.parametrize('uri', ['SECRET', '../secret.bin', 'file://SECRET',
                                 'http://127.0.0.1:9/secret.bin', 'link.bin', '%2e%2e/secret.bin'])
def test_gltf_external_files_only_from_its_own_directory(tmp_path, monkeypatch, uri):
    """A glTF's buffer naming a file outside its directory is refused, naming the URI, and
    never read, whatever trimesh's own resolver would do: trimesh 4.0 (allowed by
    requirements.txt) joined any name to the directory and opened it, so the 'secret'
    file's bytes became target vertices. Its resolver is put back here to show it."""
    import os
    secret = tmp_path / 'secret.bin'
    secret.write_bytes(triangle_bytes(scale=7.0))
    sub = tmp_path / 'cad'
    sub.mkdir()
    os.symlink(secret, sub / 'link.bin')
    (sub / 'ok.bin').write_bytes(triangle_bytes())

    def trimesh_4_0_get(self, name):               # trimesh 4.0.0 FilePathResolver.get
        with open(os.path.join(self.parent, name.strip()), 'rb') as f:
            return f.read()
    monkeypatch.setattr(trimesh.resolvers.FilePathResolver, 'get', trimesh_4_0_get)
    ok = load_target(gltf_with_buffer(sub / 'ok.gltf', 'ok.bin'), NAMES, mesh_materials='MLI')
    assert ok.vertices_m.max() == pytest.approx(1.0)  # a file beside it is read
    bad = gltf_with_buffer(sub / 'bad.gltf', uri.replace('SECRET', str(secret)))
    with pytest.raises(MeshFileError, match="bad.gltf: external file .*(not a path relative|leads "
                                            "out of)") as err:
        load_target(bad, NAMES, mesh_materials='MLI')
    assert uri.replace('SECRET', str(secret))[:40] in str(err.value)


@pytest.mark.parametrize('suffix', ['.gltf', '.glb'])
def test_gltf_json_beyond_its_limit_is_refused_before_parsing(tmp_path, monkeypatch, suffix):
    """Parsed glTF JSON takes up to ~6x its size (100 MB of numbers peaked at 574 MB):
    below the 2 GB file limit a .gltf or a .glb's JSON chunk could take ~11 GB."""
    from lidar_sim_ros.core import mesh_files
    monkeypatch.setattr(mesh_files, 'MAX_GLTF_JSON_BYTES', 1000)
    text = ('{"asset": {"version": "2.0"}, "extras": [' + '0,' * 600 + '0]}').encode()
    if suffix == '.gltf':
        data = text
    else:
        text += b' ' * (-len(text) % 4)
        data = (b'glTF' + (2).to_bytes(4, 'little') + (20 + len(text)).to_bytes(4, 'little')
                + len(text).to_bytes(4, 'little') + b'JSON' + text)
    path = tmp_path / f'big{suffix}'
    path.write_bytes(data)
    with pytest.raises(MeshFileError, match=f'big{suffix}: {len(text)} bytes of glTF JSON exceed'):
        load_target(path, NAMES, mesh_materials='MLI')
    # The shipped box-wing satellite's JSON is far below the real limit.
    assert mesh_files._gltf_json_bytes(MESH_DIR / 'box_wing_satellite.glb', 0) < 100_000


def ply_with_face(path, face):
    """An ASCII PLY of three vertices and one face ``face`` (vertex indices as written)."""
    path.write_text('ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n'
                    'property float z\nelement face 1\nproperty list uchar int vertex_indices\n'
                    f'end_header\n0 0 0\n1 0 0\n0 1 0\n3 {" ".join(map(str, face))}\n')
    return path


@pytest.mark.parametrize('face, bad', [((0, 1, 9), 9), ((0, -1, -2), -1)])
def test_faces_naming_vertices_the_file_lacks_are_refused(tmp_path, face, bad):
    """A face index past the vertex list raised IndexError out of the loader (a traceback
    from lidar-sim simulate); a negative one silently took a vertex from the end (Python
    indexing): a triangle the file does not describe."""
    path = ply_with_face(tmp_path / 'tri.ply', face)
    with pytest.raises(MeshFileError, match=rf'tri.ply: .*vertex index {bad}, but only 3 vertices') as err:
        load_target(path, NAMES, mesh_materials='MLI')
    assert '\n' not in str(err.value)
    assert load_target(ply_with_face(tmp_path / 'ok.ply', (0, 1, 2)), NAMES,
                       mesh_materials='MLI').n_faces == 1


def test_a_part_placed_many_times_brings_only_the_vertices_its_faces_use(tmp_path):
    """One triangle over a 20,000-vertex accessor, placed by 3 nodes: every placement
    copied all 20,000 vertices (a 12 MB .glb placed by 40 nodes took 2 GB; 400 nodes,
    20 GB). Now each placement keeps the vertices its faces name: at most 3 per triangle,
    whatever the file claims."""
    n = 20_000
    verts = np.zeros((n, 3), np.float32)
    verts[[7, 500, n - 1]] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    data = verts.tobytes() + np.array([7, 500, n - 1], np.uint16).tobytes() + b'\0\0'
    doc = one_buffer_gltf(data, vertex_count=n, nodes=[
        {'mesh': 0, 'name': f'copy{i}', 'translation': [0, 0, 2.0 * i]} for i in range(3)])
    t = load_target(write_glb(tmp_path / 'many.glb', doc, data), NAMES, mesh_materials='MLI')
    assert t.n_faces == 3 and len(t.vertices_m) == 9
    tri = t.vertices_m[t.faces]
    np.testing.assert_allclose(np.sort(tri[:, :, 2].mean(axis=1)), [0.0, 2.0, 4.0])
    np.testing.assert_allclose(tri[:, :, :2], [[[0, 0], [1, 0], [0, 1]]] * 3)


def test_external_files_are_read_once_and_bounded_together(tmp_path, monkeypatch):
    """60 buffers naming the same 20 MB .bin took 1.3 GB (each read again; one 2 GB file
    named 100 times, 200 GB). Each file is now read once, and all of them together stay
    within MAX_EXTERNAL_BYTES."""
    import json
    from lidar_sim_ros.core import mesh_files
    monkeypatch.setattr(mesh_files, 'MAX_EXTERNAL_BYTES', 100)
    for name in ('a.bin', 'b.bin', 'c.bin'):
        (tmp_path / name).write_bytes(triangle_bytes())            # 44 bytes each
    doc = json.loads(gltf_with_buffer(tmp_path / 'same.gltf', 'a.bin').read_text())
    doc['buffers'] = [{'uri': 'a.bin', 'byteLength': 44}] * 50
    (tmp_path / 'same.gltf').write_text(json.dumps(doc))
    assert load_target(tmp_path / 'same.gltf', NAMES, mesh_materials='MLI').n_faces == 1
    doc['buffers'] = [{'uri': name, 'byteLength': 44} for name in ('a.bin', 'b.bin', 'c.bin')]
    (tmp_path / 'three.gltf').write_text(json.dumps(doc))
    with pytest.raises(MeshFileError, match=r"three.gltf: external file 'c.bin': the external "
                                            r'files come to 132 bytes, beyond the limit of 100'):
        load_target(tmp_path / 'three.gltf', NAMES, mesh_materials='MLI')


@pytest.mark.parametrize('count, records', [(1000, 1), (1, 3), (2 ** 32 - 1, 1)])
def test_a_binary_stl_whose_count_disagrees_with_its_length_says_so(tmp_path, count, records):
    """trimesh read such a file as ASCII and the load said 'no triangles found'."""
    import struct
    record = struct.pack('<12fH', 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
    path = tmp_path / 'part.stl'
    path.write_bytes(b'\0' * 80 + struct.pack('<I', count) + record * records)
    with pytest.raises(MeshFileError, match=rf'part.stl: binary STL header says {count} triangles '
                                            rf'\({84 + 50 * count} bytes\), but the file has '
                                            rf'{84 + 50 * records} bytes'):
        load_target(path, NAMES, mesh_materials='MLI')
    path.write_bytes(b'\0' * 80 + struct.pack('<I', records) + record * records)
    assert load_target(path, NAMES, mesh_materials='MLI').n_faces == records


def test_text_meshes_beyond_their_limit_are_refused_before_parsing(tmp_path, monkeypatch):
    """trimesh's parse of text takes ~5-12x its size (ASCII PLY 12x, ASCII STL 7x, OBJ
    4.5-10x, measured on 40-100 MB files): within the 2 GB file limit an ASCII PLY needed
    ~24 GB. Text meshes stop at MAX_TEXT_MESH_BYTES; binary STL and PLY go on to 2 GB."""
    from lidar_sim_ros.core import mesh_files
    mesh = trimesh.creation.icosphere(subdivisions=1)
    paths = {'stl': tmp_path / 'a.stl', 'ply': tmp_path / 'a.ply', 'obj': tmp_path / 'a.obj'}
    paths['stl'].write_bytes(trimesh.exchange.stl.export_stl_ascii(mesh).encode())
    paths['ply'].write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding='ascii'))
    paths['obj'].write_text('usemtl MLI\n' + ''.join(f'v {x} {y} {z}\n' for x, y, z in mesh.vertices)
                            + ''.join(f'f {a + 1} {b + 1} {c + 1}\n' for a, b, c in mesh.faces))
    for path in paths.values():
        assert load_target(path, NAMES, mesh_materials='MLI').n_faces == len(mesh.faces)
    limit = min(p.stat().st_size for p in paths.values()) - 1
    monkeypatch.setattr(mesh_files, 'MAX_TEXT_MESH_BYTES', limit)
    for path in paths.values():
        with pytest.raises(MeshFileError, match=rf'a.{path.suffix[1:]}: \d+ bytes of text mesh exceed '
                                                rf'the limit of {limit} \(export it as binary'):
            load_target(path, NAMES, mesh_materials='MLI')
    big = trimesh.creation.icosphere(subdivisions=3)
    for suffix in ('stl', 'ply'):                       # binary: not text, read as before
        path = tmp_path / f'b.{suffix}'
        big.export(path)
        assert path.stat().st_size > limit
        assert load_target(path, NAMES, mesh_materials='MLI').n_faces == len(big.faces)


def test_triangle_counts_in_stl_and_ply_headers_are_held_to_the_limit_before_reading(tmp_path,
                                                                                      monkeypatch):
    """The triangle limit was checked after trimesh had read the whole file: a 100 MB
    binary STL of 2 M triangles took 1.1 GB and 14 s to get there (a 2 GB one, ~22 GB).
    A binary STL's count and a PLY's face and vertex counts are read from the header."""
    import lidar_sim_ros.core.geometry as geometry
    mesh = trimesh.creation.icosphere(subdivisions=1)           # 80 faces, 42 vertices
    stl, ply = tmp_path / 'a.stl', tmp_path / 'a.ply'
    mesh.export(stl), mesh.export(ply)
    monkeypatch.setattr(geometry, 'MAX_TRIANGLES', 79)
    monkeypatch.setattr(trimesh, 'load', lambda *a, **k: pytest.fail('trimesh read the file'))
    with pytest.raises(MeshFileError, match='a.stl: binary STL header says 80 triangles, more '
                                            'than the limit of 79'):
        load_target(stl, NAMES, mesh_materials='MLI')
    with pytest.raises(MeshFileError, match='a.ply: PLY header says 80 face elements, more than '
                                            'the limit of 79'):
        load_target(ply, NAMES, mesh_materials='MLI')
    one_face = tmp_path / 'v.ply'                              # 42 vertices, 1 face
    trimesh.Trimesh(mesh.vertices, mesh.faces[:1], process=False).export(one_face)
    monkeypatch.setattr(geometry, 'MAX_TRIANGLES', 13)
    with pytest.raises(MeshFileError, match='v.ply: PLY header says 42 vertex elements, more '
                                            'than the limit of 39'):
        load_target(one_face, NAMES, mesh_materials='MLI')


def test_parts_map_by_the_names_the_file_gives_them(tmp_path):
    """Two nodes named 'wing' (a CAD export's two solar wings) each placing the mesh
    'panel' of two primitives (materials 'cells' and 'frame'). trimesh renames them
    ('wing_1', a primitive's child frame 'wing_8846ae', the second primitive 'panel_1'),
    so mesh_materials {wing: ...} or {panel: ...}, the file's own names, stopped the load
    with "['frame'] not mapped" or "['wing_1'] not mapped" (a name not in the file)."""
    data = triangle_bytes()
    prim = {'attributes': {'POSITION': 0}, 'indices': 1}
    doc = one_buffer_gltf(data, nodes=[{'mesh': 0, 'name': 'wing'},
                                       {'mesh': 0, 'name': 'wing', 'translation': [0, 0, 4]}])
    doc['meshes'] = [{'name': 'panel', 'primitives': [{**prim, 'material': 0}, {**prim, 'material': 1}]}]
    doc['materials'] = [{'name': 'cells'}, {'name': 'frame'}]
    path = write_glb(tmp_path / 'wings.glb', doc, data)
    for mapping, name in (({'wing': 'SOLAR_ARRAY'}, 'SOLAR_ARRAY'), ({'panel': 'MLI'}, 'MLI')):
        t = load_target(path, NAMES, mesh_materials=mapping)
        assert t.n_faces == 4 and set(t.face_material) == {NAMES.index(name)}
    # The material name still comes first; an unmapped part is named by the file's names.
    t = load_target(path, NAMES, mesh_materials={'cells': 'SOLAR_ARRAY', 'wing': 'ALUMINIUM'})
    assert sorted(np.bincount(t.face_material, minlength=4)) == [0, 0, 2, 2]
    with pytest.raises(MeshMaterialError, match=r"\['frame'\] not mapped"):
        load_target(path, NAMES, mesh_materials={'cells': 'SOLAR_ARRAY'})


def test_many_unmapped_parts_are_named_in_a_short_line(tmp_path):
    """5,000 parts of their own names and no map: the error listed every name, a line of
    ~60 kB (100,000 parts: over 1 MB) in the terminal and the node's log."""
    data = triangle_bytes()
    nodes = [{'mesh': 0, 'name': f'bracket_{i:05d}'} for i in range(5000)]
    doc = one_buffer_gltf(data, nodes=nodes)
    del doc['materials'][0]['name']
    with pytest.raises(MeshMaterialError) as err:
        load_target(write_glb(tmp_path / 'many.glb', doc, data), NAMES)
    msg = str(err.value)
    assert "['bracket_00000', 'bracket_00001'" in msg and 'and 4990 more' in msg
    assert len(msg) < 600 and '\n' not in msg


def test_a_non_finite_stl_vertex_is_refused_without_numpy_warnings(tmp_path, recwarn):
    """'vertex 1 inf 0' in an ASCII STL: numpy's RuntimeWarnings (invalid value in multiply,
    subtract: six lines from trimesh's normals and the node transform) came before the
    one-line error."""
    path = tmp_path / 'inf.stl'
    path.write_text('solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 inf 0\n'
                    'vertex 0 1 0\nendloop\nendfacet\nendsolid x\n')
    with pytest.raises(MeshFileError, match=r"inf.stl: part 'x' vertex #1 = \[1.0, inf, 0.0\] is "
                                            r"not finite \(1 of its 3 vertices are not\)"):
        load_target(path, NAMES, mesh_materials='MLI')
    assert not [str(w.message) for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_a_non_finite_vertex_is_named_as_the_file_writes_it(tmp_path, monkeypatch):
    """The error named the vertex after its node's transform and counted placements: the
    file's vertex (1.0, nan, 0.0), placed twice, was '2 of 6 vertices are not finite,
    first #1: [nan, nan, nan]' (the transform spreads the NaN). It now names the part, the file's index and value; a vertex
    that a node's transform makes non-finite names the node (here with the transform limit
    raised: within +-1e5 a float32 vertex stays finite)."""
    from lidar_sim_ros.core import gltf_check
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], np.float32)
    verts[1, 1] = np.nan
    data = verts.tobytes() + np.array([0, 1, 2], np.uint16).tobytes() + b'\0\0'
    doc = one_buffer_gltf(data, vertex_count=4, nodes=[
        {'mesh': 0, 'name': 'a', 'translation': [0, 0, 3.0]}, {'mesh': 0, 'name': 'b'}])
    with pytest.raises(MeshFileError, match=r"nan.glb: part 'foil' vertex #1 = \[1.0, nan, 0.0\] "
                                            r"is not finite \(1 of its 4 vertices are not\)"):
        load_target(write_glb(tmp_path / 'nan.glb', doc, data), NAMES, mesh_materials='MLI')
    verts[1, 1] = 1e30
    data = verts.tobytes() + np.array([0, 1, 2], np.uint16).tobytes() + b'\0\0'
    doc = one_buffer_gltf(data, vertex_count=4, nodes=[
        {'mesh': 0, 'name': 'stretched', 'scale': [1.0, 1e300, 1.0]}])
    monkeypatch.setattr(gltf_check, 'MAX_TRANSFORM_VALUE', 1e300)
    with pytest.raises(MeshFileError, match=r"big.glb: node 'stretched' places part 'foil' vertex "
                                            r"#1 = \[1.0, 1.00000001504\d*e\+30, 0.0\] at \[1.0, inf, "
                                            r"0.0\], not finite"), np.errstate(over='ignore'):
        load_target(write_glb(tmp_path / 'big.glb', doc, data), NAMES, mesh_materials='MLI')


def _short_buffers(tmp_path):
    """One triangle (44 bytes) in three glTFs whose buffer declares 400 bytes: in a .glb's
    BIN chunk, in an external .bin and in a base64 data: URI."""
    import base64
    import json
    data = triangle_bytes()
    doc = one_buffer_gltf(data)
    doc['buffers'][0]['byteLength'] = 400
    glb = write_glb(tmp_path / 'short.glb', doc, data)
    (tmp_path / 'short.bin').write_bytes(data)
    external = tmp_path / 'external.gltf'
    external.write_text(json.dumps({**doc, 'buffers': [{'uri': 'short.bin', 'byteLength': 400}]}))
    embedded = tmp_path / 'embedded.gltf'
    uri = 'data:application/octet-stream;base64,' + base64.b64encode(data).decode()
    embedded.write_text(json.dumps({**doc, 'buffers': [{'uri': uri, 'byteLength': 400}]}))
    return {"the .glb's BIN chunk": glb, "file 'short.bin'": external, 'its data: URI': embedded}


def test_a_buffer_shorter_than_its_byte_length_is_refused_naming_it(tmp_path):
    """trimesh refused a buffer shorter than its byteLength only by an assert, which
    ``python -O`` removes: there the .glb below loaded its one triangle, rc 0 (and with an
    accessor past the bytes, "cannot reshape array"). Each of the three kinds of buffer is
    now measured before trimesh reads it, here and in a child under -O."""
    import subprocess
    import sys
    for source, path in _short_buffers(tmp_path).items():
        with pytest.raises(MeshFileError, match=rf'{path.name}: buffers\[0\].byteLength = 400, but '
                                                rf'{source} holds 44 bytes'):
            load_target(path, NAMES, mesh_materials='MLI')
    code = ('import sys\nfrom lidar_sim_ros.core.geometry import load_target, MeshFileError\n'
            'try:\n    load_target(sys.argv[1], ["MLI"], mesh_materials="MLI")\n'
            'except MeshFileError as e:\n    print(e)\nelse:\n    print("loaded")')
    import os
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')])}
    child = subprocess.run([sys.executable, '-O', '-c', code, str(tmp_path / 'short.glb')],
                           capture_output=True, text=True, timeout=120, env=env)
    assert 'byteLength = 400, but the .glb' in child.stdout, child.stdout + child.stderr


def ply_with_comments(path, comments, faces=1, end=True):
    """A binary PLY of one triangle whose header holds ``comments`` 100-byte comment lines
    before its elements; its face element claims ``faces``; ``end``: its end_header line."""
    head = 'ply\nformat binary_little_endian 1.0\n' + f'comment {"x" * 91}\n' * comments
    head += ('element vertex 3\nproperty float x\nproperty float y\nproperty float z\n'
             f'element face {faces}\nproperty list uchar int vertex_indices\n')
    body = triangle_bytes()[:36] + b'\x03' + np.array([0, 1, 2], '<i4').tobytes()
    path.write_bytes((head + ('end_header\n' if end else '')).encode() + body)
    return path


def test_a_ply_header_is_bounded_and_its_counts_are_read_whole(tmp_path, monkeypatch):
    """The header's counts were read from its first 64 kB: behind 1,000 comment lines
    (100 kB) a face count past the limit went unseen until trimesh had read the file,
    and a header that never ends got trimesh's "UnicodeDecodeError ... position 14". A
    header longer than MAX_PLY_HEADER_BYTES, or without end_header, is refused naming the
    file; within it, the counts are checked wherever they stand."""
    from lidar_sim_ros.core import geometry, mesh_files
    assert load_target(ply_with_comments(tmp_path / 'ok.ply', 600), NAMES,
                       mesh_materials='MLI').n_faces == 1       # 60 kB of comments
    for comments, end in ((1000, True), (10_000, True), (3, False)):
        with pytest.raises(MeshFileError, match=r'long.ply: no end_header line in its first '
                                                rf'{mesh_files.MAX_PLY_HEADER_BYTES} bytes'):
            load_target(ply_with_comments(tmp_path / 'long.ply', comments, end=end), NAMES,
                        mesh_materials='MLI')
    monkeypatch.setattr(geometry, 'MAX_TRIANGLES', 1)
    with pytest.raises(MeshFileError, match='many.ply: PLY header says 2 face elements'):
        load_target(ply_with_comments(tmp_path / 'many.ply', 600, faces=2), NAMES,
                    mesh_materials='MLI')


def test_a_buffer_without_uri_outside_a_glb_first_buffer_is_refused(tmp_path):
    """Only a .glb's first buffer may omit its uri (its BIN chunk, glTF 2.0 section
    3.6.1.1): a .gltf's got trimesh's "KeyError: 'uri'", a .glb's second was passed over."""
    import json
    data = triangle_bytes()
    gltf = tmp_path / 'nouri.gltf'
    gltf.write_text(json.dumps(one_buffer_gltf(data)))
    doc = one_buffer_gltf(data)
    doc['buffers'].append({'byteLength': 4})
    for path, i in ((gltf, 0), (write_glb(tmp_path / 'two.glb', doc, data), 1)):
        with pytest.raises(MeshFileError, match=rf'{path.name}: buffers\[{i}\] has no uri'):
            load_target(path, NAMES, mesh_materials='MLI')
