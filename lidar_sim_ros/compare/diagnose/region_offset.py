"""One part of a material reading off the rest, against a rigid reference-pose error.

A material the configuration does not list on part of the target (a panel of another
cell type on one solar wing, another paint on the upper half of a ring of faces that the
mesh gives one material) reads off the rest of the faces the mesh labels alike: a step
in the range residual confined to that part. The likelihood profiles one offset per
material, which takes the step's mean and leaves the two parts on either side of it;
one rigid correction of the reference pose (six parameters) moves the part's surfaces
toward their ranges, and its held-out test passes on exact poses (the ninth holdout's
F6: 0.5-1.0 cm "check the tracking system").

The two are different things: a rigid pose error moves every surface as its normal
and distance say (``pose_error``: n.d / n.u, a pattern over the whole target), a part
of one material reading off gives a step on that part only. So the alternative is put
to the pose's own footing: the material's points split in two by a plane of the body
frame (one of SPLIT_DIRECTIONS, the threshold the best on the fitting half: the
faces' centroids on either side, since the mesh assigns materials by face), each side
with its own offset. It is held out as every candidate is (chosen and fitted on one
random half of the points, scored on the other, both ways; nats per matched point,
z over neighbourhood blocks), and the pose and the split are each tested on top of the
other: the pose's test on the model with the split's offsets (``Diagnosis``'s rule,
run by the caller's pose test), the split's on the pose-corrected residual.

``judge``: a pose that passes its test on top of the split stands; one that does not,
is not reported: where the split passes on top of the pose, part of the target reads
off the rest (outside the catalogue); where neither adds to the other, the recording
cannot tell the two apart, and the pose is not asserted. The pose stands too where its
correction explains the materials' offsets against the configuration (``PoseError.
joint``, ``through_materials``): the split is confined to one material and leaves the
others where they read (on a box seen on two faces of one material, a translation is two
offsets of that material on the free-offset footing, but every other material reads
off the configuration by what the same translation gives), and where the split does not
pass the rule alone (no part reads off). Pure functions over numpy arrays, and
``judge`` over the diagnosis's decision.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.diagnose.features import block_mean_z
from lidar_sim_ros.compare.diagnose import pose_error

# Normals of the splitting planes, body frame: the axes and the diagonals between two.
SPLIT_DIRECTIONS = np.array([
    [1, 0, 0], [0, 1, 0], [0, 0, 1],
    [1, 1, 0], [1, -1, 0], [1, 0, 1], [1, 0, -1], [0, 1, 1], [0, 1, -1]], float)
SPLIT_DIRECTIONS /= np.linalg.norm(SPLIT_DIRECTIONS, axis=1, keepdims=True)
AXIS_NAMES = ('x', 'y', 'z', 'x+y', 'x-y', 'x+z', 'x-z', 'y+z', 'y-z')
SPLIT_SEED = 67      # stream of the random halves (the pose test uses 61)


@dataclass(frozen=True)
class Split:
    """A material's points split in two by a plane of the body frame:
    ``direction . p > threshold_m`` (p: the centroid of the face a point lies on)."""

    material: int
    axis: int                 # row of SPLIT_DIRECTIONS
    threshold_m: float
    gain: float               # weighted sum of squares the two offsets explain / 2 (nats)

    def side(self, material: np.ndarray, body_m: np.ndarray) -> np.ndarray:
        """Per point: +1 beyond the plane, -1 before it, 0 another material."""
        on = np.asarray(material) == self.material
        beyond = np.asarray(body_m, float) @ SPLIT_DIRECTIONS[self.axis] > self.threshold_m
        return np.where(on, np.where(beyond, 1, -1), 0)


def face_centroids_m(target) -> np.ndarray | None:
    """(F, 3) body-frame centroid of each face of ``target`` (``core.geometry.Target``);
    None without a mesh."""
    v = getattr(target, 'vertices_m', None)
    f = getattr(target, 'faces', None)
    if v is None or f is None or not len(f):
        return None
    return np.asarray(v, float)[np.asarray(f)].mean(axis=1)


def body_points_m(ctx) -> np.ndarray | None:
    """(N, 3) body-frame centroid of the face each point lies on (a ``ReturnContext``
    with faces and a scene); None where the context carries no faces."""
    face = getattr(ctx, 'face', None)
    scene = getattr(ctx, 'scene', None)
    centroids = face_centroids_m(getattr(scene, 'target', None))
    if face is None or centroids is None:
        return None
    face = np.asarray(face, int)
    if not len(face) or face.max() >= len(centroids):
        return None
    return np.where((face >= 0)[:, None], centroids[np.maximum(face, 0)], np.nan)


def best_split(residual_m: np.ndarray, sigma_m: np.ndarray, material: np.ndarray,
               body_m: np.ndarray, use: np.ndarray) -> Split | None:
    """The split (one material, one plane of SPLIT_DIRECTIONS, the threshold between two
    faces' centroids) whose two offsets explain most of the ``use`` points' weighted
    residual (``residual_m`` with each material's offset taken out), each side at least
    MIN_MATERIAL_POINTS points; None where no material has enough points for two."""
    w = 1.0 / np.asarray(sigma_m, float) ** 2
    best = None
    for m in np.unique(material[use]):
        sel = use & (material == m) & np.all(np.isfinite(body_m), axis=1)
        if sel.sum() < 2 * lk.MIN_MATERIAL_POINTS:
            continue
        r, wm, p = residual_m[sel], w[sel], body_m[sel]
        total = float(np.sum(wm * r) ** 2 / np.sum(wm))
        for k, e in enumerate(SPLIT_DIRECTIONS):
            c = p @ e
            order = np.argsort(c, kind='stable')
            cs, ws, ss = c[order], np.cumsum(wm[order]), np.cumsum((wm * r)[order])
            n = len(cs)
            i = np.arange(lk.MIN_MATERIAL_POINTS, n - lk.MIN_MATERIAL_POINTS + 1)
            # A threshold only between faces: points on one face stay on one side.
            i = i[cs[i - 1] < cs[np.minimum(i, n - 1)]]
            if not len(i):
                continue
            left_w, left_s = ws[i - 1], ss[i - 1]
            right_w, right_s = ws[-1] - left_w, ss[-1] - left_s
            gain = 0.5 * (left_s ** 2 / left_w + right_s ** 2 / right_w - total)
            j = int(np.argmax(gain))
            if best is None or gain[j] > best.gain:
                best = Split(int(m), k, float(0.5 * (cs[i[j] - 1] + cs[i[j]])),
                             float(gain[j]))
    return best


def split_offsets(split: Split, residual_m: np.ndarray, sigma_m: np.ndarray,
                  side: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """(N,) the offset of each point's side (weighted mean of the ``fit`` points'
    residual on that side, m); 0 on other materials."""
    w = 1.0 / np.asarray(sigma_m, float) ** 2
    out = np.zeros(len(residual_m))
    for s in (-1, 1):
        on = fit & (side == s)
        if on.any():
            out[side == s] = float(np.sum(w[on] * residual_m[on]) / np.sum(w[on]))
    return out


@dataclass(frozen=True)
class SplitTest:
    """The split's held-out test on a residual, and the split fitted on every point."""

    split: Split | None
    gain: float                  # held-out nats per matched point
    z: float
    correction_m: np.ndarray     # (N,) the fitted split's offsets (m), every point
    offsets_m: tuple[float, float] = (0.0, 0.0)   # before, beyond the plane (m)
    points: tuple[int, int] = (0, 0)              # usable points before, beyond


def heldout_split(residual_m: np.ndarray, sigma_m: np.ndarray, material: np.ndarray,
               body_m: np.ndarray, use: np.ndarray, blocks: np.ndarray,
               seed: int = 0) -> SplitTest:
    """Held out: the split chosen and its offsets fitted on one random half of the
    ``use`` points, scored on the other (Gaussian nats, ``pose_error.heldout_gain``),
    both ways; the gain per point of ``residual_m`` and its z over ``blocks``. Then the
    split chosen and fitted on every ``use`` point (its correction, for the pose's test
    on top of it)."""
    n = len(residual_m)
    half = np.random.default_rng([seed, SPLIT_SEED]).integers(0, 2, n)
    gain = np.zeros(n)
    for k in (0, 1):
        train, test = use & (half == k), use & (half != k)
        split = best_split(residual_m, sigma_m, material, body_m, train)
        if split is None:
            continue
        side = split.side(material, body_m)
        corr = split_offsets(split, residual_m, sigma_m, side, train)
        gain[test] = pose_error.heldout_gain(residual_m[test], corr[test], sigma_m[test])
    per_point = float(np.sum(gain[use]) / max(n, 1))
    z = block_mean_z(gain[use], blocks[use])[1] if use.sum() > 1 else 0.0
    split = best_split(residual_m, sigma_m, material, body_m, use)
    if split is None:
        return SplitTest(None, per_point, z, np.zeros(n))
    side = split.side(material, body_m)
    corr = split_offsets(split, residual_m, sigma_m, side, use)
    before, beyond = use & (side == -1), use & (side == 1)
    return SplitTest(split, per_point, z, corr,
                     (float(corr[before][0]) if before.any() else 0.0,
                      float(corr[beyond][0]) if beyond.any() else 0.0),
                     (int(before.sum()), int(beyond.sum())))


def footing(data: lk.FitData, effects: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pose test's footing on ``data`` with ``effects`` (``pose_error.
    fit_reference_pose``): the residual with each material's offset taken out, its
    sigma with the material's scale, and the usable points (placed, finite, within
    OUTLIER_SIGMAS)."""
    r, s, ok, _ = pose_error.footing(data, lk.model_on_rays(data, list(effects)))
    return r, s, ok & (np.abs(r) <= pose_error.OUTLIER_SIGMAS * s)


@dataclass(frozen=True)
class RegionOffset:
    """One part of a material against the reference pose: the split's test alone and on
    top of the pose, and the pose's test on top of the split (``judge``)."""

    material: str
    axis: str                    # the plane's normal in the body frame (AXIS_NAMES)
    threshold_m: float
    step_m: float                # the part beyond the plane less the part before it
    points: tuple[int, int]      # usable points before, beyond
    gain: float                  # the split alone, held out (nats per matched point)
    z: float
    gain_beyond_pose: float      # the split on the pose-corrected residual
    z_beyond_pose: float
    pose_gain_beyond: float      # the pose's test on top of the split's offsets
    pose_z_beyond: float
    pose_passes_beyond: bool
    passes: bool                 # the split alone passes the rule
    passes_beyond_pose: bool
    pose_constant: bool
    # The pose's correction explains the materials' offsets against the configuration
    # (``PoseError.joint``: their common offset, the target recorded nearer;
    # ``through_materials``: faces of one material each moved apart): what a part of
    # one material reading off cannot, since it leaves the other materials as they are.
    pose_explains_materials: bool = False

    @property
    def outcome(self) -> str:
        """'pose': the pose gains beyond the split, or explains the materials' offsets
        (``pose_explains_materials``), or the split does not pass the rule alone (no
        part reads off); 'region': the split gains beyond the pose and not the other
        way; 'tie': neither beyond the other."""
        if self.pose_passes_beyond or self.pose_explains_materials or not self.passes:
            return 'pose'
        return 'region' if self.passes_beyond_pose else 'tie'

    def as_dict(self) -> dict:
        return {'material': self.material, 'plane_normal_body': self.axis,
                'threshold_m': round(self.threshold_m, 4),
                'step_m': round(self.step_m, 5), 'points': list(self.points),
                'gain_per_matched_point': round(self.gain, 6), 'z': round(self.z, 3),
                'significant': self.passes,
                'beyond_pose': {'gain_per_matched_point': round(self.gain_beyond_pose, 6),
                                'z': round(self.z_beyond_pose, 3),
                                'significant': self.passes_beyond_pose},
                'pose_beyond': {'gain_per_matched_point': round(self.pose_gain_beyond, 6),
                                'z': round(self.pose_z_beyond, 3),
                                'significant': self.pose_passes_beyond,
                                'constant': self.pose_constant,
                                'explains_material_offsets': self.pose_explains_materials},
                'outcome': self.outcome}


def region_against_pose(data: lk.FitData, effects: list, blocks: np.ndarray,
                        pose_on: Callable[[lk.FitData], object], z_crit: float,
                        min_gain: float, seed: int = 0) -> RegionOffset | None:
    """The split against the reference pose with ``effects`` in the model.
    ``pose_on(data)``: the caller's pose test (``pose_error.fit_reference_pose``, the
    kind reported, per cloud or constant, with ``effects``) on ``data``'s matched points
    (``blocks`` per point). The split alone, the split on the residual the pose's
    correction leaves, and the pose's test on the model with the split's offsets. None
    where the points carry no faces or no material has enough points for a split."""
    body = body_points_m(data.baseline.ctx)
    material = np.asarray(data.baseline.ctx.material, int)
    if body is None or len(body) != len(material):
        return None
    r, s, use = footing(data, effects)
    alone = heldout_split(r, s, material, body, use, blocks, seed)
    if alone.split is None:
        return None
    pose = pose_on(data)
    corrected = pose_error.corrected(data, np.asarray(pose.correction_m, float))
    r_p, s_p, use_p = footing(corrected, effects)
    on_pose = heldout_split(r_p, s_p, material, body, use_p, blocks, seed)
    beyond = pose_on(pose_error.corrected(data, alone.correction_m))

    def passes(gain: float, z: float) -> bool:
        return bool(z >= z_crit and gain >= min_gain)
    names = list(getattr(getattr(data.baseline.ctx.scene, 'target', None),
                         'material_names', []) or [])
    m = alone.split.material
    return RegionOffset(
        material=names[m] if 0 <= m < len(names) else f'material {m}',
        axis=AXIS_NAMES[alone.split.axis], threshold_m=alone.split.threshold_m,
        step_m=alone.offsets_m[1] - alone.offsets_m[0], points=alone.points,
        gain=alone.gain, z=alone.z, gain_beyond_pose=on_pose.gain,
        z_beyond_pose=on_pose.z, pose_gain_beyond=float(beyond.gain),
        pose_z_beyond=float(beyond.z), pose_passes_beyond=bool(beyond.significant),
        passes=passes(alone.gain, alone.z),
        passes_beyond_pose=passes(on_pose.gain, on_pose.z),
        pose_constant=bool(getattr(pose, 'constant', False)),
        pose_explains_materials=bool(getattr(pose, 'joint', False)
                                     or getattr(pose, 'through_materials', False)))


def judge(decision, region: RegionOffset | None):
    """``decision`` (``diagnosis.Decision``) with the reference pose weighed against one
    part of a material reading off the rest (module doc): the pose stays where its test
    passes on top of the split (or where the split does not pass alone: no part reads
    off); otherwise it is not reported, and the split is kept (``region``) for the
    verdict: part of the target reads off the rest, or the two cannot be told apart."""
    if region is None:
        return decision
    if region.outcome == 'pose':
        return replace(decision, region=region)
    return replace(decision, pose=None, region=region)


def weigh_pose(decision, cands: list, data: lk.FitData, blocks: np.ndarray,
               pose_test: Callable, z_crit: float, min_gain: float, seed: int = 0):
    """``decision`` with a reported reference pose weighed against one part of a
    material reading off the rest (``region_against_pose``, ``judge``). ``pose_test(
    on_top, constant, data)``: the diagnosis's pose test on ``data``'s matched points
    (``blocks`` per point). Asked only where the pose is reported on its own held-out
    test (not tied, not on the raycast footing alone), with the named effect and the
    one that also explains a part in the model. ``pose_test`` takes ``orientations``
    (``pose_error.fit_reference_pose``): not asked again here."""
    pose = decision.pose
    if (pose is None or 'pose_error' in decision.confounded_with
            or getattr(pose, 'raycast', None) or not getattr(pose, 'significant', False)):
        return decision
    by_name = {c.name: c for c in cands}
    effects = [by_name[n].effect for n in (decision.missing, decision.also)
               if n in by_name and by_name[n].effect is not None]
    constant = bool(getattr(pose, 'constant', False))
    try:
        # The reported pose already held across the surfaces' orientations; here it is
        # asked whether it gains beyond the split (with the split's offsets in, a true
        # rigid motion need not hold across them: a 3 cm shift of a cylinder did not).
        region = region_against_pose(
            data, effects, blocks,
            lambda d: pose_test(effects, constant, d, orientations=False), z_crit,
            min_gain, seed)
    except Exception:  # noqa: BLE001 - the pose judged as before (a failed fit names nothing)
        return decision
    return judge(decision, region)
