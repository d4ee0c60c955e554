"""The reference pose moved along the line of sight, weighed on the candidates' footing.

The pose's own test (``pose_error``) is linear in the correction on the matched points,
leaves residuals beyond a few sigma and grazing rays out and, fitted jointly with the
per-material offsets, gives the pose their common offset. A target recorded a few
centimetres too far (or near) changes more than that offset: its silhouette and its
sloped faces change their place in the field (the perspective of the shift), which puts
returns just beyond a limb off the recorded target and moves the ranges near limbs by
centimetres. Those are the points where a sensor candidate that moves rays or widens
them (``laser_pointing``, ``surface_offset``'s scale, a footprint) gains: on the rocket
held tilted toward the line of sight the candidates gained 0.12 nats/point where the
pose's test counted 0.014, and on the pose raycast with the truth they gained nothing.

Here the pose is weighed as a candidate is scored: the target moved by ``t`` along the
line of sight and every ray raycast again (``cost(t)``), each returned point scored by
the likelihood of the model without a candidate, each material's offset and sigma
profiled (so the common offset stays the materials', as a range offset of the sensor
would leave it), and each point the moved target matches or loses counted as
UNMATCHED_NATS, what a candidate is credited per unmatched point it explains
(``diagnosis._set_gain``). ``best_shift`` finds the ``t`` the data put the target at,
``ray_gain`` the gain per point against the recorded pose, judged by the rule of every
candidate (held out: one parameter on tens of thousands of points, charged one nat).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from lidar_sim_ros.compare.diagnose.candidate import UNMATCHED_NATS
from lidar_sim_ros.compare.diagnose.features import block_mean_z

STEP_M = 0.02          # the first bracket's step along the line of sight (m)
SPAN_M = 0.16          # the farthest shift searched either way (m)
TOL_M = 0.003          # the search stops when the bracket is this narrow (m)
_GOLD = 0.5 * (np.sqrt(5.0) - 1.0)


@dataclass(frozen=True)
class RayScore:
    """Every point of the recording under the model with the target at one place:
    the matched points' indices (into the recording) and their NLL (nats), and the
    unmatched points' indices."""

    matched: np.ndarray
    nll: np.ndarray
    unmatched: np.ndarray


@dataclass(frozen=True)
class LineOfSightPose:
    """The target moved on the candidates' footing: along the line of sight first,
    then across it."""

    translation_m: np.ndarray   # (3,) lidar frame: the target is really here + this
    direction: np.ndarray       # (3,) unit line of sight, lidar frame
    gain: float                 # nats per point against the recorded pose, 3 nats charged
    z: float
    significant: bool
    put_back: int               # points matched that the recorded pose leaves unmatched, net
    evaluations: int = 0

    @property
    def shift_m(self) -> float:
        """The part along the line of sight (m)."""
        return float(np.dot(self.translation_m, self.direction))

    def as_dict(self) -> dict:
        return {'translation_cm': [round(100 * float(x), 2) for x in self.translation_m],
                'shift_cm': round(100 * self.shift_m, 2),
                'gain_per_point': round(self.gain, 6), 'z': round(self.z, 2),
                'significant': self.significant, 'put_back': int(self.put_back),
                'evaluations': int(self.evaluations)}


def ray_gain(before: RayScore, after: RayScore, n_points: int) -> np.ndarray:
    """(n_points,) nats each point gains from ``before`` to ``after``, as a candidate's
    gain is counted: matched in both, the NLL's fall; matched only after (put back),
    UNMATCHED_NATS, the credit of an unmatched point a candidate explains; matched only
    before (lost), -UNMATCHED_NATS."""
    out = np.zeros(n_points)
    nll_b = np.full(n_points, np.nan)
    nll_a = np.full(n_points, np.nan)
    nll_b[before.matched] = before.nll
    nll_a[after.matched] = after.nll
    both = np.isfinite(nll_b) & np.isfinite(nll_a)
    out[both] = nll_b[both] - nll_a[both]
    was_off = np.zeros(n_points, bool)
    was_off[before.unmatched] = True
    now_off = np.zeros(n_points, bool)
    now_off[after.unmatched] = True
    out[was_off & np.isfinite(nll_a)] += UNMATCHED_NATS
    out[now_off & np.isfinite(nll_b)] -= UNMATCHED_NATS
    return out


def best_shift(cost: Callable[[float], float], step_m: float = STEP_M,
               span_m: float = SPAN_M, tol_m: float = TOL_M) -> tuple[float, int]:
    """The shift (m) within +-``span_m`` that minimises ``cost``: bracketed from 0 in
    steps of ``step_m`` (doubling), then golden-section to ``tol_m``; and the number of
    evaluations. ``cost`` is evaluated once per distinct shift."""
    seen: dict[float, float] = {}

    def f(t: float) -> float:
        t = float(np.clip(round(t, 5), -span_m, span_m))
        if t not in seen:
            seen[t] = float(cost(t))
        return seen[t]
    lo, mid, hi = -step_m, 0.0, step_m
    if f(hi) < f(mid):
        direction = 1.0
    elif f(lo) < f(mid):
        direction = -1.0
    else:
        direction = 0.0
    if direction:
        a, b, h = 0.0, direction * step_m, step_m
        while True:
            c = float(np.clip(b + direction * 2 * h, -span_m, span_m))
            if c == b or f(c) >= f(b):
                lo, hi = sorted((a, c))
                break
            a, b, h = b, c, 2 * h
    while hi - lo > tol_m:
        x1 = hi - _GOLD * (hi - lo)
        x2 = lo + _GOLD * (hi - lo)
        if f(x1) <= f(x2):
            hi = x2
        else:
            lo = x1
    best = min(seen, key=seen.get)
    return best, len(seen)


def judge(before: RayScore, after: RayScore, n_points: int, blocks: np.ndarray,
          z_crit: float, min_gain: float, params: int = 1) -> tuple[float, float, bool, int]:
    """The gain per point of ``after`` over ``before`` with ``params`` charged a nat
    each, its z over neighbourhood blocks, whether it passes the rule (z and margin),
    and the points put back (net)."""
    g = ray_gain(before, after, n_points)
    mean, z = block_mean_z(g, blocks) if n_points > 1 else (0.0, 0.0)
    gain = float(mean - params / max(n_points, 1))
    put_back = int(len(before.unmatched) - len(after.unmatched))
    return gain, float(z), bool(z >= z_crit and gain >= min_gain), put_back


def axes_of(direction: np.ndarray) -> np.ndarray:
    """(3, 3) orthonormal rows: the line of sight, then two directions across it (the
    first horizontal in the lidar frame)."""
    u = np.asarray(direction, float) / max(float(np.linalg.norm(direction)), 1e-12)
    v = np.cross([0.0, 0.0, 1.0], u)
    v = v / np.linalg.norm(v) if np.linalg.norm(v) > 1e-9 else np.array([0.0, 1.0, 0.0])
    return np.vstack([u, v, np.cross(u, v)])


# Each pass: the axis (0 along the line of sight) and its first step and span (m).
PASSES = ((0, STEP_M, SPAN_M), (1, 0.01, 0.05), (2, 0.01, 0.05), (0, 0.01, 0.05))


def fit(score: Callable[[np.ndarray], RayScore], n_points: int, blocks: np.ndarray,
        direction: np.ndarray, z_crit: float, min_gain: float) -> LineOfSightPose:
    """The target moved where ``score`` (the recording scored with the target
    translated by a (3,) vector, m) is best: along ``direction`` first, then across it
    and along it again (``PASSES``, each ``best_shift`` from where the last left it);
    and its gain over the recorded pose. Where the move along the line of sight alone
    does not pass the rule, the search stops there."""
    axes = axes_of(direction)
    cache: dict[tuple, RayScore] = {}

    def at(c: np.ndarray) -> RayScore:
        key = tuple(np.round(c, 5))
        if key not in cache:
            cache[key] = score(axes.T @ np.asarray(key))
        return cache[key]
    zero = np.zeros(3)

    def cost(c: np.ndarray) -> float:
        return -float(np.sum(ray_gain(at(zero), at(c), n_points)))
    c = np.zeros(3)
    for k, (axis, step, span) in enumerate(PASSES):
        e = np.eye(3)[axis]
        delta, _ = best_shift(lambda d: cost(c + d * e), step, span)
        c = c + delta * e
        if k == 0 and not judge(at(zero), at(c), n_points, blocks, z_crit, min_gain)[2]:
            break
    gain, z, ok, put_back = judge(at(zero), at(c), n_points, blocks, z_crit, min_gain,
                                  params=3)
    return LineOfSightPose(axes.T @ c, axes[0], gain, z, ok, put_back, len(cache))
