"""A glTF 2.0 document checked against the specification before trimesh reads it.

trimesh reads what it understands and passes over the rest: a node graph with a cycle
stopped it with "Iteration limit exceeded!" (no file named). Each rule here comes from
the glTF 2.0 specification (Khronos, sections cited) or from a bound on what the
simulator may spend; a violation is a ``GltfError`` naming the JSON key and the value,
which ``mesh_files.read_cad`` prefixes with the file.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any


MAX_GLTF_NODES = 100_000
"""Most nodes in a glTF (a CAD assembly of 10,000 parts has ~10,000)."""
MAX_GLTF_DEPTH = 32
"""Deepest node, counting the root as 1 (CAD assemblies nest ~5-15 deep): trimesh's
cost grows as parts x depth (a chain of 1,000 nodes with a mesh each took 2.7 s; of
10,000, more than 200 s)."""


class GltfError(ValueError):
    """A glTF document the simulator does not read: names the JSON key and the problem."""


def gltf_document(path: Path, json_bytes: int) -> dict | None:
    """The parsed JSON of a .gltf, or of a .glb's JSON chunk (``json_bytes`` long, after
    the 20-byte header: glTF 2.0 section 4.4); None for other files and for what is not a
    JSON object (trimesh then says what it cannot read)."""
    suffix = path.suffix.lower()
    if suffix not in ('.gltf', '.glb') or json_bytes == 0:
        return None
    with open(path, 'rb') as f:
        if suffix == '.glb':
            f.seek(20)
        raw = f.read(json_bytes)
    try:
        doc = json.loads(raw)
    except RecursionError:
        raise GltfError('its JSON is nested too deeply to read') from None
    except ValueError:
        return None
    return doc if isinstance(doc, dict) else None


def check_gltf(doc: dict, max_triangles: int | None = None) -> None:
    """Raise GltfError for the first rule ``doc`` breaks (module docstring); with
    ``max_triangles``, also when its primitives hold more triangles than that."""
    check_extensions(doc)
    check_node_trees(doc)
    check_accessors(doc)
    check_primitives(doc)
    check_layout(doc)
    if max_triangles is not None:
        check_triangle_count(doc, max_triangles)


READ_EXTENSIONS = ('KHR_materials_', 'KHR_texture_', 'EXT_texture_', 'KHR_lights_punctual')
"""Required extensions (prefixes) that leave the geometry alone: a loader must refuse a
file requiring any other it does not implement (glTF 2.0 section 3.12). Compression
(KHR_draco_mesh_compression, EXT_meshopt_compression), quantization and GPU instancing
change what the accessors and nodes mean."""


def check_extensions(doc: dict) -> None:
    """No required extension that changes the geometry (``READ_EXTENSIONS``)."""
    required = doc.get('extensionsRequired', [])
    if not isinstance(required, list):
        raise GltfError('"extensionsRequired" must be a list of names')
    for name in required:
        if not isinstance(name, str) or not name.startswith(READ_EXTENSIONS):
            raise GltfError(f'extensionsRequired: {str(name)[:60]} is not read (it changes the '
                            'geometry: export without compression or instancing)')


def check_accessors(doc: dict) -> None:
    """Accessors trimesh reads as written: each in a bufferView (without one its values
    are zeros, or a compression extension's: trimesh allocated count x size bytes of
    zeros, 24 GiB for a 2^31 count in a 1 kB file, and a compressed part became zeros
    that the zero-area test then dropped without a word), none sparse (section
    3.6.2.3; trimesh reads the base values and drops the substitutions)."""
    for i, accessor in enumerate(_list(doc, 'accessors')):
        if 'sparse' in accessor:
            raise GltfError(f'accessors[{i}].sparse: sparse accessors are not read (their '
                            'substituted values would be lost); export without them')
        if 'bufferView' not in accessor:
            raise GltfError(f'accessors[{i}] has no bufferView (its values would be zeros, or '
                            'a compression extension\'s, which is not read)')


TRIANGLE_MODES = {4: 'TRIANGLES', 5: 'TRIANGLE_STRIP'}
"""Primitive modes read as surfaces (glTF 2.0 section 3.7.2.1); points and lines (0-3) have
no area and are passed over; TRIANGLE_FAN (6) trimesh drops, so it is refused."""


def check_primitives(doc: dict) -> None:
    """Every primitive's mode is one of the spec's, and not a fan (trimesh dropped fans
    without a word: a part missing from the target); its POSITION, indices and material
    name existing accessors and materials."""
    n_accessors, n_materials = len(_list(doc, 'accessors')), len(_list(doc, 'materials'))
    for m, mesh in enumerate(_list(doc, 'meshes')):
        primitives = mesh.get('primitives')
        if not isinstance(primitives, list) or not primitives \
                or not all(isinstance(p, dict) for p in primitives):
            raise GltfError(f'meshes[{m}].primitives must be a non-empty list of objects')
        for k, prim in enumerate(primitives):
            key = f'meshes[{m}].primitives[{k}]'
            mode = prim.get('mode', 4)
            if isinstance(mode, bool) or mode not in range(7):
                raise GltfError(f'{key}.mode = {str(mode)[:40]} is not a glTF primitive mode (0-6)')
            if mode == 6:
                raise GltfError(f'{key}.mode = 6 (TRIANGLE_FAN) is not read; export triangles '
                                '(mode 4)')
            attributes = prim.get('attributes')
            if not isinstance(attributes, dict) or 'POSITION' not in attributes:
                raise GltfError(f'{key}.attributes has no POSITION')
            _index(attributes['POSITION'], n_accessors, f'{key}.attributes.POSITION', 'accessors')
            if 'indices' in prim:
                _index(prim['indices'], n_accessors, f'{key}.indices', 'accessors')
            if 'material' in prim:
                _index(prim['material'], n_materials, f'{key}.material', 'materials')


COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
"""Bytes of each accessor componentType (glTF 2.0 section 3.6.2.2)."""
TYPE_COMPONENTS = {'SCALAR': 1, 'VEC2': 2, 'VEC3': 3, 'VEC4': 4, 'MAT2': 4, 'MAT3': 9, 'MAT4': 16}


def check_layout(doc: dict) -> None:
    """Where the bytes are (glTF 2.0 sections 3.6.2.4 and 3.6.1): every bufferView inside
    its buffer, every accessor inside its bufferView, strides of 4-252 bytes (a multiple
    of 4) no shorter than an element, offsets and lengths whole non-negative numbers (a
    negative byteOffset made trimesh read from the buffer's end; a 4-byte stride over
    12-byte vertices read overlapping garbage: both rc 0); POSITION float VEC3 and
    indices unsigned SCALAR (section 3.7.2.1: an int16 POSITION was read unscaled); node
    matrices affine (section 3.5.3: a projective last row was dropped)."""
    buffers, views = _list(doc, 'buffers'), _list(doc, 'bufferViews')
    accessors = _list(doc, 'accessors')
    for i, buffer in enumerate(buffers):
        _count(buffer.get('byteLength'), f'buffers[{i}].byteLength', 1)
    for i, view in enumerate(views):
        key = f'bufferViews[{i}]'
        b = _index(view.get('buffer'), len(buffers), f'{key}.buffer', 'buffers')
        start = _count(view.get('byteOffset', 0), f'{key}.byteOffset', 0)
        length = _count(view.get('byteLength'), f'{key}.byteLength', 1)
        if start + length > buffers[b]['byteLength']:
            raise GltfError(f'{key}: bytes {start}..{start + length} lie outside buffer {b} '
                            f'({buffers[b]["byteLength"]} bytes)')
        if 'byteStride' in view:
            stride = _count(view['byteStride'], f'{key}.byteStride', 4)
            if stride > 252 or stride % 4:
                raise GltfError(f'{key}.byteStride = {stride} is not a multiple of 4 in 4..252')
    for i, accessor in enumerate(accessors):
        key = f'accessors[{i}]'
        size = COMPONENT_BYTES.get(accessor.get('componentType'))
        parts = TYPE_COMPONENTS.get(accessor.get('type'))
        if size is None or parts is None:
            raise GltfError(f'{key}: componentType {str(accessor.get("componentType"))[:20]} / '
                            f'type {str(accessor.get("type"))[:20]} is not a glTF 2.0 accessor layout')
        count = _count(accessor.get('count'), f'{key}.count', 1)
        v = _index(accessor['bufferView'], len(views), f'{key}.bufferView', 'bufferViews')
        offset = _count(accessor.get('byteOffset', 0), f'{key}.byteOffset', 0)
        element = size * parts
        stride = views[v].get('byteStride', element)
        if stride < element:
            raise GltfError(f'bufferViews[{v}].byteStride = {stride} is shorter than an element '
                            f'of {key} ({element} bytes)')
        end = offset + stride * (count - 1) + element
        if end > views[v]['byteLength']:
            raise GltfError(f'{key}: {count} elements of {element} bytes (stride {stride}) from '
                            f'byte {offset} end at {end}, past bufferView {v} '
                            f'({views[v]["byteLength"]} bytes)')
    for m, mesh in enumerate(_list(doc, 'meshes')):
        for k, prim in enumerate(mesh['primitives']):
            a = accessors[prim['attributes']['POSITION']]
            if (a['componentType'], a['type']) != (5126, 'VEC3'):
                raise GltfError(f'meshes[{m}].primitives[{k}].attributes.POSITION: accessor '
                                f'{prim["attributes"]["POSITION"]} is {a["type"]} of componentType '
                                f'{a["componentType"]}, not float VEC3 (5126)')
            if 'indices' in prim:
                a = accessors[prim['indices']]
                if a['type'] != 'SCALAR' or a['componentType'] not in (5121, 5123, 5125):
                    raise GltfError(f'meshes[{m}].primitives[{k}].indices: accessor '
                                    f'{prim["indices"]} is {a["type"]} of componentType '
                                    f'{a["componentType"]}, not unsigned SCALAR')
    for i, node in enumerate(_list(doc, 'nodes')):
        _check_transform(node, f'nodes[{i}]')


def check_triangle_count(doc: dict, max_triangles: int) -> None:
    """The triangles the meshes' primitives hold (each placed once; placements are counted
    as they are read), from the accessors' counts, within ``max_triangles`` before trimesh
    reads them: a .glb near 2 GB could hold 160 M triangles, read whole before the count."""
    accessors, total = doc.get('accessors', []), 0
    for mesh in doc.get('meshes', []):
        for prim in mesh['primitives']:
            mode = prim.get('mode', 4)
            if mode not in TRIANGLE_MODES:
                continue
            counted = prim['indices'] if 'indices' in prim else prim['attributes']['POSITION']
            n = accessors[counted]['count']
            total += n // 3 if mode == 4 else max(n - 2, 0)
    if total > max_triangles:
        raise GltfError(f'its primitives hold {total} triangles, more than the limit of {max_triangles}')


def _count(value: Any, key: str, least: int) -> int:
    """``value`` if it is a whole number of at least ``least``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise GltfError(f'{key} = {str(value)[:40]} is not a whole number >= {least}')
    return value


MAX_TRANSFORM_VALUE = 1.0e5
"""Largest number in a node's matrix, translation, rotation or scale (a vertex beyond 1e5 m
is refused anyway: geometry.MAX_VERTEX_M); a 1e300 scale made trimesh print numpy's
overflow warnings over the one-line error."""


def _check_transform(node: dict, key: str) -> None:
    """A node's matrix (16 numbers, column-major, last row 0 0 0 1) or TRS (3, 4, 3 numbers)."""
    for name, length in (('matrix', 16), ('translation', 3), ('rotation', 4), ('scale', 3)):
        if name not in node:
            continue
        value = node[name]
        if not isinstance(value, list) or len(value) != length or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
            raise GltfError(f'{key}.{name} must be a list of {length} numbers, not {str(value)[:60]}')
        if not all(abs(x) <= MAX_TRANSFORM_VALUE for x in value):   # NaN fails too
            raise GltfError(f'{key}.{name} = {str(value)[:80]}: every number must be finite and '
                            f'within +-{MAX_TRANSFORM_VALUE:g}')
    matrix = node.get('matrix')
    if matrix is not None and [matrix[3], matrix[7], matrix[11], matrix[15]] != [0, 0, 0, 1]:
        raise GltfError(f'{key}.matrix: its last row {[matrix[3], matrix[7], matrix[11], matrix[15]]} '
                        'is not 0 0 0 1 (a glTF node matrix is affine: translation, rotation, scale)')


def _list(doc: dict, key: str) -> list[dict]:
    value = doc.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise GltfError(f'"{key}" must be a list of objects')
    return value


def _index(value: Any, count: int, key: str, of: str) -> int:
    """``value`` if it is an index into ``count`` items (``of``: what they are)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < count:
        raise GltfError(f'{key} = {str(value)[:40]} is not an index of the {count} {of}')
    return value


def check_node_trees(doc: dict) -> None:
    """Nodes form disjoint strict trees (glTF 2.0 section 3.5.3: no node has two parents,
    none is its own ancestor), the scene's roots are roots, and every index names an
    existing node or mesh (a node naming a missing mesh was dropped without a word)."""
    nodes, meshes, scenes = _list(doc, 'nodes'), _list(doc, 'meshes'), _list(doc, 'scenes')
    if len(nodes) > MAX_GLTF_NODES:
        raise GltfError(f'{len(nodes)} nodes exceed the limit of {MAX_GLTF_NODES}')
    parent = [-1] * len(nodes)
    for i, node in enumerate(nodes):
        if 'mesh' in node:
            _index(node['mesh'], len(meshes), f'nodes[{i}].mesh', 'meshes')
        children = node.get('children', [])
        if not isinstance(children, list):
            raise GltfError(f'nodes[{i}].children must be a list of node indices')
        for child in children:
            _index(child, len(nodes), f'nodes[{i}].children', 'nodes')
            if child == i or parent[child] != -1:
                raise GltfError(f'nodes[{i}].children: node {child} is already a child of node '
                                f'{i if child == i else parent[child]} (glTF node trees are '
                                'disjoint strict trees: one parent per node, no cycle)')
            parent[child] = i
    depth = _depths([i for i, p in enumerate(parent) if p == -1], nodes)
    if len(depth) < len(nodes):
        first = min(set(range(len(nodes))) - set(depth))
        raise GltfError(f'nodes[{first}] is its own ancestor (the node graph has a cycle)')
    deepest = max(depth, key=depth.get, default=None)
    if deepest is not None and depth[deepest] > MAX_GLTF_DEPTH:
        raise GltfError(f'nodes[{deepest}] is nested {depth[deepest]} deep, beyond the limit of '
                        f'{MAX_GLTF_DEPTH} (flatten the assembly)')
    if scenes:
        chosen = _index(doc.get('scene', 0), len(scenes), 'scene', 'scenes')
        roots = scenes[chosen].get('nodes', [])
        if not isinstance(roots, list):
            raise GltfError(f'scenes[{chosen}].nodes must be a list of node indices')
        for root in roots:
            if parent[_index(root, len(nodes), f'scenes[{chosen}].nodes', 'nodes')] != -1:
                raise GltfError(f'scenes[{chosen}].nodes: node {root} is a child of node '
                                f'{parent[root]}, not a root (glTF 2.0 section 3.5.2)')


def _depths(roots: list[int], nodes: list[dict]) -> dict[int, int]:
    """Depth (root: 1) of every node below ``roots`` (iteratively: no recursion limit)."""
    depth, stack = dict.fromkeys(roots, 1), list(roots)
    while stack:
        node = stack.pop()
        for child in nodes[node].get('children', []):
            if child not in depth:
                depth[child] = depth[node] + 1
                stack.append(child)
    return depth
