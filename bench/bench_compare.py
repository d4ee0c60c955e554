"""How long `lidar-sim compare` takes and how much memory it needs.

Two recordings of the default scenario with a range walk hidden in them, made once by
``lidar-sim simulate`` (kept under ``--data``): 12 frames (~190 000 points) and one
minute (600 frames, ~9 million points, subsampled by compare to --max-points). Each
comparison runs in a fresh process (its own peak RSS), with the report. Writes JSON:
``total_s`` and ``peak_rss_mb`` at the top level for the one-minute recording, and per
recording the seconds of every stage (``stage_seconds``).

    python bench/bench_compare.py --out bench_compare.json
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RECORDINGS = {'frames_12': 12, 'minute_600': 600}
EFFECT = 'range_walk={k_m: 0.015}'


def make_recording(data: Path, name: str, frames: int) -> Path:
    bag = data / name / 'bag'
    if not bag.exists():
        subprocess.run([sys.executable, '-m', 'lidar_sim_ros.cli', 'simulate',
                        str(REPO / 'config' / 'scenario.yaml'), '--frames', str(frames),
                        '--out', str(data / name), '--no-figures', '--effect', EFFECT],
                       check=True, stdout=subprocess.DEVNULL)
    return bag


def child(bag: str, out: str) -> None:
    """One comparison in this process; prints its figures as JSON."""
    from lidar_sim_ros.compare.run import CompareOptions, run_compare
    t0 = time.perf_counter()
    result = run_compare(CompareOptions(bag=Path(bag), mesh=REPO / 'meshes' / 'rocket_body.obj',
                                        out=Path(out)))
    s = result.summary
    use = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({
        'total_s': round(time.perf_counter() - t0, 2),
        # CPU seconds of the process: on a machine shared with other jobs the wall
        # clock says more about the neighbours than about compare.
        'cpu_s': round(use.ru_utime + use.ru_stime, 2),
        'peak_rss_mb': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        'points_in_bag': s['points'], 'points_analysed': s['points_analysed'],
        'stage_seconds': s['stage_seconds'], 'missing_effect': s['missing_effect']}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench_compare.json'))
    ap.add_argument('--data', type=Path, default=Path('bench_compare_data'),
                    help='where the recordings are made once and kept')
    ap.add_argument('--child', nargs=2, metavar=('BAG', 'OUT'), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(*args.child)
        return 0
    results = {}
    for name, frames in RECORDINGS.items():
        bag = make_recording(args.data, name, frames)
        run = subprocess.run([sys.executable, __file__, '--child', str(bag),
                              str(args.data / name / 'compare')],
                             check=True, capture_output=True, text=True)
        results[name] = {'frames': frames, **json.loads(run.stdout.strip().splitlines()[-1])}
        print(f'{name}: {results[name]["total_s"]} s, {results[name]["peak_rss_mb"]} MB, '
              f'missing effect {results[name]["missing_effect"]}', flush=True)
    longest = results['minute_600']
    doc = {'total_s': longest['total_s'], 'cpu_s': longest['cpu_s'],
           'peak_rss_mb': longest['peak_rss_mb'],
           'note': 'wall-clock seconds on this machine (shared machines disturb them)',
           'recordings': results}
    args.out.write_text(json.dumps(doc, indent=2) + '\n')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
