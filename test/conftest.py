"""Shared fixtures: small scenes built in code so tests know their closed forms."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from lidar_sim_ros.core.config import (MaterialConfig, MaterialsConfig,
                                       SensorConfig, load_scenario, parse)
from lidar_sim_ros.core.geometry import Target

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / 'config'


@pytest.fixture(scope='session')
def default_scenario():
    return load_scenario(CONFIG / 'scenario.yaml')


def plate_target(size_m: float = 4.0, material: int = 0, names=('PIF',)) -> Target:
    """A square plate in the body x-y plane, normal +z, centred on the origin."""
    h = size_m / 2
    verts = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return Target(verts, faces, np.full(2, material), list(names))


def sphere_target(radius_m: float = 1.0, subdivisions: int = 5, names=('PIF',)) -> Target:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius_m)
    return Target(mesh.vertices, mesh.faces, np.zeros(len(mesh.faces), int), list(names))


def materials(**overrides) -> MaterialsConfig:
    base = dict(name='PIF', kd=0.5, ks=0.0, n=1.0, bias_m=0.0, sigma_m=0.0)
    base.update(overrides)
    return MaterialsConfig(materials=[MaterialConfig(**base)])


def sensor(scan: dict | None = None, **det) -> SensorConfig:
    data = {
        'name': 'test',
        'frame_rate_hz': 10.0,
        'scan': scan or {'type': 'rotating', 'elevations_deg': [0.0], 'az_min_deg': -1.0,
                         'az_max_deg': 1.0, 'shots_per_beam': 8},
        'optics': {'peak_power_w': 40.0, 'transmit_efficiency': 0.9, 'receive_efficiency': 0.8,
                   'beam_divergence_rad': 0.002, 'aperture_diameter_m': 0.03},
        'detection': {'threshold_power_w': 1e-9, 'saturation_power_w': 1.0,
                      'min_range_m': 0.1, 'max_range_m': 500.0, **det},
    }
    return parse(SensorConfig, data, '<test>')
