"""Issue 33's judge, built before an outsider does: `lidar-sim simulate` of the Mid-40, the
flash array and the box-wing satellite read back and checked with none of the project's
raycast, scan, pose or point-cloud code (test/independent_raycast.py: rosbags + a decoder
of its own, the scenario's motion from its YAML, trimesh's loader and a .glb reader of
the glTF specification, a float64 Moller-Trumbore raycast behind a grid checked against
brute force). Each scenario is run once as shipped (2 frames); plates filling the field,
a row readout and a glTF node tree are run beside them.

- every noise-free point on the mesh along its own ray at its own time (1e-4 m), on the
  part whose material the cloud names;
- every detected point (no false return: `material` 255) within the profile's own range
  error of that hit: |measured - true - bias| <= K_SIGMA sigma, and per material the mean
  and spread are the profile's (Mid-40: bias 0, 2 cm; flash: bias 0, 5 cm), not the
  P-60's Table 2 (bias -0.11 to -0.14 m, sigma 2.8-4.5 cm), which the box-wing's P-60 keeps;
- the Mid-40: shots on the 100,000/s clock, inside the 38.4 deg circle, along the
  first-order two-prism rosette of its profile (docs/model.md), and 10,000 shots in a
  frame (a plate filling the field: every shot is a hit; the Cepton layout's no-return
  points: every shot of the shipped scenario); a run off the frame grid is refused;
- the flash: every point on its pixel's direction of the 256 x 256 grid (ring = row, one
  exposure at t = 0, or row r at r x row_readout_s), 65,536 pixels on the plate, and each
  pixel's power by the flood-lit form of Eqs. 1-3, 5 written out again;
- the box-wing (from its .glb, node transforms applied; the .glb read by the spec too):
  returns from each of the MLI bus, the solar arrays, the radiator and the aluminium
  antenna, each at its own material's Phong reflectance (conftest.paper_power_w).
"""
import contextlib
import io
import json
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from scipy.spatial.transform import Rotation

from lidar_sim_ros.cli import main
from independent_raycast import (GridRaycaster, cast_points, load_triangles, part_materials,
                                 read_bag, read_glb, scenario_files, target_pose)
from conftest import paper_power_w

CONFIG = Path(__file__).resolve().parents[1] / 'config'
EPOCH_NS = 1_700_000_000 * 10**9      # simulate's default --epoch-s (docs/offline.md)
FRAMES = 2
TRUTH_TOL_M = 1e-4                    # docs/offline.md: truth points on the mesh to 1e-4 m
K_SIGMA = 5.5                         # P(|z| > 5.5) = 4e-8 a point: ~0.002 over these runs
FALSE_RETURN = 255
SHIPPED = ('mid40', 'flash', 'box_wing')


def simulate(scenario: Path, out: Path) -> dict:
    """`lidar-sim simulate SCENARIO --frames 2 --out DIR --no-figures` in process; the bag
    read back by independent_raycast.read_bag."""
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(['simulate', str(scenario), '--frames', str(FRAMES), '--out', str(out),
                     '--no-figures']) == 0
    return read_bag(out / 'bag')


class Judged:
    """One run and the independent raycast of every point of both clouds."""

    def __init__(self, scenario: Path, out: Path, triangles=None):
        self.files = scenario_files(scenario)
        self.scenario, self.sensor = self.files['scenario'], self.files['sensor']
        self.bag = simulate(scenario, out)
        self.names = json.loads(self.bag['/lidar/material_names'][0][1].data)
        self.tris = triangles if triangles is not None else load_triangles(self.files['mesh_path'])
        self.part_material = part_materials(self.tris, self.scenario.get('mesh_materials'))
        self.caster = GridRaycaster(self.tris.corners_m)
        self.cast = {topic: [self._cast(cloud) for cloud in self.bag[topic]]
                     for topic in ('/lidar/points', '/lidar/points_truth')}

    def _cast(self, cloud):
        p = cloud.points
        time_s = (cloud.stamp_ns - EPOCH_NS) * 1e-9 + p['t'].astype(float)
        xyz = np.stack([p['x'], p['y'], p['z']], axis=1).astype(float)
        hit_m, face, cos_i = cast_points(self.caster, self.scenario, xyz, time_s)
        return types.SimpleNamespace(points=p, stamp_s=(cloud.stamp_ns - EPOCH_NS) * 1e-9, time_s=time_s, xyz=xyz, range_m=np.linalg.norm(xyz, axis=1),
                                     hit_m=hit_m, face=face, cos_i=cos_i)

    def hit_material(self, face: np.ndarray) -> np.ndarray:
        """The material id (the bag's numbering) of the part each ray hit by our raycast."""
        ids = np.array([self.names.index(m) for m in self.part_material])
        return ids[self.tris.part[face]]

    def range_error(self, material: str) -> tuple[float, float]:
        """(bias m, sigma m) the profile states: the sensor's own range_error, which
        replaces every material's (docs/model.md), or else the material's (Table 2)."""
        own = self.sensor.get('range_error')
        if own is not None:
            return own['bias_m'], own['sigma_m']
        m = next(m for m in self.files['materials'] if m['name'] == material)
        return m['bias_m'], m['sigma_m']


_RUNS: dict = {}


def shipped_run(name: str, tmp_path_factory) -> Judged:
    """The shipped scenario as it is (config/scenario_<name>.yaml), two frames, run once."""
    if name not in _RUNS:
        _RUNS[name] = Judged(CONFIG / f'scenario_{name}.yaml', tmp_path_factory.mktemp(name) / 'out')
    return _RUNS[name]


@pytest.fixture(scope='module', params=SHIPPED)
def shipped(request, tmp_path_factory) -> Judged:
    return shipped_run(request.param, tmp_path_factory)


def plate_scenario(tmp: Path, sensor: str, distance_m: float) -> Path:
    """A still 40 x 40 m PIF plate facing the sensor at distance_m: it fills the field, so
    every shot of a frame is a hit and is on the truth cloud."""
    (tmp / 'plate.obj').write_text(
        'v 0 -20 -20\nv 0 20 -20\nv 0 20 20\nv 0 -20 20\nusemtl PIF\nf 1 2 3\nf 1 3 4\n')
    scenario = {'seed': 1, 'mesh': str(tmp / 'plate.obj'), 'sensor': str(CONFIG / sensor),
                'materials': str(CONFIG / 'materials.yaml'), 'frame_id': 'lidar',
                'initial_pose': {'position_m': [distance_m, 0.0, 0.0], 'quat_xyzw': [0, 0, 0, 1]},
                'motion': {'approach_speed_mps': 0.0, 'tumble_axis': [0, 0, 1], 'tumble_rate_dps': 0.0},
                'effects': []}
    path = tmp / 'scenario.yaml'
    path.write_text(yaml.safe_dump(scenario))
    return path


# ----------------------------------------------------------------------------- every scenario

def test_the_judge_imports_nothing_of_the_project():
    code = ('import sys, independent_raycast; '
            'print(sorted(m for m in sys.modules if m.startswith("lidar_sim_ros")))')
    out = subprocess.run([sys.executable, '-c', code], cwd=Path(__file__).parent,
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '[]'



def test_bag_poses_are_the_scenario_yaml_motion(shipped):
    """/target/pose, which a reader interpolates, is the YAML's closed form."""
    stamps = np.array([s for s, _ in shipped.bag['/target/pose']])
    msgs = [m for _, m in shipped.bag['/target/pose']]
    pos = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in msgs])
    quat = np.array([[m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                      m.pose.orientation.w] for m in msgs])
    rot, want = target_pose(shipped.scenario, (stamps - EPOCH_NS) * 1e-9)
    assert np.abs(pos - want).max() < 1e-9
    assert (Rotation.from_quat(quat) * rot.inv()).magnitude().max() < 1e-9


def test_truth_points_lie_on_the_mesh_along_their_own_ray_at_their_own_time(shipped):
    for k, c in enumerate(shipped.cast['/lidar/points_truth']):
        assert len(c.points) > 1000
        missed = ~np.isfinite(c.hit_m)
        assert not missed.any(), f'frame {k}: {missed.sum()} truth rays miss the mesh'
        residual = np.abs(c.range_m - c.hit_m)
        assert residual.max() < TRUTH_TOL_M, f'frame {k}: max |range - hit| {residual.max():.2e} m'
        assert np.array_equal(shipped.hit_material(c.face), c.points['material'])


def test_detected_points_within_the_profiles_own_range_error(shipped):
    """Each point's measured range minus the first hit on its own ray, against the bias
    and sigma its profile states; per material, the mean and the spread are those."""
    residual, material = [], []
    for k, c in enumerate(shipped.cast['/lidar/points']):
        real = c.points['material'] != FALSE_RETURN
        assert np.isfinite(c.hit_m[real]).all(), f'frame {k}: a detected point off the mesh'
        assert np.array_equal(shipped.hit_material(c.face[real]), c.points['material'][real])
        residual.append((c.range_m - c.hit_m)[real])
        material.append(c.points['material'][real])
    residual, material = np.concatenate(residual), np.concatenate(material)
    assert len(residual) > 1000
    for mid in np.unique(material):
        name = shipped.names[mid]
        bias, sigma = shipped.range_error(name)
        r = residual[material == mid]
        worst = np.abs(r - bias).max()
        assert worst <= K_SIGMA * sigma, f'{name}: max |residual - bias| {worst:.4f} m > {K_SIGMA} x {sigma} m'
        n = len(r)
        if n >= 100:   # sample mean and sd: 5 standard errors
            assert abs(r.mean() - bias) < 5 * sigma / np.sqrt(n) + 1e-4, (name, r.mean(), bias)
            assert abs(r.std() / sigma - 1) < 5 / np.sqrt(2 * n) + 0.01, (name, r.std(), sigma)


# ----------------------------------------------------------------------------- Mid-40

def rosette_direction(scan: dict, time_s: np.ndarray) -> np.ndarray:
    """Unit beam directions (N, 3) of the first-order two-prism deviation at scenario times
    (docs/model.md: p = sum delta_i (cos phi_i, sin phi_i) toward +y, +z; |p| off +x)."""
    rate = np.asarray(scan['prism_rates_hz'], float)
    dev = np.radians(scan['prism_deviation_deg'])
    phi = np.asarray(scan['prism_phase_rad'], float) + 2 * np.pi * rate * time_s[:, None]
    py, pz = (dev * np.cos(phi)).sum(axis=1), (dev * np.sin(phi)).sum(axis=1)
    off, toward = np.hypot(py, pz), np.arctan2(pz, py)
    return np.stack([np.cos(off), np.sin(off) * np.cos(toward), np.sin(off) * np.sin(toward)], axis=1)


def angle_rad(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between rows, robust at 0 (atan2 of cross and dot)."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum('ij,ij->i', a, b))


@pytest.fixture(scope='module')
def mid40(tmp_path_factory) -> Judged:
    return shipped_run('mid40', tmp_path_factory)


def test_mid40_shots_on_the_100khz_clock_inside_the_circle_along_the_rosette(mid40):
    scan = mid40.sensor['scan']
    assert scan['shot_rate_hz'] == 100_000.0 and mid40.sensor['frame_rate_hz'] == 10.0
    half_field = np.radians(sum(scan['prism_deviation_deg']))
    assert np.isclose(2 * np.degrees(half_field), 38.4)
    for topic in ('/lidar/points', '/lidar/points_truth'):
        for k, c in enumerate(mid40.cast[topic]):
            shot = c.points['t'].astype(float) * 100_000.0
            assert np.abs(shot - np.round(shot)).max() < 1e-3          # t = i / 100,000 s
            assert shot.min() > -0.5 and shot.max() < 10_000 - 0.5    # i in [0, 10,000)
            assert len(np.unique(np.round(shot))) == len(shot)        # one point a shot
            off_axis = angle_rad(c.xyz, np.array([[1.0, 0.0, 0.0]]))
            assert off_axis.max() <= half_field + 1e-7, np.degrees(off_axis.max())
            along = angle_rad(c.xyz, rosette_direction(scan, c.stamp_s + np.round(shot) / 100_000.0))
            assert along.max() < 1e-6, f'{topic} frame {k}: {along.max():.2e} rad off the rosette'


NO_RETURN = 1 << 5          # Cepton SDK3 point flag: a shot that came back empty


def test_mid40_every_shot_at_100khz_as_the_cepton_layout_shows_them(mid40, tmp_path):
    """The shipped scenario as it is, in the layout that publishes every shot
    (`--point-layout cepton --no-return-points`): 10,000 points a frame, one each 10 us
    (timestamp_s, timestamp_us: absolute), the returns those of the native cloud."""
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(['simulate', str(CONFIG / 'scenario_mid40.yaml'), '--frames', str(FRAMES),
                     '--out', str(tmp_path), '--no-figures', '--point-layout', 'cepton',
                     '--no-return-points']) == 0
    clouds = read_bag(tmp_path / 'bag')['/cepton_pcl2']
    for k, (cloud, native) in enumerate(zip(clouds, mid40.bag['/lidar/points'])):
        p = cloud.points
        time_ns = p['timestamp_s'].astype(np.int64) * 10**9 + p['timestamp_us'].astype(np.int64) * 1000
        assert cloud.stamp_ns == native.stamp_ns == EPOCH_NS + k * 100_000_000
        np.testing.assert_array_equal(time_ns - cloud.stamp_ns, np.arange(10_000) * 10_000)
        returned = (p['flags'] & NO_RETURN) == 0
        assert returned.sum() == len(native.points)
        xyz = np.stack([p['x'], p['y'], p['z']], axis=1)[returned].astype(float)
        assert angle_rad(xyz, np.array([[1.0, 0.0, 0.0]])).max() <= np.radians(19.2) + 1e-7


def test_mid40_frame_is_10000_shots_in_100ms(tmp_path):
    """A plate filling the field: every shot hits, so the truth cloud holds the frame's
    every shot: 10,000 at i / 100,000 s, i = 0..9999, reaching the 19.2 deg rim."""
    out = Judged(plate_scenario(tmp_path, 'livox_mid40.yaml', 15.0), tmp_path / 'out')
    scan = out.sensor['scan']
    for k, c in enumerate(out.cast['/lidar/points_truth']):
        shot = np.sort(c.points['t'].astype(float)) * 100_000.0
        assert len(shot) == 10_000
        np.testing.assert_allclose(shot, np.arange(10_000), atol=1e-3)
        off_axis = np.degrees(angle_rad(c.xyz, np.array([[1.0, 0.0, 0.0]])))
        assert 19.15 < off_axis.max() <= 19.2 + 1e-5
        assert np.abs(c.range_m - c.hit_m).max() < TRUTH_TOL_M
        along = angle_rad(c.xyz, rosette_direction(scan, c.time_s))
        assert along.max() < 1e-6


# ----------------------------------------------------------------------------- flash

def flash_pixel(scan: dict, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) as real numbers of each point's direction on the pinhole grid
    (1, u_c, v_r): u_c = tan(fov_az/2) (1 - (2c + 1)/cols), v_r likewise with rows."""
    u, v = xyz[:, 1] / xyz[:, 0], xyz[:, 2] / xyz[:, 0]
    col = (1 - u / np.tan(np.radians(scan['fov_az_deg']) / 2)) * scan['cols'] / 2 - 0.5
    row = (1 - v / np.tan(np.radians(scan['fov_el_deg']) / 2)) * scan['rows'] / 2 - 0.5
    return row, col


def pixel_solid_angle_sr(scan: dict, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """Exact solid angle of each pixel's rectangle on the image plane at unit distance:
    Omega = sum of +-atan(u v / sqrt(1 + u^2 + v^2)) over its corners."""
    tu, tv = np.tan(np.radians(scan['fov_az_deg']) / 2), np.tan(np.radians(scan['fov_el_deg']) / 2)
    u0, u1 = tu * (1 - 2 * col / scan['cols']), tu * (1 - 2 * (col + 1) / scan['cols'])
    v0, v1 = tv * (1 - 2 * row / scan['rows']), tv * (1 - 2 * (row + 1) / scan['rows'])

    def corner(u, v):
        return np.arctan(u * v / np.sqrt(1 + u * u + v * v))
    return np.abs(corner(u1, v1) - corner(u0, v1) - corner(u1, v0) + corner(u0, v0))


def flash_power_w(judged: Judged, c) -> np.ndarray:
    """Each pixel's received power (W), Eqs. 1-3, 5 with the pulse spread over the flood's
    solid angle and the footprint the pixel's own: P_o tau_t tau_r f cos(theta) pi (D/2)^2
    / r^2 x Omega_pix / Omega_illum (docs/model.md), with our range and incidence."""
    optics, scan = judged.sensor['optics'], judged.sensor['scan']
    a, b = np.radians(optics['flood']['field_az_deg']), np.radians(optics['flood']['field_el_deg'])
    illum_sr = 4 * np.arcsin(np.sin(a / 2) * np.sin(b / 2))
    row, col = (np.round(x) for x in flash_pixel(scan, c.xyz))
    mats = {m['name']: m for m in judged.files['materials']}
    m = [mats[judged.names[i]] for i in c.points['material']]
    kd, ks, n = (np.array([x[key] for x in m]) for key in ('kd', 'ks', 'n'))
    theta = np.arccos(np.clip(c.cos_i, 0, 1))
    lobe = np.where(2 * theta < np.pi / 2, np.cos(2 * theta), 0.0) ** n
    f = kd / np.pi + ks * (n + 2) / (2 * np.pi) * lobe
    return (optics['peak_power_w'] * optics['transmit_efficiency'] * optics['receive_efficiency']
            * f * c.cos_i * np.pi * (optics['aperture_diameter_m'] / 2) ** 2 / c.hit_m ** 2
            * pixel_solid_angle_sr(scan, row, col) / illum_sr)


@pytest.fixture(scope='module')
def flash(tmp_path_factory) -> Judged:
    return shipped_run('flash', tmp_path_factory)


def test_flash_points_on_their_pixels_directions_one_exposure(flash):
    scan = flash.sensor['scan']
    assert (scan['rows'], scan['cols']) == (256, 256) and scan['row_readout_s'] == 0.0
    for topic in ('/lidar/points', '/lidar/points_truth'):
        for c in flash.cast[topic]:
            row, col = flash_pixel(scan, c.xyz)
            # float32 xyz: a pixel is 1.4 mrad, the stored direction good to ~1e-7 rad
            assert np.abs(row - np.round(row)).max() < 1e-3
            assert np.abs(col - np.round(col)).max() < 1e-3
            assert (np.round(row) == c.points['ring']).all()
            assert (0 <= row.min()) and row.max() <= 255 and 0 <= col.min() and col.max() <= 255
            pixel = np.round(row) * 256 + np.round(col)
            assert len(np.unique(pixel)) == len(pixel)
            assert (c.points['t'] == 0).all()


def test_flash_pixel_power_is_the_flood_lit_form(flash):
    saturation_w = flash.sensor['detection']['saturation_power_w']
    for c in flash.cast['/lidar/points_truth']:
        rel = c.points['intensity'] * saturation_w / flash_power_w(flash, c) - 1
        assert np.abs(rel).max() < 1e-4, np.abs(rel).max()


def test_flash_frame_is_every_pixel_of_the_256_grid(tmp_path):
    out = Judged(plate_scenario(tmp_path, 'flash_256.yaml', 30.0), tmp_path / 'out')
    for c in out.cast['/lidar/points_truth']:
        row, col = flash_pixel(out.sensor['scan'], c.xyz)
        pixel = np.round(row).astype(int) * 256 + np.round(col).astype(int)
        assert np.array_equal(np.sort(pixel), np.arange(256 * 256))
        assert np.abs(c.range_m - c.hit_m).max() < TRUTH_TOL_M


# ----------------------------------------------------------------------------- box-wing

@pytest.fixture(scope='module')
def box_wing(tmp_path_factory) -> Judged:
    return shipped_run('box_wing', tmp_path_factory)


def test_box_wing_every_part_returns_at_its_own_materials_reflectance(box_wing):
    """Each part of the .glb (by its glTF material, through mesh_materials) returns, and
    each point's power is the paper's Eqs. 1-3, 5 with the Phong kd, ks, n of the
    material of the part our raycast hit."""
    assert box_wing.files['mesh_path'].suffix == '.glb'
    assert set(box_wing.part_material) == {'MLI', 'SOLAR_ARRAY', 'WHITE_PAINT', 'ALUMINIUM'}
    optics = types.SimpleNamespace(**box_wing.sensor['optics'])
    saturation_w = box_wing.sensor['detection']['saturation_power_w']
    mats = {m['name']: m for m in box_wing.files['materials']}
    for topic in ('/lidar/points', '/lidar/points_truth'):
        for c in box_wing.cast[topic]:
            counts = np.bincount(c.points['material'], minlength=len(box_wing.names))
            assert (counts[[box_wing.names.index(n) for n in mats]] >= 100).all(), counts
            hit = box_wing.hit_material(c.face)
            assert np.array_equal(hit, c.points['material'])
            for name, m in mats.items():
                sel = hit == box_wing.names.index(name)
                want = paper_power_w(c.hit_m[sel], np.arccos(np.clip(c.cos_i[sel], 0, 1)),
                                     m['kd'], m['ks'], m['n'], optics) / saturation_w
                rel = c.points['intensity'][sel] / want - 1
                assert np.abs(rel).max() < 1e-4, (topic, name, np.abs(rel).max())


def test_mid40_run_off_the_frame_grid_is_refused_on_it_follows_the_prisms(tmp_path, capsys):
    """The prisms turn on the frame clock (frame k from k x the period: Simulator frame
    index, the node's clock, compare's matching). `--start-s 0.05` ran with rc 0 and put
    every shot 0.05 s of prism rotation away from the rosette at its own time (0.195 rad
    off, the 2nd frame's prisms where a run from 0 has them): now refused, naming the
    value. `--start-s 0.3`, three periods, follows the prisms at every shot's own time."""
    scenario = CONFIG / 'scenario_mid40.yaml'
    code = main(['simulate', str(scenario), '--frames', '1', '--start-s', '0.05',
                 '--out', str(tmp_path / 'off'), '--no-figures'])
    err = capsys.readouterr().err
    assert code == 2 and not (tmp_path / 'off' / 'bag').exists()
    assert '--start-s 0.05' in err and 'frame period' in err and len(err.strip().splitlines()) == 1
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(['simulate', str(scenario), '--frames', '1', '--start-s', '0.3',
                     '--out', str(tmp_path / 'on'), '--no-figures']) == 0
    sensor = scenario_files(scenario)['sensor']
    for cloud in read_bag(tmp_path / 'on' / 'bag')['/lidar/points_truth']:
        p = cloud.points
        xyz = np.stack([p['x'], p['y'], p['z']], axis=1).astype(float)
        time_s = (cloud.stamp_ns - EPOCH_NS) * 1e-9 + p['t'].astype(float)
        assert abs((cloud.stamp_ns - EPOCH_NS) * 1e-9 - 0.3) < 1e-9
        assert angle_rad(xyz, rosette_direction(sensor['scan'], time_s)).max() < 1e-6


def test_flash_row_readout_each_row_at_its_own_time(tmp_path):
    """The flash profile with a 0.2 ms row readout (row 255 read 51 ms after row 0) on a
    target closing at 5 m/s and tumbling at 90 deg/s: a row at the wrong time would sit
    centimetres off the mesh. Every point: t = row x 0.2 ms, on the mesh at that time."""
    sensor = yaml.safe_load((CONFIG / 'flash_256.yaml').read_text())
    sensor['scan']['row_readout_s'] = 2e-4
    (tmp_path / 'flash_rows.yaml').write_text(yaml.safe_dump(sensor))
    scenario = yaml.safe_load((CONFIG / 'scenario_flash.yaml').read_text())
    scenario.update(mesh=str((CONFIG / scenario['mesh']).resolve()), sensor='flash_rows.yaml',
                    materials=str(CONFIG / scenario['materials']))
    scenario['motion'].update(approach_speed_mps=5.0, tumble_rate_dps=90.0)
    (tmp_path / 'scenario.yaml').write_text(yaml.safe_dump(scenario))
    out = Judged(tmp_path / 'scenario.yaml', tmp_path / 'out')
    for topic in ('/lidar/points', '/lidar/points_truth'):
        for c in out.cast[topic]:
            row, _ = flash_pixel(out.sensor['scan'], c.xyz)
            assert np.abs(c.points['t'] - np.round(row) * 2e-4).max() < 1e-8
            assert np.ptp(c.points["t"]) > 0.015      # the body spans ~100 rows: 20 ms
    for c in out.cast['/lidar/points_truth']:
        assert np.isfinite(c.hit_m).all() and np.abs(c.range_m - c.hit_m).max() < TRUTH_TOL_M


def test_the_judges_raycast_on_a_box_and_against_brute_force():
    """The grid visits every cell a ray crosses: its first hits are those of a single cell
    holding every triangle (brute force), on the rocket body; on a box, the closed form."""
    box = trimesh.creation.box(extents=(2.0, 4.0, 6.0))
    caster = GridRaycaster(box.triangles, cells_on_longest_axis=7)
    rng = np.random.default_rng(3)
    target = rng.uniform(-1, 1, (500, 2)) * [2.0, 3.0]           # on the x = -1 face
    origin = np.array([-10.0, 0.0, 0.0])
    d = np.column_stack([np.full(500, 9.0), target - origin[1:]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hit_m, _ = caster.first_hit(np.tile(origin, (500, 1)), d)
    np.testing.assert_allclose(hit_m, 9.0 / d[:, 0], rtol=1e-12)

    tris = load_triangles(Path(__file__).resolve().parents[1] / 'meshes' / 'rocket_body.obj')
    grid, brute = GridRaycaster(tris.corners_m), GridRaycaster(tris.corners_m, cells_on_longest_axis=1)
    origins = rng.normal(size=(300, 3)) * 20
    d = rng.uniform(-2.5, 2.5, (300, 3)) * [1, 1, 2.4] - origins    # toward the body (4 x 4 x 10 m)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, fa = grid.first_hit(origins, d)
    b, fb = brute.first_hit(origins, d, chunk=8)
    assert np.isfinite(a).sum() > 150
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(fa, fb)


def write_glb(path: Path, parts: list, nodes: list) -> Path:
    """A .glb written from the glTF 2.0 specification: ``parts`` [(mesh name, material
    name, vertices (V, 3), faces (F, 3))], ``nodes`` the glTF node dicts (as JSON)."""
    binary, views, accessors, meshes, materials = b'', [], [], [], []
    for name, material, verts, faces in parts:
        for array, kind, ctype in ((np.asarray(verts, '<f4'), 'VEC3', 5126),
                                   (np.asarray(faces, '<u4').ravel(), 'SCALAR', 5125)):
            views.append({'buffer': 0, 'byteOffset': len(binary), 'byteLength': array.nbytes})
            acc = {'bufferView': len(views) - 1, 'componentType': ctype, 'type': kind,
                   'count': len(array)}
            if kind == 'VEC3':
                acc.update(min=array.min(axis=0).tolist(), max=array.max(axis=0).tolist())
            accessors.append(acc)
            binary += array.tobytes()
        if material not in materials:
            materials.append(material)
        meshes.append({'name': name, 'primitives': [{
            'attributes': {'POSITION': len(accessors) - 2}, 'indices': len(accessors) - 1,
            'material': materials.index(material), 'mode': 4}]})
    roots = sorted(set(range(len(nodes))) - {c for n in nodes for c in n.get('children', [])})
    gltf = {'asset': {'version': '2.0'}, 'scene': 0, 'scenes': [{'nodes': roots}], 'nodes': nodes,
            'meshes': meshes, 'materials': [{'name': m} for m in materials],
            'accessors': accessors, 'bufferViews': views, 'buffers': [{'byteLength': len(binary)}]}
    text = json.dumps(gltf).encode()
    text += b' ' * (-len(text) % 4)
    binary += b'\0' * (-len(binary) % 4)
    body = (np.array([len(text), 0x4E4F534A], '<u4').tobytes() + text
            + np.array([len(binary), 0x004E4942], '<u4').tobytes() + binary)
    path.write_bytes(np.array([0x46546C67, 2, 12 + len(body)], '<u4').tobytes() + body)
    return path


def test_glb_node_hierarchy_read_by_the_spec_by_trimesh_and_by_the_simulator(tmp_path):
    """A CAD export places its parts by a node tree: a bus under a rotated, scaled,
    translated root (TRS), a wing under it by a column-major matrix, a mast at the root.
    The judge's two readings (trimesh; the spec by hand) agree, and every point the
    simulator returns lies on the parts where the spec puts them, with their materials."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    wing = trimesh.creation.box(extents=(0.05, 3.0, 1.0))
    wing_matrix = np.eye(4)
    wing_matrix[:3, :3] = Rotation.from_euler('x', 20, degrees=True).as_matrix()
    wing_matrix[:3, 3] = (0.0, 1.8, 0.0)
    nodes = [{'name': 'root', 'children': [1], 'translation': [0.0, 0.0, 0.3],
              'rotation': Rotation.from_euler('zy', [25, -10], degrees=True).as_quat().tolist(),
              'scale': [1.2, 1.0, 1.5]},
             {'name': 'bus', 'mesh': 0, 'children': [2]},
             {'name': 'wing', 'mesh': 1, 'matrix': wing_matrix.T.ravel().tolist()},
             {'name': 'mast', 'mesh': 2, 'translation': [-1.0, -1.5, -0.5]}]
    glb = write_glb(tmp_path / 'tree.glb', [('bus_mesh', 'foil', box.vertices, box.faces),
                                            ('wing_mesh', 'cells', wing.vertices, wing.faces),
                                            ('mast_mesh', 'metal', box.vertices * 0.3, box.faces)], nodes)
    by_spec, by_trimesh = read_glb(glb), load_triangles(glb)

    def rows(t, material):
        sel = np.isin(t.part, [i for i, n in enumerate(t.names) if n[0] == material])
        c = t.corners_m[sel].reshape(int(sel.sum()), 9)
        return c[np.lexsort(c.T[::-1])]
    for material in ('foil', 'cells', 'metal'):
        np.testing.assert_allclose(rows(by_spec, material), rows(by_trimesh, material), atol=1e-6)
    # the wing really is where the tree puts it: root (T R S) x wing matrix
    root = np.eye(4)
    root[:3, :3] = Rotation.from_quat(nodes[0]['rotation']).as_matrix() * [1.2, 1.0, 1.5]
    root[:3, 3] = nodes[0]['translation']
    want = trimesh.transform_points(wing.vertices, root @ wing_matrix)[wing.faces]
    w = np.asarray(want).reshape(-1, 9)
    np.testing.assert_allclose(rows(by_spec, 'cells'), w[np.lexsort(w.T[::-1])], atol=1e-6)

    scenario = {'seed': 2, 'mesh': 'tree.glb', 'sensor': str(CONFIG / 'cepton_vista_p60.yaml'),
                'materials': str(CONFIG / 'materials_box_wing.yaml'), 'frame_id': 'lidar',
                'mesh_materials': {'foil': 'MLI', 'cells': 'SOLAR_ARRAY', 'metal': 'ALUMINIUM'},
                'initial_pose': {'position_m': [8.0, 0.0, 0.0],
                                 'quat_xyzw': Rotation.from_euler('y', 30, degrees=True).as_quat().tolist()},
                'motion': {'approach_speed_mps': 0.5, 'tumble_axis': [0, 0, 1], 'tumble_rate_dps': 20.0},
                'effects': []}
    (tmp_path / 'scenario.yaml').write_text(yaml.safe_dump(scenario))
    out = Judged(tmp_path / 'scenario.yaml', tmp_path / 'out', triangles=by_spec)
    for c in out.cast['/lidar/points_truth']:
        assert np.isfinite(c.hit_m).all() and np.abs(c.range_m - c.hit_m).max() < TRUTH_TOL_M
        assert np.array_equal(out.hit_material(c.face), c.points['material'])
        assert set(np.unique(c.points['material'])) == {0, 1, 3}      # MLI, SOLAR_ARRAY, ALUMINIUM


def test_box_wing_glb_read_by_the_spec_is_trimeshs_reading(box_wing):
    """The judge's trimesh reading of meshes/box_wing_satellite.glb (what the box-wing
    tests cast against) is the glTF specification's, part by part."""
    by_spec = read_glb(box_wing.files['mesh_path'])
    assert sorted(by_spec.names) == sorted(box_wing.tris.names)
    for names in by_spec.names:
        a = by_spec.corners_m[by_spec.part == by_spec.names.index(names)].reshape(-1, 9)
        b = box_wing.tris.corners_m[box_wing.tris.part == box_wing.tris.names.index(names)].reshape(-1, 9)
        np.testing.assert_allclose(a[np.lexsort(a.T[::-1])], b[np.lexsort(b.T[::-1])], atol=1e-6)
