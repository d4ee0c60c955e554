#!/usr/bin/env python3
"""Benchmark of the core pipeline on the default scenario (`make bench`).

Prints a summary and writes JSON with:

* full pipeline (``Simulator.simulate_frame`` + packing to PointCloud2): ms per
  frame, shots/s and points/s (median over frames);
* raw embreex rays/s on the SAME rays in the same run: the body-frame rays of
  each benchmarked frame, ``EmbreeScene().run(o, d, output=1)`` on a scene built
  from the same triangles, and the ratio pipeline shots/s over raw rays/s;
* a per-stage breakdown (pose, raycast, reflection, detection, packing), the
  stages timed one by one through the public core functions;
* peak RSS, and the cost per ray of a ~1M-triangle rocket mesh vs a ~10k one;
* the top cProfile entries of simulate_frame (where the time goes);
* the effects: every catalogue effect of ``--effects-scenario`` (config/
  scenario_all_effects.yaml: each at its documented example parameters) on its own and
  all together, against the plain model, frame by frame in the same loop
  (``all_effects_ms_per_frame``, ``all_effects_over_plain``, ``effects``), with the beam
  footprint's full sampling of every shot for reference;
* threads: plain and all-effects frames with the raycast split over 1 and 2 threads
  (on 2 CPUs; ``threads``).

By default the process is pinned to one CPU (``--cpus 1``) so that the "one
core" target is measured as such, whatever threads Embree or numpy start;
CPU-time / wall-time ratios are recorded to show any remaining parallelism.
* sensors (issue 33): one row per sensor profile (the P-60, the Livox Mid-40's rosette,
  the 256 x 256 flash array, a 32-beam spinning LiDAR) on the rocket body: rays per
  frame, ms per plain frame (``simulate_frame``) with the raycast on 1 and on 2 threads
  (2 CPUs), raw Embree on the same body-frame rays (the frame's cast order) on 1 thread
  and split over 2, and the ratio: raw Embree 1 thread ms / frame ms (above 1: the frame
  beats one thread of raw Embree), frames interleaved.
* the cost of sunlight (issue 11): ``Simulator.simulate_frame`` on
  config/scenario_sunlit.yaml with its sun and the ``sunlight`` effect vs the same
  scenario without them, frames interleaved, and the ratio.

Targets (issue 2): ratio >= 0.5; <= 10 ms per P-60 frame on one core;
1M-triangle mesh <= 2x a 10k-triangle mesh per ray. Issue 10: every effect on at
its example parameters <= 2x a plain frame (one core, the same run). Issue 11: a sunlit
frame <= 1.5x a plain one.
"""
from __future__ import annotations

import os

for _var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')  # numpy BLAS single-threaded; set before numpy loads

import argparse  # noqa: E402
import cProfile  # noqa: E402
import importlib.util  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import pstats  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

TARGET_RATIO = 0.5
TARGET_MS_PER_FRAME = 10.0
TARGET_MESH_COST = 2.0
TARGET_ALL_EFFECTS = 2.0
TARGET_SUNLIT_COST = 1.5
TARGET_MULTIPATH = 1.3      # issue 24: the second bounce's rays only for specular hits


def timed(fn: Callable[[], object], repeats: int) -> tuple[float, float, object]:
    """Median wall time and median CPU time (s) of ``repeats`` calls, plus the last result."""
    walls, cpus, result = [], [], None
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        result = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return statistics.median(walls), statistics.median(cpus), result


def pin_cpus(n: int) -> list[int]:
    """Restrict this process to its first n allowed CPUs (0 = leave as is)."""
    allowed = sorted(os.sched_getaffinity(0))
    if n > 0:
        os.sched_setaffinity(0, allowed[:n])
    return sorted(os.sched_getaffinity(0))


def load_mesh_tool():
    """tools/make_rocket_mesh.py is a script, not a package: import it by path."""
    path = ROOT / 'tools' / 'make_rocket_mesh.py'
    spec = importlib.util.spec_from_file_location('make_rocket_mesh', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, default=Path('bench.json'), help='JSON output file')
    ap.add_argument('--scenario', type=Path, default=ROOT / 'config' / 'scenario.yaml')
    ap.add_argument('--frames', type=int, default=10, help='frames benchmarked (default 10)')
    ap.add_argument('--repeats', type=int, default=3, help='timed repeats per frame (median)')
    ap.add_argument('--cpus', type=int, default=1, help='pin to this many CPUs (0: no pinning)')
    ap.add_argument('--small-segments', type=int, default=56, help='~10k-triangle rocket mesh')
    ap.add_argument('--big-segments', type=int, default=600, help='~1M-triangle rocket mesh')
    ap.add_argument('--no-mesh-scaling', action='store_true', help='skip the 1M-triangle test')
    ap.add_argument('--profile-top', type=int, default=12, help='cProfile entries reported')
    ap.add_argument('--effects-scenario', type=Path,
                    default=ROOT / 'config' / 'scenario_all_effects.yaml',
                    help='the scenario whose effects list is measured, one by one and together')
    ap.add_argument('--no-effects', action='store_true', help='skip the effects and threads figures')
    ap.add_argument('--no-sensors', action='store_true', help='skip the sensors table')
    ap.add_argument('--sunlit-scenario', type=Path, default=ROOT / 'config' / 'scenario_sunlit.yaml',
                    help="scenario with a sun for the sunlight cost ('' to skip)")
    args = ap.parse_args(argv)

    cpus = pin_cpus(args.cpus)
    # Import after pinning, so any thread pool sizes itself to the allowed CPUs.
    import numpy as np
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from lidar_sim_ros.core import detection, reflection
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.geometry import Target, cast_at_poses
    from lidar_sim_ros.core.pipeline import Simulator
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    from lidar_sim_ros.core.scan import frame_shots
    from lidar_sim_ros.io.pointcloud import make_points, to_rosbags_msg
    from rosbags.typesys import Stores, get_typestore

    scenario = load_scenario(args.scenario)
    t0 = time.perf_counter()
    sim = Simulator.from_scenario(scenario)
    setup_s = time.perf_counter() - t0
    traj = ScenarioTrajectory.from_config(scenario.config)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    target = sim.target
    period = sim.frame_period_s
    n_shots = len(sim.shots)
    frame_id = scenario.config.frame_id

    raw_scene = rtcore_scene.EmbreeScene()
    TriangleMesh(raw_scene, target.vertices_m[target.faces].astype(np.float32))

    def pack(frame):
        points = make_points(frame.xyz_m, frame.intensity, frame.t_s, frame.ring, frame.material)
        return to_rosbags_msg(points, int(frame.stamp_s * 1e9), frame_id, typestore)

    # Warm-up: first calls pay for lazy imports, caches and Embree's first-use setup.
    for i in range(2):
        pack(sim.simulate_frame(i * period, traj, i))

    rows = []
    for i in range(args.frames):
        start = i * period
        sim_wall, sim_cpu, frame = timed(lambda: sim.simulate_frame(start, traj, i), args.repeats)
        pack_wall, _, _ = timed(lambda: pack(frame), args.repeats)

        # The same rays in the body frame, and raw Embree on them.
        t_abs = start + sim.shots.t_s
        poses = traj.at(t_abs)
        o = np.ascontiguousarray(poses.to_body(np.zeros((n_shots, 3))), dtype=np.float32)
        d = np.ascontiguousarray(poses.vector_to_body(sim.directions), dtype=np.float32)
        raw_wall, raw_cpu, _ = timed(lambda: raw_scene.run(o, d, output=1), args.repeats)

        # Stages, one by one through the public functions the simulator uses, on the
        # shots in the simulator's cast order (coherent directions).
        cast_shots, cast_dirs = sim._cast_shots, sim._cast_directions
        t_cast = start + cast_shots.t_s
        pose_wall, _, poses_c = timed(lambda: traj.at(t_cast), args.repeats)
        cast_wall, _, hits = timed(lambda: cast_at_poses(target, cast_dirs, poses_c), args.repeats)
        o_c = np.ascontiguousarray(poses_c.to_body(np.zeros((n_shots, 3))), dtype=np.float32)
        d_c = np.ascontiguousarray(poses_c.vector_to_body(cast_dirs), dtype=np.float32)
        embree_c_wall, _, _ = timed(lambda: target.intersect(o_c, d_c), args.repeats)
        on = np.flatnonzero(hits.hit)
        mat = hits.material.take(on)
        kd, ks, n_exp = (scenario.materials.column(k).take(mat) for k in ('kd', 'ks', 'n'))
        optics, det = scenario.sensor.optics, scenario.sensor.detection

        def reflect():
            power = np.zeros(n_shots)
            power[on] = reflection.return_power_w(hits.range_m.take(on), hits.incidence_rad.take(on),
                                                  kd, ks, n_exp, optics, hits.cos_incidence.take(on))
            return power

        refl_wall, _, power = timed(reflect, args.repeats)
        bias = np.zeros(n_shots)
        bias[on] = scenario.materials.column('bias_m').take(mat)
        sigma = np.zeros(n_shots)
        sigma[on] = scenario.materials.column('sigma_m').take(mat)
        range_m = np.where(hits.hit, hits.range_m, np.nan)

        def detect():
            rng = sim.frame_rng(i)
            keep = hits.hit & detection.detected_mask(power, range_m, det)
            measured = detection.measured_range_m(range_m, bias, sigma, rng)
            out = np.flatnonzero(keep)
            return cast_dirs.take(out, axis=0) * measured.take(out)[:, None], power.take(out)

        det_wall, _, _ = timed(detect, args.repeats)
        rows.append(dict(sim=sim_wall, sim_cpu=sim_cpu, pack=pack_wall, raw=raw_wall,
                         raw_cpu=raw_cpu, pose=pose_wall, raycast=cast_wall, embree_cast=embree_c_wall,
                         reflection=refl_wall, detection=det_wall, points=len(frame)))

    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    pipeline_s = med['sim'] + med['pack']
    scan_wall, _, _ = timed(lambda: frame_shots(scenario.sensor), 3)
    stages_ms = {
        'scan (built once per Simulator, cached)': scan_wall * 1e3,
        'pose (trajectory at every shot time)': med['pose'] * 1e3,
        'raycast (cast_at_poses: to body, Embree, normals, incidence)': med['raycast'] * 1e3,
        '  of which Embree (cast order)': med['embree_cast'] * 1e3,
        '  of which the compiled ray loops around it': (med['raycast'] - med['embree_cast']) * 1e3,
        'reflection (Phong BRDF, Eqs. 1-3)': med['reflection'] * 1e3,
        'detection (dropouts, bias, noise, xyz)': med['detection'] * 1e3,
        'packing (make_points + to_rosbags_msg)': med['pack'] * 1e3,
    }
    staged = med['pose'] + med['raycast'] + med['reflection'] + med['detection']
    stages_ms['simulate_frame overhead (not in the stages above)'] = (med['sim'] - staged) * 1e3

    pack_rclpy_ms = None
    try:
        from lidar_sim_ros.io.pointcloud import to_rclpy_msg
        pts = make_points(frame.xyz_m, frame.intensity, frame.t_s, frame.ring, frame.material)
        pack_rclpy_ms = timed(lambda: to_rclpy_msg(pts, 0, frame_id), 5)[0] * 1e3
    except ImportError:
        pass

    result = {
        'scenario': str(args.scenario),
        'mesh_triangles': int(target.n_faces),
        'frames': args.frames,
        'repeats_per_frame': args.repeats,
        'cpus_pinned': cpus,
        'python': platform.python_version(),
        'machine': platform.machine(),
        'setup_s': setup_s,
        'shots_per_frame': n_shots,
        'points_per_frame_median': med['points'],
        'pipeline': {
            'definition': 'Simulator.simulate_frame + make_points + to_rosbags_msg',
            'ms_per_frame': pipeline_s * 1e3,
            'shots_per_s': n_shots / pipeline_s,
            'points_per_s': med['points'] / pipeline_s,
            'simulate_frame_ms': med['sim'] * 1e3,
            'simulate_frame_cpu_over_wall': med['sim_cpu'] / med['sim'],
        },
        'embree_raw': {
            'definition': 'EmbreeScene().run(o, d, output=1) on the same body-frame rays',
            'ms_per_frame': med['raw'] * 1e3,
            'rays_per_s': n_shots / med['raw'],
            'cpu_over_wall': med['raw_cpu'] / med['raw'],
        },
        'ratio_pipeline_over_embree': (n_shots / pipeline_s) / (n_shots / med['raw']),
        'stages_ms': stages_ms,
        'pack_rclpy_ms': pack_rclpy_ms,
    }
    result['hot_spots'] = profile(sim, traj, period, args.profile_top)
    if str(args.sunlit_scenario) not in ('', '.'):     # Path('') is '.'
        result['sunlight'] = sunlight_cost(args, load_scenario, Simulator, ScenarioTrajectory)
    result['peak_rss_mb_pipeline'] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    if not args.no_effects:
        fx = effects_costs(args, scenario, traj, pack, Simulator, np)
        result.update(all_effects_ms_per_frame=fx['all effects']['ms_per_frame'],
                      all_effects_over_plain=fx['all effects']['over_plain'], effects=fx)
        if 'multipath' in fx:
            result['multipath_over_plain'] = fx['multipath']['over_plain']
        result['beam_footprint'] = beam_footprint(args, load_scenario(args.effects_scenario), traj, np)
        result['threads'] = thread_scaling(args, load_scenario(args.effects_scenario), traj, pack,
                                           Simulator, np)
        result['peak_rss_mb_effects'] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    if not args.no_sensors:
        result['sensors'] = sensors_table(args, np)
    if not args.no_mesh_scaling:
        result['mesh_scaling'] = mesh_scaling(args, sim, traj, Target, scenario, np,
                                              rtcore_scene, TriangleMesh)
    result['peak_rss_mb'] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    result['targets'] = targets(result)

    report(result)
    args.out.write_text(json.dumps(result, indent=2) + '\n')
    print(f'\nwrote {args.out}')
    return 0


def profile(sim, traj, period: float, top: int) -> list[dict]:
    """cProfile over a few frames: the functions with the most own time."""
    prof = cProfile.Profile()
    prof.enable()
    for i in range(5):
        sim.simulate_frame(i * period, traj, i)
    prof.disable()
    stats = pstats.Stats(prof, stream=io.StringIO())
    total = sum(v[2] for v in stats.stats.values())
    rows = sorted(stats.stats.items(), key=lambda kv: kv[1][2], reverse=True)[:top]
    return [{'function': f'{Path(file).name}:{line}({name})', 'calls': nc,
             'own_ms_per_frame': tt / 5 * 1e3, 'cum_ms_per_frame': ct / 5 * 1e3,
             'own_share': tt / total}
            for (file, line, name), (_, nc, tt, ct, _) in rows]


def interleaved_ms(variants: dict, traj, period: float, pack, frames: int, repeats: int,
                   cpu: bool = False) -> dict:
    """Median ms per frame (simulate_frame + packing) of each simulator, measured frame by
    frame in turn, so that every variant sees the same frames and the same machine load."""
    times = {k: [] for k in variants}
    for sim in variants.values():                  # warm-up: kernels, caches, mesh tables
        pack(sim.simulate_frame(0.0, traj, 0))
    for i in range(frames):
        for _ in range(repeats):
            for name, sim in variants.items():
                clock = time.process_time if cpu else time.perf_counter
                t0 = clock()
                pack(sim.simulate_frame(i * period, traj, i))
                times[name].append(clock() - t0)
    return {k: statistics.median(v) * 1e3 for k, v in times.items()}


def effects_costs(args, scenario, traj, pack, Simulator, np) -> dict:
    """Each effect of the effects scenario alone and all together vs none, in one run."""
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.effects import make_effect
    fx_scenario = load_scenario(args.effects_scenario)
    specs = [(e.name, dict(e.params)) for e in fx_scenario.config.effects]
    plain = Simulator.from_scenario(scenario, effects=[])
    variants = {'plain': plain}
    for name, params in specs:
        variants[name] = Simulator(plain.sensor, plain.materials, plain.target, plain.seed,
                                   [make_effect(name, params)])
    variants['all effects'] = Simulator(plain.sensor, plain.materials, plain.target, plain.seed,
                                        [make_effect(n, p) for n, p in specs])
    ms = interleaved_ms(variants, traj, plain.frame_period_s, pack, args.frames, args.repeats)
    out = {k: {'ms_per_frame': v, 'over_plain': v / ms['plain']} for k, v in ms.items()}
    for name, params in specs:
        out[name]['params'] = params
    out['all effects']['scenario'] = str(args.effects_scenario)
    return out


def beam_footprint(args, fx_scenario, traj, np) -> dict:
    """How many shots the beam footprint samples, and the full sampling's cost for reference."""
    from lidar_sim_ros.core.effects.beam_divergence import (footprint_cast, sampled_shots,
                                                            sample_footprint)
    from lidar_sim_ros.core.pipeline import Simulator
    spec = next((e for e in fx_scenario.config.effects if e.name == 'beam_divergence'), None)
    if spec is None:
        return {}
    sim = Simulator.from_scenario(fx_scenario, effects=[])
    half = 0.5 * spec.params.get('footprint_scale', 0.0) * sim.sensor.optics.beam_divergence_rad
    if half <= 0:
        return {}
    period = sim.frame_period_s
    poses = [traj.at(i * period + sim._cast_shots.t_s) for i in range(min(args.frames, 5))]
    d = sim._cast_directions
    footprint_cast(sim.target, d, poses[0], half)          # warm-up
    fast = [timed(lambda: footprint_cast(sim.target, d, p, half), 1)[0] for p in poses]
    full = [timed(lambda: sample_footprint(sim.target, d, p, half), 1)[0] for p in poses]
    sampled = [int(np.count_nonzero(sampled_shots(sim.target, d, p, half))) for p in poses]
    return {'footprint_scale': spec.params.get('footprint_scale'), 'shots': len(d),
            'sampled_shots_per_frame': statistics.median(sampled),
            'cast_ms_per_frame': statistics.median(fast) * 1e3,
            'full_sampling_ms_per_frame': statistics.median(full) * 1e3,
            'full_over_fast': statistics.median(full) / statistics.median(fast)}


def pin_two_cpus() -> tuple[list[int], list[int]]:
    """Run on two CPUs where the machine has them: (the CPUs allowed before, those now)."""
    allowed = sorted(os.sched_getaffinity(0))
    try:
        os.sched_setaffinity(0, sorted(set(allowed) | set(range(os.cpu_count() or 1)))[:2])
    except OSError:
        pass
    return allowed, sorted(os.sched_getaffinity(0))


def thread_scaling(args, fx_scenario, traj, pack, Simulator, np) -> dict:
    """Plain and all-effects frames with the raycast on 1 and 2 threads, on 2 CPUs."""
    allowed, cpus = pin_two_cpus()
    variants = {}
    for threads in (1, 2):
        plain = Simulator.from_scenario(fx_scenario, effects=[])
        plain.target.threads = threads
        variants[f'plain, {threads} thread(s)'] = plain
        variants[f'all effects, {threads} thread(s)'] = Simulator(
            plain.sensor, plain.materials, plain.target, plain.seed,
            Simulator.from_scenario(fx_scenario).effects)
    ms = interleaved_ms(variants, traj, variants['plain, 1 thread(s)'].frame_period_s, pack,
                        args.frames, args.repeats)
    os.sched_setaffinity(0, allowed)
    out = {'cpus': cpus, 'ms_per_frame': ms}
    for t in (1, 2):
        out[f'all_effects_over_plain_{t}_thread'] = (ms[f'all effects, {t} thread(s)']
                                                     / ms[f'plain, {t} thread(s)'])
    out['plain_speedup_2_threads'] = ms['plain, 1 thread(s)'] / ms['plain, 2 thread(s)']
    out['all_effects_speedup_2_threads'] = (ms['all effects, 1 thread(s)']
                                            / ms['all effects, 2 thread(s)'])
    return out


SENSOR_PROFILES = (('Cepton Vista P-60', 'scenario.yaml', None),
                   ('Livox Mid-40 (rosette)', 'scenario_mid40.yaml', None),
                   ('flash 256 x 256', 'scenario_flash.yaml', None),
                   ('spinning 32-beam', 'scenario.yaml', 'spinning_32.yaml'))


def sensors_table(args, np) -> dict:
    """One row per sensor profile (module doc): plain frames of the rocket body with the
    raycast on 1 and 2 threads, and raw Embree on the same rays, on 2 CPUs."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh
    from lidar_sim_ros.core.config import load_sensor
    from lidar_sim_ros.core.scenario import Scenario, load_scenario
    from lidar_sim_ros.core.geometry import body_rays, split_over_threads
    from lidar_sim_ros.core.pipeline import Simulator
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    allowed, cpus = pin_two_cpus()
    rows = {}
    target = None
    for label, scenario_name, sensor_name in SENSOR_PROFILES:
        sc = load_scenario(ROOT / 'config' / scenario_name)
        if sensor_name is not None:
            sc = Scenario(sc.config, load_sensor(ROOT / 'config' / sensor_name), sc.materials,
                          sc.mesh_path, sc.source)
        one = Simulator.from_scenario(sc, effects=[], target=target, threads=1)
        target = one.target                        # the rocket body, loaded once
        traj = ScenarioTrajectory.from_config(sc.config)
        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene, target.vertices_m[target.faces].astype(np.float32))
        period = one.frame_period_s
        for i in range(2):                          # warm-up
            one.simulate_frame(i * period, traj, i)
        t1, t2, raw1, raw2 = [], [], [], []

        def frame(start, i):
            one._last_plan = (-1, one._plan)    # a rosette builds each frame's shots: timed too
            return one.simulate_frame(start, traj, i)
        for i in range(args.frames):
            start = i * period
            target.threads = 1
            t1.append(timed(lambda: frame(start, i), args.repeats)[0])
            target.threads = 2
            t2.append(timed(lambda: frame(start, i), args.repeats)[0])
            plan = one._frame_plan(i)
            rays = body_rays(plan.directions, traj.at(start + plan.cast_shots.t_s))
            o, d = rays.origins_m, rays.directions
            raw1.append(timed(lambda: scene.run(o, d, output=1), args.repeats)[0])
            raw2.append(timed(lambda: split_over_threads(
                len(o), 2, lambda part: scene.run(o[part], d[part], output=1)), args.repeats)[0])
        target.threads = 1
        med = {k: statistics.median(v) * 1e3 for k, v in
               (('frame_1_thread', t1), ('frame_2_threads', t2), ('raw_1_thread', raw1),
                ('raw_2_threads', raw2))}
        rows[label] = {'scenario': scenario_name, 'sensor': sc.sensor.name,
                       'rays_per_frame': len(one.shots), 'ms_per_frame_1_thread': med['frame_1_thread'],
                       'ms_per_frame_2_threads': med['frame_2_threads'],
                       'raw_embree_ms_1_thread': med['raw_1_thread'],
                       'raw_embree_ms_2_threads': med['raw_2_threads'],
                       'raw_embree_2_threads_speedup': med['raw_1_thread'] / med['raw_2_threads'],
                       'ratio_over_raw_embree_1_thread': med['raw_1_thread'] / med['frame_2_threads'],
                       'ratio_over_raw_embree_1_thread_frame_1_thread':
                           med['raw_1_thread'] / med['frame_1_thread']}
    os.sched_setaffinity(0, allowed)
    return {'cpus': cpus, 'definition': 'plain simulate_frame on the rocket body; ratio = raw '
                                        'Embree ms on 1 thread / frame ms (2 threads)',
            'rows': rows}


def mesh_scaling(args, sim, traj, Target, scenario, np, rtcore_scene, TriangleMesh) -> dict:
    """Cost per ray of a fine vs a coarse rocket mesh on the same rays (frame 0).

    Raw Embree is measured twice: in firing order (the 24 lasers fire round-robin,
    so consecutive rays land in different tiles) and with the same rays sorted into
    1-degree angular cells (coherent: neighbours share BVH nodes), which is how
    ``Target.cast`` is called by the pipeline.
    """
    from lidar_sim_ros.core.geometry import coherent_order
    tool = load_mesh_tool()
    names = scenario.materials.names
    poses = traj.at(sim.shots.t_s)
    o = np.ascontiguousarray(poses.to_body(np.zeros((len(sim.shots), 3))), dtype=np.float32)
    d = np.ascontiguousarray(poses.vector_to_body(sim.directions), dtype=np.float32)
    order = coherent_order(sim.shots.az_rad, sim.shots.el_rad)
    o_sorted, d_sorted = np.ascontiguousarray(o[order]), np.ascontiguousarray(d[order])
    out = {}
    for label, segments in (('small', args.small_segments), ('big', args.big_segments)):
        mesh, mats = tool.build_rocket_body(segments)
        t0 = time.perf_counter()
        target = Target(np.asarray(mesh.vertices), np.asarray(mesh.faces),
                        np.array([names.index(m) for m in mats]), names)
        build_s = time.perf_counter() - t0
        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene, target.vertices_m[target.faces].astype(np.float32))
        scene.run(o[:100], d[:100], output=1)  # BVH build happens on the first query
        raw_s, raw_cpu, res = timed(lambda: scene.run(o, d, output=1), 7)
        sorted_s, _, _ = timed(lambda: scene.run(o_sorted, d_sorted, output=1), 7)
        cast_s, _, _ = timed(lambda: target.cast(o, d, order), 7)  # as the pipeline casts
        out[label] = {'segments': segments, 'triangles': int(target.n_faces),
                      'target_build_s': build_s,
                      'hit_fraction': float(np.mean(res['primID'] >= 0)),
                      'embree_ns_per_ray': raw_s / len(o) * 1e9,
                      'embree_coherent_ns_per_ray': sorted_s / len(o) * 1e9,
                      'embree_cpu_over_wall': raw_cpu / raw_s,
                      'target_cast_ns_per_ray': cast_s / len(o) * 1e9}
        del target, scene, mesh
    big, small = out['big'], out['small']
    out['embree_cost_ratio_big_over_small'] = big['embree_ns_per_ray'] / small['embree_ns_per_ray']
    out['embree_coherent_cost_ratio_big_over_small'] = (big['embree_coherent_ns_per_ray']
                                                        / small['embree_coherent_ns_per_ray'])
    out['target_cast_cost_ratio_big_over_small'] = (big['target_cast_ns_per_ray']
                                                    / small['target_cast_ns_per_ray'])
    return out


def sunlight_cost(args, load_scenario, Simulator, ScenarioTrajectory) -> dict:
    """simulate_frame with the scenario's sun and effects vs without, frames interleaved so
    that a busy machine slows both alike; medians over frames of the per-frame medians.
    The ratio is taken on CPU time (the same as wall time on an idle pinned core, and less
    disturbed than wall time when other processes share it); wall times are recorded too."""
    scenario = load_scenario(args.sunlit_scenario)
    sunlit = Simulator.from_scenario(scenario)
    plain = Simulator.from_scenario(scenario, effects=[])
    plain.sun = None
    traj = ScenarioTrajectory.from_config(scenario.config)
    for sim in (plain, sunlit):            # warm-up: compiled kernels, caches
        sim.simulate_frame(0.0, traj, 0)
    rows = []
    for i in range(args.frames):
        start = i * sunlit.frame_period_s
        p_wall, p_cpu, _ = timed(lambda: plain.simulate_frame(start, traj, i), args.repeats)
        s_wall, s_cpu, frame = timed(lambda: sunlit.simulate_frame(start, traj, i), args.repeats)
        rows.append((p_wall, s_wall, p_cpu, s_cpu, int((frame.material == 255).sum())))
    med = [statistics.median(r[k] for r in rows) for k in range(5)]
    return {'scenario': str(args.sunlit_scenario),
            'definition': 'Simulator.simulate_frame with the sun and the sunlight effect vs '
                          'the same scenario without them; ratio on CPU time',
            'plain_ms_per_frame': med[0] * 1e3, 'sunlit_ms_per_frame': med[1] * 1e3,
            'plain_cpu_ms_per_frame': med[2] * 1e3, 'sunlit_cpu_ms_per_frame': med[3] * 1e3,
            'ratio_sunlit_over_plain': med[3] / med[2],
            'ratio_sunlit_over_plain_wall': med[1] / med[0],
            'false_returns_per_frame_median': med[4]}


def targets(r: dict) -> dict:
    t = {
        'ratio_ge_0.5': r['ratio_pipeline_over_embree'] >= TARGET_RATIO,
        'ms_per_frame_le_10': r['pipeline']['ms_per_frame'] <= TARGET_MS_PER_FRAME,
    }
    if 'all_effects_over_plain' in r:
        t['all_effects_le_2x_plain'] = r['all_effects_over_plain'] <= TARGET_ALL_EFFECTS
    if 'multipath_over_plain' in r:
        t['multipath_le_1.3x_plain'] = r['multipath_over_plain'] <= TARGET_MULTIPATH
    if 'mesh_scaling' in r:
        # What the simulator pays per ray for the mesh: Target.cast, which casts in the
        # coherent order the pipeline uses (raw Embree in firing order is shown for reference).
        t['mesh_1M_le_2x_10k'] = (r['mesh_scaling']['target_cast_cost_ratio_big_over_small']
                                  <= TARGET_MESH_COST)
    if 'sunlight' in r:
        t['sunlit_le_1.5x_plain'] = r['sunlight']['ratio_sunlit_over_plain'] <= TARGET_SUNLIT_COST
    return t


def report(r: dict) -> None:
    p, e = r['pipeline'], r['embree_raw']
    ok = {True: 'ok', False: 'MISSED'}
    print(f"scenario {r['scenario']}: {r['mesh_triangles']} triangles, {r['shots_per_frame']} "
          f"shots/frame, {r['points_per_frame_median']:.0f} points/frame; CPUs {r['cpus_pinned']}")
    print(f"pipeline ({p['definition']}):")
    print(f"  {p['ms_per_frame']:8.2f} ms/frame   {p['shots_per_s'] / 1e6:6.2f} M shots/s   "
          f"{p['points_per_s'] / 1e6:6.2f} M points/s   [target <= {TARGET_MS_PER_FRAME:g} ms: "
          f"{ok[r['targets']['ms_per_frame_le_10']]}]")
    print(f"raw embreex on the same rays: {e['ms_per_frame']:.2f} ms/frame, "
          f"{e['rays_per_s'] / 1e6:.2f} M rays/s (CPU/wall {e['cpu_over_wall']:.2f})")
    print(f"ratio pipeline / embree rays per second: {r['ratio_pipeline_over_embree']:.3f}   "
          f"[target >= {TARGET_RATIO}: {ok[r['targets']['ratio_ge_0.5']]}]")
    print('stages (median ms per frame):')
    for name, ms in r['stages_ms'].items():
        print(f'  {ms:8.3f}  {name}')
    if r['pack_rclpy_ms'] is not None:
        print(f"  {r['pack_rclpy_ms']:8.3f}  (packing for the node: to_rclpy_msg)")
    print('hot spots (cProfile own time per frame):')
    for h in r['hot_spots']:
        print(f"  {h['own_ms_per_frame']:8.3f} ms  {100 * h['own_share']:5.1f} %  "
              f"{h['calls'] // 5:>4} calls  {h['function']}")
    if 'mesh_scaling' in r:
        m = r['mesh_scaling']
        for k in ('small', 'big'):
            print(f"mesh {k}: {m[k]['triangles']:>9} triangles  embree {m[k]['embree_ns_per_ray']:7.1f} "
                  f"ns/ray (coherent order {m[k]['embree_coherent_ns_per_ray']:6.1f})  "
                  f"Target.cast {m[k]['target_cast_ns_per_ray']:7.1f} ns/ray  "
                  f"(build {m[k]['target_build_s']:.2f} s, hits {100 * m[k]['hit_fraction']:.0f} %)")
        print(f"1M vs 10k triangles, cost per ray: Target.cast (the simulator's raycast) "
              f"x{m['target_cast_cost_ratio_big_over_small']:.2f}   "
              f"[target <= {TARGET_MESH_COST:g}x: {ok[r['targets']['mesh_1M_le_2x_10k']]}]; "
              f"raw embree in firing order x{m['embree_cost_ratio_big_over_small']:.2f}, "
              f"in coherent order x{m['embree_coherent_cost_ratio_big_over_small']:.2f}")
    if 'effects' in r:
        print('effects (ms per frame, ratio to plain; one run, frame by frame in turn):')
        for name, e in r['effects'].items():
            print(f"  {e['ms_per_frame']:8.2f} ms  x{e['over_plain']:.2f}  {name}")
        print(f"all effects / plain: {r['all_effects_over_plain']:.2f}   [target <= "
              f"{TARGET_ALL_EFFECTS:g}: {ok[r['targets']['all_effects_le_2x_plain']]}]")
        if 'multipath_over_plain' in r:
            print(f"multipath / plain: {r['multipath_over_plain']:.2f}   [target <= "
                  f"{TARGET_MULTIPATH:g}: {ok[r['targets']['multipath_le_1.3x_plain']]}]")
        b = r.get('beam_footprint') or {}
        if b:
            print(f"beam footprint (scale {b['footprint_scale']}): {b['sampled_shots_per_frame']:.0f} of "
                  f"{b['shots']} shots sampled; cast {b['cast_ms_per_frame']:.1f} ms vs full sampling "
                  f"{b['full_sampling_ms_per_frame']:.1f} ms (x{b['full_over_fast']:.1f})")
        th = r['threads']
        print(f"threads (CPUs {th['cpus']}): " + ', '.join(
            f'{k} {v:.2f} ms' for k, v in th['ms_per_frame'].items()))
        print(f"  2 threads speed-up: plain x{th['plain_speedup_2_threads']:.2f}, all effects "
              f"x{th['all_effects_speedup_2_threads']:.2f}; all effects / plain: 1 thread "
              f"{th['all_effects_over_plain_1_thread']:.2f}, 2 threads {th['all_effects_over_plain_2_thread']:.2f}")
    if 'sensors' in r:
        print(f"sensors (plain frames of the rocket body, CPUs {r['sensors']['cpus']}; ratio = "
              f"raw Embree 1 thread / frame on 2 threads):")
        print(f"  {'profile':<24} {'rays/frame':>10} {'ms 1 thr':>9} {'ms 2 thr':>9} "
              f"{'raw 1 thr':>10} {'raw 2 thr':>10} {'ratio':>6}")
        for name, row in r['sensors']['rows'].items():
            print(f"  {name:<24} {row['rays_per_frame']:>10} {row['ms_per_frame_1_thread']:>9.2f} "
                  f"{row['ms_per_frame_2_threads']:>9.2f} {row['raw_embree_ms_1_thread']:>10.2f} "
                  f"{row['raw_embree_ms_2_threads']:>10.2f} "
                  f"{row['ratio_over_raw_embree_1_thread']:>6.2f}")
    if 'sunlight' in r:
        sun = r['sunlight']
        print(f"sunlight: {sun['sunlit_cpu_ms_per_frame']:.2f} ms CPU/frame sunlit vs "
              f"{sun['plain_cpu_ms_per_frame']:.2f} plain, x{sun['ratio_sunlit_over_plain']:.2f} "
              f"(wall x{sun['ratio_sunlit_over_plain_wall']:.2f})   [target <= {TARGET_SUNLIT_COST:g}x: "
              f"{ok[r['targets']['sunlit_le_1.5x_plain']]}]; "
              f"{sun['false_returns_per_frame_median']:.0f} false returns per frame")
    print(f"peak RSS: {r['peak_rss_mb_pipeline']:.0f} MB for the pipeline, "
          f"{r['peak_rss_mb']:.0f} MB at the end (incl. the mesh-scaling meshes)")


if __name__ == '__main__':
    sys.exit(main())
