#!/usr/bin/env python3
"""How fast the in-process closed loop runs against real time, per stage (no DDS).

Runs ``loop.step.loop_step`` for ``--seconds`` of simulated time (after a warm-up
period) on the loop config's scenario (every effect, config/loop.yaml) and reports the
real-time factor and the median time per period of each stage: propagate (Basilisk and
the truth samples), sense (the simulator's frame), estimate (the tracker), and the rest.
The machine may be shared: read the ratios.

    python bench/bench_loop.py [--seconds 10] [--cloud model] [--out bench_loop.json]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from lidar_sim_ros.loop import step
from lidar_sim_ros.loop.config import load_loop_config
from lidar_sim_ros.paths import config_path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=10.0)
    parser.add_argument('--cloud', default='model', choices=['model', 'truth'])
    parser.add_argument('--config', type=Path, default=config_path('loop.yaml'))
    parser.add_argument('--out', type=Path, default=None)
    args = parser.parse_args()
    config, scenario = load_loop_config(args.config)
    ctx = step.build_context(config, scenario, args.cloud)
    state = step.LoopState()
    for _ in range(3):  # the first frames compile or load the kernels
        state, _ = step.loop_step(ctx, state)
    times = {'propagate': [], 'sense+estimate': [], 'navigate+guide+control': [], 'period': []}
    n = int(round(args.seconds / config.control_period_s))
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(n):
        t0 = time.perf_counter()
        truth = step.propagate(config, ctx.dynamics, state.force_lvlh_n, ctx.R_BL, ctx.t_B)
        t1 = time.perf_counter()
        t_mid = float(0.5 * (truth.t_s[0] + truth.t_s[-1]))
        est, _, _ = step.estimate_pose(ctx, state, truth, t_mid)
        t2 = time.perf_counter()
        nav, _ = step.navigate(ctx, state.nav, truth, t_mid, est)
        g, _, force = step.guide_and_control(config, nav, state.guidance, float(truth.t_s[-1]), truth.n_rad_s)
        state = step.LoopState(force, nav, g, truth, state.frame_index + 1, est is not None,
                               est if est is not None else state.last_estimate)
        t3 = time.perf_counter()
        for key, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2, t3 - t0)):
            times[key].append(dt)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    result = {'simulated_s': n * config.control_period_s, 'wall_s': wall, 'cpu_s': cpu,
              'real_time_factor': n * config.control_period_s / wall,
              'cpu_real_time_factor': n * config.control_period_s / cpu, 'cloud': args.cloud,
              'load_average': os.getloadavg(), 'cores': os.cpu_count(),
              'median_ms': {k: 1000 * statistics.median(v) for k, v in times.items()},
              'acquisition_s': getattr(getattr(ctx.tracker, 'last_acquisition', None), 'seconds', None)}
    print(json.dumps(result, indent=2))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
