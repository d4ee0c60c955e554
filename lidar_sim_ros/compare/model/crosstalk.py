"""Ghost returns of the adjacent laser (crosstalk): found before anything is fitted.

A multi-laser sensor fires its lasers one after another. The echo of a strong return
on laser l can leak into the receiver of the laser that fires next (l+1, the adjacent
channel): that shot then reports a return at laser l's range plus a fixed delay of the
electronics, along its own direction, whatever lies there. The model has no such
effect (it is outside the catalogue). Kept among the points, the ghosts are read as
whatever the fits can bend toward them: isolated returns off the target "at random
ranges" (solar_background), a range error growing with the power (range_walk: the
strong returns' neighbours carry them), a reference-pose error.

Their signature needs only what a recording carries: per point its laser/channel id
and its time (a time field, or the scan pattern's time for each direction). A point is
a ghost candidate when the model does not produce it: an extra return, where its ray
misses the target (the model gives no return) or the one farther from the model of two
returns of one shot (the model gives one). A single return on a ray that meets the
target, however far off the model's range, is that return's own range error (a walk,
a laser's offset, a material's bias: each moves a return, none adds one). A
candidate's partner is a return of *another* laser on the shot just before it (its
time one shot period earlier, within half a period; the period is the recording's own
smallest common step between point times). Over all candidate pairs, the range behind
the partner (r - r_partner, up to MAX_OFFSET_M) is spread by the scene's geometry;
crosstalk stacks its ghosts at one delay. A peak is crosstalk when its count stands
above the counts beside it (the sidebands, 1..3 half widths on either side) and above
the count at the mirrored delay in front of the partner (two returns of one surface on
successive shots lie in front of each other as often as behind; a ghost only behind)
by a z beyond the Bonferroni bound over the delays scanned (``FAMILY_ALPHA``), with at
least MIN_GHOSTS ghosts above them, and when its delays are *fixed*: their robust spread
at most FIXED_SPREAD x the half width. A ghost is timed off its partner's pulse, so its
delay spreads by the two returns' noise at most (sigma sqrt 2, a third of the half
width); delays that merely fill the window (a density smooth over it: spread 0.74 half
widths) are the scene's geometry, e.g. a dual-return receiver's later returns at depth
steps (holdout 10 ``dual``: z 4.2 over the sidebands, spread 0.71 half widths, with
every later return behind its shot's first, so behind most partners too); the peak is looked for among the second returns
alone (a return off the target is also what a reference-pose error or a footprint
puts beyond a silhouette, and its delay to the next tile's return can be nearly fixed
on a flat panel: the box-wing under a 3 cm pose error; no pose error makes a shot
return twice). The ghosts are then the extra returns whose
partner lies at that delay (within the peak's half width, and nearer it than zero; of
the two returns of a shot, the one at the delay; off the target too, once the second
returns have shown the delay): left out of everything after this
stage (``run.leave_out_occluded``, beside occlusion), counted in ``summary.json``
(``crosstalk``) and named in the verdict as outside the catalogue.

Without laser ids (a single channel) or point times (neither a time field nor a
matched scan pattern), no pair can be formed and nothing is looked for: the summary
says so.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import norm

from lidar_sim_ros.compare.model.left_out import LeftOut

MAX_OFFSET_M = 3.0         # delays looked at behind the partner (m)
HALF_WIDTH_SIGMAS = 3.0    # the peak's half width: this many sigmas of a pair's range
                           # difference (two returns' noise)
MIN_HALF_WIDTH_M = 0.01    # ... and at least this (a noiseless recording)
MIN_GHOSTS = 20            # ghosts above the sidebands needed to call it crosstalk
STRONG_RATIO = 1.5         # the verdict calls the partners strong at this intensity ratio
FAMILY_ALPHA = 0.01        # the false-alarm rate over all the delays scanned
FIXED_SPREAD = 0.5         # a fixed delay's robust spread, at most this x the half width
                           # (between the two returns' noise, 1/3, and a window filled
                           # evenly, 0.74: module doc)
PERIOD_QUANTILE = 5.0      # the shot period: this percentile of the steps between the
                           # distinct point times of a cloud (the smallest common step)


@dataclass(frozen=True)
class Crosstalk(LeftOut):
    """What was found and left out as crosstalk ghosts (``points``): counts over the
    analysed points."""

    offset_m: float | None = None       # the ghosts' range behind their partner (median)
    half_width_m: float | None = None   # the peak's half width
    z: float | None = None              # the peak over its sidebands
    z_crit: float | None = None
    candidates: int = 0                 # returns the model does not produce
    spread_m: float | None = None       # the peak's robust spread of delays (m)
    partner_power_ratio: float | None = None   # partners' median intensity / all points'
    looked: bool = True                 # False: no laser ids or point times
    why_not: str | None = None

    def as_dict(self) -> dict:
        return {**self.counts(), 'offset_m': self.offset_m, 'half_width_m': self.half_width_m,
                'z': self.z, 'z_crit': self.z_crit, 'candidates': self.candidates,
                'spread_m': self.spread_m,
                'partner_intensity_ratio': self.partner_power_ratio,
                'looked': self.looked, 'why_not': self.why_not,
                'interpretation': words(self)}


def shot_period_s(t_s: np.ndarray, cloud: np.ndarray) -> float | None:
    """The recording's shot period (s): the PERIOD_QUANTILE percentile of the positive
    steps between consecutive distinct point times within a cloud; None without any."""
    t = np.asarray(t_s, float)
    cloud = np.asarray(cloud)
    order = np.lexsort((t, cloud))
    step = np.diff(t[order])
    same = cloud[order][1:] == cloud[order][:-1]
    step = step[same & (step > 0)]
    if len(step) == 0:
        return None
    return float(np.percentile(step, PERIOD_QUANTILE))


def previous_shot_pairs(t_s: np.ndarray, cloud: np.ndarray, laser: np.ndarray,
                        query: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (p, q): p in ``query`` (indices), q a point of the same cloud on another
    laser whose time lies one shot period before p's (within half a period)."""
    t = np.asarray(t_s, float) - float(np.min(t_s))
    cloud = np.asarray(cloud)
    laser = np.asarray(laser)
    order = np.lexsort((t, cloud))
    # One axis: clouds apart by more than any time span, times within.
    span = float(t.max()) + 10.0 * period_s + 1.0
    key = cloud[order].astype(float) * span + t[order]
    q_key = cloud[query].astype(float) * span + t[query]
    lo = np.searchsorted(key, q_key - 1.5 * period_s, 'left')
    hi = np.searchsorted(key, q_key - 0.5 * period_s, 'right')
    ps, qs = [], []
    for k in range(int(np.max(hi - lo, initial=0))):
        has = hi - lo > k
        p = query[has]
        q = order[lo[has] + k]
        keep = (cloud[q] == cloud[p]) & (laser[q] != laser[p])
        ps.append(p[keep])
        qs.append(q[keep])
    if not ps:
        return np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(ps), np.concatenate(qs)


def two_return_shots(t_s: np.ndarray, cloud: np.ndarray, laser: np.ndarray,
                     period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (a, b): two returns of one shot (the same cloud and laser, times within
    half a shot period). The model gives a shot one return."""
    t = np.asarray(t_s, float) - float(np.min(t_s))
    cloud = np.asarray(cloud)
    laser = np.asarray(laser)
    order = np.lexsort((t, laser, cloud))
    a, b = order[:-1], order[1:]
    pair = ((cloud[a] == cloud[b]) & (laser[a] == laser[b])
            & (np.abs(t[b] - t[a]) < 0.5 * period_s))
    return a[pair], b[pair]


def delay_peak(delay_m: np.ndarray, half_width_m: float) -> tuple[float, float, float, int]:
    """The delay (m) whose window (+-half_width_m) stands highest above its sidebands
    (module doc): (centre, z, z_crit, excess count). Centres step by half a half width
    over [half_width_m, MAX_OFFSET_M]; ``delay_m`` holds every pair's delay, those in
    front of the partner too (the sidebands of a short delay reach below zero)."""
    d = np.sort(np.asarray(delay_m, float))
    h = float(half_width_m)
    centres = np.arange(h, MAX_OFFSET_M + 1e-12, h / 2)
    z_crit = float(norm.isf(FAMILY_ALPHA / max(len(centres), 1)))
    if len(centres) == 0 or len(d) == 0:
        return float('nan'), 0.0, z_crit, 0

    def count(a, b):
        return np.searchsorted(d, b, 'right') - np.searchsorted(d, a, 'left')

    n = count(centres - h, centres + h)
    side = count(centres - 3 * h, centres + 3 * h) - n
    # Two returns of one surface on successive shots lie as often in front of each other
    # as behind; a ghost only behind: the mirror window is a second chance level.
    mirror = count(-centres - h, -centres + h)
    b = np.maximum(side / 2.0, mirror)               # expected count in the window
    z = (n - b) / np.sqrt(1.5 * b + 1.0)             # var(n - b) = b + b / 2 (Poisson)
    best = int(np.argmax(z))
    # The scene's delays are not exactly linear over a sideband: the scan's own centres
    # away from the peak are its null, their robust spread (at least 1) the unit of z.
    away = np.abs(centres - centres[best]) > 3 * h
    scale = 1.0
    if np.count_nonzero(away) >= 10:
        rest = z[away]
        scale = max(1.0, 1.4826 * float(np.median(np.abs(rest - np.median(rest)))))
    return (float(centres[best]), float(z[best] / scale), z_crit,
            int(round(n[best] - b[best])))


def crosstalk_ghosts(range_m: np.ndarray, expected_m: np.ndarray, sigma_m: np.ndarray,
                     t_s: np.ndarray, cloud: np.ndarray, laser: np.ndarray,
                     has_point_time: bool, intensity: np.ndarray | None = None
                     ) -> tuple[np.ndarray, Crosstalk]:
    """Bool per measured point: a crosstalk ghost (module doc), and the ``Crosstalk``.

    range_m (N,): measured ranges (m); expected_m (N,): the model's range on each ray
    (m, NaN where the ray misses the target); sigma_m (N,): the model's predicted range
    sigma (m); t_s (N,): point times (s); cloud, laser (N,): cloud index, laser id;
    has_point_time: whether the times are per point (a field or the scan pattern);
    intensity (N,) or None: only reported (the partners' strength)."""
    r = np.asarray(range_m, float)
    n = len(r)
    cloud = np.asarray(cloud)
    laser = np.asarray(laser)
    none = np.zeros(n, bool)
    n_clouds = len(np.unique(cloud)) if n else 0

    def nothing(why: str | None, **kw) -> tuple[np.ndarray, Crosstalk]:
        return none, Crosstalk(0, n, 0, n_clouds, looked=why is None, why_not=why, **kw)

    if n == 0:
        return nothing('no points')
    timed = np.isfinite(np.asarray(t_s, float))
    if 0 < timed.sum() < n:
        # Points without a finite time pair with nothing: looked for among the rest.
        keep = np.flatnonzero(timed)
        part = (None if intensity is None or len(intensity) != n
                else np.asarray(intensity)[keep])
        sub, xt = crosstalk_ghosts(r[keep], np.asarray(expected_m)[keep],
                                   np.asarray(sigma_m)[keep], np.asarray(t_s)[keep],
                                   cloud[keep], laser[keep], has_point_time, part)
        mask = np.zeros(n, bool)
        mask[keep] = sub
        return mask, replace(xt, analysed=n, clouds_total=n_clouds)
    if len(np.unique(laser)) < 2:
        return nothing('the recording carries one laser/channel id: no adjacent laser to '
                       'pair with')
    period = shot_period_s(t_s, cloud) if has_point_time else None
    if period is None or not period > 0:
        return nothing('the recording carries no per-point time (nor a matched scan '
                       'pattern): the shot before a return is unknown')
    expected = np.asarray(expected_m, float)
    sigma = np.nan_to_num(np.asarray(sigma_m, float), nan=0.0)
    off = ~np.isfinite(expected)
    with np.errstate(invalid='ignore'):
        miss = np.abs(r - expected)
    a, b = two_return_shots(t_s, cloud, laser, period)
    # Of two returns of a shot, the one farther from the model is the extra one.
    miss = np.where(off, np.inf, miss)
    second = np.zeros(n, bool)
    second[np.where(miss[a] > miss[b], a, b)] = True
    # Shown on the second returns alone: a return off the target is also what a pose
    # error or a footprint puts beyond a silhouette (whose delay to the next tile's
    # return can be nearly fixed on a flat panel); a shot's second return is not.
    cand = np.flatnonzero(second & np.isfinite(r))
    p, q = previous_shot_pairs(t_s, cloud, laser, cand, period)
    delay = r[p] - r[q]
    s = float(np.median(sigma[np.isfinite(expected)])) if np.any(~off) else 0.0
    h = max(HALF_WIDTH_SIGMAS * np.sqrt(2.0) * s, MIN_HALF_WIDTH_M)
    sel = (delay > 0) & (delay <= MAX_OFFSET_M + h)
    centre, z, z_crit, excess = delay_peak(delay, h)
    win = delay[np.abs(delay - centre) <= h]       # reported: a fixed delay's spread
    spread = (1.4826 * float(np.median(np.abs(win - np.median(win)))) if len(win)
              else float('nan'))
    found = bool(z > z_crit and excess >= MIN_GHOSTS and spread <= FIXED_SPREAD * h)
    kw = dict(half_width_m=round(h, 4), z=round(z, 2), z_crit=round(z_crit, 2),
              candidates=int(len(cand)), spread_m=round(spread, 4))
    if not found:
        return none, Crosstalk(0, n, 0, n_clouds, **kw)
    near = sel & (np.abs(delay - centre) <= h)
    offset = float(np.median(delay[near]))
    # Now that the delay is known, the ghost of a two-return shot is the one at it (an
    # echo with a walk can lie farther from the model than its ghost): both are paired.
    both = np.zeros(n, bool)
    both[a] = both[b] = True
    p, q = previous_shot_pairs(t_s, cloud, laser,
                               np.flatnonzero((off | both) & np.isfinite(r)), period)
    delay = r[p] - r[q]
    # A pair nearer zero delay than the ghosts' is one surface seen by the next shot.
    hit = (np.abs(delay - offset) <= h) & (delay > 0.5 * offset)
    closeness = np.full(n, np.inf)
    np.minimum.at(closeness, p[hit], np.abs(delay[hit] - offset))
    mask = np.isfinite(closeness)
    # Both returns of a shot at the delay: the ghost is the nearer to it.
    twice = mask[a] & mask[b]
    mask[np.where(closeness[a] > closeness[b], a, b)[twice]] = False
    ratio = None
    if intensity is not None and len(intensity) == n:
        inten = np.asarray(intensity, float)
        base = float(np.nanmedian(inten))
        if base > 0:
            ratio = round(float(np.nanmedian(inten[q[hit & mask[p]]])) / base, 3)
    return mask, Crosstalk(int(mask.sum()), n, int(len(np.unique(cloud[mask]))), n_clouds,
                           offset_m=round(offset, 4), partner_power_ratio=ratio, **kw)


def words(xt: Crosstalk) -> str | None:
    """The verdict's sentence on crosstalk, or None without any."""
    if xt.points == 0:
        return None
    ratio = xt.partner_power_ratio
    strong = (f'; their partners are strong returns (median intensity {ratio:.1f}x the '
              "recording's)" if ratio and ratio >= STRONG_RATIO else '')
    return (f'{xt.points} returns ({100 * xt.fraction:.1f} % of the points analysed, in '
            f'{xt.clouds} of {xt.clouds_total} clouds) are ghost returns behind strong returns '
            f'on the adjacent laser: each lies {xt.offset_m:.2f} m behind a return of another '
            'laser on the shot just before it, where the model puts no return '
            f'(z {xt.z:.1f} over the delays beside it){strong}: crosstalk, outside the '
            'catalogue; left out of the material refit, the pose test and the diagnosis')
