"""Maximum-likelihood fits of effects to ray-matched measurements (``likelihood.py``).

``fit_effect(cls, data, base_effects)`` estimates an effect's free parameters
(``cls.bounds``) on top of ``base_effects``. Effects never import this module: they
declare what a fit needs and the fit reads it (dependency injection, not imports):

* ``bounds`` / ``initial``: the free parameters, their search box and start;
* ``linear_bias``: free parameters the range bias is linear in (bias = a * feature
  + rest); each is estimated in closed form (robust weighted least squares of the
  residual on the feature, one intercept per material) with the others held, the
  feature being the bias at a = 1 minus the bias at a = 0;
* ``fit_options``: options of the 1-D searches (``n_grid``; ``prefer_low`` for a
  likelihood that goes flat beyond the true value; ``smooth`` for a staircase);
* an outlier effect (one with ``outlier_fraction``) is fitted on the plain mixture
  likelihood, any other with a small outlier floor (ROBUST_FLOOR) so a handful of
  spurious points cannot drive it.

The generic fit is coordinate descent over the free parameters (closed form for the
linear ones, a grid then Brent for the others), so a user effect that declares
``bounds`` is fitted with no extra code. A fit that needs more can be registered
here with :func:`register_fit` (or, for a user class, defined as its own ``fit``
classmethod taking ``(data, base_effects)``).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np
from pydantic import ValidationError
from scipy.optimize import minimize_scalar

from lidar_sim_ros.compare.model import pointing
from lidar_sim_ros.compare.model.likelihood import (MIN_SIGMA_M, ROBUST_FLOOR, FitData,
                                                    ModelOnRays, PredictionCache, RaysOnly,
                                                    _groups, group_members, is_outlier_effect,
                                                    material_nuisance,
                                                    model_on_rays, moving, objective, point_nll,
                                                    scores)
from lidar_sim_ros.core.effects.base import Effect
from lidar_sim_ros.core.pipeline import Simulator

SMOOTH_SLACK = 5.0            # nats a smoothed 1-D estimate may lose against the best step
FitFunction = Callable[[type[Effect], FitData, Sequence[Effect]], 'FitResult']
_FITS: dict[type[Effect], FitFunction] = {}


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


BOUND_TOLERANCE = 1e-6       # of the search box's width: a value this close to a bound is at it


def at_bounds(effect: Effect) -> list[str]:
    """The free parameters (``bounds``) of a fitted ``effect`` that ended at their search
    box's edge (within BOUND_TOLERANCE of its width; a list parameter if any element
    did), and those searched entry by entry (``entry_bounds``: a per-material standoff)
    if any entry did: the data asked for at least that much, so the value is a bound of
    the size, not a measurement of it."""
    out = []
    cls = type(effect)
    for name, (lo, hi) in {**cls.bounds, **cls.entry_bounds}.items():
        v = getattr(effect.params, name, None)
        if v is None:
            continue
        vals = np.asarray(list(v.values()) if isinstance(v, dict) else v, float).ravel()
        tol = BOUND_TOLERANCE * (hi - lo)
        if vals.size and np.any(np.isfinite(vals) & ((vals <= lo + tol) | (vals >= hi - tol))):
            # A lower bound at zero (a probability, a scale of a footprint) is 'none'.
            if not (lo == 0.0 and np.all(vals <= lo + tol)):
                out.append(name)
    return out


def make_effect_safe(cls: type[Effect], params: dict) -> Effect | None:
    try:
        return cls(params)
    except (ValidationError, ValueError):
        return None


def fit_bounded(cls: type[Effect], data: FitData, base_effects: Sequence[Effect] = (),
                n_grid: int = 13, sweeps: int = 3, prefer_low: float = 0.0,
                smooth: bool | None = None) -> FitResult:
    """Generic bounded maximum likelihood over ``cls.bounds``, for any effect.

    Coordinate descent: each free parameter in turn is estimated with the others held,
    in closed form if the bias is linear in it (``cls.linear_bias``), else by a
    grid-and-Brent line search (``search_1d``) over its bounds; a few sweeps, starting
    from ``cls.initial`` (or the Params defaults). The grid makes it robust to several
    minima; the robust objective (``objective``) to spurious points. Effects that
    re-predict the raycast are smoothed (``quadratic_vertex``) unless ``smooth`` says.
    """
    if smooth is None:
        smooth = bool(cls.needs_repredict) and prefer_low == 0
    floor = 0.0 if is_outlier_effect(cls) else ROBUST_FLOOR
    base_effects = list(base_effects)
    names = free_params(cls)
    linear = set(getattr(cls, 'linear_bias', ())) & set(names)
    params = _defaults(cls)
    for k in names:
        lo, hi = cls.bounds[k]
        params[k] = float(np.clip(cls.initial.get(k, params[k]), lo, hi))
    cache: dict[tuple, float] = {}

    def total(p: dict) -> float:
        key = tuple(p[k] for k in names)
        if key not in cache:
            eff = make_effect_safe(cls, p)
            cache[key] = (math.inf if eff is None
                          else objective(data, [*base_effects, eff], floor=floor))
        return cache[key]

    for sweep in range(sweeps if len(names) > 1 else 1):
        before = total(params)
        for k in names:
            lo, hi = cls.bounds[k]
            value = linear_parameter(cls, params, k, data, base_effects) if k in linear else None
            if value is None:
                value = search_1d(lambda x: total({**params, k: x}), lo, hi, params[k],
                                  n_grid=n_grid, prefer_low=prefer_low, smooth=smooth)
            params[k] = value
        if sweep and before - total(params) < 1e-3:
            break
    return make_result(cls(params), data, base_effects)


def linear_parameter(cls: type[Effect], params: dict, name: str, data: FitData,
                     base_effects: Sequence[Effect]) -> float | None:
    """Closed-form ML value of a parameter the range bias is linear in, the others held:
    the feature is the bias at ``name`` = 1 minus the bias at 0 (None if the effect
    rejects those values)."""
    at0, at1 = (make_effect_safe(cls, {**params, name: v}) for v in (0.0, 1.0))
    if at0 is None or at1 is None:
        return None
    model = model_on_rays(data, [*base_effects, at0])
    feature = model_on_rays(data, [*base_effects, at1]).expected_range_m - model.expected_range_m
    return linear_bias_coefficient(data, model, feature, cls.bounds[name])


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


def register_fit(effect_cls: type[Effect]) -> Callable[[FitFunction], FitFunction]:
    """Decorator: use ``fn(cls, data, base_effects) -> FitResult`` to fit ``effect_cls``
    (and its subclasses) instead of the generic bounded fit."""
    def deco(fn: FitFunction) -> FitFunction:
        _FITS[effect_cls] = fn
        return fn
    return deco


def fit_effect(effect_cls: type[Effect], data: FitData,
               base_effects: Sequence[Effect] = ()) -> FitResult:
    """Maximum-likelihood fit of effect_cls's free parameters on top of base_effects:
    a registered fit, the class's own ``fit`` classmethod, or the generic bounded fit
    with the class's ``fit_options``."""
    base_effects = tuple(base_effects)
    for klass in effect_cls.__mro__:
        if klass in _FITS:
            return _FITS[klass](effect_cls, data, base_effects)
    own = getattr(effect_cls, 'fit', None)
    if own is not None:
        return own(data, base_effects)
    return fit_bounded(effect_cls, data, base_effects, **dict(effect_cls.fit_options))


def linear_bias_coefficient(data: FitData, model: ModelOnRays, feature: np.ndarray,
                            bounds: tuple[float, float], iterations: int = 6) -> float:
    """ML coefficient a of an extra bias a * feature (m per feature unit), closed form
    (``linear_bias_coefficients`` with one feature)."""
    x = np.asarray(feature, float).reshape(-1, 1)
    return float(linear_bias_coefficients(data, model, x, [bounds], iterations)[0])


def linear_bias_coefficients(data: FitData, model: ModelOnRays, features: np.ndarray,
                             bounds: Sequence[tuple[float, float]],
                             iterations: int = 6) -> np.ndarray:
    """ML coefficients a_j of an extra bias sum_j a_j * features[:, j], closed form.

    Weighted least squares of the residual on the features with one intercept per
    material (the nuisance offsets), iterated with robust inlier weights (Gaussian vs
    a ROBUST_FLOOR uniform) and per-material noise scales: spurious points get no say.
    Features the centred data cannot tell apart get the least-squares minimum-norm
    split; each coefficient is clipped to its bounds."""
    x = np.asarray(features, float)
    k = x.shape[1]
    y = np.asarray(data.measured_range_m, float) - model.expected_range_m
    sigma = np.maximum(model.sigma_m, MIN_SIGMA_M)
    use = model.placed & np.all(np.isfinite(x), axis=1) & np.isfinite(y)
    a = np.zeros(k)
    if use.sum() < 3:
        return a
    y, x, sigma, group = y[use], x[use], sigma[use], _groups(data)[use]
    members = group_members(group)
    lo, hi = np.array([b[0] for b in bounds], float), np.array([b[1] for b in bounds], float)
    width = data.window_width_m
    q = np.ones(len(y))
    for _ in range(iterations):
        wt = q / sigma ** 2
        xc = np.column_stack([_centre(x[:, j], members, wt) for j in range(k)])
        yc = _centre(y, members, wt)
        normal = (xc * wt[:, None]).T @ xc
        if not np.all(np.diag(normal) > 0):
            return np.zeros(k)
        rhs = (xc * wt[:, None]).T @ yc
        a = np.clip(np.linalg.lstsq(normal, rhs, rcond=None)[0], lo, hi)
        e = yc - xc @ a
        _, scale = material_nuisance(e, sigma, group, np.ones(len(e), bool), members)
        s = sigma * scale
        g = (1 - ROBUST_FLOOR) * np.exp(-0.5 * (e / s) ** 2) / (s * math.sqrt(2 * math.pi))
        q = g / (g + ROBUST_FLOOR / width)
    return a


def _centre(v: np.ndarray, members: list[tuple[int, np.ndarray]],
            weight: np.ndarray) -> np.ndarray:
    """``v`` less its weighted mean over each group (``members``: ``group_members`` of the
    groups, found once per fit rather than by a mask per group and call)."""
    out = np.empty_like(v)
    for _, idx in members:
        w = weight[idx]
        wsum = w.sum()
        out[idx] = v[idx] - (np.sum(w * v[idx]) / wsum if wsum > 0 else 0.0)
    return out


# ---------------------------------------------------------------- building FitData
def geometry_simulator(sim: Simulator, effects: Sequence[Effect]) -> Simulator:
    """A shallow copy of ``sim`` (shares target and scan) whose only effects are the ray
    geometry of ``effects`` (``RaysOnly``): its predictions carry the per-material bias
    and sigma, and the likelihood applies every effect's hooks itself."""
    out = copy.copy(sim)
    out.effects = [RaysOnly(e) for e in moving(effects)]
    return out


def fit_data_from_rays(sim: Simulator, t_abs_s: np.ndarray, directions: np.ndarray,
                       measured_range_m: np.ndarray, pose_source, t_frame_s=None,
                       laser=None, measured_power_w=None, n_shots: int | None = None,
                       range_window_m: tuple[float, float] | None = None) -> FitData:
    """FitData for measured points (absolute times, lidar-frame directions, ranges).

    The model is ``sim`` with its effects (``base_effects``). Points whose ray hits the
    target under it are matched, the others unmatched; ``cast`` / ``cast_unmatched``
    re-run it with extra ray-moving effects. ``measured_power_w`` (optional, per point):
    the received power the sensor measured, read by power-driven effects. The range
    window defaults to the sensor's range gate.
    """
    t_abs_s = np.asarray(t_abs_s, float)
    directions = np.asarray(directions, float)
    measured_range_m = np.asarray(measured_range_m, float)
    n = len(t_abs_s)
    t_frame = np.zeros(n) if t_frame_s is None else np.asarray(t_frame_s, float)
    laser = np.zeros(n, np.uint16) if laser is None else np.asarray(laser)
    base = list(sim.effects)

    def predictor(mask):
        def run(effects):
            return geometry_simulator(sim, effects).predict(
                t_abs_s[mask], directions[mask], pose_source, t_frame[mask], laser=laser[mask])
        return run

    everything = np.ones(n, bool)
    matched = np.asarray(predictor(everything)(base).ctx.hit, bool)
    cast = PredictionCache(predictor(matched))
    det = sim.sensor.detection
    window = range_window_m or (det.min_range_m, det.max_range_m)
    power = None if measured_power_w is None else np.asarray(measured_power_w, float)[matched]
    n_unmatched = int((~matched).sum())
    missed = (max(n_shots - int(matched.sum()), 0) / n_unmatched
              if n_shots is not None and n_unmatched else None)
    return FitData(measured_range_m=measured_range_m[matched], baseline=cast(moving(base)),
                   cast=cast, unmatched_range_m=measured_range_m[~matched],
                   cast_unmatched=PredictionCache(predictor(~matched)),
                   range_window_m=tuple(window), base_effects=tuple(base),
                   measured_power_w=power, n_shots=n_shots, missed_per_unmatched=missed)


# ------------------------------------------------------------ per-laser offsets
MIN_LASER_POINTS = 20          # fewer matched points: the laser's offset stays 0


def laser_offsets_m(residual_m: np.ndarray, sigma_m: np.ndarray, material: np.ndarray,
                    laser: np.ndarray, window_width_m: float,
                    iterations: int = 12) -> np.ndarray:
    """ML range offset (m) of each laser id 0..max(laser), one intercept per material:
    alternating robust weighted means (Gaussian vs a ROBUST_FLOOR uniform, per-material
    noise scales); the offsets average to zero over the points (the material intercepts
    carry the mean); lasers with fewer than MIN_LASER_POINTS points get 0."""
    y = np.asarray(residual_m, float)
    sigma = np.maximum(np.asarray(sigma_m, float), MIN_SIGMA_M)
    group = np.asarray(material, int)
    lz = np.asarray(laser, np.int64)
    n_lasers = int(lz.max()) + 1 if len(lz) else 0
    off = np.zeros(n_lasers)
    if len(y) < MIN_LASER_POINTS:
        return off
    enough = np.bincount(lz, minlength=n_lasers) >= MIN_LASER_POINTS
    members = group_members(group)
    q = np.ones(len(y))
    for _ in range(iterations):
        wt = q / sigma ** 2
        c = y - off[lz] - _centre(y - off[lz], members, wt)      # per-material intercepts
        r = y - c
        wsum = np.bincount(lz, weights=wt, minlength=n_lasers)
        off = np.where(enough & (wsum > 0),
                       np.bincount(lz, weights=wt * r, minlength=n_lasers) / np.maximum(wsum, 1e-300),
                       0.0)
        off -= np.sum(wt * off[lz]) / np.sum(wt)
        e = y - c - off[lz]
        _, scale = material_nuisance(e, sigma, group, np.ones(len(e), bool), members)
        s = sigma * scale
        g = (1 - ROBUST_FLOOR) * np.exp(-0.5 * (e / s) ** 2) / (s * math.sqrt(2 * math.pi))
        q = g / (g + ROBUST_FLOOR / window_width_m)
    return np.where(enough, off, 0.0)


def _fit_laser_bias(cls: type[Effect], data: FitData,
                    base_effects: Sequence[Effect] = ()) -> FitResult:
    """Closed-form fit of ``laser_bias`` (one offset per laser, ``laser_offsets_m``)."""
    base_effects = list(base_effects)
    model = model_on_rays(data, base_effects)
    use = model.placed & np.isfinite(model.expected_range_m)
    y = np.asarray(data.measured_range_m, float) - model.expected_range_m
    laser = np.asarray(data.baseline.ctx.laser, np.int64)
    off = np.zeros(int(laser.max()) + 1 if len(laser) else 0)
    if use.sum() >= MIN_LASER_POINTS:
        fitted = laser_offsets_m(y[use], model.sigma_m[use], _groups(data)[use], laser[use],
                                 data.window_width_m)
        off[:len(fitted)] = fitted
    lo, hi = cls.bounds['offsets_m']
    effect = cls({'offsets_m': [round(float(v), 6) for v in np.clip(off, lo, hi)]})
    result = make_result_vector(effect, data, base_effects,
                                {f'laser_{i}_m': float(v) for i, v in enumerate(off)})
    # How the points link the lasers through the materials (``laser_tiles.poorly_linked``).
    cells = laser_material_weights(laser[use], _groups(data)[use], model.sigma_m[use])
    return replace(result, extras={'offset_cells': cells})


def laser_material_weights(laser: np.ndarray, material: np.ndarray,
                           sigma_m: np.ndarray) -> np.ndarray:
    """(L, M) summed weights 1/sigma^2 (1/m^2) of each laser's points on each material:
    what determines the lasers' offsets beside one intercept per material."""
    lz = np.asarray(laser, np.int64)
    mat = np.asarray(material, np.int64)
    if not len(lz):
        return np.zeros((0, 0))
    n_l, n_m = int(lz.max()) + 1, int(mat.max()) + 1
    w = 1.0 / np.maximum(np.asarray(sigma_m, float), MIN_SIGMA_M) ** 2
    w = np.where(np.isfinite(w), w, 0.0)
    return np.bincount(lz * n_m + mat, weights=w, minlength=n_l * n_m).reshape(n_l, n_m)


def shift_offsets_along(effect: Effect, data: FitData, base_effects: Sequence[Effect],
                        directions: np.ndarray) -> Effect:
    """``effect`` (``laser_bias``) with its offsets moved along ``directions`` ((L, k)
    columns in the lasers' offsets) by the ML shift on ``data`` (``linear_bias_coefficients``:
    one intercept per material, robust weights) on top of ``base_effects`` and itself:
    the part of the offsets that the points ``effect`` was fitted on did not determine,
    taken from these points."""
    d = np.asarray(directions, float)
    off = np.asarray(effect.params.offsets_m, float)
    if d.ndim != 2 or d.shape[1] == 0 or not len(off):
        return effect
    n = max(len(off), d.shape[0])
    off, d = np.pad(off, (0, n - len(off))), np.pad(d, ((0, n - d.shape[0]), (0, 0)))
    laser = np.asarray(data.baseline.ctx.laser, np.int64)
    features = d[np.clip(laser, 0, n - 1)] * (laser < n)[:, None]
    lo, hi = type(effect).bounds['offsets_m']
    model = model_on_rays(data, [*base_effects, effect])
    shift = linear_bias_coefficients(data, model, features, [(2 * lo, 2 * hi)] * d.shape[1])
    moved = np.clip(off + d @ shift, lo, hi)
    return type(effect)({'offsets_m': [round(float(v), 6) for v in moved]})


def _fit_laser_pointing(cls: type[Effect], data: FitData,
                        base_effects: Sequence[Effect] = ()) -> FitResult:
    """Fit of ``laser_pointing`` through the range gradient (``compare/model/pointing.py``):
    per laser, its two offsets by weighted least squares of the residual on the gradient
    (the raycast's normal and range), linear, then once more from the rays the first
    estimate casts (the gradient and residual where the beams now hit: the second-order
    part of a curved surface). Scored by casting the rays again with the fitted offsets
    (``make_result_vector``): the held-out figures are of the exact geometry. A class
    with ``turn_only`` (``pointing.SensorTurn``) is fitted as one turn of the whole sensor."""
    base_effects = list(base_effects)
    laser = np.asarray(data.baseline.ctx.laser, np.int64)
    n_lasers = int(laser.max()) + 1 if len(laser) else 0
    total = np.zeros((n_lasers, 2))
    information = np.zeros((n_lasers, 2, 2))
    lo, hi = cls.bounds['az_offsets_deg']

    def effect_of(off_rad: np.ndarray) -> Effect:
        deg = np.clip(np.degrees(off_rad), lo, hi)
        return cls({'az_offsets_deg': [round(float(v), 6) for v in deg[:, 0]],
                    'el_offsets_deg': [round(float(v), 6) for v in deg[:, 1]]})

    for step in range(2):
        on_top = [*base_effects, effect_of(total)] if step else base_effects
        model = model_on_rays(data, on_top)
        ctx = model.ctx
        if ctx.normal is None or ctx.direction is None or len(laser) < MIN_LASER_POINTS:
            break
        use = model.placed & np.isfinite(model.expected_range_m)
        y = np.asarray(data.measured_range_m, float) - model.expected_range_m
        grad = pointing.range_gradient_m_per_rad(ctx.range_m, ctx.direction, ctx.normal)
        if use.sum() < MIN_LASER_POINTS:
            break
        fitted, info = pointing.laser_pointing_rad(y[use], grad[use], model.sigma_m[use],
                                             _groups(data)[use], laser[use],
                                             np.asarray(data.baseline.directions)[use],
                                             data.window_width_m,
                                             turn_only=getattr(cls, 'turn_only', False))
        total[:len(fitted)] += fitted
        information[:len(info)] = info
    effect = effect_of(total)
    params = {'rms_offset_deg': effect.rms_offset_deg(),
              **{f'laser_{i}_{axis}_deg': float(v)
                 for i in range(n_lasers)
                 for axis, v in (('az', effect.params.az_offsets_deg[i]),
                                 ('el', effect.params.el_offsets_deg[i]))}}
    result = make_result_vector(effect, data, base_effects, params)
    # How well the points determine each laser's offsets (``laser_tiles.undetermined``).
    return replace(result, n_params=2 * n_lasers, extras={'laser_information': information})


def make_result_vector(effect: Effect, data: FitData, base_effects: Sequence[Effect],
                       params: dict) -> FitResult:
    """``make_result`` for an effect whose free parameter is a vector: ``params`` names
    its elements (plain floats)."""
    after = scores(data, [*base_effects, effect])
    before = scores(data, list(base_effects))
    return FitResult(name=type(effect).name, params=params, effect=effect,
                     nll_per_point=after['nll'], range_rmse_m=after['rmse'],
                     unmatched_explained=after['unmatched'], n_params=len(params),
                     nll_before_per_point=before['nll'], range_rmse_before_m=before['rmse'],
                     unmatched_explained_before=before['unmatched'],
                     nll_robust_per_point=after['nll_robust'],
                     nll_robust_before_per_point=before['nll_robust'])


MIN_GHOST_SCALE = 1e-4    # least scale on the ghost power a ghost fit searches (log scale)


def _fit_ghost_scale(cls: type[Effect], data: FitData,
                     base_effects: Sequence[Effect] = ()) -> FitResult:
    """ML scale on the ghost power (``cls.ghost_scale``, e.g. multipath's ``strength``),
    searched over log10 of it from MIN_GHOST_SCALE to the bound (the ghost's share
    1 - exp(-scale P / P_threshold) changes over decades of the scale, not steps), then
    against a scale of 0 (no ghosts). The ghosts are cast once (``likelihood.ghosts_on``)."""
    key = cls.ghost_scale
    lo, hi = cls.bounds[key]
    defaults = _defaults(cls)
    base_effects = list(base_effects)
    cache: dict[float, float] = {}

    def total(value: float) -> float:
        if value not in cache:
            eff = make_effect_safe(cls, {**defaults, key: value})
            cache[value] = (math.inf if eff is None
                            else objective(data, [*base_effects, eff], floor=ROBUST_FLOOR))
        return cache[value]

    start = max(lo, MIN_GHOST_SCALE)
    x = search_1d(lambda v: total(10.0 ** v), math.log10(start), math.log10(hi), n_grid=11)
    value = round(float(10.0 ** x), 6)
    if lo <= 0 and total(0.0) <= total(value):
        value = 0.0
    return make_result(cls({**defaults, key: value}), data, base_effects)


MIN_MATERIAL_STANDOFF_POINTS = 20   # fewer matched points on a material: no standoff of its own
SURFACE_OFFSET_STEPS = 4            # Gauss-Newton steps on the exact surface, at most
SURFACE_OFFSET_TOL_M = 1e-4         # ... until no standoff moves by more (m; scale x 10 m)


def _fit_surface_offset(cls: type[Effect], data: FitData,
                        base_effects: Sequence[Effect] = ()) -> FitResult:
    """Fit of ``surface_offset``: which parameters are free is chosen on the first-order
    columns at the mesh (``surface_offset.first_order_columns``: a standoff on
    -1 / cos(theta), a scale on -d / cos(theta), a standoff of a material's own on
    -1 / cos(theta) over its surfaces, estimated jointly in closed form with the material
    intercepts as nuisance), by the Bayes information criterion (total NLL of the
    linearised model plus half ln(N) per parameter, N matched points) in forward
    selection: from none, the parameter that lowers it most is freed, while one does. A
    parameter stays only where the data pay for it: on a body whose surfaces of one
    material lie at one distance from its origin (a cylinder's side) the scale's and the
    standoff's columns are nearly one, and the joint split would be noise.

    The chosen parameters are then refined on the exact surface (the effect's own forward
    model, the rays re-cast against the mesh standing proud): Gauss-Newton, each step the
    same closed form on the columns at the surface the rays now meet, until no standoff
    moves by more than SURFACE_OFFSET_TOL_M. On a curved body the first-order columns
    overstate the grazing rays' change (a cylinder's exact change is bounded by
    sqrt(2 R s) at its limb), so the linearised estimate alone runs low (0.70-0.83 of the
    truth for 4-2 cm on R = 2 m); the refined one does not."""
    from lidar_sim_ros.core.effects.surface_offset import first_order_columns
    base_effects = list(base_effects)
    zero = {**_defaults(cls), 'scale': 0.0, 'standoff_m': 0.0, 'material_standoff_m': {}}
    clip = float(cls(zero).params.max_incidence_deg)
    group = _groups(data)
    names = list(getattr(getattr(data.baseline.ctx.scene, 'target', None), 'material_names', []))
    counts = np.bincount(group[group >= 0], minlength=len(names)) if len(names) else []
    own = [names[m] for m in range(len(names)) if counts[m] >= MIN_MATERIAL_STANDOFF_POINTS
           and not getattr(cls, 'common_only', False)]   # the common part alone
    bounds = {**cls.bounds, **{m: cls.entry_bounds['material_standoff_m'] for m in own}}

    def columns(model: ModelOnRays, free: Sequence[str]) -> np.ndarray:
        at = first_order_columns(model.ctx, clip)
        return np.column_stack([
            at[k] if k in at else np.where(group == names.index(k), at['standoff_m'], 0.0)
            for k in free])

    def effect_of(values: dict) -> Effect | None:
        return make_effect_safe(cls, {
            **zero, **{k: v for k, v in values.items() if k in ('scale', 'standoff_m')},
            'material_standoff_m': {k: v for k, v in values.items() if k in own}})

    model = model_on_rays(data, base_effects)
    penalty = 0.5 * math.log(max(len(data.measured_range_m), 2))

    def linearised(free: tuple[str, ...]) -> tuple[dict, float]:
        x = columns(model, free)
        a = linear_bias_coefficients(data, model, x, [bounds[k] for k in free])
        moved = replace(model, expected_range_m=model.expected_range_m + x @ a)
        cost = float(np.sum(point_nll(data, moved, ROBUST_FLOOR)[0])) + penalty * len(free)
        return {k: float(v) for k, v in zip(free, a)}, cost

    best, best_cost = {}, float(np.sum(point_nll(data, model, ROBUST_FLOOR)[0]))
    pool = ['scale', 'standoff_m', *own]
    while True:
        tries = [(*linearised((*best, k)), k) for k in pool if k not in best]
        if not tries:
            break
        values, cost, _ = min(tries, key=lambda t: t[1])
        if not cost < best_cost:
            break
        best, best_cost = values, cost
    effect = effect_of(best) if best else cls(zero)
    free = tuple(best)
    for _ in range(SURFACE_OFFSET_STEPS if free else 0):
        at = model_on_rays(data, [*base_effects, effect])
        shift = {k: (bounds[k][0] - best[k], bounds[k][1] - best[k]) for k in free}
        step = linear_bias_coefficients(data, at, columns(at, free), [shift[k] for k in free])
        stepped = {k: best[k] + float(d) for k, d in zip(free, step)}
        moved = effect_of(stepped)
        if moved is None:
            break
        done = all(abs(float(d)) * (10.0 if k == 'scale' else 1.0) <= SURFACE_OFFSET_TOL_M
                   for k, d in zip(free, step))
        best, effect = stepped, moved
        if done:
            break
    p = effect.params
    params = {'scale': float(p.scale), 'standoff_m': float(p.standoff_m),
              **{f'standoff_{m}_m': float(v) for m, v in p.material_standoff_m.items()}}
    return make_result_vector(effect, data, base_effects, params)


def _register_catalogue_fits() -> None:
    from lidar_sim_ros.core.effects.laser_bias import LaserBias
    from lidar_sim_ros.core.effects.laser_pointing import LaserPointing
    from lidar_sim_ros.core.effects.multipath import Multipath
    from lidar_sim_ros.core.effects.surface_offset import SurfaceOffset
    register_fit(LaserBias)(_fit_laser_bias)
    register_fit(LaserPointing)(_fit_laser_pointing)
    register_fit(SurfaceOffset)(_fit_surface_offset)
    register_fit(Multipath)(_fit_ghost_scale)


_register_catalogue_fits()
