#!/usr/bin/env python3
"""Generate meshes/box_wing_satellite.glb: a box-wing satellite as a glTF 2.0 binary.

A second target beside the rocket body, as a CAD export would deliver it: parts named
by glTF nodes and materials, not by our material names (the scenario's
``mesh_materials`` maps them, config/scenario_box_wing.yaml). Units are metres.

Body frame: origin at the bus centre, +Z up the bus, solar arrays along +-Y.

    node               material               shape
    bus                bus_mli                box 1.8 x 1.8 x 2.2 m, MLI-wrapped
    radiator           radiator_white_paint   panel 1.4 x 1.4 m, 2 cm proud of the +Z face
    solar_array_left   solar_cells            wing 1.6 x 4.0 x 0.04 m, y +1.3 .. +5.3 m
    solar_array_right  solar_cells            wing 1.6 x 4.0 x 0.04 m, y -5.3 .. -1.3 m
    yoke_left/right    antenna_aluminium      booms r 3 cm from the bus to each wing
    antenna_mast       antenna_aluminium      cylinder r 5 cm, 0.4 m on the -X face
    antenna_dish       antenna_aluminium      paraboloid dish r 0.6 m, depth 0.15 m, facing -X

Run: python tools/make_box_wing_mesh.py [out.glb]
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial
from trimesh.visual.texture import TextureVisuals

OUT = Path(__file__).resolve().parent.parent / 'meshes' / 'box_wing_satellite.glb'
COLOURS = {  # display colours only (RGBA, 0-1): the simulator takes materials from its config
    'bus_mli': (0.85, 0.65, 0.2, 1.0),
    'radiator_white_paint': (0.95, 0.95, 0.95, 1.0),
    'solar_cells': (0.05, 0.08, 0.25, 1.0),
    'antenna_aluminium': (0.75, 0.75, 0.78, 1.0),
}


def box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def along_y(cylinder: trimesh.Trimesh) -> trimesh.Trimesh:
    cylinder.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    return cylinder


def dish(radius_m: float = 0.6, depth_m: float = 0.15, segments: int = 48,
         rings: int = 12) -> trimesh.Trimesh:
    """A paraboloid shell x = -x0 - depth (r/R)^2 opening toward -X, its vertex at x = 0."""
    r = np.linspace(0.0, radius_m, rings + 1)
    x = depth_m * (r / radius_m) ** 2
    profile = np.column_stack([r, x])            # revolve about the profile's second axis
    mesh = trimesh.creation.revolve(profile, sections=segments)
    # revolve() turns about +Z: the dish axis becomes -X (the bowl opens away from the bus).
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [0, 1, 0]))
    return mesh


def parts() -> dict[str, tuple[trimesh.Trimesh, str]]:
    half = 0.9
    mast = along_y(trimesh.creation.cylinder(radius=0.05, height=0.4, sections=24))
    mast.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1]))
    mast.apply_translation([-half - 0.2, 0.0, 0.3])
    antenna = dish()
    antenna.apply_translation([-half - 0.4, 0.0, 0.3])
    yoke_l = along_y(trimesh.creation.cylinder(radius=0.03, height=0.4, sections=16))
    yoke_l.apply_translation([0.0, half + 0.2, 0.0])
    yoke_r = yoke_l.copy()
    yoke_r.apply_translation([0.0, -2 * (half + 0.2), 0.0])
    return {
        'bus': (box([1.8, 1.8, 2.2], [0.0, 0.0, 0.0]), 'bus_mli'),
        'radiator': (box([1.4, 1.4, 0.02], [0.0, 0.0, 1.11]), 'radiator_white_paint'),
        'solar_array_left': (box([1.6, 4.0, 0.04], [0.0, 3.3, 0.0]), 'solar_cells'),
        'solar_array_right': (box([1.6, 4.0, 0.04], [0.0, -3.3, 0.0]), 'solar_cells'),
        'yoke_left': (yoke_l, 'antenna_aluminium'),
        'yoke_right': (yoke_r, 'antenna_aluminium'),
        'antenna_mast': (mast, 'antenna_aluminium'),
        'antenna_dish': (antenna, 'antenna_aluminium'),
    }


def build_scene() -> trimesh.Scene:
    scene = trimesh.Scene()
    materials = {name: PBRMaterial(name=name, baseColorFactor=colour, doubleSided=True)
                 for name, colour in COLOURS.items()}
    for node, (mesh, material) in parts().items():
        mesh.visual = TextureVisuals(material=materials[material])
        scene.add_geometry(mesh, node_name=node, geom_name=node)
    return scene


def main(argv: list[str]) -> None:
    out = Path(argv[0]) if argv else OUT
    out.write_bytes(build_scene().export(file_type='glb'))
    print(f'wrote {out}')


if __name__ == '__main__':
    main(sys.argv[1:])
