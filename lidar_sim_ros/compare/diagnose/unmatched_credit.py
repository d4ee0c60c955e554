"""Which of the points a candidate puts back on the target count for it (``unmatched
credit``): points that miss the silhouette mark pose and timing errors as much as any
effect, so they count only with the candidate's own signature (a footprint's edge returns
at their power fraction; a whole beam's power for an effect that moves whole rays).
Powers in W, ranges in m.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.model.likelihood import is_outlier_effect
from lidar_sim_ros.compare.model.materials import robust_sigma
from lidar_sim_ros.core.effects import Effect


def footprint_signature(data, effects: list[Effect]) -> np.ndarray:
    """(M,) bool: unmatched points the model with ``effects`` puts back on the target
    with a partial footprint, whose measured power shows that fraction: nearer the
    predicted partial power than the full beam's (below their geometric mean). A point
    just beyond the silhouette because the pose is off returns the full beam's power;
    one on the beam's edge only its fraction. All False without measured power."""
    m = len(data.unmatched_range_m)
    if data.unmatched_power_w is None or m == 0:
        return np.zeros(m, bool)
    recast = lk.recast_unmatched(data, effects)
    if recast is None:
        return np.zeros(m, bool)
    ctx, expected, sigma = recast
    pred = data.cast_unmatched(lk.moving([*data.base_effects, *effects]))
    frac = pred.hits.power_fraction
    if frac is None:
        return np.zeros(m, bool)
    frac = np.asarray(frac, float)
    sig = np.maximum(np.nan_to_num(sigma, nan=np.inf), lk.MIN_SIGMA_M)
    measured = np.asarray(data.unmatched_power_w, float)
    with np.errstate(invalid='ignore', divide='ignore'):
        placed = (np.asarray(ctx.hit, bool) & (ctx.power_w >= ctx.threshold_power_w)
                  & (np.abs(np.asarray(data.unmatched_range_m) - expected) <= lk.UNMATCHED_Z * sig))
        full = ctx.power_w / frac
        partial = placed & (frac < 1.0) & np.isfinite(measured) & (measured > 0)
        return partial & (measured < np.sqrt(ctx.power_w * full))


def full_power_placed(data, effects: list[Effect]) -> np.ndarray | None:
    """(M,) bool: unmatched points the model with ``effects`` puts back on the target
    whose measured power is a whole beam's, as the model predicts: not below it by more
    than UNMATCHED_Z of the spread that the matched points' own measured-to-predicted
    power ratio shows (ln, median and robust sigma). A surface standing proud, a turned
    beam or a clock offset moves the whole beam onto the target, so what it places
    returns as strongly as any point; a footprint's edge returns carry only the share
    of the beam that hit (weaker, near the threshold), and a rigid effect that places
    them takes a footprint's points (the battery's ``beam_divergence_first``, eleventh
    holdout ``beam_solar_incid``). None without measured power or where nothing is
    re-cast (point times unknown): nothing to judge by."""
    m = len(data.unmatched_range_m)
    if data.unmatched_power_w is None or data.measured_power_w is None or m == 0:
        return None
    recast = lk.recast_unmatched(data, effects)
    if recast is None:      # nothing placed by a re-cast (e.g. point times unknown)
        return None
    ctx, expected, sigma = recast
    with np.errstate(invalid='ignore', divide='ignore'):
        ref = np.log(np.asarray(data.measured_power_w, float)
                     / np.asarray(data.baseline.ctx.power_w, float))
        ref = ref[np.isfinite(ref)]
        if len(ref) < lk.MIN_MATERIAL_POINTS:
            return None
        floor = float(np.median(ref)) - lk.UNMATCHED_Z * max(robust_sigma(ref), 1e-6)
        measured = np.asarray(data.unmatched_power_w, float)
        sig = np.maximum(np.nan_to_num(sigma, nan=np.inf), lk.MIN_SIGMA_M)
        placed = (np.asarray(ctx.hit, bool) & (ctx.power_w >= ctx.threshold_power_w)
                  & (np.abs(np.asarray(data.unmatched_range_m) - expected) <= lk.UNMATCHED_Z * sig))
        whole = np.log(measured / ctx.power_w) >= floor
        # A point without a measured power cannot show a fraction: it keeps its credit.
        return placed & (whole | ~(np.isfinite(measured) & (measured > 0)))


def unmatched_credit(data, effects: list[Effect], effect: Effect, gained: float) -> float:
    """How many of the ``gained`` unmatched points (those ``effect`` explains beyond the
    model's own effects) count for it: the points that miss the silhouette are the mark
    of pose and timing errors as much as of any effect, so they count only with the
    effect's own signature. False returns: isolated points at uniform ranges (already
    all that ``likelihood.unmatched_explained`` credits them); a footprint: edge returns
    at its power fraction (``footprint_signature``); any other ray-moving effect: judged
    by its matched points (``Diagnosis._set_gain``), and off the target only where the
    points it places return a whole beam's power (``full_power_placed``)."""
    if gained <= 0 or is_outlier_effect(type(effect)):
        return max(gained, 0.0)
    if effect.cast_reach_rad(1.0) is not None:     # a footprint: it reaches only so far
        return float(min(gained, footprint_signature(data, effects).sum()))
    whole = full_power_placed(data, effects)
    return gained if whole is None else float(min(gained, whole.sum()))
