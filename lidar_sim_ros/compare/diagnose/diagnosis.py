"""Which effect is missing: fit the catalogue, score each on held-out points, decide.

Every candidate is fitted by maximum likelihood (``compare.model.fit.fit_effect``; for effects
with discrete options, e.g. a footprint's range mode, each option is fitted and the
best kept). The likelihood profiles each material's range offset and sigma scale
(nuisance parameters), so a per-material calibration mismatch cannot pose as an
effect. The score is the held-out gain in log likelihood, in nats per measured
point: the points are split in two halves, the candidate is fitted on one and scored
on the other and vice versa, so extra parameters cannot win on noise. The held-out
likelihood is outlier tolerant (a small uniform floor), so a handful of odd returns
cannot dominate. Unmatched points a candidate explains (returns beyond the
silhouette, false returns off the target) count too, as many as it explains beyond
those the model's own effects already explain, and only with the effect's own
signature (``unmatched_credit``): points beyond the silhouette mark pose and timing
errors as much as a footprint; a footprint's show the share of the beam that hit, a
rigid effect's (a standoff, a turned beam, a clock offset) a whole beam's power.

A diagnosis is a claim to a user. A candidate is named (``missing_effect``) only if
all of these hold, each chosen from a principle, not from a dataset:

One rule, on the quantity the verdict quotes (the score, matched and unmatched, and
its z, ``total_z``), whatever part of the data the gain is on:

* **decisive**: its held-out gain is Z_CRIT block-robust standard errors above zero,
  Bonferroni-corrected for testing every candidate (one-sided family error rate
  FAMILY_ALPHA), and at least MIN_TOTAL_GAIN nats in total (odds e^15);
* **it matters**: at least MIN_PRACTICAL_GAIN nats per point, the gain of an effect
  that moves the predicted range by 10 % of the noise sigma RMS over all points
  (0.5 x 0.1^2), or changes the sigma by ~7 %: below that the model's clouds and the
  sensor's are the same to anyone using them;
* **its signature is there**: an outlier effect (solar background) needs isolated
  points far beyond the noise (|residual| > max(FAR_MIN_M, FAR_SIGMAS sigma)) or
  isolated unmatched returns, comparable in number to the spurious returns it
  claims (surfaces that are not the target, e.g. lab clutter, are not isolated: a
  neighbouring ray sees the same range), and, since background light triggers at
  random times, the far points must spread over the range window as background
  arrivals would. Background photons are a Poisson process, so the first to trigger
  falls at range x (share of the window) with density ~ exp(-rate x): evenly for a
  weak background, crowding the window's start for a strong one (``arrival_cdf``;
  the rate is fitted to the far points, ``background_rate``, rate >= 0). Under that
  law they must not lie mostly behind the surface when the window puts many in front
  (``far_sides``), and must spread within each side as the law says
  (``far_positions``, Kolmogorov-Smirnov at the same Bonferroni level), else they
  come at a preferred range (multipath, a ghost, a second surface); multipath needs
  MIN_FAR_POINTS points behind specular surfaces at the range its mirror rays predict
  (``likelihood.ghost_points``), its gain being the ghost component of the likelihood
  on exactly those points; a bias or noise effect must account for at
  least MIN_SHARE of the residual's dependence on the features that the attribution's
  joint model finds (``features.Attribution``): a candidate that soaks up a sliver of
  a structure it does not have the shape of is a phantom (the rest of the structure
  is outside the catalogue); a candidate with a parameter per laser must show offsets
  that hold across each laser's tile (``tile_veto``, ``laser_tiles``), and lasers'
  pointing offsets a part of each laser's own beyond a turn of the whole sensor, which
  is the mount's or the pose's (``own_part_veto``); a noise effect
  must widen the core of the residual distribution (``core_veto``) and, driven by the
  measured power, cannot stand for a driver that is another feature (``driver_veto``);
* **it is decisively the best**: the paired held-out per-point NLL difference to
  every other admissible candidate is decisive (z above the same bound) and, with both
  fitted as --fit would leave them (all the points, every material's offset and sigma
  refit), at least MIN_PRACTICAL_GAIN nats per point apart (``fitted_margin``). Otherwise the
  two explain the data equally within their uncertainty (both matter: which of them
  is a statistical question): if fitting one on top of the other still gains (they explain
  different parts, two effects at once) the better is named and the other comes
  next; if not, they are confounded in this recording (``confounded_with``), none is
  named, and the verdict says which recording would separate them.
  A candidate with a parameter per laser passes on top of a simpler one that it does not
  beat decisively, not instead of it (``simpler_instead``). A candidate the rule keeps
  from naming only by its z or its share, not decisively worse, must be passed on top
  of too, else nothing is named (``rival_takes``, ``same_part``).

And, fitted as --fit leaves it (``naming_fault``), its NLL is below the model's without it,
no parameter sits at the edge of its search box, and, where the verdict quotes the range
RMSE (an effect that moves ranges or rays), that RMSE does not rise (``rmse_fault``): a
fit that gains likelihood while the ranges it predicts move away from those measured
takes points its form does not reproduce (mixed pixels between an edge and a wall
behind it read as a footprint 8-10 times the beam; the points' place is said,
``mixed_edges``).

Otherwise ``missing_effect`` is null, and the verdict says what the residual depends
on, if anything, and that no catalogue effect explains it.

The range errors kept out of the default candidates (POSE_RIVALS), and the target's
surfaces off its mesh (GEOMETRY_RIVALS), never name themselves on a recording where
nothing else is named; they are weighed against a named effect
(``weigh_rivals``: ``decide`` again among all) and against a reported reference pose
(``weigh_pose_rivals``).
"""
from __future__ import annotations

import time
from dataclasses import replace
from types import SimpleNamespace
from typing import Callable

import numpy as np
from scipy.stats import kstest, norm

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.diagnose import (beside, laser_tiles, power_incidence,
                                            range_outside, same_part, standoff_part)
from lidar_sim_ros.compare.diagnose.candidate import (
    FAMILY_ALPHA, GEOMETRY_RIVALS, MAX_ALSO_TRIES, MIN_PRACTICAL_GAIN, MIN_SHARE,
    MIN_TOTAL_GAIN, MIN_UNMATCHED_EXPLAINED, MIN_UNMATCHED_FRACTION, N_FOLDS, POSE_ERROR,
    POSE_RIVALS, SHARES_DILATION, UNMATCHED_NATS, Candidate, Decision, _num)
# The names a verdict may hold beside the catalogue's, read as ``diagnosis.X`` by the
# report and the plan.
from lidar_sim_ros.compare.diagnose.candidate import RANGE_DRIFT, RANGE_OF_RANGE  # noqa: F401
from lidar_sim_ros.compare.diagnose.far_returns import (
    CORE_SIGMAS, FAR_MIN_M, FAR_SIGMAS, MIN_FAR_POINTS, MIN_FAR_SHARE, background_rate,
    core_points, far_from_surface, far_positions, far_sides, no_false_returns,
    off_target_positions)
from lidar_sim_ros.compare.diagnose.pose_weighing import PoseWeighing
from lidar_sim_ros.compare.diagnose.unmatched_credit import unmatched_credit
from lidar_sim_ros.compare.diagnose.fit_data import RaySet, make_fit_data
from lidar_sim_ros.compare.diagnose.variants import (
    calibrated_figures, fit_best_variant, heldout_nll, literal_choices, missed_shots_gain,
    plain, refit_in_turn, transfer_both_ways, variants)
from lidar_sim_ros.compare.diagnose.features import Attribution, block_mean_se, block_mean_z
from lidar_sim_ros.compare.model import field_pattern, pointing
from lidar_sim_ros.compare.model.fit import at_bounds, fit_effect
from lidar_sim_ros.compare.model.likelihood import is_outlier_effect  # noqa: F401 (re-exported)
from lidar_sim_ros.compare.model.matching import Model
from lidar_sim_ros.core.effects import Effect


class Diagnosis(PoseWeighing):
    """Scores effect classes against the model with ``base_effects`` (the likelihood
    profiles each material's offset and sigma scale)."""

    def __init__(self, model: Model, base_effects: list[Effect], rays: RaySet, seed: int = 0):
        self.model, self.base, self.rays = model, list(base_effects), rays
        self.full = make_fit_data(model, self.base, rays)
        self.folds = rays.split(N_FOLDS, seed)
        self.fold_data = [make_fit_data(model, self.base, f, (self.full, rays))
                          for f in self.folds]
        self.n_total = len(rays.matched) + len(rays.unmatched)
        self._base_nll = [heldout_nll(d, []) for d in self.fold_data]
        # Unmatched points the model's own effects explain, per fold (every candidate's
        # unmatched credit is counted beyond these).
        self._base_unmatched = [lk.unmatched_explained(d, []) if len(d.unmatched_range_m)
                                else 0.0 for d in self.fold_data]
        # Per matched point of the folds' test sides (in fold order): neighbourhoods.
        blocks = rays.blocks if rays.blocks is not None else np.arange(len(rays.meas))
        self.blocks = np.concatenate([blocks[self.folds[(k + 1) % N_FOLDS].matched]
                                      for k in range(N_FOLDS)])
        # Per matched point of the folds' test sides (``cross_fit`` order): its place in
        # ``rays.matched``; and the neighbourhoods in that order.
        self.fold_order = self.places(np.concatenate(
            [self.folds[(k + 1) % N_FOLDS].matched for k in range(N_FOLDS)]))
        self.matched_blocks = blocks[rays.matched]
        far, residual, expected, threshold = far_from_surface(self.full, details=True)
        if rays.isolated is not None:
            far &= rays.isolated[rays.matched]
        self.n_far = int(far.sum())
        far_args = (residual[far], expected[far], threshold[far], self.full.range_window_m)
        self.far_rate = background_rate(*far_args)
        self.far_sides = far_sides(*far_args, self.far_rate)
        self.far_u = far_positions(*far_args, self.far_rate)
        off = (np.asarray(self.full.unmatched_range_m, float)[rays.isolated[rays.unmatched]]
               if rays.isolated is not None and len(rays.unmatched) else np.zeros(0))
        self.off_ranges_m = off[np.isfinite(off)]
        # A shot that misses listens from the start of the sensor's gate (``miss_window``),
        # not from the target's nearest return: background light knows nothing of where
        # the target is.
        self.off_u = off_target_positions(self.off_ranges_m, self.full.miss_window)
        self._base_outlier_w = float(np.mean(lk.model_on_rays(
            self.full, []).outlier_w)) if len(self.rays.matched) else 0.0

    def score(self, effect_cls: type[Effect]) -> Candidate:
        """Cross-fitted on halves (the score): fitted on one half, scored on the other,
        both ways; the discrete options are chosen on the first half. ``finalize`` then
        fits the candidates that count on all the points (their reported figures)."""
        name = getattr(effect_cls, 'name', '') or effect_cls.__name__
        cand = Candidate(name)
        t0 = time.perf_counter()
        try:
            first, variant = fit_best_variant(effect_cls, self.fold_data[0])
            self._describe(cand, effect_cls, first)
            cand.variant = variant
            nll, explained = self.cross_fit(variant, [], first=first.effect)
            self._set_gain(cand, nll, explained)
            cand.vetoed = self._veto(cand, explained)
            if cand.vetoed is None and cand.significant and cand.practical:
                cand.vetoed = self.tile_veto(cand)
                cand.tile_vetoed = cand.vetoed is not None
                cand.vetoed = cand.vetoed or self.core_veto(cand)
                if cand.vetoed is None:
                    cand.vetoed = self.material_veto(cand)
                    cand.material_vetoed = cand.vetoed is not None
                cand.vetoed = cand.vetoed or self.own_part_veto(cand)
        except Exception as exc:  # noqa: BLE001 - one failing candidate must not stop the rest
            cand.error = f'{type(exc).__name__}: {exc}'
            cand.score = float('-inf')
        cand.seconds = time.perf_counter() - t0
        return cand

    def finalize(self, cand: Candidate) -> None:
        """Fit the candidate on all the diagnosed points: the parameters, snippet and
        "after" figures the summary reports (what --effect NAME --fit would show)."""
        if cand.variant is None or cand.error is not None:
            return
        t0 = time.perf_counter()
        effect_cls = type(cand.effect)
        fit = fit_effect(cand.variant, self.full)
        self._describe(cand, effect_cls, fit)
        cand.nll_after, cand.range_rmse_after_m, cand.range_robust_sigma_after_m = \
            calibrated_figures(self.full, [cand.effect])
        cand.missed_gain_after = missed_shots_gain(self.full, cand.effect)
        cand.unmatched_gain_after = unmatched_gain(cand, len(self.full.measured_range_m))
        cand.seconds += time.perf_counter() - t0

    def finalized(self, *cands: Candidate) -> None:
        """``finalize`` each of ``cands`` not finalized yet (its ``nll_after`` still NaN)."""
        for c in cands:
            if not np.isfinite(c.nll_after):
                self.finalize(c)

    def _describe(self, cand: Candidate, effect_cls: type[Effect], fit) -> None:
        options = {k: getattr(fit.effect.params, k) for k in literal_choices(effect_cls)}
        cand.params = {**{k: float(v) for k, v in fit.params.items()}, **options}
        cand.at_bound = at_bounds(fit.effect)
        cand.unmatched_explained = fit.unmatched_explained
        cand.n_params = fit.n_params
        cand.effect = plain(effect_cls, fit.effect)
        cand.yaml = _snippet(cand.effect)

    def cross_fit(self, variant: type[Effect], on_top: list[Effect],
                  first: Effect | None = None) -> tuple[np.ndarray, float]:
        """Held-out per-point NLL (test sides concatenated) of the model with ``on_top``
        plus ``variant`` fitted on the other fold, and the unmatched points it explains
        that carry its own signature (``unmatched_credit``). ``first``: the fit on fold 0,
        if already made."""
        nll, explained = [], 0.0
        for k, train in enumerate(self.fold_data):
            test = self.fold_data[(k + 1) % N_FOLDS]
            effect_k = first if (k == 0 and first is not None) else \
                fit_effect(variant, train, on_top).effect
            nll.append(heldout_nll(test, [*on_top, effect_k]))
            if len(test.unmatched_range_m):
                # What the candidate adds: the model's own effects (a fitted solar
                # background, say) already account for some unmatched points.
                before = (lk.unmatched_explained(test, list(on_top)) if on_top
                          else self._base_unmatched[(k + 1) % N_FOLDS])
                after = lk.unmatched_explained(test, [*on_top, effect_k])
                gained = max(after - before, 0.0) * len(test.unmatched_range_m)
                explained += unmatched_credit(test, [*on_top, effect_k], effect_k, gained)
        return np.concatenate(nll), explained

    def base_heldout(self) -> np.ndarray:
        """The model without a candidate, per matched point, in ``cross_fit`` order
        (test folds 1, 2, ..., 0)."""
        return np.concatenate([self._base_nll[(k + 1) % N_FOLDS] for k in range(N_FOLDS)])

    def _set_gain(self, cand: Candidate, nll: np.ndarray, explained: float) -> None:
        """The one decision rule (module doc), on the quantity the verdict quotes: the
        held-out gain per analysed point (matched points plus the unmatched points the
        candidate explains with its own signature, UNMATCHED_NATS each) and its z."""
        cand.heldout_nll = nll
        d = self.base_heldout() - nll
        ok = np.isfinite(d)
        se_matched = 0.0
        if ok.sum() > 1:
            cand.matched_gain, se_matched = block_mean_se(d[ok], self.blocks[ok])
            cand.z_matched = (float(cand.matched_gain / se_matched)
                              if se_matched > 0 and np.isfinite(se_matched) else 0.0)
        if (explained > 0 and cand.effect is not None and not is_outlier_effect(type(cand.effect))
                and cand.effect.cast_reach_rad(self.model.divergence_rad) is None
                and cand.z_matched < self.z_crit):
            # A ray-moving effect without a signature of its own off the target (a time
            # offset): the points it puts back count only when its matched points show it.
            explained = 0.0
        if explained < max(MIN_UNMATCHED_EXPLAINED, MIN_UNMATCHED_FRACTION * self.n_total):
            explained = 0.0
        cand.unmatched_gain_points = float(explained)
        n_m = int(ok.sum())
        total = float(np.sum(d[ok])) + UNMATCHED_NATS * explained
        cand.score = float(total / max(self.n_total, 1))
        cand.z = total_z(cand.matched_gain, se_matched, n_m, explained)
        cand.significant = bool(total >= MIN_TOTAL_GAIN and cand.z >= self.z_crit
                                and cand.matched_gain > -MIN_PRACTICAL_GAIN)
        cand.practical = cand.score >= MIN_PRACTICAL_GAIN

    @property
    def z_crit(self) -> float:
        return getattr(self, '_z_crit', float(norm.isf(FAMILY_ALPHA / 6)))

    @z_crit.setter
    def z_crit(self, value: float) -> None:
        """The bound of another comparison (e.g. the one whose tie a plan separates)."""
        self._z_crit = float(value)

    def set_family(self, n_candidates: int) -> None:
        """Bonferroni: the z a candidate needs when ``n_candidates`` are tested."""
        self._z_crit = float(norm.isf(FAMILY_ALPHA / max(n_candidates, 1)))

    def _veto(self, cand: Candidate, unmatched_explained: float) -> str | None:
        """Why a candidate with a gain lacks its physical signature (module doc), or None."""
        eff = cand.effect
        if eff is None or not len(self.rays.matched):
            return None
        if lk.is_ghost_effect(eff):
            # Multipath's signature: points behind specular surfaces at the range the
            # mirror geometry predicts (``likelihood.ghost_points``).
            cand.far_points = float(lk.ghost_points(self.full, [eff]))
            if cand.far_points < MIN_FAR_POINTS:
                return (f'only {cand.far_points:.0f} points lie behind a specular surface at '
                        'the range its mirror ray predicts (|SA| + |AB|, within '
                        f'{lk.UNMATCHED_Z:g} sigma; at least {MIN_FAR_POINTS} needed): '
                        'no multipath ghosts')
            return None
        spurious = 0.0
        if type(eff).outlier_fraction is not Effect.outlier_fraction:   # adds false returns
            w = float(np.mean(lk.model_on_rays(self.full, [eff]).outlier_w))
            spurious = max(w - self._base_outlier_w, 0.0) * len(self.rays.matched)
        if is_outlier_effect(type(eff)):
            cand.far_points = float(self.n_far + unmatched_explained)
            if spurious < 1.0:
                # Fewer than one false return claimed on the target: its gain must then
                # rest on false returns somewhere (far points or credited off-target ones),
                # and those off the target must not bunch (a strut's edges, eleventh holdout
                # clutter_strut: 44 isolated points at 1.25-1.39 m credited as background).
                return (no_false_returns(self.n_far, unmatched_explained)
                        or self.off_target_bunch(unmatched_explained))
        if spurious >= 1.0:
            need = max(MIN_FAR_POINTS, MIN_FAR_SHARE * spurious)
            if cand.far_points < need:
                return (f'it claims {spurious:.0f} spurious returns among the matched points but only '
                        f'{cand.far_points:.0f} lie far beyond the noise (|residual| > '
                        f'max({FAR_MIN_M:g} m, {FAR_SIGMAS:g} sigma)) or off the target, '
                        'isolated from their neighbours: heavy noise tails or surfaces that are '
                        'not the target, not false returns')
            front, mu, var = self.far_sides
            if mu - front > self.z_crit * np.sqrt(max(var, 1e-12)) and front < 0.5 * mu:
                return (f'its false returns come at random times (background arrivals over '
                        f'the range window), so about {mu:.0f} of the '
                        f'{self.n_far} far points would lie in front of the surface, but '
                        f'{front} do: the far returns come from behind the surface (a longer '
                        'path: multipath via a specular surface, or a second surface seen '
                        'through), not from background light')
            if len(self.far_u) >= MIN_FAR_POINTS:
                ks = kstest(self.far_u, 'uniform')
                if ks.pvalue < norm.sf(self.z_crit):
                    return (f'its false returns come at random times, so the {len(self.far_u)} far '
                            'points would spread over the range window on either side of the '
                            'surface as the first arrivals of a background do (evenly, or falling '
                            f'off with range; fitted rate {self.far_rate:.2g} per window), but '
                            f'they bunch (Kolmogorov-Smirnov D = {ks.statistic:.2f}, '
                            f'p = {ks.pvalue:.1e}): returns at a preferred range (multipath via a '
                            'specular surface, a ghost, a second surface), not background light')
            return self.off_target_bunch(unmatched_explained)
        return None

    def off_target_bunch(self, credited: float) -> str | None:
        """Why a false-return effect whose evidence is mostly off the target (``credited``
        points at least the far matched ones) does not show background light: the
        isolated points off the target bunch in range (Kolmogorov-Smirnov against the
        first-arrival law over the receiver's gate, at the family's z), or None."""
        if len(self.off_u) < MIN_FAR_POINTS or credited < self.n_far:
            return None
        ks = kstest(self.off_u, 'uniform')
        if not ks.pvalue < norm.sf(self.z_crit):
            return None
        a, b = np.percentile(self.off_ranges_m, [25, 75])
        lo = float(self.full.miss_window[0])
        return (f'its false returns on the shots that miss the target would spread '
                f'over the receiver\'s gate (from {lo:.1f} m) as background arrivals '
                f'do (evenly, or falling off with range), but the {len(self.off_u)} '
                'isolated points off the target bunch (Kolmogorov-Smirnov D = '
                f'{ks.statistic:.2f}, p = {ks.pvalue:.1e}; half of them between '
                f'{a:.1f} and {b:.1f} m): returns at the target\'s ranges or at a '
                'surface that is not the target (lab clutter: its edges have no '
                'neighbour at their range; ghosts of another channel), so they do '
                'not show background light')

    def share_veto(self, cand: Candidate, attribution: Attribution | None) -> None:
        """A bias/noise candidate must explain MIN_SHARE of the feature structure; a noise
        effect driven by the power, the driver's part too (``driver_veto``)."""
        self._attribution = attribution    # the structure a pair is measured against
        if cand.vetoed is None:
            cand.vetoed = self.driver_veto(cand, attribution)
        if (attribution is None or not attribution.significant or cand.effect is None
                or is_outlier_effect(type(cand.effect)) or lk.is_ghost_effect(cand.effect)
                or cand.vetoed):
            return
        n_matched = max(len(self.rays.matched), 1)
        matched_total = cand.matched_gain * n_matched
        if matched_total < 0.5 * cand.score * self.n_total:
            return    # its evidence is mostly off the target (unmatched points)
        cand.share = float(cand.matched_gain / attribution.structure_gain)
        if cand.share < MIN_SHARE:
            what = attribution.driver or ', '.join(attribution.confounded) or 'the features'
            cand.vetoed = (f'it explains only {100 * cand.share:.0f} % of the residual\'s '
                           f'dependence on {what} ({cand.matched_gain:.4f} of '
                           f'{attribution.structure_gain:.4f} nats/point): the residual has '
                           'another shape than this effect')

    def in_matched_order(self, per_point: np.ndarray) -> np.ndarray:
        """A per-point array in ``cross_fit`` order (test folds concatenated) put in the
        order of ``rays.matched``."""
        out = np.full(len(self.rays.matched), np.nan)
        out[self.fold_order] = per_point
        return out

    def transfer_nll(self, variant: type[Effect], halves: list['RaySet'],
                     on_top: list[Effect] = ()) -> np.ndarray:
        """Held-out per-point NLL (order of ``rays.matched``) of ``variant`` fitted on one
        of two ``halves`` of the matched points and scored on the other, both ways, with
        ``on_top`` (fitted effects) in the model."""
        data = [make_fit_data(self.model, self.base, h, (self.full, self.rays))
                for h in halves]
        out = np.full(len(self.rays.matched), np.nan)
        for h, nll in zip(halves, transfer_both_ways(variant, data, on_top)):
            out[self.places(h.matched)] = nll
        return out

    def worst_transfer(self, cand: Candidate, splits: dict, at_random: np.ndarray,
                       on_top: list[Effect] = ()) -> tuple | None:
        """The split of the matched points (``splits``: key -> bool mask in matched order)
        on which ``cand`` fitted on one side and scored on the other (both ways) loses
        most against ``at_random`` (its held-out NLL on a random half, matched order), as
        (key, nats per analysed point, z); None when no split's loss passes the rule (z
        above the bound and at least MIN_PRACTICAL_GAIN). The tile veto."""
        idx, none = self.rays.matched, self.rays.unmatched[:0]
        worst = None
        for key, on in splits.items():
            if on.all() or not on.any():
                continue
            halves = [self.rays._with(idx[on], none), self.rays._with(idx[~on], none)]
            worst = self.larger(worst, key,
                                self.transfer_nll(cand.variant, halves, on_top) - at_random)
        return worst

    def larger(self, worst: tuple | None, key, gain: np.ndarray) -> tuple | None:
        """``(key, nats per analysed point, z)`` of ``gain`` (per matched point, matched
        order; NaN: not scored) where it passes the rule (z above the bound, at least
        MIN_PRACTICAL_GAIN) and exceeds ``worst``'s; else ``worst``. The split vetoes."""
        ok = np.isfinite(gain)
        if ok.sum() < 2:
            return worst
        _, z = block_mean_z(gain[ok], self.matched_blocks[ok])
        per_point = float(np.sum(gain[ok]) / max(self.n_total, 1))
        if (per_point >= MIN_PRACTICAL_GAIN and z >= self.z_crit
                and (worst is None or per_point > worst[1])):
            return (key, per_point, z)
        return worst

    def tile_veto(self, cand: Candidate, on_top: list[Effect] = ()) -> str | None:
        """A candidate with a parameter per laser (``laser_tiles.per_laser``): its offsets
        must be the lasers', the same wherever a laser's tile falls on the target. Fitted
        on one half of every laser's points and scored on the other (halves of each tile
        in azimuth and in elevation, early and late: ``laser_tiles.tile_halves``), they
        must do as well as fitted on a random half (its score): a loss against it that
        passes the rule (z above the bound, at least MIN_PRACTICAL_GAIN nats per analysed
        point) shows a pattern on the target, not the lasers (module doc). ``on_top``:
        fitted effects in the model, under the test and its random split alike (the
        lasers beside a named effect, ``lasers_beside``). For lasers' pointing offsets the
        loss must also be at least MIN_SHARE of the candidate's score (in the body)."""
        if (cand.effect is None or cand.variant is None or cand.heldout_nll is None
                or not laser_tiles.per_laser(cand.effect)):
            return None
        idx, meas = self.rays.matched, self.rays.meas
        if len(np.unique(meas.laser[idx])) < 2:
            return None
        beside = [e.name for e in on_top]
        memo = self.memo('tiles')
        key = (cand.name, cand.n_params, _num(cand.score), tuple(beside))
        if key not in memo:
            memo[key] = self._tile_test(cand, list(on_top))
        why, cand.tile_test = memo[key]
        return why

    def _tile_test(self, cand: Candidate, on_top: list[Effect]) -> tuple[str | None, dict]:
        """``tile_veto`` asked (its reason or None, and its figures: the worst split, its
        loss in nats per analysed point and z, the effects beside, whether it passes)."""
        idx, meas = self.rays.matched, self.rays.meas
        figures = {'beside': [e.name for e in on_top], 'passes': True}
        on_top = self.refitted_beside(cand, on_top)
        at_random = self.in_matched_order(
            self.cross_fit(cand.variant, list(on_top))[0] if on_top else cand.heldout_nll)
        worst = self.worst_transfer(cand, laser_tiles.tile_halves(
            meas.laser[idx], meas.directions[idx], meas.t_s[idx]), at_random, on_top)
        if worst is None:
            return self._field_part(cand, on_top, at_random, figures)
        split, loss, z = worst
        figures.update(split=split, loss=_num(loss), z=_num(z))
        if pointing.turn_of(cand.variant) is not None and loss < MIN_SHARE * cand.score:
            # Lasers' pointing offsets act through the surface's slope, fitted to first
            # order (and once more): over half a tile the slope's curvature and the
            # sensor's own angle convention leave a loss that grows with the offsets
            # (2-2.5 % of the gain at 0.15-0.2 deg, on two foreign simulators). A
            # pattern on the target the tiles cut up loses a share of the gain: at least
            # MIN_SHARE, as a bias effect must explain that share of the structure.
            return None, figures
        figures['passes'] = False
        halves = {'azimuth': 'the two halves of each laser\'s tile in azimuth',
                  'elevation': 'the two halves of each laser\'s tile in elevation',
                  'time': 'each laser\'s early and late points'}[split]
        return (f'a laser\'s offset is the same wherever its tile falls on the target, but '
                f'fitted on one of {halves} and scored on the other its offsets explain '
                f'{loss:.4f} nats/point less than fitted at random (z = {z:.1f}): the '
                'residual follows a pattern on the target that the tiles cut up (the '
                'target off its CAD, or another effect\'s pattern), not the lasers alone; '
                'offsets of the lasers\' own beside that pattern show only once it is '
                'modelled'), figures

    def _field_part(self, cand: Candidate, on_top: list[Effect], at_random: np.ndarray,
                    figures: dict) -> tuple[str | None, dict]:
        """Lasers' range offsets (``laser_bias``; not their pointing, weighed against a
        turn of the sensor in ``own_part_veto``) that pass the split test: what they gain
        over a range pattern smooth across the field of view (``field_pattern``: a
        quadratic surface over the shot's pointing, fitted beside ``on_top`` on the same
        folds) must pass the rule. A laser's own offsets are unrelated from tile to tile;
        a pattern on the target (sunlit faces reading long, a body off its CAD) varies
        smoothly across the field, and the offsets take it only at their tiles' centres
        (the nineteenth holdout's sunlit faces: offsets falling smoothly from +0.8 to
        -0.9 cm over the 24 lasers, the split test passed). Figures in
        ``tile_test['field']``."""
        if pointing.turn_of(cand.variant) is not None:
            return None, figures
        field = self.cross_fit(field_pattern.FieldPattern, list(on_top))[0]
        own = field - at_random[self.fold_order]        # cross_fit order, as gain_z reads
        if np.isfinite(own).sum() < 2:
            return None, figures
        gain, z = self.gain_z(own)
        passes = self.passes_rule(gain, z)
        figures['field'] = {'own_gain': _num(gain), 'own_z': _num(z), 'passes': bool(passes)}
        if passes:
            return None, figures
        figures['passes'] = False
        return (f'a laser\'s own offsets are unrelated from tile to tile, but over a range '
                f'pattern smooth across the field of view (a quadratic surface over the '
                f'pointing, fitted on the same points) they gain {gain:.4f} nats/point held '
                f'out (z = {z:.1f}), which does not pass the rule: the residual follows a '
                f'pattern on the target (faces reading long on one side, the target off its '
                f'CAD, a turned pose), not the lasers'), figures

    def tile_fault(self, cand: Candidate, named: Candidate | None = None) -> str | None:
        """Why ``cand`` may not be named where it is (the missing effect or in a tie:
        ``named`` None; 'also' beside ``named``), or None. A per-laser one: the tile test
        (``tile_veto``) asked there, alone or with ``named`` in the model; every path that
        names one asks it (``settle``), once per context (memo). A range term 'also'
        beside a per-laser ``named``: the cross-material test it would face named
        (``material_veto`` alone), as the lasers' offsets can take a part's pattern
        that the tiles cut up, so that test beside them shows nothing (bend53)."""
        if cand.heldout_nll is None or len(cand.heldout_nll) != len(self.fold_order):
            return None     # scored on another model (a corrected pose): tested there
        if (cand.effect is not None and cand.name in POSE_RIVALS and named is not None
                and named.effect is not None and laser_tiles.per_laser(named.effect)):
            try:
                why = self.material_veto(cand)
            except Exception as exc:  # noqa: BLE001 - not shown to read alike
                why = f'its cross-material test failed: {type(exc).__name__}: {exc}'
            return None if why is None else f'beside {named.name} (lasers\' offsets): {why}'
        if cand.effect is None or not laser_tiles.per_laser(cand.effect):
            return None
        on_top = ([named.effect] if named is not None and named is not cand
                  and named.effect is not None else [])
        try:
            return self.tile_veto(cand, on_top)
        except Exception as exc:  # noqa: BLE001 - not shown to hold across the tiles
            return f'its tile test failed: {type(exc).__name__}: {exc}'

    def refitted_beside(self, cand: Candidate, on_top: list[Effect]) -> list[Effect]:
        """``on_top`` refitted together with ``cand`` on all the diagnosed points
        (``_fitted_together``), ``cand`` left out: the effects the tile test asks it
        beside. Each was fitted with the lasers' offsets unmodelled, so it took part of
        them (a walk, where the lasers' ranges follow the intensity: k 0.0379 alone for
        0.0331 beside them on the twelfth holdout's ``walk_laser_1``), and what it leaves
        is its own error's pattern over the target, which the tiles cut up (there the
        elevation halves still lost 0.0115 nats/point, z 7.8, beside the walk fitted
        alone). A pair where each needs the other is judged as the pair's joint fit
        leaves it."""
        if not on_top or cand.effect is None or lk.moving([cand.effect]):
            return list(on_top)     # one that moves the rays is kept out of a joint refit
        # The candidate comes last of those refitted (``_fitted_together`` keeps the
        # order, the ones that move the rays first): the rest are the effects beside it.
        return self._fitted_together([*on_top, cand.effect])[:-1]

    def own_part_veto(self, cand: Candidate) -> str | None:
        """Lasers' pointing offsets (``laser_pointing``) are fitted with their common turn
        (the lasers' mean pointing), but a common turn of every beam is a turn of the
        whole sensor: its mount, an extrinsic, or the reference pose turned about the
        sensor (the pose test's finding: a mount tilted with every laser right is no
        laser's). So what the offsets gain over that turn alone (``pointing.SensorTurn``,
        three rotations fitted on the points, cross-fitted as the score), each laser's
        own part, must pass the rule (``paired``: z above the bound, total and per-point
        gain); a turn that gains nothing held out leaves the offsets their own score.
        Weighed against the fitted turn, not with a turn projected out of the offsets: a
        few lasers off, the rest exact, are no turn, and a projection spreads their
        offsets, and those of lasers that barely see the target, over every beam."""
        turn_cls = pointing.turn_of(cand.variant)
        if turn_cls is None or cand.effect is None or cand.heldout_nll is None:
            return None
        turn = Candidate(cand.name)
        turn.effect = cand.effect
        nll, explained = self.cross_fit(turn_cls, [])
        self._set_gain(turn, nll, explained)
        # Over the turn where it explains anything, else over nothing (the offsets' score).
        gain, z = self.paired(cand, turn) if turn.score > 0 else (cand.score, cand.z)
        passes = self.passes_rule(gain, z)
        cand.own_part = {'score': _num(gain), 'z': _num(z),
                         'turn_score': _num(turn.score), 'turn_z': _num(turn.z),
                         'passes': passes}
        if passes:
            return None
        return (f'its offsets are mostly a common turn of every beam, which is a turn of '
                f'the whole sensor (its mount, or the reference pose turned about the '
                f'sensor), not the lasers\' own: over that turn alone (which gains '
                f'{turn.score:.4f} nats/point held out) each laser\'s own part gains '
                f'{gain:.4f} nats/point (z = {z:.1f}), which does not pass the rule')

    def standoff_part_veto(self, cand: Candidate, cands: list[Candidate]) -> str | None:
        """Why a surface standoff may not be named beside an incidence-shaped rival that
        may (``standoff_part``: a standoff common to every material is, after the
        materials' offsets, an incidence-shaped bias), or None: its per-material part,
        its held-out gain over the same standoff fitted common to every material
        (``standoff_part.CommonStandoff``, cross-fitted as the score), must pass the rule
        (z, total and per-point gain). Figures in ``cand.standoff_part``."""
        if (cand.effect is None or cand.heldout_nll is None or cand.error is not None
                or standoff_part.common_part_of(cand.variant) is None
                or not self.nameable(cand)):
            return None
        rival = standoff_part.rival_of(cand, cands, self.nameable)
        if rival is None:
            return None
        common, _ = self.cross_fit(standoff_part.CommonStandoff, [])
        gain, z = standoff_part.part_gain(cand.heldout_nll, common, self.blocks,
                                          self.n_total, block_mean_se)
        passes = self.passes_rule(gain, z)
        cand.standoff_part = {'score': _num(gain), 'z': _num(z), 'beside': rival.name,
                              'passes': passes}
        if passes:
            return None
        return (f'beside {rival.name} only its part that differs between materials would '
                f'show a surface standing proud (a standoff common to every surface moves '
                f'ranges as 1 / cos(incidence), which after the materials\' offsets is an '
                f'incidence-shaped bias): over the same standoff common to every material '
                f'it gains {gain:.4f} nats/point held out (z = {z:.1f}), which does not '
                f'pass the rule')

    def split_nll(self, variant: type[Effect], group: np.ndarray,
                  on_top: list[Effect] = ()) -> np.ndarray:
        """Held-out per-point NLL (order of ``rays.matched``) of ``variant`` fitted on each
        side of ``group`` (bool, matched order) apart: on one fold's points of a side and
        scored on the other fold's points of the same side, over the diagnosis's folds (the
        split model against ``cross_fit``'s one fit for all)."""
        idx, none = self.rays.matched, self.rays.unmatched[:0]
        out = np.full(len(idx), np.nan)
        for k in range(N_FOLDS):
            train, test = self.folds[k].matched, self.folds[(k + 1) % N_FOLDS].matched
            for side in (True, False):
                tr = train[group[np.searchsorted(idx, train)] == side]
                te = test[group[np.searchsorted(idx, test)] == side]
                if len(tr) == 0 or len(te) == 0:
                    continue
                fit_on, score_on = (make_fit_data(self.model, self.base, self.rays._with(h, none),
                                                  (self.full, self.rays)) for h in (tr, te))
                effect = fit_effect(variant, fit_on, list(on_top)).effect
                out[np.searchsorted(idx, te)] = heldout_nll(score_on, [*on_top, effect])
        return out

    def material_veto(self, cand: Candidate, on_top: list[Effect] = ()) -> str | None:
        """A range error of the sensor kept out of the default candidates (POSE_RIVALS: a
        range scale, a range offset drifting over the recording) is the same on every
        surface the sensor sees: one material's points given their own value of it and the
        rest theirs (``split_nll``, fitted and held out on the diagnosis's folds) must not
        do better than one value for all (its score). A gain of the split that passes the
        rule (z above the bound, at least MIN_PRACTICAL_GAIN nats per analysed point) shows
        a part of the target reading off the rest (a material the configuration does not
        list, a part off its CAD), which a range term fits only where the part's ranges
        differ from the others'. A material seen over a short stretch of range or time
        fits the term poorly on its own; that costs the split only on its own points, so
        an imprecise fit is no evidence (transferring such a fit to the other materials
        was: holdout 10's range drift with the PAF seen in 9 of 16 clouds). Each material
        with MIN_MATERIAL_POINTS matched points (and the rest as many) is tried; the
        largest gain is reported. ``on_top``: fixed effects in the model of both sides
        (the named one, ``material_beside``)."""
        if (cand.name not in POSE_RIVALS or cand.effect is None or cand.variant is None
                or cand.heldout_nll is None):
            return None
        idx = self.rays.matched
        group = np.asarray(self.full.baseline.ctx.material, int)
        if len(group) != len(idx):
            return None
        common = self.in_matched_order(cand.heldout_nll if not on_top else
                                       self.cross_fit(cand.variant, list(on_top))[0])
        worst = None
        for m in np.unique(group[group >= 0]):
            on = group == m
            if min(on.sum(), (~on).sum()) < lk.MIN_MATERIAL_POINTS:
                continue
            worst = self.larger(worst, int(m),
                                common - self.split_nll(cand.variant, on, list(on_top)))
        if worst is None:
            return None
        m, gain, z = worst
        names = list(getattr(self.full.baseline.ctx.scene.target, 'material_names', []))
        name = names[m] if m < len(names) else f'material {m}'
        return (f'a range error of the sensor is the same on every surface, but given its own '
                f'value on the {name} points and another on the rest it explains {gain:.4f} '
                f'nats/point more, held out, than one value for all (z = {z:.1f}): part of the '
                f'target reads off the rest (outside the catalogue: a material the '
                f'configuration does not list, or a part off its CAD), which a range term '
                f'fits only where that part\'s ranges differ from the others\'')

    def core_veto(self, cand: Candidate) -> str | None:
        """A noise effect (``is_noise_effect``: it widens the sigma, nothing else) must
        widen the core of the residual distribution, not explain a few points at far
        offsets with a wide sigma (a second surface, dual returns): its held-out gain on
        the points within CORE_SIGMAS of the model without it must be decisive there (z
        above the bound; the margin that matters is the whole score's: a real widening
        moves some of the weakest points beyond CORE_SIGMAS too, so a weak real SNR noise
        keeps only part of its gain in the core: 0.0036 of 0.0064 nats/point, z 3.3, on
        the battery's short_snr_noise)."""
        if (cand.effect is None or cand.heldout_nll is None
                or not is_noise_effect(type(cand.effect))):
            return None
        core = self.core_mask()[self.fold_order]
        d = self.base_heldout() - cand.heldout_nll
        ok = np.isfinite(d) & core
        if ok.sum() < 2:
            return None
        _, z = block_mean_z(d[ok], self.blocks[ok])
        per_point = float(np.sum(d[ok]) / max(self.n_total, 1))
        if z >= self.z_crit:
            return None
        n_out = int(np.sum(np.isfinite(d) & ~core))
        return (f'a noise effect widens the core of the residual distribution, but on the '
                f'points within {CORE_SIGMAS:g} sigma its held-out gain is {per_point:.4f} '
                f'nats/point (z = {z:.1f}, not decisive): its gain rests on the {n_out} points '
                'beyond, at far offsets (a second surface, dual returns), not on a wider '
                'spread')

    def core_mask(self) -> np.ndarray:
        """Per point of ``rays.matched``: in the core of the residual distribution
        (``core_points`` of the model without a candidate)."""
        if getattr(self, '_core', None) is None or len(self._core) != len(self.rays.matched):
            self._core = core_points(self.full)
        return self._core

    def driver_veto(self, cand: Candidate, attribution: Attribution | None) -> str | None:
        """A noise effect driven by the measured power (its sigma a function of the
        power alone) cannot explain a residual whose driver, given every other feature
        and the measured power among them, is another feature (noise growing with the
        range, not the power): the driver's part is beyond it (``attribution.driver``)."""
        if (attribution is None or not attribution.significant or cand.effect is None
                or not is_noise_effect(type(cand.effect))
                or not getattr(type(cand.effect), 'power_driven', False)
                or self.rays.measured_power_w is None):
            return None
        driver = attribution.driver
        names = {f.name for f in attribution.features}
        if driver is None or driver == 'intensity' or 'intensity' not in names:
            return None
        f = next(f for f in attribution.features if f.name == driver)
        return (f'the residual depends most on {driver} given the other features, the '
                f'measured power among them ({f.score:.4f} nats/point, z = {f.score_z:.1f}), '
                f'and {cand.name} follows the measured power alone: it cannot explain '
                f'{driver}\'s part')

    @property
    def before_nll(self) -> float:
        """The calibrated NLL per matched point of the diagnosed points without a
        candidate: the "before" the verdict quotes (``calibrated_figures``)."""
        if getattr(self, '_before_nll', None) is None:
            nll, rmse, _ = calibrated_figures(self.full, [])
            self._before_nll = nll
            if getattr(self, '_before_rmse', None) is None:
                self._before_rmse = rmse       # one model evaluation for both
        return self._before_nll

    @property
    def before_rmse(self) -> float:
        """The calibrated range RMSE (m) of the diagnosed points without a candidate: the
        "before" of the range RMSE the verdict quotes."""
        if getattr(self, '_before_rmse', None) is None:
            self._before_rmse = calibrated_figures(self.full, [])[1]
        return self._before_rmse

    def naming_fault(self, cand: Candidate) -> str | None:
        """Why ``cand`` may not be named (``naming_fault``), fitting it on all the
        diagnosed points first if that was not done (its "after" figures)."""
        if cand.admissible and not np.isfinite(cand.nll_after):
            self.finalize(cand)
        rmse = (self.before_rmse if np.isfinite(cand.range_rmse_after_m) and quotes_rmse(cand)
                else float('nan'))
        return naming_fault(cand, self.before_nll, rmse)

    def nameable(self, cand: Candidate) -> bool:
        return self.naming_fault(cand) is None

    def decide(self, cands: list[Candidate]) -> Decision:
        """The missing effect, ties and confounding (module doc), among the candidates
        that may be named at all (``naming_fault``)."""
        for c in cands:
            if c.vetoed is None and c.standoff_part is None:
                c.vetoed = self.standoff_part_veto(c, cands)
        ok = [c for c in rank(cands) if self.nameable(c)]
        if not ok:
            # A walk and an incidence bias that partly cancel: each alone fits their net.
            return self.pair_beside_nothing(cands)
        best = ok[0]
        tied, pair_z, also = [], {}, None
        simpler = self.simpler_instead(best, ok[1:], pair_z)
        if simpler is not None:
            best, also = simpler, best.name    # the rich one passes on top: next
        stood_in = set()
        again = True
        while again:
            again = False
            tied = []
            for c in ok:
                if c is best or c.name == also or c.name in stood_in:
                    continue
                margin, z = self.paired(best, c)
                fitted = self.fitted_margin(best, c)
                pair_z[c.name] = {**pair_z.get(c.name, {}), 'margin': _num(margin),
                                  'z': _num(z), 'fitted_margin': _num(fitted)}
                if self.apart(margin, z, fitted):
                    continue      # decisively worse, by a margin that matters after --fit
                lead = self.range_decides(best, c, pair_z)
                if lead is c:
                    # Its held-out figures against the one it replaces, from its side.
                    held = pair_z.pop(c.name, {})
                    pair_z[best.name] = {**{k: _num(-held[k]) for k in
                                            ('margin', 'z', 'fitted_margin')
                                            if held.get(k) is not None},
                                         **pair_z.get(best.name, {})}
                    stood_in.add(best.name)
                    best, also, again = c, None, True
                    break
                if lead is best:
                    continue      # the footprint or the standoff, told apart by range
                if self.adds_to(best, c):
                    # Explains another part: two effects at once, unless that part is
                    # one the rule set aside for its shape (``beside_set_aside``).
                    if also is None and self.beside_set_aside(best, c, cands):
                        # Not decisively apart: the one ranked first may gain on top
                        # of the other only by standing in for a third effect
                        # (``stands_in_beside``); then the other is named.
                        instead = self.stands_in_beside(c, best, cands)
                        if instead is not None:
                            figs = self.memo('on_top_figures')
                            pair_z[best.name] = {
                                'stands_in_for': instead, 'beside': c.name,
                                'gain_z_on_top_of_both': {
                                    best.name: figs.get((best.name, *sorted((c.name, instead)))),
                                    instead: figs.get((instead, *sorted((c.name, best.name))))}}
                            stood_in.add(best.name)
                            best, also, again = c, None, True
                            break
                        also = c.name
                    continue
                tied.append(c.name)
        if not tied and also is None:
            joint, other = self.walk_beside_incidence(best, cands, pair_z)
            if joint == power_incidence.BOTH:
                also = other
            elif joint == power_incidence.TIE:
                tied = [other]
        if tied:
            lead, tied = self.tie_beside_set_aside(best, tied, cands, pair_z)
            if lead is not best:
                best, also = lead, None     # 'also' was judged beside the other
        if tied:
            return Decision(None, [best.name, *tied], also, pair_z)
        held = self.rival_takes(best, cands, pair_z)
        if held is not None:
            return Decision(None, [], None, pair_z, withheld={best.name: held})
        taken = self.pointing_takes(best, cands)
        if taken is not None:
            return Decision(None, [], None, pair_z, withheld={best.name: taken})
        turned = self.power_or_incidence(best, cands, pair_z)
        if turned is not None:
            return turned
        held = self.incidence_beside_model_walk(best, pair_z)
        if held is not None:
            return Decision(None, [], None, pair_z, withheld={best.name: held})
        # A candidate with fewer parameters first: the lasers' two dozen offsets fit
        # part of any pattern the tiles cut up, an incidence elongation's too.
        also = (also or self.next_beside(best, ok, cands) or self.lasers_beside(best, cands)
                or self.material_beside(best, cands))
        also = self.also_beside_walk(best, also, pair_z)
        partner = self.dilation_beside(best, ok, cands, also)
        if partner is None:
            return Decision(best.name, [], also, pair_z)
        # The one sharing the named effect's dilation first: it is fitted together with
        # it (``fit_together``), the value of the named effect alone being off by it.
        return Decision(best.name, [], partner, pair_z, also_more=[also] if also else [])

    def dilation_beside(self, best: Candidate, ok: list[Candidate],
                        cands: list[Candidate], also: str | None) -> str | None:
        """The effect that shares ``best``'s dilation at grazing incidence
        (``SHARES_DILATION``: an incidence bias beside a footprint) where it adds on top
        of ``best`` (``adds_to``: the rule on top, and the NLL of both below that of
        ``best``) and is not one the rule set aside beside it (``beside_set_aside``),
        whatever its rank; None if it is ``also`` already, or does not add. The
        eleventh holdout's beam_solar_incid: a footprint, false returns of sunlight and
        an incidence bias; the false returns (another part by construction) took the
        one 'also' and the bias, ranked fourth, was never tried. A walk set aside for its
        shape that gains nothing on top of the footprint and the bias (it stood in for
        the bias: weak returns are grazing ones) is no model to judge the bias in
        (``beside_set_aside``, ``but_taken``)."""
        name = SHARES_DILATION.get(best.name)
        c = next((c for c in ok if c.name == name), None)
        if c is None or c.name == also or best.effect is None:
            return None
        try:
            # Held out against ``best`` as fitted on all the points, in the model on both
            # sides (``_passes_on_top``): against ``best`` refitted on each fold
            # (``adds_to``'s footing) the partner is also credited with what the
            # footprint fitted on all the points gains over its fold fits.
            fair = self._passes_on_top([best.effect], c)
        except Exception:  # noqa: BLE001 - not shown to add
            fair = False
        if (fair and self.adds_to(best, c)
                and self.beside_set_aside(best, c, cands, but_taken=True)):
            return c.name
        return None

    def rival_takes(self, best: Candidate, cands: list[Candidate],
                    pair_z: dict) -> str | None:
        """Why ``best`` may not be named beside a rival the rule keeps from naming that
        explains the same part (``same_part``), or None. A rival ``best`` is not
        decisively better than (``apart``) is weighed on top: each cross-fitted on the
        other fitted together with the effects set aside beside ``best``
        (``set_aside_beside``: the lasers' offsets); unless ``best`` passes the rule on
        top of it, ``best`` is withheld. The figures go to ``pair_z[rival]['same_part']``."""
        if best.effect is None or best.variant is None or best.name == POSE_ERROR:
            return None
        rivals = same_part.rivals_of(
            best, rank(cands), self.nameable, laser_tiles.per_laser,
            lambda e: not (is_outlier_effect(type(e)) or lk.is_ghost_effect(e)),
            MIN_SHARE, MIN_TOTAL_GAIN, self.n_total)
        for c in rivals:
            try:
                margin, z = self.paired(best, c)
                fitted = self.fitted_margin(best, c)
                if self.apart(margin, z, fitted):
                    continue      # decisively better than this one, as decide asks
                rest = self.set_aside_beside(best, cands, but=(c.name,))
                self.finalized(best, c, *rest)
                others = [r.effect for r in rest]
                on_rival = self._on_top(self._fitted_together([c.effect, *others]), best)[:2]
                # Only where the named one does not pass on top is the other way asked.
                on_best = (None if self.passes_rule(*on_rival) else
                           self._on_top(self._fitted_together([best.effect, *others]), c)[:2])
            except Exception:  # noqa: BLE001 - not shown to explain the same part
                continue
            kind = same_part.outcome(on_rival, on_best, self.passes_rule)
            pair_z[c.name] = {**pair_z.get(c.name, {}), 'margin': _num(margin),
                              'z': _num(z), 'fitted_margin': _num(fitted),
                              'same_part': {'of': best.name,
                                            'with': [r.name for r in rest],
                                            'named_on_top': [_num(v) for v in on_rival],
                                            'rival_on_top': ([_num(v) for v in on_best]
                                                             if on_best else None),
                                            'outcome': kind}}
            if kind != same_part.NAMED:
                return same_part.withheld_words(best.name, c, on_rival, on_best, kind,
                                                [r.name for r in rest])
        return None

    def own_parts(self, walk: Candidate) -> dict[str, 'power_incidence.OwnPart']:
        """The walk's and incidence's own parts (``power_incidence.both_parts``) on the
        residual the model leaves without either, over the diagnosis's folds; ln P the
        walk's own (the measured power where ``walk`` reads it, else the model's)."""
        memo = self.memo('own_parts')
        key = lk.reads_measured_power(walk.effect)
        if key not in memo:
            full = self.full
            ctx, expected, sigma = lk.apply_hooks(full.baseline, self.base,
                                                  full.measured_power_w, full.extra_var_m2)
            power = np.asarray(ctx.power_w, float)
            if key and full.measured_power_w is not None:
                known = np.isfinite(full.measured_power_w) & (full.measured_power_w > 0)
                power = np.where(known, full.measured_power_w, power)
            with np.errstate(divide='ignore', invalid='ignore'):
                log_power = np.where(power > 0, np.log(power), np.nan)
            fold = np.zeros(len(self.rays.matched), int)
            for k, f in enumerate(self.folds):
                fold[self.places(f.matched)] = k
            hit = np.asarray(ctx.hit, bool)
            residual = np.where(hit, np.asarray(full.measured_range_m, float) - expected, np.nan)
            memo[key] = power_incidence.both_parts(
                residual, sigma, np.asarray(ctx.material, int), log_power,
                np.asarray(ctx.incidence_rad, float), np.asarray(ctx.range_m, float), fold,
                self.matched_blocks)
        return memo[key]

    def own_part_passes(self, part: 'power_incidence.OwnPart') -> bool:
        """Whether an own part passes the naming rule: its held-out gain over the
        matched points counted per analysed point, and its z."""
        return self.passes_rule(part.gain_per_point * part.points / max(self.n_total, 1),
                                part.z)

    def own_part_figures(self, parts: dict) -> dict:
        """The own parts' figures for the summary: each one's ``as_dict`` and whether it
        passes (``own_part_passes``)."""
        return {n: {**p.as_dict(), 'passes': self.own_part_passes(p)}
                for n, p in parts.items()}

    def power_or_incidence(self, best: Candidate, cands: list[Candidate],
                           pair_z: dict) -> Decision | None:
        """A range walk named where an incidence bias may be named too (``nameable``) must
        show its own part (``power_incidence``): a dependence on the power at a fixed
        incidence, passing the rule (held-out gain over the matched points counted per
        analysed point, and z). Where it passes, the walk stays (None); so it does where
        its fitted k_m reads weak returns long, as a leading edge does and no footprint's
        early edge at grazing incidence can (``power_incidence.reads_as_incidence``);
        where neither holds and incidence's own part (a dependence on the incidence at a
        fixed power) passes, incidence is named; where neither passes, their tie. A named
        incidence bias is not
        asked (its own form, r tan(theta), is one function of the geometry; a walk free in
        sign is any function of the incidence on a hold: battery ``short_incidence``,
        incidence 0.0252 nats/point against the walk's 0.0109, has no own part either
        way), nor a walk beside an incidence that may not be named (no tie could be
        stated: the walk stays, as before). The figures go to
        ``pair_z[incidence_angle]['power_incidence']``."""
        if best.name != power_incidence.WALK or best.effect is None:
            return None
        other = next((c for c in cands if c.name == power_incidence.INCIDENCE
                      and c.error is None and c.effect is not None
                      and c.variant is not None), None)
        if other is None or not self.nameable(other):
            return None
        try:
            parts = self.own_parts(best)
        except Exception:  # noqa: BLE001 - not measured: the decision stands
            return None
        figures = self.own_part_figures(parts)
        pair_z[other.name] = {**pair_z.get(other.name, {}), 'power_incidence': figures}
        k_m = float(getattr(best.effect.params, 'k_m', 0.0))
        figures['walk_k_m'] = float(f'{k_m:.5g}')
        if figures[best.name]['passes']:
            figures['outcome'] = 'named'
            return None
        if not power_incidence.reads_as_incidence(k_m):
            figures['outcome'] = 'named_by_sign'
            return None
        if figures[other.name]['passes']:
            figures['outcome'] = 'other'
            return Decision(other.name, [], None, pair_z)
        figures['outcome'] = 'tie'
        return Decision(None, [best.name, other.name], None, pair_z)

    def walk_beside_incidence(self, best: Candidate, cands: list[Candidate],
                              pair_z: dict) -> tuple[str | None, str | None]:
        """A named incidence bias beside a range walk, or a named walk beside an incidence
        bias, that is neither tied with it nor 'also', each weighed on top of the other
        with both refitted together (``jointly``). On a flat face the power falls with
        cos(theta), so the one fitted alone takes most of the other's part: incidence
        alone takes a walk's (walk 0.02 + 0.035 tan(theta) on a box bus: incidence alone
        bias_gain 3.2, together 2.2 with k 0.020), and where the two have opposite signs
        (the walk short at normal incidence, the bias short at grazing) each alone takes
        their net (walk 0.02 beside -0.0117 tan(theta): the walk alone k 0.0099).
        The other one is any scored candidate not vetoed (alone it may pass nothing: the
        net is what it sees), but a tie only one that may be named alone. Returns
        (power_incidence.BOTH, other) where each passes the rule on top of the other
        (the other is 'also'), (TIE, other) where the other does and the named one does
        not, or neither does, (None, other) where only the named one does (it stands
        alone), (None, None) where not weighed. The figures go to
        ``pair_z[other]['jointly']``. Where neither is named: ``pair_beside_nothing``;
        both weigh with ``each_on_top``."""
        partner = dict(zip(power_incidence.PAIR, reversed(power_incidence.PAIR)))
        name = partner.get(best.name)
        if name is None or best.effect is None or best.variant is None:
            return None, None
        other = next((c for c in cands if c.name == name and c.error is None
                      and c.vetoed is None and c.effect is not None
                      and c.variant is not None), None)
        if other is None:
            return None, None
        try:
            _, other_on_top, named_on_top = self.each_on_top(best, other)
        except Exception:  # noqa: BLE001 - not measured: the decision stands
            return None, None
        outcome = power_incidence.joint_outcome(self.passes_rule(*other_on_top),
                                                self.passes_rule(*named_on_top))
        label = outcome or 'named_alone'
        if outcome == power_incidence.TIE and not self.nameable(other):
            # A tie is with one that may be named alone (battery short_incidence).
            outcome, label = None, 'tie_with_unnameable'
        pair_z[other.name] = {**pair_z.get(other.name, {}), 'jointly': {
            'other_on_top_of_named': [_num(v) for v in other_on_top],
            'named_on_top_of_other': [_num(v) for v in named_on_top],
            'outcome': label}}
        return outcome, other.name

    def each_on_top(self, named: Candidate, other: Candidate
                    ) -> tuple[np.ndarray, tuple[float, float], tuple[float, float]]:
        """``named`` and ``other`` refitted together on each training fold (``jointly``):
        their held-out NLL per matched point, ``other``'s gain and z on top of ``named``
        alone and ``named``'s on top of ``other`` alone (``gain_z``). The one weighing of a
        walk beside an incidence bias, whichever is named (``walk_beside_incidence``) or
        neither (``pair_beside_nothing``)."""
        memo = self.memo('each_on_top')
        key = (named.name, other.name)
        if key not in memo:
            joint = self.jointly(named, other)
            memo[key] = (joint, self.gain_z(named.heldout_nll - joint),
                         self.gain_z(other.heldout_nll - joint))
        return memo[key]

    def pair_beside_nothing(self, cands: list[Candidate]) -> Decision:
        """Where no candidate may be named alone: a range walk and an incidence bias of
        opposite signs partly cancel (the walk short at normal incidence, the bias short
        at grazing), so each alone fits only their net and passes nothing, and the verdict
        would leave the structure outside the catalogue (an independent lab's box-wing at
        6.5 m: "a range error of the sensor outside the catalogue that follows range";
        both fitted together recover them). The two (scored, not vetoed) are weighed
        refitted together on each training fold (``each_on_top``; one set aside only for
        explaining too little of the features' structure alone, ``share_veto``, is weighed
        too: alone it sees the net; the pair's own share is asked): the pair over the
        model without either must pass the rule, give a fitted NLL (both refitted on all
        the diagnosed points, as --fit leaves them) below the one without them, and
        explain at least PAIR_SHARE of the features' structure (``power_incidence``; where
        the features show none, a null, the pair is not weighed);
        then each passing on top of the other names both (the one gaining more alone
        named, the other 'also'), else their tie (``power_incidence.pair_outcome``).
        Otherwise nothing is named, as before. Figures in
        ``pair_z[other]['jointly']``; each named one carries them (``Candidate.jointly``,
        with 'passes': the names ``settle`` lets stand)."""
        pair_z: dict = {}
        if self.memo('pair').get('set_aside'):
            return Decision(None, [])     # not told from a range term (``pair_against_rivals``)
        structure = self.pair_structure()
        if structure is None:
            # No structure in the features for the pair to explain (a null): not weighed
            # (the joint fit on every training fold cost ~3.7 s a compare).
            return Decision(None, [])
        two = [next((c for c in rank(cands) if c.name == n and c.error is None
                     and (c.vetoed is None or share_vetoed(c)) and c.effect is not None
                     and c.variant is not None and c.heldout_nll is not None), None)
               for n in power_incidence.PAIR]
        if None in two:
            return Decision(None, [])
        named, other = rank(two)
        try:
            joint, other_on_top, named_on_top = self.each_on_top(named, other)
            pair = self.gain_z(self.base_heldout() - joint)
            after = self._together_nll([named.effect, other.effect])
        except Exception:  # noqa: BLE001 - not measured: nothing named, as before
            return Decision(None, [])
        share = float(pair[0] * self.n_total / max(len(self.rays.matched), 1) / structure)
        pair_passes = bool(self.passes_rule(*pair) and np.isfinite(after)
                           and after < self.before_nll and share >= power_incidence.PAIR_SHARE)
        outcome = power_incidence.pair_outcome(pair_passes, self.passes_rule(*other_on_top),
                                               self.passes_rule(*named_on_top))
        label = {power_incidence.BOTH: 'pair_both', power_incidence.TIE: 'pair_tie'}.get(
            outcome, 'pair_not_shown')
        figures = {'other_on_top_of_named': [_num(v) for v in other_on_top],
                   'named_on_top_of_other': [_num(v) for v in named_on_top],
                   'pair_over_none': [_num(v) for v in pair],
                   'pair_nll_after': _num(after), 'before_nll': _num(self.before_nll),
                   'structure_share': _num(share), 'named': named.name, 'outcome': label}
        pair_z[other.name] = {'jointly': figures}
        if outcome is None:
            return Decision(None, [], None, pair_z)
        for c, on_top in ((named, named_on_top), (other, other_on_top)):
            c.jointly = {'with': (other if c is named else named).name,
                         'on_top': [_num(v) for v in on_top],
                         'pair_over_none': [_num(v) for v in pair],
                         'pair_nll_after': _num(after), 'passes': True}
        if outcome == power_incidence.BOTH:
            return Decision(named.name, [], other.name, pair_z)
        return Decision(None, [named.name, other.name], None, pair_z)

    def pair_structure(self) -> float | None:
        """The features' structure (nats per matched point) where the attribution shows
        one (``share_veto`` keeps it), else None."""
        att = getattr(self, '_attribution', None)
        if att is None or not getattr(att, 'significant', False):
            return None
        gain = float(getattr(att, 'structure_gain', 0.0) or 0.0)
        return gain if gain > 0 else None

    def jointly(self, a: Candidate, b: Candidate) -> np.ndarray:
        """Held-out NLL per matched point (``cross_fit`` order) of ``a`` and ``b`` fitted
        together on each training fold (``refit_in_turn``, each one's discrete options
        as chosen), as --fit with both fits them."""
        fixed = [{k: getattr(c.effect.params, k) for k in literal_choices(type(c.effect))}
                 for c in (a, b)]
        nll = []
        for k, train in enumerate(self.fold_data):
            test = self.fold_data[(k + 1) % N_FOLDS]
            first = fit_effect(a.variant, train).effect
            second = fit_effect(b.variant, train, [first]).effect
            nll.append(heldout_nll(test, refit_in_turn(train, [first, second], fixed)))
        return np.concatenate(nll)

    def gain_z(self, d: np.ndarray) -> tuple[float, float]:
        """Held-out gain per analysed point and its block z of the per-point NLL
        differences ``d`` (``cross_fit`` order)."""
        ok = np.isfinite(d)
        if ok.sum() < 2:
            return 0.0, 0.0
        _, z = block_mean_z(d[ok], self.blocks[ok])
        return float(np.sum(d[ok]) / max(self.n_total, 1)), z

    def incidence_beside_model_walk(self, best: Candidate, pair_z: dict) -> str | None:
        """Why an incidence bias may not be named where the model has a range walk of its
        own (``--effect range_walk``), or None: it must show a part of its own beyond a
        smooth function of ln P on the residual the model leaves (``power_incidence``, as
        ``also_beside_walk`` asks of an 'also'). A walk fitted on a noisy or clipped
        intensity is attenuated, and what it leaves follows the power; the incidence form
        takes it (an independent lab's walk on clipped raw counts, fitted by --fit with
        k 0.0258 for 0.03: the next run named incidence, bias_gain +0.36, absent from the
        data). The figures go to ``pair_z[incidence_angle]['power_incidence']`` with
        ``beside_model_walk``: 'shown' or 'not_shown'."""
        if best.name != power_incidence.INCIDENCE or best.effect is None:
            return None
        walk = next((e for e in getattr(self, 'base', ())
                     if getattr(e, 'name', '') == power_incidence.WALK), None)
        if walk is None:
            return None
        try:
            parts = self.own_parts(SimpleNamespace(effect=walk))
        except Exception:  # noqa: BLE001 - not measured: the decision stands
            return None
        figures = self.own_part_figures(parts)
        shown = figures[power_incidence.INCIDENCE]['passes']
        figures['beside_model_walk'] = 'shown' if shown else 'not_shown'
        pair_z[best.name] = {**pair_z.get(best.name, {}), 'power_incidence': figures}
        if shown:
            return None
        i = figures[power_incidence.INCIDENCE]
        return (f'with the range walk in the model, at a fixed received power its dependence '
                f'on the incidence gains {i["gain_per_point"]:.4f} nats/point held out '
                f'(z = {i["z"]:.1f}), which does not pass the rule: what it explains follows '
                f'the power, as the part a walk fitted on a noisy or clipped intensity (its '
                f'k read low), or a walk of another law in ln P, leaves; refit the walk with '
                f'power: model, or one of your own law, before adding an incidence bias')

    def also_beside_walk(self, best: Candidate, also: str | None,
                         pair_z: dict) -> str | None:
        """``also``, unless it is an incidence bias or a range scale beside a named walk
        that shows no part of its own (``power_incidence``: its depth, or the range,
        beyond a smooth function of ln P, by the rule): then None. A walk of another law
        in ln P, or one read on a noisy or clipped intensity (its k attenuated), leaves a
        part that follows the power, and the incidence form, which follows the power
        through the geometry, takes it on top of the walk (an independent lab's walk on
        raw counts clipped at 4095: the walk named, incidence 'also' on top, its own part
        0.0010 nats/point, z 1.3; none in the data). The figures go to the own parts'
        place in ``pair_z`` (``power_incidence.figures_in``; else ``pair_z[also]``), with
        ``also``: 'shown' or 'not_shown', and ``also_name``."""
        if also not in (power_incidence.INCIDENCE, power_incidence.SCALE) \
                or best.name != power_incidence.WALK or best.effect is None:
            return also
        try:
            parts = self.own_parts(best)
        except Exception:  # noqa: BLE001 - not measured: the decision stands
            return also
        shown = self.own_part_passes(parts[also])
        figures = power_incidence.figures_in(pair_z)
        if figures is None:
            figures = self.own_part_figures(parts)
            pair_z[also] = {**pair_z.get(also, {}), 'power_incidence': figures}
        figures['also'] = 'shown' if shown else 'not_shown'
        figures['also_name'] = also
        return also if shown else None

    def pointing_takes(self, best: Candidate, cands: list[Candidate]) -> str | None:
        """Why ``best`` may not be named beside lasers' pointing offsets set aside because
        their own part does not pass alone (``own_part_veto``), or None. Fitted with their
        common turn (the sensor's mount or the pose turned about it) those offsets still
        explain the residual decisively; a candidate that does not pass the rule on top of
        them explains nothing they leave, so the recording does not show it: naming it
        would name the beams' pointing (a laser's offset reads as a range error of
        r tan(incidence)) by another name. Nothing is named then."""
        if best.effect is None:
            return None
        aside = [c for c in cands
                 if not (c is best or c.effect is None or c.error is not None or not c.own_part
                         or c.own_part.get('passes') or not c.significant or not c.practical)]
        if not aside or len(np.unique(self.rays.meas.laser[self.rays.matched])) < 2:
            return None       # one laser: its "pointing" is a turn of the sensor, the pose's
        for c in aside:
            try:
                self.finalized(c)
                gain, z, _ = self._on_top([c.effect], best)
            except Exception:  # noqa: BLE001 - not shown to take it
                continue
            if self.passes_rule(gain, z):
                continue
            return (f'on top of {c.name} fitted with the beams\' common turn it gains '
                    f'{gain:.4f} nats/point held out (z = {z:.1f}), which does not pass the '
                    f'rule: what it explains, the lasers\' pointing explains (a beam off its '
                    f'direction reads as a range error of r tan(incidence)), and this '
                    f'recording shows the lasers\' own offsets too weakly to name them '
                    f'({c.own_part.get("score") or 0:.4f} nats/point, z = '
                    f'{c.own_part.get("z") or 0:.1f})')
        return None

    def next_beside(self, best: Candidate, ok: list[Candidate],
                    cands: list[Candidate] = ()) -> str | None:
        """A candidate decisively worse than ``best`` alone may still explain another part
        of the residual: a range walk and an incidence elongation at once (grazing
        returns are weak and long, so each alone takes part of the other's shape; the
        walk named alone is fitted 70 % high, eighth holdout). The next MAX_ALSO_TRIES
        candidates that may be named (``ok``, ranked) are tried on top of ``best``
        (``adds_to``: the rule on top, and the NLL of both below that of ``best``),
        and beside the effects set aside that add to ``best`` (``beside_set_aside``).
        Returns the first that adds, or None.

        Beyond those, a candidate whose evidence lies on the shots that missed the
        target model where ``best`` explains none of them (``on_other_shots``) is tried
        too: that part is another by construction, so its rank behind effects of
        ``best``'s own shape says nothing about it (twelfth holdout incid_solar: false
        returns, z 28 alone, ranked fourth behind two stand-ins of the incidence
        elongation and never tried)."""
        if best.effect is None:
            return None
        others = [c for c in ok if c is not best]
        tries = others[:MAX_ALSO_TRIES] + [c for c in others[MAX_ALSO_TRIES:]
                                            if on_other_shots(best, c)]
        for c in tries:
            if (c.name != POSE_ERROR and not laser_tiles.per_laser(c.effect)
                    and self.adds_to(best, c) and self.beside_set_aside(best, c, cands)):
                return c.name
        return None

    def set_aside_beside(self, best: Candidate, cands: list[Candidate],
                         but: tuple[str, ...] = ()) -> list[Candidate]:
        """The effects the residual holds beside ``best`` that the rule set aside for
        their shape: candidates whose own gain is decisive (``significant``) but that a
        test of their shape on the residual with ``best`` still in it vetoed (a laser's
        tile test, the share of the structure, the driver of a noise effect), and that
        add to ``best`` (``adds_to``: there their gain must also matter, as alone it is
        shared with ``best`` and the lasers: an SNR noise of 0.0041 nats/point alone
        beside the lasers of h8-d20-walk-laser-snr10_s51); a per-laser
        one only where its offsets hold across the tiles beside ``best``
        (``tile_veto`` on top, as ``lasers_beside``: else its offsets follow a pattern
        on the target, which may be the very part judged). They are never named here:
        they are the model a tie or an 'also' beside ``best`` is judged in
        (``beside_set_aside``, ``tie_beside_set_aside``). ``but``: names left out."""
        if best.effect is None or not self.nameable(best):
            return []
        memo = self.memo('set_aside')
        out = []
        for c in cands:
            if (c is best or c.name in but or c.name == POSE_ERROR or c.error is not None
                    or c.vetoed is None or not c.significant):
                continue
            if c.own_part and not c.own_part.get('passes'):
                # Lasers' pointing set aside as mostly a turn of the whole sensor: that
                # turn is the pose's (or the mount's) to explain, not a model to judge in.
                continue
            if c.standoff_part and not c.standoff_part.get('passes'):
                continue    # a standoff set aside as the rival's shape: the rival's part
            key = (best.name, c.name)
            if key not in memo:
                adds = self.adds_to(best, c)
                if adds and c.tile_vetoed:
                    adds = self.tile_veto(c, [best.effect]) is None
                memo[key] = adds
            if memo[key]:
                out.append(c)
        return out

    def _fitted_together(self, effects: list[Effect]) -> list[Effect]:
        """``effects`` refitted together on all the diagnosed points (``refit_in_turn``),
        remembered by their names and parameters. Those that move the rays (a clock
        offset) stay as fitted, in the model under the others' refit, as --fit keeps such
        effects out of the joint refit (each step would raycast the points again)."""
        moving = lk.moving(effects)
        still = [e for e in effects if all(e is not m for m in moving)]
        if len(still) < 2 and not (still and moving):
            return list(effects)
        memo = self.memo('together')
        key = tuple((e.name, repr(e.params.model_dump())) for e in effects)
        if key not in memo:
            memo[key] = [*moving, *refit_in_turn(self.full, still, [{}] * len(still),
                                                 on_top=moving)]
        return memo[key]

    def _together_nll(self, effects: list[Effect]) -> float:
        """The calibrated NLL per matched point with ``effects`` fitted together, as
        --fit with all of them leaves it (``calibrated_figures``)."""
        return calibrated_figures(self.full, self._fitted_together(effects))[0]

    def _on_top(self, on_top: list[Effect], other: Candidate) -> tuple[float, float, np.ndarray]:
        """``other`` cross-fitted on top of the fixed ``on_top``: its held-out gain over
        them (nats per analysed point, matched and unmatched), its z (``total_z``) and
        its held-out NLL per matched point."""
        base = np.concatenate([heldout_nll(self.fold_data[(k + 1) % N_FOLDS], on_top)
                               for k in range(N_FOLDS)])
        nll, explained = self.cross_fit(other.variant, on_top)
        d = base - nll
        ok = np.isfinite(d)
        if ok.sum() < 2:
            return 0.0, 0.0, nll
        gain, se = block_mean_se(d[ok], self.blocks[ok])
        total = float(np.sum(d[ok])) + UNMATCHED_NATS * explained
        z = total_z(gain, se, int(ok.sum()), explained)
        return total / max(self.n_total, 1), z, nll

    def beside_set_aside(self, best: Candidate, other: Candidate,
                         cands: list[Candidate], but_taken: bool = False) -> bool:
        """Whether ``other``, which adds to ``best``, is 'also' in its own right: it must
        still pass the rule on top of ``best`` and the effects set aside beside it
        (``set_aside_beside``), all fitted together. A part of the residual that one of
        those explains is not another effect's: a candidate that gains on top of
        ``best`` only by standing in for it (an incidence elongation's sigma for a
        noise growing at weak returns, eighth holdout ``h8-d20-walk-laser-snr10_s11``)
        would be named where the effect the data hold cannot be. With none set aside,
        ``adds_to`` alone decides. ``but_taken``: an effect set aside that gains nothing
        decisive on top of ``best`` and ``other`` fitted together (``other`` explains
        all it explains there, and more) is no model to judge ``other`` in: it stood
        in for ``other`` (``taken_by``)."""
        if best.effect is None:
            return False
        if (not laser_tiles.per_laser(other.effect)
                and self.stands_in_beside(best, other, cands) is not None):
            return False
        rest = self.set_aside_beside(best, cands, but=(other.name,))
        if but_taken:
            rest = [c for c in rest if not self.taken_by(best, other, c)]
        if not rest:
            return True
        try:
            self.finalized(best, *rest)
            together = self._fitted_together([best.effect, *[c.effect for c in rest]])
            return self._passes_on_top(together, other)
        except Exception:  # noqa: BLE001 - not shown to be separate
            return False

    def taken_by(self, best: Candidate, other: Candidate, aside: Candidate) -> bool:
        """Whether ``aside`` (an effect set aside beside ``best``) gains nothing decisive
        on top of ``best`` and ``other`` fitted together (``_passes_on_top`` without the
        practical margin: z and total evidence only). Then ``other`` explains all that
        ``aside`` explains beside ``best``: ``aside`` stood in for it."""
        try:
            self.finalized(best, other, aside)
            both = self._fitted_together([best.effect, other.effect])
            return not self._passes_on_top(both, aside, practical=False)
        except Exception:  # noqa: BLE001 - not shown to be taken
            return False

    def _passes_on_top(self, on_top: list[Effect], other: Candidate,
                       practical: bool = True) -> bool:
        """Whether ``other`` cross-fitted on top of the fixed ``on_top`` passes the rule
        (``_on_top``: z decisive, total above MIN_TOTAL_GAIN, and with ``practical`` the
        gain per point at least MIN_PRACTICAL_GAIN: one that matters enough to name)."""
        gain, z, _ = self._on_top(on_top, other)
        self.memo('on_top_figures')[
            (other.name, *sorted(e.name for e in on_top))] = (_num(gain), _num(z))
        return self.passes_rule(gain, z, practical)

    def passes_rule(self, gain: float, z: float, practical: bool = True) -> bool:
        """The naming rule on held-out figures (``gain`` nats per point, block-robust
        ``z``): z decisive, the total above MIN_TOTAL_GAIN, and with ``practical`` the gain
        per point at least MIN_PRACTICAL_GAIN."""
        return bool((gain >= MIN_PRACTICAL_GAIN or not practical) and z >= self.z_crit
                    and gain * self.n_total >= MIN_TOTAL_GAIN)

    def stands_in_beside(self, best: Candidate, other: Candidate,
                         cands: list[Candidate]) -> str | None:
        """The candidate ``other`` only stands in for beside ``best``, or None. A third
        candidate ``c`` with a decisive gain of its own that nothing set aside (scalar,
        not vetoed, ``nameable``) is the effect the part ``other`` gains on top of
        ``best`` belongs to when, with each pair fitted together (``_fitted_together``),
        ``other`` no longer passes the rule on top of ``best`` and ``c`` while ``c``
        still gains decisively on top of ``best`` and ``other`` (z and total evidence
        as the rule; a gain too small to name is enough, as ``c`` is not named by this):
        ``c`` explains what ``other`` explains there and more, not the reverse (ninth
        holdout walk+snr_103: incidence -0.0002 nats/point on top of the walk and the
        noise, the noise 0.0049, z 4.7, on top of the walk and incidence). An incidence
        elongation's sigma, growing at grazing (weak) returns, stands in for a noise
        growing at weak returns
        beside a range walk (ninth holdout ``walk+snr``: fitted together with the walk
        its bias gain is -0.012). Where each passes on top of the other (two effects)
        or neither does (the data cannot tell which), nothing changes. A footprint
        (``SHARES_DILATION``) as ``other`` is judged on the gain that matters on both
        sides, z aside (``_own_part_on_top``): its evidence lies on a few edge returns, so
        its z is small at any size and cannot be weighed against another's; it stands in
        for ``c`` only where it gains too little to matter on top of ``best`` and ``c``
        while ``c`` passes the whole rule on top of ``best`` and the footprint."""
        if best.effect is None or other.effect is None:
            return None
        memo = self.memo('stands_in')
        key = (best.name, other.name)
        if key in memo:
            return memo[key]
        memo[key] = None
        for c in rank(cands):
            if (c is best or c is other or c.name == POSE_ERROR or c.error is not None
                    or c.effect is None or c.vetoed is not None or not c.significant
                    or laser_tiles.per_laser(c.effect) or not self.nameable(c)):
                continue
            try:
                self.finalized(best, other, c)
                if self._passes_on_top(self._fitted_together([best.effect, c.effect]), other):
                    continue
                footprint = other.name in SHARES_DILATION
                if footprint and self._own_part_on_top([best.effect, c.effect], other):
                    continue
                if self._passes_on_top(self._fitted_together([best.effect, other.effect]), c,
                                       practical=footprint):
                    memo[key] = c.name
                    return c.name
            except Exception:  # noqa: BLE001 - not shown to stand in
                continue
        return None

    def _own_part_on_top(self, on_top: list[Effect], other: Candidate) -> bool:
        """Whether ``other`` (a footprint) still gains what matters on top of ``on_top``
        fitted together: held out at least MIN_PRACTICAL_GAIN per point and
        MIN_TOTAL_GAIN in all, whatever its z. A footprint's own part is its edge returns
        beyond the silhouette and mixed ranges at depth steps, a few per cent of the
        points carrying most of its gain, so its block z is small for any size there
        (foreign beam_solar_incid@1: 0.1029 nats/point alone at z 4.2, 0.0203 on top of
        false returns and the incidence bias at z 1.1); beside its dilation partner
        (``SHARES_DILATION``: an incidence bias) the two share the bias of oblique faces
        by construction. A z that small says the size is uncertain, not that the
        footprint stands in for the other."""
        try:
            gain, _, _ = self._on_top(self._fitted_together(on_top), other)
        except Exception:  # noqa: BLE001 - not shown to keep a part of its own
            return False
        return bool(gain >= MIN_PRACTICAL_GAIN and gain * self.n_total >= MIN_TOTAL_GAIN)

    def tie_beside_set_aside(self, best: Candidate, tied: list[str],
                             cands: list[Candidate],
                             pair_z: dict) -> tuple[Candidate, list[str]]:
        """A tie judged in the model the residual calls for: the effects set aside beside
        ``best`` (``set_aside_beside``) fitted together in the model, the tied candidates
        are compared again on top of them by the same rule as ``decide`` (the paired
        held-out margin and its z, and the margin fitted as --fit leaves each with them);
        a member decisively worse than the one that gains most there is no tie member.
        A candidate can tie with the named one by standing in for a set-aside effect
        the residual also holds (an incidence elongation's sigma for a noise growing at
        weak returns, which a laser's offsets left vetoed: eighth holdout
        ``h8-d20-walk-laser-snr10_s10``). Returns the lead and the members left tied
        (unchanged with none set aside)."""
        by_name = {c.name: c for c in cands}
        members = [best, *[by_name[n] for n in tied if n in by_name]]
        rest = self.set_aside_beside(best, cands, but=tuple(c.name for c in members))
        if not rest or len(members) != len(tied) + 1:
            return best, tied
        try:
            self.finalized(*members, *rest)
            base = self._fitted_together([c.effect for c in rest])
            on_rest = {c.name: self._on_top(base, c) for c in members}
            lead = max(members, key=lambda c: on_rest[c.name][0])
            n_m = len(self.rays.matched)
            lead_nll = self._together_nll([lead.effect, *base])
            left = []
            for c in members:
                if c is lead:
                    continue
                d = on_rest[c.name][2] - on_rest[lead.name][2]
                ok = np.isfinite(d)
                mean, se = block_mean_se(d[ok], self.blocks[ok])
                z = float(mean / se) if se > 0 and np.isfinite(se) else 0.0
                margin = float(np.sum(d[ok]) / max(self.n_total, 1))
                fitted = float((self._together_nll([c.effect, *base]) - lead_nll)
                               * n_m / max(self.n_total, 1))
                pair_z.setdefault(c.name, {})['beside_set_aside'] = {
                    'with': [r.name for r in rest], 'against': lead.name,
                    'margin': _num(margin), 'z': _num(z), 'fitted_margin': _num(fitted)}
                if not self.apart(margin, z, fitted):
                    left.append(c.name)
        except Exception:  # noqa: BLE001 - the tie stands
            return best, tied
        return lead, left

    def fit_together(self, decision: Decision, cands: list[Candidate]) -> None:
        """The named effect refitted with the one that also explains a part (``also``) in
        the model (``refit_in_turn``, as --fit fits the two): ``together`` on the named
        candidate (the other's name, and both fits' parameters). Alone it takes part of
        the other's shape, so its value alone is off by what they share."""
        by_name = {c.name: c for c in cands}
        best, other = by_name.get(decision.missing), by_name.get(decision.also)
        if best is None or other is None or best.effect is None or other.effect is None:
            return
        # The discrete options (a footprint's range mode) stay as each was chosen.
        fixed = [{k: getattr(c.effect.params, k) for k in literal_choices(type(c.effect))}
                 for c in (best, other)]
        try:
            first, second = refit_in_turn(self.full, [best.effect, other.effect], fixed)
        except Exception:  # noqa: BLE001 - the alone figures stand
            return
        mine, theirs = first.params.model_dump(), second.params.model_dump()
        best.together = {'with': other.name,
                         'params': {k: float(mine[k]) for k, v in best.params.items()
                                    if isinstance(v, float) and isinstance(mine.get(k), float)},
                         'with_params': {k: float(v) for k, v in theirs.items()
                                         if isinstance(v, float)}}
        # Per-laser offsets (a list parameter), fitted together: ``run.laser_intensity``.
        lists = {c.name: [float(x) for x in d['offsets_m']]
                 for c, d in ((best, mine), (other, theirs))
                 if isinstance(d.get('offsets_m'), (list, tuple))}
        if lists:
            best.together['offsets_m'] = lists

    def lasers_beside(self, best: Candidate, cands: list[Candidate]) -> str | None:
        """A per-laser candidate set aside by the tile test (``tile_veto``: its offsets
        followed a pattern on the target) is tried again with the named effect ``best``
        in the model: the named effect's own pattern (a walk's, over the target's
        intensities) is what the tiles cut up, beside the lasers' real offsets. If its
        offsets then hold across the tiles and it adds to ``best`` (``adds_to``), it
        explains another part: its veto is lifted and it is 'also'. Returns its name or
        None."""
        if best.effect is None or laser_tiles.per_laser(best.effect):
            return None
        for c in rank(cands):
            if c is best or c.error is not None:
                continue
            if c.beside == best.name:
                return c.name       # tried already (``decide`` runs again on rivals)
            if not c.tile_vetoed:
                continue
            if (self.tile_veto(c, [best.effect]) is None and self.adds_to(best, c)
                    and self.beside_set_aside(best, c, cands)):
                c.vetoed, c.tile_vetoed, c.beside = None, False, best.name
                return c.name
        return None

    def material_beside(self, best: Candidate, cands: list[Candidate]) -> str | None:
        """A range term set aside by the cross-material test (``material_veto``: one
        material's points read off the rest) is tried again with the named effect
        ``best`` in the model: an unmodelled effect that differs by material (a range
        walk, over the materials' intensities) makes the materials read apart under any
        range term fitted alone (twelfth holdout drift_walk_1: range_drift z 13.6 alone,
        vetoed on the PSS points with the walk left out). If with ``best`` fitted no
        material reads off the rest and the term adds to ``best`` (``adds_to``,
        ``beside_set_aside``), it explains another part: its veto is lifted and it is
        'also'. Returns its name or None."""
        if best.effect is None or best.name in POSE_RIVALS:
            return None
        for c in rank(cands):
            if (c is best or c.error is not None or not c.material_vetoed
                    or not (c.significant and c.practical)):
                continue
            try:
                if (self.material_veto(c, [best.effect]) is None and self.adds_to(best, c)
                        and self.beside_set_aside(best, c, cands)):
                    c.vetoed, c.material_vetoed, c.beside = None, False, best.name
                    return c.name
            except Exception:  # noqa: BLE001 - not shown to read alike beside it
                continue
        return None

    def geometry_beside(self, best: Candidate, scored: list[Candidate],
                        cands: list[Candidate]) -> str | None:
        """A surface offset (GEOMETRY_RIVALS) that does not pass the rule alone, tried on
        top of the named effect ``best``: a standoff of one material's faces moves its
        ranges by d / cos(incidence), whose mean the per-material offsets take; what is
        left, beside an unmodelled effect that differs by material and range (a walk,
        over the materials' intensities), is swamped by that effect's residual (twelfth
        holdout walk_standoff_1: surface_offset -0.005 nats/point alone beside a walk,
        0.229 alone on the same 4 cm standoff without it). If it adds to ``best``
        (``adds_to``) and in its own right (``beside_set_aside``: not standing in for a
        third, an incidence elongation), its figures on top of ``best`` are recorded
        (``against_pose['beside']``, what ``settle`` and the verdict quote for it) and
        it is 'also'. Returns its name or None."""
        if best.effect is None or best.name in GEOMETRY_RIVALS:
            return None
        for c in rank(scored):
            if (c.name not in GEOMETRY_RIVALS or c.error is not None or c.variant is None
                    or self.nameable(c)):
                continue
            try:
                if not (self.adds_to(best, c) and self.beside_set_aside(best, c, cands)):
                    continue
                gain, z, _ = self._on_top([best.effect], c)
            except Exception:  # noqa: BLE001 - not shown to add beside it
                continue
            c.against_pose = {**(c.against_pose or {}), 'beside': {
                'on_top_of': best.name, 'gain': _num(gain), 'z': _num(z)}}
            return c.name
        return None

    def lasers_beside_rival(self, decided: 'Decision', decision: 'Decision',
                            cands: list[Candidate]) -> 'Decision':
        """``lasers_beside`` for a range term named on the pose's footing
        (``weigh_pose_rivals``: ``decided`` before it, ``decision`` after). ``decide``
        tried the lasers set aside by the tile test beside the effect it named, but a
        range term is weighed against the pose after ``decide`` ran, so the lasers were
        never tried beside it (the twelfth holdout's ``rscale_laser_1``: a range scale
        across an approach named, the lasers' real offsets set aside for its pattern
        within the tiles in elevation, 0.0148 nats/point, z 7.0, and named there by the
        second pass with the scale fitted). They are tried beside it as beside any
        named effect; an 'also' already given stays."""
        if (decision.missing is None or decision.missing == decided.missing
                or decision.also is not None):
            return decision
        best = next((c for c in cands if c.name == decision.missing), None)
        if best is None:
            return decision
        also = self.lasers_beside(best, cands)
        return replace(decision, also=also) if also else decision

    def offsets_beside_also(self, decision: 'Decision', cands: list[Candidate]) -> 'Decision':
        """Lasers' pointing offsets named beside an 'also' (``decision``), against the
        lasers' range offsets the tile test set aside. A pointing offset reads as a range
        error of r tan(incidence) along the surface's slope, so its 48 parameters fit an
        incidence bias's pattern and the lasers' range offsets at once (the twelfth
        holdout's ``laser_incid_1``: pointing 0.438 nats/point alone, incidence 0.385,
        the range offsets 0.155, set aside for the incidence's pattern within the
        tiles). As ``simpler_instead`` asks of a per-laser candidate against a simpler
        one: where the range offsets hold across the tiles beside the 'also'
        (``tile_veto`` on top) and add to it (``adds_to``), the pointing must still pass
        the rule on top of the two fitted together (26 parameters against its 48); if it
        does not, the 'also' is named and the range offsets are its 'also', the pointing
        set aside with its figures. Else ``decision`` as it is."""
        by_name = {c.name: c for c in cands}
        best, also = by_name.get(decision.missing), by_name.get(decision.also)
        if (best is None or also is None or best.effect is None or also.effect is None
                or best.variant is None or pointing.turn_of(best.variant) is None
                or laser_tiles.per_laser(also.effect)):
            return decision
        for c in rank(cands):
            if (c is best or not c.tile_vetoed or not c.significant or c.error is not None
                    or c.effect is None or c.variant is None
                    or pointing.turn_of(c.variant) is not None):
                continue
            try:
                if self.tile_veto(c, [also.effect]) is not None or not self.adds_to(also, c):
                    continue
                together = self._fitted_together([also.effect, c.effect])
                gain, z, _ = self._on_top(together, best)
            except Exception:  # noqa: BLE001 - not shown to stand in for them
                continue
            if self.passes_rule(gain, z):
                return decision
            best.vetoed = (f'its offsets stand for {also.name} and {c.name} together: with '
                           f'both fitted in the model it gains {gain:.4f} nats/point held '
                           f'out (z = {z:.1f}), which does not pass the rule')
            c.vetoed, c.tile_vetoed, c.beside = None, False, also.name
            pair_z = dict(decision.pair_z)
            pair_z[best.name] = {'on_top_of': [also.name, c.name], 'gain': _num(gain),
                                 'z': _num(z)}
            return replace(decision, missing=also.name, also=c.name, pair_z=pair_z)
        return decision

    def lasers_beside_named(self, decision: 'Decision', cands: list[Candidate]) -> None:
        """A per-laser candidate the tile test set aside, tried with the named effect and
        its 'also' both in the model (fitted together, as --fit with both leaves them):
        the pattern the tiles cut up may be theirs together (a walk beside false returns,
        the walk 'also', so the lasers cannot be 'also' beside the named one). If its
        offsets then hold across the tiles and it still passes the rule on top of both,
        it is recorded as passing beside them (``beside``: 'A and B'; never named here):
        the verdict says to expect it once those are fitted."""
        by_name = {c.name: c for c in cands}
        best, also = by_name.get(decision.missing), by_name.get(decision.also)
        if (best is None or also is None or best.effect is None or also.effect is None
                or laser_tiles.per_laser(best.effect) or laser_tiles.per_laser(also.effect)):
            return
        lasers = [c for c in rank(cands) if c.tile_vetoed and c.significant and c.practical
                  and c.error is None and c.effect is not None and c.variant is not None]
        if not lasers:
            return
        c = lasers[0]
        try:
            together = self._fitted_together([best.effect, also.effect])
            if self.tile_veto(c, together) is not None:
                return
            gain, z, _ = self._on_top(together, c)
        except Exception:  # noqa: BLE001 - not shown to hold beside them
            return
        if self.passes_rule(gain, z):
            c.beside = f'{best.name} and {also.name}'
            c.beside_gain = {'gain': _num(gain), 'z': _num(z)}

    def simpler_instead(self, best: Candidate, others: list[Candidate],
                        pair_z: dict) -> Candidate | None:
        """A candidate with a parameter per laser (``laser_tiles.per_laser``) fits any
        pattern the tiles lay over the target with its dozens of parameters; named first
        it takes the pattern of a one-parameter cause into its offsets. So when a
        candidate with fewer parameters is not decisively worse (paired held-out z below
        the bound, or less than MIN_PRACTICAL_GAIN apart as --fit leaves them), the
        per-laser one must still pass on top of it (``adds_to``): then the simpler one is
        named and the per-laser one "also" (expected next, fitted on top). Returns it, or
        None (the ordinary decision: a tie if they explain the same residual)."""
        if best.effect is None or not laser_tiles.per_laser(best.effect):
            return None
        for c in others:
            if c.n_params >= best.n_params:
                continue
            margin, z = self.paired(best, c)
            fitted = self.fitted_margin(best, c)
            if self.apart(margin, z, fitted):
                continue      # decisively better than this one
            if self.adds_to(c, best):
                pair_z[best.name] = {'margin': _num(-margin), 'z': _num(-z),
                                     'fitted_margin': _num(-fitted)}
                return c
            return None
        return None

    def places(self, points: np.ndarray) -> np.ndarray:
        """Each of ``points`` (indices of matched points of the recording, as a fold's
        ``matched``) as its place in ``rays.matched``: the index into ``self.full``'s
        arrays and every per-matched-point array of the diagnosis."""
        return np.searchsorted(self.rays.matched, points)

    def memo(self, name: str) -> dict:
        """This diagnosis's cache ``name`` (results that depend on its model: effects
        fitted together, what adds beside a named one, the figures on top), made on first
        use (test stand-ins are built without ``__init__``). A diagnosis on another model
        (``pose_corrected``) starts with none."""
        return self.__dict__.setdefault('_memos', {}).setdefault(name, {})

    def false_return_budget(self, cand: Candidate) -> dict | None:
        """For an outlier effect as fitted (``cand.effect``): how many false returns it
        predicts among the diagnosed points, on the target (before the echo, for a
        first-return receiver) and on the shots that missed it (the whole window),
        against those recorded there (far points isolated from their neighbours;
        isolated unmatched points). The number a simulation with the fitted rate gives,
        to be compared with what the sensor recorded; None for other effects."""
        if cand.effect is None or not is_outlier_effect(type(cand.effect)):
            return None
        base = lk.model_on_rays(self.full, [])
        model = lk.model_on_rays(self.full, [cand.effect])
        everything = [*self.full.base_effects, cand.effect]
        on_target = float(np.sum(model.outlier_w - base.outlier_w))
        per_miss = (lk.miss_outlier_weight(model, everything)
                    - lk.miss_outlier_weight(base, list(self.full.base_effects)))
        m = len(self.rays.unmatched)
        missed = (self.rays.missed_per_unmatched * m if self.rays.missed_per_unmatched is not None
                  else None)
        isolated = (int(np.sum(self.rays.isolated[self.rays.unmatched]))
                    if self.rays.isolated is not None else m)
        off = None if missed is None else float(per_miss * missed)
        predicted = on_target + (off or 0.0)
        recorded = self.n_far + isolated
        return {'predicted_on_target': round(on_target, 1), 'recorded_on_target': self.n_far,
                'predicted_off_target': None if off is None else round(off, 1),
                'recorded_off_target': isolated, 'missed_shots': None if missed is None
                else round(float(missed), 1), 'per_missed_shot': round(per_miss, 8),
                'predicted': round(predicted, 1), 'recorded': int(recorded),
                'ratio': round(predicted / recorded, 4) if recorded else None}

    def weigh_rivals(self, decision: Decision, cands: list[Candidate],
                     rivals: list[type[Effect]],
                     attribution: Attribution | None = None) -> tuple[Decision, list[Candidate]]:
        """A named sensor effect (or a tie) against the range errors kept out of the
        default candidates (POSE_RIVALS: a range offset drifting over the recording, a
        range scale). They are no default candidates because, on their own, they fit
        smooth patterns of other causes (a bias linear in range stands for any pattern
        across a target whose range follows its azimuth); but once the data call for
        a range term, the one named must be weighed against them on the same footing:
        on an approach a walk in ln P follows the range as a scale does. They are
        scored here, with the same vetoes, and ``decide`` is run again among all: a
        rival decisively better by its rule is named instead, one within its margins
        makes a tie, one decisively worse leaves the decision. On an empty decision a
        rival names itself only where the residual's structure would be left outside
        the catalogue and a range term explains most of it (``range_outside``). Returns
        the decision and the rivals scored."""
        if power_incidence.pair_figures(decision.pair_z) is not None and rivals:
            held, scored = self.pair_against_rivals(decision, cands, rivals, attribution)
            if held is not None:
                return held, scored
            # Not told from a range term: as without the pair (nothing named).
            decision = Decision(None, [], None, decision.pair_z)
        if range_outside.applies(decision, attribution):
            # Where the structure would be left outside the catalogue, the range terms
            # are weighed too, and named only where they explain most of it.
            return range_outside.weigh(self, decision, cands, rivals, attribution, rank)
        if not (decision.missing or decision.confounded_with) or not rivals:
            return decision, []
        scored = self.scored_with_vetoes(rivals, attribution)
        if not any(self.nameable(r) for r in scored):
            # None may be named instead; one set aside by the material split may still
            # be 'also', with the named effect in the model (``material_beside``).
            best = next((c for c in cands if c.name == decision.missing), None)
            if best is not None and decision.also is None:
                lifted = (self.material_beside(best, scored)
                          or self.geometry_beside(best, scored, cands))
                # Beside a walk, as in ``decide``: a part of its own beyond the power.
                lifted = self.also_beside_walk(best, lifted, decision.pair_z)
                if lifted is not None:
                    return replace(decision, also=lifted), scored
            return decision, scored
        again = self.decide(rank([*cands, *scored]))
        return replace(decision, missing=again.missing, confounded_with=again.confounded_with,
                       also=again.also, pair_z=again.pair_z), scored

    def pair_against_rivals(self, decision: Decision, cands: list[Candidate],
                            rivals: list[type[Effect]], attribution: Attribution | None
                            ) -> tuple[Decision | None, list[Candidate]]:
        """A walk and an incidence bias named as a pair (``pair_beside_nothing``) against
        the range terms kept out of the default candidates (``weigh_rivals``): each
        nameable one scored, the pair refitted together must pass the rule over it (held
        out, ``gain_z`` of the rival's NLL less the pair's). Where it does over all, the
        pair stands (None of them named) and the rivals scored are returned; where it does
        not, the pair is set aside (``pair_set_aside``: the names it carried withheld, a
        later ``decide`` names nothing by it) and (None, []) is returned: the decision is
        then weighed as without the pair. Figures in the pair's ``against_rivals``
        (gain per point, z, per rival). A seed of the box-wing item: the pair 0.0078
        nats/point, range_scale 0.0054 (z 4.9) alone, which the rivals' ``decide``
        then named in its place."""
        f = power_incidence.pair_figures(decision.pair_z)
        by_name = {c.name: c for c in cands}
        named = by_name.get(f['named'])
        other = by_name.get(next(n for n in power_incidence.PAIR if n != f['named']))
        scored = self.scored_with_vetoes(rivals, attribution)
        try:
            joint = self.each_on_top(named, other)[0]
            over = {r.name: self.gain_z(r.heldout_nll - joint) for r in scored
                    if self.nameable(r)}
        except Exception:  # noqa: BLE001 - not shown beyond the rivals
            over = None
        f['against_rivals'] = ({n: [_num(v) for v in g] for n, g in over.items()}
                               if over is not None else None)
        if over is not None and all(self.passes_rule(*g) for g in over.values()):
            return decision, scored
        self.memo('pair')['set_aside'] = True
        f['outcome'] = 'pair_not_beyond_rival'
        for c in (named, other):
            if c is not None and c.jointly:
                c.jointly['passes'] = False
        return None, []

    def scored_with_vetoes(self, classes: list[type[Effect]],
                           attribution: Attribution | None = None) -> list[Candidate]:
        """Each of ``classes`` scored (``score``) and passed through the share veto, one
        after the other."""
        scored = []
        for cls in classes:
            r = self.score(cls)
            self.share_veto(r, attribution)
            scored.append(r)
        return scored

    def fitted_margin(self, a: Candidate, b: Candidate) -> float:
        """How much better ``a`` explains the data than ``b`` as --fit would leave them:
        each fitted on all the diagnosed points with every material's offset and sigma
        scale refit (``finalize``), nats per analysed point (matched NLL plus the
        unmatched credit). A tie on this footing is a tie: --fit could not tell them
        apart either."""
        self.finalized(a, b)
        n_m = len(self.rays.matched)
        return float(((b.nll_after - a.nll_after) * n_m + UNMATCHED_NATS
                      * (a.unmatched_gain_points - b.unmatched_gain_points)) / self.n_total)

    def apart(self, margin: float, z: float, fitted: float) -> bool:
        """decide's rule for two candidates: the first decisively better than the second,
        its paired held-out margin (``paired``: nats per analysed point, and z) positive
        at z above the bound, and at least MIN_PRACTICAL_GAIN better as --fit leaves them
        (``fitted_margin``)."""
        return bool(margin > 0 and z >= self.z_crit and fitted >= MIN_PRACTICAL_GAIN)

    def paired(self, a: Candidate, b: Candidate) -> tuple[float, float]:
        """How much better ``a`` explains the data than ``b``: the paired held-out per-point
        NLL difference plus their unmatched credit, nats per analysed point, and its z
        (the same quantity and rule as each candidate's own, ``total_z``)."""
        d = b.heldout_nll - a.heldout_nll
        ok = np.isfinite(d)
        mean, se = block_mean_se(d[ok], self.blocks[ok])
        n_m = max(int(ok.sum()), 1)
        du = UNMATCHED_NATS * (a.unmatched_gain_points - b.unmatched_gain_points)
        total = mean * n_m + du
        margin = total / self.n_total
        var = (se * n_m) ** 2 + UNMATCHED_NATS ** 2 * (a.unmatched_gain_points
                                                       + b.unmatched_gain_points)
        z = total / np.sqrt(var) if var > 0 and np.isfinite(var) else 0.0
        return float(margin), float(z)

    def range_decides(self, a: Candidate, b: Candidate, pair_z: dict) -> Candidate | None:
        """Of a beam footprint and a surface standing proud that the held-out points do
        not set apart, the one the ranges tell (or None: not such a pair, or untold). A
        footprint's dilation and its edge bias grow with range (divergence x range), a
        standoff moves the surface by the same distance at any range: each fitted on the
        nearer half of the matched points (by measured range) and scored on the farther,
        and the other way round (``transfer_nll``), the right one carries over. Decided
        by the rule of any two candidates (``apart``: z above the bound, at least
        MIN_PRACTICAL_GAIN nats per point, the transfer's margin standing for both)."""
        if {self.footprint_or_standoff(a), self.footprint_or_standoff(b)} != {'footprint',
                                                                              'standoff'}:
            return None
        try:
            order = self.rays.matched
            r = np.asarray(self.rays.meas.range_m[order], float)
            near = r <= np.median(r)
            none = self.rays.unmatched[:0]
            halves = [self.rays._with(order[near], none), self.rays._with(order[~near], none)]
            d = self.transfer_nll(b.variant, halves) - self.transfer_nll(a.variant, halves)
        except Exception:  # noqa: BLE001 - not shown to be told apart
            return None
        ok = np.isfinite(d)
        if ok.sum() < 2:
            return None
        mean, se = block_mean_se(d[ok], self.matched_blocks[ok])
        margin = float(mean * ok.sum() / max(self.n_total, 1))
        z = float(mean / se) if se > 0 and np.isfinite(se) else 0.0
        lead = a if self.apart(margin, z, margin) else b if self.apart(-margin, -z, -margin) \
            else None
        if lead is None:           # untold: ``a``'s margin over ``b`` on the split, kept
            pair_z[b.name] = {**pair_z.get(b.name, {}), 'range_split_margin': _num(margin),
                              'range_split_z': _num(z)}
            return None
        lost = b if lead is a else a   # the verdict says why it is not named
        pair_z[lost.name] = {**pair_z.get(lost.name, {}), 'range_split_by': lead.name,
                             'range_split_margin': _num(abs(margin)),
                             'range_split_z': _num(abs(z))}
        return lead

    @staticmethod
    def footprint_or_standoff(c: Candidate) -> str | None:
        """'footprint' for an effect that reaches beyond the ray (a beam's cone),
        'standoff' for one that moves the target's surfaces (``Effect.seen_target``)."""
        eff = c.effect
        if eff is None or c.variant is None:
            return None
        if eff.cast_reach_rad(1.0) is not None:
            return 'footprint'
        if type(eff).seen_target is not Effect.seen_target:
            return 'standoff'
        return None

    def adds_to(self, best: Candidate, other: Candidate) -> bool:
        """Whether ``other``, fitted on top of ``best``, still passes the rule: its
        held-out gain over ``best`` (matched and unmatched, ``total_z``) decisive and
        practical, and, both fitted on all the diagnosed points, the NLL below that of
        ``best`` alone. Then they explain different parts of the residual."""
        if best.effect is None or other.variant is None or not self.nameable(best):
            return False
        try:
            nll, explained = self.cross_fit(other.variant, [best.effect])
            d = best.heldout_nll - nll
            ok = np.isfinite(d)
            if ok.sum() < 2:
                return False
            gain, se = block_mean_se(d[ok], self.blocks[ok])
            n_m = int(ok.sum())
            total = float(np.sum(d[ok])) + UNMATCHED_NATS * explained
            z = total_z(gain, se, n_m, explained)
            if not (total >= MIN_TOTAL_GAIN and z >= self.z_crit
                    and total / max(self.n_total, 1) >= MIN_PRACTICAL_GAIN):
                return False
            both = fit_effect(other.variant, self.full, [best.effect]).effect
            after = calibrated_figures(self.full, [best.effect, both])[0]
        except Exception:  # noqa: BLE001
            return False
        return bool(np.isfinite(after) and after < best.nll_after)


def on_other_shots(best: Candidate, other: Candidate) -> bool:
    """Whether ``other``'s evidence lies on shots ``best`` does not touch: it is credited
    with at least MIN_UNMATCHED_EXPLAINED unmatched points (returns off the target model,
    ``unmatched_credit``: false returns at random ranges, say) while ``best`` is credited
    with fewer than that (a range bias moves matched points only)."""
    return bool(other.unmatched_gain_points >= MIN_UNMATCHED_EXPLAINED
                and best.unmatched_gain_points < MIN_UNMATCHED_EXPLAINED)


def is_noise_effect(effect_cls: type[Effect]) -> bool:
    """An effect that only widens the range sigma (no bias, no false returns, no ghosts,
    rays not moved): e.g. ``snr_noise``."""
    return (effect_cls.range_sigma_m is not Effect.range_sigma_m
            and effect_cls.range_bias_m is Effect.range_bias_m
            and effect_cls.cast is Effect.cast
            and effect_cls.pose_time_s is Effect.pose_time_s
            and not is_outlier_effect(effect_cls)
            and not getattr(effect_cls, 'ghost_scale', None))


def total_z(matched_gain: float, se_matched: float, n_matched: int,
            explained: float) -> float:
    """z of a held-out gain made of ``n_matched`` matched points (mean ``matched_gain``,
    block-robust standard error ``se_matched``, nats) and ``explained`` unmatched points
    credited UNMATCHED_NATS each (a count: Poisson variance)."""
    total = matched_gain * n_matched + UNMATCHED_NATS * explained
    var = (se_matched * n_matched) ** 2 + UNMATCHED_NATS ** 2 * explained
    if not (var > 0 and np.isfinite(var)):
        return 0.0
    return float(total / np.sqrt(var))


def unmatched_gain(cand: 'Candidate', n_matched: int) -> float:
    """What the returns ``cand`` puts back on the target gain, nats per matched point:
    UNMATCHED_NATS for each unmatched point credited to it (``unmatched_gain_points``,
    its own signature only). The matched points alone are not the same returns before
    and after a footprint: its weak edge returns join them, so their NLL per point rises
    for the right model; with this term the fitted footing counts the same returns as
    the score. 0 for a false-return effect (its footing is ``missed_shots_gain``)."""
    if (n_matched <= 0 or cand.effect is None or is_outlier_effect(type(cand.effect))
            or cand.unmatched_gain_points <= 0):
        return 0.0
    return float(UNMATCHED_NATS * cand.unmatched_gain_points / n_matched)


def fitted_footing(cand: 'Candidate') -> float:
    """The NLL per matched point ``cand`` gives fitted as --fit leaves it, on the footing
    of the score (all the analysed returns): the matched points' NLL (``nll_after``)
    less its gain on the missed shots (a false-return effect) or on the unmatched
    returns it puts back on the target (a footprint). ``naming_fault`` compares it with
    the model's without it; the verdict quotes it."""
    missed, back = footing_gains(cand)
    return float(cand.nll_after - missed - back)


def footing_gains(cand: 'Candidate') -> tuple[float, float]:
    """(on the missed shots, on the returns put back) nats per matched point that
    ``fitted_footing`` takes off ``nll_after``; 0 where not finite or absent."""
    missed, back = (float(getattr(cand, k, 0.0) or 0.0)
                    for k in ('missed_gain_after', 'unmatched_gain_after'))
    return (missed if np.isfinite(missed) else 0.0), (back if np.isfinite(back) else 0.0)


def per_return_nll(nll_matched: float, unmatched_fraction: float) -> float:
    """NLL per analysed return (nats): the matched points' mean, each return the model
    leaves off the target charged UNMATCHED_NATS more (the credit a candidate earns for
    putting one back). Comparable between models that match different returns, as the
    NLL per matched point is not: a footprint's weak edge returns raise that mean."""
    return float(nll_matched + UNMATCHED_NATS * unmatched_fraction)


def quotes_rmse(cand: Candidate) -> bool:
    """Whether the verdict quotes the range RMSE for ``cand`` (``verdict._gain_words``):
    an effect that moves ranges or rays. Not a false-return effect (its far outliers
    stay in the data: the robust spread is quoted) nor one that only widens the sigma
    (it moves no range)."""
    return (cand.effect is not None and not is_outlier_effect(type(cand.effect))
            and not is_noise_effect(type(cand.effect)))


def rmse_fault(cand: Candidate, before_rmse: float) -> str | None:
    """Why ``cand``, whose NLL falls, may not be named because the range RMSE the verdict
    quotes rises with it (``quotes_rmse``), or None. At the verdict's precision (0.1 mm):
    the likelihood gained by taking points the model did not place, or by widening what
    it allows, while the ranges it predicts moved away from those measured; an effect
    that is there places them better. Mixed pixels at the edges (a receiver averaging
    the echoes of the target's edge and a surface behind it) read that way as a beam
    footprint many times the configured beam (mixpix52)."""
    after = cand.range_rmse_after_m
    if not (np.isfinite(after) and np.isfinite(before_rmse) and quotes_rmse(cand)):
        return None
    if round(float(after), 4) <= round(float(before_rmse), 4):
        return None
    scale = ''
    if cand.effect is not None and cand.effect.cast_reach_rad(1.0) is not None:
        # A footprint: how far its cone is from the configured beam.
        scale = (f' (its footprint {cand.params.get("footprint_scale", float("nan")):.1f} '
                 'times the configured beam)')
    return (f'fitted as --fit leaves it{scale}, it lowers the NLL but raises the range RMSE '
            f'from {before_rmse:.4f} to {after:.4f} m: it does not place the measured ranges '
            'better, it takes points its form does not reproduce. To be named it would have '
            'to cut the range RMSE as well; it stands in for something outside the catalogue')


def naming_fault(cand: Candidate, before_nll: float,
                 before_rmse: float = float('nan')) -> str | None:
    """The one rule at the point of naming: why ``cand`` may not be named as a missing
    effect, a member of a tie or an effect explaining a separate part, or None. Its
    held-out gain (the score the verdict quotes, and its z) passes the rule (decisive,
    it matters, its signature: ``admissible``) and, fitted as --fit leaves it, the
    calibrated NLL per point it gives (``nll_after``, the "after" the verdict quotes) is
    below the model's without it (``before_nll``), with no parameter at the edge of its
    search box (``at_bound``). For a false-return effect that NLL
    takes in what it gains on the missed shots (``missed_gain_after``), and for a
    footprint what the returns it puts back on the target gain (``unmatched_gain_after``):
    the footing it is scored on, the same returns before and after, not the matched
    points alone (``fitted_footing``). Where the verdict quotes the range RMSE
    (``quotes_rmse``), it must not rise (``rmse_fault``; ``before_rmse``: the model's
    without it, NaN to skip)."""
    if cand.error is not None:
        return f'its fit failed: {cand.error}'
    if not cand.significant:
        return (f'its held-out gain ({cand.score:.4f} nats/point, z = {cand.z:.1f}) is not '
                'decisive')
    if not cand.practical:
        return (f'its held-out gain ({cand.score:.4f} nats/point) is below the '
                f'{MIN_PRACTICAL_GAIN:g} that would matter')
    if cand.vetoed:
        return cand.vetoed
    if cand.at_bound:
        return (f'fitted as --fit leaves it, {" and ".join(cand.at_bound)} ended at the edge of '
                'its search box: the data ask for more of it than the catalogue allows, so '
                'its form does not fit them; it stands in for something outside the '
                'catalogue')
    after = fitted_footing(cand)
    if not (np.isfinite(after) and np.isfinite(before_nll) and after < before_nll):
        gain, back = footing_gains(cand)
        missed = (f' ({cand.nll_after:.4f} on the matched points, {gain:+.4f} gained on '
                  'the missed shots)' if gain else
                  f' ({cand.nll_after:.4f} on the matched points, {back:+.4f} gained on '
                  'the returns it puts back on the target)' if back else '')
        return (f'fitted as --fit leaves it, the NLL per point is {after:.4f}{missed}, not '
                f'below the {before_nll:.4f} without it')
    return rmse_fault(cand, before_rmse)


def settle(decision: Decision, cands: list[Candidate],
           fault: 'Callable[[Candidate], str | None]',
           tiles: 'Callable[[Candidate, Candidate | None], str | None] | None' = None
           ) -> Decision:
    """Every name a decision carries (``missing``, ``confounded_with``, ``also``; for
    ``sunlight``, the candidate that is its ``evidence``) passes ``naming_fault`` on the
    candidates the verdict quotes (``cands``; ``fault``: ``Diagnosis.naming_fault``, which
    fits a candidate on all the diagnosed points first, or ``naming_fault`` with the
    "before" NLL), or is
    withheld (``Decision.withheld``: name -> why). A tie left with one member is no
    tie, and its last member is not promoted to missing. ``pose_error`` in a tie is
    the reference pose, judged by its own test (``judge_pose``). ``tiles``
    (``Diagnosis.tile_fault``): a per-laser name must also hold across the lasers'
    tiles where it is named (alone, or beside the named one for an 'also'), whichever
    path put it there (bend53: lasers' range offsets named for a body bent off its CAD)."""
    by_name = {c.name: c for c in cands}
    withheld = dict(decision.withheld)

    def why_not(name: str | None, beside_named: str | None = None) -> str | None:
        if name is None or name == POSE_ERROR:
            return None
        c = by_name.get(decision.evidence if name == decision.missing and decision.evidence
                        else name)
        why = ('not among the candidates' if c is None else
               None if passed_on_top_of(c, beside_named) or passed_jointly(c) else fault(c))
        if why is None and c is not None and tiles is not None:
            why = tiles(c, by_name.get(beside_named) if beside_named else None)
        if why is not None:
            withheld[name] = why
        return why

    missing = decision.missing if why_not(decision.missing) is None else None
    tied = [n for n in decision.confounded_with if why_not(n) is None]
    if len(tied) < 2 or (tied == [POSE_ERROR]):
        tied = []
    # "Also" beside a named effect, or beside the tie of the pose with a candidate
    # (``judge_pose``: it passed on the corrected pose too).
    also = (decision.also if (missing is not None or POSE_ERROR in tied)
            and why_not(decision.also, missing) is None else None)
    more = [n for n in decision.also_more if also is not None and why_not(n, missing) is None]
    return replace(decision, missing=missing, also=also, confounded_with=tied,
                   evidence=decision.evidence if missing else None, withheld=withheld,
                   also_more=more)


def passed_on_top_of(cand: Candidate, named: str | None) -> bool:
    """Whether ``cand`` passed the rule on top of the named effect ``named``, held out
    and fitted (``beside.clock_on_top``: a clock offset, whose gain alone an effect ten
    times its size swamps): its 'also' is judged on that gain, the one the verdict
    quotes for it."""
    on_top = (cand.against_pose or {}).get('beside') or {}
    return bool(named is not None and on_top.get('on_top_of') == named
                and on_top.get('gain') is not None)


def share_vetoed(cand: Candidate) -> bool:
    """Whether ``cand`` was set aside only by the share veto (``share_veto`` measures the
    share only of a candidate no earlier veto set aside)."""
    return bool(cand.vetoed and cand.share is not None and cand.share < MIN_SHARE)


def passed_jointly(cand: Candidate) -> bool:
    """Whether ``cand`` passed the rule as one of a walk and an incidence bias refitted
    together where neither may be named alone (``Diagnosis.pair_beside_nothing``)."""
    return bool((cand.jointly or {}).get('passes'))


def rank(candidates: list[Candidate]) -> list[Candidate]:
    return sorted(candidates, key=lambda c: (c.error is not None, -c.score))


def missing_effect(candidates: list[Candidate]) -> str | None:
    """The best admissible candidate's name (no tie test; ``Diagnosis.decide`` does that)."""
    ok = [c for c in rank(candidates) if c.admissible]
    return ok[0].name if ok else None


def _snippet(effect: Effect) -> str:
    to_yaml = getattr(effect, 'to_yaml_snippet', None)
    if to_yaml is not None:
        return to_yaml().strip()
    params = effect.params.model_dump() if hasattr(effect.params, 'model_dump') else {}
    inner = ', '.join(f'{k}: {v:.6g}' if isinstance(v, float) else f'{k}: {v}'
                      for k, v in params.items())
    return f'- {{name: {effect.name}, params: {{{inner}}}}}'
