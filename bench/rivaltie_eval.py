"""An incidence bias beside a rival the rule keeps from naming: one compare run (the
diagnosis) per dataset, the pose exact.

    PYTHONPATH=<checkout> python bench/rivaltie_eval.py --out F.json --seeds 701 702
        [--cases law_drum law_box g_box] [--data DIR] [--tag before]

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
from foreign_sim import ForeignDataset, ForeignSpec, battery, generate  # noqa: E402

HOLD = dict(frames=8, distance_m=10.0, speed_mps=0.0, spin_dps=4.0, precession_dps=1.0,
            shots_per_frame=12_000)
LAW = {'law': 'range_sin', 'g': -3.5, 'a': 0.5, 'sigma_frac': 0.15}
CASES = {
    # The incidence law of foreign_sim.INCIDENCE_LAW on the rocket-like drum and the box.
    'law_drum': ForeignSpec('rt_law_drum', 'incidence_angle', {**LAW, 'a': 0.8, 'g': -3.0},
                            intensity='reflectivity', lasers=4, bus_shape='drum', **HOLD),
    'law_box': ForeignSpec('rt_law_box', 'incidence_angle', LAW, intensity='linear',
                           fins=True, **HOLD),
    'law_drum_weak': ForeignSpec('rt_law_drum_weak', 'incidence_angle',
                                 {**LAW, 'a': 0.8, 'g': -1.0}, intensity='reflectivity',
                                 lasers=4, bus_shape='drum', **HOLD),
    'law_drum_far': ForeignSpec('rt_law_drum_far', 'incidence_angle',
                                {**LAW, 'a': 0.8, 'g': -3.0}, intensity='reflectivity',
                                lasers=4, bus_shape='drum', **{**HOLD, 'distance_m': 18.0}),
    'law_drum_far_weak': ForeignSpec('rt_law_drum_far_weak', 'incidence_angle',
                                     {**LAW, 'a': 0.8, 'g': -1.0}, intensity='reflectivity',
                                     lasers=4, bus_shape='drum',
                                     **{**HOLD, 'distance_m': 18.0}),
    'law_drum_mid_weak': ForeignSpec('rt_law_drum_mid_weak', 'incidence_angle',
                                     {**LAW, 'a': 0.8, 'g': -1.5}, intensity='reflectivity',
                                     lasers=4, bus_shape='drum',
                                     **{**HOLD, 'distance_m': 14.0}),
    'g_drum': ForeignSpec('rt_g_drum', 'incidence_angle', {'g_m': 0.012, 'h': 0.4},
                          intensity='counts16', bus_shape='drum', **HOLD),
    # The battery's footprint, incidence bias and false returns (on main, seed 21: the
    # footprint withheld beside incidence).
    'bsi': battery(['beam_solar_incid'])[0],
    # The battery's short_incidence law on a hold.
    'g_box': ForeignSpec('rt_g_box', 'incidence_angle', {'g_m': 0.015, 'h': 0.5},
                         intensity='counts8', **{**HOLD, 'frames': 10, 'spin_dps': 3.0,
                                                 'shots_per_frame': 8000}),
}


def row(summary: dict) -> dict:
    """The decision and the figures behind it."""
    cands = [{k: c.get(k) for k in ('name', 'score', 'z', 'significant', 'params', 'vetoed')
              if k in c} for c in (summary.get('candidates') or [])[:6]]
    return {'missing_effect': summary.get('missing_effect'),
            'confounded_with': summary.get('confounded_with'),
            'reference_pose_off': summary.get('reference_pose_off'),
            'withheld': summary.get('withheld'),
            'held_beside': summary.get('held_beside'),
            'candidates': cands, 'verdict': summary.get('verdict'),
            'error': summary.get('error'), 'seconds': round(summary.get('seconds', 0), 1),
            'total_seconds': summary.get('total_seconds')}


def own_snr(seed: int, root: Path) -> dict:
    """test_compare.py's SNR dataset (our own simulator: snr_noise c_m 0.3, exponent 0.7;
    there seed 103, snr_noise withheld beside incidence_angle), one compare run."""
    import time

    from datasets import make_dataset

    from lidar_sim_ros.compare.run import CompareOptions, run_compare
    from lidar_sim_ros.core.effects import make_effect
    data = root / 'data'
    ds = make_dataset(data, 'snr', [make_effect('snr_noise', {'c_m': 0.3, 'exponent': 0.7})],
                      seed=seed)
    t0 = time.perf_counter()
    s = run_compare(CompareOptions(bag=ds.bag, mesh=ds.mesh, out=root / 'cmp', config=ds.scenario,
                                   report=False)).summary
    return {**s, 'seconds': time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--out', required=True)
    ap.add_argument('--seeds', type=int, nargs='+', required=True)
    ap.add_argument('--cases', nargs='+', default=list(CASES))  # and snr_own
    ap.add_argument('--data', default='/tmp/rivaltie_data')
    ap.add_argument('--tag', default='run')
    a = ap.parse_args()
    out = {}
    for seed in a.seeds:
        for case in a.cases:
            if case == 'snr_own':
                s = own_snr(seed, Path(a.data) / f'snr_own_{seed}_{a.tag}')
            else:
                spec = replace(CASES[case], seed=seed)
                root = Path(a.data) / f'{spec.name}_{seed}'
                data = root / 'data'
                ds = (ForeignDataset(spec, data / 'bag', data / 'satellite.obj',
                                     data / 'scenario.yaml', 0, {})
                      if (data / 'scenario.yaml').is_file() else generate(spec, data))
                s = compare_once(ds, root / f'cmp_{a.tag}', root / f'hist_{a.tag}.json', [],
                                 False)
            out[f'{case}_{seed}'] = r = {**row(s), 'full': s}
            print(case, seed, r['missing_effect'], r['confounded_with'],
                  r['reference_pose_off'], list((r['withheld'] or {}).keys()),
                  [(c['name'], c.get('score'), c.get('z')) for c in r['candidates'][:4]],
                  r['seconds'], flush=True)
            Path(a.out).write_text(json.dumps(out, indent=1, default=str))


if __name__ == '__main__':
    main()
