"""Measured datasets for the compare tests: the simulator plus a hidden effect, as bags.

Deliberately NOT the default scenario: another seed, another pose and tumble, a
coarser rocket mesh (other tessellation), fewer shots per laser (small, fast frames)
and effect magnitudes other than the catalogue defaults. Bags are written with
``io.bag.BagWriter`` so the whole read path of ``lidar-sim compare`` is exercised.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.effects import Effect
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.io.bag import CLOUD_TOPIC, MATERIAL_NAMES_TOPIC, POSE_TOPIC, BagWriter
from lidar_sim_ros.io.pointcloud import make_points

REPO = Path(__file__).resolve().parents[1]
EPOCH_NS = 1_650_000_000 * 1_000_000_000
POSES_PER_FRAME = 20


@dataclass(frozen=True)
class Dataset:
    bag: Path
    mesh: Path
    scenario: Path          # what the comparison is given (no hidden effect in it)


def coarse_mesh(dirname: Path, segments: int = 48) -> Path:
    """The rocket body with another tessellation, written by the repo's mesh tool."""
    obj = dirname / 'rocket_coarse.obj'
    if obj.exists():
        return obj
    spec = importlib.util.spec_from_file_location('make_rocket_mesh',
                                                  REPO / 'tools' / 'make_rocket_mesh.py')
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    mesh, names = tool.build_rocket_body(segments)
    tool.write_obj_with_groups(dirname / 'rocket_coarse', mesh, names)
    return obj


def write_scenario(dirname: Path, mesh: Path, seed: int = 7, shots_per_laser: int = 220,
                   position_m=(11.0, 0.6, -0.4), quat_xyzw=(-0.62, -0.2, 0.12, 0.75),
                   tumble_axis=(0.1, 0.3, 1.0), tumble_rate_dps: float = 8.0,
                   approach_speed_mps: float = 0.08, materials: Path | None = None) -> Path:
    """A small scenario: P-60 optics with fewer shots per laser, another pose and tumble."""
    dirname.mkdir(parents=True, exist_ok=True)
    sensor = yaml.safe_load((REPO / 'config' / 'cepton_vista_p60.yaml').read_text())
    sensor['scan']['shots_per_laser'] = shots_per_laser
    sensor_path = dirname / 'sensor.yaml'
    sensor_path.write_text(yaml.safe_dump(sensor))
    q = np.asarray(quat_xyzw, float)
    scenario = {
        'seed': seed, 'mesh': str(mesh), 'sensor': str(sensor_path),
        'materials': str(materials or REPO / 'config' / 'materials.yaml'),
        'initial_pose': {'position_m': list(map(float, position_m)),
                         'quat_xyzw': (q / np.linalg.norm(q)).tolist()},
        'motion': {'approach_speed_mps': approach_speed_mps, 'tumble_axis': list(tumble_axis),
                   'tumble_rate_dps': tumble_rate_dps},
        'effects': [],
    }
    path = dirname / 'scenario.yaml'
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return path


def write_bag(bag: Path, scenario_path: Path, effects: list[Effect], frames: int = 3,
              seed: int | None = None, point_time: bool = True, storage: str = 'mcap',
              materials_path: Path | None = None, intensity_scale: float = 1.0) -> Path:
    """Simulate ``frames`` frames with ``effects`` hidden in them and write a bag.

    ``materials_path`` simulates with other materials than the scenario names (a
    per-material bias/sigma mismatch). Without ``point_time`` the clouds carry no
    ``t`` field, like many drivers; ``intensity_scale`` puts intensities in other units.
    """
    scenario = load_scenario(scenario_path)
    if materials_path is not None:
        from lidar_sim_ros.core.config import load_materials
        scenario.materials = load_materials(materials_path)
    sim = Simulator.from_scenario(scenario, effects=list(effects))
    if seed is not None:
        sim.seed = seed
    traj = ScenarioTrajectory.from_config(scenario.config)
    period = sim.frame_period_s
    period_ns = int(round(period * 1e9))
    with BagWriter(bag, storage=storage) as writer:
        writer.write_material_names(MATERIAL_NAMES_TOPIC, EPOCH_NS, scenario.materials.names)
        n_pose = frames * POSES_PER_FRAME + 1
        t_pose = np.arange(n_pose) * (period / POSES_PER_FRAME)
        poses = traj.at(t_pose)
        for k, (pos, q) in enumerate(zip(poses.position_m, poses.rotation.as_quat())):
            writer.write_pose(POSE_TOPIC, EPOCH_NS + k * period_ns // POSES_PER_FRAME,
                              'lidar', pos, q)
        for i in range(frames):
            frame = sim.simulate_frame(i * period, traj, i)
            points = make_points(frame.xyz_m, frame.intensity * intensity_scale, frame.t_s,
                                 frame.ring, frame.material)
            if not point_time:
                points = _drop_field(points, 't')
            _write_points(writer, points, EPOCH_NS + i * period_ns)
    return bag


def _drop_field(points: np.ndarray, name: str) -> np.ndarray:
    keep = [n for n in points.dtype.names if n != name]
    out = np.empty(len(points), dtype=[(n, points.dtype[n]) for n in keep])
    for n in keep:
        out[n] = points[n]
    return out


def _write_points(writer: BagWriter, points: np.ndarray, stamp_ns: int) -> None:
    """Any structured array as PointCloud2 (the shared layout or a reduced one)."""
    from lidar_sim_ros.io.pointcloud import POINT_DTYPE
    if points.dtype == POINT_DTYPE:
        writer.write_cloud(CLOUD_TOPIC, points, stamp_ns, 'lidar')
        return
    write_custom_cloud(writer, CLOUD_TOPIC, points, stamp_ns)


def write_custom_cloud(writer: BagWriter, topic: str, points: np.ndarray, stamp_ns: int) -> None:
    """PointCloud2 with the fields of a packed structured array (f4/u1/u2 fields)."""
    codes = {'u1': 2, 'u2': 4, 'f4': 7, 'f8': 8, 'i4': 5, 'u4': 6}
    types = writer.typestore.types
    packed = np.ascontiguousarray(points)
    fields = [types['sensor_msgs/msg/PointField'](
        name=n, offset=packed.dtype.fields[n][1], datatype=codes[packed.dtype[n].str[1:]],
        count=1) for n in packed.dtype.names]
    stamp = types['builtin_interfaces/msg/Time'](sec=stamp_ns // 1_000_000_000,
                                                 nanosec=stamp_ns % 1_000_000_000)
    msg = types['sensor_msgs/msg/PointCloud2'](
        header=types['std_msgs/msg/Header'](stamp=stamp, frame_id='lidar'),
        height=1, width=len(packed), fields=fields, is_bigendian=False,
        point_step=packed.dtype.itemsize, row_step=packed.dtype.itemsize * len(packed),
        data=packed.view(np.uint8).reshape(-1), is_dense=True)
    cdr = writer.typestore.serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2')
    writer.write_raw(topic, 'sensor_msgs/msg/PointCloud2', stamp_ns, cdr)


def make_dataset(root: Path, name: str, effects: list[Effect], **kw) -> Dataset:
    """Scenario + coarse mesh + bag under ``root/name``."""
    mesh = coarse_mesh(root)
    scen_kw = {k: kw.pop(k) for k in list(kw) if k in (
        'shots_per_laser', 'position_m', 'quat_xyzw', 'tumble_axis', 'tumble_rate_dps',
        'approach_speed_mps')}
    scenario = write_scenario(root / name, mesh, **scen_kw)
    bag = write_bag(root / name / 'bag', scenario, effects, **kw)
    return Dataset(bag, mesh, scenario)
