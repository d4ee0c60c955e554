#!/usr/bin/env python3
"""The beam footprint's cone test alone, on the inputs of real all-effects frames.

Runs ``--frames`` frames of the all-effects scenario, records every call of the cone
test (``silhouette.cones_touching_edges``: the frame's rays, the candidate segments,
each ray's depth limit), then times the compiled kernel on those inputs in CPU time
(``time.process_time``; the least disturbed by other jobs). ``--against FILE`` loads a
second copy of ``core/silhouette.py`` (e.g. the code before a change, from ``git show
HEAD:lidar_sim_ros/core/silhouette.py``), checks that both give the same mask on every
call, and alternates the two, repeat by repeat, so that both see the same load.

    python bench/bench_cone.py [--frames 10] [--repeats 7] [--against old_silhouette.py]
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from lidar_sim_ros.core import silhouette
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.effects import beam_divergence
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.paths import config_path


def record_cone_inputs(scenario_path: Path, frames: int) -> list[tuple]:
    """The kernel's arguments (o, d, tan_a, a, b, limit) of every cone test in ``frames``
    frames of the scenario, with the mask each call returned."""
    calls = []
    original = beam_divergence.cones_touching_edges

    def spy(o, d, tan_a, a, b, limit):
        mask = original(o, d, tan_a, a, b, limit)
        calls.append((np.ascontiguousarray(o), np.ascontiguousarray(d), float(tan_a),
                      np.ascontiguousarray(a, dtype=np.float64),
                      np.ascontiguousarray(b, dtype=np.float64),
                      np.ascontiguousarray(limit, dtype=np.float64), mask.copy()))
        return mask

    scenario = load_scenario(scenario_path)
    sim = Simulator.from_scenario(scenario)
    traj = ScenarioTrajectory.from_config(scenario.config)
    beam_divergence.cones_touching_edges = spy
    try:
        for i in range(frames):
            sim.simulate_frame(i * sim.frame_period_s, traj, i)
    finally:
        beam_divergence.cones_touching_edges = original
    return calls


def load_kernel(path: Path):
    """``_cones_touching_edges`` of another copy of silhouette.py."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module        # dataclasses look their module up
    spec.loader.exec_module(module)
    return module._cones_touching_edges


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scenario', type=Path, default=config_path('scenario_all_effects.yaml'))
    parser.add_argument('--frames', type=int, default=10)
    parser.add_argument('--repeats', type=int, default=7, help='timed passes over all calls')
    parser.add_argument('--against', type=Path, help='another silhouette.py to compare with')
    parser.add_argument('--out', type=Path, help='JSON output file')
    args = parser.parse_args()

    calls = record_cone_inputs(args.scenario, args.frames)
    kernels = {'current': silhouette._cones_touching_edges}
    if args.against:
        kernels['against'] = load_kernel(args.against)
    for name, kernel in kernels.items():
        for *inputs, mask in calls:
            if not np.array_equal(kernel(*inputs), mask):
                raise SystemExit(f'{name}: the cone test differs from the frame\'s on a call')
    ms = {name: [] for name in kernels}
    for _ in range(args.repeats):
        for name, kernel in kernels.items():
            t0 = time.process_time()
            for *inputs, _mask in calls:
                kernel(*inputs)
            ms[name].append((time.process_time() - t0) / len(calls) * 1e3)
    result = {
        'calls': len(calls),
        'rays_per_call': statistics.mean(len(c[0]) for c in calls),
        'segments_per_call': statistics.mean(len(c[3]) for c in calls),
        'rays_touching_per_call': statistics.mean(int(c[-1].sum()) for c in calls),
        'cpu_ms_per_call': {name: statistics.median(v) for name, v in ms.items()},
        'cpu_ms_per_call_runs': ms,
    }
    print(f"{result['calls']} calls, {result['rays_per_call']:.0f} rays, "
          f"{result['segments_per_call']:.0f} segments, "
          f"{result['rays_touching_per_call']:.0f} rays touching an edge per call")
    for name, v in ms.items():
        print(f'{name}: {statistics.median(v):.3f} ms CPU per call (median of {len(v)}; '
              f'{min(v):.3f}-{max(v):.3f})')
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
