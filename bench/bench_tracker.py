#!/usr/bin/env python3
"""What each LiDAR error costs the pose tracker, and how long a registration takes (offline).

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

    python bench/bench_tracker.py [--frames 100] [--out bench_tracker.json]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from lidar_sim_ros.core.config import MaterialsConfig, load_scenario
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.gnc.evaluate import tracking_errors
from lidar_sim_ros.gnc.tracker import PoseTracker, TrackerConfig, build_model, pose_matrix, pose_parts
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=100)
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
    for name, switches in VARIANTS.items():
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
    sim_p50 = statistics.median(sim_ms)
    doc = {'frames': args.frames, 'model_points': len(model), 'model_build_s': model_s,
           'simulate_frame_ms_p50': sim_p50,
           'registration_over_simulation': {k: v['registration_ms_p50'] / sim_p50 for k, v in results.items()},
           'tracker': config.model_dump(), 'variants': results,
           'note': 'timings on a possibly shared machine: read the ratio to simulate_frame'}
    args.out.write_text(json.dumps(doc, indent=2) + '\n')
    print(f'simulate_frame p50 {sim_p50:.1f} ms (baseline); model of {len(model)} points built in '
          f'{model_s:.2f} s; wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
