"""What the separation plan of a tie (``compare/diagnose/plan.py``) adds to `lidar-sim compare`.

The two ties of the foreign battery (``test/foreign_sim.py``: ``short_range_walk_speckle``,
``short_snr_noise``; seed 0) are generated once under ``--data``; each is compared in a
fresh process with and without the plan (``--no-plan``), ``--repeat`` times each, without
the report. CPU seconds of the whole process are the fair figure on a shared machine
(the wall clock is mostly the neighbours'). Writes JSON: per dataset the CPU seconds of
each run with and without, their medians, the ratio, the plan stage's own seconds, and
which recording the plan chose.

    python bench/bench_compare_plan.py --out bench_compare_plan.json
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))

DATASETS = ('short_range_walk_speckle', 'short_snr_noise')


def child(data: str, out: str, plan: str) -> None:
    """One comparison in this process; prints its figures as JSON."""
    from lidar_sim_ros.compare.run import CompareOptions, run_compare
    d = Path(data)
    s = run_compare(CompareOptions(d / 'bag', d / 'satellite.obj', Path(out), d / 'scenario.yaml',
                                   report=False, progress=False, plan=plan == 'plan')).summary
    use = resource.getrusage(resource.RUSAGE_SELF)
    best = (s.get('separation_plan') or [{}])[0]
    print(json.dumps({'cpu_s': round(use.ru_utime + use.ru_stime, 2),
                      'plan_s': s['stage_seconds'].get('plan'),
                      'confounded_with': s['confounded_with'],
                      'plan_best': best.get('recording'), 'plan_separates': best.get('separates'),
                      'recordings_flown': len(s.get('separation_plan') or [])}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench_compare_plan.json'))
    ap.add_argument('--data', type=Path, default=Path('bench_compare_plan_data'),
                    help='where the datasets are made once and kept')
    ap.add_argument('--repeat', type=int, default=2)
    ap.add_argument('--child', nargs=3, metavar=('DATA', 'OUT', 'PLAN'), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(*args.child)
        return 0
    from foreign_sim import battery, generate
    doc = {}
    for name in DATASETS:
        data = args.data / name
        if not (data / 'bag').exists():
            generate(battery([name])[0], data)
        runs: dict[str, list[dict]] = {'plan': [], 'no_plan': []}
        for _ in range(args.repeat):
            for mode in runs:
                out = subprocess.run([sys.executable, __file__, '--child', str(data),
                                      str(data / f'compare_{mode}'), mode.replace('no_', 'no-')],
                                     check=True, capture_output=True, text=True)
                runs[mode].append(json.loads(out.stdout.strip().splitlines()[-1]))
        med = {m: sorted(r['cpu_s'] for r in rs)[len(rs) // 2] for m, rs in runs.items()}
        doc[name] = {'cpu_s_plan': [r['cpu_s'] for r in runs['plan']],
                     'cpu_s_no_plan': [r['cpu_s'] for r in runs['no_plan']],
                     'median_ratio': round(med['plan'] / med['no_plan'], 3),
                     'plan_stage_s': [r['plan_s'] for r in runs['plan']],
                     **{k: runs['plan'][0][k] for k in ('confounded_with', 'plan_best',
                                                         'plan_separates', 'recordings_flown')}}
        print(f'{name}: CPU {med["no_plan"]} s -> {med["plan"]} s with the plan '
              f'(x{doc[name]["median_ratio"]}); best {doc[name]["plan_best"]}', flush=True)
    args.out.write_text(json.dumps(doc, indent=2) + '\n')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
