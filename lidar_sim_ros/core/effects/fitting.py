"""Fitting effects to measurements: maximum likelihood on ray-matched ranges.

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

w never drops below MODEL_FLOOR (1e-6): no real sensor is free of spurious returns,
and without a floor one point on the wrong side of a depth step (z ~ 100) would
outweigh thousands of good ones. A matched point whose ray misses the target under
a candidate model (a pose shift, a different footprint) counts as a spurious return
of weight max(w, MISS_WEIGHT).

Fits maximise this likelihood over the effect's free parameters (``Effect.bounds``);
non-outlier effects are fitted with a small outlier floor (ROBUST_FLOOR) so a few
spurious points in the data cannot drive them. Reported numbers use the model as is.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np
from pydantic import ValidationError
from scipy.optimize import minimize_scalar

from lidar_sim_ros.core.effects.base import Effect, ReturnContext, apply_effects
from lidar_sim_ros.core.pose import PoseCoverageError

if TYPE_CHECKING:
    from lidar_sim_ros.core.pipeline import Prediction, Simulator

MIN_SIGMA_M = 1e-4            # noise floor of the likelihood (m): a zero sigma is never exact
MIN_MATERIAL_POINTS = 30      # fewer matched points: no per-material nuisance for that material
MODEL_FLOOR = 1e-6            # least outlier weight of the predictive density (module doc)
ROBUST_FLOOR = 1e-3           # outlier weight assumed while fitting non-outlier effects
MISS_WEIGHT = 1e-3            # least outlier weight of a point the model cannot place
UNMATCHED_Z = 5.0             # an unmatched ray that now hits within this many sigma is explained
SMOOTH_SLACK = 5.0            # nats a smoothed 1-D estimate may lose against the best step
CHI2_1_MEDIAN = 0.454936423   # median of z^2 for z ~ N(0, 1)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


@dataclass(frozen=True)
class FitData:
    """Ray-matched measurement vs model, the input of every fit.

    Matched = the measured point's ray hits the target.

    ``baseline`` is the model WITHOUT the effects being evaluated: every effect passed
    to :func:`evaluate` / :func:`fit_effect` (``base_effects`` and the candidate) is
    applied on top of it, through its hooks on ``baseline.ctx`` or, if one of them
    ``needs_repredict``, through ``predict(effects)``. ``baseline_effects`` (optional)
    lists effects already inside ``baseline`` whose ``outlier_fraction`` the likelihood
    must still count (a Prediction carries bias and sigma, not outlier weights).
    """

    measured_range_m: np.ndarray          # (N,) matched points' measured ranges
    baseline: 'Prediction'                # the model on those rays with NO candidate effect
    measured_intensity: np.ndarray | None  # (N,) in sensor units, or None
    # Simulator.predict on the SAME matched rays with these effects added:
    predict: Callable[[list[Effect]], 'Prediction']
    unmatched_range_m: np.ndarray         # (M,) ranges of points whose rays miss the target
    predict_unmatched: Callable[[list[Effect]], 'Prediction']  # same for the unmatched rays
    range_window_m: tuple[float, float]   # support of spurious-return ranges (min, max)
    n_shots: int | None = None            # shots fired if known (else None)
    baseline_effects: tuple[Effect, ...] = ()   # inside baseline; for their outlier_fraction

    @property
    def window_width_m(self) -> float:
        lo, hi = self.range_window_m
        return max(float(hi) - float(lo), 1e-3)


@dataclass(frozen=True)
class FitResult:
    """One fitted effect and what it brings. ``*_before`` are the same numbers for the
    model without it (``evaluate(data, base_effects)``), so gains compare like with like."""

    name: str
    params: dict                  # fitted parameter values (plain floats)
    effect: Effect                # instance with those params
    nll_per_point: float          # mean NLL over matched points after adding the effect
    range_rmse_m: float           # RMS(measured - expected), matched points, with the effect
    unmatched_explained: float    # fraction of unmatched points the effect accounts for (0..1)
    n_params: int
    nll_before_per_point: float = float('nan')
    range_rmse_before_m: float = float('nan')
    unmatched_explained_before: float = float('nan')
    # The same NLL with an extra ROBUST_FLOOR outlier weight: a few gross points
    # (which a pure Gaussian scores by z^2) cannot dominate it. Rank candidates by
    # its gain; the plain NLL is what the model predicts.
    nll_robust_per_point: float = float('nan')
    nll_robust_before_per_point: float = float('nan')
    extras: dict = field(default_factory=dict)   # effect-specific diagnostics

    @property
    def nll_gain_per_point(self) -> float:
        """Drop of the mean NLL the effect brings (nats per matched point; > 0 is better)."""
        return self.nll_before_per_point - self.nll_per_point

    @property
    def robust_gain_per_point(self) -> float:
        """Drop of the robust mean NLL (nats per matched point)."""
        return self.nll_robust_before_per_point - self.nll_robust_per_point

    @property
    def yaml_snippet(self) -> str:
        return self.effect.to_yaml_snippet()


# ----------------------------------------------------------------- the model on rays
@dataclass(frozen=True)
class ModelOnRays:
    """Predictive distribution of each matched point's range under a model."""

    ctx: ReturnContext
    expected_range_m: np.ndarray
    sigma_m: np.ndarray
    outlier_w: np.ndarray
    placed: np.ndarray            # the model's ray hits the target


def _outlier_weight(effects: Sequence[Effect], ctx: ReturnContext, n: int) -> np.ndarray:
    keep = np.ones(n)
    for eff in effects:
        w = np.clip(np.broadcast_to(np.asarray(eff.outlier_fraction(ctx), float), (n,)), 0.0, 1.0)
        keep = keep * (1.0 - w)
    return 1.0 - keep


def needs_repredict(effects: Sequence[Effect]) -> bool:
    return any(getattr(e, 'needs_repredict', False) for e in effects)


def model_on_rays(data: FitData, effects: Sequence[Effect]) -> ModelOnRays:
    """The baseline plus ``effects`` on the matched rays (re-predicted if an effect needs it)."""
    effects = list(effects)
    n = len(data.measured_range_m)
    if needs_repredict(effects):
        pred = data.predict(effects)
        ctx, expected, sigma = pred.ctx, pred.expected_range_m, pred.sigma_m
    else:
        base = data.baseline
        ctx, bias, var = apply_effects(base.ctx, effects, base.bias_m, np.asarray(base.sigma_m) ** 2)
        expected = ctx.range_m + bias
        sigma = np.sqrt(var)
    placed = np.asarray(ctx.hit, bool) & np.isfinite(expected) & np.isfinite(sigma)
    w = _outlier_weight([*data.baseline_effects, *effects], ctx, n)
    return ModelOnRays(ctx, np.asarray(expected, float), np.asarray(sigma, float), w, placed)


# --------------------------------------------------------------------- likelihood
def _groups(data: FitData) -> np.ndarray:
    return np.asarray(data.baseline.ctx.material, int)


def material_nuisance(residual_m: np.ndarray, sigma_m: np.ndarray, group: np.ndarray,
                      use: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-point offset c_m (m) and sigma scale s_m (-) of each point's material.

    c_m = median residual, s_m^2 = median((r - c_m)^2 / sigma^2) / median(chi2_1), over
    the material's usable points; materials with fewer than MIN_MATERIAL_POINTS keep
    (0, 1). Medians keep spurious points from moving either.
    """
    offset = np.zeros(len(residual_m))
    scale = np.ones(len(residual_m))
    for g in np.unique(group[use]):
        member = group == g
        sel = member & use
        if sel.sum() < MIN_MATERIAL_POINTS:
            continue
        c = float(np.median(residual_m[sel]))
        z2 = ((residual_m[sel] - c) / sigma_m[sel]) ** 2
        s = math.sqrt(max(float(np.median(z2)) / CHI2_1_MEDIAN, 1e-6))
        offset[member] = c
        scale[member] = s
    return offset, scale


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
        offset, scale = material_nuisance(residual, sigma, _groups(data), use)
        residual = residual - offset
        sigma = sigma * scale
    w = 1.0 - (1.0 - model.outlier_w) * (1.0 - max(floor, MODEL_FLOOR))
    width = data.window_width_m
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        z = residual / sigma
        log_gauss = -0.5 * z * z - np.log(sigma) - _LOG_SQRT_2PI
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


def unmatched_explained(data: FitData, effects: Sequence[Effect],
                        model: ModelOnRays | None = None) -> float:
    """Fraction (0..1) of unmatched points the effects account for.

    Two ways: a re-predicted ray now hits the target with a detectable power and a
    range within UNMATCHED_Z sigma (beam divergence, time offset); or spurious
    returns on shots that miss the target (outlier fraction x missed shots, at most
    the share of unmatched ranges that look uniform over the window). Missed shots
    are ``n_shots - N`` when ``n_shots`` is known, else assumed to be N.
    """
    effects = list(effects)
    r_u = np.asarray(data.unmatched_range_m, float)
    m = len(r_u)
    if m == 0:
        return 0.0
    hit_now = np.zeros(m, bool)
    if needs_repredict(effects):
        pu = data.predict_unmatched(effects)
        sig = np.maximum(np.nan_to_num(pu.sigma_m, nan=np.inf), MIN_SIGMA_M)
        with np.errstate(invalid='ignore'):
            hit_now = (np.asarray(pu.ctx.hit, bool)
                       & (pu.ctx.power_w >= pu.ctx.threshold_power_w)
                       & (np.abs(r_u - pu.expected_range_m) <= UNMATCHED_Z * sig))
    rest = r_u[~hit_now]
    if model is None:
        model = model_on_rays(data, effects)
    w_mean = float(np.mean(model.outlier_w)) if len(model.outlier_w) else 0.0
    spurious = 0.0
    if w_mean > 0 and len(rest):
        n = len(data.measured_range_m)
        missed = max(data.n_shots - n, 0) if data.n_shots is not None else n
        share = uniform_share(rest, data.range_window_m, np.asarray(data.measured_range_m))
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
    width = data.window_width_m
    ll_u = np.full(m, math.log(max(floor, MISS_WEIGHT) / width))
    if needs_repredict(effects):
        try:
            pu = data.predict_unmatched(effects)
        except PoseCoverageError:
            return math.inf
        sig = np.maximum(np.nan_to_num(pu.sigma_m, nan=1.0), MIN_SIGMA_M)
        ok = np.asarray(pu.ctx.hit, bool) & (pu.ctx.power_w >= pu.ctx.threshold_power_w)
        with np.errstate(invalid='ignore', over='ignore'):
            z = (np.asarray(data.unmatched_range_m) - pu.expected_range_m) / sig
            log_in = math.log1p(-floor) - 0.5 * z * z - np.log(sig) - _LOG_SQRT_2PI
            ll_u = np.where(ok & np.isfinite(z), np.logaddexp(log_in, ll_u), ll_u)
    return total - float(np.sum(ll_u))


# ------------------------------------------------------------------------ fitting
def search_1d(f: Callable[[float], float], lo: float, hi: float, x0: float | None = None,
              n_grid: int = 13, prefer_low: float = 0.0, smooth: bool = False) -> float:
    """Minimise f on [lo, hi]: a grid (plus x0), then Brent in the best grid cell.

    ``prefer_low`` > 0 returns instead the smallest x whose f is within that many nats
    of the minimum (bisection below the minimum): for likelihoods that go flat beyond
    the true value, e.g. a footprint size once every edge point is explained.
    ``smooth`` replaces the minimum by the vertex of a parabola fitted through the
    basin (``quadratic_vertex``): for step-like likelihoods of raycast parameters.
    """
    grid = np.linspace(lo, hi, max(n_grid, 3))
    if x0 is not None and lo <= x0 <= hi:
        grid = np.unique(np.append(grid, x0))
    values = np.array([f(float(x)) for x in grid])
    if not np.any(np.isfinite(values)):
        return float(x0 if x0 is not None else grid[0])
    best = int(np.nanargmin(values))
    x_best, f_best = float(grid[best]), float(values[best])
    a, b = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    if b > a:
        res = minimize_scalar(f, bounds=(a, b), method='bounded',
                              options={'xatol': (hi - lo) * 1e-5})
        if res.fun < f_best:
            x_best, f_best = float(res.x), float(res.fun)
    if prefer_low > 0:
        level = f_best + prefer_low
        ok = np.flatnonzero(values <= level)
        upper = min(float(grid[ok[0]]), x_best) if len(ok) else x_best
        below = grid[grid < upper]
        lower = float(below.max()) if len(below) else upper
        for _ in range(12):
            if upper - lower <= (hi - lo) * 1e-4:
                break
            mid = 0.5 * (lower + upper)
            if f(mid) <= level:
                upper = mid
            else:
                lower = mid
        x_best = upper
    elif smooth:
        vertex = quadratic_vertex(f, x_best, f_best, lo, hi)
        # The vertex may sit a fraction of a step above the lowest step, not several
        # steps (rays put on the wrong surface) above it.
        if f(vertex) <= f_best + SMOOTH_SLACK:
            x_best = vertex
    return x_best


def quadratic_vertex(f: Callable[[float], float], x: float, f_x: float, lo: float, hi: float,
                     rise: float = 50.0, n: int = 11) -> float:
    """Vertex of a parabola least-squares fitted to f over its basin around x.

    When a parameter moves the raycast (a pose time, a footprint), rays near depth
    steps switch surface one by one: the likelihood is a staircase with ~15-nat
    steps and its lowest step is a matter of luck. Its trend is smooth: the basin is
    widened until f has risen by ``rise`` nats on one side, sampled at n points
    symmetrically about x, and the parabola's vertex is the estimate. Falls back to x
    if the basin is not convex.
    """
    def reach(sign: float) -> float:
        d = (hi - lo) * 1e-4
        while True:
            edge = x + sign * d
            if edge <= lo or edge >= hi:
                return min(d, x - lo) if sign < 0 else min(d, hi - x)
            if f(edge) >= f_x + rise:
                return d
            d *= 2.0

    # A symmetric window: on a lopsided basin the parabola would lean to the flat side.
    d_lo = d_hi = min(reach(-1.0), reach(+1.0))
    xs = np.linspace(x - d_lo, x + d_hi, n)
    ys = np.array([f(float(v)) for v in xs])
    ok = np.isfinite(ys)
    if ok.sum() < 4 or d_lo + d_hi <= 0:
        return x
    a, b, _ = np.polyfit(xs[ok] - x, ys[ok] - f_x, 2)
    if a <= 0:
        return x
    vertex = x - b / (2.0 * a)
    return float(vertex) if x - d_lo <= vertex <= x + d_hi else x


def _defaults(cls: type[Effect]) -> dict:
    return cls().params.model_dump()


def free_params(cls: type[Effect]) -> list[str]:
    return list(cls.bounds)


def make_effect_safe(cls: type[Effect], params: dict) -> Effect | None:
    try:
        return cls(params)
    except (ValidationError, ValueError):
        return None


def fit_bounded(cls: type[Effect], data: FitData, base_effects: Sequence[Effect] = (),
                n_grid: int = 13, sweeps: int = 3, prefer_low: float = 0.0,
                smooth: bool | None = None) -> FitResult:
    """Generic bounded maximum likelihood over ``cls.bounds``, for any effect.

    Coordinate descent: each free parameter in turn gets a grid-and-Brent line search
    (``search_1d``) over its bounds, for a few sweeps, starting from ``cls.initial``
    (or the Params defaults). The grid makes it robust to several minima; the robust
    objective (``objective``) makes it robust to spurious points. Effects that
    re-predict the raycast are smoothed (``quadratic_vertex``) unless ``smooth`` says.
    """
    if smooth is None:
        smooth = bool(cls.needs_repredict) and prefer_low == 0
    base_effects = list(base_effects)
    names = free_params(cls)
    params = _defaults(cls)
    for k in names:
        lo, hi = cls.bounds[k]
        params[k] = float(np.clip(cls.initial.get(k, params[k]), lo, hi))
    cache: dict[tuple, float] = {}

    def total(p: dict) -> float:
        key = tuple(p[k] for k in names)
        if key not in cache:
            eff = make_effect_safe(cls, p)
            cache[key] = math.inf if eff is None else objective(data, [*base_effects, eff])
        return cache[key]

    for sweep in range(sweeps if len(names) > 1 else 1):
        before = total(params)
        for k in names:
            lo, hi = cls.bounds[k]
            params[k] = search_1d(lambda x: total({**params, k: x}), lo, hi, params[k],
                                  n_grid=n_grid, prefer_low=prefer_low, smooth=smooth)
        if sweep and before - total(params) < 1e-3:
            break
    return make_result(cls(params), data, base_effects)


def make_result(effect: Effect, data: FitData, base_effects: Sequence[Effect] = (),
                extras: dict | None = None) -> FitResult:
    """Score a fitted effect against the model without it."""
    base_effects = list(base_effects)
    cls = type(effect)
    after = scores(data, [*base_effects, effect])
    before = scores(data, base_effects)
    values = effect.params.model_dump()
    params = {k: float(values[k]) for k in free_params(cls)}
    return FitResult(name=cls.name or cls.__name__, params=params, effect=effect,
                     nll_per_point=after['nll'], range_rmse_m=after['rmse'],
                     unmatched_explained=after['unmatched'], n_params=len(params),
                     nll_before_per_point=before['nll'], range_rmse_before_m=before['rmse'],
                     unmatched_explained_before=before['unmatched'],
                     nll_robust_per_point=after['nll_robust'],
                     nll_robust_before_per_point=before['nll_robust'],
                     extras=dict(extras or {}))


def fit_effect(effect_cls: type[Effect], data: FitData,
               base_effects: Sequence[Effect] = ()) -> FitResult:
    """Maximum-likelihood fit of effect_cls's free parameters on top of base_effects."""
    return effect_cls.fit(data, tuple(base_effects))


def linear_bias_coefficient(data: FitData, model: ModelOnRays, feature: np.ndarray,
                            bounds: tuple[float, float], iterations: int = 6) -> float:
    """ML coefficient a of an extra bias a * feature (m per feature unit), closed form.

    Weighted least squares of the residual on the feature with one intercept per
    material (the nuisance offsets), iterated with robust inlier weights (Gaussian vs
    a ROBUST_FLOOR uniform) and per-material noise scales: spurious points get no say.
    """
    y = np.asarray(data.measured_range_m, float) - model.expected_range_m
    x = np.asarray(feature, float)
    sigma = np.maximum(model.sigma_m, MIN_SIGMA_M)
    use = model.placed & np.isfinite(x) & np.isfinite(y)
    if use.sum() < 3:
        return 0.0
    y, x, sigma, group = y[use], x[use], sigma[use], _groups(data)[use]
    width = data.window_width_m
    q = np.ones(len(y))
    a = 0.0
    for _ in range(iterations):
        wt = q / sigma ** 2
        xc, yc = _centre(x, group, wt), _centre(y, group, wt)
        den = float(np.sum(wt * xc * xc))
        if den <= 0:
            return 0.0
        a = float(np.clip(np.sum(wt * xc * yc) / den, *bounds))
        e = yc - a * xc
        _, scale = material_nuisance(e, sigma, group, np.ones(len(e), bool))
        s = sigma * scale
        g = (1 - ROBUST_FLOOR) * np.exp(-0.5 * (e / s) ** 2) / (s * math.sqrt(2 * math.pi))
        q = g / (g + ROBUST_FLOOR / width)
    return a


def _centre(v: np.ndarray, group: np.ndarray, weight: np.ndarray) -> np.ndarray:
    out = np.empty_like(v)
    for g in np.unique(group):
        sel = group == g
        wsum = weight[sel].sum()
        out[sel] = v[sel] - (np.sum(weight[sel] * v[sel]) / wsum if wsum > 0 else 0.0)
    return out


# ---------------------------------------------------------------- building FitData
def with_effects(sim: 'Simulator', effects: Sequence[Effect]) -> 'Simulator':
    """A shallow copy of ``sim`` with extra effects appended (shares target and scan)."""
    out = copy.copy(sim)
    out.effects = [*sim.effects, *effects]
    return out


def fit_data_from_rays(sim: 'Simulator', t_abs_s: np.ndarray, directions: np.ndarray,
                       measured_range_m: np.ndarray, pose_source, t_frame_s=None,
                       laser=None, measured_intensity=None, n_shots: int | None = None,
                       range_window_m: tuple[float, float] | None = None) -> FitData:
    """FitData for measured points (absolute times, lidar-frame directions, ranges).

    Points whose ray hits the target under ``sim`` are matched, the others
    unmatched; ``predict`` / ``predict_unmatched`` re-run ``sim`` with extra effects.
    The range window defaults to the sensor's range gate.
    """
    t_abs_s = np.asarray(t_abs_s, float)
    directions = np.asarray(directions, float)
    measured_range_m = np.asarray(measured_range_m, float)
    n = len(t_abs_s)
    t_frame = np.zeros(n) if t_frame_s is None else np.asarray(t_frame_s, float)
    laser = np.zeros(n, np.uint16) if laser is None else np.asarray(laser)
    first = sim.predict(t_abs_s, directions, pose_source, t_frame, laser=laser)
    matched = np.asarray(first.ctx.hit, bool)

    def predictor(mask):
        def run(effects):
            return with_effects(sim, effects).predict(
                t_abs_s[mask], directions[mask], pose_source, t_frame[mask], laser=laser[mask])
        return run

    predict, predict_unmatched = predictor(matched), predictor(~matched)
    det = sim.sensor.detection
    window = range_window_m or (det.min_range_m, det.max_range_m)
    intensity = None if measured_intensity is None else np.asarray(measured_intensity)[matched]
    return FitData(measured_range_m=measured_range_m[matched], baseline=predict([]),
                   measured_intensity=intensity, predict=predict,
                   unmatched_range_m=measured_range_m[~matched],
                   predict_unmatched=predict_unmatched, range_window_m=tuple(window),
                   n_shots=n_shots)
