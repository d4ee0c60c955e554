#!/usr/bin/env python3
"""Peak memory of `lidar-sim compare` with a 2-million-triangle mesh (issue 22, part 3).

Makes, once, under ``--data``: the rocket body at ``--segments`` circumferential
segments (``tools/make_rocket_mesh.py``; 850 gives 2 023 052 triangles) and a
``--frames``-frame recording of the default scenario (``lidar-sim simulate``). Then runs
``lidar-sim compare RECORDING --mesh BIG.obj`` (every candidate, the report) in a child
process and reads its peak RSS from the kernel (``getrusage(RUSAGE_CHILDREN)``, the same
figure as ``/usr/bin/time -v``'s "Maximum resident set size"). Writes JSON with
``peak_rss_mb``, ``wall_s``, ``cpu_s``, the triangle count and the candidates' scores
(``summary.json``), so that a change can be checked to move memory and not the scores.

    python bench/bench_big_mesh.py --out bench_big_mesh.json      # ~3 min on an idle machine
    make bench-big-mesh

Target (issue 22): peak RSS under 2 GB.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TARGET_PEAK_MB = 2048.0


def make_inputs(data: Path, segments: int, frames: int) -> tuple[Path, Path]:
    """The big mesh and the recording, made once (kept between runs)."""
    data.mkdir(parents=True, exist_ok=True)
    mesh = data / f'rocket_{segments}.obj'
    if not mesh.exists():
        subprocess.run([sys.executable, str(REPO / 'tools' / 'make_rocket_mesh.py'),
                        '--segments', str(segments), '--out', str(mesh.with_suffix(''))],
                       check=True, stdout=subprocess.DEVNULL)
    recording = data / f'frames_{frames}'
    if not (recording / 'bag').exists():
        subprocess.run([sys.executable, '-m', 'lidar_sim_ros.cli', 'simulate',
                        str(REPO / 'config' / 'scenario.yaml'), '--frames', str(frames),
                        '--out', str(recording), '--no-figures'],
                       check=True, stdout=subprocess.DEVNULL)
    return mesh, recording / 'bag'


def triangles(obj: Path) -> int:
    with obj.open('rb') as f:
        return sum(1 for line in f if line.startswith(b'f '))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench_big_mesh.json'))
    ap.add_argument('--data', type=Path, default=Path('bench_big_mesh_data'),
                    help='where the mesh and the recording are made once and kept')
    ap.add_argument('--segments', type=int, default=850,
                    help='rocket mesh segments (default 850: 2 023 052 triangles)')
    ap.add_argument('--frames', type=int, default=3, help='frames in the recording (default 3)')
    args = ap.parse_args(argv)

    mesh, bag = make_inputs(args.data, args.segments, args.frames)
    out_dir = args.data / 'compare'
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, '-m', 'lidar_sim_ros.cli', 'compare', str(bag),
                           '--mesh', str(mesh), '--out', str(out_dir)],
                          capture_output=True, text=True, env=dict(os.environ))
    wall = time.perf_counter() - t0
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        print(proc.stdout[-2000:], proc.stderr[-2000:], sep='\n', file=sys.stderr)
        return proc.returncode
    summary = json.loads((out_dir / 'summary.json').read_text())
    result = {
        'mesh': str(mesh), 'triangles': triangles(mesh), 'recording_frames': args.frames,
        # The largest child's peak: the compare run (the mesh and recording makers are smaller).
        'peak_rss_mb': round(use.ru_maxrss / 1024, 1),
        'wall_s': round(wall, 1),
        'cpu_s': round(use.ru_utime + use.ru_stime - before.ru_utime - before.ru_stime, 1),
        'target_peak_mb': TARGET_PEAK_MB,
        'candidate_scores': [{k: c.get(k) for k in ('name', 'score', 'params')}
                             for c in summary.get('candidates') or []],
        'missing_effect': summary.get('missing_effect'),
        'stage_seconds': summary.get('stage_seconds'),
    }
    ok = result['peak_rss_mb'] <= TARGET_PEAK_MB
    print(f"compare with {result['triangles']} triangles against {args.frames} frames: peak RSS "
          f"{result['peak_rss_mb']:.0f} MB [target <= {TARGET_PEAK_MB:.0f}: "
          f"{'ok' if ok else 'MISSED'}], {result['wall_s']:.0f} s wall, {result['cpu_s']:.0f} s CPU")
    args.out.write_text(json.dumps(result, indent=2) + '\n')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
