#!/usr/bin/env python3
"""How fast the in-process closed loop runs against real time, per stage (no DDS).

Runs the stages of ``loop.step.loop_step`` for ``--seconds`` of simulated time (after a
warm-up period) on the loop config's scenario (every effect, config/loop.yaml) and
reports the real-time factor (wall and CPU) and the CPU and wall time per period of
each stage: propagate (Basilisk and the truth samples), sense (the simulator's frame),
estimate (the gate and the tracker), and navigate + guide + control. CPU time
(``time.process_time``) is what the other jobs on a shared machine disturb least; the
wall-clock ratio is the one a user sees. The first ``--seconds`` hold at 30 m; 150 runs
the whole approach in to 8 m, where the frames hold more points.

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
    stages = ('propagate', 'sense', 'estimate', 'navigate+guide+control')
    cpu_ms = {k: [] for k in (*stages, 'period')}
    wall_ms = {k: [] for k in (*stages, 'period')}
    n = int(round(args.seconds / config.control_period_s))
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(n):
        marks = [(time.perf_counter(), time.process_time())]
        truth = step.propagate(config, ctx.dynamics, state.force_lvlh_n, ctx.mount_true, ctx.t_B)
        marks.append((time.perf_counter(), time.process_time()))
        t_mid = float(0.5 * (truth.t_s[0] + truth.t_s[-1]))
        true_pose = step._pose_at(truth, state.previous, t_mid)
        xyz = step.sense_period(ctx, state, truth)
        marks.append((time.perf_counter(), time.process_time()))
        est, _ = step.estimate(ctx, state, xyz, t_mid, true_pose)
        marks.append((time.perf_counter(), time.process_time()))
        nav, _ = step.navigate(ctx, state.nav, truth, t_mid, est)
        g, _, force = step.guide_and_control(config, nav, state.guidance, float(truth.t_s[-1]), truth.n_rad_s)
        state = step.next_state(state, truth, nav, g, force, est)
        marks.append((time.perf_counter(), time.process_time()))
        for key, (w0, c0), (w1, c1) in zip(stages, marks, marks[1:]):
            wall_ms[key].append(1000 * (w1 - w0))
            cpu_ms[key].append(1000 * (c1 - c0))
        wall_ms['period'].append(1000 * (marks[-1][0] - marks[0][0]))
        cpu_ms['period'].append(1000 * (marks[-1][1] - marks[0][1]))
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    result = {'simulated_s': n * config.control_period_s, 'wall_s': wall, 'cpu_s': cpu,
              'real_time_factor': n * config.control_period_s / wall,
              'cpu_real_time_factor': n * config.control_period_s / cpu, 'cloud': args.cloud,
              'load_average': os.getloadavg(), 'cores': os.cpu_count(),
              'cpu_ms_mean': {k: statistics.fmean(v) for k, v in cpu_ms.items()},
              'cpu_ms_median': {k: statistics.median(v) for k, v in cpu_ms.items()},
              'wall_ms_median': {k: statistics.median(v) for k, v in wall_ms.items()},
              'acquisition_s': getattr(getattr(ctx.tracker, 'last_acquisition', None), 'seconds', None)}
    print(json.dumps(result, indent=2))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
