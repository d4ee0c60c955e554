"""A pose claim asked what the target's outline says: the silhouette test.

The pose tests (``pose_error``) fit a rigid correction to the matched points' range
residuals. A range error fixed to the body or to some of its faces (a body bent off its
CAD, sunlit faces reading long) with an exact reference pose is absorbed by such a
correction as well as by a true pose error, and the range-only guards cannot always
tell the two apart. The outline can: a target that really is elsewhere moves its
silhouette and its depth steps across the rays, so a correction that puts the model
where the target is puts back on the target the returns just beyond the recorded
silhouette, and moves the rays at a depth step onto the surface they measured; a range
bias on faces moves no edge, and a correction fitted to it moves the model's outline off
returns that lay on it.

The test raycasts every measured ray once more with the claimed correction applied and
scores only the rays whose outcome the correction changes there (``edge_gain``): a
return matched under one pose and not the other (put back: +UNMATCHED_NATS, the credit a
candidate gets per unmatched point it explains; lost: -UNMATCHED_NATS), and a return
matched under both whose expected range jumps by more than JUMP_M plus the correction's
own largest motion (another surface across a depth step, or a grazing ray at a curved
limb, where the range follows the outline's place many times over).
A jump is scored as the
return's range fits the surface it lands on either way (``capped_nll``: half its squared
normalised residual, capped at UNMATCHED_NATS, so that moving a return off the surface it
measured costs no more than losing it). The correction is fitted to the matched points'
ranges only (never to which rays hit, and
a jump is far beyond the range change it was fitted to make), so these rays are held out
from it by construction. ``judge`` weighs their mean gain per edge ray over
neighbourhood blocks by the rule of every test (z and margin): 'supports', 'contradicts'
(the edges lose by the rule: the pose claim is withheld), 'no_support' (neither: the
claim stands, the figures said), or 'cannot_tell' where fewer than MIN_EDGE_RAYS rays
change (a target filling the view, a correction too small to move an edge across a
ray): the decision is then left as it is.

Rays that came back empty are not seen here: a recording holds returns (a Cepton
NO_RETURN shot carries no direction), so a ray just inside the model's silhouette that
finds nothing is not scored; only the returns are.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.diagnose.candidate import UNMATCHED_NATS
from lidar_sim_ros.compare.diagnose.features import block_mean_z

# A return matched under both poses whose expected range changes by more than this plus
# the correction's own largest motion has crossed a depth step (m).
JUMP_M = 0.05
# Fewer rays than this whose outcome the correction changes: the edges cannot tell.
MIN_EDGE_RAYS = 30
OUTCOMES = ('supports', 'contradicts', 'no_support', 'cannot_tell')


@dataclass(frozen=True)
class Silhouette:
    """What the edges say of a pose correction."""

    edge_rays: int        # rays whose outcome the correction changes
    put_back: int         # returns off the recorded model that the correction matches
    lost: int             # returns on the recorded model that the correction loses
    jumped: int           # returns matched both ways, moved across a depth step
    gain: float           # mean nats per edge ray (the correction against none)
    z: float
    outcome: str          # one of OUTCOMES
    reach_m: float = 0.0  # the correction's largest motion of a matched point (m)
    # Where the whole is contradicted: each part alone ('translation', 'rotation'), asked
    # the same (``run.silhouette_of``); a part the edges do not contradict keeps the claim.
    parts: dict | None = None

    @property
    def withholds(self) -> bool:
        """Whether a pose claim with this correction is withheld: the edges contradict
        it. Not where they only fail to support it: at a few centimetres against a beam
        footprint of one or two, a true per-cloud pose's edges gain short of the rule
        (docs/compare.md, "The silhouette test of a pose claim")."""
        return self.outcome == 'contradicts' and not self.part_left

    @property
    def part_left(self) -> bool:
        """Whether a part of the correction alone (its translation or its rotation) is
        not contradicted where the edges can judge it: the pose may be off, its claimed
        size having taken a range error beside it too."""
        return any(p.outcome in ('supports', 'no_support')
                   for p in (self.parts or {}).values())

    def as_dict(self) -> dict:
        return {'edge_rays': int(self.edge_rays), 'put_back': int(self.put_back),
                'lost': int(self.lost), 'jumped': int(self.jumped),
                'gain_per_edge_ray': round(float(self.gain), 4), 'z': round(float(self.z), 2),
                'outcome': self.outcome, 'reach_cm': round(100 * float(self.reach_m), 2),
                **({'parts': {k: p.as_dict() for k, p in self.parts.items()}}
                   if self.parts else {})}


def edge_gain(matched_before: np.ndarray, matched_after: np.ndarray,
              expected_before_m: np.ndarray, expected_after_m: np.ndarray,
              nll_before: np.ndarray, nll_after: np.ndarray, reach_m: float
              ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Per ray (arrays over the same rays): the nats the correction gains there and
    whether the ray is an edge ray. ``matched_*``: the ray hits the model without /
    with the correction; ``expected_*_m``: the model's range there (any value where it
    misses); ``nll_*``: the held-out NLL of the return (needed where matched both ways,
    NaN elsewhere); ``reach_m``: the correction's largest motion of the target. Returns
    (gain, edge mask, counts)."""
    b = np.asarray(matched_before, bool)
    a = np.asarray(matched_after, bool)
    put_back, lost = a & ~b, b & ~a
    both = a & b
    with np.errstate(invalid='ignore'):
        step = np.abs(np.asarray(expected_after_m, float) - np.asarray(expected_before_m, float))
        jumped = both & (step > JUMP_M + max(float(reach_m), 0.0))
    gain = np.zeros(len(b))
    gain[put_back] = UNMATCHED_NATS
    gain[lost] = -UNMATCHED_NATS
    d = np.asarray(nll_before, float) - np.asarray(nll_after, float)
    gain[jumped] = np.where(np.isfinite(d[jumped]), d[jumped], 0.0)
    edge = put_back | lost | jumped
    return gain, edge, {'put_back': int(put_back.sum()), 'lost': int(lost.sum()),
                        'jumped': int(jumped.sum())}


def capped_nll(residual_m: np.ndarray, sigma_m: np.ndarray) -> np.ndarray:
    """Half the squared normalised residual, capped at UNMATCHED_NATS (NaN stays NaN)."""
    r = np.asarray(residual_m, float) / np.maximum(np.asarray(sigma_m, float), 1e-6)
    return np.minimum(0.5 * r * r, UNMATCHED_NATS)


def judge(gain: np.ndarray, edge: np.ndarray, blocks: np.ndarray, counts: dict,
          z_crit: float, min_gain: float, reach_m: float = 0.0) -> Silhouette:
    """The edge rays' mean gain and its z over neighbourhood ``blocks``, and the
    outcome: 'cannot_tell' under MIN_EDGE_RAYS edge rays; 'supports' where z >= z_crit
    and the mean >= ``min_gain``; 'contradicts' where z <= -z_crit and the mean <=
    -``min_gain``; else 'no_support'."""
    edge = np.asarray(edge, bool)
    n = int(edge.sum())
    if n < MIN_EDGE_RAYS:
        mean = float(np.mean(gain[edge])) if n else 0.0
        return Silhouette(n, counts['put_back'], counts['lost'], counts['jumped'], mean, 0.0,
                          'cannot_tell', reach_m)
    mean, z = block_mean_z(np.asarray(gain, float)[edge], np.asarray(blocks)[edge])
    if z >= z_crit and mean >= min_gain:
        outcome = 'supports'
    elif z <= -z_crit and mean <= -min_gain:
        outcome = 'contradicts'
    else:
        outcome = 'no_support'
    return Silhouette(n, counts['put_back'], counts['lost'], counts['jumped'], float(mean),
                      float(z), outcome, reach_m)


def largest_motion_m(correction, xyz_m: np.ndarray, t_s: np.ndarray) -> float:
    """The largest motion (m) the correction (``pose_error.PoseCorrection``: a rigid
    motion per cloud, with its drift within the cloud if any) gives any of the points
    ``xyz_m`` (lidar frame) at their times ``t_s``."""
    p = np.asarray(xyz_m, float).reshape(-1, 3)
    if not len(p):
        return 0.0
    q, _ = correction.apply(p, t_s)
    return float(np.max(np.linalg.norm(q - p, axis=1)))
