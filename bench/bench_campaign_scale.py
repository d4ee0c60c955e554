#!/usr/bin/env python3
"""Campaign engine at scale (`make bench-campaign` writes bench_campaign_scale.json).

The client's (main process's) peak resident memory for campaigns of very short runs
(one frame of a 16-shot sensor on the rocket body, ``save: stats``), each in a fresh
process on a local cluster of ``--workers`` workers: memory must stay flat in the
number of runs (runs are submitted as they go, a bounded number in flight, and the
manifest keeps one status byte per run). Also: seconds from the call to the first
manifest row (cluster, workers' preparation, the first run) and to the end, runs per
second, and how many Dask tasks carried the runs (short runs go several to a task); then
the time and memory of judging the runs (``summary.summarize_frames``: two criteria, a
pass rate, the metric-against-dispersion figure). The
local cluster's scheduler lives in the main process, so its memory is counted too.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
SENSOR = {'type': 'rotating', 'elevations_deg': [0.0], 'az_min_deg': -5.0, 'az_max_deg': 5.0,
          'shots_per_beam': 16}


# Judged at the end (summary.summarize_frames: criteria.csv and vs_dispersions.png from the
# manifest, read row by row): its time and the client's peak memory after it are measured too.
CRITERIA = ['points >= 8', 'range_error_mean_m > -0.14']


def write_campaign(tmp: Path, runs: int) -> Path:
    """A campaign of ``runs`` one-frame runs on a 16-shot sensor."""
    sensor = yaml.safe_load((ROOT / 'config' / 'cepton_vista_p60.yaml').read_text())
    sensor['scan'] = SENSOR
    (tmp / 'sensor.yaml').write_text(yaml.safe_dump(sensor))
    scenario = yaml.safe_load((ROOT / 'config' / 'scenario.yaml').read_text())
    scenario.update(sensor=str(tmp / 'sensor.yaml'), materials=str(ROOT / 'config' / 'materials.yaml'),
                    mesh=str(ROOT / 'meshes' / 'rocket_body.obj'), effects=[])
    (tmp / 'scenario.yaml').write_text(yaml.safe_dump(scenario))
    path = tmp / 'campaign.yaml'
    path.write_text(yaml.safe_dump({
        'scenario': str(tmp / 'scenario.yaml'), 'seed': 1, 'runs': runs, 'duration_s': 0.1,
        'save': 'stats', 'coverage_frames': 0, 'criteria': CRITERIA,
        'dispersions': {'initial_distance_m': {'dist': 'uniform', 'low': 8.0, 'high': 25.0}}}))
    return path


def one(runs: int, workers: int) -> None:
    """In a fresh process: run the campaign, print what it cost as JSON."""
    sys.path.insert(0, str(ROOT))
    from lidar_sim_ros.campaign.engine import run_campaign
    from lidar_sim_ros.campaign.spec import load_campaign
    tmp = Path(tempfile.mkdtemp(prefix='bench_campaign_scale_'))
    try:
        campaign = load_campaign(write_campaign(tmp, runs))
        t0 = time.perf_counter()
        report = run_campaign(campaign, tmp / 'out', workers=workers, progress=False)
        wall = time.perf_counter() - t0
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        from lidar_sim_ros.campaign.summary import summarize_frames
        t1 = time.perf_counter()
        summary = summarize_frames(tmp / 'out', campaign)
        print(json.dumps({'runs': runs, 'ok': report.ok, 'failed': report.failed,
                          'peak_rss_mb': peak_mb, 'summary_s': time.perf_counter() - t1,
                          'peak_rss_after_summary_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                          'pass_rate': summary.verdicts[-1]['pass_rate'],
                          'first_row_s': report.startup_s, 'wall_s': wall, 'tasks': report.tasks,
                          'runs_per_s': report.ran / report.wall_s if report.wall_s else None,
                          'load_avg_1min': os.getloadavg()[0]}))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, nargs='+', default=[1000, 100_000])
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--out', type=Path, default=None, help='JSON file to write')
    ap.add_argument('--one', type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        one(args.one, args.workers)
        return
    results = []
    for runs in args.runs:
        proc = subprocess.run([sys.executable, __file__, '--one', str(runs), '--workers',
                               str(args.workers)], capture_output=True, text=True, cwd=ROOT)
        if proc.returncode:
            sys.exit(f'{runs} runs failed:\n{proc.stderr[-2000:]}')
        result = json.loads(proc.stdout.strip().splitlines()[-1])
        results.append(result)
        print(f"{runs:>7} runs: client peak RSS {result['peak_rss_mb']:.0f} MB "
              f"({result['peak_rss_after_summary_mb']:.0f} MB after the criteria's summary, "
              f"{result['summary_s']:.1f} s), "
              f"{result['runs_per_s']:.0f} runs/s, {result['wall_s']:.0f} s "
              f"(first row after {result['first_row_s']:.1f} s, {result['tasks']} tasks, "
              f"load {result['load_avg_1min']:.1f})", flush=True)
    out = {'workers': args.workers, 'results': results,
           'peak_rss_growth_mb': results[-1]['peak_rss_mb'] - results[0]['peak_rss_mb']}
    if args.out:
        args.out.write_text(json.dumps(out, indent=2) + '\n')


if __name__ == '__main__':
    main()
