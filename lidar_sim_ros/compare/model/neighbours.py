"""Which measured points have neighbours: surfaces versus isolated returns.

A false return (a background photon) lands at a random range: the rays next to it
see something else. A surface, be it the target, a wall, a jig or a cable of the lab,
is seen by neighbouring rays at nearly the same range. ``isolated`` tells the two
apart per point, so that clutter is not taken for sunlight; ``blocks`` groups points
into small angular neighbourhoods per cloud, the units whose residuals may share a
misfit (for cluster-robust standard errors).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

NEIGHBOURS = 8                 # rays looked at around each point
SPACING_REACH = 4.0            # ... within this many times the typical ray spacing
SAME_SURFACE_M = 0.2           # a neighbour this close in range (or ...
SAME_SURFACE_FRACTION = 0.02   # ... this fraction of the range) sees the same surface
BLOCKS_PER_AXIS = 12           # angular neighbourhoods per cloud, per axis of the view
SAME_RAY = 1e-6                # directions closer than this (chord of unit vectors): one ray
_CLOUD_GAP = 10.0              # separates clouds in the search space (unit vectors: |d| = 1)


def search_space(directions: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """(N, 4) points whose Euclidean neighbours are rays of the same cloud: the unit
    directions (N, 3) beside the cloud index times a gap no two unit vectors span."""
    return np.column_stack([np.asarray(directions, float),
                            _CLOUD_GAP * np.asarray(cloud, float)])


def isolated(directions: np.ndarray, range_m: np.ndarray, cloud: np.ndarray,
             query: np.ndarray, same_surface_m: np.ndarray | None = None, slope: float = 0.0,
             min_agreeing: int = 1, local_reach: bool = False) -> np.ndarray:
    """For the points ``query`` (indices): True where fewer than ``min_agreeing`` of the
    NEIGHBOURS nearest rays of the same cloud, within SPACING_REACH typical spacings,
    measured a range within max(SAME_SURFACE_M, SAME_SURFACE_FRACTION r) of the point's
    (the comparison's rule), or, if given, within ``same_surface_m`` (per query point, m)
    plus ``slope`` r theta (theta: the neighbour's angular distance, rad; ``slope`` is the
    tangent of the steepest incidence a surface may be seen at). ``local_reach``: the
    reach is SPACING_REACH times each point's own nearest-neighbour distance, not the
    query's median (a pattern whose density varies across the view: a Lissajous's rays
    crowd at its edges, and a median spacing of the crowded part leaves the sparse part's
    neighbours out of reach)."""
    query = np.asarray(query, int)
    if len(query) == 0:
        return np.zeros(0, bool)
    space = search_space(directions, cloud)
    tree = cKDTree(space)
    k = min(NEIGHBOURS + 1, len(space))
    dist, idx = tree.query(space[query], k=k)
    dist, idx = dist[:, 1:], idx[:, 1:]          # the point itself comes first
    if dist.size == 0:
        return np.ones(len(query), bool)
    # The spacing to the nearest *other* ray: another return of the same shot (a
    # multi-return receiver) shares the point's direction and says nothing of it (with
    # it, the reach fell to zero and every return with a later one was isolated).
    gap = np.min(np.where(dist > SAME_RAY, dist, np.inf), axis=1, keepdims=True)
    spacing = float(np.median(gap[np.isfinite(gap)])) if np.isfinite(gap).any() else 0.0
    reach = SPACING_REACH * max(spacing, 1e-6)
    if local_reach:
        reach = SPACING_REACH * np.maximum(np.where(np.isfinite(gap), gap, 0.0), 1e-6)
    r = np.asarray(range_m, float)
    if same_surface_m is None:
        tol = np.maximum(SAME_SURFACE_M, SAME_SURFACE_FRACTION * r[query])[:, None]
    else:
        # dist is a chord of unit vectors: the angle for the small reaches looked at.
        tol = np.asarray(same_surface_m, float)[:, None] + slope * r[query][:, None] * dist
    safe = np.minimum(idx, len(r) - 1)
    same = (dist <= reach) & (np.abs(r[safe] - r[query][:, None]) <= tol)
    return np.count_nonzero(same, axis=1) < min_agreeing


def blocks(directions: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """Block id per point: its cloud and its cell in a BLOCKS_PER_AXIS^2 grid over the
    angular extent of the points."""
    az = np.arctan2(directions[:, 1], directions[:, 0])
    el = np.arcsin(np.clip(directions[:, 2], -1.0, 1.0))

    def cell(a: np.ndarray) -> np.ndarray:
        lo, hi = np.percentile(a, [1, 99]) if len(a) else (0.0, 1.0)
        width = max(hi - lo, 1e-6) / BLOCKS_PER_AXIS
        return np.clip(((a - lo) / width).astype(int), 0, BLOCKS_PER_AXIS - 1)

    return (np.asarray(cloud, np.int64) * BLOCKS_PER_AXIS + cell(az)) * BLOCKS_PER_AXIS + cell(el)
