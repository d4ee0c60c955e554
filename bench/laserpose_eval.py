"""A constant pose along the line of sight on the rocket held tilted toward it, with the
P-60 pattern and its 24 lasers: one compare run (the diagnosis) per dataset.

    PYTHONPATH=<checkout> python bench/laserpose_eval.py --out F.json --seeds 401 402
        [--cases pose both scale pointing] [--data DIR] [--tag before]

Datasets are generated once under --data (the generator is this checkout's
test/foreign_sim.py), so before/after runs read the same recordings.
"""
from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))
sys.path.insert(0, str(REPO / 'bench'))

from foreign_sim import ForeignSpec  # noqa: E402
from posescale_eval import run_cases  # noqa: E402

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
    run_cases(CASES, ['pose', 'both', 'scale', 'pointing'], '/tmp/laserpose_data', top=5)


if __name__ == '__main__':
    main()
