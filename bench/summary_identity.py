"""Does a speed-up change what a compare says? Four recordings compared by two source trees,
their summary.json (less timings and paths) byte for byte, and each compare's CPU.

The recordings: a null and a range walk (``lidar-sim simulate``, the package scenario),
a reference-pose error (test/foreign_sim.py ``pose_error_rigid``) and a Cepton-layout one
(``clean_cepton``), 3 frames each. Each tree runs in its own process, with its own tree
first on PYTHONPATH; compares in-process with --no-report (the first absorbs the imports)::

    export OPENBLAS_NUM_THREADS=1
    PYTHONPATH=.:test python bench/summary_identity.py gen /tmp/ident
    PYTHONPATH=/path/to/main:/path/to/main/test python bench/summary_identity.py run /tmp/ident before
    PYTHONPATH=.:test python bench/summary_identity.py run /tmp/ident after
    python bench/summary_identity.py diff /tmp/ident before after

``diff`` exits 1 unless every summary is byte-identical.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import resource
import sys
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FOREIGN = ('pose_error_rigid', 'clean_cepton')
NAMES = ('null', 'walk', *FOREIGN)
SIMULATED = {'null': [], 'walk': ['--effect', 'range_walk={k_m: 0.015}']}
FRAMES = 3
VOLATILE = ('seconds', 'timing', 'elapsed')                   # parts of a key
PATH_KEYS = {'bag', 'mesh', 'config', 'out', 'history'}


def stripped(value):
    """The summary less what differs between two runs of the same code: timings and paths."""
    if isinstance(value, dict):
        return {k: stripped(v) for k, v in value.items()
                if k not in PATH_KEYS and not any(w in k.lower() for w in VOLATILE)}
    if isinstance(value, list):
        return [stripped(v) for v in value]
    if isinstance(value, str) and ('/tmp/' in value or str(REPO) in value):
        return '<path>'
    return value


def generate(root: Path) -> None:
    from foreign_sim import CEPTON_TOPIC, battery, generate as make
    from lidar_sim_ros.cli import main
    root.mkdir(parents=True, exist_ok=True)
    for name in FOREIGN:
        spec = replace(battery([name])[0], frames=FRAMES)
        ds = make(spec, root / name)
        argv = [str(ds.bag), '--mesh', str(ds.mesh), '--config', str(ds.scenario)]
        if spec.layout == 'cepton':
            argv += ['--cloud-topic', CEPTON_TOPIC]
        (root / name / 'argv.json').write_text(json.dumps(argv))
    for name, effects in SIMULATED.items():
        with contextlib.redirect_stdout(io.StringIO()):
            main(['simulate', str(REPO / 'config/scenario.yaml'), '--frames', str(FRAMES),
                  '--out', str(root / name), '--no-figures', *effects])
        (root / name / 'argv.json').write_text(json.dumps(
            [str(root / name / 'bag'), '--mesh', str(REPO / 'meshes/rocket_body.obj'),
             '--config', str(REPO / 'config/scenario.yaml')]))


def run(root: Path, tag: str) -> None:
    from lidar_sim_ros.cli import main
    out = root / 'out' / tag
    out.mkdir(parents=True, exist_ok=True)
    cpu = {}
    for name in NAMES:
        argv = json.loads((root / name / 'argv.json').read_text())
        before = resource.getrusage(resource.RUSAGE_SELF)
        log = io.StringIO()
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            code = main(['compare', *argv, '--out', str(out / name),
                         '--history', str(out / f'{name}_history.json'), '--no-report'])
        after = resource.getrusage(resource.RUSAGE_SELF)
        cpu[name] = round(after.ru_utime + after.ru_stime
                          - before.ru_utime - before.ru_stime, 2)
        summary = json.loads((out / name / 'summary.json').read_text())
        (out / f'{name}.json').write_text(json.dumps(stripped(summary), indent=1,
                                                     sort_keys=True))
        print(f'{tag} {name}: exit {code}, CPU {cpu[name]:.1f} s', flush=True)
    (out / 'cpu.json').write_text(json.dumps(cpu))


def diff(root: Path, a: str, b: str) -> int:
    same = True
    for name in NAMES:
        x = (root / 'out' / a / f'{name}.json').read_bytes()
        y = (root / 'out' / b / f'{name}.json').read_bytes()
        print(f'{name}: {"identical" if x == y else "DIFFERS"}')
        same &= x == y
    files = [root / 'out' / t / 'cpu.json' for t in (a, b)]
    if all(f.is_file() for f in files):
        cpu = [json.loads(f.read_text()) for f in files]
        print('CPU s ' + ', '.join(f'{n} {cpu[0][n]:.1f} -> {cpu[1][n]:.1f}' for n in NAMES))
    return 0 if same else 1


def main_() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('action', choices=('gen', 'run', 'diff'))
    p.add_argument('root', type=Path)
    p.add_argument('tags', nargs='*')
    args = p.parse_args()
    if args.action == 'gen':
        generate(args.root)
    elif args.action == 'run':
        run(args.root, args.tags[0])
    else:
        return diff(args.root, *args.tags[:2])
    return 0


if __name__ == '__main__':
    sys.exit(main_())
