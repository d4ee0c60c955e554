"""How well does `lidar-sim compare` name a hidden effect in data it has never seen?

Generates the foreign battery (test/foreign_sim.py: an independent simulator with its
own scan, target, radiometry, intensity units, time fields and effect formulas) into
a temporary directory, runs ``lidar-sim compare`` on every dataset through
``lidar_sim_ros.cli.main`` and prints one row per dataset: hidden effect, what compare
expected/found, top feature, top candidate, range RMSE, NLL, time. Writes all of it,
plus each summary's features and candidates, as JSON.

    python bench/hidden_effect_eval.py --out hidden_effect_eval.json
    python bench/hidden_effect_eval.py --only clean range_walk_poly --keep /tmp/foreign
    python bench/hidden_effect_eval.py --seeds 3      # each dataset with 3 seeds (~15 min)
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))

from foreign_sim import battery, describe, generate  # noqa: E402

from lidar_sim_ros.cli import main  # noqa: E402


def run_one(spec, root: Path, report: bool) -> dict:
    """Generate one dataset, compare it, and distil summary.json into a result row."""
    t0 = time.perf_counter()
    ds = generate(spec, root / spec.name)
    t_gen = time.perf_counter() - t0
    out = root / spec.name / 'compare'
    argv = ['compare', str(ds.bag), '--mesh', str(ds.mesh), '--config', str(ds.scenario),
            '--out', str(out), '--history', str(root / spec.name / 'history.json')]
    if not report:
        argv.append('--no-report')
    log = io.StringIO()
    t1 = time.perf_counter()
    with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        try:
            code = main(argv)
        except Exception as exc:  # noqa: BLE001 - a crash is a result too
            code, log = -1, io.StringIO(f'{type(exc).__name__}: {exc}')
    t_cmp = time.perf_counter() - t1
    row = {**describe(ds), 'generate_s': round(t_gen, 2), 'compare_s': round(t_cmp, 2),
           'exit_code': code, 'truth': ds.truth}
    summary_path = out / 'summary.json'
    if code != 0 or not summary_path.is_file():
        row.update(found='ERROR', ok=False, error=log.getvalue()[-2000:])
        return row
    s = json.loads(summary_path.read_text())
    feats, cands = s.get('features', []), s.get('candidates', [])
    row.update({
        'found': s.get('missing_effect'),
        'ok': s.get('missing_effect') == spec.expected_effect,
        'top_feature': feats[0] if feats else None,
        'top_candidate': cands[0] if cands else None,
        'features': feats,
        'candidates': [{k: c.get(k) for k in ('name', 'score', 'z', 'significant', 'params',
                                              'range_rmse_after_m', 'nll_after',
                                              'unmatched_explained', 'error') if k in c}
                       for c in cands],
        'range_rmse_m': s.get('range_rmse_m'), 'nll_per_point': s.get('nll_per_point'),
        'unmatched_fraction': s.get('unmatched_fraction'),
        'point_times': s.get('point_times'), 'has_intensity': s.get('has_intensity'),
        'materials_flagged': [k for k, m in s.get('materials', {}).items()
                              if m.get('bias_mismatch') or m.get('sigma_mismatch')],
        'verdict': s.get('verdict'), 'notes': s.get('notes'),
    })
    return row


def _fmt(x, spec: str) -> str:
    return format(x, spec) if isinstance(x, (int, float)) else '-'


def table(rows: list[dict]) -> str:
    head = (f'{"dataset":24s} {"hidden":17s} {"found":17s} ok  {"top feature":18s} '
            f'{"top candidate (score)":28s} {"rmse_m":>7s} {"nll":>7s} {"unm%":>5s} '
            f'{"pts":>6s} {"time_s":>6s}')
    lines = [head, '-' * len(head)]
    for r in rows:
        tf = r.get('top_feature') or {}
        tc = r.get('top_candidate') or {}
        unm = r.get('unmatched_fraction')
        lines.append(
            f'{r["name"]:24s} {str(r["effect"]):17s} {str(r["found"]):17s} '
            f'{"yes" if r["ok"] else "NO ":3s} '
            f'{(tf.get("name", "-") + " " + _fmt(tf.get("score"), ".3f")):18s} '
            f'{(tc.get("name", "-") + " " + _fmt(tc.get("score"), ".4f")):28s} '
            f'{_fmt(r.get("range_rmse_m"), "7.4f")} {_fmt(r.get("nll_per_point"), "7.3f")} '
            f'{_fmt(None if unm is None else 100 * unm, "5.1f")} '
            f'{r["points"]:6d} {r["compare_s"]:6.1f}')
    n_ok = sum(r['ok'] for r in rows)
    lines.append(f'{n_ok} of {len(rows)} verdicts right')
    return '\n'.join(lines)


def per_dataset(rows: list[dict]) -> dict[str, str]:
    """Right verdicts per battery dataset over its seeds, e.g. {'clean': '3/3'}."""
    tally: dict[str, list[bool]] = defaultdict(list)
    for r in rows:
        tally[r['name'].split('@')[0]].append(bool(r['ok']))
    return {k: f'{sum(v)}/{len(v)}' for k, v in tally.items()}


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
    args = ap.parse_args(argv)
    specs = [s if k == 0 else replace(s, name=f'{s.name}@{k}', seed=s.seed + 1000 * k)
             for k in range(args.seeds) for s in battery(args.only)]
    rows = []
    with tempfile.TemporaryDirectory(prefix='foreign_') as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        for spec in specs:
            row = run_one(spec, root, args.report)
            rows.append(row)
            print(f'{spec.name}: hidden {spec.effect}, found {row["found"]} '
                  f'({row["compare_s"]:.1f} s)', flush=True)
    print()
    print(table(rows))
    tally = per_dataset(rows)
    if args.seeds > 1:
        print('right per dataset: ' + ', '.join(f'{k} {v}' for k, v in tally.items()))
    args.out.write_text(json.dumps({'per_dataset': tally, 'rows': rows}, indent=2,
                                   default=str) + '\n')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main_cli())
