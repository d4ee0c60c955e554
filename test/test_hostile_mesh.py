"""Hostile meshes (issue 22, part 2): non-finite vertices and meshes without area are
refused naming the file; zero-area faces (no ray can hit them) are removed."""
import re

import numpy as np
import pytest

from lidar_sim_ros.core.geometry import MeshFileError, load_target

HEAD = 'usemtl PIF\n'
SQUARE = 'v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n'


def obj(tmp_path, text):
    path = tmp_path / 'm.obj'
    path.write_text(HEAD + text)
    return path


@pytest.mark.parametrize('v', ['1 nan 0', '1 0 -INF', '1e400 0 0'])
def test_non_finite_vertex_is_refused_naming_it(tmp_path, v):
    """Named as the file writes it: its number as 'f' lines count (from 1), its line and
    text. The error named the vertex trimesh had regrouped per material ('first #2', a
    0-based index of another list) and its parsed value."""
    path = obj(tmp_path, f'v 0 0 0\nv 1 0 0\nv {v}\nv 0 1 0\nf 1 2 3\nf 1 3 4\n')
    with pytest.raises(MeshFileError, match=rf'm.obj: vertex 3 \(line 4: "v {v}"\) is not finite'):
        load_target(path, ['PIF'])
    ok = load_target(obj(tmp_path, 'v 0 0 0\nv 1E+002 0 0\nv 0 1 0\nf 1 2 3\n'), ['PIF'])
    assert ok.vertices_m.max() == 100.0        # a finite exponent passes


def test_zero_area_mesh_is_refused(tmp_path):
    path = obj(tmp_path, 'v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n')
    with pytest.raises(MeshFileError, match='all 2 triangles have zero area'):
        load_target(path, ['PIF'])


def test_zero_area_faces_are_removed_and_the_rest_kept(tmp_path):
    # Two unit-square halves plus a sliver with a repeated vertex.
    target = load_target(obj(tmp_path, SQUARE + 'f 1 2 3\nf 1 3 4\nf 1 2 2\n'), ['PIF'])
    assert target.n_faces == 2
    # Its area is the square's: 1 m^2 (hand calculation).
    tri = target.vertices_m[target.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(1.0)


def test_triangle_count_is_limited(tmp_path, monkeypatch):
    import lidar_sim_ros.core.geometry as geometry
    monkeypatch.setattr(geometry, 'MAX_TRIANGLES', 1)
    with pytest.raises(MeshFileError, match='2 faces exceed the limit of 1 triangles'):
        load_target(obj(tmp_path, SQUARE + 'f 1 2 3\nf 1 3 4\n'), ['PIF'])


@pytest.mark.parametrize('mtllib', ['../outside.mtl', '{outside}'])
def test_an_obj_material_library_out_of_its_folder_is_not_read(tmp_path, mtllib):
    """An OBJ's mtllib is read from the mesh's own folder only (as a glTF's buffers are):
    '../x.mtl' or an absolute path once had its file read to decide the material names."""
    outside = tmp_path / 'outside.mtl'
    outside.write_text('newmtl PIF\n')
    (tmp_path / 'inner').mkdir()
    obj = tmp_path / 'inner' / 'm.obj'
    obj.write_text(f'mtllib {mtllib.format(outside=outside)}\nv 0 0 0\nv 1 0 0\nv 0 1 0\n'
                   'usemtl PIF\nf 1 2 3\n')
    with pytest.raises(MeshFileError, match='is not beside the mesh'):
        load_target(obj, ['PIF', 'MLI'])


@pytest.mark.parametrize('x', ['1e300', '-2e5', '123456.5', '1E+06', '-1.0000001e+5'])
def test_vertex_beyond_the_size_limit_is_refused_naming_it(tmp_path, x):
    """1e300 m is finite in float64 but overflowed the zero-area test (OverflowError, a
    traceback from lidar-sim simulate) and is inf in Embree's float32; any vertex past
    MAX_VERTEX_M (100 km, far beyond any target; a millimetre CAD export of a 10 m
    satellite reaches 1e4) is refused naming it as the file writes it (its number as 'f'
    lines count, its line and text, as a non-finite one), not as trimesh regrouped it
    ('vertex #1 [1e+300, 0.0, 0.0]'). 1e5 itself, and digits after the point, pass."""
    import lidar_sim_ros.core.geometry as geometry
    path = obj(tmp_path, f'v 0 0 0\nv 0 0 1\nv 0 1 0\nv {x} 0 0\nf 1 2 3\nf 1 4 3\n')
    beyond = (rf'm.obj: vertex 4 \(line 5: "v {re.escape(x)} 0 0"\) is beyond the limit of '
              rf'{geometry.MAX_VERTEX_M:g} m on an axis \(is the file in metres\?\)$')
    if float(x) == -1e5:
        assert load_target(path, ['PIF']).n_faces == 2
        return
    with pytest.raises(MeshFileError, match=beyond) as err:
        load_target(path, ['PIF'])
    assert '\n' not in str(err.value)
    for fine in ('1e4', '1E+005', '-100000', '0.1234567', '99999.999999'):
        ok = load_target(obj(tmp_path, f'v 0 0 0\nv {fine} 0 0\nv 0 1 0\nf 1 2 3\n'), ['PIF'])
        assert ok.vertices_m[:, 0].min() == min(0.0, float(fine))


def test_a_cad_vertex_beyond_the_size_limit_is_named_as_the_file_writes_it(tmp_path):
    """A glTF part's vertex that its node places beyond MAX_VERTEX_M: the error named the
    placed value alone ('vertex #1 [2000000.0, 0.0, 3.0]', the index of the target's
    vertices, not the file's); it now names the node, the part, the file's index and value
    and where the node puts it. A vertex beyond the limit as written is named the same way."""
    from test_mesh_files import one_buffer_gltf, write_glb
    verts = np.array([[0, 0, 0], [2e4, 0, 0], [0, 1, 0]], np.float32)
    data = verts.tobytes() + np.array([0, 1, 2], np.uint16).tobytes() + b'\0\0'
    doc = one_buffer_gltf(data, nodes=[{'mesh': 0, 'name': 'mm', 'scale': [100.0, 1.0, 1.0],
                                        'translation': [0.0, 0.0, 3.0]}])
    with pytest.raises(MeshFileError, match=r"far.glb: node 'mm' places part 'foil' vertex #1 = "
                                            r"\[20000.0, 0.0, 0.0\] at \[2000000.0, 0.0, 3.0\] "
                                            r"\(m\), beyond the limit of 100000 m \(1 of its 3 "
                                            r"vertices are; is the file in metres\?\)$"):
        load_target(write_glb(tmp_path / 'far.glb', doc, data), ['foil'])
    verts[2, 1] = -3e5
    data = verts.tobytes() + np.array([0, 1, 2], np.uint16).tobytes() + b'\0\0'
    doc = one_buffer_gltf(data, nodes=[{'mesh': 0, 'name': 'plain'}])
    with pytest.raises(MeshFileError, match=r"far2.glb: node 'plain' places part 'foil' vertex #2 "
                                            r"= \[0.0, -300000.0, 0.0\] at \[0.0, -300000.0, 0.0\]"):
        load_target(write_glb(tmp_path / 'far2.glb', doc, data), ['foil'])


def test_links_in_the_mesh_folder(tmp_path):
    """What a link in the mesh's folder can reach (model.md): an OBJ's mtllib or a glTF's
    buffer that is a symbolic link (or sits below a linked folder) resolving out of the
    mesh's real folder is refused naming it; a texture so linked is dropped unread (the
    simulator uses none). A hard link is a name of the folder like any other file (no
    system call tells the 'original' name): it is read, so whoever may write into the
    mesh's folder decides what the mesh reads."""
    import json
    import os
    from test_mesh_files import gltf_with_buffer, triangle_bytes
    out, cad = tmp_path / 'outside', tmp_path / 'cad'
    out.mkdir()
    cad.mkdir()
    (out / 'lib.mtl').write_text('newmtl PIF\n')
    (out / 'far.bin').write_bytes(triangle_bytes(scale=7.0))
    os.symlink(out / 'lib.mtl', cad / 'lib.mtl')
    os.symlink(out, cad / 'sub')
    (cad / 'm.obj').write_text('mtllib lib.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl PIF\nf 1 2 3\n')
    with pytest.raises(MeshFileError, match=r"m.obj: mtllib 'lib.mtl' is not beside the mesh"):
        load_target(cad / 'm.obj', ['PIF'])
    (cad / 'm2.obj').write_text('mtllib sub/lib.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl PIF\nf 1 2 3\n')
    with pytest.raises(MeshFileError, match=r"m2.obj: mtllib 'sub/lib.mtl' is not beside the mesh"):
        load_target(cad / 'm2.obj', ['PIF'])
    with pytest.raises(MeshFileError, match=r"b.gltf: external file 'sub/far.bin' leads out of"):
        load_target(gltf_with_buffer(cad / 'b.gltf', 'sub/far.bin'), ['PIF'], mesh_materials='PIF')
    # A texture linked out of the folder: never read, and the mesh loads without it.
    (cad / 'near.bin').write_bytes(triangle_bytes())
    os.symlink(out / 'lib.mtl', cad / 'tex.png')
    doc = json.loads(gltf_with_buffer(cad / 't.gltf', 'near.bin').read_text())
    doc.update(images=[{'uri': 'tex.png'}], textures=[{'source': 0}])
    doc['materials'][0]['pbrMetallicRoughness'] = {'baseColorTexture': {'index': 0}}
    (cad / 't.gltf').write_text(json.dumps(doc))
    assert load_target(cad / 't.gltf', ['PIF'], mesh_materials='PIF').vertices_m.max() == 1.0
    # A hard link is read: the folder's own file as far as any check can tell.
    os.link(out / 'far.bin', cad / 'hard.bin')
    hard = load_target(gltf_with_buffer(cad / 'h.gltf', 'hard.bin'), ['PIF'], mesh_materials='PIF')
    assert hard.vertices_m.max() == pytest.approx(7.0)
