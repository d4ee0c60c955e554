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
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose import features, line_of_sight

POSE_PARAMS = 6    # one rigid correction for the recording: 3 translations, 3 turns
CLOCK_PARAMS = 1   # dt
# A clock stands for a pose per cloud only through the pattern one dt lays over many
# clouds: with fewer, the clock and one correction fit a few clouds' own offsets by
# chance (pose_error_rigid on 2 clouds: a 144 ms clock 'passed' over a pose that was
# off rigidly per cloud). The per-cloud weighing asks at least this many clouds.
MIN_CLOUDS_PER_CLOUD = 6
# A clock is told from one rigid correction only by what it does beyond one rigid motion
# of the target's points (``clock_beyond_rigid_m``): nothing on a constant-rate turn about
# a fixed axis at a steady speed, where a clock IS one rigid correction.
BEYOND_RIGID_POINTS = 5_000     # points (a fixed thinning) the motion is measured on


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
    # False on a spin at a constant rate about a fixed axis (``spin_clock.fixed_spin``):
    # a clock is one rigid rotation there, which the correction takes alike, so a part
    # of its own found on top of it is not the clock's and names nothing.
    own_part_possible: bool = True

    @property
    def outcome(self) -> str | None:
        """'clock', 'tie' or None (module docstring)."""
        if self.clock_over_pose.passes and self.own_part_possible:
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
                'n_points': self.n_points, 'outcome': self.outcome,
                **({} if self.own_part_possible else {
                    'fixed_spin': 'a spin at a constant rate about a fixed axis: a clock '
                                  'offset is one rotation of the pose there'})}


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


# Where the pose test reports a correction per cloud (its rotation varying over the
# recording), the clock and one rigid correction are weighed against that per-cloud
# correction on the same footing: on a target spinning about an axis that turns with a
# tumble, a clock offset reads each cloud's attitude off about a different lidar-frame
# axis, which twelve rigid corrections take as well as one correction and a dt. Each
# hypothesis is charged its parameters: six per cloud against seven.

def charged_part(before: line_of_sight.RayScore, after: line_of_sight.RayScore,
                 n_points: int, blocks: np.ndarray, z_crit: float, min_gain: float,
                 charge: float) -> Part:
    """``after`` against ``before`` with ``charge`` nats (the parameters ``after`` has
    beyond ``before``'s; below zero where it has fewer) taken from the gain spread over
    the points, so that z is the charged gain's too (``part`` charges the mean only:
    nested hypotheses, where the charge is small beside the points; here it is not)."""
    g = line_of_sight.ray_gain(before, after, n_points) - charge / max(n_points, 1)
    mean, z = features.block_mean_z(g, blocks) if n_points > 1 else (0.0, 0.0)
    put_back = int(len(before.unmatched) - len(after.unmatched))
    return Part(float(mean), float(z), bool(z >= z_crit and mean >= min_gain), put_back,
                bool(z >= z_crit))


@dataclass(frozen=True)
class PerCloudClock:
    """The constant nested test (``NestedClock``) and the per-cloud correction weighed
    against the clock with one correction: ``joint_over_per_cloud`` (the clock and one
    correction against the per-cloud correction, 6 x clouds - 7 nats credited) and
    ``per_cloud_over_joint`` (the reverse, as many charged)."""

    nested: NestedClock
    per_cloud_alone: Part
    joint_over_per_cloud: Part
    per_cloud_over_joint: Part
    n_clouds: int

    @property
    def outcome(self) -> str | None:
        """'clock' where the clock's own part on top of one correction passes and the
        clock with that correction passes over the per-cloud correction (the clock is
        named, the pose beside it as the nested test gives it); 'tie' where the clock's
        own part passes but neither the clock with one correction nor the per-cloud
        correction passes on top of the other; None otherwise (the per-cloud pose
        stands)."""
        if not self.nested.clock_over_pose.passes:
            return None
        if self.joint_over_per_cloud.passes:
            return 'clock'
        if not self.per_cloud_over_joint.passes:
            return 'tie'
        return None

    # What the naming tail reads off a nested test (``Diagnosis.clock_named_beside``).
    @property
    def clock_over_pose(self) -> Part:
        return self.nested.clock_over_pose

    @property
    def pose_over_clock(self) -> Part:
        return self.nested.pose_over_clock

    @property
    def dt_beside_pose_s(self) -> float:
        return self.nested.dt_beside_pose_s

    def as_dict(self) -> dict:
        return {**self.nested.as_dict(), 'outcome': self.outcome,
                'per_cloud': {'n_clouds': self.n_clouds,
                              'params': POSE_PARAMS * self.n_clouds,
                              'alone': self.per_cloud_alone.as_dict(),
                              'joint_over_per_cloud': self.joint_over_per_cloud.as_dict(),
                              'per_cloud_over_joint': self.per_cloud_over_joint.as_dict()}}


def weigh_per_cloud(nested: NestedClock, nothing: line_of_sight.RayScore,
                    per_cloud: line_of_sight.RayScore, both: line_of_sight.RayScore,
                    n_clouds: int, blocks: np.ndarray, z_crit: float,
                    min_gain: float) -> PerCloudClock:
    """``nested`` (the four comparisons on the same points) and the per-cloud
    correction (``per_cloud``, fitted on those points, ``n_clouds`` x six parameters)
    against nothing and against the clock with one correction (``both``)."""
    n = nested.n_points
    extra = POSE_PARAMS * n_clouds - (POSE_PARAMS + CLOCK_PARAMS)
    return PerCloudClock(
        nested=nested,
        per_cloud_alone=charged_part(nothing, per_cloud, n, blocks, z_crit, min_gain,
                                     POSE_PARAMS * n_clouds),
        joint_over_per_cloud=charged_part(per_cloud, both, n, blocks, z_crit, min_gain,
                                          -extra),
        per_cloud_over_joint=charged_part(both, per_cloud, n, blocks, z_crit, min_gain,
                                          extra),
        n_clouds=int(n_clouds))


def clock_beyond_rigid_m(xyz_m: np.ndarray, t_s: np.ndarray, poses, dt_s: float) -> float:
    """RMS (m) of what reading the pose ``dt_s`` later does to the measured target points
    ``xyz_m`` (N, 3), lidar frame, at their times ``t_s`` (each carried with the target
    from its pose at t to its pose at t + dt), beyond the one rigid motion of them all
    that fits it best (Kabsch): 0 where the target's motion makes a clock one constant
    pose correction. ``poses.at(t)``: a pose source (``core.pose``)."""
    xyz = np.asarray(xyz_m, float)
    t = np.asarray(t_s, float)
    ok = np.all(np.isfinite(xyz), axis=1) & np.isfinite(t)
    xyz, t = xyz[ok], t[ok]
    if len(xyz) < 3 or not np.isfinite(dt_s):
        return float('nan')
    if len(xyz) > BEYOND_RIGID_POINTS:
        pick = np.linspace(0, len(xyz) - 1, BEYOND_RIGID_POINTS).astype(np.int64)
        xyz, t = xyz[pick], t[pick]
    moved = poses.at(t + float(dt_s)).to_lidar(poses.at(t).to_body(xyz))
    a, b = xyz - xyz.mean(axis=0), moved - moved.mean(axis=0)
    rot, _ = Rotation.align_vectors(b, a)
    rest = b - rot.apply(a)
    return float(np.sqrt(np.mean(np.sum(rest ** 2, axis=1))))
