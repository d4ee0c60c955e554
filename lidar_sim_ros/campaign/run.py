"""One campaign run: dispersed scenario -> frames -> statistics (and optionally a rosbag2),
and the engine's task, a batch of runs of either kind (a closed-loop campaign's run is
``loop_case.run_one_loop``).

Runs execute in engine workers, on the per-process cache of ``worker.py`` (mesh, BVH,
kernels built once per process).
"""
from __future__ import annotations

import os
import pickle
import shutil
import socket
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar_sim_ros.campaign.coverage import covered_fraction, visible_faces
from lidar_sim_ros.campaign.loop_case import prepare_loop_worker, run_one_loop, sample_loop_case
from lidar_sim_ros.campaign.sample import RunCase, run_seed, sample_run
from lidar_sim_ros.campaign.spec import Campaign
from lidar_sim_ros.campaign.statistics import RunStatistics
from lidar_sim_ros.campaign.worker import prepare_scenario, worker_target
from lidar_sim_ros.core.pipeline import NO_MATERIAL, Frame, Simulator
from lidar_sim_ros.core.pose import (PoseSource, Poses, ScenarioTrajectory, quat_multiply,
                                     quat_to_matrix)


@dataclass(frozen=True)
class MountedPose:
    """A pose source seen through a misaligned sensor mount M (unit quaternion xyzw):
    p_lidar = M (R p_body + t), i.e. rotation M R and position M t."""

    source: PoseSource
    mount_xyzw: tuple[float, float, float, float]

    def at(self, t_s: np.ndarray) -> Poses:
        poses = self.source.at(t_s)
        mount = np.asarray(self.mount_xyzw, dtype=float)
        position = poses.position_m.reshape(-1, 3) @ quat_to_matrix(mount[None])[0].T
        return Poses.from_quat(quat_multiply(mount, poses.quat_xyzw), position)


_PREPARED: set[str] = set()  # campaigns this process has run prepare_worker for


def prepare_worker(campaign: Campaign) -> dict[str, str | bool | None]:
    """Everything a run of ``campaign`` needs that is paid once per worker process: the
    mesh and BVH, the kernels of the dispersed effects, and the modules the samplers
    import on first use (scipy.stats alone takes ~0.6 s): run 0 is sampled for that.

    Returns ``worker_facts()``. The engine's first task on each worker calls it
    (``run_batch``); a benchmark may call it on every worker up front.
    """
    try:
        if campaign.spec.loop is not None:
            prepare_loop_worker(campaign)
        else:
            prepare_scenario(sample_run(campaign, 0).scenario)
    except Exception:  # run 0's own failure is recorded when it runs, not here
        prepare_scenario(campaign.scenario)
    _PREPARED.add(_campaign_key(campaign))
    return worker_facts()


def _campaign_key(campaign: Campaign) -> str:
    return f'{campaign.source}:{campaign.spec.model_dump_json()}'


def worker_facts() -> dict[str, str | bool | None]:
    """What the engine checks of a worker it joins: ``MALLOC_TRIM_THRESHOLD_`` (None:
    unset, glibc's adaptive default) and whether Dask's stack profiler runs."""
    import dask  # a worker has it; the core and `--run` in-process do not need it
    return {'MALLOC_TRIM_THRESHOLD_': os.environ.get('MALLOC_TRIM_THRESHOLD_'),
            'profile': bool(dask.config.get('distributed.worker.profile.enabled', True))}


# ------------------------------------------------------------------ one run
def run_dir(out_dir: str | Path, run_id: int) -> Path:
    return Path(out_dir) / 'runs' / f'run_{run_id:05d}'


def simulate_case(case: RunCase, out_dir: str | Path | None = None) -> dict[str, float | int]:
    """Simulate one run and return its statistics; raises on failure."""
    scenario = case.scenario
    target, faces = worker_target(scenario)
    sim = Simulator.from_scenario(scenario, target=target)
    pose: PoseSource = ScenarioTrajectory.from_config(scenario.config)
    if case.misalignment_xyzw is not None:
        pose = MountedPose(pose, case.misalignment_xyzw)
    stats = RunStatistics(scenario.materials.names)
    coverage_at = set(np.unique(np.linspace(0, case.frames - 1, case.coverage_frames)
                                .round().astype(int)).tolist()) if case.coverage_frames else set()
    fov = ((float(sim.shots.az_rad.min()), float(sim.shots.az_rad.max())),
           (float(sim.shots.el_rad.min()), float(sim.shots.el_rad.max())))
    period = sim.frame_period_s

    def on_frame(frame: Frame) -> None:
        stats.add_frame(frame)
        if frame.index in coverage_at:
            visible = visible_faces(target, faces, pose.at(frame.stamp_s + 0.5 * period), *fov)
            stats.add_coverage(
                covered_fraction(faces.area_m2, visible, frame.face[frame.material != NO_MATERIAL]),
                covered_fraction(faces.area_m2, visible, frame.truth_face))

    if case.save == 'bags':
        from lidar_sim_ros.offline import simulate_to_bag
        bag_dir = run_dir(out_dir, case.run_id)
        if bag_dir.exists():
            shutil.rmtree(bag_dir)  # left by an interrupted attempt: finished runs are skipped
        simulate_to_bag(scenario, bag_dir, case.frames, storage=case.storage, figures=False,
                        simulator=sim, pose_source=pose, on_frame=on_frame)
    else:
        for i in range(case.frames):
            on_frame(sim.simulate_frame(i * period, pose, i))
    return stats.summary()


def run_case(case: RunCase, out_dir: str | Path | None = None,
             start: tuple[float, float] | None = None) -> dict:
    """One manifest row: never raises; a failure becomes ``status: failed`` with its error.

    ``start``: (perf_counter, process_time) at which the run's compute began (default:
    now, after the worker's one-time preparation, which is not the run's compute).
    """
    row = {'run_id': case.run_id, 'seed': case.seed,
           **{f'param.{k}': v for k, v in case.params.items()}}
    try:
        if prepare_scenario(case.scenario) or start is None:
            start = time.perf_counter(), time.process_time()  # preparing is not the run's
        stats = simulate_case(case, out_dir)
    except Exception as exc:  # a run's failure must not stop the campaign
        last = traceback.extract_tb(exc.__traceback__)[-1]
        row.update(status='failed', error=f'{type(exc).__name__}: {exc} '
                                          f'({Path(last.filename).name}:{last.lineno})')
    else:
        row.update(status='ok', error='', **{f'stat.{k}': v for k, v in stats.items()})
    start = start or (time.perf_counter(), time.process_time())
    row['compute_s'] = time.perf_counter() - start[0]
    row['cpu_s'] = time.process_time() - start[1]
    row['worker'] = f'{socket.gethostname()}:{os.getpid()}'
    return row


def run_batch(campaign: Campaign | bytes, run_ids: list[int],
              out_dir: str | Path | None = None) -> list[dict]:
    """The engine's task: runs ``run_ids`` one after the other, one manifest row each (in
    order); never raises. Each row is exactly ``run_one``'s: a run's result depends on
    the campaign and its id alone, not on the batch it came in.

    ``campaign`` may come pickled (the engine sends it so): Dask's scheduler unpickles
    every task it is given and kept ~500 objects (~32 kB) of each task's campaign after
    the task was released; one bytes object of ~3.5 kB is what it keeps instead.

    Short runs come in batches because Dask's own cost per task (~5-10 ms of scheduler,
    client and worker time) would otherwise exceed the run (a one-frame run of a small
    sensor takes ~1 ms). The first task a process gets for a campaign prepares the worker
    (``prepare_worker``), outside every run's compute.
    """
    if isinstance(campaign, bytes):
        campaign = pickle.loads(campaign)  # noqa: S301 - the engine's own task, as Dask's are
    if _campaign_key(campaign) not in _PREPARED:
        try:
            prepare_worker(campaign)
        except Exception:  # noqa: BLE001 - e.g. a missing mesh: each run records its own error
            _PREPARED.add(_campaign_key(campaign))
    rows = [run_one(campaign, run_id, out_dir) for run_id in run_ids]
    if not keeps_series(campaign):
        for row in rows:  # nothing to send back to the client that it would not keep
            row.pop('series', None)
    return rows


def keeps_series(campaign: Campaign) -> bool:
    """Whether the engine's client keeps any run's time series (``series.SeriesKeeper``)."""
    series = campaign.spec.series
    return campaign.spec.loop is not None and series is not None and bool(
        (series.worst and series.by) or series.runs)


def run_one(campaign: Campaign, run_id: int, out_dir: str | Path | None = None) -> dict:
    """Sample run ``run_id`` of ``campaign`` and simulate it (the engine's tasks are
    batches of these, ``run_batch``). Never raises.

    The run's compute (``compute_s``, ``cpu_s``) counts the sampling: it is the run's own work.
    A closed-loop campaign's run is ``loop_case.run_one_loop``.
    """
    if campaign.spec.loop is not None:
        return run_one_loop(campaign, run_id, out_dir)
    start = time.perf_counter(), time.process_time()
    try:
        case = sample_run(campaign, run_id)
    except Exception as exc:  # e.g. a dispersed value that a config model rejects
        return {'run_id': run_id, 'seed': run_seed(campaign.spec.seed, run_id), 'status': 'failed',
                'error': f'sampling: {type(exc).__name__}: {exc}', 'compute_s': 0.0,
                'worker': f'{socket.gethostname()}:{os.getpid()}'}
    return run_case(case, out_dir, start)


def param_names(campaign: Campaign) -> list[str]:
    """The ``params`` keys every run of this campaign has, in manifest column order."""
    if campaign.spec.loop is not None:
        return list(sample_loop_case(campaign, 0).params)
    return list(sample_run(campaign, 0).params)
