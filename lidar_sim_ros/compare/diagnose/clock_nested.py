"""A clock offset and one rigid pose correction weighed nested on the candidates' footing.

The linear joint fit of a clock beside one rigid correction (``clock_footing``) is made
on the pose test's rays: it leaves the limbs out, where a clock offset on a target
spinning about a moving axis shows most, and where a correction of centimetres puts
returns back on the target. Here the two hypotheses are raycast, every point scored as a
candidate is scored (``line_of_sight.ray_gain``: the held-out NLL of the matched points,
UNMATCHED_NATS per point put back or lost), on the same points:

* nothing: the recorded pose;
* the pose alone: the correction fitted alone (six parameters);
* the clock alone: the recorded pose read ``dt`` later (one parameter);
* both: the correction fitted on top of the clock, the pose read ``dt`` later.

Each of the pair is judged on top of the other's absence (the pose alone against
nothing, the clock alone against nothing) and on top of the other (both against the
clock alone: the pose's own part, six nats charged; both against the pose alone: the
clock's own part, one nat charged), by the rule of every candidate (z at the family's
bound and the margin that matters). ``outcome``: 'clock' where the clock's own part
passes (the clock is named; the pose beside it where its own part passes too), 'tie'
where each passes alone but neither on top of the other (the data cannot tell them
apart), None otherwise (the decision stands).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.diagnose import line_of_sight

POSE_PARAMS = 6    # one rigid correction for the recording: 3 translations, 3 turns
CLOCK_PARAMS = 1   # dt


@dataclass(frozen=True)
class Part:
    """One nested comparison: nats per point (parameters charged a nat each), z over
    neighbourhood blocks, whether it passes the rule, points put back (net)."""

    gain: float
    z: float
    passes: bool
    put_back: int
    decisive: bool = False     # z at the family's bound, whatever the margin

    def as_dict(self) -> dict:
        return {'gain_per_point': round(self.gain, 6), 'z': round(self.z, 2),
                'passes': self.passes, 'put_back': self.put_back,
                'decisive': self.decisive}


@dataclass(frozen=True)
class NestedClock:
    """The four comparisons and the clock offsets (s) they were made with."""

    pose_alone: Part
    clock_alone: Part
    clock_over_pose: Part
    pose_over_clock: Part
    dt_alone_s: float
    dt_beside_pose_s: float
    n_points: int

    @property
    def outcome(self) -> str | None:
        """'clock', 'tie' or None (module docstring)."""
        if self.clock_over_pose.passes:
            return 'clock'
        if (self.pose_alone.passes and self.clock_alone.passes
                and not self.pose_over_clock.passes):
            return 'tie'
        return None

    def as_dict(self) -> dict:
        return {'pose_alone': self.pose_alone.as_dict(),
                'clock_alone': self.clock_alone.as_dict(),
                'clock_over_pose': self.clock_over_pose.as_dict(),
                'pose_over_clock': self.pose_over_clock.as_dict(),
                'dt_alone_s': round(self.dt_alone_s, 5),
                'dt_beside_pose_s': round(self.dt_beside_pose_s, 5),
                'n_points': self.n_points, 'outcome': self.outcome}


def part(before: line_of_sight.RayScore, after: line_of_sight.RayScore, n_points: int,
         blocks: np.ndarray, z_crit: float, min_gain: float, params: int) -> Part:
    """``after`` against ``before`` on the same points (``line_of_sight.judge``)."""
    gain, z, ok, put_back = line_of_sight.judge(before, after, n_points, blocks, z_crit,
                                                min_gain, params=params)
    return Part(gain, z, ok, put_back, bool(z >= z_crit))


def weigh(nothing: line_of_sight.RayScore, pose: line_of_sight.RayScore,
          clock: line_of_sight.RayScore, both: line_of_sight.RayScore, n_points: int,
          blocks: np.ndarray, z_crit: float, min_gain: float, dt_alone_s: float,
          dt_beside_pose_s: float) -> NestedClock:
    """The four nested comparisons of the module docstring on ``n_points`` points
    (their neighbourhood ``blocks``)."""
    def p(a, b, k):
        return part(a, b, n_points, blocks, z_crit, min_gain, k)
    return NestedClock(pose_alone=p(nothing, pose, POSE_PARAMS),
                       clock_alone=p(nothing, clock, CLOCK_PARAMS),
                       clock_over_pose=p(pose, both, CLOCK_PARAMS),
                       pose_over_clock=p(clock, both, POSE_PARAMS),
                       dt_alone_s=float(dt_alone_s),
                       dt_beside_pose_s=float(dt_beside_pose_s), n_points=int(n_points))
