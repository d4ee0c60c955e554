#!/usr/bin/env python3
"""Generate the triangle mesh of a tumbling upper-stage rocket body.

The target follows the upper stage used in the JAXA paper "Development of
LiDAR measurement simulator considering target surface reflection": a
4 m diameter, 10 m long body.  Units are metres.

Body frame: long axis along +Z, origin at the middle of the overall length,
so the mesh spans z = -5 .. +5 (engine nozzle exit at -Z, payload end at +Z)
and x, y = -2.0 .. +2.0 (tank radius 2.0 m; MLI blankets at 2.02 m do not
reach the extreme +-X/+-Y points).

Parts (each one OBJ group / material, listed bottom to top):

    NOZZLE    bell nozzle, throat r 0.25 m, exit r 0.90 m     z -5.00 .. -3.10
    MLI       aft skirt (r 2.0 m, hangs below the dome)      z -3.30 .. -2.20
    BULKHEAD  shallow elliptical aft dome, r 2.0 m            z -3.20 .. -2.90
    PIF       foam-covered tank cylinder, r 2.0 m             z -2.20 .. +1.60
    MLI       forward band, r 2.0 m                           z +1.60 .. +2.20
    MLI       two rectangular blankets, r 2.02 m              z -1.20 .. +1.00
    ADAPTER   frustum + ring r 2.0 -> 1.9 m                   z +2.20 .. +2.65
    PSS       truncated cone r 1.9 -> 0.65 m                  z +2.65 .. +4.55
    PAF       ring r 0.6 m, top annulus, recessed centre disk z +4.55 .. +5.00

All triangles wind counter-clockwise seen from outside (normals point away
from the body).  The main body (skirt, dome, tank, adapter, PSS, PAF) is one
closed, watertight surface; the nozzle is a separate closed solid of
revolution (outer wall, exit lip, inner wall, injector plate) whose top
0.1 m is buried inside the aft dome; each blanket is a closed 2 cm thick
slab lying on the tank (its inner face is hidden against the foam).

Run ``python tools/make_rocket_mesh.py`` to (re)write meshes/rocket_body.obj
and .mtl; ``--segments`` sets the circumferential resolution (the triangle
count grows with its square) and ``--out`` the output path without extension.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import trimesh

# Order of the groups in the OBJ file (and of faces in the returned mesh).
MATERIALS = ("PIF", "MLI", "ADAPTER", "PSS", "PAF", "BULKHEAD", "NOZZLE")

DEFAULT_SEGMENTS = 128
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "meshes" / "rocket_body"

# Main dimensions [m].
TANK_R = 2.0
BLANKET_R = 2.02
SKIRT_INNER_R = 1.98
Z_SKIRT_BOTTOM = -3.30
Z_DOME_APEX = -3.20
Z_DOME_EDGE = -2.90
Z_AFT_MLI_TOP = -2.20
Z_FWD_MLI_BOTTOM = 1.60
Z_TANK_TOP = 2.20
ADAPTER_R = 1.90
Z_ADAPTER_KNEE = 2.35
Z_PSS_BOTTOM = 2.65
PSS_TOP_R = 0.65
Z_PSS_TOP = 4.55
PAF_R = 0.60
PAF_INNER_R = 0.45
Z_TOP = 5.00
Z_PAF_RECESS = 4.90

NOZZLE_THROAT_R = 0.25
NOZZLE_EXIT_R = 0.90
NOZZLE_CHAMBER_R = 0.32
NOZZLE_WALL = 0.03
Z_NOZZLE_EXIT = -5.00
Z_NOZZLE_THROAT = -3.35
Z_NOZZLE_TOP = -3.25  # chamber top / injector plate, seen looking up the bell
Z_NOZZLE_MOUNT = -3.10  # outer wall ends inside the aft dome: no visible gap

# (theta_min_deg, theta_max_deg, z_min, z_max) of the MLI blankets on the tank.
BLANKETS = ((30.0, 75.0, -1.20, 0.40), (200.0, 250.0, -0.50, 1.00))


# --------------------------------------------------------------------------
# Profile helpers.  A profile is an (n, 2) array of (r, z) points.  Surfaces of
# revolution are outward-facing when the profile runs counter-clockwise in the
# (r, z) plane around the solid, i.e. the solid lies to the left of the
# direction of travel (for a closed body: from the bottom of the axis, out,
# up the side and back in to the top of the axis).
# --------------------------------------------------------------------------


def _line(p0, p1, step):
    """Points from p0 to p1 (inclusive), spaced at most ``step`` apart."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(1, math.ceil(np.linalg.norm(p1 - p0) / step - 1e-9))
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    return p0 + t * (p1 - p0)


def _resample(curve, step):
    """Resample a dense polyline at (nearly) uniform arc length <= step."""
    seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(1, math.ceil(s[-1] / step - 1e-9))
    s_new = np.linspace(0.0, s[-1], n + 1)
    return np.column_stack([np.interp(s_new, s, curve[:, 0]), np.interp(s_new, s, curve[:, 1])])


def _dome(step):
    """Elliptical aft dome from the axis (apex) out to the skirt inner radius."""
    t = np.linspace(0.0, 0.5 * math.pi, 512)
    depth = Z_DOME_EDGE - Z_DOME_APEX
    curve = np.column_stack([SKIRT_INNER_R * np.sin(t), Z_DOME_EDGE - depth * np.cos(t)])
    return _resample(curve, step)


def _bell_contour(step):
    """Inner nozzle contour (r, z) from the exit plane up to the chamber top.

    Rao-style approximation: a quadratic Bezier from the throat (wall angle
    30 deg) to the exit (wall angle 8 deg), a short converging cone above the
    throat.
    """
    length = Z_NOZZLE_THROAT - Z_NOZZLE_EXIT
    a_n, a_e = math.radians(30.0), math.radians(8.0)
    # Work in d = distance below the throat; r(d) leaves the throat at slope
    # tan(a_n) and reaches the exit at slope tan(a_e).
    p0 = np.array([0.0, NOZZLE_THROAT_R])
    p2 = np.array([length, NOZZLE_EXIT_R])
    d1 = (p2[1] - p0[1] - math.tan(a_e) * p2[0]) / (math.tan(a_n) - math.tan(a_e))
    p1 = np.array([d1, p0[1] + math.tan(a_n) * d1])
    t = np.linspace(1.0, 0.0, 512)[:, None]  # exit -> throat
    bez = (1 - t) ** 2 * p0 + 2 * (1 - t) * t * p1 + t**2 * p2
    bell = np.column_stack([bez[:, 1], Z_NOZZLE_THROAT - bez[:, 0]])
    converging = np.array([[NOZZLE_THROAT_R, Z_NOZZLE_THROAT], [NOZZLE_CHAMBER_R, Z_NOZZLE_TOP]])
    return np.vstack([_resample(bell, step), _line(*converging, step)[1:]])


def _join(pieces):
    """Concatenate (points, material) pieces sharing end points.

    Returns the profile points and the material of each profile segment.
    """
    points, mats = [pieces[0][0][:1]], []
    for pts, mat in pieces:
        assert np.allclose(points[-1][-1], pts[0]), (mat, points[-1][-1], pts[0])
        points.append(pts[1:])
        mats += [mat] * (len(pts) - 1)
    return np.vstack(points), np.array(mats, dtype=object)


def _revolve(profile, seg_mats, thetas):
    """Sweep an (r, z) profile a full turn around Z.

    thetas: angles of the vertex columns (the last column joins the first).
    Points with r == 0 become a single vertex.
    Returns (vertices, faces, face_materials) with faces indexing vertices.
    """
    n_th = len(thetas)
    cos, sin = np.cos(thetas), np.sin(thetas)
    on_axis = profile[:, 0] == 0.0
    verts, index = [], np.empty((len(profile), n_th), dtype=np.int64)
    count = 0
    for i, (r, z) in enumerate(profile):
        if on_axis[i]:
            verts.append([[0.0, 0.0, z]])
            index[i] = count
            count += 1
        else:
            verts.append(np.column_stack([r * cos, r * sin, np.full(n_th, z)]))
            index[i] = count + np.arange(n_th)
            count += n_th
    j0 = np.arange(n_th)
    j1 = (j0 + 1) % n_th
    faces, mats = [], []
    for i in range(len(profile) - 1):
        a, b = index[i, j0], index[i, j1]  # lower ring (profile point i)
        c, d = index[i + 1, j0], index[i + 1, j1]  # upper ring (point i+1)
        # (a, b, c): along theta then along the profile -> outward normal.
        if not on_axis[i]:
            faces.append(np.column_stack([a, b, c]))
        if not on_axis[i + 1]:
            faces.append(np.column_stack([b, d, c]))
        mats += [seg_mats[i]] * (len(j0) * ((not on_axis[i]) + (not on_axis[i + 1])))
    return np.vstack(verts), np.vstack(faces), np.array(mats, dtype=object)


def _blanket(th0_deg, th1_deg, z0, z1, dtheta, step):
    """Closed MLI slab on the tank, outer face at r = BLANKET_R.

    Cross-section loop (counter-clockwise, as for profiles): bottom edge out,
    outer face up, top edge in, inner face down; swept from th0 to th1 and
    closed by two flat end walls.  The inner face lies 5 mm inside the
    faceted tank (below its chords), so no grazing ray can slip under the
    blanket and hit its back.
    """
    r_in = TANK_R * math.cos(dtheta / 2.0) - 0.005
    span = math.radians(th1_deg - th0_deg)
    n = max(1, math.ceil(span / dtheta - 1e-9))
    thetas = math.radians(th0_deg) + span * np.arange(n + 1) / n
    zs = _line((0.0, z0), (0.0, z1), step)[:, 1]
    m = len(zs)
    # points 0..m-1: outer column O_k, m..2m-1: inner column I_k (same z_k)
    pts = np.vstack([np.column_stack([np.full(m, BLANKET_R), zs]),
                     np.column_stack([np.full(m, r_in), zs])])
    verts = np.column_stack([
        (pts[:, :1] * np.cos(thetas)).ravel(),
        (pts[:, :1] * np.sin(thetas)).ravel(),
        np.repeat(pts[:, 1], n + 1),
    ])
    vid = np.arange(2 * m * (n + 1)).reshape(2 * m, n + 1)
    loop = np.concatenate([[m], np.arange(m), np.arange(2 * m - 1, m - 1, -1)])  # I0, O.., I.. down to I0
    j = np.arange(n)
    faces = []
    for p, q in zip(loop[:-1], loop[1:]):
        a, b, c, d = vid[p, j], vid[p, j + 1], vid[q, j], vid[q, j + 1]
        faces += [np.column_stack([a, b, c]), np.column_stack([b, d, c])]
    k = np.arange(m - 1)
    for col, flip in ((0, False), (n, True)):  # end walls, facing -theta / +theta
        o0, o1, i0, i1 = vid[k, col], vid[k + 1, col], vid[m + k, col], vid[m + k + 1, col]
        tris = [np.column_stack([i0, o0, o1]), np.column_stack([i0, o1, i1])]
        faces += [t[:, ::-1] for t in tris] if flip else tris
    faces = np.vstack(faces)
    return verts, faces, np.array(["MLI"] * len(faces), dtype=object)


def _main_body_profile(step):
    """Closed outline of the body, bottom of axis -> top of axis."""
    r_in, r = SKIRT_INNER_R, TANK_R
    return _join(
        [
            (_dome(step), "BULKHEAD"),
            # aft skirt: inner wall down, bottom lip, outer wall up
            (_line((r_in, Z_DOME_EDGE), (r_in, Z_SKIRT_BOTTOM), step), "MLI"),
            (_line((r_in, Z_SKIRT_BOTTOM), (r, Z_SKIRT_BOTTOM), step), "MLI"),
            (_line((r, Z_SKIRT_BOTTOM), (r, Z_AFT_MLI_TOP), step), "MLI"),
            (_line((r, Z_AFT_MLI_TOP), (r, Z_FWD_MLI_BOTTOM), step), "PIF"),
            (_line((r, Z_FWD_MLI_BOTTOM), (r, Z_TANK_TOP), step), "MLI"),
            (_line((r, Z_TANK_TOP), (ADAPTER_R, Z_ADAPTER_KNEE), step), "ADAPTER"),
            (_line((ADAPTER_R, Z_ADAPTER_KNEE), (ADAPTER_R, Z_PSS_BOTTOM), step), "ADAPTER"),
            (_line((ADAPTER_R, Z_PSS_BOTTOM), (PSS_TOP_R, Z_PSS_TOP), step), "PSS"),
            # PAF: step in, ring up, top annulus, recess wall down, centre disk
            (_line((PSS_TOP_R, Z_PSS_TOP), (PAF_R, Z_PSS_TOP), step), "PAF"),
            (_line((PAF_R, Z_PSS_TOP), (PAF_R, Z_TOP), step), "PAF"),
            (_line((PAF_R, Z_TOP), (PAF_INNER_R, Z_TOP), step), "PAF"),
            (_line((PAF_INNER_R, Z_TOP), (PAF_INNER_R, Z_PAF_RECESS), step), "PAF"),
            (_line((PAF_INNER_R, Z_PAF_RECESS), (0.0, Z_PAF_RECESS), step), "PAF"),
        ]
    )


def _nozzle_profile(step):
    """Closed outline of the nozzle wall solid, bottom of axis -> top of axis.

    Injector plate (faces -Z into the bell), inner wall down to the exit, exit
    lip, outer wall up into the dome, top plate (hidden inside the body) back
    to the axis.
    """
    inner = _bell_contour(step)[::-1]  # chamber top -> exit
    outer = inner[::-1] + [NOZZLE_WALL, 0.0]  # exit -> chamber top
    r_top = outer[-1, 0]
    return _join(
        [
            (_line((0.0, Z_NOZZLE_TOP), inner[0], step), "NOZZLE"),
            (inner, "NOZZLE"),
            (_line(inner[-1], outer[0], step), "NOZZLE"),
            (outer, "NOZZLE"),
            (_line(outer[-1], (r_top, Z_NOZZLE_MOUNT), step), "NOZZLE"),
            (_line((r_top, Z_NOZZLE_MOUNT), (0.0, Z_NOZZLE_MOUNT), step), "NOZZLE"),
        ]
    )


def build_rocket_body(segments: int = DEFAULT_SEGMENTS) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Build the rocket body mesh.

    segments: circumferential segments of every full surface of revolution;
    the profile is subdivided at the same spacing as the tank circumference
    (2*pi*2.0/segments), so the triangle count scales with segments**2
    (128 -> 48,844 triangles, 600 -> 1,009,724).

    Returns (mesh, face_material_names); faces are ordered by group in the
    order of MATERIALS, exactly as written to the OBJ.
    """
    if segments < 32:
        raise ValueError("segments must be >= 32 (coarser tanks would swallow the 2 cm MLI blankets)")
    step = 2.0 * math.pi * TANK_R / segments
    full = 2.0 * math.pi * np.arange(segments) / segments

    parts = [
        _revolve(*_main_body_profile(step), full),
        _revolve(*_nozzle_profile(step), full),
    ]
    parts += [_blanket(*b, 2.0 * math.pi / segments, step) for b in BLANKETS]

    verts, faces, mats, offset = [], [], [], 0
    for v, f, m in parts:
        verts.append(v)
        faces.append(f + offset)
        mats.append(m)
        offset += len(v)
    verts, faces, mats = np.vstack(verts), np.vstack(faces), np.concatenate(mats)

    order = np.argsort([MATERIALS.index(m) for m in mats], kind="stable")
    faces, mats = faces[order], mats[order].astype(str)
    mesh = trimesh.Trimesh(vertices=verts, faces=faces, process=False)
    return mesh, mats


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------

# name: (Kd, Ks, Ns) -- only for viewers, see the MTL header.
_MTL = {
    "PIF": ((0.80, 0.45, 0.15), (0.05, 0.05, 0.05), 5.0),  # orange-brown foam
    "MLI": ((0.85, 0.72, 0.35), (0.60, 0.55, 0.40), 200.0),  # gold kapton
    "ADAPTER": ((0.60, 0.60, 0.62), (0.30, 0.30, 0.30), 60.0),  # aluminium
    "PSS": ((0.75, 0.75, 0.72), (0.20, 0.20, 0.20), 40.0),  # painted CFRP
    "PAF": ((0.70, 0.70, 0.72), (0.50, 0.50, 0.50), 120.0),  # bare aluminium
    "BULKHEAD": ((0.45, 0.45, 0.47), (0.20, 0.20, 0.20), 30.0),
    "NOZZLE": ((0.18, 0.18, 0.20), (0.30, 0.30, 0.30), 80.0),  # niobium / C-C
}


def _fmt_rows(fmt, arr):
    """Format every row of a 2-D array with ``fmt`` in one string operation."""
    if len(arr) == 0:
        return ""
    return (fmt * len(arr)) % tuple(arr.ravel().tolist())


def write_obj_with_groups(path_stem, mesh: trimesh.Trimesh, face_material_names) -> tuple[Path, Path]:
    """Write ``<path_stem>.obj`` and ``<path_stem>.mtl``.

    One ``o``/``g``/``usemtl`` block per material, named exactly like the
    material, in the order of MATERIALS (unknown names follow, sorted).
    Output is byte-for-byte deterministic.  Returns (obj_path, mtl_path).
    """
    stem = Path(path_stem)
    if stem.suffix in (".obj", ".mtl"):
        stem = stem.with_suffix("")
    stem.parent.mkdir(parents=True, exist_ok=True)
    obj_path, mtl_path = stem.with_suffix(".obj"), stem.with_suffix(".mtl")
    names = np.asarray(face_material_names).astype(str)
    faces = np.asarray(mesh.faces)
    if len(names) != len(faces):
        raise ValueError("need one material name per face")
    groups = [m for m in MATERIALS if m in names] + sorted(set(names) - set(MATERIALS))

    # round first so that tiny negatives do not print as "-0.000000"
    verts = np.round(np.asarray(mesh.vertices, dtype=np.float64), 6) + 0.0
    ext = mesh.extents
    parts = [
        "# Upper-stage rocket body, units: metres, long axis +Z, origin at mid-length\n",
        f"# written by tools/make_rocket_mesh.py; {len(verts)} vertices, {len(faces)} triangles,"
        f" extents {ext[0]:.3f} x {ext[1]:.3f} x {ext[2]:.3f}\n",
        f"mtllib {mtl_path.name}\n",
        _fmt_rows("v %.6f %.6f %.6f\n", verts),
    ]
    for name in groups:
        sel = faces[names == name] + 1
        parts += [f"o {name}\ng {name}\nusemtl {name}\n", _fmt_rows("f %d %d %d\n", sel)]
    obj_path.write_text("".join(parts))

    mtl = [
        "# Materials of the rocket body mesh (colours for viewers only).\n",
        "# The LiDAR simulator does NOT use these values: reflectance/BRDF parameters\n",
        "# per material name come from config/materials.yaml.\n",
    ]
    for name in groups:
        kd, ks, ns = _MTL.get(name, ((0.5, 0.5, 0.5), (0.1, 0.1, 0.1), 10.0))
        mtl.append(
            f"\nnewmtl {name}\nKa 0.000 0.000 0.000\nKd {kd[0]:.3f} {kd[1]:.3f} {kd[2]:.3f}\n"
            f"Ks {ks[0]:.3f} {ks[1]:.3f} {ks[2]:.3f}\nNs {ns:.1f}\nd 1.0\nillum 2\n"
        )
    mtl_path.write_text("".join(mtl))
    return obj_path, mtl_path


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--segments", type=int, default=DEFAULT_SEGMENTS,
                    help=f"circumferential segments (default {DEFAULT_SEGMENTS}; 600 gives ~1.0M triangles)")
    ap.add_argument("--out", default=str(DEFAULT_OUT),
                    help="output path without extension (default meshes/rocket_body)")
    args = ap.parse_args(argv)
    mesh, mats = build_rocket_body(args.segments)
    obj_path, mtl_path = write_obj_with_groups(args.out, mesh, mats)
    counts = ", ".join(f"{m} {int(np.sum(mats == m))}" for m in MATERIALS)
    print(f"wrote {obj_path} and {mtl_path}: {len(mesh.faces)} triangles ({counts})")


if __name__ == "__main__":
    main()
