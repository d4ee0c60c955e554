"""An effect fitted over its discrete options (``variants``: e.g. a footprint's range
mode), several effects refitted each with the others until they settle
(``refit_in_turn``), and the figures a fit is scored by: the held-out NLL per point
(with an outlier floor), the tile test's transfer between halves, and the calibrated
figures a ``--fit`` run reports. NLL in nats per point, ranges in m.
"""
from __future__ import annotations

import itertools
from typing import Literal, get_args, get_origin

import numpy as np
from pydantic import create_model

from lidar_sim_ros.compare.diagnose import laser_tiles
from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.model.fit import fit_effect, shift_offsets_along
from lidar_sim_ros.compare.model.likelihood import is_outlier_effect
from lidar_sim_ros.compare.model.materials import robust_sigma
from lidar_sim_ros.core.effects import Effect

OUTLIER_FLOOR = 1e-5        # outlier weight every held-out likelihood carries (robustness)
JOINT_ROUNDS = 8           # passes refitting several effects each with the others (refit_in_turn)


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


def missed_shots_gain(data, effect: Effect) -> float:
    """What a false-return ``effect`` gains over the model without it on the shots that
    missed the target (``lk.missed_shots_nll``: the binomial count of false returns
    among them), nats per matched point of ``data``; 0 for an effect that adds none, or
    when the shots fired are unknown. With ``calibrated_figures``' NLL it is the
    fitted footing on the likelihood such an effect is fitted and held out on: a
    background's evidence sits mostly on the misses, which listen over the whole window."""
    n = len(data.measured_range_m)
    if not is_outlier_effect(type(effect)) or n == 0:
        return 0.0
    before = lk.missed_shots_nll(data, lk.model_on_rays(data, []), [])
    after = lk.missed_shots_nll(data, lk.model_on_rays(data, [effect]), [effect])
    return float((before - after) / n) if np.isfinite(before - after) else 0.0


def heldout_nll(data, effects: list[Effect]) -> np.ndarray:
    """Per-point NLL (nats) of ``data``'s matched ranges under baseline + ``effects``:
    the fitting likelihood (per-material nuisance profiled) with an outlier floor."""
    model = lk.model_on_rays(data, effects)
    return lk.point_nll(data, model, OUTLIER_FLOOR)[0]


def transfer_both_ways(variant: type[Effect], data: list, on_top: list[Effect] = ()
                       ) -> list[np.ndarray]:
    """Per-point held-out NLL of each of two halves (``data``: two FitData) under
    ``variant`` fitted on the other half, with ``on_top`` (fitted effects) in the model:
    the tile test's transfer (``Diagnosis.transfer_nll``). NaN on the points of a laser
    whose offsets the training half does not determine (``laser_tiles.undetermined``)."""
    fits = [fit_effect(variant, data[1 - k], list(on_top)) for k in range(len(data))]
    info = [f.extras.get('laser_information') for f in fits]
    cells = [f.extras.get('offset_cells') for f in fits]
    out = []
    for k, part in enumerate(data):
        effect = fits[k].effect
        # The lasers' offsets that the other half leaves as loose as a few shared points
        # do (groups of lasers linked through a material's intercept only there) are no
        # evidence of a pattern: their level is taken on this half
        # (``laser_tiles.poorly_linked``).
        free = laser_tiles.poorly_linked(cells[k], cells[1 - k])
        if free is not None and free.shape[1]:
            effect = shift_offsets_along(effect, part, list(on_top), free)
        nll = heldout_nll(part, [*on_top, effect])
        # A laser whose offsets the other half does not determine (two per laser, seen
        # through the surface's slope there) is not scored (``laser_tiles.undetermined``).
        unknown = laser_tiles.undetermined(info[k], info[1 - k])
        if unknown is not None:
            laser = np.asarray(part.baseline.ctx.laser, np.int64)
            nll = np.where(unknown[np.clip(laser, 0, len(unknown) - 1)]
                           & (laser < len(unknown)), np.nan, nll)
        out.append(nll)
    return out


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


def fit_best_variant(effect_cls: type[Effect], data, fixed: dict | None = None,
                     on_top: list[Effect] = ()):
    """ML fit over the free parameters and the discrete options, with ``on_top`` (fitted
    effects) in the model: (FitResult, variant class)."""
    best = None
    for v in variants(effect_cls, fixed):
        fit = fit_effect(v, data, list(on_top))
        if best is None or fit.nll_per_point < best[0].nll_per_point - 1e-9:
            best = (fit, v)
    return best


def refit_in_turn(data, effects: list[Effect], fixed_of: list[dict],
                  rounds: int = JOINT_ROUNDS, on_top: list[Effect] = ()) -> list[Effect]:
    """``effects`` (fitted each on top of those before it) refitted each with all the
    others in the model, in turn, until their parameters settle (within 1 %) or
    ``rounds`` passes: the joint maximum of the likelihood, not the first effect's
    value alone. Two effects that share part of the residual (a range walk and an
    incidence elongation: grazing returns are weak and long) otherwise leave the first
    with the other's share (the eighth holdout: walk k 0.0236 alone, 0.0156 together,
    for a true 0.015). ``fixed_of``: per effect, the parameters the user fixed; ``on_top``:
    fitted effects kept as they are in the model."""
    done = list(effects)
    for _ in range(rounds):
        before = [e.params.model_dump() for e in done]
        for i, eff in enumerate(done):
            cls = type(eff)
            fit, _ = fit_best_variant(cls, data, fixed_of[i],
                                      on_top=[*on_top, *done[:i], *done[i + 1:]])
            done[i] = plain(cls, fit.effect)
        if all(_settled(a, b.params.model_dump()) for a, b in zip(before, done)):
            break
    return done


def _settled(before: dict, after: dict) -> bool:
    """Every numeric parameter within 1 % of its value (or 1e-9) before."""
    for k, v in after.items():
        was = before.get(k)
        for a, b in zip(np.ravel(was if was is not None else v), np.ravel(v)):
            if isinstance(b, (int, float, np.floating)) and not isinstance(b, bool) and \
                    abs(float(b) - float(a)) > max(0.01 * abs(float(b)), 1e-9):
                return False
    return True


def plain(effect_cls: type[Effect], effect: Effect) -> Effect:
    """A variant's fitted instance as an instance of the original class (same params)."""
    return effect_cls(effect.params.model_dump())
