"""How well does `lidar-sim compare` name hidden effects in data it has never seen?

Generates the foreign battery (test/foreign_sim.py: an independent simulator with its
own scan, target, radiometry, intensity units, time fields, effect formulas, lab
clutter, speckle and stamp conventions) into a temporary directory and walks the
comparison loop on every dataset, as a user would, through ``lidar_sim_ros.cli.main``:

    compare                                   -> names A (or null)
    compare --effect A --fit                  -> names B (or null)
    compare --effect A --effect B --fit       -> null

A dataset is right when the loop names exactly its hidden catalogue effects, one per
step, and ends with null (no phantom after the last fix); an effect outside the
catalogue must give null at once (and its feature first, when the dataset says which);
the NLL must fall at every step. One row per dataset and seed; all of it as JSON.

    python bench/hidden_effect_eval.py --out hidden_effect_eval.json
    python bench/hidden_effect_eval.py --only clean range_walk_poly --keep /tmp/foreign
    python bench/hidden_effect_eval.py --seeds 3      # each dataset with 3 seeds
    python bench/hidden_effect_eval.py --v4 --seeds 3 # issue 30's situations (ties, drifts)
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))

from foreign_loop import judge, walk_loop  # noqa: E402
from foreign_sim import V4, ForeignSpec, battery, describe, generate  # noqa: E402

def run_one(spec: ForeignSpec, root: Path, report: bool) -> dict:
    """Generate one dataset, walk the loop, distil it into a result row."""
    t0 = time.perf_counter()
    shutil.rmtree(root / spec.name, ignore_errors=True)
    ds = generate(spec, root / spec.name)
    t_gen = time.perf_counter() - t0
    steps = walk_loop(spec, ds, root / spec.name, report)
    row = {**describe(ds), 'generate_s': round(t_gen, 2), 'truth': ds.truth,
           **judge(spec, steps, ds.truth),
           'compare_s': [round(s['seconds'], 2) for s in steps]}
    row['steps'] = [{
        'effects': [e['name'] for e in s.get('fitted_effects', [])],
        'missing_effect': s.get('missing_effect'),
        'confounded_with': s.get('confounded_with'),
        'reference_pose_off': s.get('reference_pose_off'),
        'reference_pose': {k: v for k, v in (s.get('reference_pose') or {}).items()
                           if k != 'clouds'} or None,
        'pose_correction': {k: v for k, v in (s.get('pose_correction') or {}).items()
                            if k != 'clouds'} or None,
        'against_named': s.get('against_named'),
        'features': (s.get('features') or [])[:4],
        'candidates': [{k: c.get(k) for k in ('name', 'score', 'z', 'significant', 'params',
                                              'vetoed', 'error') if k in c}
                       for c in (s.get('candidates') or [])[:4]],
        'range_rmse_m': s.get('range_rmse_m'), 'nll_per_point': s.get('nll_per_point'),
        'nll_calibrated': s.get('nll_calibrated'), 'nll_per_return': s.get('nll_per_return'),
        'unmatched_fraction': s.get('unmatched_fraction'),
        'crosstalk_points': (s.get('crosstalk') or {}).get('points'),
        'later_returns': (s.get('multiple_returns') or {}).get('points'),
        'point_times': s.get('point_times'), 'verdict': s.get('verdict'),
        'scan_pattern_match': s.get('scan_pattern_match'),
        'scan_pattern_rate_error': s.get('scan_pattern_rate_error'),
        'error': s.get('error')} for s in steps]
    return row


def table(rows: list[dict]) -> str:
    head = (f'{"dataset":28s} {"hidden":30s} {"named by the loop":34s} ok  '
            f'{"top feature":16s} {"time_s":>8s}')
    lines = [head, '-' * len(head)]
    for r in rows:
        hidden = '+'.join(n for n, _ in r['hidden']) or 'none'
        named = ' > '.join(str(n) for n in r.get('named', [])) or 'ERROR'
        feats = r['steps'][0]['features'] if r['steps'] else []
        top = f'{feats[0]["name"]} {feats[0]["score"]:.3f}' if feats else '-'
        lines.append(f'{r["name"]:28s} {hidden:30s} {named:34s} '
                     f'{"yes" if r["ok"] else "NO ":3s} {top:16s} '
                     f'{sum(r["compare_s"]):8.1f}')
        if not r['ok']:
            lines.append(f'    {r["why"]}')
    n_ok = sum(r['ok'] for r in rows)
    lines.append(f'{n_ok} of {len(rows)} loops right')
    return '\n'.join(lines)


def per_dataset(rows: list[dict]) -> dict[str, str]:
    """Right loops per battery dataset over its seeds, e.g. {'clean': '3/3'}."""
    tally: dict[str, list[bool]] = defaultdict(list)
    for r in rows:
        tally[r['name'].split('@')[0]].append(bool(r['ok']))
    return {k: f'{sum(v)}/{len(v)}' for k, v in tally.items()}


def with_seed(spec: ForeignSpec, k: int) -> ForeignSpec:
    """Seed k of a dataset: another noise, pose, attitude and material jitter."""
    return spec if k == 0 else replace(spec, name=f'{spec.name}@{k}', seed=spec.seed + 1000 * k)


def main_cli(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=Path('hidden_effect_eval.json'),
                    help='JSON results (default hidden_effect_eval.json)')
    ap.add_argument('--only', nargs='*', default=None, metavar='NAME', help='dataset names')
    ap.add_argument('--keep', type=Path, default=None, metavar='DIR',
                    help='write datasets and compare outputs here instead of a temp dir')
    ap.add_argument('--report', action='store_true', help='also render report.html (slower)')
    ap.add_argument('--seeds', type=int, default=1, metavar='N',
                    help='run every dataset with N seeds (noise, pose, jitter; default 1)')
    ap.add_argument('--first-seed', type=int, default=0, metavar='K',
                    help='start at seed K (default 0)')
    ap.add_argument('--v4', action='store_true',
                    help="issue 30's situations (foreign_sim.V4, range_scale_approach and the "
                         'two ties, short_snr_noise and pose_error_rigid) instead of the battery')
    args = ap.parse_args(argv)
    names = args.only
    if args.v4:
        names = [s.name for s in V4] + ['range_scale_approach', 'short_snr_noise',
                                        'pose_error_rigid'] + list(names or [])
    specs = [with_seed(s, k) for k in range(args.first_seed, args.first_seed + args.seeds)
             for s in battery(names)]
    rows = []
    with tempfile.TemporaryDirectory(prefix='foreign_') as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        for spec in specs:
            row = run_one(spec, root, args.report)
            rows.append(row)
            print(f'{spec.name}: hidden {[n for n, _ in spec.hidden]}, loop named '
                  f'{row.get("named")} -> {"right" if row["ok"] else "WRONG: " + row["why"]} '
                  f'({sum(row["compare_s"]):.1f} s)', flush=True)
            args.out.write_text(json.dumps({'per_dataset': per_dataset(rows), 'rows': rows},
                                           indent=2, default=str) + '\n')
    print()
    print(table(rows))
    tally = per_dataset(rows)
    print('right per dataset: ' + ', '.join(f'{k} {v}' for k, v in tally.items()))
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main_cli())
