"""A glTF document against the specification before trimesh reads it (core/gltf_check.py):
each rule with a document that breaks it, the error naming the file, the key and the value."""
import copy

import numpy as np
import pytest

from lidar_sim_ros.core.geometry import MeshFileError, load_target
from lidar_sim_ros.core.gltf_check import GltfError, check_gltf
from test_mesh_files import NAMES, one_buffer_gltf, triangle_bytes, write_glb

DATA = triangle_bytes()
DOC = one_buffer_gltf(DATA)


def changed(**nodes_and_scene):
    doc = copy.deepcopy(DOC)
    doc.update(nodes_and_scene)
    return doc


def test_the_reference_document_passes_and_loads(tmp_path):
    check_gltf(DOC)
    assert load_target(write_glb(tmp_path / 'ok.glb', DOC, DATA), NAMES, mesh_materials='MLI').n_faces == 1


@pytest.mark.parametrize('nodes, words', [
    ([{'mesh': 0, 'name': 'a', 'children': [1]}, {'name': 'b', 'children': [0]}],
     'nodes\\[1\\].children: node 0 is already a child of node 0|is its own ancestor'),
    ([{'mesh': 0, 'name': 'a', 'children': [0]}], 'node 0 is already a child of node 0'),
    ([{'mesh': 0, 'name': 'a', 'children': [2]}, {'name': 'b', 'children': [2]}, {'mesh': 0}],
     'nodes\\[1\\].children: node 2 is already a child of node 0'),
    ([{'mesh': 0, 'name': 'a', 'children': [9]}], 'nodes\\[0\\].children = 9 is not an index of the 1 nodes'),
    ([{'mesh': 5, 'name': 'a'}], 'nodes\\[0\\].mesh = 5 is not an index of the 1 meshes'),
    ([{'mesh': 0, 'name': 'a', 'children': [True]}], 'children = True is not an index'),
])
def test_node_graphs_that_are_not_disjoint_trees_are_refused(tmp_path, nodes, words):
    """A cycle stopped trimesh with "ValueError: Iteration limit exceeded!" (no file named)
    or was read once round; a node with two parents, or naming a missing mesh, was read
    as trimesh guessed (the part dropped without a word). glTF 2.0 section 3.5.3."""
    doc = changed(nodes=nodes)
    with pytest.raises(GltfError, match=words):
        check_gltf(doc)
    with pytest.raises(MeshFileError, match=r'graph.glb: nodes\[') as err:
        load_target(write_glb(tmp_path / 'graph.glb', doc, DATA), NAMES, mesh_materials='MLI')
    assert '\n' not in str(err.value)


def test_a_two_node_cycle_below_a_root_is_found():
    nodes = [{'mesh': 0, 'children': [1]}, {'children': [2]}, {'children': [1]}]
    with pytest.raises(GltfError, match='node 1 is already a child of node 0'):
        check_gltf(changed(nodes=nodes))
    # Unreachable from any root: a cycle on its own.
    nodes = [{'mesh': 0}, {'children': [2]}, {'children': [1]}]
    with pytest.raises(GltfError, match=r'nodes\[1\] is its own ancestor'):
        check_gltf(changed(nodes=nodes))


def test_scene_roots_must_be_roots_and_exist():
    nodes = [{'children': [1]}, {'mesh': 0}]
    with pytest.raises(GltfError, match=r'scenes\[0\].nodes: node 1 is a child of node 0'):
        check_gltf(changed(nodes=nodes, scenes=[{'nodes': [0, 1]}]))
    with pytest.raises(GltfError, match='scene = 3 is not an index of the 1 scenes'):
        check_gltf(changed(scene=3))


def chain(n):
    """n nodes, each the only child of the one before, a mesh on each."""
    return [{'mesh': 0, 'name': f'n{i}', **({'children': [i + 1]} if i + 1 < n else {})}
            for i in range(n)]


def test_nesting_deeper_than_the_limit_is_refused(tmp_path):
    """trimesh's cost grows as parts x depth: a chain of 10,000 nodes with a mesh on each
    (a 1 MB file) ran more than 200 s; 10^6 nodes deep, days."""
    from lidar_sim_ros.core.gltf_check import MAX_GLTF_DEPTH
    doc = changed(nodes=chain(MAX_GLTF_DEPTH))
    check_gltf(doc)
    t = load_target(write_glb(tmp_path / 'deep.glb', doc, DATA), NAMES, mesh_materials='MLI')
    assert t.n_faces == MAX_GLTF_DEPTH
    with pytest.raises(GltfError, match=rf'nodes\[{MAX_GLTF_DEPTH}\] is nested {MAX_GLTF_DEPTH + 1} '
                                        rf'deep, beyond the limit of {MAX_GLTF_DEPTH}'):
        check_gltf(changed(nodes=chain(MAX_GLTF_DEPTH + 1)))
    with pytest.raises(MeshFileError, match='deeper.glb: nodes.* deep'):
        load_target(write_glb(tmp_path / 'deeper.glb', changed(nodes=chain(10_000)), DATA),
                    NAMES, mesh_materials='MLI')


def test_more_nodes_than_the_limit_are_refused(monkeypatch):
    from lidar_sim_ros.core import gltf_check
    monkeypatch.setattr(gltf_check, 'MAX_GLTF_NODES', 3)
    check_gltf(changed(nodes=[{'mesh': 0}] * 3, scenes=[{'nodes': [0, 1, 2]}]))
    with pytest.raises(GltfError, match='4 nodes exceed the limit of 3'):
        check_gltf(changed(nodes=[{'mesh': 0}] * 4, scenes=[{'nodes': [0, 1, 2, 3]}]))


def test_sparse_accessors_are_refused(tmp_path):
    """A sparse accessor moving vertex 1 from (1, 0, 0) to (5, 0, 0) (glTF 2.0 section
    3.6.2.3) loaded with the vertex at (1, 0, 0): trimesh reads the base values and drops
    the substitutions, so the part had the wrong shape and rc 0."""
    data = DATA + np.array([1], np.uint16).tobytes() + b'\0\0' + np.array([5, 0, 0], np.float32).tobytes()
    doc = one_buffer_gltf(data)
    doc['bufferViews'] += [{'buffer': 0, 'byteOffset': 44, 'byteLength': 2},
                           {'buffer': 0, 'byteOffset': 48, 'byteLength': 12}]
    doc['accessors'][0]['sparse'] = {'count': 1, 'indices': {'bufferView': 2, 'componentType': 5123},
                                     'values': {'bufferView': 3}}
    with pytest.raises(MeshFileError, match=r'sparse.glb: accessors\[0\].sparse: sparse accessors '
                                            'are not read'):
        load_target(write_glb(tmp_path / 'sparse.glb', doc, data), NAMES, mesh_materials='MLI')


def test_triangle_fans_and_unknown_modes_are_refused(tmp_path):
    """Two parts, the second a TRIANGLE_FAN (mode 6, glTF 2.0 section 3.7.2.1): it loaded
    as one triangle, the fan dropped without a word (rc 0, half the target missing)."""
    doc = copy.deepcopy(DOC)
    doc['meshes'].append({'primitives': [{'attributes': {'POSITION': 0}, 'indices': 1,
                                          'material': 0, 'mode': 6}]})
    doc['nodes'].append({'mesh': 1, 'name': 'fan', 'translation': [0, 0, 5]})
    doc['scenes'][0]['nodes'].append(1)
    with pytest.raises(MeshFileError, match=r'fan.glb: meshes\[1\].primitives\[0\].mode = 6 '
                                            r'\(TRIANGLE_FAN\) is not read'):
        load_target(write_glb(tmp_path / 'fan.glb', doc, DATA), NAMES, mesh_materials='MLI')
    for mode, words in ((7, 'mode = 7 is not a glTF primitive mode'), ('4', "mode = 4 is not"),
                        (True, 'mode = True is not')):
        doc['meshes'][1]['primitives'][0]['mode'] = mode
        with pytest.raises(GltfError, match=words):
            check_gltf(doc)
    doc['meshes'][1]['primitives'][0]['mode'] = 5      # a strip is read (trimesh: strip -> triangles)
    check_gltf(doc)


@pytest.mark.parametrize('primitive, words', [
    ({'attributes': {}}, 'attributes has no POSITION'),
    ({'attributes': {'POSITION': 7}}, r'attributes.POSITION = 7 is not an index of the 2 accessors'),
    ({'attributes': {'POSITION': 0}, 'indices': -1}, r'indices = -1 is not an index'),
    ({'attributes': {'POSITION': 0}, 'material': 3}, r'material = 3 is not an index of the 1 materials'),
])
def test_primitives_naming_missing_accessors_or_materials_are_refused(primitive, words):
    doc = copy.deepcopy(DOC)
    doc['meshes'][0]['primitives'] = [primitive]
    with pytest.raises(GltfError, match=r'meshes\[0\].primitives\[0\].' + words):
        check_gltf(doc)


def test_accessors_without_a_buffer_view_are_refused(tmp_path):
    """An accessor without a bufferView holds zeros (or a compression extension's values):
    a second part so stored loaded as the first alone (its zero-area triangles dropped,
    rc 0), and a 2^31 count in a 1 kB file made trimesh allocate 24 GiB of zeros."""
    doc = copy.deepcopy(DOC)
    doc['accessors'].append({'componentType': 5126, 'count': 3, 'type': 'VEC3'})
    doc['meshes'].append({'primitives': [{'attributes': {'POSITION': 2}, 'material': 0}]})
    doc['nodes'].append({'mesh': 1, 'name': 'packed'})
    doc['scenes'][0]['nodes'].append(1)
    with pytest.raises(MeshFileError, match=r'zeros.glb: accessors\[2\] has no bufferView'):
        load_target(write_glb(tmp_path / 'zeros.glb', doc, DATA), NAMES, mesh_materials='MLI')
    doc['accessors'][2]['count'] = 2 ** 31
    with pytest.raises(GltfError, match=r'accessors\[2\] has no bufferView'):
        check_gltf(doc)


@pytest.mark.parametrize('name', ['KHR_draco_mesh_compression', 'EXT_meshopt_compression',
                                  'KHR_mesh_quantization', 'EXT_mesh_gpu_instancing', 7])
def test_required_extensions_that_change_the_geometry_are_refused(name):
    """A loader must refuse a file requiring an extension it does not implement (glTF 2.0
    section 3.12); materials and textures do not change the geometry."""
    with pytest.raises(GltfError, match=f'extensionsRequired: {name} is not read'):
        check_gltf(changed(extensionsRequired=[name]))
    check_gltf(changed(extensionsRequired=['KHR_materials_emissive_strength', 'KHR_texture_transform']))


def test_a_negative_buffer_view_offset_is_refused(tmp_path):
    """byteOffset -44 of a 44-byte buffer: trimesh sliced from the buffer's end (Python
    indexing) and loaded whatever lay there, rc 0."""
    doc = copy.deepcopy(DOC)
    doc['bufferViews'][0]['byteOffset'] = -44
    with pytest.raises(MeshFileError, match=r'negative.glb: bufferViews\[0\].byteOffset = -44 is '
                                            'not a whole number >= 0'):
        load_target(write_glb(tmp_path / 'negative.glb', doc, DATA), NAMES, mesh_materials='MLI')


def test_a_stride_shorter_than_a_vertex_is_refused(tmp_path):
    """byteStride 4 over 12-byte vertices: trimesh read 7 overlapping 'vertices' out of 36
    bytes, a triangle of garbage, rc 0 (glTF 2.0 section 3.6.2.4)."""
    doc = copy.deepcopy(DOC)
    doc['bufferViews'][0]['byteStride'] = 4
    doc['accessors'][0]['count'] = 7
    with pytest.raises(MeshFileError, match=r'stride.glb: bufferViews\[0\].byteStride = 4 is '
                                            r'shorter than an element of accessors\[0\] \(12 bytes\)'):
        load_target(write_glb(tmp_path / 'stride.glb', doc, DATA), NAMES, mesh_materials='MLI')


def test_a_projective_node_matrix_is_refused(tmp_path):
    """A matrix whose last row is not 0 0 0 1 loaded with that row dropped, rc 0."""
    doc = changed(nodes=[{'mesh': 0, 'name': 'p',
                          'matrix': [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0.5, 0, 0, 0, 1]}])
    with pytest.raises(MeshFileError, match=r'proj.glb: nodes\[0\].matrix: its last row '
                                            r'\[0, 0, 0.5, 1\] is not 0 0 0 1'):
        load_target(write_glb(tmp_path / 'proj.glb', doc, DATA), NAMES, mesh_materials='MLI')


@pytest.mark.parametrize('change, words', [
    (lambda d: d['accessors'][0].update(count=2 ** 31), r'accessors\[0\]: 2147483648 elements of 12 '
                                                          r'bytes .* past bufferView 0 \(36 bytes\)'),
    (lambda d: d['accessors'][0].update(byteOffset=4), r'accessors\[0\]: 3 elements .* end at 40, past'),
    (lambda d: d['bufferViews'][1].update(byteLength=100), r'bufferViews\[1\]: bytes 36..136 lie '
                                                             r'outside buffer 0 \(44 bytes\)'),
    (lambda d: d['bufferViews'][0].update(byteStride=14), r'byteStride = 14 is not a multiple of 4'),
    (lambda d: d['bufferViews'][0].update(byteStride=256), r'byteStride = 256 is not a multiple of 4'),
    (lambda d: d['accessors'][0].update(componentType=5122), r'POSITION: accessor 0 is VEC3 of '
                                                               r'componentType 5122, not float VEC3'),
    (lambda d: d['accessors'][1].update(componentType=5126, count=1), r'indices: accessor 1 is SCALAR of '
                                                               r'componentType 5126, not unsigned'),
    (lambda d: d['accessors'][0].update(componentType=9999), r'componentType 9999 / type VEC3 is not'),
    (lambda d: d['accessors'][0].update(count=0), r'accessors\[0\].count = 0 is not a whole number >= 1'),
    (lambda d: d['accessors'][0].update(count=3.0), r'accessors\[0\].count = 3.0 is not a whole number'),
    (lambda d: d['buffers'][0].update(byteLength='44'), r'buffers\[0\].byteLength = 44 is not'),
    (lambda d: d['nodes'][0].update(scale=[1, 1]), r'nodes\[0\].scale must be a list of 3 numbers'),
    (lambda d: d['nodes'][0].update(rotation=[0, 0, 0, None]), r'rotation must be a list of 4 numbers'),
])
def test_layouts_outside_the_specification_are_refused(change, words):
    doc = copy.deepcopy(DOC)
    change(doc)
    with pytest.raises(GltfError, match=words):
        check_gltf(doc)


@pytest.mark.parametrize('name, value', [('scale', [1e300, 1, 1]), ('translation', [0, float('nan'), 0]),
                                         ('rotation', [0, 0, 0, float('inf')])])
def test_node_transforms_beyond_the_limit_are_refused_naming_the_node(tmp_path, recwarn, name, value):
    """A 1e300 scale reached the vertex limit only after trimesh printed numpy's overflow
    warnings (two lines above the error); the node's number is now named, alone."""
    doc = changed(nodes=[{'mesh': 0, 'name': 'p', name: value}])
    with pytest.raises(MeshFileError, match=rf'huge.glb: nodes\[0\].{name} = .*every number must be '
                                            'finite and within'):
        load_target(write_glb(tmp_path / 'huge.glb', doc, DATA), NAMES, mesh_materials='MLI')
    assert not [str(w.message) for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_triangles_beyond_the_limit_are_refused_before_trimesh_reads_them(tmp_path, monkeypatch):
    """The triangle limit was checked once trimesh had read every accessor (a .glb near 2 GB
    could hold 160 M triangles); the accessors' counts say it first."""
    import trimesh
    import lidar_sim_ros.core.geometry as geometry
    doc = copy.deepcopy(DOC)
    doc['meshes'].append({'primitives': [{'attributes': {'POSITION': 0}, 'mode': 5}]})  # a strip: 1
    doc['nodes'].append({'mesh': 1})
    doc['scenes'][0]['nodes'].append(1)
    path = write_glb(tmp_path / 'two.glb', doc, DATA)
    assert load_target(path, NAMES, mesh_materials='MLI').n_faces == 2
    monkeypatch.setattr(geometry, 'MAX_TRIANGLES', 1)
    monkeypatch.setattr(trimesh, 'load', lambda *a, **k: pytest.fail('trimesh read the file'))
    with pytest.raises(MeshFileError, match='two.glb: its primitives hold 2 triangles, more than '
                                            'the limit of 1'):
        load_target(path, NAMES, mesh_materials='MLI')
    check_gltf(doc)                                     # no limit given: no count


def test_json_nested_too_deeply_is_refused_in_one_line(tmp_path):
    """10^5 nested arrays in a .gltf's extras: Python's JSON parser's RecursionError."""
    import json
    text = json.dumps(DOC)[:-1] + ', "extras": ' + '[' * 100_000 + ']' * 100_000 + '}'
    path = tmp_path / 'deep.gltf'
    path.write_text(text)
    with pytest.raises(MeshFileError, match='deep.gltf: its JSON is nested too deeply to read'):
        load_target(path, NAMES, mesh_materials='MLI')
