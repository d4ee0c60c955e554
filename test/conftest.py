"""Shared fixtures: small scenes built in code so tests know their closed forms."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from lidar_sim_ros.core.config import MaterialConfig, MaterialsConfig, SensorConfig, parse
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.geometry import Target

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / 'config'


# Embree intersects in float32, so a raycast range is exact only to a few float32 ulps.
# Measured worst case on plates 2-60 m away at 0-60 deg incidence: 2.3 ulps of the range;
# tests allow EMBREE_ULPS. Relative to the range that is at most EMBREE_ULPS * eps32.
EMBREE_ULPS = 8
EMBREE_RTOL = EMBREE_ULPS * float(np.finfo(np.float32).eps)


def copy_config(tmp_path: Path, names=('scenario.yaml', 'cepton_vista_p60.yaml',
                                      'materials.yaml')) -> Path:
    """The package's config files ``names`` copied into ``tmp_path`` to be edited; the
    scenario's mesh made absolute (the mesh stays where it is)."""
    import shutil
    import yaml
    for name in names:
        shutil.copy(CONFIG / name, tmp_path / name)
    if 'scenario.yaml' in names:
        edit_yaml(tmp_path / 'scenario.yaml',
                  lambda d: d.update(mesh=str(CONFIG.parent / 'meshes' / 'rocket_body.obj')))
    return tmp_path


def edit_yaml(path: Path, fn) -> None:
    """Load the YAML file, let ``fn`` change the data in place, write it back."""
    import yaml
    data = yaml.safe_load(path.read_text())
    fn(data)
    path.write_text(yaml.safe_dump(data))


def private_domain_id(base: int, span: int) -> int:
    """A ROS domain id in [base, base + span) for a test's DDS traffic.

    From the pid, so that runs of the suite side by side rarely meet; and distinct for
    the workers of one pytest-xdist run (each worker takes every W-th id, W workers).
    """
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    index = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0')[2:])
    slots = max(span // workers, 1)
    return base + (os.getpid() % slots) * workers + index


# Modules that start processes of their own whose timing matters (ROS 2 nodes over DDS,
# a Dask cluster): `make test` runs them after the rest, alone (marker ``serial``). A new
# module that starts nodes or joins a DDS domain belongs here.
SERIAL_MODULES = {'test_node_dds', 'test_node_plugins', 'test_node_cepton_dds', 'test_node_sun_dds', 'test_node_demo', 'test_gnc_demo',
                  'test_gnc_node', 'test_warm_up', 'test_recorder', 'test_campaign',
                  'test_node_latency', 'test_loop_dds', 'test_node_cepton_udp', 'test_loop_nodes'}
# Tests that share no module fixture and each run long: pytest-xdist spreads them one by one
# (the docs pages' transcripts were one unit of about two minutes of CPU).
SPREAD_TESTS = {'test_compare_foreign.py::test_foreign_loop',
                'test_docs.py::test_documented_commands_print_what_the_page_quotes'}


def pytest_ignore_collect(collection_path: Path, config):
    """``-m serial`` / ``-m 'not serial'`` (the two parts of make test) do not import the
    modules whose every test the marker deselects (each part saved ~5 s of CPU of imports
    in each process: rclpy, Dask, the nodes; the tests run are the same)."""
    if collection_path.suffix != '.py' or not collection_path.name.startswith('test_'):
        return None
    expr = ' '.join((config.getoption('markexpr', '') or '').split())
    serial = collection_path.stem in SERIAL_MODULES
    if (expr == 'serial' and not serial) or (expr == 'not serial' and serial):
        return True
    return None


def _spread(nodeid: str) -> bool:
    return nodeid.split('[', 1)[0].endswith(tuple(SPREAD_TESTS))


@pytest.hookimpl(tryfirst=True)   # before ``-m`` deselects by marker
def pytest_collection_modifyitems(config, items):
    """The tests of SERIAL_MODULES get the marker ``serial``. On a pytest-xdist worker
    the SPREAD_TESTS come first: the long units start first and the modules fill the end."""
    for item in items:
        if item.module.__name__ in SERIAL_MODULES:
            item.add_marker(pytest.mark.serial)
    if hasattr(config, 'workerinput'):
        items.sort(key=lambda item: not _spread(item.nodeid))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``pytest -n N --dist loadscope`` (make test): one work unit per module, so that a
    module fixture (a simulated recording, a node) is built on one worker only, except
    the tests of SPREAD_TESTS, each a unit of its own; SERIAL_MODULES form one unit, so
    that they never run side by side. (``--dist loadgroup`` cannot do this: pytest-xdist
    3.8 groups by rewriting node ids, which pytest 9.2 ignores.)"""
    if config.getvalue('dist') != 'loadscope':
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ModuleScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split('::', 1)[0]
            if Path(path).stem in SERIAL_MODULES:
                return 'serial'
            return nodeid if _spread(nodeid) else path

    config.option.loadscopereorder = False   # units in collection order (above)
    return ModuleScheduling(config, log)


# LIDAR_SIM_TEST_TIMES=FILE: one JSON line per test (its worker, wall start and end, and
# the CPU seconds of the test process and of the child processes it waited for, fixture
# setup included), to see where `make test`'s time budget goes (CPU, which a busy machine
# does not inflate, and how the workers' units line up in wall time).
_TIMES = os.environ.get('LIDAR_SIM_TEST_TIMES')
if _TIMES:
    import json
    import time

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        wall0, cpu0 = time.time(), os.times()
        yield
        cpu = os.times()
        row = {'test': item.nodeid, 'worker': os.environ.get('PYTEST_XDIST_WORKER', 'main'),
               'start': wall0, 'end': time.time(),
               'cpu': cpu.user + cpu.system - cpu0.user - cpu0.system,
               'children': (cpu.children_user + cpu.children_system
                            - cpu0.children_user - cpu0.children_system)}
        with open(_TIMES, 'a') as f:
            f.write(json.dumps(row) + '\n')


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


def ahead_fit_data(material, p_model_w, measured_m, sigma_m: float, threshold_power_w: float):
    """A ``FitData`` of matched points 10 m ahead along +x (no raycast, normal
    incidence): on ``material``, the model's power ``p_model_w`` (W, the intensity the
    same), measured ``measured_m`` (m), range noise ``sigma_m`` (m)."""
    from lidar_sim_ros.compare.model import likelihood as lk
    from lidar_sim_ros.core.effects.base import ReturnContext
    from lidar_sim_ros.core.geometry import Hits
    from lidar_sim_ros.core.pipeline import Prediction
    material = np.asarray(material, int)
    n = len(material)
    rng_m = np.full(n, 10.0)
    ctx = ReturnContext(range_m=rng_m, incidence_rad=np.zeros(n), material=material,
                        power_w=p_model_w, intensity=p_model_w, t_s=np.zeros(n),
                        az_rad=np.zeros(n), el_rad=np.zeros(n), laser=np.zeros(n, int),
                        divergence_rad=0.002, hit=np.ones(n, bool),
                        threshold_power_w=threshold_power_w)
    hits = Hits(np.ones(n, bool), rng_m, np.zeros((n, 3)), np.zeros(n), material,
                np.zeros(n, int))
    pred = Prediction(ctx, hits, np.tile([1.0, 0.0, 0.0], (n, 1)), np.zeros(n),
                      np.full(n, sigma_m))
    return lk.FitData(measured_range_m=measured_m, baseline=pred, cast=lambda e: pred,
                      unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                      range_window_m=(0.0, 100.0))


def plane_fit_data(expected_m, measured_m, normal, u, t_s, sigma_m: float,
                   range_window_m: tuple[float, float], az_rad=None, el_rad=None):
    """A ``FitData`` builder over the rays ``idx`` of a closed-form scene (no raycast):
    each ray ``u`` expects ``expected_m`` on a surface of ``normal`` (material 0, normal
    incidence, one power), measured ``measured_m`` at ``t_s``, sigma ``sigma_m``; the
    rays' azimuth and elevation (rad) where given, else 0."""
    from lidar_sim_ros.compare.model import likelihood as lk
    from lidar_sim_ros.core.effects.base import ReturnContext
    from lidar_sim_ros.core.geometry import Hits
    from lidar_sim_ros.core.pipeline import Prediction

    def data(idx: np.ndarray) -> 'lk.FitData':
        m = len(idx)
        one, zero = np.ones(m), np.zeros(m, int)
        ctx = ReturnContext(range_m=expected_m[idx], incidence_rad=0 * one, material=zero,
                            power_w=1e-6 * one, intensity=one, t_s=t_s[idx],
                            az_rad=0 * one if az_rad is None else az_rad[idx],
                            el_rad=0 * one if el_rad is None else el_rad[idx],
                            laser=zero, divergence_rad=1e-3,
                            hit=np.ones(m, bool), threshold_power_w=1e-9, direction=u[idx],
                            normal=-normal[idx])
        hits = Hits(np.ones(m, bool), expected_m[idx], -normal[idx], 0 * one, zero, zero, None,
                    one)
        pred = Prediction(ctx, hits, u[idx], 0 * one, sigma_m * one)
        return lk.FitData(measured_range_m=measured_m[idx], baseline=pred, cast=lambda e: pred,
                          unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                          range_window_m=range_window_m)
    return data


def three_planes(rng: np.random.Generator, n: int):
    """``n`` rays over three tilted planes, 12 x 8 deg across, through one point 10 m
    ahead: azimuth and elevation (rad), unit direction and the plane's unit normal per
    ray, and that point (m), drawn from ``rng``."""
    az, el = rng.uniform(-0.1, 0.1, n), rng.uniform(-0.07, 0.07, n)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    normals = np.array([[-0.8, -0.5, 0.33], [-0.9, 0.1, -0.42], [-0.75, 0.6, 0.28]])
    normal = (normals / np.linalg.norm(normals, axis=1, keepdims=True))[
        np.digitize(az, [-0.033, 0.033])]
    return az, el, u, normal, np.array([10.0, 0.0, 0.0])


def turned_plane_ranges(normal, u, centre, rotvec_rad):
    """Range (m) along each ray ``u`` to its plane (``normal``, through ``centre``) turned
    by ``rotvec_rad`` (rad; one per ray) about ``centre``."""
    from scipy.spatial.transform import Rotation
    n_rot = Rotation.from_rotvec(rotvec_rad).apply(normal)
    return np.einsum('ij,ij->i', n_rot, np.tile(centre, (len(u), 1))) / np.einsum(
        'ij,ij->i', u, n_rot)


def three_plane_rays(rng: np.random.Generator, n_clouds: int, per_cloud: int):
    """Rays over three tilted planes (``three_planes``) in ``n_clouds`` clouds of 0.1 s:
    (cloud index, time s, unit direction, the plane's normal) per ray, drawn from ``rng``."""
    n = n_clouds * per_cloud
    _, _, u, normal, _ = three_planes(rng, n)
    cloud = np.repeat(np.arange(n_clouds), per_cloud)
    t = cloud * 0.1 + rng.uniform(0.0, 0.09, n)
    return cloud, t, u, normal
