"""Rays the lab hides: an object between the sensor and the target (an occluder).

A pillar, a jig or a cable between the sensor and the target returns its own range on
the rays it cuts: the model's ray meets the target, the measured point lies metres in
front of it. Kept among the matched points, such returns are read as whatever the
fits can bend toward them: a material's range bias (a material mostly hidden refits to
the occluder's range), a reference-pose error, a tie of sensor effects. They are found
here once, on the model's rays before anything is fitted, and left out of the
material refit, the pose test and the diagnosis (``run.leave_out_occluded``); the
verdict and ``summary.json`` (``occlusion``) count them.

A measured point is taken as occlusion when

* its ray hits the target under the model and its measured range lies in front of the
  target's nearest modelled surface in its cloud by more than the far threshold
  (``far_returns.far_threshold_m``: max(FAR_MIN_M, FAR_SIGMAS sigma)): no range effect,
  pose error or beam footprint of the target puts a return there, while a return
  within the target's own depth span (a depth step, a silhouette under a pose error)
  is the target's business and stays;
* and it lies on a surface: at least MIN_AGREEING of its neighbouring rays in the same
  cloud measured the same range (``neighbours.isolated``, within a reach of its own
  ray spacing; the occluder's own returns off the mesh count). A single stray point short of the target is a false return
  (``solar_background``, ``sunlight``: catalogue effects) and stays.

Points far *behind* the target (multipath ghosts, a wall) are never occlusion.

Something partly transparent in front of the target (a film, a net, a curtain) gives a
multi-return receiver two returns of a shot: its own first, the target's behind it. Its
returns are occlusion as above, and the target's later return of the same shot, on the
target (within the far threshold of the model's range on its ray), is the target seen
through it (``seen_through``): kept as the shot's return, not left out as a later one.
The other returns of a shot share its direction: the neighbour test measures the ray
spacing to other rays (``neighbours.isolated``), or every such film was isolated.

A film near the target (about 1 m in front of its near surface): the cloud's nearest
modelled surface lies within the far threshold of the film, so the test above leaves
its returns in, and they were read as the target (the target's own returns behind them
left out as later returns: range biases of -40 cm, pose claims). ``veiled`` looks at
such a shot on its own ray: its later return lies on the model, its first lies in front
of the nearest modelled surface on its own and its neighbouring rays by more than the
threshold it is given (``run.leave_out_occluded``: FAR_SIGMAS sigma, without the
FAR_MIN_M floor, the shot's later return fitting the model), and on a surface; the
first is occlusion, the later the target seen through it. ``grown`` extends the film
over the neighbouring first returns at its range that lie further in front of the
model than their shot's later return lies off it (a flat film comes within a few sigma
of a curved body). A first return on the target with a later multipath echo, or a
depth step (the near edge on a neighbouring ray), is not in front of the model, and
stays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from lidar_sim_ros.compare.model import neighbours
from lidar_sim_ros.compare.model.left_out import LeftOut

MIN_AGREEING = 1       # neighbouring rays at the same range that make a surface (the rule of
                       # ``neighbours.isolated``: two false returns side by side are rare)


def occluded(range_m: np.ndarray, expected_m: np.ndarray, threshold_m: np.ndarray,
             directions: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """Bool per measured point: a return from something in front of the target (module doc).

    range_m (N,): measured ranges (m); expected_m (N,): the model's expected range on
    each ray (m, NaN where the ray misses the target); threshold_m (N,): how far in
    front of the target's nearest modelled surface a return must lie (m);
    directions (N, 3) unit, cloud (N,): for the neighbour test."""
    range_m = np.asarray(range_m, float)
    expected = np.asarray(expected_m, float)
    threshold = np.asarray(threshold_m, float)
    cloud = np.asarray(cloud)
    on_target = np.isfinite(expected) & np.isfinite(range_m)
    # The target's nearest modelled surface per cloud (one pass, whatever the clouds).
    clouds, which = np.unique(cloud, return_inverse=True)
    nearest = np.full(len(clouds), np.inf)
    np.minimum.at(nearest, which[on_target], expected[on_target])
    margin = np.nan_to_num(threshold, nan=np.inf)
    with np.errstate(invalid='ignore'):
        front = on_target & (range_m < nearest[which] - margin)
    found = np.flatnonzero(front)
    if len(found) == 0:
        return front
    out = np.zeros(len(range_m), bool)
    out[found] = ~neighbours.isolated(directions, range_m, cloud, found,
                                      min_agreeing=MIN_AGREEING, local_reach=True)
    return out


def veiled(range_m: np.ndarray, expected_m: np.ndarray, threshold_m: np.ndarray,
           shot: np.ndarray, later: np.ndarray, directions: np.ndarray,
           cloud: np.ndarray) -> np.ndarray:
    """Bool per point: a film's first return near the target (module doc, "A film near
    the target"): a return that is not ``later`` of a shot (``shot``: group id per point)
    whose later return lies on the model (within ``threshold_m`` of ``expected_m`` on its
    ray, m), while the point itself lies in front of the nearest modelled surface on its
    own and its NEIGHBOURS nearest rays of the cloud by more than ``threshold_m`` (a
    depth step's near edge is on a neighbouring ray, and stays), and on a surface
    (``neighbours.isolated``)."""
    r = np.asarray(range_m, float)
    expected = np.asarray(expected_m, float)
    shot = np.asarray(shot, np.int64)
    later = np.asarray(later, bool)
    out = np.zeros(len(r), bool)
    if len(r) == 0 or not later.any():
        return out
    margin = np.nan_to_num(np.asarray(threshold_m, float), nan=np.inf)
    with np.errstate(invalid='ignore'):
        fits = later & np.isfinite(expected) & (np.abs(r - expected) <= margin)
    behind = np.zeros(int(shot.max()) + 1, bool)
    behind[shot[fits]] = True
    cand = np.flatnonzero(~later & behind[shot] & np.isfinite(r))
    if len(cand) == 0:
        return out
    # The nearest modelled surface around the ray: its own and its neighbours' rays.
    on = np.flatnonzero(np.isfinite(expected))
    space = neighbours.search_space(directions, cloud)
    tree = cKDTree(space[on])
    k = min(neighbours.NEIGHBOURS + 1, len(on))
    _, idx = tree.query(space[cand], k=k)
    near = np.min(expected[on][np.asarray(idx).reshape(len(cand), -1)], axis=1)
    front = cand[r[cand] < near - margin[cand]]
    if len(front) == 0:
        return out
    out[front] = ~neighbours.isolated(directions, r, cloud, front,
                                      min_agreeing=MIN_AGREEING, local_reach=True)
    # How far the shot's later return lies from the model (the nearest of several).
    off = np.full(len(behind), np.inf)
    np.minimum.at(off, shot[fits], np.abs(r - expected)[fits])
    return grown(out, r, expected, off[shot], cand, directions, cloud)


FILM_GROW_STEPS = 50                    # at most this many rings of neighbours


def grown(film: np.ndarray, range_m: np.ndarray, expected_m: np.ndarray, later_off_m: np.ndarray,
          cand: np.ndarray, directions: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """``film`` grown over the first returns ``cand`` (indices: of shots whose later
    return lies on the model, ``later_off_m`` from it per point, m) that lie further in
    front of the model on their ray than their later return lies off it (the later is the
    target's) and next to a film return at the same range (``neighbours.SAME_SURFACE_M``,
    among the NEIGHBOURS nearest rays of the cloud): the film where it comes within the
    far threshold of the target's surface (a flat film before a curved body)."""
    out = np.asarray(film, bool).copy()
    r = np.asarray(range_m, float)
    with np.errstate(invalid='ignore'):
        c = cand[(r[cand] < expected_m[cand] - later_off_m[cand]) & ~out[cand]]
    if len(c) == 0 or not out.any():
        return out
    pts = np.concatenate([np.flatnonzero(out), c])
    space = neighbours.search_space(np.asarray(directions, float)[pts],
                                    np.asarray(cloud, float)[pts])
    k = min(neighbours.NEIGHBOURS + 1, len(pts))
    dist, idx = cKDTree(space).query(space[len(pts) - len(c):], k=k)
    idx = np.asarray(idx).reshape(len(c), -1)
    dist = np.asarray(dist).reshape(len(c), -1)
    gap = np.min(np.where(dist > neighbours.SAME_RAY, dist, np.inf), axis=1, keepdims=True)
    near = (dist > neighbours.SAME_RAY) & (dist <= neighbours.SPACING_REACH * gap)
    tol = np.maximum(neighbours.SAME_SURFACE_M, neighbours.SAME_SURFACE_FRACTION * r[c])
    same = near & (np.abs(r[pts][idx] - r[c][:, None]) <= tol[:, None])
    for _ in range(FILM_GROW_STEPS):
        on = out[pts][idx] & same
        new = on.any(axis=1) & ~out[c]
        if not new.any():
            break
        out[c[new]] = True
    return out


def seen_through(range_m: np.ndarray, expected_m: np.ndarray, threshold_m: np.ndarray,
                 shot: np.ndarray, occluded_: np.ndarray, later: np.ndarray) -> np.ndarray:
    """Bool per point: the target's return behind an occluder on the same shot (module
    doc): a later return (``later``) of a shot (``shot``: group id per point) whose other
    return is occluded (``occluded_``), within ``threshold_m`` of the model's range on its
    ray (``expected_m``, NaN off the target); of several in a shot, the nearest."""
    r = np.asarray(range_m, float)
    expected = np.asarray(expected_m, float)
    shot = np.asarray(shot, np.int64)
    out = np.zeros(len(r), bool)
    if len(r) == 0 or not np.any(occluded_):
        return out
    hidden = np.zeros(int(shot.max()) + 1, bool)
    hidden[shot[np.asarray(occluded_, bool)]] = True
    with np.errstate(invalid='ignore'):
        on = (np.asarray(later, bool) & np.isfinite(expected)
              & (np.abs(r - expected) <= np.nan_to_num(threshold_m, nan=-1.0)) & hidden[shot])
    idx = np.flatnonzero(on)
    idx = idx[np.lexsort((r[idx], shot[idx]))]
    first = np.ones(len(idx), bool)
    first[1:] = shot[idx[1:]] != shot[idx[:-1]]
    out[idx[first]] = True
    return out


@dataclass(frozen=True)
class Occlusion(LeftOut):
    """What was left out as occlusion (``points``: occluded returns): counts over the
    analysed points."""

    range_median_m: float | None     # the occluder's measured range
    shortfall_median_m: float | None   # how far in front of the modelled surface
    seen_through: int = 0            # of the shots, with the target's own return behind

    def as_dict(self) -> dict:
        return {**self.counts(), 'range_median_m': self.range_median_m,
                'in_front_of_target_median_m': self.shortfall_median_m,
                'target_seen_through': self.seen_through,
                'interpretation': words(self)}


def summarise(mask: np.ndarray, range_m: np.ndarray, expected_m: np.ndarray,
              cloud: np.ndarray, n_clouds: int) -> Occlusion:
    """The ``Occlusion`` of the points ``mask`` (from ``occluded``)."""
    mask = np.asarray(mask, bool)
    n = int(mask.sum())
    r = np.asarray(range_m, float)[mask]
    short = (np.asarray(expected_m, float) - np.asarray(range_m, float))[mask]
    return Occlusion(n, int(len(mask)), int(len(np.unique(np.asarray(cloud)[mask]))),
                     int(n_clouds),
                     round(float(np.median(r)), 3) if n else None,
                     round(float(np.median(short)), 3) if n else None)


def words(occ: Occlusion) -> str | None:
    """The verdict's sentence on occlusion, or None without any."""
    if occ.points == 0:
        return None
    return (f'{occ.points} returns ({100 * occ.fraction:.1f} % of the points analysed, in '
            f'{occ.clouds} of {occ.clouds_total} clouds) come from something in front of the '
            f'target: an occluding object at about {occ.range_median_m:.1f} m, '
            f'{occ.shortfall_median_m:.1f} m short of the modelled surface on the same rays '
            '(lab clutter); left out of the material refit, the pose test and the diagnosis'
            + (f'. On {occ.seen_through} of their shots the target\'s own return lies behind '
               'it as a later return of the shot, on the modelled surface: the object is '
               'partly transparent (a film, a net, a curtain), and those returns of the '
               'target are kept' if occ.seen_through else ''))
