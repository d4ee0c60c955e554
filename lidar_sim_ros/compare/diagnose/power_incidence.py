"""A range walk against an incidence bias: each one's own part of the residual.

On a target held at one range the received power varies only through the incidence and
the material (whose range offset is profiled), so a walk free in sign, -k ln(P / P_th),
is one more function of the incidence: it can fit an incidence law of another form
better than ``incidence_angle``'s own r dtheta tan(theta) (another lab's law g r dtheta
sin(theta) / cos(theta)^a, held at 10 m: the walk named, 0.0093 nats/point over
incidence). Neither's held-out gain says which drives the bias there.

Each one's **own part** does: the walk's evidence is a dependence of the range on the
power *at a fixed incidence* (across ranges, or intensity fluctuations such as speckle),
incidence's a dependence on incidence *at a fixed power*. So (pure functions over the
matched points' arrays):

* the walk's driver ln P less a smooth function of the incidence fitted per material
  (``residual_part``: a cubic in theta, least squares), and incidence's driver, its own
  depth r tan(theta), less a smooth function of ln P per material;
* each driver's slope fitted with per-material offsets and sigma scales on the residual
  the model leaves without either effect, cross-fitted over the diagnosis's folds
  (``own_part``): the held-out Gaussian log-likelihood gain over the offsets alone, per
  point, and its block-robust z.

``Diagnosis.power_or_incidence`` asks a named walk that reads weak returns short (k_m < 0,
as an incidence bias reads grazing returns through the power: ``reads_as_incidence``),
beside an incidence bias that may be named too, for its own part by the naming rule:
the walk stays where it passes; incidence is named where only its own part passes; where
neither passes, the answer is their tie (the bias follows the incidence and the power
together; ``plan.yaml`` names the recording that separates them). A walk's range part
is taken beyond the range times a smooth function of incidence vanishing at normal
incidence (``walk_driver``): a bias in proportion to range, as the footprint family's
is, moves with the range as a walk does.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.diagnose.features import block_mean_se
from lidar_sim_ros.compare.diagnose.range_outside import NAME_SHARE

WALK, INCIDENCE, SCALE = 'range_walk', 'incidence_angle', 'range_scale'
PAIR = (WALK, INCIDENCE)
# A named incidence bias and a walk (or a named walk and an incidence bias) weighed each
# on top of the other, both refitted together (``Diagnosis.walk_beside_incidence``): both
# named, or their tie.
BOTH, TIE = 'both', 'tie'
# Least share of the features' structure a walk and an incidence bias weighed together,
# where neither may be named alone, explain to be named (``Diagnosis.pair_beside_nothing``):
# most of it, as a range term weighed where the structure is left outside the catalogue
# (``range_outside.NAME_SHARE``, the same number); two forms fit part of any smooth
# pattern. Set before any run.
PAIR_SHARE = NAME_SHARE
DEGREE = 3                  # the smooth function a driver's part is taken beyond
MIN_GROUP_POINTS = 20       # a material with fewer keeps its driver about its mean
CORE_SIGMAS = 6.0           # points farther from their material's median are left out
MAX_INCIDENCE_RAD = np.radians(80.0)


@dataclass(frozen=True)
class OwnPart:
    """One driver's own part: held-out gain (nats per used point), z, slope (m per unit
    of the driver), points used, and the driver's spread beyond the smooth function
    (RMS, its own units)."""

    gain_per_point: float
    z: float
    slope: float
    points: int
    driver_rms: float

    def as_dict(self) -> dict:
        return {'gain_per_point': round(self.gain_per_point, 5), 'z': round(self.z, 2),
                'slope': float(f'{self.slope:.5g}'), 'points': self.points,
                'driver_rms': float(f'{self.driver_rms:.4g}')}


def residual_part(y: np.ndarray, x: np.ndarray, group: np.ndarray,
                  degree: int = DEGREE, scale: np.ndarray | None = None) -> np.ndarray:
    """``y`` less a least-squares polynomial of ``degree`` in ``x`` fitted per group
    (x standardised per group), and with ``scale`` given, less ``scale`` times a
    polynomial in x of the same degree without its constant (x as given, so the term
    vanishes at x = 0); a group of fewer than MIN_GROUP_POINTS points loses its mean
    only. NaN where y, x or scale is not finite."""
    y, x = np.asarray(y, float), np.asarray(x, float)
    out = np.full(len(y), np.nan)
    ok = np.isfinite(y) & np.isfinite(x)
    if scale is not None:
        scale = np.asarray(scale, float)
        ok &= np.isfinite(scale)
    for g in np.unique(group[ok]):
        idx = np.flatnonzero(ok & (group == g))
        if len(idx) < MIN_GROUP_POINTS:
            out[idx] = y[idx] - np.mean(y[idx])
            continue
        xs = x[idx]
        span = np.std(xs)
        t = (xs - np.mean(xs)) / (span if span > 0 else 1.0)
        basis = np.vander(t, degree + 1)
        if scale is not None:
            s = scale[idx] - np.mean(scale[idx])
            basis = np.column_stack([basis, s[:, None] * np.vander(xs, degree + 1)[:, :-1]])
        coef, *_ = np.linalg.lstsq(basis, y[idx], rcond=None)
        out[idx] = y[idx] - basis @ coef
    return out


def walk_driver(log_power: np.ndarray, incidence_rad: np.ndarray, material: np.ndarray,
                range_m: np.ndarray | None = None) -> np.ndarray:
    """ln P's part a smooth per-material function of the incidence does not predict, nor,
    with ``range_m``, the range times a smooth function of the incidence that vanishes at
    normal incidence (the footprint family's bias, r f(theta), f(0) = 0, moves with the
    range at a fixed incidence as a walk does: its range part is not the walk's own; a
    walk's range part at normal incidence is)."""
    return residual_part(log_power, incidence_rad, material, scale=range_m)


def incidence_driver(range_m: np.ndarray, incidence_rad: np.ndarray, log_power: np.ndarray,
                     material: np.ndarray) -> np.ndarray:
    """Incidence's own depth r tan(theta) (theta clipped at 80 deg, m), its part a smooth
    per-material function of ln P does not predict."""
    theta = np.minimum(np.asarray(incidence_rad, float), MAX_INCIDENCE_RAD)
    return residual_part(np.asarray(range_m, float) * np.tan(theta), log_power, material)


def scale_driver(range_m: np.ndarray, log_power: np.ndarray,
                 material: np.ndarray) -> np.ndarray:
    """A range scale's own driver, the range (m), its part a smooth per-material function
    of ln P does not predict."""
    return residual_part(np.asarray(range_m, float), log_power, material)


def _fit(e: np.ndarray, w: np.ndarray, group: np.ndarray, x: np.ndarray | None):
    """Weighted least squares of ``e`` on per-group offsets (and a common slope on ``x``):
    (per-group offsets as a dict, slope)."""
    groups = np.unique(group)
    cols = [(group == g).astype(float) for g in groups]
    if x is not None:
        cols.append(x)
    a = np.column_stack(cols) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(a, e * np.sqrt(w), rcond=None)
    return dict(zip(groups.tolist(), coef[:len(groups)])), (float(coef[-1]) if x is not None
                                                           else 0.0)


def _heldout_nll(e, sigma, group, x, train, test) -> tuple[np.ndarray, float]:
    """Per test point Gaussian NLL (nats, up to a constant) of offsets (+ slope on x) and
    per-group sigma scales fitted on ``train``; and the slope."""
    w = 1.0 / sigma[train] ** 2
    offs, slope = _fit(e[train], w, group[train], None if x is None else x[train])
    pred_tr = np.array([offs[g] for g in group[train]]) + (0 if x is None else slope * x[train])
    z2 = ((e[train] - pred_tr) / sigma[train]) ** 2
    scale = {g: np.sqrt(max(np.mean(z2[group[train] == g]), 1e-6)) for g in offs}
    known = np.array([g in offs for g in group[test]])
    gt = group[test]
    off = np.array([offs.get(g, 0.0) for g in gt])
    sc = np.array([scale.get(g, 1.0) for g in gt])
    pred = off + (0 if x is None else slope * x[test])
    s = sigma[test] * sc
    nll = 0.5 * ((e[test] - pred) / s) ** 2 + np.log(s)
    return np.where(known, nll, np.nan), slope


def own_part(residual_m: np.ndarray, sigma_m: np.ndarray, group: np.ndarray,
             driver: np.ndarray, fold: np.ndarray, blocks: np.ndarray) -> OwnPart:
    """The held-out gain of a common slope on ``driver`` over per-group offsets alone, on
    ``residual_m`` (m, sigma ``sigma_m``), cross-fitted over ``fold`` (each fold scored
    by the fit on the others), per used point, with its z (``blocks``: neighbourhoods)."""
    e, s = np.asarray(residual_m, float), np.asarray(sigma_m, float)
    use = np.isfinite(e) & np.isfinite(s) & (s > 0) & np.isfinite(driver)
    for g in np.unique(group[use]):
        idx = np.flatnonzero(use & (group == g))
        med = np.median(e[idx])
        mad = 1.4826 * np.median(np.abs(e[idx] - med)) or np.median(s[idx])
        use[idx] &= np.abs(e[idx] - med) <= CORE_SIGMAS * mad
    idx = np.flatnonzero(use)
    if len(idx) < 2 * MIN_GROUP_POINTS or len(np.unique(fold[idx])) < 2:
        return OwnPart(0.0, 0.0, 0.0, int(len(idx)), 0.0)
    e, s, g, x, f, b = e[idx], s[idx], group[idx], driver[idx], fold[idx], blocks[idx]
    d = np.full(len(idx), np.nan)
    for k in np.unique(f):
        test, train = f == k, f != k
        base, _ = _heldout_nll(e, s, g, None, train, test)
        with_x, _ = _heldout_nll(e, s, g, x, train, test)
        d[test] = base - with_x
    ok = np.isfinite(d)
    gain, se = block_mean_se(d[ok], b[ok])
    _, slope = _fit(e, 1.0 / s ** 2, g, x)
    z = gain / se if se > 0 and np.isfinite(se) else 0.0
    return OwnPart(float(gain), float(z), slope, int(ok.sum()), float(np.sqrt(np.mean(x ** 2))))


def both_parts(residual_m, sigma_m, material, log_power, incidence_rad, range_m, fold,
               blocks) -> dict[str, OwnPart]:
    """Each of the pair's own part (``own_part``) on the same points: the walk's on
    ``walk_driver``, incidence's on ``incidence_driver``; and a range scale's beyond the
    power (``scale_driver``), asked of one said beside a walk."""
    material = np.asarray(material, int)
    return {WALK: own_part(residual_m, sigma_m, material,
                           walk_driver(log_power, incidence_rad, material, range_m), fold,
                           blocks),
            INCIDENCE: own_part(residual_m, sigma_m, material,
                                incidence_driver(range_m, incidence_rad, log_power, material),
                                fold, blocks),
            SCALE: own_part(residual_m, sigma_m, material,
                            scale_driver(range_m, log_power, material), fold, blocks)}


def figures_in(pair_z: dict | None) -> dict | None:
    """The own parts' figures ``Diagnosis.power_or_incidence`` put beside the named
    candidates (``pair_z[incidence_angle]['power_incidence']``), or None."""
    return next((v['power_incidence'] for v in (pair_z or {}).values()
                 if isinstance(v, dict) and 'power_incidence' in v), None)


def reads_as_incidence(k_m: float) -> bool:
    """Whether a walk -k_m ln(P / P_th) fitted with this k_m (m) reads weak returns short
    (k_m < 0): the way an incidence bias of the footprint family reads through the power
    on a hold (its early edge at grazing incidence, where returns are weak), and the
    opposite of a leading-edge discriminator's walk (a weak pulse crosses the threshold
    late: long, k_m > 0). Fitted on the battery's and INCIDENCE_LAW's recordings, every
    hidden walk gave k_m 0.011 to 0.026 and every hidden incidence bias -0.007 to -0.044
    (the lab's -0.026). Only a walk that reads as an incidence bias must show its own part
    before it is named beside one."""
    return bool(k_m < 0.0)


def also_not_shown_words(figures: dict[str, dict], walk: str = WALK) -> str:
    """The verdict's words where an incidence bias or a range scale adds on top of a named
    walk but shows no part of its own (``Diagnosis.also_beside_walk``)."""
    name = figures.get('also_name', INCIDENCE)
    i = figures[name]
    what = 'the incidence' if name == INCIDENCE else 'the range'
    return (f'{name} gains on top of {walk} too, but shows no part of its own: at a '
            f'fixed received power its dependence on {what} gains '
            f'{i["gain_per_point"]:.4f} nats/point held out (z = {i["z"]:.1f}), which does '
            f'not pass the rule. What it adds follows the power, as a walk of another law '
            f'in ln P, or one read on a noisy or clipped intensity, leaves it; it is not '
            f'said as a separate effect.')


def tie_words(figures: dict[str, dict], rule: str = 'the rule') -> str:
    """The verdict's words where neither has an own part that passes the rule
    (``figures``: each name's ``OwnPart.as_dict``)."""
    w, i = figures[WALK], figures[INCIDENCE]
    return (f'the range bias follows the incidence and the received power together: at a '
            f'fixed incidence the power explains {w["gain_per_point"]:.4f} nats/point held '
            f'out (z = {w["z"]:.1f}), at a fixed power the incidence '
            f'{i["gain_per_point"]:.4f} (z = {i["z"]:.1f}), neither passing {rule}; on this '
            'recording the power moves only with the incidence and the material, so a range '
            'walk and an incidence bias cannot be told apart (two reflectivities at one '
            'incidence, a spread of ranges, or a target whose incidence and range vary apart '
            'would separate them)')


def joint_outcome(other_passes: bool, named_passes: bool) -> str | None:
    """A named incidence bias beside a walk (or a named walk beside an incidence bias),
    each weighed on top of the other refitted with it: BOTH where each passes the rule;
    TIE where neither does, or only the other (the named one then has no part of its
    own: which drives the bias cannot be told); None where only the named one passes
    (it stands alone)."""
    if other_passes:
        return BOTH if named_passes else TIE
    return None if named_passes else TIE


def pair_outcome(pair_passes: bool, walk_passes: bool, incidence_passes: bool) -> str | None:
    """A walk and an incidence bias neither of which may be named alone (each alone sees
    only their net where they partly cancel), fitted together on each training fold:
    BOTH where the pair passes the rule over the model without either and each passes
    on top of the other; TIE where the pair passes and the data do not split it; None
    where the pair does not pass (what is left stays outside the catalogue)."""
    if not pair_passes:
        return None
    return BOTH if walk_passes and incidence_passes else TIE


def pair_figures(pair_z: dict) -> dict | None:
    """The figures of a walk and an incidence bias weighed as a pair where neither was
    named alone (``Diagnosis.pair_beside_nothing``), if they were named (both or tied)."""
    for w in pair_z.values():
        f = w.get('jointly') if isinstance(w, dict) else None
        if f and f.get('outcome') in ('pair_both', 'pair_tie'):
            return f
    return None


def pair_words(pair_z: dict) -> str:
    """The verdict's sentence on a walk and an incidence bias named as a pair (or '')."""
    f = pair_figures(pair_z)
    if f is None:
        return ''
    named = f['named']
    other = INCIDENCE if named == WALK else WALK
    (g, z), (go, zo), (gn, zn) = (f['pair_over_none'], f['other_on_top_of_named'],
                                  f['named_on_top_of_other'])
    head = (f'Alone, {named} and {other} each fit only their net (of opposite signs they '
            f'partly cancel) and neither passes the rule; refitted together on each training '
            f'fold the pair gains {g:.4f} nats/point held out over neither (z = {z:.1f}; '
            f'fitted on all the points, NLL {f["before_nll"]:.4f} -> '
            f'{f["pair_nll_after"]:.4f}), {other} {go:.4f} (z = {zo:.1f}) on top of {named} '
            f'alone and {named} {gn:.4f} (z = {zn:.1f}) on top of {other} alone')
    if f['outcome'] == 'pair_both':
        return (head + f': both are there. Fit them together: --effect {named} --effect '
                f'{other} --fit (each alone would be fitted at their net).')
    return (head + ': the pair explains the residual, but these data do not split it '
            'between the two (a spread of received power at one incidence would).')
