#!/usr/bin/env python3
"""Benchmark of the campaign engine (`make bench-campaign` writes bench_campaign.json).

The same campaign (config/campaign_example.yaml's dispersions, ``--runs`` runs of
``--duration-s``) runs on a local Dask cluster of 1 worker and of 2 workers, each
cluster started and prepared (mesh + kernels on every worker) before the clock starts.
Per configuration, the best of ``--repeats`` (a shared machine only ever slows a run
down):

* ``frames_per_s``: frames of all runs / wall time from the first submit to the last
  manifest row;
* ``speedup_2_workers``: frames/s on 2 workers over frames/s on 1 (target >= 1.7);
* ``overhead_per_run_fraction``: on 1 worker, (wall - sum of the runs' compute) / sum
  of compute, i.e. what the engine adds per run (scheduling, transfer, manifest row)
  as a fraction of the run's own compute (target < 5 %). One worker has no idle tail,
  so the figure is the engine's cost alone; ``parallel_efficiency`` (2 workers: sum of
  compute / (2 x wall)) adds the tail where one worker waits for the other's last run;
* start-up (cluster + preparing the workers), worker memory, load average before and
  after (the machine is shared: a load above ~0.5 at the start disturbs the figures),
  and ``cpu_share_of_compute``: the runs' CPU time over their wall time on the workers;
  below 1 a run waited for a core that something else held.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
TARGET_SPEEDUP = 1.7
TARGET_OVERHEAD = 0.05


def bench_campaign_file(tmp: Path, runs: int, duration_s: float) -> Path:
    """The example campaign with this benchmark's run count and duration."""
    spec = yaml.safe_load((ROOT / 'config' / 'campaign_example.yaml').read_text())
    spec.update(runs=runs, duration_s=duration_s, scenario=str(ROOT / 'config' / 'scenario.yaml'))
    path = tmp / 'bench_campaign.yaml'
    path.write_text(yaml.safe_dump(spec))
    return path


def worker_rss_mb() -> float:
    import psutil
    return psutil.Process().memory_info().rss / 2**20


def measure(campaign, workers: int, repeats: int, tmp: Path) -> dict:
    from dask.distributed import Client, LocalCluster

    from lidar_sim_ros.campaign.engine import run_campaign
    from lidar_sim_ros.campaign.run import prepare_worker
    t0 = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        cluster_s = time.perf_counter() - t0
        client.run(prepare_worker, campaign)
        startup_s = time.perf_counter() - t0
        best = None
        for k in range(repeats):
            out = tmp / f'out_{workers}_{k}'
            report = run_campaign(campaign, out, address=cluster.scheduler_address, progress=False)
            if report.failed:
                raise RuntimeError(f'{report.failed} runs failed; see {report.manifest_path}')
            with report.manifest_path.open(newline='') as fh:
                cpu_s = sum(float(row['cpu_s']) for row in csv.DictReader(fh))
            shutil.rmtree(out)
            if best is None or report.wall_s < best[0].wall_s:
                best = report, cpu_s
        rss = client.run(worker_rss_mb)
    best, cpu_s = best
    frames = best.ran * campaign.frames_per_run
    return {
        'workers': workers, 'runs': best.ran, 'frames': frames,
        'wall_s': round(best.wall_s, 3), 'compute_s': round(best.compute_s, 3),
        'frames_per_s': round(frames / best.wall_s, 2),
        'compute_per_run_s': round(best.compute_s / best.ran, 4),
        'cpu_per_run_s': round(cpu_s / best.ran, 4),
        'cpu_share_of_compute': round(cpu_s / best.compute_s, 3),
        'overhead_per_run_fraction': round((workers * best.wall_s - best.compute_s) / best.compute_s, 4),
        'parallel_efficiency': round(best.compute_s / (workers * best.wall_s), 3),
        'cluster_start_s': round(cluster_s, 2), 'startup_s': round(startup_s, 2),
        'worker_rss_mb': [round(v, 1) for v in rss.values()],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', type=Path, default=Path('bench_campaign.json'))
    parser.add_argument('--runs', type=int, default=32)
    parser.add_argument('--duration-s', type=float, default=2.0)
    parser.add_argument('--repeats', type=int, default=2)
    args = parser.parse_args()

    from lidar_sim_ros.campaign.spec import load_campaign
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix='bench_campaign_') as tmp_name:
        tmp = Path(tmp_name)
        campaign = load_campaign(bench_campaign_file(tmp, args.runs, args.duration_s))
        one = measure(campaign, 1, args.repeats, tmp)
        two = measure(campaign, 2, args.repeats, tmp)
    load_after = os.getloadavg()
    speedup = two['frames_per_s'] / one['frames_per_s']
    result = {
        'engine': 'dask.distributed LocalCluster, 1 thread per worker process',
        'campaign': f'config/campaign_example.yaml dispersions, {args.runs} runs x '
                    f'{campaign.frames_per_run} frames, best of {args.repeats}',
        'frames_per_s_1_worker': one['frames_per_s'],
        'frames_per_s_2_workers': two['frames_per_s'],
        'speedup_2_workers': round(speedup, 3),
        'overhead_per_run_fraction': one['overhead_per_run_fraction'],
        'targets': {'speedup_2_workers': f'>= {TARGET_SPEEDUP}',
                    'overhead_per_run_fraction': f'< {TARGET_OVERHEAD}'},
        'met': {'speedup_2_workers': speedup >= TARGET_SPEEDUP,
                'overhead_per_run_fraction': one['overhead_per_run_fraction'] < TARGET_OVERHEAD},
        'one_worker': one, 'two_workers': two,
        'load_average_before': [round(v, 2) for v in load_before],
        'load_average_after': [round(v, 2) for v in load_after],
        'machine': {'cpus': os.cpu_count(), 'python': platform.python_version(),
                    'platform': platform.platform()},
    }
    args.out.write_text(json.dumps(result, indent=2) + '\n')
    print(f'1 worker : {one["frames_per_s"]:.1f} frames/s ({one["compute_per_run_s"] * 1e3:.0f} ms '
          f'compute per run, overhead {100 * one["overhead_per_run_fraction"]:.1f} % of it)')
    print(f'2 workers: {two["frames_per_s"]:.1f} frames/s, speedup {speedup:.2f} '
          f'(target >= {TARGET_SPEEDUP}), parallel efficiency {two["parallel_efficiency"]:.2f}')
    print(f'start-up: {one["startup_s"]:.1f} s (1 worker), {two["startup_s"]:.1f} s (2 workers); '
          f'worker RSS {two["worker_rss_mb"]} MB')
    print(f'load average before {result["load_average_before"][0]}, after '
          f'{result["load_average_after"][0]} (shared machine: figures above ~0.5 are disturbed)')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
