"""A constant pose along the line of sight on the rocket held tilted toward it, with the
P-60 pattern and its 24 lasers: one compare run (the diagnosis) per dataset.

    PYTHONPATH=<checkout> python bench/laserpose_eval.py --out F.json --seeds 401 402
        [--cases pose both scale pointing] [--data DIR] [--tag before]

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
sys.path.insert(0, str(REPO / 'bench'))

from foreign_loop import compare_once  # noqa: E402
from foreign_sim import ForeignDataset, ForeignSpec, generate  # noqa: E402
from posescale_eval import row  # noqa: E402

HOLD = dict(frames=10, speed_mps=0.0, spin_dps=3.0, precession_dps=0.0, distance_m=7.0,
            scan='lissajous', lasers=24, tilt_deg=35.0, bus_shape='drum')
LOS = (0.06, 0.0, 0.0)
CASES = {
    'pose': ForeignSpec('lp_pose', None, pose_offset_m=LOS, **HOLD),
    'both': ForeignSpec('lp_both', 'range_scale', {'ppm': 10000.0}, pose_offset_m=LOS, **HOLD),
    'scale': ForeignSpec('lp_scale', 'range_scale', {'ppm': 10000.0}, **HOLD),
    'pointing': ForeignSpec('lp_pointing', 'laser_pointing', {'sd_deg': 0.15}, **HOLD),
    # Nearer (the lab's points centred ~6 m away): a larger perspective for the same 6 cm.
    'pose6': ForeignSpec('lp_pose6', None, pose_offset_m=LOS, **{**HOLD, 'distance_m': 6.3}),
    'both6': ForeignSpec('lp_both6', 'range_scale', {'ppm': 10000.0}, pose_offset_m=LOS,
                         **{**HOLD, 'distance_m': 6.3}),
    'pointing_pose': ForeignSpec('lp_pointing_pose', 'laser_pointing', {'sd_deg': 0.15},
                                 pose_offset_m=LOS, **HOLD),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--out', required=True)
    ap.add_argument('--seeds', type=int, nargs='+', required=True)
    ap.add_argument('--cases', nargs='+', default=['pose', 'both', 'scale', 'pointing'])
    ap.add_argument('--data', default='/tmp/laserpose_data')
    ap.add_argument('--tag', default='run')
    a = ap.parse_args()
    out = {}
    for seed in a.seeds:
        for case in a.cases:
            spec = replace(CASES[case], seed=seed)
            root = Path(a.data) / f'{spec.name}_{seed}'
            data = root / 'data'
            ds = (ForeignDataset(spec, data / 'bag', data / 'satellite.obj',
                                 data / 'scenario.yaml', 0, {})
                  if (data / 'scenario.yaml').is_file() else generate(spec, data))
            s = compare_once(ds, root / f'cmp_{a.tag}', root / f'hist_{a.tag}.json', [], False)
            out[f'{case}_{seed}'] = r = {**row(s), 'full': s}
            print(case, seed, r['missing_effect'], r['confounded_with'],
                  r['reference_pose_off'], [(c['name'], c.get('score'), c.get('z'),
                                             c.get('params')) for c in r['candidates'][:5]],
                  r['seconds'], flush=True)
            Path(a.out).write_text(json.dumps(out, indent=1, default=str))


if __name__ == '__main__':
    main()
