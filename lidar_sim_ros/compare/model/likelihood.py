"""The likelihood of measured ranges under the model plus effects: what every fit maximises.

``lidar-sim compare`` casts every measured point's own ray through the model
(``Simulator.predict``) and hands the result here as :class:`FitData`. The model's
predictive density of a matched point's measured range r is

    p(r) = (1 - w) N(r; mu + c_m, (s_m sigma)^2) + w / W

mu: expected range (true range + material bias + effect biases); sigma: predicted
noise (material sigma and effect sigmas in quadrature); w: the effects' outlier
fraction; W: width of the range window of spurious returns. ``c_m`` and ``s_m``
are per-material nuisance parameters (a bias offset and a sigma scale, re-estimated
robustly for every model: median and median of z^2). They keep a per-material
constant mismatch -- a calibration matter, reported by the comparison under
``materials`` -- from ever being credited to a physical effect, and they make
effects whose bias has a per-material mean (range walk, incidence angle) be
identified from the variation within each material, not from the offsets.

An effect that adds ghosts along a shot's own line of sight (``Effect.extra_returns``
with a ``ghost_scale`` parameter the ghost power is proportional to: multipath) adds a
third component: p(r) = (1 - w) [(1 - g) N(echo) + g N(r; r_g + b_B, s_g^2)] + w / W,
r_g the ghost's range behind the specular surface (``|SA| + |AB|``), b_B the bias of the
surface B the mirror ray meets, s_g = hypot(sigma_B, GHOST_SPREAD |AB|) (the lobe spreads
the ray over B: one mirror ray stands for the lobe). g, the ghost's share of the points
its shot reports, is a trigger probability that saturates with the ghost's power over
the detection threshold: g = 1 - exp(-P_ghost / P_threshold) (Poisson triggers of mean
P / P_threshold), so a fit of the scale on the ghost power is smooth. The ghosts are
cast once per prediction at the top of the scale's bounds and scaled (``ghosts_on``).

w never drops below MODEL_FLOOR (1e-6): no real sensor is free of spurious returns,
and without a floor one point on the wrong side of a depth step (z ~ 100) would
outweigh thousands of good ones. A matched point whose ray misses the target under
a candidate model (a pose shift, a different footprint) counts as a spurious return
of weight max(w, MISS_WEIGHT).

This module sits above the pipeline (it re-runs ``Simulator.predict`` through the
callables of :class:`FitData`); effect classes never import it. The fits that
maximise it are in ``compare/model/fit.py``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Callable, Sequence

import numpy as np

from lidar_sim_ros.core.effects.base import Effect, ReturnContext, apply_effects
from lidar_sim_ros.core.effects.surface_offset import by_material_id
from lidar_sim_ros.core.pipeline import Prediction
from lidar_sim_ros.core.pose import PoseCoverageError

MIN_SIGMA_M = 1e-4            # noise floor of the likelihood (m): a zero sigma is never exact
MIN_MATERIAL_POINTS = 30      # fewer matched points: no per-material nuisance for that material
MODEL_FLOOR = 1e-6            # least outlier weight of the predictive density (module doc)
ROBUST_FLOOR = 1e-3           # outlier weight assumed while fitting non-outlier effects
# A surface moved by a few cm changes a ray's range on the same surface by at most
# sqrt(2 R s) at a limb (R 1.5 m, s 5 cm: 0.39 m); a larger jump is another surface.
SILHOUETTE_JUMP_M = 0.5
MISS_WEIGHT = 1e-3            # least outlier weight of a point the model cannot place
UNMATCHED_Z = 5.0             # an unmatched ray that now hits within this many sigma is explained
CHI2_1_MEDIAN = 0.454936423   # median of z^2 for z ~ N(0, 1)
GHOST_SPREAD = 0.05           # ghost range sigma per metre of |AB| (the lobe over B, module doc)
MAX_GHOST_SHARE = 1.0 - 1e-9  # a shot's echo keeps some weight (log of 1 - g finite)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


@dataclass(frozen=True)
class FitData:
    """Ray-matched measurement vs model, the input of every fit.

    Matched = the measured point's ray hits the target (under the model's geometry).

    ``baseline`` is the raycast, reflection and per-material bias/sigma on the matched
    rays, with the ray-moving effects of ``base_effects`` (pose time, cast) in its
    geometry but NO effect's bias, noise, power or outlier hooks: every effect, those
    of ``base_effects`` and the candidates, acts through its hooks in
    :func:`model_on_rays`, so that power-driven effects can read the measured power.
    ``cast(effects)`` re-predicts the same rays with these ray-moving effects (hooks
    not applied; results cached).
    """

    measured_range_m: np.ndarray          # (N,) matched points' measured ranges
    baseline: Prediction                  # the model's geometry on those rays (class doc)
    cast: Callable[[list[Effect]], Prediction]   # the same rays, these ray-moving effects
    unmatched_range_m: np.ndarray         # (M,) ranges of points whose rays miss the target
    cast_unmatched: Callable[[list[Effect]], Prediction]   # same for the unmatched rays
    range_window_m: tuple[float, float]   # support of spurious-return ranges (min, max)
    base_effects: tuple[Effect, ...] = ()   # the model's effects, applied through their hooks
    # (N,) received power (W, model units) from the measured intensity, NaN where unknown;
    # power-driven effects read it instead of the model's power (None: model power).
    measured_power_w: np.ndarray | None = None
    extra_var_m2: np.ndarray | float = 0.0   # (N,) variance the model adds (unknown point times)
    n_shots: int | None = None            # shots fired if known (else None)
    # Shots that gave no matched point, per unmatched point (``fit_data_from_rays``: from
    # ``n_shots``; compare: from the scan pattern's shots per frame or an organised
    # cloud's size, ``compare.shots``); None: unknown.
    missed_per_unmatched: float | None = None
    # (M,) unmatched points no neighbouring ray sees at the same range: only these can be
    # spurious returns (a surface that is not the target, e.g. lab clutter, is not).
    unmatched_isolated: np.ndarray | None = None
    # The points' own times are unknown (clouds without a time field): whether a ray near
    # the silhouette hits the target at its real time is unknown too, so a candidate that
    # moves the rays neither loses the points it no longer places (they keep the
    # model's prediction) nor gains the unmatched ones it now places.
    placement_uncertain: bool = False
    # (M,) received power (W, model units) of the unmatched points from the measured
    # intensity (NaN where unknown; None: no intensity): a footprint's edge returns must
    # show its power fraction to be credited to it (``unmatched_credit.footprint_signature``).
    unmatched_power_w: np.ndarray | None = None
    # Where a false return on a shot that misses the target can lie (m): the sensor's
    # range gate, which a miss listens over whole (None: ``range_window_m``). The
    # unmatched points' uniform share is judged over it: isolated points that all sit
    # at the target's ranges are no background when the gate reaches far beyond them.
    miss_window_m: tuple[float, float] | None = None

    @property
    def miss_window(self) -> tuple[float, float]:
        return self.miss_window_m if self.miss_window_m is not None else self.range_window_m

    @property
    def window_width_m(self) -> float:
        lo, hi = self.range_window_m
        return max(float(hi) - float(lo), 1e-3)

    @cached_property
    def members(self) -> list[tuple[int, np.ndarray]]:
        """(material id, indices of its matched points), computed once."""
        return group_members(np.asarray(self.baseline.ctx.material, int))

    @cached_property
    def base_expected_m(self) -> np.ndarray:
        """(N,) expected range (m) of the model with its own effects (``base_effects``)
        and no candidate: what an added effect's shift is measured from
        (``unprofiled_offset``), computed once."""
        return apply_hooks(self.baseline, list(self.base_effects), self.measured_power_w,
                           self.extra_var_m2)[1]

    @cached_property
    def false_returns(self) -> float:
        """``false_returns_off_target`` (it reads the data only), computed once: a fit
        asks it at every trial value (``missed_shots_nll``)."""
        return false_returns_off_target(self)


def group_members(group: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(value, indices) of every distinct value of ``group``."""
    order = np.argsort(group, kind='stable')
    values, starts = np.unique(group[order], return_index=True)
    bounds = np.append(starts, len(group))
    return [(int(v), order[bounds[k]:bounds[k + 1]]) for k, v in enumerate(values)]


class RaysOnly(Effect):
    """An effect's ray geometry only (``pose_time_s``, ``seen_target``, ``beam_directions``, ``cast``) for ``Simulator.predict``:
    its bias, noise, power and outlier hooks are applied by the likelihood instead."""

    name = 'rays_only'
    needs_repredict = True

    def __init__(self, effect: Effect):   # no Params of its own
        self.inner = effect
        self.params = effect.params

    def pose_time_s(self, t_s: np.ndarray) -> np.ndarray:
        return self.inner.pose_time_s(t_s)

    def seen_target(self, target):
        return self.inner.seen_target(target)

    def beam_directions(self, directions_lidar, laser):
        return self.inner.beam_directions(directions_lidar, laser)

    def cast(self, target, directions_lidar, poses, divergence_rad):
        return self.inner.cast(target, directions_lidar, poses, divergence_rad)


def moving(effects: Sequence[Effect]) -> list[Effect]:
    """The effects that change the pose time or the raycast."""
    return [e for e in effects if getattr(e, 'needs_repredict', False)]


def effect_key(effects: Sequence[Effect]) -> tuple:
    """A hashable identity of a list of effects (class and parameter values)."""
    return tuple((type(e).__module__, type(e).__qualname__,
                  tuple(sorted((k, repr(v)) for k, v in e.params.model_dump().items())))
                 for e in effects)


class PredictionCache:
    """``predict(effects)`` memoised by the effects' classes and parameters: a fit that
    re-visits a trial value (grid, Brent, final scoring) pays one raycast for it."""

    def __init__(self, predict: Callable[[list[Effect]], Prediction], size: int = 24):
        self._predict, self._size = predict, size
        self._memo: dict[tuple, Prediction] = {}

    def __call__(self, effects: Sequence[Effect]) -> Prediction:
        key = effect_key(effects)
        if key not in self._memo:
            if len(self._memo) >= self._size:
                self._memo.pop(next(iter(self._memo)))
            self._memo[key] = self._predict(list(effects))
        return self._memo[key]


# ----------------------------------------------------------------- the model on rays
@dataclass(frozen=True)
class ModelOnRays:
    """Predictive distribution of each matched point's range under a model."""

    ctx: ReturnContext
    expected_range_m: np.ndarray
    sigma_m: np.ndarray
    outlier_w: np.ndarray
    placed: np.ndarray            # the model's ray hits the target
    # Ghost component (module doc), or None without a ghost effect: per point the
    # expected ghost range (m, NaN: no ghost), its sigma (m) and share g (0..1).
    ghost_range_m: np.ndarray | None = None
    ghost_sigma_m: np.ndarray | None = None
    ghost_w: np.ndarray | None = None


@dataclass(frozen=True)
class Ghosts:
    """Ghosts of a ghost effect on the rays of one prediction, cast at ``probe`` (the top
    of the effect's ``ghost_scale`` bounds): index of the ray, expected range (m: true
    ghost range plus B's material bias), sigma (m) and power per unit scale (W)."""

    index: np.ndarray
    range_m: np.ndarray
    sigma_m: np.ndarray
    power_per_scale_w: np.ndarray
    threshold_w: float
    probe: float


_GHOSTS: dict[tuple, tuple[Prediction, Ghosts | None]] = {}
_GHOSTS_SIZE = 64


def is_ghost_effect(effect: Effect) -> bool:
    """Whether the effect adds ghosts the likelihood scores (``ghost_scale`` declared)."""
    return bool(getattr(type(effect), 'ghost_scale', None))


def ghosts_on(pred: Prediction, effect: Effect) -> Ghosts | None:
    """The ghosts ``effect`` adds to ``pred``'s rays, cast once per prediction and effect
    (all parameters but the scale): at the top of the scale's bounds, so every ghost a
    smaller scale could make is there, its power then proportional to the scale."""
    scale = type(effect).ghost_scale
    params = effect.params.model_dump()
    probe = float(type(effect).bounds[scale][1])
    key = (id(pred), type(effect).__module__, type(effect).__qualname__,
           tuple(sorted((k, repr(v)) for k, v in params.items() if k != scale)))
    hit = _GHOSTS.get(key)
    if hit is not None and hit[0] is pred:
        return hit[1]
    extra = type(effect)({**params, scale: probe}).extra_returns(pred.ctx)
    ghosts = None
    if extra is not None and len(extra):
        mats = pred.ctx.scene.materials
        bias, sigma = mats.column('bias_m'), mats.column('sigma_m')
        mat_b = np.asarray(extra.material, int)
        index = np.asarray(extra.shot, np.int64)
        path = extra.range_m - pred.ctx.range_m[index]
        ghosts = Ghosts(index=index, range_m=extra.range_m + bias.take(mat_b),
                        sigma_m=np.hypot(sigma.take(mat_b), GHOST_SPREAD * path),
                        power_per_scale_w=np.asarray(extra.power_w, float) / probe,
                        threshold_w=float(pred.ctx.threshold_power_w), probe=probe)
    if len(_GHOSTS) >= _GHOSTS_SIZE:
        _GHOSTS.pop(next(iter(_GHOSTS)))
    _GHOSTS[key] = (pred, ghosts)
    return ghosts


def ghost_component(pred: Prediction, effects: Sequence[Effect], n: int):
    """(ghost range m, sigma m, share g) per ray of the ghost effects among ``effects``
    (the last one wins where two predict a ghost), or (None, None, None)."""
    found = [e for e in effects if is_ghost_effect(e)]
    if not found or pred.ctx.scene is None:
        return None, None, None
    rng, sig, share = np.full(n, np.nan), np.ones(n), np.zeros(n)
    for eff in found:
        value = float(getattr(eff.params, type(eff).ghost_scale))
        gh = ghosts_on(pred, eff)
        if gh is None or value <= 0:
            continue
        rng[gh.index], sig[gh.index] = gh.range_m, np.maximum(gh.sigma_m, MIN_SIGMA_M)
        share[gh.index] = np.minimum(-np.expm1(-value * gh.power_per_scale_w
                                               / max(gh.threshold_w, 1e-300)), MAX_GHOST_SHARE)
    return rng, sig, share


def _outlier_weight(effects: Sequence[Effect], ctx: ReturnContext, n: int) -> np.ndarray:
    keep = np.ones(n)
    for eff in effects:
        w = np.clip(np.broadcast_to(np.asarray(eff.outlier_fraction(ctx), float), (n,)), 0.0, 1.0)
        keep = keep * (1.0 - w)
    return 1.0 - keep


def needs_repredict(effects: Sequence[Effect]) -> bool:
    return bool(moving(effects))


def reads_measured_power(effect: Effect) -> bool:
    """A power-driven effect (``Effect.power_driven``) that reads the measured intensity's
    power, not the model's (a walk's ``power`` option, ``range_walk.py``)."""
    return (bool(getattr(effect, 'power_driven', False))
            and getattr(effect.params, 'power', 'measured') == 'measured')


def apply_hooks(pred: Prediction, effects: Sequence[Effect],
                measured_power_w: np.ndarray | None = None,
                extra_var_m2: np.ndarray | float = 0.0) -> tuple[ReturnContext, np.ndarray,
                                                                   np.ndarray]:
    """(ctx, expected range m, sigma m) of ``pred`` with the effects' hooks applied.

    Power-driven effects (``Effect.power_driven``) read ``measured_power_w`` where it is
    known (the sensor's own measure of the pulse that made the point), the others the
    model's power; ``extra_var_m2`` adds to every point's variance.
    """
    effects = list(effects)
    driven = ([e for e in effects if reads_measured_power(e)]
              if measured_power_w is not None else [])
    rest = [e for e in effects if not any(e is d for d in driven)]
    var0 = np.asarray(pred.sigma_m, float) ** 2 + extra_var_m2
    ctx, bias, var = apply_effects(pred.ctx, rest, pred.bias_m, var0)
    if driven:
        model_p = np.asarray(ctx.power_w, float)
        known = np.isfinite(measured_power_w) & (measured_power_w > 0) & (model_p > 0)
        power = np.where(known, measured_power_w, model_p)
        with np.errstate(divide='ignore', invalid='ignore'):
            intensity = np.where(model_p > 0, ctx.intensity * power / model_p, ctx.intensity)
        measured_ctx = replace(ctx, power_w=power, intensity=intensity)
        _, bias, var = apply_effects(measured_ctx, driven, bias, var)
    expected = np.where(np.asarray(ctx.hit, bool), ctx.range_m + bias, np.nan)
    return ctx, np.asarray(expected, float), np.sqrt(np.asarray(var, float))


def model_on_rays(data: FitData, effects: Sequence[Effect]) -> ModelOnRays:
    """The model's effects plus ``effects`` on the matched rays (re-cast if one of
    ``effects`` moves the rays; every hook applied here)."""
    effects = list(effects)
    everything = [*data.base_effects, *effects]
    n = len(data.measured_range_m)
    pred = data.cast(moving(everything)) if moving(effects) else data.baseline
    ctx, expected, sigma = apply_hooks(pred, everything, data.measured_power_w,
                                       data.extra_var_m2)
    placed = np.asarray(ctx.hit, bool) & np.isfinite(expected) & np.isfinite(sigma)
    if data.placement_uncertain and moving(effects) and not placed.all():
        _, base_expected, base_sigma = apply_hooks(data.baseline, everything,
                                                   data.measured_power_w, data.extra_var_m2)
        lost = ~placed & np.isfinite(base_expected) & np.isfinite(base_sigma)
        expected = np.where(lost, base_expected, expected)
        sigma = np.where(lost, base_sigma, sigma)
        placed = placed | lost
    if moves_surfaces(effects):
        crossed = crossed_silhouette(data.baseline, pred, material_standoffs_m(pred, effects))
        if crossed.any():
            _, base_expected, base_sigma = apply_hooks(data.baseline, everything,
                                                       data.measured_power_w, data.extra_var_m2)
            base_expected = base_expected + own_face_shift_m(data.baseline, effects)
            expected = np.where(crossed, base_expected, expected)
            sigma = np.where(crossed, base_sigma, sigma)
            placed = np.where(crossed, np.isfinite(base_expected) & np.isfinite(base_sigma),
                              placed)
    w = _outlier_weight(everything, ctx, n)
    ghost_range, ghost_sigma, ghost_w = ghost_component(pred, everything, n)
    return ModelOnRays(ctx, expected, sigma, w, placed, ghost_range, ghost_sigma, ghost_w)


def moves_surfaces(effects: Sequence[Effect]) -> bool:
    """Whether one of ``effects`` moves the target's surfaces (``Effect.seen_target``:
    a standoff, a scale), rather than the rays or the pose."""
    return any(type(e).seen_target is not Effect.seen_target for e in effects)


def crossed_silhouette(base: Prediction, pred: Prediction,
                       standoff_m: np.ndarray | None = None) -> np.ndarray:
    """Per matched ray, whether moving the surfaces took it across a silhouette or a
    blanket's edge: it now meets a surface more than SILHOUETTE_JUMP_M nearer or farther
    than on the mesh (a ray past a limb now stopped by the proud limb, the part behind
    it lost), or moved from a bare face to a proud one or back (``standoff_m``: per
    material id, m; the rim of a blanket over some materials onto bare structure). A
    standoff of a few cm decides such a ray only through the shape of the edge within
    those cm, which the mesh does not give (a rim, a ramp, or a lab's surface read proud
    along each ray with its silhouette left where the mesh has it): it is placed on its
    own face of the mesh, that face moved (``own_face_shift_m``), neither evidence for
    the standoff's edges nor against them. A ray moved within a
    surface, or over a seam between faces that both move (a box proud all over, by one
    standoff or by its materials' own), still counts.
    Both predictions must place the ray."""
    r0 = np.asarray(base.expected_range_m, float)
    r1 = np.asarray(pred.expected_range_m, float)
    both = (np.asarray(base.ctx.hit, bool) & np.asarray(pred.ctx.hit, bool)
            & np.isfinite(r0) & np.isfinite(r1))
    with np.errstate(invalid='ignore'):
        out = both & (np.abs(r1 - r0) > SILHOUETTE_JUMP_M)
    if standoff_m is not None:
        bare = np.abs(standoff_m) < 1e-12
        out |= both & (by_material_id(bare, base.ctx.material)
                       != by_material_id(bare, pred.ctx.material))
    return out


def own_face_shift_m(base: Prediction, effects: Sequence[Effect]) -> np.ndarray | float:
    """Per ray, the range change (m) ``effects`` make to first order on the face it meets
    on the mesh (``first_order_shift_m`` of a surface offset): where a crossed ray is
    placed, on its own face moved, so that it neither pulls its material's profiled
    offset nor is pulled by it (the faces around it moved, it would be off by their
    standoff). 0 without a surface offset or the material names."""
    scene = base.ctx.scene
    names = None if scene is None else getattr(scene.target, 'material_names', None)
    if names is None:
        return 0.0
    return sum((e.first_order_shift_m(base.ctx, names) for e in effects
                if hasattr(e, 'first_order_shift_m')), 0.0)


def material_standoffs_m(pred: Prediction, effects: Sequence[Effect]) -> np.ndarray | None:
    """Per material id, how far ``effects`` move its faces (m; ``standoffs_by_material_m``
    of a surface offset), or None where none says or the material names are unknown."""
    scene = pred.ctx.scene
    names = None if scene is None else getattr(scene.target, 'material_names', None)
    tables = [e.standoffs_by_material_m(names) for e in effects
              if names is not None and hasattr(e, 'standoffs_by_material_m')]
    return np.sum(tables, axis=0) if tables else None


def recast_unmatched(data: FitData, effects: Sequence[Effect]):
    """(ctx, expected range, sigma) of the unmatched rays under the model's effects plus
    ``effects`` (which move the rays), or None if none of ``effects`` moves them."""
    effects = list(effects)
    if not moving(effects) or len(data.unmatched_range_m) == 0 or data.placement_uncertain:
        return None
    everything = [*data.base_effects, *effects]
    return apply_hooks(data.cast_unmatched(moving(everything)), everything)


# --------------------------------------------------------------------- likelihood
def _groups(data: FitData) -> np.ndarray:
    return np.asarray(data.baseline.ctx.material, int)


def median(values: np.ndarray) -> np.float64:
    """np.median of a 1-D float array, the same value (NaN if one is NaN), without
    np.median's generic overhead: the fits take ~50 000 medians of a few hundred points
    per compare (``material_nuisance``), where the overhead was 3/4 of their cost."""
    n = values.size
    h = n // 2
    if n % 2:
        part = np.partition(values, (h, n - 1))
        mid = part[h]
    else:
        part = np.partition(values, (h - 1, h, n - 1))
        mid = (part[h - 1] + part[h]) / 2.0
    return np.float64(np.nan) if np.isnan(part[-1]) else mid


def material_nuisance(residual_m: np.ndarray, sigma_m: np.ndarray, group: np.ndarray,
                      use: np.ndarray, members: list | None = None) -> tuple[np.ndarray,
                                                                            np.ndarray]:
    """Per-point offset c_m (m) and sigma scale s_m (-) of each point's material.

    c_m = median residual, s_m^2 = median((r - c_m)^2 / sigma^2) / median(chi2_1), over
    the material's usable points; materials with fewer than MIN_MATERIAL_POINTS keep
    (0, 1). Medians keep spurious points from moving either. ``members``: the groups'
    point indices, if known (``group_members``).
    """
    offset = np.zeros(len(residual_m))
    scale = np.ones(len(residual_m))
    for _, idx in (members if members is not None else group_members(np.asarray(group))):
        sel = idx[use[idx]]
        if len(sel) < MIN_MATERIAL_POINTS:
            continue
        r = residual_m[sel]
        c = float(median(r))
        z2 = ((r - c) / sigma_m[sel]) ** 2
        s = math.sqrt(max(float(median(z2)) / CHI2_1_MEDIAN, 1e-6))
        offset[idx] = c
        scale[idx] = s
    return offset, scale


def unprofiled_offset(data: FitData, expected_m: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Per point, the offset (m) a material too small for its own (fewer than
    MIN_MATERIAL_POINTS usable points, ``material_nuisance``) takes under a model whose
    effects move its ranges: the median shift of the effects added to the model's own
    (``expected_m`` less ``FitData.base_expected_m``) over its points, taken back; 0
    elsewhere. Its offset was calibrated with the model's own effects, as every material's
    is profiled: an effect with a constant part (a walk's -k ln(P / P_threshold), -18 cm
    at 10 m) then moves a large material's offset with it but left a small one's at 0, and
    its dozen points lost 15 nats each to a shift that is nobody's (walk_graze s7, a
    material of 12 points per fold: the walk's held-out z 2.1 against 11.0)."""
    out = np.zeros(len(expected_m))
    small = [idx[use[idx]] for _, idx in data.members
             if 0 < int(np.sum(use[idx])) < MIN_MATERIAL_POINTS]
    if not small:
        return out
    shift = np.asarray(expected_m, float) - data.base_expected_m
    for sel in small:
        ok = sel[np.isfinite(shift[sel])]
        if len(ok):
            out[sel] = -float(np.median(shift[ok]))
    return out


def point_nll(data: FitData, model: ModelOnRays, floor: float = 0.0,
              profile_materials: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Per-point negative log-likelihood (nats) and residual (m) of the matched points.

    ``floor`` adds an outlier weight (robust fitting); unplaced points score as
    spurious returns; residuals of unplaced points are taken against the baseline.
    """
    r = np.asarray(data.measured_range_m, float)
    placed = model.placed
    base_expected = np.asarray(data.baseline.expected_range_m, float)
    expected = np.where(placed, model.expected_range_m, base_expected)
    residual = r - expected
    sigma = np.maximum(np.where(placed, model.sigma_m, MIN_SIGMA_M), MIN_SIGMA_M)
    use = placed & np.isfinite(residual)
    if profile_materials:
        offset, scale = material_nuisance(residual, sigma, _groups(data), use, data.members)
        offset = offset + unprofiled_offset(data, expected, use)
        residual = residual - offset
        sigma = sigma * scale
    w = 1.0 - (1.0 - model.outlier_w) * (1.0 - max(floor, MODEL_FLOOR))
    width = data.window_width_m
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        z = residual / sigma
        log_gauss = -0.5 * z * z - np.log(sigma) - _LOG_SQRT_2PI
        if model.ghost_w is not None:
            # The ghost component (module doc): measured range against the ghost's, no
            # material nuisance (B's bias is in the ghost's expected range).
            g = np.where(np.isfinite(model.ghost_range_m), model.ghost_w, 0.0)
            zg = (r - model.ghost_range_m) / model.ghost_sigma_m
            log_ghost = -0.5 * zg * zg - np.log(model.ghost_sigma_m) - _LOG_SQRT_2PI
            log_gauss = np.where(g > 0, np.logaddexp(np.log1p(-g) + log_gauss,
                                                     np.log(g) + log_ghost), log_gauss)
        log_in = np.log1p(-np.minimum(w, 1.0)) + log_gauss
        log_out = np.log(w / width)
        ll = np.logaddexp(log_in, log_out)
        ll_miss = np.log(np.maximum(w, MISS_WEIGHT) / width)
    ll = np.where(use, ll, ll_miss)
    return -ll, np.where(np.isfinite(residual), residual, 0.0)


def uniform_share(ranges_m: np.ndarray, window: tuple[float, float],
                   target_ranges_m: np.ndarray) -> float:
    """ML share of points at uniform ranges over ``window`` rather than near the target.

    Two-component mixture: uniform over the window, or uniform over the target's
    span of ranges (+-1 m). Points of a beam edge or a pose error sit near the target;
    sunlight triggers are spread over the window.
    """
    if len(ranges_m) == 0:
        return 0.0
    lo, hi = window
    a = ((ranges_m >= lo) & (ranges_m <= hi)) / max(hi - lo, 1e-3)
    if len(target_ranges_m):
        t_lo, t_hi = np.min(target_ranges_m) - 1.0, np.max(target_ranges_m) + 1.0
        b = ((ranges_m >= t_lo) & (ranges_m <= t_hi)) / (t_hi - t_lo)
    else:
        b = np.zeros(len(ranges_m))
    keep = (a > 0) | (b > 0)
    if not np.any(keep):
        return 0.0
    a, b = a[keep], b[keep]
    share = 0.5
    for _ in range(200):
        resp = share * a / (share * a + (1.0 - share) * b)
        new = float(np.mean(resp))
        if abs(new - share) < 1e-7:
            break
        share = new
    return share * keep.mean()


def miss_outlier_weight(model: ModelOnRays, effects: Sequence[Effect]) -> float:
    """P(a false return) on a shot that misses the target, under ``effects``: a
    first-return receiver listens over the whole window there, not only up to an echo
    (``solar_background``, ``sunlight``), so it is not the matched points' mean weight.
    The matched rays' context with no echo stands in for a miss."""
    if not len(model.outlier_w):
        return 0.0
    ctx = model.ctx
    miss = replace(ctx, hit=np.zeros(len(ctx), bool), range_m=np.full(len(ctx), np.nan),
                   power_w=np.zeros(len(ctx)))
    try:
        w = _outlier_weight(list(effects), miss, len(ctx))
    except Exception:  # noqa: BLE001 - an effect that cannot take a miss: the hit mean
        return float(np.mean(model.outlier_w))
    return float(np.mean(w))


def unmatched_explained(data: FitData, effects: Sequence[Effect],
                        model: ModelOnRays | None = None) -> float:
    """Fraction (0..1) of unmatched points the effects account for.

    Two ways: a re-predicted ray now hits the target with a detectable power and a
    range within UNMATCHED_Z sigma (beam divergence, time offset); or spurious
    returns on shots that miss the target (outlier fraction x missed shots, at most
    the share of the isolated unmatched ranges that look uniform over the window). Missed
    shots are ``missed_per_unmatched x M`` when the shots fired are known, else assumed
    to be N.
    """
    effects = list(effects)
    r_u = np.asarray(data.unmatched_range_m, float)
    m = len(r_u)
    if m == 0:
        return 0.0
    hit_now = np.zeros(m, bool)
    recast = recast_unmatched(data, effects)
    if recast is not None:
        ctx, expected, sigma = recast
        sig = np.maximum(np.nan_to_num(sigma, nan=np.inf), MIN_SIGMA_M)
        with np.errstate(invalid='ignore'):
            hit_now = (np.asarray(ctx.hit, bool) & (ctx.power_w >= ctx.threshold_power_w)
                       & (np.abs(r_u - expected) <= UNMATCHED_Z * sig))
    rest = r_u[~hit_now & (True if data.unmatched_isolated is None
                           else np.asarray(data.unmatched_isolated, bool))]
    if model is None:
        model = model_on_rays(data, effects)
    w_mean = miss_outlier_weight(model, [*data.base_effects, *effects])
    spurious = 0.0
    if w_mean > 0 and len(rest):
        n = len(data.measured_range_m)
        missed = data.missed_per_unmatched * m if data.missed_per_unmatched is not None else n
        share = uniform_share(rest, data.miss_window, np.asarray(data.measured_range_m))
        spurious = min(share * len(rest), w_mean * missed)
    return float(min(1.0, (hit_now.sum() + spurious) / m))


def evaluate(data: FitData, effects: Sequence[Effect], profile_materials: bool = True,
             floor: float = 0.0) -> tuple[float, float, float]:
    """(nll_per_point, range_rmse_m, unmatched_explained) of the model with these effects.

    Both figures include the per-material nuisance (module docstring) unless
    ``profile_materials`` is False; the RMSE is the plain RMS over all matched points.
    ``floor`` > 0 scores with that extra outlier weight (the robust NLL of fits).
    """
    effects = list(effects)
    model = model_on_rays(data, effects)
    nll, residual = point_nll(data, model, floor, profile_materials)
    explained = unmatched_explained(data, effects, model)
    if len(nll) == 0:
        return float('nan'), float('nan'), explained
    return float(np.mean(nll)), float(np.sqrt(np.mean(residual ** 2))), explained


def scores(data: FitData, effects: Sequence[Effect]) -> dict:
    """All figures of a model in one prediction: nll, robust nll, rmse, unmatched."""
    effects = list(effects)
    model = model_on_rays(data, effects)
    nll, residual = point_nll(data, model, 0.0)
    nll_robust, _ = point_nll(data, model, ROBUST_FLOOR)
    n = max(len(nll), 1)
    return {'nll': float(np.sum(nll) / n), 'nll_robust': float(np.sum(nll_robust) / n),
            'rmse': float(np.sqrt(np.sum(residual ** 2) / n)),
            'unmatched': unmatched_explained(data, effects, model)}


def objective(data: FitData, effects: Sequence[Effect], floor: float = ROBUST_FLOOR) -> float:
    """Total NLL (nats) a fit minimises: matched points, plus unmatched points that a
    re-predicted model (new pose time or raycast) places back on the target."""
    effects = list(effects)
    try:
        model = model_on_rays(data, effects)
    except PoseCoverageError:
        return math.inf
    total = float(np.sum(point_nll(data, model, floor)[0]))
    m = len(data.unmatched_range_m)
    if m == 0:
        return total
    total += missed_shots_nll(data, model, effects)
    width = data.window_width_m
    ll_u = np.full(m, math.log(max(floor, MISS_WEIGHT) / width))
    try:
        recast = recast_unmatched(data, effects)
    except PoseCoverageError:
        return math.inf
    if recast is not None:
        ctx, expected, sigma = recast
        sig = np.maximum(np.nan_to_num(sigma, nan=1.0), MIN_SIGMA_M)
        ok = np.asarray(ctx.hit, bool) & (ctx.power_w >= ctx.threshold_power_w)
        with np.errstate(invalid='ignore', over='ignore'):
            z = (np.asarray(data.unmatched_range_m) - expected) / sig
            log_in = math.log1p(-floor) - 0.5 * z * z - np.log(sig) - _LOG_SQRT_2PI
            ll_u = np.where(ok & np.isfinite(z), np.logaddexp(log_in, ll_u), ll_u)
    return total - float(np.sum(ll_u))


def false_returns_off_target(data: FitData) -> float:
    """How many of the unmatched points are false returns: the isolated ones at uniform
    ranges over the window (``uniform_share``)."""
    r_u = np.asarray(data.unmatched_range_m, float)
    iso = (np.ones(len(r_u), bool) if data.unmatched_isolated is None
           else np.asarray(data.unmatched_isolated, bool))
    rest = r_u[iso]
    if not len(rest):
        return 0.0
    return uniform_share(rest, data.miss_window, np.asarray(data.measured_range_m)) * len(rest)


def missed_shots_nll(data: FitData, model: ModelOnRays, effects: Sequence[Effect]) -> float:
    """NLL (nats) of the false returns counted among the shots that missed the target
    (binomial: k of the N missed shots, each with the effects' probability of a false
    return on a miss, ``miss_outlier_weight``, at least MODEL_FLOOR); 0 when the shots
    fired are unknown. The misses hold most of a background's false returns: a shot
    that misses listens over the whole window, a first-return receiver's hit only up
    to its echo, so a rate fitted on the target's points alone rests on a handful."""
    if data.missed_per_unmatched is None or not len(data.unmatched_range_m):
        return 0.0
    n = float(data.missed_per_unmatched) * len(data.unmatched_range_m)
    k = min(data.false_returns, n)
    w = min(max(miss_outlier_weight(model, [*data.base_effects, *effects]), MODEL_FLOOR),
            1.0 - 1e-12)
    return -float(k * math.log(w) + (n - k) * math.log1p(-w))


def ghost_points(data: FitData, effects: Sequence[Effect]) -> int:
    """Matched points that lie at the range the ghost effects among ``effects`` predict
    behind their surface: within UNMATCHED_Z ghost sigmas of it and nearer the ghost than
    the echo (in sigmas of each): the signature of multipath."""
    model = model_on_rays(data, effects)
    if model.ghost_w is None:
        return 0
    r = np.asarray(data.measured_range_m, float)
    with np.errstate(invalid='ignore', divide='ignore'):
        zg = np.abs(r - model.ghost_range_m) / model.ghost_sigma_m
        ze = np.abs(r - model.expected_range_m) / np.maximum(model.sigma_m, MIN_SIGMA_M)
        at = (model.ghost_w > 0) & (zg <= UNMATCHED_Z) & (zg < ze)
    return int(np.sum(at))


def is_outlier_effect(effect_cls: type[Effect]) -> bool:
    """Whether the effect adds spurious returns (its likelihood is a mixture: it is fitted
    without the robust floor, and judged by the likelihood and the robust spread)."""
    return (effect_cls.outlier_fraction is not Effect.outlier_fraction
            or effect_cls.false_returns is not Effect.false_returns)
