"""Closed-loop campaign runs: each run is the whole rendezvous loop (``loop.step``), in one
process on a Dask worker, with the campaign's dispersions applied to the loop and its lidar.

A campaign with a ``loop:`` section (docs/campaign.md, "Closed-loop campaigns") runs
``loop.step.run_steps`` instead of frame statistics. What is dispersed, and where it goes:

- ``tumble_rate_dps``, ``tumble_axis`` (body frame; a cone's default axis is the loop
  config's ``target.tumble_axis_body``), ``initial_attitude`` (the target's body -> LVLH
  attitude; small_rotation perturbs the loop config's): the target's initial state;
- ``initial_distance_m``: the chaser's start, the loop config's ``initial.position_m``
  scaled to that distance; the loop config's own ``position_sigma_m`` /
  ``velocity_sigma_mps`` then disperse it with the run's seed (the drawn start is in the
  manifest: ``initial_rho_m_*``, ``initial_rho_dot_mps_*``);
- ``mounting_misalignment``: the lidar is really mounted rotated by M from the mount the
  GNC knows (``LoopContext.R_BL_true``);
- ``materials``, ``effects``: the LiDAR's error parameters, in the base scenario (the
  campaign's ``scenario``), which is the loop's lidar (the loop config's own
  ``scenario`` is not used here).

Per run the worker writes ``runs/run_NNNNN/loop.json`` (the metrics of loop.json,
``LOOP_METRICS`` and the rest of ``loop.metrics.loop_metrics``) and returns the manifest
row (status, dispersed parameters, compute time), with its metrics and series besides
for the client (``series.py`` keeps the worst runs'); ``summary.py`` then writes the
tables, the criteria's verdicts and the figures.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import socket
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar_sim_ros.campaign.sample import key_rng, run_seed, sample_run
from lidar_sim_ros.campaign.spec import Campaign, loop_config_path
from lidar_sim_ros.campaign.worker import prepare_scenario, worker_target
from lidar_sim_ros.core.scenario import Scenario
from lidar_sim_ros.core.pose import quat_multiply

LOOP_METRICS = ('hold_error_m', 'delta_v_mps', 'min_range_m', 'est_trans_rms_m', 'est_axis_rms_deg',
                'acquired_at_s', 'losses')
RESULT = 'loop.json'


@dataclass(frozen=True)
class LoopRunCase:
    """One closed-loop run: its dispersed loop config, lidar scenario and mount error."""

    run_id: int
    seed: int
    params: dict[str, float]
    loop: object                    # loop.config.LoopConfig
    scenario: Scenario
    misalignment_xyzw: tuple[float, float, float, float] | None
    cloud: str
    duration_s: float


# ------------------------------------------------------------------ loading
_CONFIGS: dict[tuple[str, str], object] = {}


def base_loop_config(campaign: Campaign):
    """The campaign's loop config (parsed once per process and file version)."""
    from lidar_sim_ros.loop.config import load_loop_config
    path = loop_config_path(campaign.source, campaign.spec)
    key = (str(path), campaign.spec.loop.config_sha256)
    if key not in _CONFIGS:
        if hashlib.sha256(path.read_bytes()).hexdigest() != campaign.spec.loop.config_sha256:
            raise RuntimeError(f'{path} changed since the campaign was loaded')
        _CONFIGS[key] = load_loop_config(path)[0]
    return _CONFIGS[key]


# ----------------------------------------------------------------- sampling
def sample_loop_case(campaign: Campaign, run_id: int) -> LoopRunCase:
    """Run ``run_id``'s dispersed loop: a pure function of (campaign seed, run id), the same
    keyed generators as ``sample.sample_run`` (which disperses the lidar scenario)."""
    from lidar_sim_ros.loop.config import LoopConfig
    from lidar_sim_ros.loop.dynamics import initial_relative_state
    spec, disp = campaign.spec, campaign.spec.dispersions
    case = sample_run(campaign, run_id)  # the lidar's errors and the mount error
    base = base_loop_config(campaign)
    params = {k: v for k, v in case.params.items()
              if k.startswith(('material.', 'effect.', 'misalignment_'))}

    def rng(key: str) -> np.random.Generator:
        return key_rng(spec.seed, run_id, key)

    data = base.model_dump()
    data['seed'] = case.seed
    target, initial = data['target'], data['initial']
    if disp.tumble_rate_dps is not None:
        target['tumble_rate_dps'] = params['tumble_rate_dps'] = disp.tumble_rate_dps.sample(rng('tumble_rate_dps'))
    if disp.tumble_axis is not None:
        axis = disp.tumble_axis.sample(rng('tumble_axis'), np.asarray(base.target.tumble_axis_body, float))
        target['tumble_axis_body'] = tuple(float(a) for a in axis)
        params.update({f'tumble_axis_{a}': float(v) for a, v in zip('xyz', axis)})
    if disp.initial_attitude is not None:
        drawn = disp.initial_attitude.sample(rng('initial_attitude'))
        quat = drawn if disp.initial_attitude.dist == 'uniform_attitude' else \
            quat_multiply(drawn, np.asarray(base.target.quat_xyzw_lvlh, float))
        target['quat_xyzw_lvlh'] = tuple(float(q) for q in quat)
        params.update({f'initial_quat_{a}': float(v) for a, v in zip('xyzw', quat)})
    if disp.initial_distance_m is not None:
        distance = disp.initial_distance_m.sample(rng('initial_distance_m'))
        nominal = np.asarray(base.initial.position_m, float)
        initial['position_m'] = tuple(float(x) for x in nominal * (distance / np.linalg.norm(nominal)))
        params['initial_distance_m'] = distance
    config = LoopConfig.model_validate(data)
    rho, rho_dot = initial_relative_state(config)
    params.update({f'initial_rho_m_{a}': float(v) for a, v in zip('xyz', rho)})
    params.update({f'initial_rho_dot_mps_{a}': float(v) for a, v in zip('xyz', rho_dot)})
    return LoopRunCase(run_id, case.seed, params, config, case.scenario, case.misalignment_xyzw,
                       spec.loop.cloud, spec.duration_s)


# ---------------------------------------------------------------- one run
_MODELS: dict[tuple, object] = {}
_LOCK = threading.Lock()


def tracker_model(scenario: Scenario):
    """The tracker's model of the scenario's mesh, built once per worker process."""
    from lidar_sim_ros.gnc.tracker import TrackerConfig, build_model
    target, _ = worker_target(scenario)
    key = (str(Path(scenario.mesh_path).resolve()), Path(scenario.mesh_path).stat().st_mtime_ns)
    with _LOCK:
        if key not in _MODELS:
            _MODELS[key] = build_model(target.vertices_m, target.faces, TrackerConfig())
        return _MODELS[key]


def prepare_loop_worker(campaign: Campaign) -> None:
    """What every run would pay once: Basilisk's import, the mesh, kernels, tracker model."""
    import Basilisk.simulation.spacecraft  # noqa: F401  (~1 s the first time)
    case = sample_loop_case(campaign, 0)
    prepare_scenario(case.scenario)
    tracker_model(case.scenario)


def simulate_loop_case(case: LoopRunCase):
    """Run the case's loop: its ``loop.step.LoopResult`` (metrics: ``loop.metrics.loop_metrics``
    and step's extras; series: arrays, one row per control period)."""
    from lidar_sim_ros.loop.step import build_context, run_steps
    target = model = None
    if case.cloud is not None:
        target, _ = worker_target(case.scenario)
        model = tracker_model(case.scenario)
    # One loop per worker thread: the tracker's ICP on one thread too.
    loop = case.loop.model_copy(update={'tracker_threads': 1})
    ctx = build_context(loop, case.scenario, case.cloud, target=target, tracker_model=model,
                        misalignment_xyzw=case.misalignment_xyzw)
    return run_steps(ctx, case.duration_s)


def result_path(out_dir: str | Path, run_id: int) -> Path:
    return Path(out_dir) / 'runs' / f'run_{run_id:05d}' / RESULT


def run_one_loop(campaign: Campaign, run_id: int, out_dir: str | Path | None = None) -> dict:
    """The engine's task for a closed-loop campaign (``run.run_one`` hands it on): sample and
    run one case, write its loop.json, return its manifest row, with the run's ``metrics``
    and ``series`` besides for the client's ``series.SeriesKeeper`` (not manifest columns).
    Never raises."""
    start = time.perf_counter(), time.process_time()
    row: dict = {'run_id': run_id, 'seed': run_seed(campaign.spec.seed, run_id)}
    try:
        case = sample_loop_case(campaign, run_id)
        row.update({f'param.{k}': v for k, v in case.params.items()})
        result = simulate_loop_case(case)
        metrics = result.metrics
        if out_dir is not None:
            path = result_path(out_dir, run_id)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix('.json.tmp')
            tmp.write_text(json.dumps({'run_id': run_id, 'seed': case.seed, 'params': case.params,
                                       'metrics': _json_safe(metrics)}, indent=1) + '\n')
            os.replace(tmp, path)
    except Exception as exc:  # a run's failure must not stop the campaign
        last = traceback.extract_tb(exc.__traceback__)[-1]
        row.update(status='failed', error=f'{type(exc).__name__}: {exc} '
                                          f'({Path(last.filename).name}:{last.lineno})')
    else:
        row.update(status='ok', error='', metrics=metrics, series=result.series)
    row['compute_s'] = time.perf_counter() - start[0]
    row['cpu_s'] = time.process_time() - start[1]
    row['worker'] = f'{socket.gethostname()}:{os.getpid()}'
    return row


def _json_safe(metrics: dict) -> dict:
    """NaN as null: loop.json stays strict JSON."""
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()}


def read_result(out_dir: str | Path, run_id: int) -> dict | None:
    path = result_path(out_dir, run_id)
    return json.loads(path.read_text()) if path.is_file() else None
