"""A deliberately foreign LiDAR simulator: measured-looking bags for testing `lidar-sim compare`.

`lidar-sim compare` will be judged on data "made by a different simulator (or a real
sensor)". Datasets made by our own simulator share its scan pattern, mesh, power model
and effect formulas with the model under test, which flatters it. This module shares
none of them: it never imports ``lidar_sim_ros.core`` (pipeline, scan, reflection,
detection, effects). Only the public contract of issue 4 is common: a rosbag2 with
``sensor_msgs/PointCloud2`` on ``/lidar/points`` (lidar frame, REP-103) and the target
body pose in the lidar frame (``p_lidar = R p_body + t``) as ``geometry_msgs/PoseStamped``
on ``/target/pose``, and an OBJ+MTL whose ``usemtl`` names are those of
``config/materials.yaml``.

What differs from our simulator, on purpose:

* scan: a boustrophedon raster or a two-prism rosette over 40 x 20 deg (no Lissajous
  tiles, no laser/ring field);
* target: a satellite (box bus, adapter cylinder, fairing cone, nozzle, a detached
  solar panel on a gap) built here with trimesh, cast with trimesh's Embree intersector;
* radiometry: a Blinn-Phong BRDF with its own reflectances and a single cos(theta)
  link budget (paper Eqs. 1-3 have cos^2), in its own units;
* intensity: 8-bit log counts, 16-bit saturating counts, range-compensated
  reflectivity, a reflectivity compensated for range and for a Lambertian incidence law
  (``reflectivity_lambert``: P r^2 / cos(theta) ** ``intensity_cos_exponent``, 1 by
  default, as a sensor calibrated on white panels
  reports it; on the Blinn-Phong surfaces it is not a monotone function of the received
  power, which is what the timing walk follows: two returns of one power read apart by
  1 / cos(theta)), or no intensity field at all; with ``intensity_scale='log'`` any of
  them is replaced by log counts, 40 log10(P / 1 nW) (float32), another lab's flash
  sensor's scale;
* per-point time: ``t`` float32 seconds, ``t`` uint32 nanoseconds, a float64 absolute
  ``timestamp`` field (another name), or none (cloud stamped mid-scan);
* baseline range error: the paper's Table 2 per material, each bias moved by up to
  +-1 cm and each sigma scaled by 0.8-1.2 (seeded), i.e. close to but not exactly the
  materials config;
* every effect with its own functional form (see the ``*_m`` functions below), one or
  several at once, and two outside the compare catalogue: a range bias that depends on
  the scan azimuth, as an encoder or mirror-facet error gives, and lab multipath: with
  probability p a shot on a mirror-like material (specular albedo >= 0.5: MLI, PSS)
  beyond 25 deg incidence, whose mirror direction d - 2 (d.n) n meets a bright lab
  surface, returns that way and back, so its range is r + L, L the path from the
  surface to the room (a box around the target, its parts outside the sensor's view
  bright, the rest a black backdrop; with clutter the fixtures too): a few metres,
  set by the lab, so the returns bunch behind the surface (``multipath_extra_m``); the
  catalogue's multipath (a second surface of the target itself) has no room to cast at,
  so these datasets expect no effect named. The catalogue's kind is ``via: target``: the
  same mirror ray, cast at the satellite (with ``fins``: two diffuse radiator fins
  standing out of the mirror-like MLI sides, a concave corner), returns with probability
  p at r + |AB| (``target_multipath_returns``);
* a cyclic range error of the receiver (``range_cyclic``: ``a_m`` cos(2 pi r /
  ``period_m``), outside the catalogue), a function of the range alone, which on an
  approach moves each cloud as a per-cloud reference pose would;
* lasers (``lasers`` > 0): the shots are fired round-robin by that many lasers over the
  whole scan (as multi-laser Risley scanners do), written as a laser id field; the
  hidden ``laser_bias`` gives each laser its own range offset (a seeded draw of sd
  ``sd_m`` about zero, or the given ``offsets_m``); the hidden ``laser_pointing`` turns
  each laser's beam off the direction it reports its points along: a turn of ``a`` about
  the lidar z axis, then of ``e`` about the axis d x z (a seeded draw of sd ``sd_deg``
  per laser for each; ``laser_turns_of``), the shot cast along the turned beam;
* layout: ours-like generic fields, or the Cepton SDK3 driver's (``layout='cepton'``:
  x, y, z, intensity = a reflectivity in 1 % steps of this sensor's own scale,
  timestamp_s + timestamp_us INT32, flags UINT16 with SATURATED/NO_RETURN, channel_id
  UINT16, on ``/cepton_pcl2`` in frame ``cepton3`` stamped at the frame start), from
  the issue's field list, not from lidar_sim_ros.io.cepton;
* what labs add: shot-to-shot amplitude fluctuation (speckle: the pulse that drives
  both the intensity and the timing walk), lab clutter (a wall behind the target, a
  support jig, a cable across the view: static returns that are not the target), and
  clouds without per-point time stamped at the start, middle or end of the scan.

Entry point: :func:`generate` (a :class:`ForeignSpec` -> bag, mesh and scenario YAML).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
import yaml
from scipy.spatial.transform import Rotation
from trimesh.ray.ray_pyembree import RayMeshIntersector

from lidar_sim_ros.io.bag import BagWriter

REPO = Path(__file__).resolve().parents[1]
CLOUD_TOPIC = '/lidar/points'
POSE_TOPIC = '/target/pose'
FRAME_ID = 'lidar'
EPOCH_NS = 1_712_000_000 * 1_000_000_000
NS_PER_S = 1_000_000_000

EFFECTS = ('range_walk', 'incidence_angle', 'snr_noise', 'solar_background',
           'beam_divergence', 'time_offset', 'laser_bias', 'multipath', 'laser_pointing',
           'surface_offset')
CEPTON_TOPIC = '/cepton_pcl2'
CEPTON_FRAME = 'cepton3'
CEPTON_SATURATED, CEPTON_NO_RETURN = 1, 32
SATURATION_POWER_W = 1.0e-3      # this sensor's detector clips above this
# Hidden effects compare has no candidate for: expected answer null (and the feature).
OUTSIDE_CATALOGUE = ('azimuth_bias', 'range_scale', 'crosstalk',   # range_scale: by name only
                     'dual_return', 'range_cyclic', 'veil', 'mixed_pixels', 'face_bias',
                     'bent_body')
# Range errors of the sensor that compare weighs against the reference pose (issue 30).
POSE_RIVALS = ('range_drift',)

# ------------------------------------------------------------------ materials
# Range error per material from the paper's Table 2: mean of the 5 m and 15 m rows
# (bias = measured - true, sigma = 1-sigma random error, metres). The nozzle has no
# row: the mean of the four metallic materials.
_TABLE2_BIAS_M = {'PIF': (-0.1417, -0.1349), 'MLI': (-0.1361, -0.1337),
                  'BULKHEAD': (-0.1334, -0.1093), 'PSS': (-0.1179, -0.1053),
                  'PAF': (-0.1146, -0.1199), 'ADAPTER': (-0.1329, -0.1304)}
_TABLE2_SIGMA_M = {'PIF': (0.0228, 0.0334), 'MLI': (0.0228, 0.0387),
                   'BULKHEAD': (0.0306, 0.0344), 'PSS': (0.0357, 0.0390),
                   'PAF': (0.0437, 0.0472), 'ADAPTER': (0.0338, 0.0393)}
_METALS = ('PAF', 'PSS', 'BULKHEAD', 'ADAPTER')


def table2_error_m() -> dict[str, tuple[float, float]]:
    """Material name -> (bias_m, sigma_m) from the paper's Table 2 (row means)."""
    out = {k: (float(np.mean(_TABLE2_BIAS_M[k])), float(np.mean(_TABLE2_SIGMA_M[k])))
           for k in _TABLE2_BIAS_M}
    out['NOZZLE'] = (float(np.mean([out[k][0] for k in _METALS])),
                     float(np.mean([out[k][1] for k in _METALS])))
    return out


@dataclass(frozen=True)
class Surface:
    """Blinn-Phong reflectance of one material: diffuse and specular albedo (-), exponent."""

    diffuse: float
    specular: float
    exponent: float


# Our own guesses (not materials.yaml): foam diffuse, MLI and PSS mirror-like,
# metals in between. Blinn exponents are about 4x a Phong exponent of the same width.
SURFACES = {
    'PIF': Surface(0.50, 0.00, 1.0),
    'MLI': Surface(0.07, 0.80, 70.0),
    'PAF': Surface(0.18, 0.40, 45.0),
    'PSS': Surface(0.08, 0.60, 110.0),
    'NOZZLE': Surface(0.30, 0.20, 20.0),
    'BULKHEAD': Surface(0.24, 0.30, 35.0),
    'ADAPTER': Surface(0.20, 0.32, 30.0),
}
MATERIALS = tuple(SURFACES)


# -------------------------------------------------------------------- sensor
@dataclass(frozen=True)
class Sensor:
    """The foreign sensor: link budget in watts, detector limits, beam, frame."""

    peak_power_w: float = 30.0
    efficiency: float = 0.75                 # transmit x receive optics (-)
    aperture_diameter_m: float = 0.03
    threshold_power_w: float = 5.0e-8
    divergence_rad: float = 1.2e-3           # nominal full-angle beam divergence
    min_range_m: float = 0.5
    max_range_m: float = 150.0
    frame_rate_hz: float = 10.0
    fov_az_deg: float = 40.0
    fov_el_deg: float = 20.0
    scan_fraction: float = 0.9               # share of the frame period spent scanning

    @property
    def aperture_area_m2(self) -> float:
        return float(np.pi * (0.5 * self.aperture_diameter_m) ** 2)


def raster_scan(sensor: Sensor, n_shots: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boustrophedon raster: rows top to bottom, azimuth sweeping back and forth.

    Returns t_s (since frame start), az_rad, el_rad, each (n,).
    """
    rows, cols = raster_shape(sensor, n_shots)
    az = np.radians(np.linspace(-0.5, 0.5, cols) * sensor.fov_az_deg)
    el = np.radians(np.linspace(0.5, -0.5, rows) * sensor.fov_el_deg)
    az_grid = np.tile(az, (rows, 1))
    az_grid[1::2] = az_grid[1::2, ::-1]
    el_grid = np.repeat(el[:, None], cols, axis=1)
    n = rows * cols
    t = np.arange(n) * (sensor.scan_fraction / sensor.frame_rate_hz / n)
    return t, az_grid.ravel(), el_grid.ravel()


def raster_shape(sensor: Sensor, n_shots: int) -> tuple[int, int]:
    """(rows, cols) of the raster: about square angular steps, rows * cols <= n_shots."""
    rows = max(2, int(round(np.sqrt(n_shots * sensor.fov_el_deg / sensor.fov_az_deg))))
    return rows, max(2, n_shots // rows)


def rosette_scan(sensor: Sensor, n_shots: int, t0_s: float,
                 prism_hz: tuple[float, float] = (211.0, -137.0)) -> tuple[np.ndarray, ...]:
    """Two counter-rotating prisms (Risley pair): a non-repeating rosette.

    The deflection is the sum of two equal rotating vectors, stretched to the FOV
    ellipse; the pattern depends on absolute time t0_s, so frames differ.
    """
    t = np.arange(n_shots) * (sensor.scan_fraction / sensor.frame_rate_hz / n_shots)
    ta = t0_s + t
    w1, w2 = 2 * np.pi * prism_hz[0], 2 * np.pi * prism_hz[1]
    x = 0.5 * (np.cos(w1 * ta) + np.cos(w2 * ta))
    y = 0.5 * (np.sin(w1 * ta) + np.sin(w2 * ta))
    az = np.radians(0.5 * sensor.fov_az_deg) * x
    el = np.radians(0.5 * sensor.fov_el_deg) * y
    return t, az, el


def lissajous_p60_scan(freq_scale: float = 1.0, together: bool = False,
                       shot_offset: float = 0.0) -> tuple[np.ndarray, ...]:
    """The P-60 pattern as config/cepton_vista_p60.yaml publishes it (paper Sec. 3): a
    60 x 22 deg field cut into 8 x 3 tiles, one laser each, firing round-robin at 880
    shots per laser in 0.1 s; each laser traces az = centre + A sin(2 pi 110 Hz t),
    el = centre + B sin(2 pi 100 Hz t + pi/4) over its tile, 12 % beyond it. Written
    here from those published numbers; ``freq_scale`` multiplies both frequencies (a
    sensor whose scan runs 0.5 % off its data sheet: 1.005). ``together``: the 24 lasers
    fire at the same 880 instants, not round-robin; ``shot_offset``: the instants sit this
    many shot intervals later (0.5: t = (k + 1/2) T / N)."""
    tiles_az, tiles_el, per_laser, period = 8, 3, 880, 0.1
    fov_az, fov_el, over = 60.0, 22.0, 0.12
    lasers = tiles_az * tiles_el
    k = np.arange(per_laser * lasers)
    if together:
        t = (k // lasers + shot_offset) * period / per_laser
    else:
        t = (k + shot_offset) * period / len(k)
    laser = k % lasers
    col, row = laser % tiles_az, laser // tiles_az
    w, h = fov_az / tiles_az, fov_el / tiles_el
    az = (-fov_az / 2 + (col + 0.5) * w
          + 0.5 * w * (1 + over) * np.sin(2 * np.pi * 110.0 * freq_scale * t))
    el = (fov_el / 2 - (row + 0.5) * h
          + 0.5 * h * (1 + over) * np.sin(2 * np.pi * 100.0 * freq_scale * t + np.pi / 4))
    return t, np.radians(az), np.radians(el)


def directions_lidar(az_rad: np.ndarray, el_rad: np.ndarray) -> np.ndarray:
    """REP-103 unit vectors: x forward, y left (positive azimuth), z up."""
    ce = np.cos(el_rad)
    return np.column_stack([ce * np.cos(az_rad), ce * np.sin(az_rad), np.sin(el_rad)])


# -------------------------------------------------------------------- target
def satellite_parts(fins: bool = False, bus_shape: str = 'box') -> dict[str, trimesh.Trimesh]:
    """The satellite in its body frame (long axis +z), one mesh per material name; with
    ``fins``, two diffuse (PIF) radiator fins 0.9 m out of the MLI sides, in the plane
    y = 0: MLI mirrors them. ``bus_shape`` 'drum': the bus a cylinder (radius 0.8 m,
    48 sides) wrapped in MLI all round, so its MLI is seen at every incidence."""
    if bus_shape == 'drum':
        bus = trimesh.creation.cylinder(radius=0.8, height=2.0, sections=48)
    elif bus_shape == 'box':
        bus = trimesh.creation.box(extents=(1.6, 1.6, 2.0))
    elif bus_shape == 'box_wing':
        return box_wing_parts()
    else:
        raise ValueError(f'bus_shape must be box, drum or box_wing, got {bus_shape!r}')
    n = bus.face_normals
    side = np.abs(n[:, 2]) < 0.5
    groups = ({'MLI': side, 'BULKHEAD': n[:, 2] > 0.5} if bus_shape == 'drum' else
              {'MLI': np.abs(n[:, 0]) > 0.5, 'PIF': np.abs(n[:, 1]) > 0.5,
               'BULKHEAD': n[:, 2] > 0.5})
    parts = {name: bus.submesh([np.flatnonzero(sel)], append=True) for name, sel in groups.items()}
    if fins:
        plates = [trimesh.creation.box(extents=(0.9, 0.04, 1.6)) for _ in range(2)]
        for side, plate in zip((1.0, -1.0), plates):
            plate.apply_translation((side * (0.8 + 0.45), 0.0, 0.0))
        parts['PIF'] = trimesh.util.concatenate([parts['PIF'], *plates])
    # The bus floor and the detached panel share PSS (support-structure metal).
    floor = bus.submesh([np.flatnonzero(n[:, 2] < -0.5)], append=True)
    panel = trimesh.creation.box(extents=(0.04, 2.4, 1.1))
    panel.apply_translation((0.0, 0.8 + 0.35 + 1.2, 0.2))
    parts['PSS'] = trimesh.util.concatenate([floor, panel])
    parts['ADAPTER'] = trimesh.creation.cylinder(radius=0.55, height=0.4, sections=48)
    parts['ADAPTER'].apply_translation((0.0, 0.0, 1.2))
    parts['PAF'] = trimesh.creation.cone(radius=0.55, height=0.9, sections=48)
    parts['PAF'].apply_translation((0.0, 0.0, 1.4))
    parts['NOZZLE'] = trimesh.creation.cone(radius=0.45, height=0.7, sections=32)
    parts['NOZZLE'].apply_translation((0.0, 0.0, -1.7))
    return parts


def box_wing_parts() -> dict[str, trimesh.Trimesh]:
    """An independent lab's box-wing (boxnull53), body frame, long axis +z: a bus 1.8 x
    1.8 x 2.2 m wrapped in MLI on every face, two flat PIF wings 1.6 x 1.6 m (4 cm thick)
    centred at y = +-2.75 m in the plane x = 0, and small PAF parts (an adapter ring on
    +z and the wings' two yokes)."""
    bus = trimesh.creation.box(extents=(1.8, 1.8, 2.2))
    wings = [trimesh.creation.box(extents=(0.04, 1.6, 1.6)) for _ in range(2)]
    yokes = [trimesh.creation.box(extents=(0.12, 1.05, 0.12)) for _ in range(2)]
    for side, wing, yoke in zip((1.0, -1.0), wings, yokes):
        wing.apply_translation((0.0, side * 2.75, 0.0))
        yoke.apply_translation((0.0, side * (0.9 + 0.525), 0.0))
    ring = trimesh.creation.cylinder(radius=0.45, height=0.25, sections=48)
    ring.apply_translation((0.0, 0.0, 1.1 + 0.125))
    return {'MLI': bus, 'PIF': trimesh.util.concatenate(wings),
            'PAF': trimesh.util.concatenate([ring, *yokes])}


def write_obj(parts: dict[str, trimesh.Trimesh], obj_path: Path) -> Path:
    """OBJ + MTL with one ``g``/``usemtl`` block per material (our own writer)."""
    obj_path = Path(obj_path)
    mtl_path = obj_path.with_suffix('.mtl')
    obj = [f'# foreign satellite target, {sum(len(m.faces) for m in parts.values())} faces',
           f'mtllib {mtl_path.name}']
    mtl = ['# Blinn-Phong guesses of the foreign simulator (display only)']
    base = 1
    for name, mesh in parts.items():
        s = SURFACES[name]
        mtl += [f'newmtl {name}', f'Kd {s.diffuse:.3f} {s.diffuse:.3f} {s.diffuse:.3f}',
                f'Ks {s.specular:.3f} {s.specular:.3f} {s.specular:.3f}', f'Ns {s.exponent:g}', '']
        obj += [f'g {name}', f'usemtl {name}']
        obj += [f'v {x:.6f} {y:.6f} {z:.6f}' for x, y, z in mesh.vertices]
        obj += [f'f {a + base} {b + base} {c + base}' for a, b, c in mesh.faces]
        base += len(mesh.vertices)
    obj_path.write_text('\n'.join(obj) + '\n')
    mtl_path.write_text('\n'.join(mtl) + '\n')
    return obj_path


BEND_EDGE_M = 0.08   # the bent body's faces cut to this size, so that the bend curves them


def bent_parts(parts: dict[str, trimesh.Trimesh], amp_m: float) -> dict[str, trimesh.Trimesh]:
    """The body as built, not as drawn: bent like a banana along its long axis, body
    x += ``amp_m`` (z / z_max)^2 (z_max: the largest |z| of the drawn body, m). The
    faces are cut to BEND_EDGE_M first so that the bend curves them (a box's side of two
    triangles would only shift)."""
    z_max = max(float(np.abs(m.vertices[:, 2]).max()) for m in parts.values())
    out = {}
    for name, mesh in parts.items():
        v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, BEND_EDGE_M)
        v = np.array(v, float)
        v[:, 0] += amp_m * (v[:, 2] / z_max) ** 2
        out[name] = trimesh.Trimesh(v, f, process=False)
    return out


class Target:
    """The satellite as one mesh with a material name index per face, and its raycaster."""

    def __init__(self, parts: dict[str, trimesh.Trimesh]):
        names = list(parts)
        self.mesh = trimesh.util.concatenate([parts[k] for k in names])
        self.face_material = np.concatenate(
            [np.full(len(parts[k].faces), MATERIALS.index(k)) for k in names])
        self._rays = RayMeshIntersector(self.mesh)

    def cast(self, origins_m: np.ndarray, dirs: np.ndarray,
             with_normal: bool = False) -> tuple[np.ndarray, ...]:
        """First hit of body-frame rays: (hit, range_m, cos_incidence, material id), and
        with ``with_normal`` the hit face's unit normal turned towards the ray (NaN on
        a miss)."""
        n = len(dirs)
        tri, ray, loc = self._rays.intersects_id(origins_m, dirs, multiple_hits=False,
                                                 return_locations=True)
        hit = np.zeros(n, bool)
        rng = np.full(n, np.inf)
        cos_i = np.zeros(n)
        mat = np.full(n, -1)
        hit[ray] = True
        rng[ray] = np.linalg.norm(loc - origins_m[ray], axis=1)
        dot = np.einsum('ij,ij->i', self.mesh.face_normals[tri], dirs[ray])
        cos_i[ray] = np.abs(dot)
        mat[ray] = self.face_material[tri]
        out = (hit, rng, np.clip(cos_i, 1e-6, 1.0), mat)
        if not with_normal:
            return out
        normal = np.full((n, 3), np.nan)
        normal[ray] = -np.sign(dot)[:, None] * self.mesh.face_normals[tri]
        return out + (normal,)


# ---------------------------------------------------------------- trajectory
@dataclass(frozen=True)
class Trajectory:
    """Target pose in the lidar frame: drift in position, spin about a body axis and
    a slower precession of that axis about a lidar-frame axis."""

    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    attitude: Rotation
    spin_axis_body: tuple[float, float, float]
    spin_dps: float
    precession_axis_lidar: tuple[float, float, float]
    precession_dps: float

    def at(self, t_s: np.ndarray) -> tuple[Rotation, np.ndarray]:
        t = np.asarray(t_s, float)
        spin = Rotation.from_rotvec(np.outer(np.radians(self.spin_dps) * t,
                                             _unit(self.spin_axis_body)))
        prec = Rotation.from_rotvec(np.outer(np.radians(self.precession_dps) * t,
                                             _unit(self.precession_axis_lidar)))
        pos = np.asarray(self.position_m) + np.outer(t, self.velocity_mps)
        return prec * self.attitude * spin, pos


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# ---------------------------------------------------------------- radiometry
def blinn_brdf_per_sr(surface: Surface, cos_half: np.ndarray) -> np.ndarray:
    """Energy-normalised Blinn-Phong BRDF (1/sr). Monostatic: the half vector is the
    view direction, so cos_half = cos(incidence)."""
    lobe = surface.specular * (surface.exponent + 8.0) / (8.0 * np.pi)
    return surface.diffuse / np.pi + lobe * np.power(cos_half, surface.exponent)


@dataclass(frozen=True)
class Coating:
    """Another lab's reflection law of one material (``reflection='ts_km'``): a
    Torrance-Sparrow lobe (Fresnel f0 at normal incidence (-), Beckmann slope rms
    ``roughness`` (-)) over a Kubelka-Munk-like body of absorption/scattering ratio
    ``k_over_s`` (-)."""

    f0: float
    roughness: float
    k_over_s: float


# Coatings whose powers span a wider range than the Blinn-Phong surfaces (and the
# compare model's Phong table): narrow bright lobes on the foils and metals, dark or
# bright bodies. Not fitted to anything.
COATINGS = {
    'PIF': Coating(0.04, 0.60, 0.08),
    'MLI': Coating(0.90, 0.10, 6.0),
    'PAF': Coating(0.55, 0.14, 1.5),
    'PSS': Coating(0.75, 0.08, 4.0),
    'NOZZLE': Coating(0.30, 0.25, 0.8),
    'BULKHEAD': Coating(0.40, 0.18, 0.5),
    'ADAPTER': Coating(0.45, 0.16, 0.7),
}


def coating_brdf_per_sr(c: Coating, cos_i: np.ndarray) -> np.ndarray:
    """Monostatic Torrance-Sparrow lobe (Beckmann D, shadowing G = min(1, 2 cos^2),
    F = f0) plus a Lambertian body of Kubelka-Munk albedo 1 + q - sqrt(q^2 + 2 q),
    q = K/S, through (1 - f0) (1/sr)."""
    cos = np.clip(np.asarray(cos_i, float), 1e-3, 1.0)
    tan2 = (1.0 - cos ** 2) / cos ** 2
    m2 = c.roughness ** 2
    d = np.exp(-tan2 / m2) / (np.pi * m2 * cos ** 4)
    g = np.minimum(1.0, 2.0 * cos ** 2)
    lobe = c.f0 * d * g / (4.0 * cos ** 2)
    q = c.k_over_s
    albedo = 1.0 + q - np.sqrt(q * q + 2.0 * q)
    return lobe + (1.0 - c.f0) * albedo / np.pi


def received_power_w(sensor: Sensor, range_m: np.ndarray, cos_i: np.ndarray,
                     material: np.ndarray, law: str = 'blinn') -> np.ndarray:
    """Whole beam on an extended surface: P = P0 eta f cos(theta) A_rx / r^2 (W); f the
    Blinn-Phong BRDF (``law='blinn'``) or the coatings' (``'ts_km'``)."""
    f = np.zeros(len(range_m))
    for k, name in enumerate(MATERIALS):
        sel = material == k
        if sel.any():
            f[sel] = (coating_brdf_per_sr(COATINGS[name], cos_i[sel]) if law == 'ts_km'
                      else blinn_brdf_per_sr(SURFACES[name], cos_i[sel]))
    r = np.where(np.isfinite(range_m), range_m, 1.0)
    return np.where(material >= 0, sensor.peak_power_w * sensor.efficiency * f * cos_i
                    * sensor.aperture_area_m2 / r ** 2, 0.0)


def intensity_units(power_w: np.ndarray, range_m: np.ndarray, mode: str,
                    sensor: Sensor, cos_i: np.ndarray | None = None,
                    cos_exponent: float = 1.0) -> np.ndarray | None:
    """The sensor's own intensity: not proportional to power in any mode. ``cos_i``:
    the cosine of each return's incidence (-), for ``reflectivity_lambert``, which
    divides by cos_i ** ``cos_exponent`` (1: a Lambertian law; less: a partial one)."""
    p = np.maximum(power_w, sensor.threshold_power_w)
    if mode == 'counts8':       # log-compressed 8-bit counts, 1 at threshold, clipped
        u = np.log(p / sensor.threshold_power_w) / np.log(2e-3 / sensor.threshold_power_w)
        return np.clip(np.round(1 + 254 * u ** 0.85), 1, 255).astype(np.uint8)
    if mode == 'counts16':      # square-root amplifier with soft saturation
        return np.round(65535 * (1 - np.exp(-np.sqrt(p / 4e-4)))).astype(np.uint16)
    if mode == 'reflectivity':  # range-compensated, float
        return (p * range_m ** 2 * 1e3).astype(np.float32)
    if mode == 'reflectivity_lambert':   # range- and Lambert-compensated, float
        c = np.clip(np.ones(len(p)) if cos_i is None else np.asarray(cos_i, float), 0.05, 1.0)
        return (p * range_m ** 2 * 1e3 / c ** cos_exponent).astype(np.float32)
    if mode == 'linear':        # proportional to the received power, arbitrary units
        return (p * 2.5e7).astype(np.float32)
    if mode == 'none':
        return None
    if mode == 'log':           # log counts: 40 log10 of the power in nW (float)
        return (40.0 * np.log10(p / 1e-9)).astype(np.float32)
    raise ValueError(f'intensity mode must be counts8, counts16, reflectivity, '
                     f'reflectivity_lambert, linear or none, got {mode!r}')


# ------------------------------------------------------- effects (own forms)
def range_walk_bias_m(power_w: np.ndarray, sensor: Sensor, p: dict) -> np.ndarray:
    """Leading-edge walk. 'poly_log': -(a u + b u^2), u = log10(P/P_thr);
    'inv_sqrt': c sqrt(P_ref / P) (weak returns read long), P_ref = 100 P_thr."""
    form = p.get('form', 'poly_log')
    if form == 'poly_log':
        u = np.log10(np.maximum(power_w / sensor.threshold_power_w, 1.0))
        return -(p.get('a_m', 0.012) * u + p.get('b_m', 0.003) * u ** 2)
    if form == 'inv_sqrt':
        ref = 100.0 * sensor.threshold_power_w
        return p.get('c_m', 0.015) * np.sqrt(ref / np.maximum(power_w, sensor.threshold_power_w))
    if form == 'ln':            # -g ln(P / 1 uW): log of the received power, own reference
        return -p.get('g_m', 0.02) * np.log(np.maximum(power_w, sensor.threshold_power_w) / 1e-6)
    raise ValueError(f'range_walk form {form!r}')


def laser_offsets_of(spec: ForeignSpec) -> np.ndarray:
    """The hidden per-laser range offsets (m): ``offsets_m`` as given, else a seeded draw
    of sd ``sd_m`` (default 2 cm) about zero."""
    p = spec.params_of('laser_bias') or {}
    if not spec.lasers:
        raise ValueError('laser_bias needs lasers > 0')
    if 'offsets_m' in p:
        off = np.asarray(p['offsets_m'], float)
        if len(off) != spec.lasers:
            raise ValueError(f'laser_bias offsets_m has {len(off)} values for {spec.lasers} lasers')
        return off
    return np.random.default_rng([spec.seed, 53]).normal(0.0, p.get('sd_m', 0.02), spec.lasers)


def laser_turns_of(spec: ForeignSpec) -> np.ndarray:
    """The hidden pointing errors (lasers, 2): per laser a turn ``a`` (deg) about the lidar
    z axis and ``e`` (deg) about d x z; ``turns_deg`` as given, else a seeded draw of sd
    ``sd_deg`` (default 0.1 deg) for each."""
    p = spec.params_of('laser_pointing') or {}
    if not spec.lasers:
        raise ValueError('laser_pointing needs lasers > 0')
    if 'turns_deg' in p:
        out = np.asarray(p['turns_deg'], float).reshape(-1, 2)
        if len(out) != spec.lasers:
            raise ValueError(f'laser_pointing turns_deg has {len(out)} pairs for {spec.lasers} lasers')
        return out
    return np.random.default_rng([spec.seed, 59]).normal(0.0, p.get('sd_deg', 0.1),
                                                         (spec.lasers, 2))


def turned_beams(d: np.ndarray, laser: np.ndarray, turns_deg: np.ndarray) -> np.ndarray:
    """Unit beams (N, 3): each direction d turned by its laser's ``a`` about z, then by
    its ``e`` about the horizontal axis d' x z (lifting it toward +z), as rotation vectors."""
    a = np.radians(turns_deg[laser, 0])
    e = np.radians(turns_deg[laser, 1])
    first = Rotation.from_rotvec(np.outer(a, [0.0, 0.0, 1.0])).apply(d)
    axis = np.cross(first, [0.0, 0.0, 1.0])
    axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    return Rotation.from_rotvec(axis * e[:, None]).apply(first)


def range_cyclic_bias_m(range_m: np.ndarray, p: dict) -> np.ndarray:
    """A cyclic range error (m) of the receiver, a function of the true range alone:
    ``a_m`` cos(2 pi r / ``period_m``) (an electronic crosstalk of the timing clock into
    the echo, or a phase-measuring unit's cyclic error); outside compare's catalogue."""
    return p.get('a_m', 0.05) * np.cos(2 * np.pi * np.asarray(range_m, float)
                                       / p.get('period_m', 3.0))


def face_bias_m(target: 'Target', rot: Rotation, origins_b: np.ndarray, dirs_b: np.ndarray,
                p: dict) -> np.ndarray:
    """A range error that depends on which way the surface faces (a sunlit face warmer,
    read long): ``amp_m`` x max(0, n.s), n the hit face's unit normal turned toward the
    sensor and s the unit direction ``s`` fixed in the sensor frame (``frame`` 'sensor')
    or in the target's body frame ('body'). 0 on a miss (m)."""
    normal_b = target.cast(origins_b, dirs_b, with_normal=True)[4]
    s = _unit(p.get('s', (0.0, 0.34, 0.94)))
    n = normal_b if p.get('frame', 'sensor') == 'body' else rot.apply(np.nan_to_num(normal_b))
    return p['amp_m'] * np.maximum(0.0, np.nan_to_num(n @ s))


def azimuth_bias_m(az_rad: np.ndarray, p: dict) -> np.ndarray:
    """Outside the compare catalogue: a range bias periodic in the scan azimuth,
    A sin(2 pi az / period + phase) (a scanner encoder or mirror-facet error)."""
    period = np.radians(p.get('period_deg', 12.0))
    return p.get('a_m', 0.02) * np.sin(2 * np.pi * az_rad / period + p.get('phase', 0.3))


def incidence_bias_m(cos_i: np.ndarray, p: dict, range_m: np.ndarray | None = None,
                     sensor: Sensor | None = None) -> np.ndarray:
    """Footprint smear read early: -g (1/cos(theta) - 1), theta clipped at 80 deg. With
    p['law'] 'range_sin' (another lab's law, in proportion to range): g r dtheta
    sin(theta) / cos(theta)^a (g < 0 reads grazing returns short; ``range_m`` and the
    sensor's ``divergence_rad`` needed). With p['law'] 'tan' (a third lab's): g_m tan(theta)
    (g_m > 0: grazing returns read long; < 0: short)."""
    c = np.maximum(cos_i, np.cos(np.radians(80.0)))
    if p.get('law') == 'tan':
        return p['g_m'] * np.sqrt(1 - c ** 2) / c
    if p.get('law') == 'range_sin':
        return (p['g'] * range_m * sensor.divergence_rad * np.sqrt(1 - c ** 2)
                / c ** p.get('a', 0.7))
    return -p.get('g_m', 0.012) * (1.0 / c - 1.0)


def incidence_sigma_m(range_m: np.ndarray, cos_i: np.ndarray, sensor: Sensor,
                      p: dict) -> np.ndarray:
    """Extra jitter h r dtheta tan(theta) (the footprint's depth), theta clipped at 80 deg;
    with p['law'] 'range_sin' or 'tan', p['sigma_frac'] (default 0.3) times the bias's size."""
    if p.get('law') in ('range_sin', 'tan'):
        return p.get('sigma_frac', 0.3) * np.abs(incidence_bias_m(cos_i, p, range_m, sensor))
    c = np.maximum(cos_i, np.cos(np.radians(80.0)))
    tan = np.sqrt(1 - c ** 2) / c
    return p.get('h', 0.4) * range_m * sensor.divergence_rad * tan


def snr_sigma_m(power_w: np.ndarray, p: dict) -> np.ndarray:
    """Extra jitter s0 (P0/P)^0.4 (P0 = 1 uW: a typical weak return)."""
    ratio = p.get('p0_w', 1e-6) / np.maximum(power_w, 1e-12)
    return p.get('s0_m', 0.05) * ratio ** p.get('exponent', 0.4)


def background_range_m(n: int, rng: np.random.Generator, sensor: Sensor, p: dict) -> np.ndarray:
    """First background photon: an exponential in range (a Poisson arrival process),
    truncated to the range gate, not uniform."""
    lam = p.get('mean_range_m', 40.0)
    lo, hi = sensor.min_range_m, p.get('max_range_m', sensor.max_range_m)
    u = rng.random(n)
    return lo - lam * np.log(1 - u * (1 - np.exp(-(hi - lo) / lam)))


def mirror_direction(dirs: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Specular reflection of unit rays on surfaces of unit normal: d - 2 (d.n) n."""
    return dirs - 2.0 * np.einsum('ij,ij->i', dirs, normal)[:, None] * normal


def multipath_extra_m(point_m: np.ndarray, mirror: np.ndarray, sensor: Sensor,
                      distance_m: float, p: dict) -> np.ndarray:
    """Outside the compare catalogue: the extra one-way path L (m) of a mirror path, or
    NaN where there is none. The beam leaves the specular point ``point_m`` (lidar
    frame) along ``mirror`` and meets the lab room, a box around the target (lidar
    frame: floor at z = -floor_m, ceiling at z = ceiling_m, side walls at y = +-side_m,
    back wall back_m behind the target, the sensor's wall 1 m behind it), at the exit
    distance L of the box. Only the room's surfaces outside the sensor's field of view
    are bright: a black backdrop covers what the sensor sees directly, as labs hang
    one behind the target. The range is then r + L: L is set by how far the room's
    surfaces are from the target, a few metres."""
    lo = np.array([-1.0, -p.get('side_m', 4.0), -p.get('floor_m', 2.5)])
    hi = np.array([distance_m + p.get('back_m', 4.0), p.get('side_m', 4.0),
                   p.get('ceiling_m', 3.0)])
    with np.errstate(invalid='ignore', divide='ignore'):
        bound = np.where(mirror > 0, hi, lo)
        extra = np.nanmin(np.where(np.abs(mirror) > 1e-9, (bound - point_m) / mirror, np.inf),
                          axis=1)
        wall = point_m + extra[:, None] * mirror
        az = np.degrees(np.arctan2(np.abs(wall[:, 1]), wall[:, 0]))
        el = np.degrees(np.arctan2(np.abs(wall[:, 2]), np.hypot(wall[:, 0], wall[:, 1])))
        bright = ((extra > 0) & np.isfinite(extra) & ((wall[:, 0] <= 0)
                  | (az > 0.5 * sensor.fov_az_deg) | (el > 0.5 * sensor.fov_el_deg)))
    return np.where(bright, extra, np.nan)


def footprint_returns(target: Target, origins_b: np.ndarray, dirs_b: np.ndarray,
                      sensor: Sensor, rng: np.random.Generator, p: dict) -> tuple[np.ndarray, ...]:
    """The beam as K random sub-rays in a cone of ``scale`` x the nominal divergence,
    Gaussian-weighted. Returns (detected, range_m, power_w, cos_i, material) of the
    shot: power = weighted mean over sub-rays (misses count 0), range = energy-weighted
    mean ('weighted') or nearest ('first') of the hit sub-rays; material and incidence
    from the strongest hit sub-ray."""
    k = int(p.get('subrays', 12))
    half = 0.5 * p.get('scale', 6.0) * sensor.divergence_rad
    n = len(dirs_b)
    rho = np.sqrt(rng.random((n, k)))       # uniform over the disk
    rho[:, 0] = 0.0                         # keep the axis
    phi = 2 * np.pi * rng.random((n, k))
    helper = np.where(np.abs(dirs_b[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(dirs_b, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(dirs_b, u)
    off = np.tan(half * rho)[..., None] * (np.cos(phi)[..., None] * u[:, None]
                                           + np.sin(phi)[..., None] * v[:, None])
    sub = dirs_b[:, None, :] + off
    sub /= np.linalg.norm(sub, axis=2, keepdims=True)
    hit, r, cos_i, mat = target.cast(np.repeat(origins_b, k, axis=0), sub.reshape(-1, 3))
    weight = np.exp(-2.0 * rho ** 2)
    weight /= weight.sum(axis=1, keepdims=True)
    power = received_power_w(sensor, r, cos_i, mat).reshape(n, k)
    hit, r = hit.reshape(n, k), r.reshape(n, k)
    e = np.where(hit, weight * power, 0.0)
    total = e.sum(axis=1)
    ok = total > 0
    if p.get('mode', 'weighted') == 'first':
        rng_m = np.min(np.where(hit, r, np.inf), axis=1)
    else:
        rng_m = np.where(ok, (e * np.where(hit, r, 0.0)).sum(axis=1) / np.where(ok, total, 1),
                         np.inf)
    best = np.argmax(e, axis=1)
    pick = np.arange(n) * k + best
    return ok, rng_m, total, cos_i[pick], np.where(ok, mat[pick], -1)


def mixed_pixel_returns(target: Target, origins_b: np.ndarray, rot: Rotation,
                        beam_d: np.ndarray, fixtures: list, sensor: Sensor, hit: np.ndarray,
                        range_m: np.ndarray, power: np.ndarray, cos_i: np.ndarray,
                        mat: np.ndarray, rng: np.random.Generator,
                        p: dict) -> tuple[np.ndarray, ...]:
    """This lab's receiver averaging echoes (multi-echo averaging): each shot's footprint
    is the axis plus ``subrays`` - 1 (6) rays on a ring of radius ``ring_rad`` (4e-3
    rad) at a random phase per shot, each cast on the target and the lab's fixtures
    (lidar frame, the nearest surface). A shot whose sub-ray ranges spread more than
    ``spread_m`` (0.3 m: across an edge with the wall behind) and that meets both the
    target and a fixture (``with_fixture``, default True) reports the power-weighted mean
    range of its hit sub-rays: a point between the edge and the surface behind it.
    Other shots keep the axis's answer. Returns (hit, range_m, power_w, cos_i, material,
    mixed) with ``mixed`` the shots replaced; material is the strongest sub-ray's."""
    k = int(p.get('subrays', 7))
    n = len(beam_d)
    phase = 2 * np.pi * rng.random(n)[:, None]
    phi = phase + 2 * np.pi * np.arange(k - 1)[None, :] / (k - 1)
    helper = np.where(np.abs(beam_d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(beam_d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(beam_d, u)
    t = np.tan(p.get('ring_rad', 4e-3))
    ring = beam_d[:, None, :] + t * (np.cos(phi)[..., None] * u[:, None]
                                     + np.sin(phi)[..., None] * v[:, None])
    ring /= np.linalg.norm(ring, axis=2, keepdims=True)
    flat = ring.reshape(-1, 3)
    h, r, c, m = target.cast(np.repeat(origins_b, k - 1, axis=0), _body_dirs(rot, flat, k - 1))
    pw = received_power_w(sensor, r, c, m)
    for fixture in fixtures:
        f_hit, f_r, f_cos = fixture.cast(np.zeros((len(flat), 3)), flat)
        front = f_hit & (~h | (f_r < r))
        h, r, c = h | front, np.where(front, f_r, r), np.where(front, f_cos, c)
        m = np.where(front, CLUTTER, m)
        pw = np.where(front, received_power_w(sensor, f_r, f_cos, np.zeros(len(flat), int))
                      * CLUTTER_SURFACE_RATIO, pw)
    sub_h = np.concatenate([hit[:, None], h.reshape(n, k - 1)], axis=1)
    sub_r = np.concatenate([range_m[:, None], r.reshape(n, k - 1)], axis=1)
    sub_p = np.where(sub_h, np.concatenate([power[:, None], pw.reshape(n, k - 1)], axis=1), 0.0)
    sub_c = np.concatenate([cos_i[:, None], c.reshape(n, k - 1)], axis=1)
    sub_m = np.concatenate([mat[:, None], m.reshape(n, k - 1)], axis=1)
    near = np.min(np.where(sub_h, sub_r, np.inf), axis=1)
    far = np.max(np.where(sub_h, sub_r, -np.inf), axis=1)
    mixed = sub_h.any(axis=1) & (far - near > p.get('spread_m', 0.3))
    if p.get('with_fixture', True):
        # Only footprints over the target and a fixture (the wall behind): the target's
        # own depth steps keep the axis's echo.
        on_fixture = (sub_h & (sub_m == CLUTTER)).any(axis=1)
        on_target = (sub_h & (sub_m >= 0) & (sub_m < CLUTTER)).any(axis=1)
        mixed &= on_fixture & on_target
    total = sub_p.sum(axis=1)
    mean = (sub_p * np.where(sub_h, sub_r, 0.0)).sum(axis=1) / np.where(total > 0, total, 1.0)
    best = np.argmax(sub_p, axis=1)
    pick = (np.arange(n), best)
    return (hit | mixed, np.where(mixed, mean, range_m),
            np.where(mixed, total / k, power), np.where(mixed, sub_c[pick], cos_i),
            np.where(mixed, sub_m[pick], mat), mixed)


def _body_dirs(rot: Rotation, dirs_lidar: np.ndarray, per_shot: int) -> np.ndarray:
    """Lidar-frame directions (n * per_shot, 3), ``per_shot`` rows per shot, into the body
    frame by each shot's own rotation (``rot`` holds one per shot)."""
    return np.einsum('nij,nkj->nki', rot.inv().as_matrix(),
                     dirs_lidar.reshape(len(rot), per_shot, 3)).reshape(-1, 3)


# -------------------------------------------------------------------- clutter
CLUTTER = len(MATERIALS)          # material id of lab clutter (not in the target mesh)
CLUTTER_SIGMA_M = 0.02            # range noise on clutter (painted walls, anodised jigs)
CLUTTER_SURFACE_RATIO = 1.6       # clutter power relative to the PIF-like diffuse surface


class Clutter:
    """Static lab fixtures in the lidar frame: a wall panel 4 m behind the target, a
    support jig (a post rising to just under the target) and a cable across the view."""

    def __init__(self, distance_m: float = 11.0):
        wall = trimesh.creation.box(extents=(0.1, 4.0, 3.0))
        wall.apply_translation((distance_m + 4.0, 1.8, 0.3))
        jig = trimesh.creation.cylinder(radius=0.06, height=3.0, sections=16)
        jig.apply_translation((distance_m + 0.3, -0.4, -3.0))
        cable = trimesh.creation.cylinder(radius=0.012, height=7.0, sections=8)
        cable.apply_transform(trimesh.transformations.rotation_matrix(
            np.radians(70.0), (1.0, 0.0, 0.0)))
        cable.apply_translation((distance_m - 2.5, 0.3, 0.4))
        self.mesh = trimesh.util.concatenate([wall, jig, cable])
        self._rays = RayMeshIntersector(self.mesh)

    def cast(self, origins_m: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, ...]:
        """(hit, range_m, cos_incidence) of lidar-frame rays."""
        n = len(dirs)
        tri, ray, loc = self._rays.intersects_id(origins_m, dirs, multiple_hits=False,
                                                 return_locations=True)
        hit = np.zeros(n, bool)
        rng = np.full(n, np.inf)
        cos_i = np.ones(n)
        hit[ray] = True
        rng[ray] = np.linalg.norm(loc - origins_m[ray], axis=1)
        cos_i[ray] = np.abs(np.einsum('ij,ij->i', self.mesh.face_normals[tri], dirs[ray]))
        return hit, rng, np.clip(cos_i, 1e-6, 1.0)


class Occluder(Clutter):
    """A lab pillar between the sensor and the target (lidar frame, static): a box
    OCCLUDER_WIDTH_M wide and 4 m tall at OCCLUDER_AT of the target's distance, set off
    the line of sight to the target's centre by OCCLUDER_OFFSET_M so that it hides a
    strip of the target and its own returns lie partly off the target's silhouette."""

    def __init__(self, target_m: tuple[float, float, float]):
        toward = _unit(target_m)
        at = OCCLUDER_AT * float(np.linalg.norm(target_m)) * toward
        side = _unit(np.cross(toward, (0.0, 0.0, 1.0)))
        pillar = trimesh.creation.box(extents=(0.15, OCCLUDER_WIDTH_M, 4.0))
        pillar.apply_translation(at + OCCLUDER_OFFSET_M * side)
        self.mesh = pillar
        self._rays = RayMeshIntersector(self.mesh)


class Backdrop(Clutter):
    """A lab wall ``behind_m`` behind the target's centre (lidar frame, static), square to
    the line of sight to it and ``width_m`` wide and high: the whole target seen against it."""

    def __init__(self, target_m: tuple[float, float, float], behind_m: float,
                 width_m: float = 8.0):
        toward = _unit(target_m)
        wall = trimesh.creation.box(extents=(0.1, width_m, width_m))
        turn = trimesh.geometry.align_vectors((1.0, 0.0, 0.0), toward)
        wall.apply_transform(turn)
        wall.apply_translation((float(np.linalg.norm(target_m)) + behind_m) * toward)
        self.mesh = wall
        self._rays = RayMeshIntersector(self.mesh)


OCCLUDER_AT = 0.6            # the pillar's distance, share of the target's
OCCLUDER_WIDTH_M = 0.4
OCCLUDER_OFFSET_M = 0.35     # off the line of sight to the target's centre, sideways

_CLUTTER: dict[float, Clutter] = {}


def lab_clutter(distance_m: float = 11.0) -> Clutter:
    if distance_m not in _CLUTTER:
        _CLUTTER[distance_m] = Clutter(distance_m)
    return _CLUTTER[distance_m]


# ------------------------------------------------------------------- dataset
@dataclass(frozen=True)
class ForeignSpec:
    """One foreign dataset. ``effect`` is hidden in the data (a catalogue name or None);
    ``expected`` is what compare should report (defaults to ``effect``)."""

    name: str
    effect: str | None = None
    params: dict = field(default_factory=dict)
    seed: int = 1
    scan: str = 'raster'                 # raster | rosette | lissajous | flash (a raster grid exposed at once)
    shots_per_frame: int = 24_000
    frames: int = 3
    distance_m: float = 11.0
    storage: str = 'mcap'                # mcap | sqlite3
    intensity: str = 'counts8'           # counts8 | counts16 | reflectivity | reflectivity_lambert | linear | none
    intensity_cos_exponent: float = 1.0  # reflectivity_lambert: P r^2 / cos(theta) ** this
    intensity_scale: str = 'native'      # native (the mode's own) | log: 40 log10(P / 1 nW)
    # The range a compensated intensity is scaled with: the measured one, or the lab's
    # true one (its own raycast; the intensity then does not carry the range's error).
    intensity_range: str = 'measured'    # measured | true
    point_time: str = 't_s'              # t_s | t_ns | timestamp | none
    spin_dps: float = 7.0
    precession_dps: float = 2.0
    speed_mps: float = 0.06
    pose_rate_hz: float = 50.0
    frame_rate_hz: float = 10.0
    stamp: str = 'auto'                  # start | mid | end of the scan; auto: mid without time
    organized: bool = False              # height x width cloud, NaN where a shot gave nothing
    noise: str = 'gauss'                 # gauss | studentN (t, N dof, same sigma: heavier tails)
    pose_noise: tuple[float, float] = (0.0, 0.0)   # motion-capture noise: metres, degrees
    # Reference-pose error (tracking system, extrinsic calibration): a rigid offset of the
    # target, RMS metres per axis and degrees per axis; held per cloud (period 0) or
    # varying smoothly over pose_error_period_s.
    pose_error: tuple[float, float] = (0.0, 0.0)
    pose_error_period_s: float = 0.0
    # A reference pose that drifts within each cloud (a tracking system's lag): a rigid
    # offset growing linearly from 0 at the scan start to a per-cloud draw of this RMS
    # (metres per axis, degrees per axis) at its end.
    pose_error_ramp: tuple[float, float] = (0.0, 0.0)
    # A constant reference-pose error (an extrinsic calibration off): the recorded target
    # this far from the true one in the lidar frame (m; +x is the boresight, the line of
    # sight), the same in every pose.
    pose_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # A tracking lag growing within each scan, tied to the motion: the pose recorded at t
    # is the true one at t - pose_lag_s u (u: 0 at the scan's start, 1 at its end).
    pose_lag_s: float = 0.0
    frame_gap_s: float = 0.0             # time between cloud starts; 0: back to back
    scan_freq_scale: float = 1.0         # 'lissajous' scan: its frequencies x this
    scan_together: bool = False          # 'lissajous': all lasers fire at the same instants
    scan_shot_offset: float = 0.0        # 'lissajous': instants this many shots later
    max_range_m: float = 150.0           # the end of the range gate (m)
    material_bias_shift_m: dict = field(default_factory=dict)   # on top of the +-1 cm jitter
    material_sigma_scale: dict = field(default_factory=dict)
    also: tuple = ()                     # further hidden effects: ((name, params), ...)
    amplitude_cv: float = 0.0            # shot-to-shot power fluctuation (speckle), rel. sd
    clutter: bool = False                # lab fixtures in view: wall, jig, cable
    occluder: bool = False               # a lab pillar between the sensor and the target
    lasers: int = 0                      # lasers firing round-robin; 0 = no laser field
    layout: str = 'generic'              # generic | cepton (the SDK3 driver's fields)
    reflection: str = 'blinn'            # blinn (SURFACES) | ts_km (COATINGS: another lab's law)
    fins: bool = False                   # radiator fins beside the MLI sides (satellite_parts)
    bus_shape: str = 'box'               # box | drum (satellite_parts)
    # The body's long axis tilted this far (deg) from across the line of sight toward it
    # (None: the seeded attitude); the spin is then about the long axis, no precession,
    # so the tilt holds over the recording.
    tilt_deg: float | None = None
    tilt_from: str = 'z'                 # the lidar axis the long axis lies on before the tilt: z | y
    # The spin exactly about the body's long axis and the precession about this lidar
    # axis (None: both seeded, the spin axis jittered about +z).
    precession_axis: tuple[float, float, float] | None = None
    expected: str | None = 'same'
    expected_feature: str | None = None  # the feature the residual should be attributed to
    note: str = ''

    @property
    def hidden(self) -> tuple[tuple[str, dict], ...]:
        """Every hidden effect, (name, params)."""
        first = () if self.effect is None else ((self.effect, self.params),)
        return first + tuple((n, dict(p)) for n, p in self.also)

    def params_of(self, name: str) -> dict | None:
        """The params of hidden effect ``name``, or None if it is not hidden."""
        return next((p for n, p in self.hidden if n == name), None)

    @property
    def expected_effects(self) -> tuple[str, ...]:
        """The catalogue effects compare should name, one per step of the loop."""
        if self.expected != 'same':
            return () if self.expected is None else (self.expected,)
        return tuple(n for n, _ in self.hidden if n in EFFECTS)

    @property
    def expected_effect(self) -> str | None:
        """What the first compare run should name (any of them if several are hidden)."""
        found = self.expected_effects
        return found[0] if found else None


@dataclass(frozen=True)
class ForeignDataset:
    spec: ForeignSpec
    bag: Path
    mesh: Path
    scenario: Path
    points: int
    truth: dict


def trajectory_for(spec: ForeignSpec) -> Trajectory:
    """A seeded pose near the boresight at spec.distance_m, with the spec's tumble."""
    rng = np.random.default_rng([spec.seed, 7])
    bearing = rng.uniform(-0.06, 0.06, 2)
    pos = spec.distance_m * _unit([1.0, bearing[0], bearing[1]])
    vel = -spec.speed_mps * _unit(pos) + rng.normal(0, 0.3 * spec.speed_mps, 3)
    # Body +z roughly across the line of sight, tipped so the top or bottom shows.
    attitude = Rotation.from_euler('zyx', [rng.uniform(-60, 60), rng.uniform(-70, -20),
                                           rng.uniform(-30, 30)], degrees=True)
    if spec.tilt_deg is not None:
        # Body +z from lidar +z (across the line of sight, in elevation) or from lidar +y
        # (in azimuth) toward +x (the boresight): the body's +z end (the adapter's) is
        # the far one, deeper by the length between them x sin(tilt).
        roll = rng.uniform(0, 360)
        attitude = ((Rotation.from_euler('y', spec.tilt_deg, degrees=True)
                     if spec.tilt_from == 'z' else
                     Rotation.from_euler('z', -spec.tilt_deg, degrees=True)
                     * Rotation.from_euler('x', -90.0, degrees=True))
                    * Rotation.from_euler('z', roll, degrees=True))
        return Trajectory(tuple(pos), tuple(vel), attitude, (0.0, 0.0, 1.0), spec.spin_dps,
                          (1.0, 0.0, 0.0), 0.0)
    spin_axis = tuple(rng.normal(0, 0.3, 3) + [0, 0, 1])
    precession_axis = tuple(_unit(rng.normal(size=3)))
    if spec.precession_axis is not None:
        spin_axis, precession_axis = (0.0, 0.0, 1.0), tuple(_unit(spec.precession_axis))
    return Trajectory(tuple(pos), tuple(vel), attitude, spin_axis, spec.spin_dps,
                      precession_axis, spec.precession_dps)


def material_errors(spec: ForeignSpec) -> dict[str, tuple[float, float]]:
    """Per-material (bias_m, sigma_m): Table 2, jittered +-1 cm / x0.8-1.2, then shifted."""
    rng = np.random.default_rng([spec.seed, 11])
    out = {}
    for name, (bias, sigma) in table2_error_m().items():
        b = bias + rng.uniform(-0.01, 0.01) + spec.material_bias_shift_m.get(name, 0.0)
        s = sigma * rng.uniform(0.8, 1.2) * spec.material_sigma_scale.get(name, 1.0)
        out[name] = (b, s)
    return out


def simulate_frame(spec: ForeignSpec, sensor: Sensor, target: Target, traj: Trajectory,
                   t0_s: float, rng: np.random.Generator,
                   errors: dict[str, tuple[float, float]]) -> dict[str, Any]:
    """One frame: shots -> raycast (or footprint) -> power -> detection -> range error.

    Returns per-point arrays: xyz_m (lidar frame), power_w, t_s (since t0_s), range_m,
    true_range_m (nan for false returns), material (-1 for false returns), shot (index
    into the frame's shots); and grid, the raster's (rows, cols) or None.
    """
    grid = None
    if spec.scan == 'raster':
        t, az, el = raster_scan(sensor, spec.shots_per_frame)
        grid = raster_shape(sensor, spec.shots_per_frame)
    elif spec.scan == 'rosette':
        t, az, el = rosette_scan(sensor, spec.shots_per_frame, t0_s)
    elif spec.scan == 'flash':
        # One global exposure per frame: the raster's angular grid, every pixel at once.
        t, az, el = raster_scan(sensor, spec.shots_per_frame)
        t = np.zeros(len(t))
    elif spec.scan == 'lissajous':
        t, az, el = lissajous_p60_scan(spec.scan_freq_scale, spec.scan_together,
                                       spec.scan_shot_offset)
    else:
        raise ValueError(f'scan must be raster, rosette, lissajous or flash, got {spec.scan!r}')
    d = directions_lidar(az, el)
    laser = np.arange(len(d)) % spec.lasers if spec.lasers else np.zeros(len(d), int)
    rot, pos = traj.at(t0_s + t)
    origins_b = rot.inv().apply(-pos)
    # The beam the shot really leaves along (a laser's pointing error); the point is
    # reported along d at the range measured along it.
    beam_d = (turned_beams(d, laser, laser_turns_of(spec))
              if spec.params_of('laser_pointing') is not None else d)
    dirs_b = rot.inv().apply(beam_d)
    beam = spec.params_of('beam_divergence')
    if beam is not None:
        hit, true_r, power, cos_i, mat = footprint_returns(target, origins_b, dirs_b, sensor,
                                                           rng, beam)
    else:
        hit, true_r, cos_i, mat = target.cast(origins_b, dirs_b)
        power = received_power_w(sensor, true_r, cos_i, mat, spec.reflection)
    bias = np.zeros(len(d))
    var = np.zeros(len(d))
    for k, name in enumerate(MATERIALS):
        sel = mat == k
        bias[sel], var[sel] = errors[name][0], errors[name][1] ** 2
    mixed = spec.params_of('mixed_pixels')
    fixtures = ([lab_clutter(spec.distance_m)] if spec.clutter else []) + \
        ([Occluder(traj.position_m)] if spec.occluder else []) + \
        ([Backdrop(traj.position_m, mixed['wall_behind_m'])]
         if mixed is not None and mixed.get('wall_behind_m') else [])
    on_mesh = hit.copy()
    hidden = np.zeros(len(d), bool)      # the target's echo hidden by a fixture in front
    for fixture in fixtures:
        # Lab fixtures are static in the lidar frame; a nearer fixture hides the target.
        c_hit, c_r, c_cos = fixture.cast(np.zeros((len(d), 3)), beam_d)
        front = c_hit & (~hit | (c_r < true_r))
        hidden = (hidden | front) & on_mesh
        hit, true_r, cos_i = hit | front, np.where(front, c_r, true_r), np.where(front, c_cos, cos_i)
        mat = np.where(front, CLUTTER, mat)
        power = np.where(front, received_power_w(sensor, c_r, c_cos, np.zeros(len(d), int))
                         * CLUTTER_SURFACE_RATIO, power)
        bias, var = np.where(front, 0.0, bias), np.where(front, CLUTTER_SIGMA_M ** 2, var)
    if mixed is not None:
        hit, true_r, power, cos_i, mat, on_mix = mixed_pixel_returns(
            target, origins_b, rot, beam_d, fixtures, sensor, hit, true_r, power, cos_i, mat,
            rng, mixed)
        bias, var = (np.where(on_mix, 0.0, bias),
                     np.where(on_mix, CLUTTER_SIGMA_M ** 2, var))
    if spec.amplitude_cv > 0:
        # Speckle: the received pulse energy fluctuates shot to shot (Gamma, mean 1); the
        # fluctuating pulse is what both the intensity and the timing walk see.
        m = 1.0 / spec.amplitude_cv ** 2
        power = power * rng.gamma(m, 1.0 / m, len(d))
    r_hit = np.where(hit, true_r, 0.0)
    on_target = hit & (mat >= 0) & (mat < CLUTTER)
    base_sigma = np.sqrt(var)
    contrib: dict[str, tuple[np.ndarray, np.ndarray]] = {}   # effect -> (bias, extra var)
    for eff, p in spec.hidden:
        b, v = np.zeros(len(d)), np.zeros(len(d))
        if eff == 'range_walk':
            b = np.where(hit, range_walk_bias_m(power, sensor, p), 0.0)
        elif eff == 'incidence_angle':
            b = np.where(on_target, incidence_bias_m(cos_i, p, r_hit, sensor), 0.0)
            v = np.where(on_target, incidence_sigma_m(r_hit, cos_i, sensor, p) ** 2, 0.0)
        elif eff == 'snr_noise':
            v = np.where(hit, snr_sigma_m(power, p) ** 2, 0.0)
        elif eff == 'azimuth_bias':
            b = np.where(hit, azimuth_bias_m(az, p), 0.0)
        elif eff == 'laser_bias':
            b = np.where(hit, laser_offsets_of(spec)[laser], 0.0)
        elif eff == 'range_scale':
            # This sensor's counter clock runs fast by `ppm`: every time of flight, and so
            # every range, reads long by that fraction.
            b = np.where(hit, r_hit * p['ppm'] * 1e-6, 0.0)
        elif eff == 'range_cyclic':
            b = np.where(hit, range_cyclic_bias_m(r_hit, p), 0.0)
        elif eff == 'surface_offset':
            # One material's blankets standing proud as this lab models them: each hit on
            # the material is read where the ray meets the plane standoff_m out along
            # its normal (range - s / cos(theta)); the silhouette stays the mesh's.
            k = MATERIALS.index(p.get('material', 'MLI'))
            b = np.where(on_target & (mat == k),
                         -p['standoff_m'] / np.maximum(cos_i, STANDOFF_MIN_COS), 0.0)
        elif eff == 'face_bias':
            b = np.where(on_target, face_bias_m(target, rot, origins_b, dirs_b, p), 0.0)
        elif eff == 'range_drift':
            # The sensor warming up: its range offset settles exponentially toward a_m
            # (time constant tau_s) from the start of the recording.
            b = np.where(hit, p['a_m'] * -np.expm1(-(t0_s + t) / p.get('tau_s', 60.0)), 0.0)
        else:
            continue
        bias, var = bias + b, var + v
        contrib[eff] = (b, v)
    measured = r_hit + bias + np.sqrt(var) * unit_noise(spec.noise, len(d), rng)
    multipath = np.zeros(len(d), bool)
    mp = spec.params_of('multipath')
    if mp is not None and mp.get('via') == 'target':
        multipath, ghost_r, power_g = target_multipath_returns(
            target, sensor, origins_b, dirs_b, r_hit, mat, on_target, rng, mp)
        b_g = np.array([errors[m][0] for m in MATERIALS] + [0.0])
        s_g = np.array([errors[m][1] for m in MATERIALS] + [CLUTTER_SIGMA_M])
        mat_g = np.where(multipath, ghost_r[1], len(MATERIALS))
        measured = np.where(multipath, ghost_r[0] + b_g[mat_g]
                            + s_g[mat_g] * rng.standard_normal(len(d)), measured)
        power = np.where(multipath, power_g, power)
    elif mp is not None:
        normal = rot.apply(target.cast(origins_b, dirs_b, with_normal=True)[4])
        multipath, extra, wall_power = multipath_returns(spec, sensor, d, r_hit, normal, cos_i,
                                                         mat, on_target, rng, mp)
        measured = np.where(multipath, r_hit + extra
                            + CLUTTER_SIGMA_M * rng.standard_normal(len(d)), measured)
        power = np.where(multipath, wall_power, power)
    detected = hit & (power >= sensor.threshold_power_w)
    solar = spec.params_of('solar_background')
    if solar is not None:
        p = solar
        if p.get('first_return'):
            # A Poisson background over the range gate: `fraction` is the chance of a
            # crossing over the whole gate (a shot that sees no echo); the receiver
            # records the first crossing only if it comes before a detected echo.
            lo, hi = sensor.min_range_m, sensor.max_range_m
            per_m = -np.log1p(-p.get('fraction', 0.015)) / (hi - lo)
            first = lo + rng.exponential(1.0 / per_m, len(d))
            echo = hit & (power >= sensor.threshold_power_w)
            false = (first < hi) & (~echo | (first < measured))
            measured = np.where(false, first, measured)
        else:
            false = rng.random(len(d)) < p.get('fraction', 0.015)
            measured = np.where(false, background_range_m(len(d), rng, sensor, p), measured)
        power = np.where(false, sensor.threshold_power_w * rng.uniform(1.0, 3.0, len(d)), power)
        r_hit = np.where(false, np.nan, r_hit)
        mat = np.where(false, -1, mat)
        hidden &= ~false
        detected |= false
    detected &= (measured > sensor.min_range_m) & (measured < sensor.max_range_m)
    i = np.flatnonzero(detected)
    silent = np.flatnonzero(~detected)
    frame = {'xyz_m': d[i] * measured[i, None], 'power_w': power[i], 't_s': t[i],
             'laser': laser[i], 'silent_t_s': t[silent], 'silent_laser': laser[silent],
             'range_m': measured[i], 'true_range_m': r_hit[i], 'material': mat[i],
             'cos_i': cos_i[i], 'shot': i, 'n_shots': len(d), 'shot_t_s': t, 'grid': grid,
             'base_sigma_m': base_sigma[i], 'multipath': multipath[i], 'hidden': hidden[i],
             'effects': {k: (b[i], v[i]) for k, (b, v) in contrib.items()}}
    frame['return_index'] = np.zeros(len(i), np.int64)
    xt = spec.params_of('crosstalk')
    if xt is not None:
        real = detected & (mat >= 0)
        at, ghost_r, ghost_p = crosstalk_returns(measured, power, real, laser, sensor, rng, xt)
        frame = with_ghosts(frame, d, t, laser, at, ghost_r, ghost_p)
    veil = spec.params_of('veil')
    if veil is not None:
        frame = through_veil(frame, d, t, laser, measured, power, detected, r_hit, mat, sensor,
                             spec.distance_m, rng, veil)
    dual = spec.params_of('dual_return')
    if dual is not None:
        first = detected & on_target & (mat >= 0)
        at, r2, p2, m2 = second_returns(target, origins_b, dirs_b, r_hit, first, sensor, rng,
                                        dual)
        sig = np.array([errors[m][1] for m in MATERIALS])
        b2 = np.array([errors[m][0] for m in MATERIALS])
        meas2 = r2 + b2[m2] + sig[m2] * rng.standard_normal(len(at))
        ok = meas2 < sensor.max_range_m
        frame = with_ghosts(frame, d, t, laser, at[ok], meas2[ok], p2[ok], material=m2[ok],
                            index=1, true_range_m=r2[ok])
    return frame


def second_returns(target: Target, origins_b: np.ndarray, dirs_b: np.ndarray,
                   first_r: np.ndarray, first: np.ndarray, sensor: Sensor,
                   rng: np.random.Generator, p: dict) -> tuple[np.ndarray, ...]:
    """A dual-return receiver, this sensor's own form: the footprint's edge as
    ``subrays`` (8) rays on a ring at ``scale`` (6) x half the nominal divergence, at a
    random phase per shot. A shot whose echo was detected on the target, and some of whose
    ring rays meet a surface more than ``separation_m`` (0.5 m: the receiver's pulse
    separation) beyond the echo, reports a second return at the farthest such range,
    with that surface's power times the share of the ring on it; kept above the
    threshold. Returns (shot index, true range m, power W, material id)."""
    k = int(p.get('subrays', 8))
    idx = np.flatnonzero(first)
    n = len(idx)
    if n == 0:
        return (np.zeros(0, int),) + (np.zeros(0),) * 2 + (np.zeros(0, int),)
    half = 0.5 * p.get('scale', 6.0) * sensor.divergence_rad
    phi = 2 * np.pi * (rng.random((n, 1)) + np.arange(k)[None, :] / k)
    dirs = dirs_b[idx]
    helper = np.where(np.abs(dirs[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(dirs, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(dirs, u)
    sub = dirs[:, None, :] + np.tan(half) * (np.cos(phi)[..., None] * u[:, None]
                                             + np.sin(phi)[..., None] * v[:, None])
    sub /= np.linalg.norm(sub, axis=2, keepdims=True)
    hit, r, cos_i, mat = target.cast(np.repeat(origins_b[idx], k, axis=0), sub.reshape(-1, 3))
    hit, r = hit.reshape(n, k), r.reshape(n, k)
    far = hit & (r > first_r[idx, None] + p.get('separation_m', 0.5))
    top = np.argmax(np.where(far, r, -np.inf), axis=1)
    has = far.any(axis=1)
    pick = np.arange(n) * k + top
    r2 = r.reshape(-1)[pick]
    share = far.sum(axis=1) / k
    power = received_power_w(sensor, r2, cos_i[pick], np.clip(mat[pick], 0, None)) * share
    ok = has & (power >= sensor.threshold_power_w) & (mat[pick] >= 0)
    return idx[ok], r2[ok], power[ok], mat[pick][ok]


CROSSTALK = -2     # material id of a crosstalk ghost (not the target, not a false return)


def crosstalk_returns(measured_m: np.ndarray, power_w: np.ndarray, real: np.ndarray,
                      laser: np.ndarray, sensor: Sensor, rng: np.random.Generator,
                      p: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crosstalk between channels, this sensor's own form: the echo of a return of power
    P on shot k leaks into the receiver of the channel that fires next (shot k+1, another
    laser), with a chance that grows with how far P stands above the strong level
    S = ``strong`` x threshold: ``p`` (1 - S / P) for P > S, nothing below. The leaked
    echo is timed by the next channel's electronics: its range is shot k's measured range
    plus ``offset_m`` (a fixed delay) plus 1 cm of its own timing noise, its power
    ``ratio`` x P, along shot k+1's direction (a second return there if that shot has
    its own). Returns (shot index of each ghost, its range m, its power W)."""
    strong = p.get('strong', 20.0) * sensor.threshold_power_w
    with np.errstate(divide='ignore', invalid='ignore'):
        chance = np.where(real & (power_w > strong), p.get('p', 0.5) * (1.0 - strong / power_w),
                          0.0)
    src = np.flatnonzero(rng.random(len(power_w)) < chance)
    src = src[src + 1 < len(power_w)]
    src = src[laser[src + 1] != laser[src]]
    ghost_r = measured_m[src] + p.get('offset_m', 0.3) + 0.01 * rng.standard_normal(len(src))
    ghost_p = p.get('ratio', 0.15) * power_w[src]
    keep = (ghost_p >= sensor.threshold_power_w) & (ghost_r < sensor.max_range_m)
    return src[keep] + 1, ghost_r[keep], ghost_p[keep]


def with_ghosts(frame: dict, d: np.ndarray, t: np.ndarray, laser: np.ndarray, at: np.ndarray,
                range_m: np.ndarray, power_w: np.ndarray, material: np.ndarray | None = None,
                index: int = 0, true_range_m: np.ndarray | None = None) -> dict:
    """``frame`` with the extra returns (shot ``at``, ``range_m``, ``power_w``) merged in
    shot order, after their shot's own (material CROSSTALK unless given, no effect bias,
    return index ``index``)."""
    n = len(at)
    add = {'xyz_m': d[at] * range_m[:, None], 'power_w': power_w, 't_s': t[at],
           'laser': laser[at], 'range_m': range_m,
           'true_range_m': np.full(n, np.nan) if true_range_m is None else true_range_m,
           'material': np.full(n, CROSSTALK) if material is None else material, 'shot': at,
           'base_sigma_m': np.full(n, 0.01), 'return_index': np.full(n, index, np.int64),
           'multipath': np.zeros(n, bool), 'hidden': np.zeros(n, bool),
           'second': np.ones(n, bool), 'cos_i': np.ones(n)}
    frame = {**frame, 'second': frame.get('second', np.zeros(len(frame['shot']), bool))}
    order = np.argsort(np.concatenate([frame['shot'], at]), kind='stable')
    out = dict(frame)
    for k, v in add.items():
        out[k] = np.concatenate([frame[k], v])[order]
    out['effects'] = {k: (np.concatenate([b, np.zeros(n)])[order],
                          np.concatenate([v, np.zeros(n)])[order])
                      for k, (b, v) in frame['effects'].items()}
    return out


VEIL = -3         # material id of a veil's return (a film in front of the target, not the target)


def through_veil(frame: dict, d: np.ndarray, t: np.ndarray, laser: np.ndarray,
                 measured: np.ndarray, power: np.ndarray, detected: np.ndarray,
                 r_hit: np.ndarray, mat: np.ndarray, sensor: Sensor, distance_m: float,
                 rng: np.random.Generator, p: dict) -> dict:
    """A thin film (a veil: a thermal blanket's loose foil, a net, a lab curtain) across
    the line of sight at ``at`` (0.55) x the target's distance, ``half_w_m`` x
    ``half_h_m`` (1.2 x 0.6 m) in the lidar's y and z, outside the catalogue. A shot
    through it returns the film first (index 0: its range with CLUTTER_SIGMA_M of noise,
    a weak power ``reflect`` (4) x the threshold with a 30 % spread) and, behind it, the
    target's echo as a later return (index 1) where that echo, ``transmission`` (0.95)
    squared of its power, is still above the threshold. ``frame`` with the film's returns
    in place of the shots' own and the target's behind them."""
    x = p.get('at', 0.55) * distance_m
    with np.errstate(divide='ignore', invalid='ignore'):
        r_v = np.where(d[:, 0] > 0, x / d[:, 0], np.inf)
    y, z = d[:, 1] * r_v, d[:, 2] * r_v
    cross = (np.isfinite(r_v) & (np.abs(y) <= p.get('half_w_m', 1.2))
             & (np.abs(z) <= p.get('half_h_m', 0.6))
             & (~detected | ~np.isfinite(measured) | (r_v < measured)))
    shots = np.asarray(frame['shot'])
    in_frame = np.zeros(len(d), bool)
    in_frame[shots] = True
    # The target's echo behind the film, where the shot had one: moved to index 1.
    behind = cross & in_frame & (power * p.get('transmission', 0.95) ** 2
                                 >= sensor.threshold_power_w)
    film_r = r_v + CLUTTER_SIGMA_M * rng.standard_normal(len(d))
    film_p = sensor.threshold_power_w * p.get('reflect', 4.0) * rng.uniform(0.7, 1.3, len(d))
    out = dict(frame)
    row = np.full(len(d), -1)
    row[shots] = np.arange(len(shots))
    hit_rows = row[cross & in_frame]
    at_target = np.flatnonzero(behind)
    target = {k: np.asarray(frame[k])[row[at_target]] for k in ('range_m', 'power_w')}
    target_mat = np.asarray(frame['material'])[row[at_target]]
    target_true = np.asarray(frame['true_range_m'])[row[at_target]]
    # The film replaces the shots' own first return (or adds one where there was none).
    fresh = np.flatnonzero(cross & ~in_frame & (film_r > sensor.min_range_m))
    for k, v in (('range_m', film_r), ('power_w', film_p)):
        arr = np.asarray(out[k], float).copy()
        arr[hit_rows] = v[cross & in_frame]
        out[k] = arr
    out['xyz_m'] = np.asarray(out['xyz_m']).copy()
    out['xyz_m'][hit_rows] = d[cross & in_frame] * film_r[cross & in_frame, None]
    for k, v in (('material', VEIL), ('true_range_m', np.nan)):
        arr = np.asarray(out[k]).copy()
        arr[hit_rows] = v
        out[k] = arr
    eff = {}
    for k, (b, var) in frame['effects'].items():
        b, var = np.asarray(b, float).copy(), np.asarray(var, float).copy()
        b[hit_rows], var[hit_rows] = 0.0, 0.0
        eff[k] = (b, var)
    out['effects'] = eff
    if len(fresh):
        out = with_ghosts(out, d, t, laser, fresh, film_r[fresh], film_p[fresh],
                          material=np.full(len(fresh), VEIL))
    return with_ghosts(out, d, t, laser, at_target, target['range_m'],
                       target['power_w'] * p.get('transmission', 0.95) ** 2,
                       material=target_mat, index=1, true_range_m=target_true)


STANDOFF_MIN_COS = 0.05   # a standoff read along the ray: at most 20 x s at grazing
SPECULAR_MIN = 0.5     # specular albedo of a mirror-like material (MLI, PSS)


def multipath_returns(spec: ForeignSpec, sensor: Sensor, dirs: np.ndarray, true_r: np.ndarray,
                      normal: np.ndarray, cos_i: np.ndarray, mat: np.ndarray,
                      on_target: np.ndarray, rng: np.random.Generator,
                      p: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which shots return via a mirror path, their extra one-way path (m) and the
    power of that return (W). A shot on a mirror-like material, beyond
    min_incidence_deg (the direct glint is gone, its lobe points elsewhere), whose
    mirror ray meets a bright lab surface (``multipath_extra_m``; with clutter, the
    fixtures too, the nearer wins) returns that way with probability p. The bright
    surface scatters like the clutter; the light meets the mirror twice."""
    n = len(dirs)
    specular = np.array([SURFACES[m].specular for m in MATERIALS] + [0.0])
    mirror_like = on_target & (specular[np.clip(mat, 0, len(MATERIALS))] >= SPECULAR_MIN)
    oblique = cos_i < np.cos(np.radians(p.get('min_incidence_deg', 25.0)))
    point = dirs * np.where(on_target, true_r, 0.0)[:, None]
    mirror = mirror_direction(dirs, np.where(np.isfinite(normal), normal, 0.0))
    extra = multipath_extra_m(point, mirror, sensor, spec.distance_m, p)
    cos_wall = np.full(n, 0.5)       # a typical incidence on the room's surfaces
    if spec.clutter:
        idx = np.flatnonzero(mirror_like & oblique)
        c_hit, c_r, c_cos = lab_clutter(spec.distance_m).cast(point[idx], mirror[idx])
        nearer = c_hit & ~(extra[idx] <= c_r)
        extra[idx[nearer]] = c_r[nearer]
        cos_wall[idx[nearer]] = c_cos[nearer]
    chosen = mirror_like & oblique & np.isfinite(extra) & (rng.random(n) < p.get('p', 0.15))
    s = specular[np.clip(mat, 0, len(MATERIALS))]
    path = np.where(chosen, true_r + extra, 1.0)
    power = (received_power_w(sensor, path, cos_wall, np.zeros(n, int))
             * CLUTTER_SURFACE_RATIO * s ** 2)
    return chosen, np.where(chosen, extra, 0.0), np.where(chosen, power, 0.0)


def target_multipath_returns(target: Target, sensor: Sensor, origins_b: np.ndarray,
                            dirs_b: np.ndarray, true_r: np.ndarray, mat: np.ndarray,
                            on_target: np.ndarray, rng: np.random.Generator, p: dict):
    """Ghosts off the target itself: a shot on a mirror-like material (specular albedo
    >= SPECULAR_MIN) whose mirror ray (body frame) meets another part B of the
    satellite within ``max_path_m`` (3 m) returns via B with probability ``p``, at range
    r + |AB| along the shot (out and back: (r + |AB| + |AB| + r) / 2). Its power: B's
    Blinn return over the whole path, times A's specular albedo twice; its range error
    is B's (the pulse is B's). Returns (chosen, (ghost range m, B's material id), power W)."""
    n = len(dirs_b)
    specular = np.array([SURFACES[m].specular for m in MATERIALS] + [0.0])
    idx = np.flatnonzero(on_target & (specular[np.clip(mat, 0, len(MATERIALS))] >= SPECULAR_MIN))
    chosen, ghost_r = np.zeros(n, bool), np.zeros(n)
    mat_b, power = np.full(n, len(MATERIALS)), np.zeros(n)
    if len(idx) == 0:
        return chosen, (ghost_r, mat_b), power
    normal = target.cast(origins_b[idx], dirs_b[idx], with_normal=True)[4]
    normal = np.where(np.isfinite(normal), normal, 0.0)
    point = origins_b[idx] + dirs_b[idx] * true_r[idx, None]
    hit, ab, cos_b, m_b = target.cast(point + 1e-4 * normal, mirror_direction(dirs_b[idx], normal))
    ok = hit & (ab > 0.02) & (ab < p.get('max_path_m', 3.0))
    pick = idx[ok][rng.random(int(ok.sum())) < p.get('p', 0.3)]
    sel = np.isin(idx, pick)
    chosen[pick] = True
    ghost_r[pick] = true_r[pick] + ab[sel]
    mat_b[pick] = m_b[sel]
    power[pick] = (received_power_w(sensor, ghost_r[pick], cos_b[sel], m_b[sel])
                   * specular[mat[pick]] ** 2)
    return chosen, (ghost_r, mat_b), power


def effect_gain_nats(frames: list[dict], name: str) -> float:
    """What a bias/noise effect is worth, nats per target point: the expected
    log-likelihood gain of the true model over one without the effect whose
    per-material offset and sigma are refit (0.5 d^2 / var for the bias d about its
    material mean, plus the Gaussian KL of the variance about the material's mean)."""
    mat = np.concatenate([f['material'] for f in frames])
    sig2 = np.concatenate([f['base_sigma_m'] for f in frames]) ** 2
    b = np.concatenate([f['effects'][name][0] for f in frames])
    v = np.concatenate([f['effects'][name][1] for f in frames])
    gain = []
    for k in range(len(MATERIALS)):
        sel = mat == k
        if sel.sum() < 30:
            continue
        total = sig2[sel] + v[sel]
        ratio = total / np.mean(total)
        d = b[sel] - np.mean(b[sel])
        gain.append(0.5 * d ** 2 / total + 0.5 * (ratio - 1.0 - np.log(ratio)))
    return float(np.mean(np.concatenate(gain))) if gain else 0.0


def unit_noise(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean, unit-variance range noise: 'gauss', or 'studentN' (Student t with N > 2
    degrees of freedom, default 4: the same sigma with heavier tails)."""
    if kind == 'gauss':
        return rng.standard_normal(n)
    if kind.startswith('student'):
        dof = float(kind[len('student'):] or 4)
        if dof <= 2:
            raise ValueError(f'Student t noise needs more than 2 dof, got {kind!r}')
        return rng.standard_t(dof, n) / np.sqrt(dof / (dof - 2))
    raise ValueError(f'noise must be gauss or studentN, got {kind!r}')


# ---------------------------------------------------------------- bag output
_POINTFIELD_CODE = {'u1': 2, 'u2': 4, 'i4': 5, 'u4': 6, 'f4': 7, 'f8': 8}


def cloud_fields(spec: ForeignSpec, frame: dict, intensity: np.ndarray | None,
                 stamp_s: float, t_abs0_s: float) -> np.ndarray:
    """The per-point record of this sensor: xyz, optional intensity and time, padded to
    a multiple of 16 bytes (drivers often pad). Organized clouds hold every shot of the
    raster, NaN where it gave no return (as Ouster-like drivers publish them)."""
    if spec.layout == 'cepton':
        return cepton_fields(spec, frame, stamp_s, t_abs0_s)
    if spec.layout != 'generic':
        raise ValueError(f'layout must be generic or cepton, got {spec.layout!r}')
    n_out = frame['n_shots'] if spec.organized else len(frame['range_m'])
    at = frame['shot'] if spec.organized else np.arange(n_out)
    t_point = frame['shot_t_s'] if spec.organized else frame['t_s']   # s since frame start
    xyz = np.full((n_out, 3), np.nan)
    xyz[at] = frame['xyz_m']
    names, formats, values = ['x', 'y', 'z'], ['<f4'] * 3, list(xyz.T)
    if intensity is not None:
        full = np.zeros(n_out, intensity.dtype)
        full[at] = intensity
        names.append('intensity')
        formats.append('<' + intensity.dtype.str[1:])
        values.append(full)
    since_stamp_s = t_point + t_abs0_s - stamp_s
    if spec.point_time == 't_s':
        names.append('t'), formats.append('<f4'), values.append(since_stamp_s)
    elif spec.point_time == 't_ns':       # Ouster-style: uint32 ns since the stamp
        if since_stamp_s.min() < 0:
            raise ValueError('t_ns (unsigned) needs the stamp at the scan start')
        names.append('t'), formats.append('<u4')
        values.append(np.round(since_stamp_s * 1e9).astype(np.uint32))
    elif spec.point_time == 'timestamp':  # Velodyne/Hesai-style absolute float64 seconds
        names.append('timestamp'), formats.append('<f8')
        values.append(EPOCH_NS / NS_PER_S + t_abs0_s + t_point)
    elif spec.point_time != 'none':
        raise ValueError(f'point_time must be t_s, t_ns, timestamp or none, '
                         f'got {spec.point_time!r}')
    if spec.lasers:
        full = np.zeros(n_out, np.uint16)
        full[at] = frame['laser']
        names.append('ring'), formats.append('<u2'), values.append(full)
    dual = spec.params_of('dual_return') or spec.params_of('veil')
    if dual is not None and dual.get('field', 'return'):
        # The receiver's return index: from ``base`` (0 or 1) for the first return.
        full = np.zeros(n_out, np.uint8)
        full[at] = frame['return_index'] + int(dual.get('base', 0))
        names.append(dual.get('field', 'return')), formats.append('u1'), values.append(full)
    offsets, off = [], 0
    for f in formats:
        size = np.dtype(f).itemsize
        off = -(-off // size) * size
        offsets.append(off)
        off += size
    step = -(-off // 16) * 16
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets, 'itemsize': step})
    rec = np.zeros(n_out, dtype=dtype)
    for n, v in zip(names, values):
        rec[n] = v
    return rec


def cepton_fields(spec: ForeignSpec, frame: dict, stamp_s: float, t_abs0_s: float) -> np.ndarray:
    """The Cepton SDK3 driver's record (issue 20's field list, packed, 28 bytes): returns,
    then one NO_RETURN point (0, 0, 0) per silent shot; intensity = this sensor's
    range-compensated reflectivity in 1 % steps; returns above SATURATION_POWER_W flagged
    SATURATED (kept, as the driver does)."""
    p = frame['power_w']
    refl = np.round(p * compensation_range_m(spec, frame) ** 2 / 3.0e-5 * 100) / 100
    t = np.concatenate([frame['t_s'], frame['silent_t_s']])
    n_ret = len(p)
    names = ['x', 'y', 'z', 'intensity', 'timestamp_s', 'timestamp_us', 'flags', 'channel_id']
    formats = ['<f4'] * 4 + ['<i4', '<i4', '<u2', '<u2']
    offsets = [0, 4, 8, 12, 16, 20, 24, 26]
    rec = np.zeros(len(t), np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                                     'itemsize': 28}))
    rec['x'][:n_ret], rec['y'][:n_ret], rec['z'][:n_ret] = frame['xyz_m'].T
    rec['intensity'][:n_ret] = refl
    t_us = EPOCH_NS // 1000 + np.floor((t_abs0_s + t) * 1e6).astype(np.int64)
    rec['timestamp_s'], rec['timestamp_us'] = np.divmod(t_us, 1_000_000)
    flags = np.zeros(len(t), np.uint16)
    flags[:n_ret][p >= SATURATION_POWER_W] = CEPTON_SATURATED
    flags[n_ret:] = CEPTON_NO_RETURN
    rec['flags'] = flags
    rec['channel_id'] = np.concatenate([frame['laser'], frame['silent_laser']])
    return rec


def compensation_range_m(spec: ForeignSpec, frame: dict) -> np.ndarray:
    """Per point, the range a compensated intensity is scaled with (m): the measured
    range, or with ``intensity_range='true'`` the true one where there is one."""
    if spec.intensity_range == 'measured':
        return frame['range_m']
    if spec.intensity_range != 'true':
        raise ValueError(f'intensity_range must be measured or true, got {spec.intensity_range!r}')
    true = frame['true_range_m']
    return np.where(np.isfinite(true) & (true > 0), true, frame['range_m'])


def write_cloud(writer: BagWriter, rec: np.ndarray, stamp_ns: int,
                shape: tuple[int, int] | None = None, topic: str = CLOUD_TOPIC,
                frame_id: str = FRAME_ID) -> None:
    """Serialise a structured array as sensor_msgs/msg/PointCloud2 and write it;
    ``shape`` (rows, cols) makes it an organized, non-dense cloud."""
    types = writer.typestore.types
    fields = [types['sensor_msgs/msg/PointField'](
        name=n, offset=rec.dtype.fields[n][1], datatype=_POINTFIELD_CODE[rec.dtype[n].str[1:]],
        count=1) for n in rec.dtype.names]
    height, width = shape if shape is not None else (1, len(rec))
    sec, nsec = divmod(int(stamp_ns), NS_PER_S)
    msg = types['sensor_msgs/msg/PointCloud2'](
        header=types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nsec), frame_id=frame_id),
        height=height, width=width, fields=fields, is_bigendian=False,
        point_step=rec.dtype.itemsize, row_step=rec.dtype.itemsize * width,
        data=np.frombuffer(rec.tobytes(), np.uint8), is_dense=shape is None)
    cdr = writer.typestore.serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2')
    writer.write_raw(topic, 'sensor_msgs/msg/PointCloud2', stamp_ns, cdr)


def reference_pose_error(spec: ForeignSpec, t_s: np.ndarray, period_s: float,
                         rot: Rotation, pos: np.ndarray) -> tuple[Rotation, np.ndarray]:
    """The recorded poses with the spec's reference-pose error: a rigid transform of
    the target (translation RMS ``pose_error[0]`` m per axis, rotation about the body
    origin RMS ``pose_error[1]`` deg per axis), constant over each cloud's frame period
    (``pose_error_period_s`` 0) or a smooth sum of two sinusoids per axis of that period
    and a third of it. The lidar measured the true target: only the poses are off."""
    pos = pos + np.asarray(spec.pose_offset_m, float)
    ramp_m, ramp_deg = spec.pose_error_ramp
    if ramp_m > 0 or ramp_deg > 0:
        # Within each cloud: 0 at its scan's start, the cloud's draw at its end (a lag
        # growing over the scan), back to 0 at the next cloud's start.
        gap = spec.frame_gap_s or period_s
        k = np.clip(np.floor(t_s / gap).astype(int), 0, spec.frames - 1)
        u = np.clip((t_s - k * gap) / period_s, 0.0, 1.0)[:, None]
        draws = np.random.default_rng([spec.seed, 37]).standard_normal((spec.frames, 6))
        pos = pos + ramp_m * u * draws[k, :3]
        rot = rot * Rotation.from_rotvec(np.radians(ramp_deg) * u * draws[k, 3:])
    sigma_m, sigma_deg = spec.pose_error
    if sigma_m <= 0 and sigma_deg <= 0:
        return rot, pos
    rng = np.random.default_rng([spec.seed, 31])
    if spec.pose_error_period_s <= 0:
        k = np.clip(np.floor(t_s / period_s).astype(int), 0, spec.frames - 1)
        draws = rng.standard_normal((spec.frames, 6))
        err = draws[k]
    else:
        freq = np.array([1.0, 3.0]) / spec.pose_error_period_s
        phase = rng.uniform(0, 2 * np.pi, (2, 6))
        amp = rng.standard_normal((2, 6)) * np.array([[1.0], [0.5]])
        err = sum(amp[j] * np.sin(2 * np.pi * freq[j] * t_s[:, None] + phase[j])
                  for j in range(2)) / np.sqrt(0.5 * 1.25)
    pos = pos + sigma_m * err[:, :3]
    rot = rot * Rotation.from_rotvec(np.radians(sigma_deg) * err[:, 3:])
    return rot, pos


def stamp_offset_s(spec: ForeignSpec, sensor: Sensor) -> float:
    """Cloud stamp relative to the scan start: start, mid or end of the scan. Without a
    usable per-point time ('auto') the cloud is stamped mid-scan, the least-biased
    single time; an absolute 'timestamp' field goes with a start stamp, like drivers."""
    scan_s = sensor.scan_fraction / sensor.frame_rate_hz
    where = spec.stamp if spec.stamp != 'auto' else ('mid' if spec.point_time == 'none'
                                                      else 'start')
    offsets = {'start': 0.0, 'mid': 0.5 * scan_s, 'end': scan_s}
    if where not in offsets:
        raise ValueError(f'stamp must be start, mid, end or auto, got {spec.stamp!r}')
    return offsets[where]


def write_compare_scenario(path: Path, mesh: Path, traj: Trajectory) -> Path:
    """The scenario compare is given: the P-60 sensor config and materials.yaml (with no
    hidden effect); its pose fields are required by the format but unused by compare."""
    q = traj.attitude.as_quat()
    scenario = {'seed': 5, 'mesh': str(mesh),
                'sensor': str(REPO / 'config' / 'cepton_vista_p60.yaml'),
                'materials': str(REPO / 'config' / 'materials.yaml'),
                'initial_pose': {'position_m': [float(x) for x in traj.position_m],
                                 'quat_xyzw': [float(x) for x in q]},
                'effects': []}
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return path


def generate(spec: ForeignSpec, out_dir: str | Path,
             sensor: Sensor | None = None) -> ForeignDataset:
    """Simulate ``spec`` and write out_dir/{satellite.obj,.mtl, scenario.yaml, bag/}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name, _ in spec.hidden:
        if name not in EFFECTS + OUTSIDE_CATALOGUE + POSE_RIVALS:
            raise ValueError(f'effect must be one of {EFFECTS + OUTSIDE_CATALOGUE + POSE_RIVALS} '
                             f'or None, got {name!r}')
    if spec.organized and spec.scan != 'raster':
        raise ValueError('organized clouds need the raster scan')
    if (spec.params_of('crosstalk') is not None or spec.params_of('dual_return') is not None) \
            and (spec.organized or not spec.lasers):
        raise ValueError('crosstalk and dual_return need lasers (a channel to leak into, a '
                         'shot to share) and an unorganized cloud (a shot may return twice)')
    sensor = sensor or Sensor(frame_rate_hz=spec.frame_rate_hz, max_range_m=spec.max_range_m)
    parts = satellite_parts(spec.fins, spec.bus_shape)
    mesh = write_obj(parts, out / 'satellite.obj')
    # The drawn (straight) mesh goes to compare; a bent body is what the sensor sees.
    bend = spec.params_of('bent_body')
    target = Target(bent_parts(parts, float(bend['amp_m'])) if bend is not None else parts)
    traj = trajectory_for(spec)
    errors = material_errors(spec)
    rng = np.random.default_rng([spec.seed, 23])
    period = 1.0 / sensor.frame_rate_hz
    # Pose clock minus lidar clock: the pose stamped s shows the target at lidar time s - dt.
    offset = spec.params_of('time_offset')
    dt_s = float(offset.get('dt_s', 0.05)) if offset is not None else 0.0
    n_points = n_clutter = n_false = n_multipath = n_hidden = n_ghost = n_second = n_veil = 0
    kept: list[dict] = []
    bag = out / 'bag'
    gap = spec.frame_gap_s or period
    with BagWriter(bag, storage=spec.storage) as writer:
        span = (spec.frames - 1) * gap + period
        t_pose = np.arange(-0.2, span + 0.2, 1.0 / spec.pose_rate_hz)
        t_true = t_pose
        if spec.pose_lag_s > 0:
            k = np.clip(np.floor(t_pose / gap).astype(int), 0, spec.frames - 1)
            u = np.clip((t_pose - k * gap) / period, 0.0, 1.0)
            t_true = t_pose - spec.pose_lag_s * u
        rot, pos = traj.at(t_true)
        pos_sigma_m, att_sigma_deg = spec.pose_noise
        if pos_sigma_m > 0 or att_sigma_deg > 0:
            noise = np.random.default_rng([spec.seed, 29])
            pos = pos + pos_sigma_m * noise.standard_normal(pos.shape)
            rot = Rotation.from_rotvec(np.radians(att_sigma_deg)
                                       * noise.standard_normal((len(t_pose), 3))) * rot
        rot, pos = reference_pose_error(spec, t_pose, period, rot, pos)
        for tk, q, p in zip(t_pose, rot.as_quat(), pos):
            writer.write_pose(POSE_TOPIC, EPOCH_NS + int(round((tk + dt_s) * NS_PER_S)),
                              CEPTON_FRAME if spec.layout == 'cepton' else FRAME_ID, p, q)
        for k in range(spec.frames):
            t0 = k * gap
            frame = simulate_frame(spec, sensor, target, traj, t0, rng, errors)
            stamp_s = t0 + stamp_offset_s(spec, sensor)
            inten = intensity_units(frame['power_w'], compensation_range_m(spec, frame),
                                    'log' if spec.intensity_scale == 'log' else spec.intensity,
                                    sensor, frame['cos_i'], spec.intensity_cos_exponent)
            rec = cloud_fields(spec, frame, inten, stamp_s, t0)
            cepton = spec.layout == 'cepton'
            write_cloud(writer, rec, EPOCH_NS + int(round(stamp_s * NS_PER_S)),
                        frame['grid'] if spec.organized else None,
                        CEPTON_TOPIC if cepton else CLOUD_TOPIC,
                        CEPTON_FRAME if cepton else FRAME_ID)
            n_points += len(frame['range_m'])
            kept.append({k: frame[k] for k in ('material', 'base_sigma_m', 'effects')})
            n_clutter += int(np.sum(frame['material'] == CLUTTER))
            n_false += int(np.sum(frame['material'] == -1))
            n_ghost += int(np.sum(frame['material'] == CROSSTALK))
            n_veil += int(np.sum(frame['material'] == VEIL))
            n_second += int(np.sum(frame['return_index'] > 0))
            n_multipath += int(np.sum(frame['multipath']))
            n_hidden += int(np.sum(frame['hidden']))
    truth = {'hidden': [[n, p] for n, p in spec.hidden], 'time_offset_s': dt_s,
             **({'laser_offsets_m': laser_offsets_of(spec).tolist()}
                if spec.params_of('laser_bias') is not None else {}),
             **({'laser_turns_deg': laser_turns_of(spec).tolist()}
                if spec.params_of('laser_pointing') is not None else {}),
             'material_errors_m': {k: [round(b, 5), round(s, 5)] for k, (b, s) in errors.items()},
             'distance_m': spec.distance_m,
             'effect_gain_nats': {n: round(effect_gain_nats(kept, n), 5)
                                  for n in kept[0]['effects']} if kept else {},
             'clutter_fraction': n_clutter / max(n_points, 1),
             'false_return_fraction': n_false / max(n_points, 1), 'false_returns': n_false,
             'multipath_fraction': n_multipath / max(n_points, 1),
             'occluded_fraction': n_hidden / max(n_points, 1),
             'crosstalk_fraction': n_ghost / max(n_points, 1),
             'second_returns': n_second, 'veil_returns': n_veil}
    scen = write_compare_scenario(out / 'scenario.yaml', mesh, traj)
    return ForeignDataset(spec, bag, mesh, scen, n_points, truth)


def describe(ds: ForeignDataset) -> dict[str, Any]:
    """A JSON-able record of what was generated."""
    s = ds.spec
    return {'name': s.name, 'effect': s.effect, 'expected': list(s.expected_effects),
            'hidden': [[n, p] for n, p in s.hidden], 'clutter': s.clutter,
            'amplitude_cv': s.amplitude_cv, 'scan': s.scan, 'storage': s.storage, 'intensity': s.intensity,
            'intensity_scale': s.intensity_scale,
            'point_time': s.point_time, 'stamp': s.stamp, 'organized': s.organized,
            'noise': s.noise, 'distance_m': s.distance_m, 'frames': s.frames,
            'frame_rate_hz': s.frame_rate_hz, 'pose_rate_hz': s.pose_rate_hz,
            'points': ds.points, 'note': s.note}


# ------------------------------------------------------------------- battery
# Every hidden effect in its own form at a realistic magnitude, spread over scan
# patterns, storages, intensity encodings, time fields and distances (6-25 m); clean
# datasets (expected: null) in several recording styles, including two robustness
# probes a real sensor would present: motion-capture pose noise and heavy-tailed noise.
BATTERY: tuple[ForeignSpec, ...] = (
    ForeignSpec('clean', None, seed=1),
    ForeignSpec('clean_materials', None, seed=2, scan='rosette', storage='sqlite3',
                intensity='counts16',
                material_bias_shift_m={'PIF': 0.05, 'PAF': -0.04, 'ADAPTER': 0.03},
                material_sigma_scale={'MLI': 1.6},
                note='per-material bias/sigma off the config: belongs under materials'),
    ForeignSpec('clean_no_time', None, seed=3, scan='rosette', intensity='none',
                point_time='none', note='no intensity, no per-point time, stamped mid-scan'),
    ForeignSpec('clean_organized', None, seed=5, organized=True, frame_rate_hz=20.0, frames=5,
                stamp='end', pose_rate_hz=20.0, storage='sqlite3', intensity='counts16',
                note='organized NaN-padded clouds, 20 Hz frames stamped at scan end '
                     '(negative t), poses at 20 Hz'),
    ForeignSpec('clean_timestamp_field', None, seed=4, point_time='timestamp', spin_dps=12.0,
                note='per-point time only as an absolute float64 "timestamp" field, '
                     'clouds stamped at scan start'),
    ForeignSpec('clean_pose_noise', None, seed=6, pose_noise=(0.002, 0.05),
                note='motion-capture pose noise 2 mm / 0.05 deg per pose sample'),
    # --- reference-pose errors (tracking system, extrinsic calibration): no sensor
    # effect is missing; the verdict must say the pose is off
    ForeignSpec('pose_error_rigid', None, seed=48, pose_error=(0.015, 0.25),
                note='reference pose off by a rigid 1.5 cm / 0.25 deg per axis, per cloud'),
    ForeignSpec('pose_error_smooth', None, seed=49, pose_error=(0.015, 0.25),
                pose_error_period_s=1.0, frames=10, shots_per_frame=8000,
                note='reference pose off by 1.5 cm / 0.25 deg, varying smoothly over 1 s'),
    # Per-cloud jitter over many clouds (the seventh holdout's h7-n80-jitB): 60 clouds,
    # about 200 of the diagnosis sample's points each, fewer than six parameters a cloud
    # need on the held-out test (compare's run.pose_points).
    ForeignSpec('pose_jitter_many', None, seed=83, pose_error=(0.004, 0.07), frames=60,
                shots_per_frame=5000,
                note='reference pose off by a rigid 0.4 cm / 0.07 deg per axis, per cloud, '
                     'over 60 clouds'),
    # Per-cloud jitter of one part only (the twelfth holdout's translation-only jitter,
    # reported with a rotation the data did not show): the position 1.5 cm per axis with
    # the attitude exact, and the attitude 0.25 deg per axis with the position exact.
    ForeignSpec('pose_jitter_translation', None, seed=84, pose_error=(0.015, 0.0),
                note='reference pose off by 1.5 cm per axis per cloud, attitude exact'),
    ForeignSpec('pose_jitter_attitude', None, seed=85, pose_error=(0.0, 0.25),
                note='reference pose off by 0.25 deg per axis per cloud, position exact'),
    ForeignSpec('clean_heavy_tails', None, seed=7, noise='student6',
                note='range noise Student t (6 dof) with the Table 2 sigma'),
    ForeignSpec('range_walk_poly', 'range_walk', {'form': 'poly_log', 'a_m': 0.012, 'b_m': 0.003},
                seed=11, storage='sqlite3', point_time='t_ns', distance_m=9.0),
    ForeignSpec('range_walk_sqrt', 'range_walk', {'form': 'inv_sqrt', 'c_m': 0.02}, seed=12,
                scan='rosette', intensity='reflectivity', distance_m=7.0, shots_per_frame=12_000),
    ForeignSpec('incidence_angle', 'incidence_angle', {'g_m': 0.012, 'h': 0.4}, seed=13,
                intensity='counts16', distance_m=12.0),
    ForeignSpec('snr_noise', 'snr_noise', {'s0_m': 0.05, 'exponent': 0.4, 'p0_w': 1e-6},
                seed=14, scan='rosette', distance_m=18.0, shots_per_frame=50_000),
    ForeignSpec('solar_background', 'solar_background', {'fraction': 0.015,
                                                         'mean_range_m': 40.0}, seed=15,
                storage='sqlite3', intensity='none'),
    ForeignSpec('solar_background_far', 'solar_background', {'fraction': 0.006,
                                                             'mean_range_m': 25.0}, seed=16,
                scan='rosette', distance_m=22.0, shots_per_frame=50_000),
    ForeignSpec('beam_divergence', 'beam_divergence', {'scale': 6.0, 'subrays': 12,
                                                       'mode': 'weighted'}, seed=17),
    ForeignSpec('beam_divergence_first', 'beam_divergence', {'scale': 9.0, 'subrays': 8,
                                                             'mode': 'first'}, seed=18,
                scan='rosette', storage='sqlite3', distance_m=8.0, shots_per_frame=14_000),
    ForeignSpec('time_offset', 'time_offset', {'dt_s': 0.06}, seed=19, spin_dps=20.0,
                speed_mps=0.25),
    ForeignSpec('time_offset_small', 'time_offset', {'dt_s': 0.03}, seed=20, spin_dps=15.0,
                point_time='t_ns', distance_m=6.5, scan='rosette', shots_per_frame=12_000),
    ForeignSpec('time_offset_no_time', 'time_offset', {'dt_s': -0.04}, seed=21, spin_dps=15.0,
                point_time='none', intensity='none', note='negative offset, no t field'),
    # --- what labs record: short passes at near-constant range (1 s at ~11 m), where
    # the intensity is nearly a function of incidence and material
    ForeignSpec('short_range_walk', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=31,
                frames=10, speed_mps=0.0, spin_dps=3.0, precession_dps=1.0,
                intensity='linear', shots_per_frame=8000,
                note='walk in ln(received power), intensity proportional to power'),
    ForeignSpec('short_range_walk_speckle', 'range_walk', {'form': 'ln', 'g_m': 0.015},
                seed=32, frames=10, speed_mps=0.0, spin_dps=3.0, precession_dps=1.0,
                intensity='counts16', amplitude_cv=0.25, shots_per_frame=8000, scan='rosette',
                note='speckle: the pulse amplitude fluctuates and drives intensity and walk'),
    ForeignSpec('short_snr_noise', 'snr_noise', {'s0_m': 0.04, 'exponent': 0.5, 'p0_w': 2e-6},
                seed=33, frames=10, speed_mps=0.0, spin_dps=3.0, precession_dps=1.0,
                intensity='linear', shots_per_frame=8000,
                note='power and incidence move together at near-constant range: fitted as '
                     '--fit leaves them, snr_noise and incidence_angle may differ by less '
                     'than the practical margin (a tie is right, foreign_loop.borderline_tie)'),
    ForeignSpec('short_incidence', 'incidence_angle', {'g_m': 0.015, 'h': 0.5}, seed=34,
                frames=10, speed_mps=0.0, spin_dps=3.0, precession_dps=1.0,
                intensity='counts8', shots_per_frame=8000),
    # --- an effect outside the catalogue: null, and the residual's feature named
    ForeignSpec('azimuth_bias', 'azimuth_bias', {'a_m': 0.02, 'period_deg': 12.0}, seed=35,
                expected=None, expected_feature='azimuth', note='range bias periodic in scan azimuth (encoder error)'),
    ForeignSpec('azimuth_bias_short', 'azimuth_bias', {'a_m': 0.015, 'period_deg': 8.0},
                seed=36, frames=10, speed_mps=0.0, spin_dps=3.0, intensity='linear',
                shots_per_frame=8000, scan='rosette', expected=None, expected_feature='azimuth'),
    # --- outside the catalogue and no outlier effect: lab multipath (a mirror path via
    # a specular surface to the lab's walls returns a few metres behind the surface)
    ForeignSpec('multipath_target', 'multipath', {'via': 'target', 'p': 0.3}, seed=53, fins=True,
                note='ghosts of the diffuse fins in the mirror-like MLI sides, at r + |AB|'),
    ForeignSpec('clean_fins', None, seed=51, fins=True,
                note='the finned satellite without ghosts: no false multipath'),
    ForeignSpec('multipath', 'multipath', {'p': 0.05}, seed=46, expected=None,
                note='mirror path via MLI/PSS to the lab room: returns 1-5 m behind the surface'),
    ForeignSpec('clutter_multipath', 'multipath', {'p': 0.08}, seed=47, clutter=True,
                scan='rosette', intensity='counts16', expected=None,
                note='lab clutter, and mirror paths to the room and the fixtures'),
    # --- two effects at once, walked step by step
    ForeignSpec('walk_and_offset', 'range_walk', {'form': 'poly_log', 'a_m': 0.015, 'b_m': 0.002},
                seed=37, also=(('time_offset', {'dt_s': 0.05}),), spin_dps=15.0,
                intensity='counts16'),
    ForeignSpec('incidence_and_solar', 'incidence_angle', {'g_m': 0.015, 'h': 0.5}, seed=38,
                also=(('solar_background', {'fraction': 0.01, 'mean_range_m': 30.0}),),
                scan='rosette', storage='sqlite3'),
    # Three at once (the eleventh holdout's beam_solar_incid): a footprint read at its
    # nearest sub-ray, an incidence bias and false returns of sunlight (docs/compare.md,
    # "A footprint beside an incidence bias and false returns"; there seeds 1-6 are this
    # spec's seed).
    ForeignSpec('beam_solar_incid', 'beam_divergence', {'scale': 5.0, 'subrays': 24,
                                                        'mode': 'first'}, seed=1,
                also=(('incidence_angle', {'g_m': 0.015, 'h': 0.5}),
                      ('solar_background', {'fraction': 0.01, 'mean_range_m': 30.0})),
                note='footprint 5 x 1.2 mrad (nearest of 24 sub-rays), incidence bias, '
                     'solar false returns 1 %'),
    ForeignSpec('snr_and_beam', 'snr_noise', {'s0_m': 0.05, 'exponent': 0.4, 'p0_w': 1e-6},
                seed=39, also=(('beam_divergence', {'scale': 7.0, 'subrays': 12,
                                                    'mode': 'weighted'}),),
                distance_m=16.0, shots_per_frame=40_000, intensity='linear'),
    # --- lab clutter: a wall behind, a support jig, a cable in front
    # --- a range scale (compare tests it only when asked, --effect range_scale): no
    # catalogue effect may be named for it, and no reference-pose error reported
    ForeignSpec('range_scale_approach', 'range_scale', {'ppm': 2000.0}, seed=62, frames=10,
                speed_mps=14.0, distance_m=20.0, shots_per_frame=8000, expected=None,
                note='the counter clock runs 2000 ppm fast; clouds from 20 m to 6 m'),
    ForeignSpec('range_scale_static', 'range_scale', {'ppm': 5000.0}, seed=63, frames=10,
                speed_mps=0.0, spin_dps=3.0, distance_m=12.0, shots_per_frame=8000,
                expected=None, note='the counter clock runs 5000 ppm fast, target at 12 m'),
    ForeignSpec('clutter', None, seed=40, clutter=True, note='wall, jig and cable in view'),
    # --- an object between the sensor and the target (a lab pillar): its returns on the
    # rays it cuts lie metres short of the target; no pose error, no material refit
    ForeignSpec('occluder', None, seed=90, occluder=True,
                note='a pillar 0.4 m wide at 60 % of the distance hides a strip of the target'),
    # A film across the line of sight (outside the catalogue): the shots through it return
    # the film first and the target behind it as a later return of the shot (a return
    # field); the film is not the target, and the target is still seen through it.
    ForeignSpec('veil', None, seed=98, lasers=6, distance_m=9.0,
                also=(('veil', {'at': 0.55, 'half_w_m': 1.2, 'half_h_m': 0.6}),),
                note='a film 1.2 x 2.4 m at 55 % of the distance, the target behind it'),
    ForeignSpec('occluder_walk', 'range_walk', {'form': 'poly_log', 'a_m': 0.03, 'b_m': 0.006},
                seed=91, occluder=True, distance_m=9.0, intensity='counts16',
                note='the pillar, and a range walk to be named through it'),
    # --- crosstalk between channels (outside the catalogue): a strong return leaks into
    # the next shot's channel a fixed delay later (``crosstalk_returns``), 6 lasers
    # round-robin; the ghosts must be counted and left out, and nothing named for them.
    ForeignSpec('crosstalk', None, seed=91, lasers=6, also=(('crosstalk', {'p': 0.5}),),
                note='about a third of the strong returns leak 0.3 m behind into the next shot'),
    ForeignSpec('crosstalk_small_near', None, seed=92, lasers=6, scan='rosette',
                also=(('crosstalk', {'p': 0.05, 'offset_m': 0.1}),),
                note='a few % ghosts only 0.1 m behind, rosette'),
    ForeignSpec('crosstalk_far', None, seed=93, lasers=4, intensity='counts16',
                also=(('crosstalk', {'p': 0.15, 'offset_m': 1.0}),),
                note='about 10 % ghosts 1 m behind'),
    ForeignSpec('crosstalk_walk', 'range_walk', {'form': 'poly_log', 'a_m': 0.015, 'b_m': 0.003},
                seed=94, lasers=6, also=(('crosstalk', {'p': 0.05, 'offset_m': 0.3}),),
                note='a walk beside a few % ghosts: the walk must be named'),
    ForeignSpec('crosstalk_walk_large', 'range_walk', {'form': 'poly_log', 'a_m': 0.015,
                                                       'b_m': 0.003},
                seed=95, lasers=6, scan='rosette',
                also=(('crosstalk', {'p': 0.5, 'offset_m': 0.2}),),
                note='a walk beside a third of ghosts 0.2 m behind'),
    # --- a dual-return receiver (outside the catalogue): a shot whose footprint edge meets
    # a surface behind its echo reports it too (``second_returns``), with a return index
    # field or without one (the two returns share the shot's time, laser and direction);
    # they must be counted and left out as later returns of the shot, not crosstalk.
    ForeignSpec('dual_return', None, seed=96, lasers=6,
                also=(('dual_return', {'scale': 8.0, 'field': 'return'}),),
                note='second returns at depth steps, field return (0 first)'),
    ForeignSpec('dual_return_nofield', None, seed=97, lasers=6, scan='rosette',
                also=(('dual_return', {'scale': 8.0, 'field': None}),),
                note='second returns at depth steps, no return field: shared shot times'),
    ForeignSpec('clutter_solar', 'solar_background', {'fraction': 0.008, 'mean_range_m': 30.0},
                seed=41, clutter=True, scan='rosette', intensity='counts16'),
    # --- clouds without per-point time, stamped at the start, middle or end of the scan
    ForeignSpec('time_offset_no_time_end', 'time_offset', {'dt_s': 0.07}, seed=42,
                spin_dps=15.0, point_time='none', stamp='end', intensity='counts16'),
    ForeignSpec('time_offset_no_time_start', 'time_offset', {'dt_s': -0.08}, seed=43,
                spin_dps=12.0, point_time='none', stamp='start', scan='rosette'),
    ForeignSpec('clean_no_time_end', None, seed=44, spin_dps=12.0, point_time='none',
                stamp='end', expected='time_offset',
                note='a stamp half a scan late is the same data as a clock offset: named as '
                     'time_offset, with the stamp caveat'),
    ForeignSpec('clean_no_time_mid_fast', None, seed=45, spin_dps=20.0, point_time='none',
                stamp='mid', scan='rosette',
                note='fast tumble, no point times: the smear is no physical effect'),
)

# Multi-laser sensors (a range offset per laser) and the Cepton driver's layout (issue 20):
# tested by test/test_compare_laser.py, outside the battery's loop test to keep the suite short.
VENDOR: tuple[ForeignSpec, ...] = (
    ForeignSpec('laser_bias', 'laser_bias', {'sd_m': 0.03}, seed=61, lasers=6,
                shots_per_frame=12_000, expected_feature='laser',
                note='6 lasers round-robin, each its own range offset (sd 3 cm)'),
    ForeignSpec('laser_pointing', 'laser_pointing', {'sd_deg': 0.15}, seed=63, lasers=6,
                shots_per_frame=12_000, expected_feature='laser',
                note='6 lasers round-robin, each beam turned off its reported direction '
                     '(sd 0.15 deg in azimuth and elevation)'),
    ForeignSpec('incidence_lasers', 'incidence_angle', {'g_m': 0.03, 'h': 0.8}, seed=64,
                lasers=6, intensity='counts16', distance_m=12.0, shots_per_frame=12_000,
                note='incidence_angle (own form) on a 6-laser sensor whose beams point right: '
                     'a bias growing with incidence is no laser\'s pointing'),
    ForeignSpec('clean_cepton', None, seed=62, layout='cepton', lasers=6, scan='rosette',
                shots_per_frame=12_000,
                note="the Cepton SDK3 driver's fields: timestamp_s + timestamp_us, flags "
                     '(NO_RETURN points), channel_id, reflectivity in 1 % steps'),
)


# Issue 30 (compare v4): where two explanations leave the same residual. Run by
# bench/hidden_effect_eval.py --only NAME (and a few by test/test_compare_foreign.py);
# ``expected`` is judged by the bench's own rule for each (docs/compare.md, "Compare v4").
V4: tuple[ForeignSpec, ...] = (
    # A tracking system's lag: the reference pose drifts within each 0.1 s scan (a rigid
    # offset growing from 0 at the scan's start), at two sizes; point times in a field.
    ForeignSpec('pose_drift_within', None, seed=71, frames=5, pose_error_ramp=(0.0, 0.9),
                pose_rate_hz=1000.0, shots_per_frame=12_000, expected=None,
                note='reference pose rotating within each scan, ~5 cm at the body end'),
    ForeignSpec('pose_drift_within_large', None, seed=78, frames=5, pose_error_ramp=(0.0, 3.0),
                pose_rate_hz=1000.0, shots_per_frame=12_000, expected=None,
                note='the same, ~17 cm at the body end: a rate the data show'),
    ForeignSpec('pose_drift_within_small', None, seed=72, frames=5,
                pose_error_ramp=(0.0, 0.35), pose_rate_hz=1000.0, shots_per_frame=12_000,
                expected=None, note='the same, ~2 cm at the body end'),
    # A tracking lag tied to the motion (the fifteenth holdout's lag5): the pose recorded
    # at t is the true one at t - 96 ms x u, u the place in the scan (0..1); a 20 deg/s
    # tumble, and a 6 deg/s one on a 1 m/s approach; point times in a field. On the
    # P-60 Lissajous, which meets a direction at several times within the scan: on a
    # raster, whose rows fix the time, the drift is a pattern over the directions to
    # first order (docs/compare.md, "A tracking lag growing over each scan").
    ForeignSpec('pose_lag', None, seed=83, frames=8, spin_dps=20.0, pose_lag_s=0.096,
                pose_rate_hz=1000.0, shots_per_frame=12_000, scan='lissajous',
                expected=None,
                note='reference pose lagging 0 -> 96 ms over each scan, 20 deg/s tumble'),
    ForeignSpec('pose_lag_approach', None, seed=84, frames=8, spin_dps=6.0, speed_mps=1.0,
                pose_lag_s=0.096, pose_rate_hz=1000.0, shots_per_frame=12_000,
                scan='lissajous', expected=None,
                note='the same lag on a 1 m/s approach, 6 deg/s tumble'),
    # The sensor warming up: its range offset settles toward +6 cm (tau 60 s), a cloud
    # every 6 s for a minute, the target held at 10 m.
    ForeignSpec('range_drift', 'range_drift', {'a_m': 0.06, 'tau_s': 60.0}, seed=73,
                frames=10, frame_gap_s=6.0, speed_mps=0.0, spin_dps=1.0, precession_dps=0.3,
                distance_m=10.0, shots_per_frame=8000, expected=None,
                note='thermal range drift 0 -> +3.8 cm over 60 s, static target at 10 m'),
    # A Lissajous 0.5 % off the configured pattern, no time field (and the exact one).
    ForeignSpec('pattern_off_no_time', None, seed=74, scan='lissajous', scan_freq_scale=1.005,
                point_time='none', stamp='start', spin_dps=12.0, expected=None,
                note='the P-60 Lissajous with both frequencies 0.5 % high, no time field'),
    # The same at other rates, and on a faster spin (the times matter more).
    ForeignSpec('pattern_off_fast_03', None, seed=85, scan='lissajous', scan_freq_scale=1.003,
                point_time='none', stamp='start', spin_dps=12.0, expected=None,
                note='the P-60 Lissajous with both frequencies 0.3 % high, no time field'),
    ForeignSpec('pattern_off_slow_05', None, seed=86, scan='lissajous', scan_freq_scale=0.995,
                point_time='none', stamp='start', spin_dps=12.0, expected=None,
                note='the P-60 Lissajous with both frequencies 0.5 % low, no time field'),
    ForeignSpec('pattern_off_fast_1', None, seed=87, scan='lissajous', scan_freq_scale=1.01,
                point_time='none', stamp='start', spin_dps=12.0, expected=None,
                note='the P-60 Lissajous with both frequencies 1 % high, no time field'),
    ForeignSpec('pattern_off_spin', None, seed=88, scan='lissajous', scan_freq_scale=1.005,
                point_time='none', stamp='start', spin_dps=30.0, precession_dps=5.0,
                expected=None,
                note='frequencies 0.5 % high, the target spinning at 30 deg/s'),
    ForeignSpec('pattern_exact_no_time', None, seed=75, scan='lissajous', point_time='none',
                stamp='start', spin_dps=12.0, expected=None,
                note='the P-60 Lissajous as configured, no time field'),
    # The same curve sampled at other instants: lasers firing together, half a shot later.
    ForeignSpec('pattern_together_no_time', None, seed=76, scan='lissajous', point_time='none',
                stamp='start', spin_dps=12.0, expected=None, scan_together=True,
                scan_shot_offset=0.5,
                note='the P-60 Lissajous curve, lasers firing together half a shot later'),
    ForeignSpec('pattern_together_time_offset', 'time_offset', {'dt_s': 0.05}, seed=77,
                scan='lissajous', point_time='none', stamp='start', spin_dps=15.0,
                scan_together=True, scan_shot_offset=0.5,
                note='as pattern_together_no_time, the pose clock 50 ms off'),
    # The fifth holdout's two causes (docs/compare.md): a range walk beside a reference
    # pose drifting within each cloud (incidence_angle was named, or "also"), and a
    # clock offset with lab clutter (the wall's isolated returns named solar_background).
    ForeignSpec('walk_with_drift', 'range_walk', {'form': 'poly_log', 'a_m': 0.03,
                                                  'b_m': 0.006},
                seed=79, frames=5, pose_error_ramp=(0.0, 0.9), pose_rate_hz=1000.0,
                scan='lissajous', expected=None,
                note='range walk and the reference pose drifting within each scan, ~5 cm'),
    ForeignSpec('clock_with_clutter', 'time_offset', {'dt_s': 0.04}, seed=80, clutter=True,
                scan='lissajous', spin_dps=20.0, speed_mps=0.25, expected=None,
                note='40 ms clock offset with a wall, a jig and a cable in view'),
    # A constant reference-pose error (an extrinsic calibration off by centimetres): along
    # the line of sight (every material's ranges move alike, as a sensor range offset
    # would) and mixed; the sixth and seventh holdouts' largest family.
    ForeignSpec('extrinsic_los', None, seed=81, pose_offset_m=(0.05, 0.0, 0.0),
                expected=None, note='the recorded target 5 cm farther along the line of sight'),
    ForeignSpec('extrinsic_mixed', None, seed=82, pose_offset_m=(0.03, 0.02, -0.03),
                expected=None, note='the recorded target off by (3, 2, -3) cm, lidar frame'),
    # Solar false returns in a first-return receiver: 0.5 % a shot over the whole gate.
    ForeignSpec('solar_first_return', 'solar_background',
                {'fraction': 0.005, 'first_return': True}, seed=76, distance_m=20.0,
                note='first-return receiver, 0.5 % per shot over the gate, target at 20 m'),
    # The same with the configured sensor's scan and gate (0.5-250 m): the shots that
    # missed are the model's, so the fitted rate must give the count recorded.
    ForeignSpec('solar_first_return_p60', 'solar_background',
                {'fraction': 0.005, 'first_return': True}, seed=77, distance_m=20.0,
                scan='lissajous', max_range_m=250.0,
                note='as solar_first_return, on the P-60 pattern and range gate'),
)


# A range error outside the catalogue that follows range (the twelfth holdout's
# out_cyclic): a cyclic error of the receiver, 5 cm cos(2 pi r / 3 m), exact reference
# poses. On an approach each cloud sits at another range, so a per-cloud pose takes what
# no catalogue term does; the right answer is no pose claimed (a range error that
# follows range, or the tie with the pose where the data cannot tell). Run by name.
RANGE_OUTSIDE: tuple[ForeignSpec, ...] = (
    ForeignSpec('range_cyclic_approach', 'range_cyclic', {'a_m': 0.05, 'period_m': 3.0},
                seed=121, frames=10, speed_mps=14.0, distance_m=20.0, shots_per_frame=8000,
                expected=None, note='a cyclic range error 5 cm cos(2 pi r / 3 m); clouds '
                                    'from 20 m to 6 m, exact poses'),
    ForeignSpec('range_cyclic_slow', 'range_cyclic', {'a_m': 0.05, 'period_m': 3.0},
                seed=122, frames=10, speed_mps=4.0, distance_m=14.0, shots_per_frame=8000,
                expected=None, note='the same on a slower approach, 14 m to 10 m'),
    ForeignSpec('range_cyclic_short', 'range_cyclic', {'a_m': 0.05, 'period_m': 3.0},
                seed=123, frames=4, speed_mps=3.0, distance_m=12.0, shots_per_frame=8000,
                expected=None, note='a short pass: four clouds, 12 m to 11 m'),
    ForeignSpec('range_cyclic_hold', 'range_cyclic', {'a_m': 0.05, 'period_m': 3.0},
                seed=124, frames=10, speed_mps=0.0, spin_dps=3.0, precession_dps=1.0,
                distance_m=11.0, shots_per_frame=8000, expected=None,
                note='the target held at 11 m: the error is one shape over its depth'),
    # Controls: a real per-cloud pose error on the same approach must still be reported,
    # alone and beside the cyclic error.
    ForeignSpec('pose_error_approach', None, seed=125, pose_error=(0.015, 0.25), frames=10,
                speed_mps=14.0, distance_m=20.0, shots_per_frame=8000,
                note='reference pose off by a rigid 1.5 cm / 0.25 deg per axis, per cloud, '
                     'on the approach 20 m to 6 m'),
    ForeignSpec('range_cyclic_pose', 'range_cyclic', {'a_m': 0.05, 'period_m': 3.0},
                seed=126, pose_error=(0.015, 0.25), frames=10, speed_mps=14.0,
                distance_m=20.0, shots_per_frame=8000, expected=None,
                note='the cyclic range error and the reference pose off per cloud together'),
)



# A range scale with no other effect, beside material range biases off the configuration
# (a nuisance compare refits per material): an independent lab's recording, a short
# approach of the rocket body (12 clouds, 14 -> 12.9 m). compare weighs the range terms
# where the residual's structure is left outside the catalogue (``Diagnosis.weigh_rivals``
# beside an empty decision). By name only; seeds 0-1 developed on, 2-3 held out.
SCALE_ALONE: tuple[ForeignSpec, ...] = (
    ForeignSpec('range_scale_short', 'range_scale', {'ppm': 4000.0}, seed=511, frames=12,
                speed_mps=0.95, distance_m=14.0, shots_per_frame=24_000, tilt_deg=40.0,
                spin_dps=3.0, material_bias_shift_m={'MLI': -0.20, 'PSS': -0.06},
                note='range scale +0.4 %, MLI/PSS range biases -20/-6 cm off the config; '
                     '14 m to 12.9 m'),
    ForeignSpec('range_scale_short_strong', 'range_scale', {'ppm': 10000.0}, seed=531,
                frames=12, speed_mps=0.95, distance_m=14.0, shots_per_frame=24_000,
                tilt_deg=40.0, spin_dps=3.0, material_bias_shift_m={'MLI': -0.20, 'PSS': -0.06},
                note='as range_scale_short with a scale of +1 %'),
    ForeignSpec('range_scale_short_small', 'range_scale', {'ppm': 3000.0}, seed=521,
                frames=12, speed_mps=1.4, distance_m=14.0, shots_per_frame=24_000,
                note='range scale +0.3 % alone, 14 m to 12.5 m'),
)

# A material's blankets standing proud of the mesh, read along each ray to the plane
# standoff_m out (the silhouette left where the mesh has it): the situation of an
# independent lab's recording (8 clouds at 9-12 m, reflectivity, a t and a ring field).
# By name only (bench --only NAME).
STANDOFF: tuple[ForeignSpec, ...] = (
    ForeignSpec('mli_proud_normal', 'surface_offset', {'material': 'MLI', 'standoff_m': 0.025},
                seed=301, frames=8, distance_m=10.5, speed_mps=0.4, spin_dps=5.0,
                intensity='reflectivity', lasers=4, shots_per_frame=12_000, bus_shape='drum',
                note='drum bus in MLI read 2.5 cm out along its normal, the silhouette the mesh\'s'),
    ForeignSpec('mli_proud_rosette', 'surface_offset', {'material': 'MLI', 'standoff_m': 0.03},
                seed=311, frames=8, distance_m=10.5, speed_mps=0.4, spin_dps=5.0,
                intensity='reflectivity', lasers=4, shots_per_frame=12_000, scan='rosette',
                bus_shape='drum',
                note='the same at 3 cm, rosette scan'),
)


# A null recording whose intensity is a reflectivity compensated with the *measured*
# range (P r_meas^2) and carries no noise of its own (no speckle): at a fixed geometry the
# intensity moves only with the range's own error, 2 dr / r in ln I. The situation of an
# independent lab's null (exact poses, 8 clouds at 9-12 m, a t and a ring field), on the
# box bus with panels and on the drum bus; and the same lab's incidence-bias recording.
# The right answer on a null is null; no structure outside the catalogue. By name only.
COMPENSATED: tuple[ForeignSpec, ...] = (
    ForeignSpec('null_reflectivity_box', None, seed=401, frames=8, distance_m=10.5,
                speed_mps=0.4, spin_dps=5.0, intensity='reflectivity', lasers=4,
                shots_per_frame=12_000, fins=True,
                note='no effect, exact poses; intensity P r_meas^2, noise-free; box bus, panels'),
    ForeignSpec('null_reflectivity_drum', None, seed=411, frames=8, distance_m=10.5,
                speed_mps=0.4, spin_dps=5.0, intensity='reflectivity', lasers=4,
                shots_per_frame=12_000, bus_shape='drum',
                note='no effect, exact poses; intensity P r_meas^2, noise-free; drum bus'),
    ForeignSpec('null_reflectivity_lambert', None, seed=431, frames=8, distance_m=10.5,
                speed_mps=0.4, spin_dps=5.0, intensity='reflectivity_lambert', lasers=4,
                shots_per_frame=12_000, fins=True,
                note='no effect, exact poses; intensity P r_meas^2 / cos, noise-free; box bus'),
    ForeignSpec('incidence_reflectivity', 'incidence_angle', {'g_m': 0.012, 'h': 0.4},
                seed=421, frames=8, distance_m=10.5, speed_mps=0.4, spin_dps=5.0,
                intensity='reflectivity', lasers=4, shots_per_frame=12_000, fins=True,
                note='incidence bias; intensity P r_meas^2, noise-free; box bus, panels'),
)


# An incidence bias of another lab's law (walkincid36): g r dtheta sin(theta) /
# cos(theta)^a, in proportion to range, grazing returns read short (g < 0), an extra sigma
# a fraction of the bias's size. On a hold at one range the measured power moves only
# with the incidence (and the material), so a walk free in sign is one more function of
# incidence and may fit this law better than incidence_angle's own form. Right: incidence
# named, or a tie holding it; a walk alone is wrong (``foreign_loop.judge``). The box bus
# with panels and the drum bus (a rocket-like cylinder); a hold at ~10 m and a short
# approach; the intensity deterministic (P r_meas^2 or linear) or with speckle. By name.
_LAW = {'law': 'range_sin', 'g': -3.5, 'a': 0.5, 'sigma_frac': 0.15}
_HOLD = dict(frames=8, distance_m=10.0, speed_mps=0.0, spin_dps=4.0, precession_dps=1.0,
             shots_per_frame=12_000)
INCIDENCE_LAW: tuple[ForeignSpec, ...] = (
    ForeignSpec('incid_law_box_hold', 'incidence_angle', _LAW, seed=501, **_HOLD,
                intensity='linear', fins=True,
                note='incidence law g r dtheta sin/cos^0.5, g -3.5, sigma 0.15 |bias|; box bus, '
                     'panels; held at 10 m; intensity linear in power, noise-free'),
    ForeignSpec('incid_law_box_hold_a7', 'incidence_angle', {**_LAW, 'a': 0.7, 'g': -3.0},
                seed=511, **_HOLD, intensity='reflectivity', lasers=4, fins=True,
                note='the law with a 0.7, g -3.0; intensity P r_meas^2, noise-free'),
    ForeignSpec('incid_law_box_speckle', 'incidence_angle', _LAW, seed=521, **_HOLD,
                intensity='linear', amplitude_cv=0.2, fins=True,
                note='the hold on the box bus with speckle (20 %) on the pulse'),
    ForeignSpec('incid_law_box_approach', 'incidence_angle', _LAW, seed=531, frames=8,
                distance_m=12.0, speed_mps=4.0, spin_dps=4.0, intensity='linear',
                shots_per_frame=12_000, fins=True,
                note='a short approach 12 m -> ~9 m on the box bus, noise-free intensity'),
    ForeignSpec('incid_law_drum_hold', 'incidence_angle', {**_LAW, 'a': 0.8, 'g': -3.0},
                seed=541, **_HOLD, intensity='reflectivity', lasers=4, bus_shape='drum',
                note='the law (a 0.8) on the drum bus, held at 10 m, noise-free intensity'),
    ForeignSpec('incid_law_drum_speckle', 'incidence_angle', {**_LAW, 'a': 0.6, 'g': -3.0},
                seed=551, frames=8, distance_m=10.0, speed_mps=3.0, spin_dps=4.0,
                intensity='counts16', amplitude_cv=0.2, shots_per_frame=12_000,
                bus_shape='drum',
                note='the law (a 0.6) on the drum bus, a short approach, speckle 20 %'),
    # The probe that reproduced the lab's answer on c0f6953 (range_walk named alone,
    # 0.0071 nats/point over incidence_angle): the box hold at seed 604.
    ForeignSpec('incid_law_box_repro', 'incidence_angle', _LAW, seed=604, **_HOLD,
                intensity='linear', fins=True,
                note='the box hold of incid_law_box_hold at the seed that reproduced the lab'),
    # Controls: a true walk on the same box bus must still be named where the power moves
    # at a fixed incidence (speckle; an approach).
    ForeignSpec('walk_box_speckle', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=561,
                **_HOLD, intensity='linear', amplitude_cv=0.2, fins=True,
                note='a walk 0.02 ln P on the box bus held at 10 m, speckle 20 %'),
    ForeignSpec('walk_box_approach', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=571,
                frames=8, distance_m=12.0, speed_mps=4.0, spin_dps=4.0, intensity='linear',
                shots_per_frame=12_000, fins=True,
                note='a walk 0.02 ln P on the box bus, approach 12 m -> ~9 m, no speckle'),
)
INCIDENCE_LAW_NAMES = frozenset(s.name for s in INCIDENCE_LAW if s.effect == 'incidence_angle')


# A few lasers of the 24-laser P-60 pattern off in pointing (pointpose37), the rest
# exact, on the box bus with fins, held or slowly tumbling at ~9 m, exact poses: some
# lasers' tiles barely see the target. Right: laser_pointing named (or its tie with
# laser_bias); wrong: the reference pose claimed off, or another effect alone. By name.
def _few_turns(turns: dict[int, tuple[float, float]], lasers: int = 24) -> list[float]:
    """turns_deg (lasers x (az, el) deg, flattened): ``turns`` on their lasers, 0 else."""
    out = np.zeros((lasers, 2))
    for k, v in turns.items():
        out[k] = v
    return out.ravel().tolist()


_FEW = dict(scan='lissajous', lasers=24, fins=True, frames=8, distance_m=9.0,
            speed_mps=0.0, spin_dps=4.0, precession_dps=1.0)
POINTING_FEW: tuple[ForeignSpec, ...] = (
    ForeignSpec('pointing_few_b', 'laser_pointing',
                {'turns_deg': _few_turns({4: (0.3, 0.0), 12: (0.0, -0.25),
                                          13: (0.2, 0.15), 20: (-0.2, 0.0)})},
                seed=701, **_FEW,
                note='lasers 4, 12, 13, 20 off (0.2-0.3 deg), the rest exact; box bus, fins'),
    ForeignSpec('pointing_few_c', 'laser_pointing',
                {'turns_deg': _few_turns({4: (0.0, 0.3), 20: (0.0, 0.3),
                                          12: (0.0, -0.3), 13: (0.0, -0.3)})},
                seed=711, **_FEW,
                note='el +0.3 on lasers 4 and 20, -0.3 on 12 and 13 (no common turn)'),
)


# A clock offset (poses stamped 30 ms late) with a constant reference-pose translation
# (0, 3, 2) cm beside it, on the rocket-like drum body at 10 m closing 0.3 m/s, tumbling
# 8 deg/s with a 25 deg/s spin about the body's long axis on top (the rotation axis moves):
# 12 clouds over 5.5 s, point times given (clockspin38). Right: time_offset named with the
# pose reported beside it, or the tie naming both; wrong: a tie with a range term that is
# absent, or the clock missed. Controls: the clock alone (named) and the pose alone (no
# clock gained), same motion. By name.
_SPIN = dict(frames=12, frame_gap_s=0.5, distance_m=10.0, speed_mps=0.3, spin_dps=25.0,
             precession_dps=8.0, bus_shape='drum', shots_per_frame=12_000)
CLOCK_SPIN: tuple[ForeignSpec, ...] = (
    ForeignSpec('clock_pose_spin', 'time_offset', {'dt_s': 0.03}, seed=801,
                pose_offset_m=(0.0, 0.03, 0.02), **_SPIN,
                note='poses 30 ms late and off by (0, 3, 2) cm; spin 25 deg/s on a tumble'),
    ForeignSpec('clock_spin', 'time_offset', {'dt_s': 0.03}, seed=811, **_SPIN,
                note='poses 30 ms late alone; spin 25 deg/s on a tumble'),
    ForeignSpec('pose_spin', None, seed=821, pose_offset_m=(0.0, 0.03, 0.02), **_SPIN,
                expected=None, note='poses off by (0, 3, 2) cm alone; spin 25 deg/s on a tumble'),
    # The lab's motion as it gave it: the spin about the body's long axis exactly, the
    # tumble about lidar (0.2, 0, 1).
    ForeignSpec('clock_pose_spin_lab', 'time_offset', {'dt_s': 0.03}, seed=831,
                pose_offset_m=(0.0, 0.03, 0.02), precession_axis=(0.2, 0.0, 1.0), **_SPIN,
                note="poses 30 ms late and off by (0, 3, 2) cm; the lab's spin and tumble axes"),
)
CLOCK_SPIN_NAMES = frozenset(s.name for s in CLOCK_SPIN)


# A range walk read through log counts (walk50): an intensity of 40 log10(P / 1 nW), not
# proportional to the power; the walk -g ln(P / 1 uW). On the P-60 Lissajous (point times)
# and on a flash sensor (one exposure per frame on a raster grid, no time field, stamped at
# the exposure), and a null with the same scale. Right: range_walk named with k ~ g; the
# null null. And the walk beside an incidence bias g tan(theta) on the flat-faced box bus
# (no panels' fins), the Lissajous with point times: both named (or a pair), or their tie;
# incidence alone then "outside the catalogue" is wrong. By name.
_LOG = dict(scan='lissajous', lasers=24, frames=5, distance_m=10.0, intensity_scale='log')
LOG_WALK: tuple[ForeignSpec, ...] = (
    ForeignSpec('walk_log_lissajous', 'range_walk', {'form': 'ln', 'g_m': 0.03}, seed=901,
                **_LOG, note='walk 0.03 ln P; intensity 40 log10(P / 1 nW); P-60 Lissajous'),
    ForeignSpec('walk_log_lissajous_02', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=902,
                **_LOG, note='walk 0.02 ln P; intensity 40 log10(P / 1 nW); P-60 Lissajous'),
    ForeignSpec('walk_log_flash', 'range_walk', {'form': 'ln', 'g_m': 0.03}, seed=903,
                scan='flash', point_time='none', stamp='start', shots_per_frame=12_000,
                frames=5, distance_m=10.0, intensity_scale='log',
                note='walk 0.03 ln P; log intensity; flash: one exposure per frame, no t'),
    ForeignSpec('walk_log_flash_02', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=905,
                scan='flash', point_time='none', stamp='start', shots_per_frame=12_000,
                frames=5, distance_m=10.0, intensity_scale='log',
                note='walk 0.02 ln P; log intensity; flash: one exposure per frame, no t'),
    ForeignSpec('null_log_lissajous', None, seed=904, **_LOG,
                note='no effect; intensity 40 log10(P / 1 nW); P-60 Lissajous'),
    ForeignSpec('walk_incidence_box', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=911,
                scan='lissajous', lasers=24, frames=5, distance_m=10.0, intensity='linear',
                also=(('incidence_angle', {'law': 'tan', 'g_m': 0.035, 'sigma_frac': 0.0}),),
                note='walk 0.02 ln P beside an incidence bias 0.035 tan(theta); box bus'),
    # The lab's pair whose effects partly cancel: the walk reads short at normal incidence
    # (strong returns), the bias short at grazing: -1.2 r dtheta tan(theta) at 6.5 m with
    # the P-60's 1.5 mrad (-0.0117 m), the long axis tilted 55 deg (a wide incidence spread).
    ForeignSpec('walk_incidence_box_neg', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=912,
                scan='lissajous', lasers=24, frames=5, distance_m=6.5, intensity='linear',
                also=(('incidence_angle', {'law': 'tan', 'g_m': -0.0117, 'sigma_frac': 0.0}),),
                note='walk 0.02 ln P beside an incidence bias -0.0117 tan(theta); box bus'),
    # The lab's target (walkpair52): the box bus with its two flat fins (a box-wing), the
    # long axis tilted 55 deg toward the line of sight at 6.5 m, so the flat faces span a
    # wide range and incidence (seed 0: 5.1-6.8 m, 31-79 deg; tilted in azimuth instead,
    # up to 82 deg, and the catalogue's pair at the truth's values, its tan capped at 85
    # deg, fit worse than none). The lab's law -1.2 r (1.5 mrad) tan(theta): range_sin, a
    # 1, g -1.5 on this sensor's 1.2 mrad; the noise within each material the lab's
    # (about 1 cm: Table 2's sigmas x 0.35).
    ForeignSpec('walk_incidence_wings', 'range_walk', {'form': 'ln', 'g_m': 0.02}, seed=952,
                scan='lissajous', lasers=24, frames=5, distance_m=6.5, intensity='linear',
                fins=True, tilt_deg=55.0, tilt_from='z',
                material_sigma_scale={m: 0.35 for m in MATERIALS},
                also=(('incidence_angle', {'law': 'range_sin', 'g': -1.5, 'a': 1.0,
                                           'sigma_frac': 0.0}),),
                note='walk 0.02 ln P beside an incidence bias -1.2 r dtheta tan(theta); '
                     'box-wing tilted 55 deg at 6.5 m, noise about 1 cm'),
    # A third lab's (loswalk53): the box-wing at 8 m turning 8 deg/s about its long axis,
    # tilted 10 deg from lidar z toward the line of sight, so each flat face sweeps a wide
    # range of incidence; the walk 0.02 m per e-fold (strong returns short) beside a bias
    # -0.04 (1/cos(theta) - 1) (short at grazing, partly cancelling the walk); exact
    # reference poses; the noise within each material about 1 cm, as walk_incidence_wings.
    # On a flat face that bias is nearly a target moved along the line of sight: a pose
    # claim alone is wrong. Seeds 0-1 developed on, 2-3 held out.
    ForeignSpec('walk_incidence_wings_los', 'range_walk', {'form': 'ln', 'g_m': 0.02},
                seed=5301, scan='lissajous', lasers=24, frames=5, distance_m=8.0,
                intensity='linear', fins=True, tilt_deg=10.0, tilt_from='z', spin_dps=8.0,
                material_sigma_scale={m: 0.35 for m in MATERIALS},
                also=(('incidence_angle', {'g_m': 0.04, 'h': 0.0}),),
                note='walk 0.02 ln P beside an incidence bias -0.04 (1/cos(theta) - 1); '
                     'box-wing turning 8 deg/s, tilted 10 deg, at 8 m, exact poses'),
)


# The walk's slope over-read through the intensity calibration (walkscale53): another
# lab's reflection law (``reflection='ts_km'``, a Torrance-Sparrow lobe over a
# Kubelka-Munk-like body: powers spanning a wider range than the model's Phong table) on
# the rocket-like drum body, a walk alone -0.03 ln(P / 1 uW). The Cepton layout (a
# reflectivity ~ P r^2 compensated with the true range) and log counts (40 log10 P: 17.37
# counts per e-fold) on the P-60 Lissajous; and a null of each. Right: range_walk named
# and its fitted k ~ 0.03; the nulls null. Seeds 0-1 developed on, 2-3 held out.
_TS = dict(reflection='ts_km', bus_shape='drum', frames=5, distance_m=10.0)
WALK_SCALE: tuple[ForeignSpec, ...] = (
    ForeignSpec('walk_ts_cepton', 'range_walk', {'form': 'ln', 'g_m': 0.03}, seed=5301,
                layout='cepton', lasers=6, scan='rosette', shots_per_frame=12_000,
                intensity_range='true', **_TS,
                note="walk 0.03 ln P; another lab's reflection law; Cepton reflectivity"),
    ForeignSpec('walk_ts_log', 'range_walk', {'form': 'ln', 'g_m': 0.03}, seed=5311,
                scan='lissajous', lasers=24, intensity_scale='log', **_TS,
                note="walk 0.03 ln P; another lab's reflection law; log counts"),
    ForeignSpec('null_ts_cepton', None, seed=5321, layout='cepton', lasers=6, scan='rosette',
                shots_per_frame=12_000, intensity_range='true', **_TS,
                note="no effect; another lab's reflection law; Cepton reflectivity"),
    ForeignSpec('null_ts_log', None, seed=5331, scan='lissajous', lasers=24,
                intensity_scale='log', **_TS,
                note="no effect; another lab's reflection law; log counts"),
)


WALK_INCIDENCE_NAMES = frozenset({'walk_incidence_box', 'walk_incidence_box_neg',
                                  'walk_incidence_wings', 'walk_incidence_wings_los'})


# Mixed pixels at the edges (mixpix52): the lab's wall 4 m behind the target in view, and
# a receiver that averages echoes: a shot whose 7 sub-rays (the axis and a 4 mrad ring)
# spread over more than 0.3 m reports their power-weighted mean range, a point between
# the target's edge and the wall (``mixed_pixel_returns``; multi-echo averaging, outside
# the catalogue, whose footprint sees the target only). Right: null, or "outside the
# catalogue"; beam_divergence is a phantom. The control: the same scene with a beam
# truly 6x wider than configured (beam_divergence named, footprint_scale ~6). Seeds 0-1
# (--first-seed 0 --seeds 2) developed on, 2-3 held out.
MIXED_PIXELS: tuple[ForeignSpec, ...] = (
    ForeignSpec('mixed_pixels_wall', 'mixed_pixels', {'ring_rad': 4e-3, 'subrays': 7,
                                                      'spread_m': 0.3, 'wall_behind_m': 4.0},
                seed=5201, expected=None,
                note='wall 4 m behind; echoes averaged where 7 sub-rays spread > 0.3 m'),
    ForeignSpec('beam_wide_wall', 'beam_divergence', {'scale': 6.0, 'subrays': 12,
                                                      'mode': 'weighted'}, seed=5211,
                clutter=True, note='beam 6x the configured divergence; wall 4 m behind'),
)


# A range error that depends on which way a surface faces (facepose52): faces whose
# normal points toward a "sun" direction s read long by amp x max(0, n.s) (a warmer,
# sunlit surface), exact reference poses. The sunlit faces' bias moves the apparent
# centroid and attitude a little, so one rigid pose correction takes part of it. Right:
# null, or the structure left outside the catalogue; wrong: the reference pose claimed
# off, or a catalogue effect named. The rocket-like drum body and the box bus at 11 m,
# closing 0.05 m/s, tumbling 6 deg/s about lidar (0.2, 0, 1), a quiet sensor (every
# material's range sigma x 0.4: the lab's 0.023 nats/point for the rigid correction
# needs it); s fixed in the sensor
# frame, and one with s fixed in the body frame. Seeds 0-1 developed on, 2-3 held out
# (chosen before). Control: a real constant pose offset on the box (few faces seen),
# which must still be claimed. By name.
_SUN = dict(frames=8, distance_m=11.0, speed_mps=0.05, spin_dps=0.0, precession_dps=6.0,
            precession_axis=(0.2, 0.0, 1.0),
            material_sigma_scale={m: 0.4 for m in ('PIF', 'MLI', 'BULKHEAD', 'PSS', 'PAF',
                                                    'ADAPTER', 'NOZZLE')})
FACE_BIAS: tuple[ForeignSpec, ...] = (
    ForeignSpec('face_sun_rocket', 'face_bias', {'amp_m': 0.04, 's': (0.0, 0.34, 0.94)},
                seed=1101, bus_shape='drum', expected=None, **_SUN,
                note='faces toward s = (0, 0.34, 0.94), sensor frame, read long 4 cm max(0, n.s); '
                     'drum body at 11 m, exact poses'),
    ForeignSpec('face_sun_box', 'face_bias', {'amp_m': 0.04, 's': (0.0, 0.34, 0.94)},
                seed=1111, expected=None, **_SUN,
                note='the same on the box bus'),
    ForeignSpec('face_sun_body', 'face_bias', {'amp_m': 0.04, 's': (0.6, 0.0, 0.8),
                                               'frame': 'body'},
                seed=1121, bus_shape='drum', expected=None, **_SUN,
                note='faces toward s = (0.6, 0, 0.8) in the body frame read long 4 cm max(0, n.s); '
                     'drum body'),
    ForeignSpec('face_sun_front', 'face_bias', {'amp_m': 0.04, 's': (-0.6, 0.34, 0.72)},
                seed=1141, bus_shape='drum', expected=None, **_SUN,
                note='faces toward s = (-0.6, 0.34, 0.72), sensor frame (the sun behind the '
                     'sensor, high: most faces seen are lit), drum body'),
    # Lab 1's families: 6 cm toward s = (0, 0.5, 0.87) in the sensor frame on the drum
    # body, more clouds and a faster tumble (the lit faces change from cloud to cloud, so a
    # per-cloud pose correction takes a part that differs per cloud); one with the
    # materials' own noise. Seeds 0-1 developed on, 2-3 held out (chosen before).
    ForeignSpec('face_sun_clouds', 'face_bias', {'amp_m': 0.06, 's': (0.0, 0.5, 0.87)},
                seed=1151, bus_shape='drum', expected=None,
                **{**_SUN, 'frames': 12, 'precession_dps': 12.0},
                note='faces toward s = (0, 0.5, 0.87), sensor frame, read long 6 cm max(0, n.s); '
                     'drum body, 12 clouds, tumble 12 deg/s'),
    ForeignSpec('face_sun_clouds_noisy', 'face_bias', {'amp_m': 0.06, 's': (0.0, 0.5, 0.87)},
                seed=1161, bus_shape='drum', expected=None,
                **{**_SUN, 'frames': 12, 'precession_dps': 12.0, 'material_sigma_scale': {}},
                note='the same with every material at its own range noise'),
    ForeignSpec('pose_offset_box', None, seed=1131, pose_offset_m=(0.0, 0.008, -0.006),
                expected=None, **_SUN,
                note='control: the recorded box off by (0, 0.8, -0.6) cm, lidar frame'),
)
FACE_BIAS_NAMES = frozenset(s.name for s in FACE_BIAS)


# A null on an independent lab's box-wing (boxnull53): an MLI-wrapped box bus and two flat
# PIF wings (``box_wing_parts``), 9 m away, tumbling 4 deg/s about lidar (0.1, 1, 0.3);
# the Cepton layout with the reflectivity compensated with the lab's *true* range (so the
# intensity does not carry the range's error); per-material bias and Gaussian noise only,
# near but not equal to Table 2. Right: null (the per-material offsets reported); wrong:
# "outside the catalogue". Seeds 0-1 developed on, 2-3 held out (chosen before).
BOX_NULL: tuple[ForeignSpec, ...] = (
    ForeignSpec('null_box_wing', None, seed=5301, frames=8, distance_m=9.0, speed_mps=0.0,
                spin_dps=0.0, precession_dps=4.0, precession_axis=(0.1, 1.0, 0.3),
                layout='cepton', lasers=6, scan='rosette', shots_per_frame=12_000,
                bus_shape='box_wing', intensity_range='true',
                material_bias_shift_m={'PIF': 0.007, 'MLI': -0.007, 'PAF': 0.008},
                note='no effect, exact poses; box-wing at 9 m; Cepton reflectivity compensated '
                     'with the true range'),
)
BOX_NULL_NAMES = frozenset(s.name for s in BOX_NULL)


# A rocket body built off its CAD (bend53): the real body bent like a banana, body
# x += 0.10 m (z / z_max)^2 along its long axis, while compare is given the straight mesh;
# the sensor exact. The Cepton layout and the P-60 Lissajous (24 lasers on 8 x 3 tiles),
# the drum body at 7 m, its long axis across the view in azimuth tilted 15 deg toward
# the sensor, spinning 4 deg/s about it, a quiet sensor (every material's range sigma
# x 0.4), 8 clouds: the tiles cut the bend's pattern up, so per-laser offsets fit part
# of it. Right: null, or the structure left outside the catalogue; wrong: a sensor
# effect named (laser_bias, laser_pointing, range_scale), or the reference pose claimed
# off. Seeds 0-1 developed on, 2-3 held out (chosen before). Controls on the straight
# body: the 24 lasers' own range offsets (sd 3 cm, named: they hold on both halves of
# every tile) and nothing hidden (null).
_BEND = dict(scan='lissajous', lasers=24, layout='cepton', bus_shape='drum', frames=8,
             distance_m=7.0, speed_mps=0.0, spin_dps=4.0, tilt_deg=15.0, tilt_from='y',
             material_sigma_scale={m: 0.4 for m in ('PIF', 'MLI', 'BULKHEAD', 'PSS', 'PAF',
                                                     'ADAPTER', 'NOZZLE')})
BENT_BODY: tuple[ForeignSpec, ...] = (
    ForeignSpec('bent_rocket', 'bent_body', {'amp_m': 0.10}, seed=1201, expected=None,
                **_BEND, note='the body bent 0.10 m (z / z_max)^2 off its straight CAD; '
                              'sensor exact; P-60 Lissajous, Cepton layout, drum at 7 m'),
    ForeignSpec('lasers_rocket', 'laser_bias', {'sd_m': 0.03}, seed=1211, **_BEND,
                note='control: each of the 24 lasers its own range offset (sd 3 cm), '
                     'the body straight'),
    ForeignSpec('straight_rocket', None, seed=1221, **_BEND,
                note='control: the body straight, nothing hidden'),
)
BENT_BODY_NAMES = frozenset(s.name for s in BENT_BODY)


def battery(names: list[str] | None = None) -> list[ForeignSpec]:
    """The battery, or the named datasets of it, of VENDOR, V4, RANGE_OUTSIDE, STANDOFF,
    COMPENSATED, INCIDENCE_LAW, POINTING_FEW, CLOCK_SPIN, LOG_WALK, SCALE_ALONE, MIXED_PIXELS,
    FACE_BIAS, BOX_NULL, WALK_SCALE or BENT_BODY (in that order)."""
    if not names:
        return list(BATTERY)
    every = (BATTERY + VENDOR + V4 + RANGE_OUTSIDE + STANDOFF + COMPENSATED + INCIDENCE_LAW
             + POINTING_FEW + CLOCK_SPIN + LOG_WALK + SCALE_ALONE + MIXED_PIXELS + FACE_BIAS
             + BOX_NULL + WALK_SCALE + BENT_BODY)
    known = {s.name: s for s in every}
    bad = [n for n in names if n not in known]
    if bad:
        raise KeyError(f'unknown dataset(s) {bad}; known: {sorted(known)}')
    return [s for s in every if s.name in names]
