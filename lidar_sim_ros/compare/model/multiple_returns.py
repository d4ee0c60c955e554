"""Later returns of one shot (a multi-return receiver): found before anything is fitted.

A dual- or multi-return receiver reports more than one return of a shot: its first
(or strongest) echo, and a later one where the footprint spans a depth step, a
multipath ghost, or an echo leaked from another channel (crosstalk). The model casts
one echo per shot and the likelihood scores one return per ray, so a shot's later
returns are left out of the fit (``run.leave_out_occluded``, beside occlusion and
crosstalk), counted in ``summary.json`` (``multiple_returns``) and said in the notes
as what they are: later returns of the same shot, not ghosts of another laser.

Which returns are later:

* the recording gives a return index (``fields.RETURN_FIELDS``, or the Cepton
  SECOND_RETURN flag): every point whose index is above the recording's smallest
  (0 or 1, as its convention counts) is a later return, as the sensor says, whether
  or not its shot's first return is among the points;
* otherwise, when the recording gives per-point times (a field: times taken from the
  configured scan pattern give two nearby shots the time of the one nearest shot, 52
  points of holdout 9's ``null_notime_100``, so they tell nothing here):
  returns of one shot share the cloud, the laser, the point time (within the time
  field's resolution, ``Measurements.time_quantum_s``) and the direction (within
  SAME_DIRECTION_RAD: a flash array's pixels share a time but not a direction); of
  such a group the nearest is the first return (what a first-return receiver reports)
  and the others are later;
* without either, nothing can be told: the summary says so.

The model has later returns of its own: the catalogue's multipath adds a ghost on a
shot's line of sight behind a specular surface (``likelihood.ghosts_on``). The later
returns within ``likelihood.UNMATCHED_Z`` ghost sigmas of the ghost the model casts on
their ray (``at_ghost_range``) are counted (``at_model_ghost``) and said, but left out
like the rest: a depth step just past a grazing edge gives the same range (the mirror
ray of a grazing hit runs on nearly straight to the surface behind), and the
likelihood scores one return per ray, so it cannot tell them apart. Kept, they named a
phantom multipath on the battery's ``dual_return`` seed 1 (196 of its 329 depth-step
returns at the model's ghost), as main did keeping every later return; left out, our
simulator's dual-return box-wing with multipath (all 947 later returns at the ghost)
is an honest miss whose notes point at multipath.

For the later returns whose shot's first return is among the points, the range behind
it is reported (percentiles): depth steps within the footprint give a spread of a few
decimetres to metres, crosstalk a fixed delay (``crosstalk.py`` looks for that among
these very returns first, and the later returns it names are counted there).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.model.left_out import LeftOut

SAME_DIRECTION_RAD = 2e-4    # two returns of one shot lie along one direction (the
                             # scan-pattern match tolerance; float32 x, y, z keep 1e-7)


@dataclass(frozen=True)
class MultipleReturns(LeftOut):
    """Later returns of a shot left out of the fit (``points``), over the analysed points."""

    source: str | None = None            # how they were told: a field, a flag, shared times
    shots: int = 0                       # shots with a later return among the points
    with_first: int = 0                  # later returns whose first return is a point too
    behind_first_m: list | None = None   # range behind the first return, p5/p50/p95 (m)
    lasers: int = 0                      # lasers with a later return
    crosstalk: int = 0                   # later returns named crosstalk ghosts instead
    at_model_ghost: int = 0              # of them, at the model's multipath ghost range
    looked: bool = True
    why_not: str | None = None

    def as_dict(self) -> dict:
        return {**self.counts(), 'source': self.source, 'shots': self.shots,
                'with_first_return': self.with_first,
                'range_behind_first_p5_p50_p95_m': self.behind_first_m,
                'lasers': self.lasers, 'crosstalk_among_them': self.crosstalk,
                'at_model_multipath_ghost': self.at_model_ghost,
                'looked': self.looked, 'why_not': self.why_not, 'interpretation': words(self)}


def shot_groups(t_frame_s: np.ndarray, cloud: np.ndarray, laser: np.ndarray,
                directions: np.ndarray, quantum_s: float) -> np.ndarray:
    """A group id per point: the points of one shot (module doc) share it. ``t_frame_s``
    (N,) s since the cloud stamp; ``quantum_s``: the times' resolution (s)."""
    n = len(t_frame_s)
    if n == 0:
        return np.zeros(0, np.int64)
    step = max(float(quantum_s), 1e-12)
    t_bin = np.round(np.asarray(t_frame_s, float) / step).astype(np.int64)
    d = np.asarray(directions, float)
    cell = np.round(d / SAME_DIRECTION_RAD).astype(np.int64)
    order = np.lexsort((cell[:, 2], cell[:, 1], cell[:, 0], t_bin, np.asarray(laser),
                        np.asarray(cloud)))
    c, la, tb = np.asarray(cloud)[order], np.asarray(laser)[order], t_bin[order]
    ds = d[order]
    same = np.zeros(n, bool)
    cos_tol = np.cos(SAME_DIRECTION_RAD)
    same[1:] = ((c[1:] == c[:-1]) & (la[1:] == la[:-1]) & (np.abs(tb[1:] - tb[:-1]) <= 1)
                & (np.sum(ds[1:] * ds[:-1], axis=1) >= cos_tol))
    group = np.empty(n, np.int64)
    group[order] = np.cumsum(~same) - 1
    return group


def later_returns(range_m: np.ndarray, t_frame_s: np.ndarray, cloud: np.ndarray,
                  laser: np.ndarray, directions: np.ndarray, return_index: np.ndarray | None,
                  has_point_time: bool, quantum_s: float, source: str | None,
                  exclude: np.ndarray | None = None) -> tuple[np.ndarray, MultipleReturns]:
    """Bool per point: a later return of its shot (module doc), and the counts.

    range_m (N,) m; t_frame_s (N,) s since the cloud stamp; cloud, laser (N,);
    directions (N, 3) unit; return_index (N,) int or None; ``source``: the return
    field's name (or the flag) when ``return_index`` is given; ``exclude`` (N,) bool:
    points already left out (crosstalk ghosts): counted apart, not as later returns."""
    r = np.asarray(range_m, float)
    n = len(r)
    cloud = np.asarray(cloud)
    n_clouds = len(np.unique(cloud)) if n else 0
    none = np.zeros(n, bool)
    exclude = none if exclude is None else np.asarray(exclude, bool)
    if return_index is None and not has_point_time:
        return none, MultipleReturns(0, n, 0, n_clouds, looked=False, why_not=(
            'the recording carries neither a return index nor a per-point time field: two '
            'returns of one shot cannot be told from two shots'))
    group = (shot_groups(t_frame_s, cloud, laser, directions, quantum_s) if has_point_time
             else None)
    if return_index is not None:
        idx = np.asarray(return_index, np.int64)
        later = idx > (int(idx.min()) if n else 0)
        how = source
    else:
        # The nearest return of each shot is its first; the others are later (the points
        # already left out take no part: a ghost nearer than its shot's echo leaves the
        # echo the first).
        keep = np.flatnonzero(~exclude)
        order = keep[np.lexsort((r[keep], group[keep]))]
        g = group[order]
        first_in = np.ones(len(order), bool)
        first_in[1:] = g[1:] != g[:-1]
        later = np.zeros(n, bool)
        later[order] = ~first_in
        how = 'shared shot time, laser and direction'
    if return_index is not None:
        xt = later & exclude
    else:
        # The ghosts left out that share their shot with another return.
        size = np.bincount(group, minlength=int(group.max()) + 1 if n else 0)
        xt = exclude & (size[group] > 1)
    later &= ~exclude
    behind, with_first, shots = None, 0, 0
    if group is not None and later.any():
        # The first return of each shot: the nearest of its points that are not later.
        best = np.full(int(group.max()) + 1, np.inf)
        np.minimum.at(best, group[~later & ~exclude], r[~later & ~exclude])
        ref = best[group[later]]
        have = np.isfinite(ref)
        with_first = int(have.sum())
        if have.any():
            behind = [round(float(v), 3)
                      for v in np.percentile(r[later][have] - ref[have], [5, 50, 95])]
        shots = int(len(np.unique(group[later])))
    elif later.any():
        shots = int(later.sum())
    return later, MultipleReturns(
        int(later.sum()), n, int(len(np.unique(cloud[later]))), n_clouds, source=how,
        shots=shots, with_first=with_first, behind_first_m=behind,
        lasers=int(len(np.unique(np.asarray(laser)[later]))), crosstalk=int(xt.sum()))


def at_ghost_range(range_m: np.ndarray, ghost_index: np.ndarray, ghost_range_m: np.ndarray,
                   ghost_sigma_m: np.ndarray, z_max: float) -> np.ndarray:
    """Bool per point: its range within ``z_max`` sigmas of the ghost the model casts on
    its ray. ghost_index (K,): the rays (indices into ``range_m``) with a ghost; its range
    (m, material bias included) and sigma (m)."""
    r = np.asarray(range_m, float)
    out = np.zeros(len(r), bool)
    idx = np.asarray(ghost_index, np.int64)
    if len(idx) == 0:
        return out
    with np.errstate(invalid='ignore', divide='ignore'):
        z = np.abs(r[idx] - np.asarray(ghost_range_m, float)) / np.asarray(ghost_sigma_m, float)
    np.logical_or.at(out, idx, z <= z_max)
    return out


def words(mr: MultipleReturns) -> str | None:
    """The notes' sentence on later returns, or None without any."""
    if mr.points == 0:
        return None
    where = ''
    if mr.behind_first_m is not None:
        p5, p50, p95 = mr.behind_first_m
        where = (f'; {mr.with_first} of them lie {p50:.2f} m behind their shot\'s first return '
                 f'(5-95 %: {p5:.2f} to {p95:.2f} m)')
    xt = (f'; {mr.crosstalk} more later returns lie at the crosstalk delay and are counted as '
          'crosstalk' if mr.crosstalk else '')
    return (f'{mr.points} later returns of the same shot (a multi-return receiver; told by '
            f'{mr.source}; {100 * mr.fraction:.1f} % of the points analysed, {mr.shots} shots, '
            f'{mr.lasers} lasers, {mr.clouds} of {mr.clouds_total} clouds){where}{xt}: the '
            'model reports one return per shot, so they are left out of the fit (not '
            'crosstalk: the same shot of the same laser)' + (
                f'. {mr.at_model_ghost} of them lie where the catalogue\'s multipath would put '
                'a ghost of their shot (a mirror path off a specular surface); a depth step '
                'just past a grazing edge gives the same range, and a fit of one return per '
                'shot cannot tell the two apart' if mr.at_model_ghost else ''))
