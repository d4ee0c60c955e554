"""A range scale beside a constant pose along the line of sight, on a body tilted toward
the line of sight on a hold: one compare run (the diagnosis) per dataset.

    PYTHONPATH=<checkout> python bench/posescale_eval.py --out F.json --seeds 301 302
        [--cases both scale offset box_both] [--data DIR]

Datasets are generated once under --data (the generator is this checkout's
test/foreign_sim.py), so before/after runs read the same recordings.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))

from foreign_loop import compare_once  # noqa: E402
from foreign_sim import ForeignDataset, ForeignSpec, generate  # noqa: E402

HOLD = dict(frames=10, speed_mps=0.0, spin_dps=3.0, precession_dps=0.0, distance_m=9.0,
            shots_per_frame=8000, lasers=6, tilt_deg=35.0, bus_shape='drum')
SCALE = {'ppm': 10000.0}
CASES = {
    'both': ForeignSpec('ps_both', 'range_scale', SCALE, pose_offset_m=(0.06, 0.0, 0.0), **HOLD),
    'scale': ForeignSpec('ps_scale', 'range_scale', SCALE, **HOLD),
    'offset': ForeignSpec('ps_offset', None, pose_offset_m=(0.06, 0.0, 0.0), **HOLD),
    'both_near': ForeignSpec('ps_both_near', 'range_scale', SCALE,
                             pose_offset_m=(-0.06, 0.0, 0.0), **HOLD),
    'both_az': ForeignSpec('ps_both_az', 'range_scale', SCALE, pose_offset_m=(0.06, 0.0, 0.0),
                           **{**HOLD, 'tilt_from': 'y'}),
    'scale_az': ForeignSpec('ps_scale_az', 'range_scale', SCALE, **{**HOLD, 'tilt_from': 'y'}),
    'box_both': ForeignSpec('ps_box_both', 'range_scale', SCALE, pose_offset_m=(0.06, 0.0, 0.0),
                            **{**HOLD, 'bus_shape': 'box'}),
}


def row(summary: dict) -> dict:
    """The decision and the figures behind it."""
    cands = [{k: c.get(k) for k in ('name', 'score', 'z', 'significant', 'params', 'vetoed')
              if k in c} for c in (summary.get('candidates') or [])[:6]]
    return {'missing_effect': summary.get('missing_effect'),
            'confounded_with': summary.get('confounded_with'),
            'reference_pose_off': summary.get('reference_pose_off'),
            'reference_pose': {k: v for k, v in (summary.get('reference_pose') or {}).items()
                               if k != 'clouds'} or None,
            'candidates': cands, 'verdict': summary.get('verdict'),
            'error': summary.get('error'), 'seconds': round(summary.get('seconds', 0), 1)}


def run_cases(cases: dict, default_cases: list[str], default_data: str,
              top: int = 4) -> None:
    """The command line of a case runner: each of ``--cases`` (keys of ``cases``,
    ForeignSpecs) at each of ``--seeds``, its recording generated once under ``--data``,
    compared once (the diagnosis); the rows to ``--out`` (JSON) as they come."""
    ap = argparse.ArgumentParser()
    ap.add_argument('--out', required=True)
    ap.add_argument('--seeds', type=int, nargs='+', required=True)
    ap.add_argument('--cases', nargs='+', default=default_cases)
    ap.add_argument('--data', default=default_data)
    ap.add_argument('--tag', default='run')
    a = ap.parse_args()
    out = {}
    for seed in a.seeds:
        for case in a.cases:
            spec = replace(cases[case], seed=seed)
            root = Path(a.data) / f'{spec.name}_{seed}'
            data = root / 'data'
            ds = (ForeignDataset(spec, data / 'bag', data / 'satellite.obj',
                                 data / 'scenario.yaml', 0, {})
                  if (data / 'scenario.yaml').is_file() else generate(spec, data))
            s = compare_once(ds, root / f'cmp_{a.tag}', root / f'hist_{a.tag}.json', [], False)
            out[f'{case}_{seed}'] = r = {**row(s), 'full': s}
            print(case, seed, r['missing_effect'], r['confounded_with'],
                  r['reference_pose_off'], [(c['name'], c.get('score'), c.get('z'),
                                             c.get('params')) for c in r['candidates'][:top]],
                  r['seconds'], flush=True)
            Path(a.out).write_text(json.dumps(out, indent=1, default=str))


def main() -> None:
    run_cases(CASES, ['both', 'scale', 'offset', 'box_both'], '/tmp/posescale_data')


if __name__ == '__main__':
    main()
