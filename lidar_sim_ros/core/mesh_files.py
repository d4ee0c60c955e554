"""Targets from CAD exports: glTF 2.0 (.gltf, .glb), STL and PLY, read with trimesh.

A CAD export names its parts, not our materials: the scenario's ``mesh_materials`` maps
them. For every mesh placed in the file's scene graph (with its node's transform; glTF
is in metres, STL and PLY are read as metres) the candidate names are, in order, the
mesh's material name, its node's name and the mesh's own name; the first that the map
holds (or, without a map, the first that is itself a config material) gives its
material. A string instead of a map gives one material to the whole file (an STL or
PLY has no material names at all). Parts that no name maps stop the load with one line
naming them.

A glTF's external files (``buffers[].uri``, ``images[].uri``) are read only from the
file's own directory, by ``DirectoryResolver``: an absolute path, ``..`` out of it, a
symbolic link leading out, a URI with a scheme (``file:``, ``http:``) or anything but a
regular file is never read or fetched; for a buffer this stops the load naming the URI
(trimesh drops a texture it cannot read: the simulator uses none). (trimesh before 5.x
joined any such path to the directory and read it: a CAD file from elsewhere could turn
``/etc/passwd``'s bytes into target vertices.) Embedded ``data:`` URIs are trimesh's.
The directory is the one the CAD file resolves to (a linked .gltf reads the .bin beside
its target). A hard link is a regular file of the directory like any other (nothing tells
it apart): it is read.
"""
from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import trimesh
import trimesh.resolvers

from lidar_sim_ros.core.gltf_check import GltfError, check_gltf, gltf_document

CAD_SUFFIXES = ('.gltf', '.glb', '.stl', '.ply')
MAX_MESH_FILE_BYTES = 2_000_000_000
"""Largest CAD file read (a binary STL of MAX_TRIANGLES is 500 MB)."""
MAX_TEXT_MESH_BYTES = 256_000_000
"""Largest text mesh read (OBJ, ASCII STL, ASCII PLY): trimesh's parse takes ~5-12x the
text (measured: ASCII PLY 12x, ASCII STL 7x, OBJ 4.5-10x), so a 2 GB one needed up to
~24 GB. 256 MB holds ~1.3 M triangles of ASCII STL, ~1.7 M of PLY, ~7 M of OBJ; binary
STL and PLY, and glTF, are read up to MAX_MESH_FILE_BYTES."""
MAX_PLY_HEADER_BYTES = 65_536
"""Longest PLY header read (to its end_header line): exporters write a few hundred bytes,
a few kB with comments."""
MAX_EXTERNAL_BYTES = MAX_MESH_FILE_BYTES
"""Largest sum of a glTF's external files (its .bin buffers and images), each read once."""
MAX_VERTEX_M = 1.0e5
"""Farthest vertex from the mesh origin (m, per axis): no target is 100 km across (a
millimetre CAD export of a 10 m satellite reaches 1e4); 1e300 overflowed the zero-area
test and is inf in Embree's float32."""
MAX_GLTF_JSON_BYTES = 256_000_000
"""Largest glTF JSON read (a .gltf, or a .glb's JSON chunk): parsed JSON takes up to ~6x its
size (100 MB of small numbers peaked at 574 MB: a 2 GB one ~11 GB); a .gltf embedding
MAX_TRIANGLES in base64 is ~240 MB."""


class MeshMaterialError(ValueError):
    """A mesh group/material name that the materials config does not know."""


class MeshFileError(ValueError):
    """A mesh file that cannot be read as a target: names the file and the problem."""


_URI_SCHEME = re.compile(r'^[A-Za-z][A-Za-z0-9+.-]*:')


class DirectoryResolver(trimesh.resolvers.FilePathResolver):
    """trimesh's resolver for a CAD file's external files, confined to its directory
    (module docstring); refusals are MeshFileError naming the CAD file and the URI."""

    def __init__(self, cad_path: Path):
        super().__init__(str(cad_path))
        self.cad_path = Path(cad_path)
        self._read: dict[Path, bytes] = {}

    def get(self, name) -> bytes:
        uri = str(name)
        path = external_path(self.cad_path, uri)
        where = f'{self.cad_path}: external file {uri[:120]!r}'
        if path not in self._read:
            # Each file once, and all of them together within the limit: 60 buffers naming
            # the same 20 MB file took 1.3 GB (a 2 GB file named 100 times, 200 GB).
            total = path.stat().st_size + sum(map(len, self._read.values()))
            if total > MAX_EXTERNAL_BYTES:
                raise MeshFileError(f'{where}: the external files come to {total} bytes, beyond '
                                    f'the limit of {MAX_EXTERNAL_BYTES}')
            self._read[path] = path.read_bytes()
        return self._read[path]


def external_path(cad_path: Path, uri: str) -> Path:
    """The file a glTF's external ``uri`` names in ``cad_path``'s own directory (module
    docstring), or MeshFileError naming the CAD file and the URI."""
    where = f'{cad_path}: external file {uri[:120]!r}'
    if _URI_SCHEME.match(uri) or uri.startswith(('/', '\\')):
        raise MeshFileError(f'{where} is not a path relative to the file\'s directory '
                            '(absolute paths and URLs are not read; embed it or copy it beside)')
    root = Path(cad_path).resolve().parent
    path = (root / unquote(uri)).resolve()
    if not path.is_relative_to(root):
        raise MeshFileError(f'{where} leads out of {root}: not read')
    if not path.is_file():
        raise MeshFileError(f'{where} is not a regular file in {root}')
    return path


def load_scene(path: Path, loadable: Path, kind: str) -> trimesh.Scene:
    """trimesh's scene of ``loadable`` (the mesh file ``path`` or a stand-in for it), its
    external files read from its own folder only (``DirectoryResolver``); anything trimesh
    cannot read is a MeshFileError naming ``path`` (``kind``: 'an OBJ', 'a .glb')."""
    try:
        # Non-finite values are refused afterwards (geometry.checked_mesh), in one line:
        # numpy's warnings on them from inside trimesh would come first.
        with np.errstate(all='ignore'):
            return trimesh.load(str(loadable), force='scene', process=False,
                                resolver=DirectoryResolver(loadable))
    except MeshFileError:
        raise
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds on malformed files
        raise MeshFileError(f'{path}: trimesh cannot read it as {kind} mesh '
                            f'({type(exc).__name__}: {_first_line(exc)})') from None


def read_cad(path: Path, material_names: list[str], mesh_materials: str | dict[str, str] | None,
             max_triangles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (m, V x 3), faces (F x 3) and each face's material id of a CAD file."""
    file_names = check_before_reading(path, max_triangles)
    scene = load_scene(path, path, f'a {path.suffix}')
    verts, faces, mats, unmapped = [], [], [], []
    offset = n_faces = 0
    for node in scene.graph.nodes_geometry:
        matrix, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        n_faces += len(geom.faces)
        if n_faces > max_triangles:
            raise MeshFileError(f'{path}: more than {max_triangles} triangles')
        material = getattr(getattr(getattr(geom, 'visual', None), 'material', None), 'name', None)
        names = _file_names(scene, node, geom_name, file_names)
        candidates = [n for n in (material, *names) if n]
        chosen = _material_of(candidates, material_names, mesh_materials)
        if chosen is not None and chosen not in material_names:
            raise MeshMaterialError(f'{path}: part {candidates[0]!r} is mapped to {chosen!r}, '
                                    f'which is not in the materials config ({material_names})')
        if chosen is None:
            unmapped.append(candidates[0])
            continue
        raw = np.asarray(geom.vertices)
        _check_finite_vertices(raw, path, candidates[0])
        used, f = _used_vertices(raw, _checked_faces(
            np.asarray(geom.faces, dtype=np.int64), len(geom.vertices), path, candidates[0]))
        verts.append(_placed(raw, used, np.asarray(matrix), path, candidates[0], names[0]))
        faces.append(f + offset)
        mats.append(np.full(len(geom.faces), material_names.index(chosen)))
        offset += len(used)
    if unmapped:
        raise MeshMaterialError(
            f'{path}: mesh material/node name(s) {few(sorted(set(map(str, unmapped))))} not '
            f'mapped to a config material (give each an entry in mesh_materials: the '
            f'scenario\'s, or the node\'s mesh_materials parameter; known materials: '
            f'{material_names})')
    if not faces:
        raise MeshFileError(f'{path}: no triangles found')
    return np.vstack(verts), np.vstack(faces), np.concatenate(mats)


def check_before_reading(path: Path, max_triangles: int) -> set[str]:
    """What a CAD file's size, headers and glTF document say, checked before trimesh reads
    it (what trimesh would spend or pass over); returns the glTF's node and mesh names."""
    size = path.stat().st_size
    if size > MAX_MESH_FILE_BYTES:
        raise MeshFileError(f'{path}: {size} bytes exceed the limit of {MAX_MESH_FILE_BYTES}')
    json_bytes = _gltf_json_bytes(path, size)
    if json_bytes > MAX_GLTF_JSON_BYTES:
        raise MeshFileError(f'{path}: {json_bytes} bytes of glTF JSON exceed the limit of '
                            f'{MAX_GLTF_JSON_BYTES} (keep buffers in a .bin or a .glb)')
    file_names = _check_gltf_document(path, json_bytes, max_triangles)
    _check_binary_stl_length(path, size)
    _check_header_counts(path, size, max_triangles)
    if size > MAX_TEXT_MESH_BYTES and _is_text_mesh(path, size):
        raise MeshFileError(f'{path}: {size} bytes of text mesh exceed the limit of '
                            f'{MAX_TEXT_MESH_BYTES} (export it as binary STL or PLY, or glTF)')
    return file_names


def _check_gltf_document(path: Path, json_bytes: int, max_triangles: int) -> set[str]:
    """A glTF's document against the specification (``gltf_check``), before trimesh reads
    what it understands of it; MeshFileError names the file and the JSON key. Returns the
    names its nodes and meshes have (empty for other files)."""
    try:
        doc = gltf_document(path, json_bytes)
        if doc is None:
            return set()
        check_gltf(doc, max_triangles)
    except GltfError as exc:
        raise MeshFileError(f'{path}: {exc}') from None
    _check_buffer_bytes(path, doc, json_bytes)
    return {item['name'] for key in ('nodes', 'meshes') for item in doc.get(key, [])
            if isinstance(item.get('name'), str)}


def _check_buffer_bytes(path: Path, doc: dict, json_bytes: int) -> None:
    """Every glTF buffer holds at least the ``byteLength`` it declares (the .glb's BIN
    chunk, a base64 ``data:`` URI, or an external file beside it). A shorter one was refused
    only by trimesh's ``assert len(view) == byteLength``: under ``python -O`` it loaded
    what bytes there were (and with a count past them, "cannot reshape array")."""
    for i, buffer in enumerate(doc.get('buffers', [])):
        declared, uri = buffer['byteLength'], buffer.get('uri')
        if uri is None and (i > 0 or path.suffix.lower() != '.glb'):
            raise MeshFileError(f'{path}: buffers[{i}] has no uri (only a .glb\'s first buffer, '
                                'its BIN chunk, may omit it: glTF 2.0 section 3.6.1.1)')
        if uri is None:
            held, source = _glb_bin_bytes(path, json_bytes), 'the .glb\'s BIN chunk'
        elif not isinstance(uri, str):
            raise MeshFileError(f'{path}: buffers[{i}].uri = {str(uri)[:40]} is not a string')
        elif uri.startswith('data:'):
            if ';base64,' not in uri[:200]:
                continue        # trimesh reads only base64 data URIs, and says so
            text = uri.split(',', 1)[1].rstrip()
            held, source = 3 * len(text) // 4 - len(text) + len(text.rstrip('=')), 'its data: URI'
        else:
            held, source = external_path(path, uri).stat().st_size, f'file {uri[:120]!r}'
        if held < declared:
            raise MeshFileError(f'{path}: buffers[{i}].byteLength = {declared}, but {source} '
                                f'holds {held} bytes (truncated?)')


def _glb_bin_bytes(path: Path, json_bytes: int) -> int:
    """Length of a .glb's BIN chunk (the chunk after the JSON one: glTF 2.0 section 4.4),
    0 when there is none (a .gltf has none)."""
    if path.suffix.lower() != '.glb':
        return 0
    with open(path, 'rb') as f:
        f.seek(20 + json_bytes)
        head = f.read(8)
    if len(head) < 8 or head[4:8] != b'BIN\0':
        return 0
    return min(int.from_bytes(head[:4], 'little'), path.stat().st_size - 28 - json_bytes)


_UNIQUE_SUFFIX = re.compile(r'_\d+$')


def _file_names(scene: trimesh.Scene, node: str, geom_name: str,
                file_names: set[str]) -> tuple[str, str]:
    """The glTF node's and mesh's names as the file gives them, for trimesh's names of a
    placed part: trimesh makes names unique ('wing' twice: 'wing', 'wing_1'; a mesh's
    second primitive 'panel_1') and puts each primitive of a mesh of several under a
    child frame of its node ('wing_8846ae'), names no user can map."""
    if scene.geometry[geom_name].metadata.get('from_gltf_primitive'):
        node = scene.graph.transforms.parents.get(node, node)
    return tuple(_UNIQUE_SUFFIX.sub('', name) if name not in file_names
                 and _UNIQUE_SUFFIX.sub('', name) in file_names else name
                 for name in (node, geom_name))


def _check_binary_stl_length(path: Path, size: int) -> None:
    """A binary STL (80-byte header, uint32 triangle count, 50 bytes a triangle) whose
    count disagrees with its length: trimesh then tried it as ASCII and reported "no
    triangles found". A file starting with 'solid' whose length does not fit the count is
    ASCII (some binary exporters also start their header with 'solid')."""
    if path.suffix.lower() != '.stl' or size < 84:
        return
    with open(path, 'rb') as f:
        head = f.read(84)
    count = int.from_bytes(head[80:84], 'little')
    if size == 84 + 50 * count or head[:5].lower() == b'solid':
        return
    raise MeshFileError(f'{path}: binary STL header says {count} triangles ({84 + 50 * count} '
                        f'bytes), but the file has {size} bytes (truncated or not an STL?)')


def _check_header_counts(path: Path, size: int, max_triangles: int) -> None:
    """A binary STL's triangle count, a PLY's face and vertex counts, from their headers,
    within the limits before trimesh reads them (a 100 MB binary STL of 2 M triangles took
    1.1 GB and 14 s to reach the count check; a 2 GB one of 40 M would have taken ~22 GB)."""
    suffix = path.suffix.lower()
    if suffix == '.stl' and size >= 84:
        with open(path, 'rb') as f:
            head = f.read(84)
        count = int.from_bytes(head[80:84], 'little')
        if size == 84 + 50 * count and count > max_triangles:
            raise MeshFileError(f'{path}: binary STL header says {count} triangles, more than '
                                f'the limit of {max_triangles}')
    elif suffix == '.ply':
        header = ply_header(path)
        counts = dict(re.findall(r'^element\s+(vertex|face)\s+(\d+)\s*$', header, re.M))
        for element, limit in (('face', max_triangles), ('vertex', 3 * max_triangles)):
            if int(counts.get(element, 0)) > limit:
                raise MeshFileError(f'{path}: PLY header says {counts[element]} {element} '
                                    f'elements, more than the limit of {limit}')


def _is_text_mesh(path: Path, size: int) -> bool:
    """An ASCII STL (starts with 'solid' and its length does not fit a binary header's
    count) or an ASCII PLY ('format ascii' in its header)."""
    with open(path, 'rb') as f:
        head = f.read(4096)
    suffix = path.suffix.lower()
    if suffix == '.stl':
        count = int.from_bytes(head[80:84], 'little') if len(head) >= 84 else -1
        return head[:5].lower() == b'solid' and size != 84 + 50 * count
    if suffix == '.ply':
        return re.search(r'^format\s+ascii\b', ply_header(path), re.M) is not None
    return False


def ply_header(path: Path) -> str:
    """A PLY's header (up to its ``end_header`` line), at most MAX_PLY_HEADER_BYTES: the
    counts were read from the first 64 kB only, so a header of 1,000 comment lines
    (100 kB) put its element counts past them and past the triangle limit's check, and
    one that never ends was read by trimesh to the end of the file."""
    with open(path, 'rb') as f:
        head = f.read(MAX_PLY_HEADER_BYTES + len(b'end_header'))
    end = re.search(rb'(^|[\r\n])end_header', head)
    if end is None or end.start() > MAX_PLY_HEADER_BYTES:
        raise MeshFileError(f'{path}: no end_header line in its first {MAX_PLY_HEADER_BYTES} '
                            'bytes (a PLY header is at most that long: this one is longer, or '
                            'not a PLY header)')
    return head[:end.start()].decode('latin-1')


def _checked_faces(faces: np.ndarray, n_vertices: int, path: Path, part: str) -> np.ndarray:
    """``faces`` if every index names one of the part's ``n_vertices`` vertices: an index
    past the end raised IndexError later, a negative one took a vertex from the end."""
    bad = (faces < 0) | (faces >= n_vertices)
    if bad.any():
        raise MeshFileError(f'{path}: part {part!r} has a face with vertex index '
                            f'{int(faces[bad][0])}, but only {n_vertices} vertices '
                            f'(indices 0..{n_vertices - 1})')
    return faces


def _used_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the part's vertices kept and its faces over them: only the vertices the
    faces name when there are more than 3 per face (every placement of a part is copied,
    and a one-triangle part over a 1e6-vertex accessor placed by 40 nodes took 2 GB, the
    file 12 MB), so vertices stay below 3 x MAX_TRIANGLES whatever the file claims."""
    if len(vertices) <= 3 * len(faces):
        return np.arange(len(vertices)), faces
    used, inverse = np.unique(faces, return_inverse=True)
    return used, inverse.reshape(faces.shape)


def _check_finite_vertices(vertices: np.ndarray, path: Path, part: str) -> None:
    """Every vertex of a part finite as the file writes it: the error names the part, the
    vertex's index in it (the file's order: a glTF accessor's, a PLY's vertex element, an
    STL's three per facet) and its value as written, not where a node put it."""
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise MeshFileError(f'{path}: part {part!r} vertex #{k} = {vertices[k].tolist()} is not '
                            f'finite ({int(bad.sum())} of its {len(vertices)} vertices are not)')


def _placed(vertices: np.ndarray, used: np.ndarray, matrix: np.ndarray, path: Path, part: str,
            node: str) -> np.ndarray:
    """The ``used`` vertices (float64, m) placed by their node's ``matrix``; a vertex the
    transform makes non-finite (a finite 1e304 scaled by 1e5) or puts beyond MAX_VERTEX_M
    on an axis is refused naming the node, the part's vertex index, its value as written
    and where the node puts it."""
    with np.errstate(all='ignore'):
        placed = np.asarray(vertices[used], dtype=float) @ matrix[:3, :3].T + matrix[:3, 3]
    bad = ~np.isfinite(placed).all(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise MeshFileError(f'{path}: node {node!r} places part {part!r} vertex '
                            f'#{int(used[k])} = {vertices[used[k]].tolist()} at '
                            f'{placed[k].tolist()}, not finite')
    far = np.abs(placed).max(axis=1, initial=0.0) > MAX_VERTEX_M
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise MeshFileError(f'{path}: node {node!r} places part {part!r} vertex '
                            f'#{int(used[k])} = {vertices[used[k]].tolist()} at '
                            f'{placed[k].tolist()} (m), beyond the limit of {MAX_VERTEX_M:g} m '
                            f'({int(far.sum())} of its {len(used)} vertices are; is the file '
                            'in metres?)')
    return placed


def _gltf_json_bytes(path: Path, size: int) -> int:
    """Bytes of JSON trimesh would parse: a .gltf's size, a .glb's first (JSON) chunk's
    length from its header (glTF 2.0 binary: magic, version, length, then chunk length and
    type); 0 for other files."""
    suffix = path.suffix.lower()
    if suffix == '.gltf':
        return size
    if suffix == '.glb':
        with open(path, 'rb') as f:
            head = f.read(20)
        if len(head) == 20 and head[:4] == b'glTF' and head[16:20] == b'JSON':
            return int.from_bytes(head[12:16], 'little')
    return 0


def _material_of(candidates: list[str], material_names: list[str],
                 mesh_materials: str | dict[str, str] | None) -> str | None:
    """The config material of a part with these candidate names (module doc), or None."""
    if isinstance(mesh_materials, str):
        return mesh_materials
    for name in candidates:
        if mesh_materials is not None:
            if name in mesh_materials:
                return mesh_materials[name]
        elif name in material_names:
            return name
    return None


def few(names: list[str], shown: int = 10) -> str:
    """The first ``shown`` of ``names`` and how many more: an error stays a short line
    (5,000 unmapped parts listed every name, ~60 kB)."""
    more = f' and {len(names) - shown} more' if len(names) > shown else ''
    return f'{[n[:60] for n in names[:shown]]}{more}'


def _first_line(exc: Exception) -> str:
    text = ' '.join(str(exc).split())
    return text if len(text) <= 200 else text[:197] + '...'
