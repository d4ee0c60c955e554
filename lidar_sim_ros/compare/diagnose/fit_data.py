"""The rays a diagnosis runs on, and the likelihood's data for them: the measured points
split into matched and unmatched rays (``RaySet``: sampled, split into folds), the model's
prediction on a subset of them, and ``make_fit_data``, which hands the likelihood a set of
rays with the model's baseline and a cache of re-casts. Ranges in m, powers in W.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.model.matching import Model, predict_rays
from lidar_sim_ros.compare.recording.measurements import Measurements
from lidar_sim_ros.core.effects import Effect
from lidar_sim_ros.core.geometry import Hits
from lidar_sim_ros.core.pipeline import Prediction


@dataclass(frozen=True)
class RaySet:
    """Measured points split into matched and unmatched rays, as index arrays into
    ``meas``, with what the comparison knows about every point (arrays over ``meas``):
    the model's geometry prediction (``pred``: raycast, reflection and per-material
    bias/sigma with the model's ray-moving effects, no effect hooks), the received power
    from the measured intensity, and any variance the model adds (unknown point times)."""

    meas: Measurements
    matched: np.ndarray
    unmatched: np.ndarray
    pred: Prediction | None = None
    measured_power_w: np.ndarray | None = None
    extra_var_m2: np.ndarray | None = None
    isolated: np.ndarray | None = None     # bool: no neighbouring ray sees the same range
    blocks: np.ndarray | None = None       # int: neighbourhood of each point (for SEs)
    edge_rad: np.ndarray | None = None     # distance to the nearest edge (NaN: unknown)
    # Shots without a matched point per unmatched point, in the whole recording (``shots``);
    # a sample keeps it: matched and unmatched rays are drawn separately.
    missed_per_unmatched: float | None = None

    def _with(self, matched: np.ndarray, unmatched: np.ndarray) -> 'RaySet':
        return replace(self, matched=matched, unmatched=unmatched)

    def sample(self, max_points: int, seed: int) -> 'RaySet':
        """At most ``max_points`` matched and as many unmatched rays, drawn at random."""
        rng = np.random.default_rng(seed)

        def pick(idx: np.ndarray) -> np.ndarray:
            return idx if len(idx) <= max_points else np.sort(rng.choice(idx, max_points, False))
        return self._with(pick(self.matched), pick(self.unmatched))

    def split(self, n_folds: int, seed: int) -> list['RaySet']:
        rng = np.random.default_rng(seed)
        fm = rng.permutation(len(self.matched)) % n_folds
        fu = rng.permutation(len(self.unmatched)) % n_folds
        return [self._with(np.sort(self.matched[fm == k]), np.sort(self.unmatched[fu == k]))
                for k in range(n_folds)]


def take_prediction(pred: Prediction, index: np.ndarray) -> Prediction:
    """The prediction on a subset of its rays (integer indices or a mask)."""
    h = pred.hits
    hits = Hits(*(None if v is None else v[index] for v in (
        h.hit, h.range_m, h.normal, h.incidence_rad, h.material, h.face, h.power_fraction,
        h.cos_incidence)))
    return Prediction(pred.ctx.subset(index), hits, pred.directions[index], pred.bias_m[index],
                      pred.sigma_m[index])


def range_window_m(meas: Measurements) -> tuple[float, float]:
    """Support of spurious-return ranges: the measured ranges, at least 1 m wide."""
    lo, hi = float(meas.range_m.min()), float(meas.range_m.max())
    if hi - lo < 1.0:
        lo, hi = max(0.0, lo - 0.5), hi + 0.5
    return lo, hi


def miss_window_m(meas: Measurements, model) -> tuple[float, float]:
    """Support of a false return on a shot that misses the target: the sensor's range
    gate (what a miss listens over), widened to the measured ranges."""
    lo, hi = range_window_m(meas)
    det = model.sensor.detection
    return min(lo, float(det.min_range_m)), max(hi, float(det.max_range_m))


def put_prediction(pred: Prediction, index: np.ndarray, part: Prediction) -> Prediction:
    """``pred`` with the rays ``index`` replaced by ``part`` (a prediction of those rays)."""
    def put(full, sub):
        if full is None and sub is None:
            return None
        if full is None:      # e.g. power_fraction: the whole beam elsewhere
            full = np.ones(len(pred.bias_m), np.asarray(sub).dtype)
        out = np.array(full, copy=True)
        out[index] = sub
        return out

    h, q = pred.hits, part.hits
    hits = Hits(*(put(getattr(h, k), getattr(q, k)) for k in (
        'hit', 'range_m', 'normal', 'incidence_rad', 'material', 'face', 'power_fraction',
        'cos_incidence')))
    ctx = replace(pred.ctx, **{k: put(v, getattr(part.ctx, k)) for k, v in pred.ctx.__dict__.items()
                               if isinstance(v, np.ndarray) and len(v) == len(pred.bias_m)})
    return Prediction(ctx, hits, pred.directions, put(pred.bias_m, part.bias_m),
                      put(pred.sigma_m, part.sigma_m))


def make_fit_data(model: Model, base_effects: list[Effect], rays: RaySet,
                  parent: tuple[lk.FitData, RaySet] | None = None) -> lk.FitData:
    """FitData for ``rays``: the model with ``base_effects`` (their hooks applied by the
    likelihood); ``cast(effects)`` re-predicts the rays with extra ray-moving effects.
    The baseline is sliced from ``rays.pred`` when given (it must have been predicted
    with the ray geometry of ``base_effects``), else predicted here. With ``parent`` (a
    FitData of a superset of the rays), casts are sliced from the parent's, so folds
    share the raycasts of the whole. An effect whose cast reaches only so far from its
    axis (``Effect.cast_reach_rad``) is re-cast on the rays near an edge only
    (``rays.edge_rad``), the others keep the baseline."""
    meas = rays.meas
    m_sub, u_sub = meas.subset(rays.matched), meas.subset(rays.unmatched)
    base_moving = lk.moving(base_effects)

    def caster(index: np.ndarray, sub: Measurements, base: Prediction | None) -> lk.PredictionCache:
        edge = None if rays.edge_rad is None else rays.edge_rad[index]

        def cast(effects: list[Effect]) -> Prediction:
            sim = model.simulator(effects=[lk.RaysOnly(e) for e in effects])
            reach = [e.cast_reach_rad(model.divergence_rad) for e in effects]
            if (base is not None and edge is not None and effects and not base_moving
                    and all(r is not None for r in reach)):
                near = np.flatnonzero(~(edge > max(reach) + 1e-9))   # NaN edge: near
                if len(near) == 0:
                    return base
                return put_prediction(base, near, predict_rays(sim, sub.subset(near)))
            return predict_rays(sim, sub)
        return lk.PredictionCache(cast)

    if parent is not None:
        pdata, prays = parent
        im = np.searchsorted(prays.matched, rays.matched)
        iu = np.searchsorted(prays.unmatched, rays.unmatched)
        cast = lk.PredictionCache(lambda e: take_prediction(pdata.cast(e), im))
        cast_un = lk.PredictionCache(lambda e: take_prediction(pdata.cast_unmatched(e), iu))
        baseline = take_prediction(pdata.baseline, im)
    else:
        base_m = (take_prediction(rays.pred, rays.matched) if rays.pred is not None else None)
        base_u = (take_prediction(rays.pred, rays.unmatched) if rays.pred is not None else None)
        cast = caster(rays.matched, m_sub, base_m)
        cast_un = caster(rays.unmatched, u_sub, base_u)
        baseline = base_m if base_m is not None else cast(base_moving)
    power = None if rays.measured_power_w is None else rays.measured_power_w[rays.matched]
    power_u = (None if rays.measured_power_w is None
               else rays.measured_power_w[rays.unmatched])
    extra = 0.0 if rays.extra_var_m2 is None else rays.extra_var_m2[rays.matched]
    isolated = None if rays.isolated is None else rays.isolated[rays.unmatched]
    return lk.FitData(
        measured_range_m=m_sub.range_m, baseline=baseline, cast=cast,
        unmatched_range_m=u_sub.range_m, cast_unmatched=cast_un,
        range_window_m=range_window_m(meas), miss_window_m=miss_window_m(meas, model),
        base_effects=tuple(base_effects), measured_power_w=power, extra_var_m2=extra,
        unmatched_isolated=isolated,
        placement_uncertain=rays.extra_var_m2 is not None,
        missed_per_unmatched=rays.missed_per_unmatched, unmatched_power_w=power_u)
