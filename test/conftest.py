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

# Embree intersects in float32, so a raycast range is exact only to a few float32 ulps.
# Measured worst case on plates 2-60 m away at 0-60 deg incidence: 2.3 ulps of the range;
# tests allow EMBREE_ULPS. Relative to the range that is at most EMBREE_ULPS * eps32.
EMBREE_ULPS = 8
EMBREE_RTOL = EMBREE_ULPS * float(np.finfo(np.float32).eps)


def embree_range_tol_m(range_m) -> float:
    """Tolerance (m) on Embree ranges up to max(range_m): EMBREE_ULPS float32 ulps there."""
    return EMBREE_ULPS * float(np.spacing(np.float32(np.max(range_m))))


def paper_power_w(range_m, incidence_rad, kd, ks, n, optics):
    """Received power (W) of a monostatic shot, the paper's Eqs. 1-3 and 5 written out again.

    The tests' second implementation (reflection.py is the first): mirror angle
    alpha = 2 theta, the specular lobe cut where alpha passes 90 deg.
    """
    r, theta = np.asarray(range_m, float), np.asarray(incidence_rad, float)
    alpha = 2.0 * theta
    lobe = np.where(alpha < np.pi / 2, np.cos(alpha), 0.0) ** n
    f = kd / np.pi + ks * (n + 2) / (2 * np.pi) * lobe                              # Eq. 5
    spot_m2 = np.pi * (r * optics.beam_divergence_rad / 2) ** 2                    # beam section
    irradiance = optics.peak_power_w * optics.transmit_efficiency / spot_m2       # Eq. 2
    radiance = f * irradiance * np.cos(theta)                                      # Eq. 1
    footprint_m2 = spot_m2 / np.cos(theta)
    aperture = np.pi * (optics.aperture_diameter_m / 2) ** 2 / (4 * np.pi * r ** 2)
    return radiance * optics.receive_efficiency * footprint_m2 * np.cos(theta) * 4 * np.pi * aperture  # Eq. 3


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
