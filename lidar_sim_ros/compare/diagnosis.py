"""Which effect is missing: fit the catalogue, score each on held-out points, decide.

Every candidate is fitted by maximum likelihood (``compare.fit.fit_effect``; for effects
with discrete options, e.g. a footprint's range mode, each option is fitted and the
best kept). The likelihood profiles each material's range offset and sigma scale
(nuisance parameters), so a per-material calibration mismatch cannot pose as an
effect. The score is the held-out gain in log likelihood, in nats per measured
point: the points are split in two halves, the candidate is fitted on one and scored
on the other and vice versa, so extra parameters cannot win on noise. The held-out
likelihood is outlier tolerant (a small uniform floor), so a handful of odd returns
cannot dominate. Unmatched points a candidate explains (returns beyond the
silhouette, false returns off the target) count too.

A candidate is the missing effect when it is the best admissible one and its
held-out gain is both decisive (a held-out likelihood ratio of at least e^15) and
large enough to matter in practice (at least MIN_GAIN nats per point:
real data are never exactly the model's shape, and a slightly misspecified noise
model lends any flexible candidate a few thousandths of a nat per point), or it
explains enough unmatched points; else null.

Admissible: an outlier effect (one that adds spurious returns, e.g. solar background)
must show its signature, points far beyond the noise (|residual| > max(FAR_MIN_M,
FAR_SIGMAS sigma)) or unmatched returns it explains, in number comparable to the
spurious returns it claims; otherwise its gain comes from mildly heavy noise tails,
which no false-return process explains. A time offset fitted on clouds without
per-point times must exceed the spread of the unknown point times within a frame.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import Literal, get_args, get_origin

import numpy as np
from pydantic import create_model

from lidar_sim_ros.compare import likelihood as lk
from lidar_sim_ros.compare.fit import fit_effect
from lidar_sim_ros.compare.likelihood import is_outlier_effect  # noqa: F401 (re-exported)
from lidar_sim_ros.compare.matching import Model, predict_rays
from lidar_sim_ros.compare.materials import robust_sigma
from lidar_sim_ros.compare.measurements import Measurements
from lidar_sim_ros.core.effects import Effect
from lidar_sim_ros.core.geometry import Hits
from lidar_sim_ros.core.pipeline import Prediction

OUTLIER_FLOOR = 1e-5        # outlier weight every held-out likelihood carries (robustness)
UNMATCHED_NATS = 3.0        # gain credited per unmatched point a candidate explains
MIN_TOTAL_GAIN = 15.0       # nats of held-out log-likelihood ratio (odds e^15 : 1), and ...
MIN_GAIN = 0.001            # ... nats per point: smaller gains do not matter in practice
FAR_MIN_M = 0.5             # a point "far beyond the noise": |residual| above this and ...
FAR_SIGMAS = 10.0           # ... this many predicted sigmas
MIN_FAR_POINTS = 20         # an outlier effect needs this many far or unmatched points ...
MIN_FAR_SHARE = 0.5         # ... and this share of the spurious matched returns it claims
MIN_UNMATCHED_EXPLAINED = 20   # unmatched points explained count only from this many ...
MIN_UNMATCHED_FRACTION = 0.002  # ... and this share of all points (grazing rays aside)
N_FOLDS = 2


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


def make_fit_data(model: Model, base_effects: list[Effect], rays: RaySet) -> lk.FitData:
    """FitData for ``rays``: the model with ``base_effects`` (their hooks applied by the
    likelihood); ``cast(effects)`` re-predicts the rays with extra ray-moving effects.
    The baseline is sliced from ``rays.pred`` when given (it must have been predicted
    with the ray geometry of ``base_effects``), else predicted here."""
    meas = rays.meas
    m_sub, u_sub = meas.subset(rays.matched), meas.subset(rays.unmatched)

    def caster(sub: Measurements) -> lk.PredictionCache:
        def cast(effects: list[Effect]) -> Prediction:
            return predict_rays(model.simulator(effects=[lk.RaysOnly(e) for e in effects]), sub)
        return lk.PredictionCache(cast)

    cast = caster(m_sub)
    baseline = (take_prediction(rays.pred, rays.matched) if rays.pred is not None
                else cast(lk.moving(base_effects)))
    power = None if rays.measured_power_w is None else rays.measured_power_w[rays.matched]
    extra = 0.0 if rays.extra_var_m2 is None else rays.extra_var_m2[rays.matched]
    return lk.FitData(
        measured_range_m=m_sub.range_m, baseline=baseline, cast=cast,
        unmatched_range_m=u_sub.range_m, cast_unmatched=caster(u_sub),
        range_window_m=range_window_m(meas), base_effects=tuple(base_effects),
        measured_power_w=power, extra_var_m2=extra)


def calibrated_figures(data, effects: list[Effect]) -> tuple[float, float, float]:
    """(nll_per_point, range_rmse_m, range_robust_sigma_m) of ``data``'s matched points
    under baseline + ``effects``, each material's range offset and sigma scale profiled
    out: the "calibrated" basis, i.e. what a ``--fit`` run (materials refit) reports.
    The robust sigma (MAD) of the same residuals is not swayed by far outliers."""
    model = lk.model_on_rays(data, effects)
    nll, residual = lk.point_nll(data, model)
    if len(nll) == 0:
        return float('nan'), float('nan'), float('nan')
    use = model.placed & np.isfinite(residual)
    robust = robust_sigma(residual[use]) if use.any() else float('nan')
    return float(np.mean(nll)), float(np.sqrt(np.mean(residual ** 2))), robust


def heldout_nll(data, effects: list[Effect]) -> np.ndarray:
    """Per-point NLL (nats) of ``data``'s matched ranges under baseline + ``effects``:
    the fitting likelihood (per-material nuisance profiled) with an outlier floor."""
    model = lk.model_on_rays(data, effects)
    return lk.point_nll(data, model, OUTLIER_FLOOR)[0]


def literal_choices(effect_cls: type[Effect]) -> dict[str, tuple]:
    """The effect's discrete options (``Literal`` params that are not fitted), e.g. a
    beam footprint's range mode: the fit is run for each and the best kept."""
    out = {}
    for name, info in effect_cls.Params.model_fields.items():
        if name not in effect_cls.bounds and get_origin(info.annotation) is Literal:
            out[name] = get_args(info.annotation)
    return out


def with_defaults(effect_cls: type[Effect], defaults: dict) -> type[Effect]:
    """``effect_cls`` whose Params default to ``defaults`` (fixed, non-fitted values),
    so the generic fit keeps them while it estimates the free parameters."""
    if not defaults:
        return effect_cls
    fields = {k: (effect_cls.Params.model_fields[k].annotation, v) for k, v in defaults.items()}
    params = create_model(effect_cls.Params.__name__, __base__=effect_cls.Params, **fields)
    return type(effect_cls.__name__, (effect_cls,), {
        'Params': params, '__module__': effect_cls.__module__,
        '__qualname__': effect_cls.__qualname__, '__doc__': effect_cls.__doc__})


def variants(effect_cls: type[Effect], fixed: dict | None = None,
             max_variants: int = 4) -> list[type[Effect]]:
    """``effect_cls`` with ``fixed`` params, once per combination of its discrete options
    (the combination closest to the class's own defaults first)."""
    fixed = dict(fixed or {})
    choices = {k: v for k, v in literal_choices(effect_cls).items() if k not in fixed}
    own = effect_cls.Params.model_fields
    combos = [dict(zip(choices, combo)) for combo in itertools.product(*choices.values())]
    combos.sort(key=lambda c: sum(c[k] != own[k].default for k in c))
    return [with_defaults(effect_cls, {**fixed, **c}) for c in combos[:max_variants]]


def fit_best_variant(effect_cls: type[Effect], data, fixed: dict | None = None):
    """ML fit over the free parameters and the discrete options: (FitResult, variant class)."""
    best = None
    for v in variants(effect_cls, fixed):
        fit = fit_effect(v, data)
        if best is None or fit.nll_per_point < best[0].nll_per_point - 1e-9:
            best = (fit, v)
    return best


def plain(effect_cls: type[Effect], effect: Effect) -> Effect:
    """A variant's fitted instance as an instance of the original class (same params)."""
    return effect_cls(effect.params.model_dump())


@dataclass
class Candidate:
    """One catalogue effect fitted to the residuals and what it would bring."""

    name: str
    score: float = 0.0                 # held-out gain, nats per measured point
    params: dict = field(default_factory=dict)
    # What the model with this effect would show on the calibrated basis (each
    # material's offset and sigma scale profiled out, as a --fit run): comparable with
    # the summary's range_rmse_calibrated_m / nll_calibrated / robust sigma.
    range_rmse_after_m: float = float('nan')
    nll_after: float = float('nan')
    range_robust_sigma_after_m: float = float('nan')
    unmatched_explained: float = 0.0
    matched_gain: float = 0.0          # held-out, nats per matched point
    z: float = 0.0
    unmatched_gain_points: float = 0.0
    n_params: int = 0
    significant: bool = False
    vetoed: str | None = None          # why it cannot be the missing effect despite its gain
    far_points: float = 0.0            # outlier effects: far or unmatched points it explains
    effect: Effect | None = None
    yaml: str = ''
    error: str | None = None

    def as_dict(self) -> dict:
        return {'name': self.name, 'score': _num(self.score), 'params': self.params,
                'range_rmse_after_m': _num(self.range_rmse_after_m),
                'nll_after': _num(self.nll_after),
                'range_robust_sigma_after_m': _num(self.range_robust_sigma_after_m),
                'unmatched_explained': _num(self.unmatched_explained),
                'heldout_gain_per_matched_point': _num(self.matched_gain), 'z': _num(self.z),
                'n_params': self.n_params, 'significant': self.significant,
                **({'vetoed': self.vetoed} if self.vetoed else {}),
                **({'error': self.error} if self.error else {})}


def _num(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else round(float(x), 6)


class Diagnosis:
    """Scores effect classes against the model with ``base_effects`` (materials as
    configured; the likelihood profiles each material's offset and sigma scale)."""

    def __init__(self, model: Model, base_effects: list[Effect], rays: RaySet, seed: int = 0,
                 frame_time_spread_s: float | None = None):
        """``frame_time_spread_s``: when the point times within a frame are unknown (every
        point stamped with its cloud), the standard deviation of their true times."""
        self.model, self.base, self.rays = model, list(base_effects), rays
        self.full = make_fit_data(model, self.base, rays)
        self.folds = rays.split(N_FOLDS, seed)
        self.fold_data = [make_fit_data(model, self.base, f) for f in self.folds]
        self.n_total = len(rays.matched) + len(rays.unmatched)
        self._base_nll = [heldout_nll(d, []) for d in self.fold_data]
        self.n_far = int(far_from_surface(self.full).sum())
        self._base_outlier_w = float(np.mean(lk.model_on_rays(
            self.full, []).outlier_w)) if len(self.rays.matched) else 0.0
        self.frame_time_spread_s = frame_time_spread_s

    def score(self, effect_cls: type[Effect]) -> Candidate:
        """Fit on all points (reported params) and cross-fitted on halves (the score)."""
        name = getattr(effect_cls, 'name', '') or effect_cls.__name__
        cand = Candidate(name)
        try:
            fit, variant = fit_best_variant(effect_cls, self.full)
            options = {k: getattr(fit.effect.params, k) for k in literal_choices(effect_cls)}
            cand.params = {**{k: float(v) for k, v in fit.params.items()}, **options}
            # Calibrated basis, on the rays diagnosed; run_compare re-evaluates them on
            # all matched points (calibrated_figures).
            cand.range_rmse_after_m, cand.nll_after = fit.range_rmse_m, fit.nll_per_point
            cand.unmatched_explained = fit.unmatched_explained
            cand.n_params = fit.n_params
            cand.effect = plain(effect_cls, fit.effect)
            cand.yaml = _snippet(cand.effect)
            gains, explained = [], 0.0
            for k, train in enumerate(self.fold_data):
                test = self.fold_data[(k + 1) % N_FOLDS]
                effect_k = fit_effect(variant, train).effect
                gains.append(self._base_nll[(k + 1) % N_FOLDS] - heldout_nll(test, [effect_k]))
                if len(test.unmatched_range_m):
                    _, _, u = lk.evaluate(test, [effect_k])
                    explained += u * len(test.unmatched_range_m)
            d = np.concatenate(gains)
            d = d[np.isfinite(d)]
            if len(d) > 1:
                cand.matched_gain = float(d.mean())
                se = float(d.std(ddof=1)) / np.sqrt(len(d))
                cand.z = float(cand.matched_gain / se) if se > 0 else 0.0
            cand.unmatched_gain_points = float(explained)
            counts = explained >= max(MIN_UNMATCHED_EXPLAINED,
                                      MIN_UNMATCHED_FRACTION * self.n_total)
            total = d.sum() + (UNMATCHED_NATS * explained if counts else 0.0)
            cand.score = float(total / max(self.n_total, 1))
            cand.significant = bool(total >= max(MIN_TOTAL_GAIN, MIN_GAIN * self.n_total)
                                    and cand.matched_gain > -MIN_GAIN)
            cand.vetoed = self._veto(cand, explained)
        except Exception as exc:  # noqa: BLE001 - one failing candidate must not stop the rest
            cand.error = f'{type(exc).__name__}: {exc}'
            cand.score = float('-inf')
        return cand


    def _veto(self, cand: Candidate, unmatched_explained: float) -> str | None:
        """Why a candidate with a gain cannot be the missing effect (module doc), or None."""
        eff = cand.effect
        if eff is None or not len(self.rays.matched):
            return None
        spurious = 0.0
        if type(eff).outlier_fraction is not Effect.outlier_fraction:   # adds false returns
            w = float(np.mean(lk.model_on_rays(self.full, [eff]).outlier_w))
            spurious = max(w - self._base_outlier_w, 0.0) * len(self.rays.matched)
        if spurious >= 1.0:
            cand.far_points = float(self.n_far + unmatched_explained)
            need = max(MIN_FAR_POINTS, MIN_FAR_SHARE * spurious)
            if cand.far_points < need:
                return (f'it claims {spurious:.0f} spurious returns among the matched points but only '
                        f'{cand.far_points:.0f} lie far beyond the noise (|residual| > '
                        f'max({FAR_MIN_M:g} m, {FAR_SIGMAS:g} sigma)) or off the target: '
                        'heavy noise tails, not false returns')
        spread = self.frame_time_spread_s
        if spread and type(eff).pose_time_s is not Effect.pose_time_s:
            t = self.rays.meas.t_s[self.rays.matched]
            dt = float(np.median(np.asarray(eff.pose_time_s(t), float) - t))
        else:
            dt = None
        if dt is not None and abs(dt) <= spread:
            return (f'the clouds carry no per-point times: an offset of {1e3 * dt:.1f} ms is '
                    f'within the spread of the point times in a frame ({1e3 * spread:.1f} ms) '
                    'and cannot be told from the scan motion')
        return None


def far_from_surface(data) -> np.ndarray:
    """Matched points far beyond the noise: |residual| > max(FAR_MIN_M, FAR_SIGMAS sigma),
    residual and sigma after the per-material nuisance (offset, sigma scale)."""
    model = lk.model_on_rays(data, [])
    r = np.asarray(data.measured_range_m, float) - model.expected_range_m
    sigma = np.maximum(model.sigma_m, lk.MIN_SIGMA_M)
    use = model.placed & np.isfinite(r)
    offset, scale = lk.material_nuisance(
        r, sigma, np.asarray(data.baseline.ctx.material, int), use)
    with np.errstate(invalid='ignore'):
        return use & (np.abs(r - offset) > np.maximum(FAR_MIN_M, FAR_SIGMAS * sigma * scale))


def rank(candidates: list[Candidate]) -> list[Candidate]:
    return sorted(candidates, key=lambda c: (c.error is not None, -c.score))


def missing_effect(candidates: list[Candidate]) -> str | None:
    """The best admissible candidate's name if it is significant, else None. A vetoed
    candidate (module doc) steps aside: the next one may still be named."""
    for c in rank(candidates):
        if c.error is not None:
            return None
        if c.vetoed is None:
            return c.name if c.significant else None
    return None


def _snippet(effect: Effect) -> str:
    to_yaml = getattr(effect, 'to_yaml_snippet', None)
    if to_yaml is not None:
        return to_yaml().strip()
    params = effect.params.model_dump() if hasattr(effect.params, 'model_dump') else {}
    inner = ', '.join(f'{k}: {v:.6g}' if isinstance(v, float) else f'{k}: {v}'
                      for k, v in params.items())
    return f'- {{name: {effect.name}, params: {{{inner}}}}}'
