"""A range walk on the true received power beside per-laser range offsets, intensity
compensated for range and partly for a Lambertian incidence law (reflectivity_lambert):
the foreign reproduction of issue 30's walk_laser_graze runs, walked through the loop.

    python bench/walk_graze_eval.py --out F.json --runs 1:0.02:0.7 2:0.01:1.0
    (each run seed:laser_sd_m:q; --keep DIR keeps each dataset and its compare outputs)
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'bench'))
sys.path.insert(0, str(REPO / 'test'))

from foreign_sim import ForeignSpec  # noqa: E402
from hidden_effect_eval import run_one  # noqa: E402


def graze_spec(seed: int, sd_m: float, q: float) -> ForeignSpec:
    """Walk -0.035 ln(P / 1 uW) plus 4 lasers' offsets of sd ``sd_m``, 8 clouds at 10.5 m."""
    return ForeignSpec(f'walk_graze_s{seed}', 'range_walk', {'form': 'ln', 'g_m': 0.035},
                       seed=seed, also=(('laser_bias', {'sd_m': sd_m}),), lasers=4,
                       frames=8, distance_m=10.5, shots_per_frame=12_000,
                       intensity='reflectivity_lambert', intensity_cos_exponent=q)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument('--out', type=Path, required=True)
    ap.add_argument('--runs', nargs='+', required=True, metavar='SEED:SD:Q')
    ap.add_argument('--keep', type=Path, default=None, metavar='DIR',
                    help='write datasets and compare outputs here instead of a temp dir')
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if a.keep is not None:
            a.keep.mkdir(parents=True, exist_ok=True)
            tmp = str(a.keep)
        for run in a.runs:
            s, sd, q = run.split(':')
            row = run_one(graze_spec(int(s), float(sd), float(q)), Path(tmp), False)
            row['sd_m'], row['q'] = float(sd), float(q)
            rows.append(row)
            print(row['name'], sd, q, row.get('named'), row.get('ok'), flush=True)
            a.out.write_text(json.dumps(rows, indent=1, default=str))
    return 0


if __name__ == '__main__':
    sys.exit(main())
