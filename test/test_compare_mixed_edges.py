"""Points between the target's edge and a surface behind it (compare/diagnose/
mixed_edges.py), on hand-made rays: a plate's edge at 11 m with a wall at 15 m behind
it. Mixed pixels (ranges between the two) are counted; a footprint's edge returns (at
the plate's range, beyond its silhouette) and mixed ranges across a depth step of the
target itself (its farther surface matched) are not."""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.compare.diagnose import mixed_edges as me


def _scene(kind: str, n: int = 60):
    """Rays on a 1-D fan across the plate's edge (angle 0): plate (matched, 11 m) for
    angle < 0, wall (unmatched, 15 m) beyond; ``kind`` adds n rays at the edge."""
    rng = np.random.default_rng(3)
    ang = np.linspace(-0.03, 0.03, 121)
    on = ang < 0
    r = np.where(on, 11.0, 15.0) + rng.normal(0, 0.01, len(ang))
    matched = on.copy()
    model = np.where(on, 11.0, np.nan)
    extra = rng.uniform(-0.002, 0.002, n)
    if kind == 'mixed':          # averaged echoes: between the plate and the wall
        er, em, emod = rng.uniform(11.6, 14.4, n), np.zeros(n, bool), np.full(n, np.nan)
    elif kind == 'footprint':    # the catalogue's footprint: beyond the silhouette, 11 m
        er, em, emod = 11.0 + rng.normal(0, 0.01, n), np.zeros(n, bool), np.full(n, np.nan)
    else:                        # 'step': the wall is the target's own surface (matched)
        matched = np.ones(len(ang), bool)
        model = np.where(on, 11.0, 15.0)
        er, em, emod = rng.uniform(11.6, 14.4, n), np.ones(n, bool), np.full(n, 11.0)
    a = np.concatenate([ang, extra])
    d = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    return (d, np.concatenate([r, er]), np.concatenate([matched, em]),
            np.concatenate([model, emod]))


def test_mixed_pixels_lie_between_the_edge_and_the_wall():
    f = me.between_edge_and_behind(*_scene('mixed'))
    assert f['between'] == 60 and me.shown(f)
    assert 3.0 < f['behind_m'] < 4.5


def test_a_footprint_edge_and_a_depth_step_of_the_target_are_not_mixed_pixels():
    for kind in ('footprint', 'step'):
        f = me.between_edge_and_behind(*_scene(kind))
        assert f['between'] == 0 and not me.shown(f), kind
