"""Run seeds and dispersed parameters: pure functions of (campaign seed, run index).

Seeds come from numpy's ``SeedSequence`` tree, the construction numpy recommends for
independent parallel streams. Run ``i`` owns the node ``spawn_key=(i,)`` of the
campaign seed (what ``SeedSequence(seed).spawn(n)[i]`` gives), and below it:

- ``(i, 1)``: the run seed, 63 bits, the dispersed scenario's ``seed`` (per-frame noise);
- ``(i, 0, crc32(key))``: one generator per dispersed quantity, so adding a
  dispersion to a spec leaves the values the other quantities draw unchanged.

Nothing depends on which worker runs a case or in which order: ``--run RUN_ID``
reproduces run ``RUN_ID`` exactly.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.campaign.spec import Campaign, Dispersions
from lidar_sim_ros.core.config import (MaterialConfig, MaterialsConfig, ScenarioConfig,
                                       with_sensor_range_error)
from lidar_sim_ros.core.scenario import Scenario
from lidar_sim_ros.core.pose import quat_multiply


@dataclass(frozen=True)
class RunCase:
    """Everything a worker needs for one run; small and picklable.

    ``params``: the dispersed values, flat (manifest columns ``param.<name>``).
    ``misalignment_xyzw``: sensor mounting rotation M (None = perfectly mounted).
    """

    run_id: int
    seed: int
    frames: int
    params: dict[str, float]
    scenario: Scenario
    misalignment_xyzw: tuple[float, float, float, float] | None
    save: str
    storage: str
    coverage_frames: int


def run_seed(campaign_seed: int, run_index: int) -> int:
    """The run's 63-bit seed (node ``(run_index, 1)`` of the campaign's SeedSequence)."""
    ss = np.random.SeedSequence(campaign_seed, spawn_key=(int(run_index), 1))
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(1))


def key_rng(campaign_seed: int, run_index: int, key: str) -> np.random.Generator:
    """The generator of one dispersed quantity of one run."""
    ss = np.random.SeedSequence(campaign_seed,
                                spawn_key=(int(run_index), 0, zlib.crc32(key.encode())))
    return np.random.default_rng(ss)


def sample_run(campaign: Campaign, run_index: int) -> RunCase:
    """Draw run ``run_index``'s dispersed parameters and build its scenario."""
    spec, base = campaign.spec, campaign.scenario
    if not 0 <= run_index < spec.runs:
        raise ValueError(f'run {run_index} is not in this campaign (runs 0..{spec.runs - 1})')
    disp: Dispersions = spec.dispersions
    seed = run_seed(spec.seed, run_index)

    def rng(key: str) -> np.random.Generator:
        return key_rng(spec.seed, run_index, key)

    cfg = base.config
    params: dict[str, float] = {}
    position = np.asarray(cfg.initial_pose.position_m, dtype=float)
    quat = np.asarray(cfg.initial_pose.quat_xyzw, dtype=float)
    motion = cfg.motion.model_dump()

    if disp.initial_distance_m is not None:
        distance = disp.initial_distance_m.sample(rng('initial_distance_m'))
        position = position * (distance / np.linalg.norm(position))
        params['initial_distance_m'] = distance
    if disp.initial_attitude is not None:
        drawn = disp.initial_attitude.sample(rng('initial_attitude'))
        # small_rotation perturbs the base attitude in the lidar frame; uniform replaces it.
        quat = drawn if disp.initial_attitude.dist == 'uniform_attitude' else quat_multiply(drawn, quat)
        params.update(_vector('initial_quat', quat, 'xyzw'))
    if disp.tumble_axis is not None:
        axis = disp.tumble_axis.sample(rng('tumble_axis'), np.asarray(cfg.motion.tumble_axis, float))
        motion['tumble_axis'] = tuple(float(a) for a in axis)
        params.update(_vector('tumble_axis', axis, 'xyz'))
    for key in ('tumble_rate_dps', 'approach_speed_mps'):
        law = getattr(disp, key)
        if law is not None:
            motion[key] = params[key] = law.sample(rng(key))

    misalignment = None
    if disp.mounting_misalignment is not None:
        m = disp.mounting_misalignment.sample(rng('mounting_misalignment'))
        misalignment = tuple(float(v) for v in m)
        params.update(_vector('misalignment_quat', m, 'xyzw'))
        params['misalignment_deg'] = float(np.degrees(2.0 * np.arccos(min(1.0, abs(m[3])))))

    sensor, mesh_path, mesh_materials = base.sensor, base.mesh_path, cfg.mesh_materials
    table = base.materials
    if campaign.sensors is not None or campaign.targets is not None:
        # A drawn sensor brings its own range error, a drawn target its mesh and materials.
        table = campaign.base_materials
        if campaign.sensors is not None:
            i = int(rng('sensor').integers(len(campaign.sensors)))
            sensor, params['sensor_choice'] = campaign.sensors[i], float(i)
        if campaign.targets is not None:
            i = int(rng('target').integers(len(campaign.targets)))
            target = campaign.targets[i]
            mesh_path, table, mesh_materials = target.mesh_path, target.materials, target.mesh_materials
            params['target_choice'] = float(i)
        table = with_sensor_range_error(table, sensor)      # dispersed errors below still win
    materials = []
    for mat in table.materials:
        values = mat.model_dump()
        laws = disp.materials.get(mat.name)
        for attr in ('bias_m', 'sigma_m'):
            law = getattr(laws, attr) if laws is not None else None
            if law is not None:
                values[attr] = params[f'material.{mat.name}.{attr}'] = law.sample(
                    rng(f'materials.{mat.name}.{attr}'))
        materials.append(MaterialConfig.model_validate(values))

    effects = [e.model_dump() for e in cfg.effects]
    for name, laws in disp.effects.items():
        entry = next((e for e in effects if e['name'] == name), None)
        if entry is None:
            entry = {'name': name, 'params': {}}
            effects.append(entry)
        for param, law in laws.items():
            entry['params'][param] = params[f'effect.{name}.{param}'] = law.sample(
                rng(f'effects.{name}.{param}'))

    config = ScenarioConfig.model_validate({
        **cfg.model_dump(), 'seed': seed, 'motion': motion,
        'initial_pose': {'position_m': tuple(position), 'quat_xyzw': tuple(quat)},
        'effects': effects, 'mesh_materials': mesh_materials})
    scenario = Scenario(config, sensor, MaterialsConfig(materials=materials), mesh_path, base.source)
    return RunCase(run_index, seed, campaign.frames_for(sensor), params, scenario, misalignment,
                   spec.save, spec.storage, spec.coverage_frames)


def _vector(prefix: str, values: np.ndarray, axes: str) -> dict[str, float]:
    return {f'{prefix}_{a}': float(v) for a, v in zip(axes, values)}
