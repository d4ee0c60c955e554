"""Points between the target's edge and a surface behind it: mixed pixels.

A receiver that averages the echoes of a footprint straddling the target's edge and a
surface farther along (a lab wall, clutter) reports one range between the two: a
point off the target model that no catalogue effect places (the catalogue's footprint
sees the target only: its mixed ranges lie between two of the target's surfaces). Such
a recording reads as a footprint many times the configured beam whose fit raises the
range RMSE (``diagnosis.rmse_fault``); these figures say where the points lie.

``between_edge_and_behind``: of the points off the model (the model's ray misses the
target, or the measured range lies GAP_M beyond the model's) at the target's edge (a
return of the target, a matched point, among the rays within NEIGHBOUR_RAD), those with
such a return nearer by GAP_M and at least MIN_BEHIND returns off the target farther by
GAP_M. Ranges in m, angles in rad.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from lidar_sim_ros.compare.diagnose.candidate import MIN_SHARE, MIN_UNMATCHED_EXPLAINED

GAP_M = 0.15            # beyond range noise (cm) and the target's sub-footprint relief
NEIGHBOUR_RAD = 0.01    # rays this close see the edge and the surface behind it
MIN_BEHIND = 2          # farther off-target returns: a surface, not one false return
MIN_POINTS = MIN_UNMATCHED_EXPLAINED   # fewer points between say nothing
# MIN_SHARE (the share veto's): the least share of the off-model points at the edge


def off_model(range_m: np.ndarray, matched: np.ndarray,
              model_range_m: np.ndarray) -> np.ndarray:
    """bool (N,): unmatched, or measured more than GAP_M beyond the model's range."""
    model = np.where(np.isfinite(model_range_m), model_range_m, np.inf)
    return ~matched | (range_m > model + GAP_M)


def between_edge_and_behind(directions: np.ndarray, range_m: np.ndarray,
                            matched: np.ndarray, model_range_m: np.ndarray) -> dict:
    """{'off_model': points off the model at the target's edge, 'between': those between
    the edge and a surface behind it, 'share': between / off_model, 'behind_m': median
    distance of that surface beyond the edge (NaN if none)}. ``directions`` (N, 3) unit,
    ``matched`` bool (N,), ``model_range_m`` (N,) NaN/inf where the model's ray misses."""
    idx = np.flatnonzero(off_model(range_m, matched, model_range_m))
    out = {'off_model': 0, 'between': 0, 'share': 0.0, 'behind_m': float('nan')}
    if len(idx) == 0 or not matched.any():
        return out
    # At the target's edge: a matched point among the rays within NEIGHBOUR_RAD (the
    # others, the wall or clutter far off, are most of them on a lab recording).
    edge = cKDTree(directions[matched]).query_ball_point(
        directions[idx], NEIGHBOUR_RAD, return_length=True) > 0
    idx = idx[edge]
    at_edge = len(idx)
    tree = cKDTree(directions)
    between, behind = [], []
    for i, nb in zip(idx, tree.query_ball_point(directions[idx], NEIGHBOUR_RAD)):
        nb = np.asarray(nb, int)
        near = range_m[nb[matched[nb]]]
        far = range_m[nb[~matched[nb]]]
        r = range_m[i]
        if near.min() > r - GAP_M:
            continue
        farther = far[far > r + GAP_M]
        if len(farther) < MIN_BEHIND:
            continue
        between.append(i)
        behind.append(float(np.median(farther) - near.min()))
    out['off_model'] = at_edge
    out['between'] = len(between)
    out['share'] = float(len(between) / max(at_edge, 1))
    if behind:
        out['behind_m'] = float(np.median(behind))
    return out


def shown(figures: dict | None) -> bool:
    """Whether the data show points between an edge and a surface behind it."""
    return bool(figures and figures.get('between', 0) >= MIN_POINTS
                and figures.get('share', 0.0) >= MIN_SHARE)


def words(figures: dict) -> str:
    """The sentence a verdict says where ``shown``."""
    return (f' Of the {figures["off_model"]} points off the model, {figures["between"]} '
            f'({100 * figures["share"]:.0f} %) lie between the target\'s edge and a surface '
            f'about {figures["behind_m"]:.1f} m farther along neighbouring rays (returns off '
            'the target: the clutter or background behind it): mixed pixels, a receiver '
            'averaging the echoes of the edge and what is behind it. That is outside the '
            'catalogue (its footprint sees the target only); leave those points unmatched '
            'or write an effect for it (docs/effects.md, "Write your own effect").')
