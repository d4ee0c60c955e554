"""Per-laser offsets are the lasers' own (compare/diagnose/laser_tiles.py and
``Diagnosis.tile_veto``), and a per-laser candidate passes on top of a simpler one it
does not beat, not instead of it (``Diagnosis.simpler_instead``). The fits here are an
independent closed form (each laser's offset the mean of its training residuals, a
Gaussian held-out NLL), not the comparison's likelihood."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lidar_sim_ros.compare.diagnose import diagnosis as dg
from lidar_sim_ros.compare.diagnose import laser_tiles, variants
from lidar_sim_ros.compare.model import field_pattern

from test_compare_naming import Hand, cand

N_LASERS = 6
SIGMA = 0.02


def test_tile_halves_split_each_laser_at_its_own_median():
    laser = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    az = np.radians([-10, -5, 5, 10, 30, 31, 32, 33])
    el = np.radians([1, 2, 3, 4, -4, -3, -2, -1])
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    t = np.array([0.0, 0.3, 0.1, 0.2, 5.0, 5.1, 4.0, 4.1])
    h = laser_tiles.tile_halves(laser, d, t)
    assert h['azimuth'].tolist() == [False, False, True, True, False, False, True, True]
    assert h['elevation'].tolist() == [False, False, True, True, False, False, True, True]
    assert h['time'].tolist() == [False, True, False, True, True, True, False, False]
    # Each laser's halves hold half its points, whatever its tile's place.
    assert all(h[k][laser == one].sum() == 2 for k in h for one in (0, 1))


def test_per_laser_is_a_parameter_list():
    from lidar_sim_ros.core.effects import make_effect
    assert laser_tiles.per_laser(make_effect('laser_bias', {'offsets_m': [0.01, -0.01]}))
    assert not laser_tiles.per_laser(make_effect('range_walk', {'k_m': 0.01}))
    assert not laser_tiles.per_laser(object())


def _recording(pattern_m: float, seed: int):
    """Six lasers, each a 10 deg tile side by side in azimuth, 2000 points each; a true
    offset per laser (sd 1 cm) plus a range error growing across the field in azimuth
    (``pattern_m`` per radian: a target off its CAD), Gaussian noise 2 cm."""
    rng = np.random.default_rng(seed)
    laser = np.repeat(np.arange(N_LASERS), 2000)
    az = np.radians(10.0 * laser + rng.uniform(-5, 5, len(laser)))
    el = np.radians(rng.uniform(-5, 5, len(laser)))
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    t = rng.uniform(0.0, 0.8, len(laser))
    offsets = rng.normal(0.0, 0.01, N_LASERS)
    residual = (offsets[laser] + pattern_m * np.sin(6.0 * az)
                + rng.normal(0.0, SIGMA, len(laser)))
    return SimpleNamespace(laser=laser, directions=d, t_s=t), residual


def _field_nll(residual, meas, train, test):
    """Held-out Gaussian NLL on ``test`` of a quadratic surface over the pointing (az, el)
    fitted on ``train`` (``field_pattern``, with its constant)."""
    d = meas.directions
    az, el = np.arctan2(d[:, 1], d[:, 0]), np.arcsin(np.clip(d[:, 2], -1, 1))
    x = np.column_stack([np.ones(len(az)), az, el, az * az, az * el, el * el])
    a, *_ = np.linalg.lstsq(x[train], residual[train], rcond=None)
    r = residual[test] - x[test] @ a
    return 0.5 * (r / SIGMA) ** 2 + np.log(SIGMA * np.sqrt(2 * np.pi))


def _held_out(variant, residual, meas, one):
    """``cross_fit``'s order (fold 1 scored, then fold 0): per-laser means, or the
    field's surface for ``field_pattern``."""
    if variant is field_pattern.FieldPattern:
        return np.concatenate([_field_nll(residual, meas, ~one, one),
                               _field_nll(residual, meas, one, ~one)])
    return np.concatenate([_nll(residual, meas.laser, ~one, one),
                           _nll(residual, meas.laser, one, ~one)])


def _nll(residual, laser, train, test):
    """Held-out Gaussian NLL on ``test`` of per-laser means fitted on ``train``."""
    off = np.array([residual[train & (laser == k)].mean() for k in range(N_LASERS)])
    r = residual[test] - off[laser[test]]
    return 0.5 * (r / SIGMA) ** 2 + np.log(SIGMA * np.sqrt(2 * np.pi))


class Splits(Hand):
    """A diagnosis of ``residual`` (every point matched) whose split tests (``Diagnosis.
    worst_transfer``) the subclass scores in closed form (``transfer_nll``)."""

    def __init__(self, residual, seed=0, meas=None):
        super().__init__()
        n = len(residual)
        self.rays = SimpleNamespace(matched=np.arange(n), unmatched=np.arange(0), meas=meas,
                                    _with=lambda m, u: SimpleNamespace(matched=m))
        self.n_total = n
        self.residual = residual
        order = np.random.default_rng(seed).permutation(n) % 2
        self.random_fold = order
        self.fold_order = np.concatenate([np.flatnonzero(order == 1), np.flatnonzero(order == 0)])
        self.matched_blocks = np.arange(n) // 20
        self.blocks = self.matched_blocks[self.fold_order]     # cross_fit order
        self._z_crit = 3.0


class Tiles(Splits):
    """A diagnosis of one recording's per-laser residuals, fitted in closed form."""

    def __init__(self, meas, residual, seed=0):
        super().__init__(residual, seed, meas)

    def transfer_nll(self, variant, halves, on_top=()):
        out = np.full(self.n_total, np.nan)
        for k, h in enumerate(halves):
            test = np.zeros(self.n_total, bool)
            test[h.matched] = True
            out[test] = _nll(self.residual, self.rays.meas.laser, ~test, test)
        return out

    def cross_fit(self, variant, on_top, first=None):
        return _held_out(variant, self.residual, self.rays.meas, self.random_fold == 1), 0.0

    def laser_candidate(self):
        c = dg.Candidate('laser_bias', n_params=N_LASERS)
        c.effect = SimpleNamespace(params=SimpleNamespace(
            model_dump=lambda: {'offsets_m': [0.0] * N_LASERS}))
        c.variant = object
        laser = self.rays.meas.laser
        one = self.random_fold == 1
        held = np.concatenate([_nll(self.residual, laser, ~one, one),
                               _nll(self.residual, laser, one, ~one)])
        c.heldout_nll = held
        return c


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_lasers_own_offsets_hold_across_its_tile(seed):
    d = Tiles(*_recording(0.0, seed), seed)
    assert d.tile_veto(d.laser_candidate()) is None


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_pattern_across_the_tiles_is_not_the_lasers(seed):
    """A 2 cm range error varying across each tile in azimuth (the lasers' own offsets
    beside it): fitted on one azimuth half of each tile, the offsets miss the other."""
    d = Tiles(*_recording(0.02, seed), seed)
    why = d.tile_veto(d.laser_candidate())
    assert why is not None and 'in azimuth' in why and 'not the lasers' in why


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_pattern_smooth_across_the_field_is_not_the_lasers(seed):
    """The nineteenth holdout's sunlit faces: a range error growing smoothly across the
    field (2 cm per radian of azimuth, no laser's own offset). Each tile sees so little
    of it that the split test passes, while the lasers' offsets take it at their tiles'
    centres; over a surface smooth across the field they gain nothing: not the lasers."""
    meas, _ = _recording(0.0, seed)
    az = np.arctan2(meas.directions[:, 1], meas.directions[:, 0])
    rng = np.random.default_rng(100 + seed)
    d = Tiles(meas, 0.02 * az + rng.normal(0.0, SIGMA, len(az)), seed)
    lasers = d.laser_candidate()
    why = d.tile_veto(lasers)
    assert why is not None and 'smooth across the field' in why
    assert lasers.tile_test['field']['passes'] is False
    assert 'split' not in lasers.tile_test          # the split test alone passed
    # The lasers' own offsets (sd 1 cm) beside the same gradient: their own part passes.
    meas, residual = _recording(0.0, seed)
    d = Tiles(meas, residual + 0.02 * az, seed)
    lasers = d.laser_candidate()
    assert d.tile_veto(lasers) is None and lasers.tile_test['field']['passes']


class Beside(Tiles):
    """The lasers' offsets beside a pattern on the target that a named effect (a walk
    over the target's intensities) accounts for: with it in the model (``on_top``),
    ``removed`` is gone from the residual."""

    def __init__(self, meas, residual, removed, seed=0):
        super().__init__(meas, residual, seed)
        self.removed = removed
        self.on_top = {('range_walk', 'laser_bias'): True}

    def _residual(self, on_top):
        return self.residual - self.removed if on_top else self.residual

    def _fitted_together(self, effects):
        return list(effects)       # the named effect's fit is already its joint one

    def transfer_nll(self, variant, halves, on_top=()):
        out = np.full(self.n_total, np.nan)
        for h in halves:
            test = np.zeros(self.n_total, bool)
            test[h.matched] = True
            out[test] = _nll(self._residual(on_top), self.rays.meas.laser, ~test, test)
        return out

    def cross_fit(self, variant, on_top, first=None):
        return _held_out(variant, self._residual(on_top), self.rays.meas,
                         self.random_fold == 1), 0.0


def _pattern(meas, size_m):
    az = np.arctan2(meas.directions[:, 1], meas.directions[:, 0])
    return size_m * np.sin(6.0 * az)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_the_lasers_beside_a_named_effect_are_tried_with_it_in_the_model(seed):
    """A 2 cm pattern across the tiles (the named walk's, over the target) beside the
    lasers' own offsets: alone the tile test sets the lasers aside; with the walk in
    the model their offsets hold across the tiles, so they are 'also', their veto
    lifted (holdout 8: range_walk + laser_bias + snr_noise named the walk and said of
    the real offsets 'not the lasers')."""
    meas, residual = _recording(0.02, seed)
    d = Beside(meas, residual, _pattern(meas, 0.02), seed)
    laser = d.laser_candidate()
    laser.vetoed = d.tile_veto(laser)
    laser.tile_vetoed = laser.vetoed is not None
    assert laser.tile_vetoed
    walk = _one('range_walk', 0.030, -2.058, seed=seed)
    decision = d.decide([walk, laser])
    assert decision.missing == 'range_walk' and decision.also == 'laser_bias'
    assert laser.vetoed is None and not laser.tile_vetoed and laser.beside == 'range_walk'
    # Decided again (rivals weighed): the lasers stay 'also', though alone they are
    # decisively worse than the walk.
    assert d.decide([walk, laser]).also == 'laser_bias'


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_pattern_the_named_effect_leaves_keeps_the_lasers_set_aside(seed):
    """The walk takes only a fifth of the pattern: with it in the model the offsets
    still follow the target, so the veto stands and nothing is 'also'."""
    meas, residual = _recording(0.02, seed)
    d = Beside(meas, residual, _pattern(meas, 0.004), seed)
    laser = d.laser_candidate()
    laser.vetoed = d.tile_veto(laser)
    laser.tile_vetoed = True
    walk = _one('range_walk', 0.030, -2.058, seed=seed)
    decision = d.decide([walk, laser])
    assert decision.missing == 'range_walk' and decision.also is None
    assert laser.vetoed is not None


def _laser(gain, nll_after, seed):
    c = cand('laser_bias', gain, nll_after, seed=seed)
    c.n_params = 24
    c.effect = SimpleNamespace(name='laser_bias', params=SimpleNamespace(
        model_dump=lambda: {'offsets_m': [0.0] * 24}))
    return c


def _one(name, gain, nll_after, seed):
    c = cand(name, gain, nll_after, seed=seed)
    c.n_params = 1
    return c


def test_a_per_laser_candidate_passes_on_top_of_the_simpler_one_it_does_not_beat():
    """laser_bias ahead of range_walk by 0.002 nats/point held out (not decisive, and
    less than the margin as fitted): it must pass on top of the walk, and then the walk
    is named and laser_bias is 'also'; if it does not add to the walk, they explain the
    same residual: a tie, not laser_bias."""
    laser = _laser(0.032, -2.060, seed=10)
    walk = _one('range_walk', 0.030, -2.058, seed=10)
    d = Hand(on_top={('range_walk', 'laser_bias'): True}).decide(dg.rank([laser, walk]))
    assert d.missing == 'range_walk' and d.also == 'laser_bias' and d.confounded_with == []
    d = Hand().decide(dg.rank([laser, walk]))
    assert d.missing is None and sorted(d.confounded_with) == ['laser_bias', 'range_walk']


def test_a_per_laser_candidate_decisively_better_stays_named():
    laser = _laser(0.060, -2.090, seed=11)
    walk = _one('range_walk', 0.030, -2.058, seed=11)
    d = Hand(on_top={('range_walk', 'laser_bias'): True}).decide(dg.rank([laser, walk]))
    assert d.missing == 'laser_bias'


def test_a_scalar_best_is_not_replaced_by_a_simpler_one():
    """The parsimony applies to per-laser candidates only: two scalar effects close
    together keep the ordinary decision (a tie here)."""
    inc = _one('incidence_angle', 0.032, -2.060, seed=12)
    inc.n_params = 2
    walk = _one('range_walk', 0.030, -2.058, seed=12)
    d = Hand(on_top={('range_walk', 'incidence_angle'): True}).decide(dg.rank([inc, walk]))
    assert d.missing is None and sorted(d.confounded_with) == ['incidence_angle', 'range_walk']


# ------------------------------------------------ a half whose lasers are poorly linked
def test_offset_information_is_the_least_squares_precision():
    """The lasers' information with the materials' intercepts profiled out
    (``laser_tiles.offset_information``) gives each contrast of the offsets the variance
    of a plain least-squares fit of ``offset[laser] + intercept[material]`` (an
    independent calculation: the full design's pseudo-inverse)."""
    rng = np.random.default_rng(3)
    cells = rng.uniform(0.0, 50.0, (5, 3)) * (rng.uniform(size=(5, 3)) > 0.3)
    cells[:, 0] += 1.0                                 # every laser sees material 0
    n_l, n_m = cells.shape
    x, w = [], []
    for la in range(n_l):
        for m in range(n_m):
            row = np.zeros(n_l + n_m)
            row[la], row[n_l + m] = 1.0, 1.0
            x.append(row)
            w.append(cells[la, m])
    x, w = np.array(x), np.array(w)
    full_cov = np.linalg.pinv((x * w[:, None]).T @ x)[:n_l, :n_l]
    cov = np.linalg.pinv(laser_tiles.offset_information(cells))
    for _ in range(5):
        c = rng.normal(size=n_l)
        c -= c.mean()
        assert c @ cov @ c == pytest.approx(c @ full_cov @ c, rel=1e-9)


def _weak_half_cells(link: float) -> tuple[np.ndarray, np.ndarray]:
    """Six lasers on two materials (weights per cell): in one half lasers 0-2 see only
    material 0 and lasers 3-5 only material 1, but for ``link`` of laser 2 on material 1;
    in the other half every laser sees both."""
    weak = np.zeros((6, 2))
    weak[:3, 0] = weak[3:, 1] = 500.0
    weak[2, 1] = link
    return weak, np.full((6, 2), 250.0)


def test_a_half_whose_laser_groups_share_a_material_through_few_points_leaves_their_level():
    weak, linked = _weak_half_cells(5.0)
    free = laser_tiles.poorly_linked(weak, linked)
    assert free.shape == (6, 1)
    level = free[:, 0]
    # The groups' relative level: the same within each group (but laser 2, which holds
    # the link), opposite across.
    assert np.ptp(level[3:]) < 1e-6 and abs(level[0] - level[1]) < 1e-6
    assert np.sign(level[0]) == -np.sign(level[3]) and np.sign(level[2]) == np.sign(level[0])
    # The well-linked half determines everything, as does a random half, and a half with
    # fewer points on the same links (60 % of a random half's) is not poor.
    assert laser_tiles.poorly_linked(linked, weak).shape[1] == 0
    assert laser_tiles.poorly_linked(1.1 * linked, 0.9 * linked).shape[1] == 0
    assert laser_tiles.poorly_linked(0.6 * linked, 1.4 * linked).shape[1] == 0
    assert laser_tiles.poorly_linked(None, linked) is None


def test_poorly_linked_ignores_lasers_without_points_and_empty_halves():
    weak, linked = _weak_half_cells(5.0)
    gap = [np.insert(c, 3, 0.0, axis=0) for c in (weak, linked)]   # laser 3: no point
    free = laser_tiles.poorly_linked(*gap)
    assert free.shape == (7, 1) and free[3, 0] == 0.0
    assert np.allclose(np.delete(free, 3, axis=0), laser_tiles.poorly_linked(weak, linked))
    assert laser_tiles.poorly_linked(np.zeros((0, 0)), np.zeros((0, 0))).shape == (0, 0)
    # A half with no points determines no contrast of the six lasers' offsets.
    assert laser_tiles.poorly_linked(np.zeros((0, 0)), linked).shape == (6, 5)


N_HALF = 6 * 2 * 250


def _half(residual_m, laser, material, sigma_m=SIGMA):
    """FitData of matched points at 10 m with a known residual, laser and material."""
    from lidar_sim_ros.compare.model import likelihood as lk
    from lidar_sim_ros.core.effects import ReturnContext
    from lidar_sim_ros.core.geometry import Hits
    from lidar_sim_ros.core.pipeline import Prediction
    n = len(residual_m)
    rng_m, one = np.full(n, 10.0), np.ones(n)
    ctx = ReturnContext(range_m=rng_m, incidence_rad=0 * one, material=material,
                        power_w=one, intensity=one, t_s=0 * one, az_rad=0 * one,
                        el_rad=0 * one, laser=laser, divergence_rad=1e-3,
                        hit=np.ones(n, bool), threshold_power_w=0.1)
    hits = Hits(np.ones(n, bool), rng_m, np.zeros((n, 3)), 0 * one, material,
                np.zeros(n, int))
    pred = Prediction(ctx, hits, np.tile([1.0, 0, 0], (n, 1)), 0 * one, sigma_m * one)
    return lk.FitData(measured_range_m=rng_m + residual_m, baseline=pred,
                      cast=lambda e: pred, unmatched_range_m=np.zeros(0),
                      cast_unmatched=lambda e: pred, range_window_m=(5.0, 15.0))


def _two_halves(seed: int, link: int, pattern_m: float = 0.0):
    """Points of six lasers (true offsets sd 3 cm, each material its own intercept) in
    two halves of each tile: in the first, lasers 0-2 see material 0 and 3-5 material 1,
    linked through ``link`` points of laser 2 on material 1; in the second every laser
    sees both. ``pattern_m``: a range error of the target that differs between the
    halves of lasers 0 and 3 (a pattern the tiles cut up). Returns the halves'
    (residual, laser, material) and the same points split at random."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(0.0, 0.03, 6)
    intercept = np.array([0.01, -0.02])
    weak_l = np.repeat(np.arange(6), 500)
    weak_m = (weak_l >= 3).astype(int)
    weak_l = np.concatenate([weak_l, np.full(link, 2)])
    weak_m = np.concatenate([weak_m, np.ones(link, int)])
    linked_l = np.repeat(np.arange(6), 500)
    linked_m = np.tile(np.repeat([0, 1], 250), 6)
    parts = []
    for k, (la, m) in enumerate(((weak_l, weak_m), (linked_l, linked_m))):
        r = offsets[la] + intercept[m] + rng.normal(0.0, SIGMA, len(la))
        r += np.where(np.isin(la, (0, 3)), pattern_m * (1 if k else -1), 0.0)
        parts.append((r, la, m))
    together = [np.concatenate(v) for v in zip(*parts)]
    pick = rng.permutation(len(together[0])) % 2 == 0
    at_random = [tuple(v[side] for v in together) for side in (pick, ~pick)]
    return parts, at_random


def _loss(parts, at_random, free_level: bool = True) -> float:
    """What the lasers' offsets fitted on one half and scored on the other lose against
    fitted on a random half and scored on the other (nats per point, both ways);
    ``free_level`` False: scored as fitted (the old transfer)."""
    from lidar_sim_ros.compare.model.fit import fit_effect
    from lidar_sim_ros.core.effects.laser_bias import LaserBias

    def both_ways(halves):
        data = [_half(*h) for h in halves]
        if free_level:
            return np.concatenate(variants.transfer_both_ways(LaserBias, data))
        return np.concatenate([variants.heldout_nll(data[k], [fit_effect(LaserBias, data[1 - k]).effect])
                               for k in range(2)])
    n = sum(len(p[0]) for p in parts)
    return float((both_ways(parts).sum() - both_ways(at_random).sum()) / n)


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_a_groups_level_a_half_leaves_loose_is_not_held_against_the_lasers(seed):
    """Pure offsets per laser, but one half links its two groups of lasers through two
    points (the materials' intercepts take the groups' level there, as the azimuth halves
    of the ninth holdout's walk+laser+bg_101 and the eleventh's laser_1 do): scored as
    fitted the transfer loses the groups' level guessed from two points (past the
    rule's margin on these seeds); with that level taken on the scored half it loses
    nothing against a random half (the halves' own scoring differs by up to 0.001
    nats/point with the true offsets)."""
    parts, at_random = _two_halves(seed, link=2)
    assert _loss(parts, at_random, free_level=False) > dg.MIN_PRACTICAL_GAIN
    assert _loss(parts, at_random) < 0.2 * dg.MIN_PRACTICAL_GAIN


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_pattern_the_tiles_cut_up_still_loses_beside_a_loose_level(seed):
    """The same halves with a range error 1.2 cm apart between the halves of two lasers of
    different groups (a pattern on the target): the level left free does not take it,
    the transfer still loses past the margin."""
    parts, at_random = _two_halves(seed, link=2, pattern_m=0.006)
    assert _loss(parts, at_random) > dg.MIN_PRACTICAL_GAIN


# ------------------------------------- the lasers beside the named effect and its 'also'
class BesideTwo(Beside):
    """``Beside`` where the pattern is the named effect's and its 'also''s together:
    their joint fit is the effects themselves, and the lasers' gain on top of them the
    closed-form held-out gain of per-laser means on the residual they leave."""

    def _fitted_together(self, effects):
        return list(effects)

    def _on_top(self, on_top, other):
        res, laser = self._residual(on_top), self.rays.meas.laser
        one = self.random_fold == 1
        fitted = np.concatenate([_nll(res, laser, ~one, one), _nll(res, laser, one, ~one)])
        r = np.concatenate([res[one], res[~one]])
        d = 0.5 * (r / SIGMA) ** 2 + np.log(SIGMA * np.sqrt(2 * np.pi)) - fitted
        gain, se = dg.block_mean_se(d, self.matched_blocks)
        return gain, gain / se, fitted


def _named(name):
    c = _one(name, 0.4, -3.2, seed=5)
    c.effect = SimpleNamespace(name=name, params=SimpleNamespace(model_dump=lambda: {'p': 0.0}))
    return c


@pytest.mark.parametrize('size_m, passes', [(0.02, True), (0.004, False)])
def test_lasers_set_aside_hold_beside_the_named_effect_and_its_also(size_m, passes):
    """The eleventh holdout's walk_solar_laser: false returns named, the walk 'also', and
    the lasers' real offsets set aside by the tile test for the walk's pattern. With
    both in the model the offsets hold across the tiles and still gain: recorded as
    passing beside them, for the verdict's 'expect it once they are fitted' (never
    named); where the named effects take a fifth of the pattern only, nothing is."""
    from lidar_sim_ros.compare.report.verdict import set_aside_words
    meas, residual = _recording(0.02, 0)
    d = BesideTwo(meas, residual, _pattern(meas, size_m), 0)
    laser = d.laser_candidate()
    laser.vetoed = d.tile_veto(laser)
    laser.tile_vetoed, laser.significant, laser.practical = True, True, True
    assert laser.vetoed is not None
    cands = [_named('solar_background'), _named('range_walk'), laser]
    d.lasers_beside_named(dg.Decision('solar_background', [], 'range_walk'), cands)
    words = set_aside_words(laser)
    assert laser.vetoed is not None                      # never named here
    if passes:
        assert laser.beside == 'solar_background and range_walk'
        assert laser.beside_gain['z'] > d.z_crit
        assert 'expect it once they are fitted' in words
        assert '--effect solar_background --effect range_walk --fit' in words
    else:
        assert laser.beside is None and 'is not the missing effect' in words


# ------------------------------- the lasers beside a named effect fitted with them
class AloneOrJoint(Beside):
    """The lasers beside a named walk whose fit alone took part of the lasers' offsets
    (where the lasers' ranges follow the intensity): in the model the walk removes
    ``takes`` of its pattern from the residual, ``alone`` as fitted without the lasers
    and ``joint`` refitted together with them (``_fitted_together``)."""

    def __init__(self, meas, residual, pattern, joint, seed=0):
        super().__init__(meas, residual, pattern, seed)
        self.joint = joint
        self.refits = []

    def _residual(self, on_top):
        return self.residual - sum(getattr(e, 'takes', 0.0) for e in on_top) * self.removed

    def _fitted_together(self, effects):
        self.refits.append(list(effects))
        return [SimpleNamespace(name=e.name, takes=self.joint) for e in effects[:-1]] + \
            [effects[-1]]


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('joint, held', [(1.0, True), (1.5, False)])
def test_the_lasers_are_tested_beside_the_named_effect_fitted_with_them(seed, joint, held):
    """The twelfth holdout's walk_laser: a walk fitted with the lasers unmodelled comes
    out high (k 0.0379 for 0.0331) and leaves its own error's pattern over the target,
    which the tiles cut up, so beside it the lasers were still set aside. Beside the
    walk refitted together with them the pattern is gone and their offsets hold; where
    the joint fit leaves the same pattern (a pattern the walk does not explain), the
    veto stands."""
    meas, residual = _recording(0.0, seed)
    pattern = _pattern(meas, 0.02)
    d = AloneOrJoint(meas, residual + pattern, pattern, joint, seed)
    laser = d.laser_candidate()
    alone = SimpleNamespace(name='range_walk', takes=1.5)
    # As fitted alone the walk leaves half its pattern with the other sign: set aside.
    d_alone = AloneOrJoint(meas, residual + pattern, pattern, 1.5, seed)
    assert d_alone.tile_veto(d_alone.laser_candidate(), [alone]) is not None
    why = d.tile_veto(laser, [alone])
    assert d.refits[0][0] is alone and d.refits[0][1] is laser.effect   # refitted together
    assert (why is None) == held


@pytest.mark.parametrize('seed', [0, 1])
def test_the_lasers_are_tried_beside_a_range_term_named_on_the_poses_footing(seed):
    """The twelfth holdout's rscale_laser_1: a range scale named after ``decide`` ran
    (weighed against the pose, ``weigh_pose_rivals``), the lasers' real offsets set aside
    for its pattern within the tiles. They are tried beside it as beside any named
    effect: 'also'. A name ``decide`` gave already had its try (not asked again), and an
    'also' given stays."""
    meas, residual = _recording(0.02, seed)
    d = Beside(meas, residual, _pattern(meas, 0.02), seed)
    d.on_top[('range_scale', 'laser_bias')] = True
    laser = d.laser_candidate()
    laser.vetoed = d.tile_veto(laser)
    laser.tile_vetoed = laser.vetoed is not None
    assert laser.tile_vetoed
    scale = _one('range_scale', 0.16, -1.745, seed=seed)
    named = dg.Decision('range_scale', [], None, {})
    kept = d.lasers_beside_rival(named, named, [scale, laser])
    assert kept.also is None and laser.tile_vetoed          # decide's own name: tried there
    other = dg.Decision('range_scale', [], 'range_drift', {})
    assert d.lasers_beside_rival(dg.Decision(None, [], None, {}), other,
                                 [scale, laser]).also == 'range_drift'
    after = d.lasers_beside_rival(dg.Decision(None, [], None, {}), named, [scale, laser])
    assert after.missing == 'range_scale' and after.also == 'laser_bias'
    assert laser.vetoed is None and laser.beside == 'range_scale'


# --------------------------- lasers' pointing against an 'also' and the lasers' offsets
class PointingOrOffsets(Hand):
    """Lasers' pointing named, an incidence bias 'also', and the lasers' range offsets
    set aside by the tile test: ``held`` whether the offsets hold across the tiles
    beside the incidence bias, ``pointing_on_top`` the pointing's (gain, z) on top of
    the two fitted together."""

    def __init__(self, held, pointing_on_top):
        super().__init__(on_top={('incidence_angle', 'laser_bias'): True})
        self.held, self.pointing_on_top = held, pointing_on_top
        self.asked = []

    def tile_veto(self, cand, on_top=()):
        self.asked.append((cand.name, [e.name for e in on_top]))
        return None if self.held else 'a pattern on the target'

    def _fitted_together(self, effects):
        return list(effects)

    def _on_top(self, on_top, other):
        gain, z = self.pointing_on_top
        return gain, z, None


def _pointing_case(held, pointing_on_top):
    from lidar_sim_ros.compare.model import pointing
    d = PointingOrOffsets(held, pointing_on_top)
    point = _one('laser_pointing', 0.438, -1.780, seed=1)
    point.variant, point.n_params = pointing.LaserPointing, 48
    incid = _one('incidence_angle', 0.385, -1.70, seed=2)
    laser = _laser(0.155, -1.60, seed=3)
    laser.variant = object
    laser.vetoed, laser.tile_vetoed = 'a pattern on the target', True
    decision = dg.Decision('laser_pointing', [], 'incidence_angle', {})
    return d, point, laser, d.offsets_beside_also(decision, [point, incid, laser])


def test_pointing_that_adds_nothing_beside_the_also_and_the_offsets_is_set_aside():
    """The twelfth holdout's laser_incid_1: lasers' pointing (48 parameters) named for an
    incidence bias and per-laser range offsets; beside the incidence bias the offsets
    hold across the tiles, and on top of the two fitted together the pointing gains
    -0.020 nats/point (z -4.8): the incidence bias is named, the offsets its 'also'."""
    d, point, laser, out = _pointing_case(True, (-0.020, -4.8))
    assert out.missing == 'incidence_angle' and out.also == 'laser_bias'
    assert ('laser_bias', ['incidence_angle']) in d.asked
    assert laser.vetoed is None and laser.beside == 'incidence_angle'
    assert 'stand for incidence_angle and laser_bias' in point.vetoed
    assert out.pair_z['laser_pointing']['on_top_of'] == ['incidence_angle', 'laser_bias']


@pytest.mark.parametrize('held, on_top', [(True, (0.05, 10.0)), (False, (-0.02, -4.8))])
def test_pointing_stays_named_where_it_passes_on_top_or_the_offsets_do_not_hold(held, on_top):
    """Pointing that still passes the rule on top of the 'also' and the offsets (the
    tenth holdout's real pointing), or offsets that do not hold across the tiles beside
    the 'also' (a pattern on the target): the decision stands."""
    d, point, laser, out = _pointing_case(held, on_top)
    assert out.missing == 'laser_pointing' and out.also == 'incidence_angle'
    assert point.vetoed is None and laser.tile_vetoed
