#!/usr/bin/env python3
"""What each LiDAR error costs the pose tracker, how long a registration takes, and how
often acquisition from the cloud alone succeeds (offline).

Simulates the default scenario frame by frame with the core (no DDS) and tracks the
target with ``gnc.tracker.PoseTracker`` on five clouds of the same frames:

* ``truth``: every hit, exact ranges (the scan lattice only);
* ``dropouts``: the detected returns, exact ranges (lattice + dropouts);
* ``noise``: detected returns with the per-material noise, no bias;
* ``bias``: detected returns with the per-material bias, no noise;
* ``full``: the published cloud (bias, noise, dropouts).

Errors are scored like ``make demo-gnc`` (truth at mid-scan). Timing: the median
registration time per frame, next to the simulator's own time per frame measured in
the same run as the baseline (the machine may be shared: compare the ratio).

Acquisition (``gnc.acquire``, no guess): one frame of the full error model cloud per
case, over a grid of attitudes (the long axis along ``--attitudes`` directions spread
evenly over the sphere, each with its own roll) times ``--ranges`` (distance to the body
centre, the body centred in the field of view). A case succeeds when the acquisition
says so and its pose is within 0.2 m (the range bias moves it ~0.1 m) and 3 deg of the
long axis of the truth; roll is not scored (docs/gnc.md). A miss is *ambiguous* when
the truth, refined the same way, scores no better than what was found (the cloud does
not tell them apart: a patch of the tank with neither end in view), else *missed* (the
search did not find it). Cases where the body would come within 1 m of the sensor are
left out.

    python bench/bench_tracker.py [--frames 100] [--attitudes 12] [--ranges 5 10 20 30]
                                  [--out bench_tracker.json]
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import MaterialsConfig
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory, StaticPose
from lidar_sim_ros.gnc.acquire import AcquisitionConfig, acquire, coverage, fit_score
from lidar_sim_ros.gnc.evaluate import tracking_errors
from lidar_sim_ros.gnc.tracker import (PoseTracker, TrackerConfig, build_model, pose_matrix, pose_parts,
                                       register)
from lidar_sim_ros.paths import config_path

NS = 1_000_000_000
VARIANTS = {'truth': None, 'dropouts': (False, False), 'noise': (False, True), 'bias': (True, False),
            'full': (True, True)}


def with_errors(sim: Simulator, bias: bool, noise: bool) -> Simulator:
    """The same simulator with the materials' bias and/or noise switched off."""
    mats = MaterialsConfig(materials=[m.model_copy(update={'bias_m': m.bias_m if bias else 0.0,
                                                           'sigma_m': m.sigma_m if noise else 0.0})
                                      for m in sim.materials.materials])
    return Simulator(sim.sensor, mats, sim.target, sim.seed, sim.effects)


def grid_attitudes(count: int) -> list[np.ndarray]:
    """``count`` rotations whose long axis (+Z) points along a Fibonacci spiral over the
    sphere (evenly spread), each rolled by a further 137.5 deg about it."""
    golden = math.pi * (3.0 - math.sqrt(5.0))
    out = []
    for k in range(count):
        z = 1.0 - 2.0 * (k + 0.5) / count
        axis = np.array([math.sqrt(1 - z * z) * math.cos(golden * k), math.sqrt(1 - z * z) * math.sin(golden * k), z])
        align, _ = Rotation.align_vectors([axis], [[0.0, 0.0, 1.0]])
        out.append((Rotation.from_rotvec(golden * k * axis) * align).as_matrix())
    return out


def acquisition_grid(sim: Simulator, model, tracker: TrackerConfig, acquisition: AcquisitionConfig,
                     attitudes: int, ranges_m: list[float], sim_ms: list[float]) -> dict:
    """Acquire each grid case from one full-error-model frame; success rate and time per range.
    Appends each frame's simulation time (ms) to ``sim_ms``."""
    per_range, seconds = {}, []
    for range_m in ranges_m:
        counts = {'cases': 0, 'acquired': 0, 'ambiguous': 0, 'missed': 0, 'skipped_too_close': 0}
        trans, axis_err = [], []
        for R in grid_attitudes(attitudes):
            truth = np.eye(4)
            truth[:3, :3], truth[:3, 3] = R, [range_m, 0.0, 0.0]
            if np.linalg.norm(model.points_m @ R.T + truth[:3, 3], axis=1).min() < 1.0:
                counts['skipped_too_close'] += 1
                continue
            pose = StaticPose(tuple(truth[:3, 3]), tuple(Rotation.from_matrix(R).as_quat()))
            s0 = time.perf_counter()
            xyz = sim.simulate_frame(0.0, pose, 0).xyz_m
            sim_ms.append(1e3 * (time.perf_counter() - s0))
            acq = acquire(model, xyz, acquisition, tracker)
            seconds.append(acq.seconds)
            counts['cases'] += 1
            dt = float(np.linalg.norm(acq.pose[:3, 3] - truth[:3, 3]))
            da = math.degrees(math.acos(min(1.0, float((acq.pose[:3, 2]) @ R[:, 2]))))
            if acq.success and dt < 0.2 and da < 3.0:
                counts['acquired'] += 1
                trans.append(dt)
                axis_err.append(da)
                continue
            # Would the truth have scored better? Refined from the truth like a hypothesis.
            refined = register(model, xyz, truth, list(tracker.capture_gates_m), tracker).pose
            voxel = xyz[np.isfinite(xyz).all(axis=1)]
            truth_score = fit_score(model, voxel, refined, acquisition.score_gate_m) * coverage(
                model, voxel, refined, acquisition)
            found = fit_score(model, voxel, acq.pose, acquisition.score_gate_m) * coverage(
                model, voxel, acq.pose, acquisition)
            counts['ambiguous' if truth_score <= found + acquisition.ambiguity_margin else 'missed'] += 1
        counts['success_rate'] = counts['acquired'] / counts['cases'] if counts['cases'] else float('nan')
        counts['trans_err_m_p50'] = statistics.median(trans) if trans else float('nan')
        counts['axis_err_deg_p50'] = statistics.median(axis_err) if axis_err else float('nan')
        per_range[f'{range_m:g}'] = counts
        print(f'acquisition at {range_m:4.1f} m: {counts["acquired"]}/{counts["cases"]} acquired '
              f'({counts["ambiguous"]} ambiguous, {counts["missed"]} missed, {counts["skipped_too_close"]} '
              f'too close); translation p50 {100 * counts["trans_err_m_p50"]:.1f} cm, axis p50 '
              f'{counts["axis_err_deg_p50"]:.2f} deg', flush=True)
    total = sum(c['cases'] for c in per_range.values())
    acquired = sum(c['acquired'] for c in per_range.values())
    return {'attitudes': attitudes, 'ranges_m': ranges_m, 'cloud': 'full error model, one frame',
            'success_rate': acquired / total if total else float('nan'), 'cases': total,
            'seconds_p50': statistics.median(seconds) if seconds else float('nan'),
            'seconds_max': max(seconds) if seconds else float('nan'),
            'config': acquisition.model_dump(), 'per_range': per_range}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=100)
    parser.add_argument('--attitudes', type=int, default=12, help='acquisition: attitudes per range (0: none)')
    parser.add_argument('--ranges', type=float, nargs='+', default=[5.0, 10.0, 20.0, 30.0],
                        help='acquisition: distances to the body centre (m)')
    parser.add_argument('--out', type=Path, default=Path('bench_tracker.json'))
    args = parser.parse_args(argv)

    scenario = load_scenario(config_path('scenario.yaml'))
    base = Simulator.from_scenario(scenario)
    base.warm_up()
    trajectory = ScenarioTrajectory.from_config(scenario.config)
    config = TrackerConfig()
    t0 = time.perf_counter()
    model = build_model(base.target.vertices_m, base.target.faces, config)
    model_s = time.perf_counter() - t0
    period = base.frame_period_s
    # The truth as the pose player sends it: 50 Hz samples of the trajectory.
    truth_t = np.arange(0.0, args.frames * period + 0.1, 0.02)
    truth = trajectory.at(truth_t)
    truth_ns = np.round(truth_t * NS).astype(np.int64)

    results, sim_ms = {}, []
    for name, switches in VARIANTS.items() if args.frames > 0 else ():
        sim = base if switches is None else with_errors(base, *switches)
        tracker = PoseTracker(model, config)
        stamps, positions, quats, track_ms, points = [], [], [], [], []
        for k in range(args.frames):
            s0 = time.perf_counter()
            frame = sim.simulate_frame(k * period, trajectory, k)
            sim_ms.append(1e3 * (time.perf_counter() - s0))
            xyz = frame.truth_xyz_m if switches is None else frame.xyz_m
            mid = k * period + period / 2
            guess = None
            if k == 0:
                first = trajectory.at(np.array([k * period]))  # the first pose, as the node captures
                guess = pose_matrix(first.position_m[0], first.rotation.as_quat()[0])
            r0 = time.perf_counter()
            estimate = tracker.update(mid, xyz, guess)
            track_ms.append(1e3 * (time.perf_counter() - r0))
            points.append(estimate.points)
            if estimate.acceptable(config):
                position, quat = pose_parts(estimate.pose)
                stamps.append(round(mid * NS))
                positions.append(position)
                quats.append(quat)
        errors = tracking_errors(np.array(stamps), np.array(positions), np.array(quats), truth_ns,
                                 truth.position_m, truth.rotation.as_quat())
        results[name] = {**errors.summary(), 'registration_ms_p50': statistics.median(track_ms),
                         'registration_ms_max': max(track_ms),
                         'points_per_frame': statistics.median(points)}
        s = results[name]
        print(f'{name:9s} {s["frames"]:4d} frames  translation RMS {100 * s["trans_rms_m"]:5.1f} cm '
              f'(line of sight mean {100 * s["trans_los_mean_m"]:+5.1f} cm)  rotation RMS '
              f'{s["rot_rms_deg"]:6.2f} deg (axis {s["axis_rms_deg"]:.2f}, roll {s["roll_rms_deg"]:.2f})  '
              f'registration p50 {s["registration_ms_p50"]:.1f} ms', flush=True)
    acquisition = {}
    if args.attitudes > 0:
        acquisition = acquisition_grid(base, model, config, AcquisitionConfig(), args.attitudes, args.ranges,
                                       sim_ms)
    sim_p50 = statistics.median(sim_ms)
    doc = {'frames': args.frames, 'model_points': len(model), 'model_build_s': model_s,
           'simulate_frame_ms_p50': sim_p50,
           'registration_over_simulation': {k: v['registration_ms_p50'] / sim_p50 for k, v in results.items()},
           'tracker': config.model_dump(), 'variants': results, 'acquisition': acquisition,
           'note': 'timings on a possibly shared machine: read the ratio to simulate_frame'}
    args.out.write_text(json.dumps(doc, indent=2) + '\n')
    if acquisition:
        print(f'acquisition: {acquisition["success_rate"]:.0%} of {acquisition["cases"]} cases; '
              f'{acquisition["seconds_p50"]:.2f} s per acquisition (p50, max {acquisition["seconds_max"]:.2f} s), '
              f'{1e3 * acquisition["seconds_p50"] / sim_p50:.0f} simulated frames\' time')
    print(f'simulate_frame p50 {sim_p50:.1f} ms (baseline); model of {len(model)} points built in '
          f'{model_s:.2f} s; wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
