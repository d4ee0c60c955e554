"""A named effect against a rival the rule keeps from naming that explains the same part
(``Diagnosis.rival_takes``, ``same_part``): the walk_graze runs' step 1 (per-laser offsets
fitted, a walk on the power at grazing incidence), where incidence_angle (z 8.3) was named
beside a walk of the same held-out gain whose z (2.7) was not decisive. Hand-made
candidates whose held-out NLLs and on-top figures are given (the decision's arithmetic,
not a dataset)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from lidar_sim_ros.compare.diagnose import diagnosis as dg
from lidar_sim_ros.compare.diagnose import same_part
from lidar_sim_ros.compare.report import verdict as vd
from lidar_sim_ros.core.effects import get_effect_class, make_effect

N = 12000
BEFORE_NLL = -2.022
WALK = {'k_m': 0.033, 'power': 'model'}
INCIDENCE = {'bias_gain': 0.75, 'sigma_gain': 0.15}


class OnTop(dg.Diagnosis):
    """A diagnosis of N matched points whose candidates come fitted; ``on_top[(other,
    base)]``: ``other``'s held-out gain and z on top of ``base`` (the lasers in the model
    already); ``asked``: the on-top figures asked for."""

    def __init__(self, on_top, set_aside=()):
        self.rays = SimpleNamespace(matched=np.arange(N), unmatched=np.arange(0))
        self.n_total = N
        self.blocks = np.arange(N) // 20
        self._z_crit = 3.4
        self._before_nll = BEFORE_NLL
        self.on_top, self.aside, self.asked = on_top, list(set_aside), []

    def finalize(self, cand):
        raise AssertionError('the hand-made candidates come fitted')

    def adds_to(self, best, other):
        return False

    def set_aside_beside(self, best, cands, but=()):
        return [c for c in self.aside if c.name not in but]

    def _fitted_together(self, effects):
        return list(effects)

    def _on_top(self, on_top, other):
        key = (other.name, on_top[0].name)
        self.asked.append(key)
        gain, z = self.on_top[key]
        return gain, z, other.heldout_nll


def cand(name, params, gain, z, nll_after, seed, vetoed=None, share=None):
    """A candidate gaining ``gain`` nats per point held out (the same points' noise for
    every seed: two candidates of one gain are level, block by block)."""
    rng = np.random.default_rng(seed)
    base = np.random.default_rng(0).normal(0.0, 1.0, N)
    c = dg.Candidate(name, score=gain, matched_gain=gain, z=z, significant=z >= 3.4,
                     practical=gain >= dg.MIN_PRACTICAL_GAIN, nll_after=nll_after,
                     vetoed=vetoed, share=share, n_params=len(params))
    c.heldout_nll = base - gain + rng.normal(0.0, 0.3, N)
    c.effect, c.variant = make_effect(name, params), get_effect_class(name)
    return c


def test_walk_and_incidence_that_neither_passes_on_top_of_the_other_name_nothing():
    """walk_graze s1 step 1: incidence 0.0218 (z 8.3), the walk 0.0212 (z 2.7, not
    decisive). Neither passes the rule on top of the other: incidence is withheld, nothing
    is named, and the verdict says which two cannot be told (before: incidence named)."""
    inc = cand('incidence_angle', INCIDENCE, 0.0218, 8.3, -2.045, 1)
    walk = cand('range_walk', WALK, 0.0212, 2.7, -2.044, 2)
    diag = OnTop({('incidence_angle', 'range_walk'): (0.0012, 1.1),
                  ('range_walk', 'incidence_angle'): (0.0009, 0.6)})
    d = dg.settle(diag.decide(dg.rank([inc, walk])), [inc, walk], diag.naming_fault)
    assert d.missing is None and d.confounded_with == [] and d.also is None
    assert 'cannot tell which of the two' in d.withheld['incidence_angle']
    assert 'not decisive' in d.withheld['incidence_angle']
    fig = d.pair_z['range_walk']['same_part']
    assert fig['outcome'] == same_part.TIE and fig['of'] == 'incidence_angle'
    assert fig['named_on_top'] == [0.0012, 1.1] and fig['rival_on_top'] == [0.0009, 0.6]
    text = vd.verdict({'materials': {}, 'unmatched': {'points': 0}, 'withheld': d.withheld,
                       'against_named': d.pair_z,
                       'nll_calibrated': BEFORE_NLL}, None, [inc, walk], d)
    assert 'is not named: range_walk explains the same part' in text
    assert 'outside the catalogue' not in text and 'would separate them' in text


def test_a_rival_that_explains_all_the_named_one_does_and_more_withholds_it():
    """walk_graze s7 step 1: the walk set aside by its share (16 %) but passing the rule
    on top of incidence, incidence not on top of it: incidence is withheld; the walk is
    not named by this (its share still keeps it)."""
    inc = cand('incidence_angle', INCIDENCE, 0.0271, 10.0, -2.05, 1)
    walk = cand('range_walk', WALK, 0.0290, 9.0, -2.049, 2, share=0.16,
                vetoed='it explains only 16 % of the residual\'s dependence on intensity')
    diag = OnTop({('incidence_angle', 'range_walk'): (0.0010, 0.9),
                  ('range_walk', 'incidence_angle'): (0.0090, 7.5)})
    d = dg.settle(diag.decide(dg.rank([inc, walk])), [inc, walk], diag.naming_fault)
    assert d.missing is None and d.confounded_with == []
    assert 'explains all it explains and more' in d.withheld['incidence_angle']
    assert d.pair_z['range_walk']['same_part']['outcome'] == same_part.RIVAL
    # The walk, set aside, ranks first; the verdict says why incidence is not named.
    text = vd.verdict({'materials': {}, 'unmatched': {'points': 0}, 'withheld': d.withheld,
                       'against_named': d.pair_z, 'nll_calibrated': BEFORE_NLL},
                      None, dg.rank([inc, walk]), d)
    assert 'incidence_angle gains 0.0271 nats/point held out (z = 10.0) and is not named' in text


def test_the_named_one_passing_on_top_of_the_rival_stays_named():
    """The walk named (z 11) beside an incidence elongation that is not decisive alone:
    on top of the incidence, fitted with the lasers set aside, the walk still passes the
    rule, so it is named as before; the lasers are in both models."""
    walk = cand('range_walk', WALK, 0.0400, 11.0, -2.06, 2)
    inc = cand('incidence_angle', INCIDENCE, 0.0390, 3.0, -2.058, 1)
    lasers = cand('laser_bias', {'offsets_m': [0.01, -0.01, 0.02, -0.02]}, 0.05, 20.0, -2.07,
                  3, share=0.2, vetoed='it explains only 20 % of the residual\'s dependence')
    diag = OnTop({('range_walk', 'incidence_angle'): (0.0150, 8.0),
                  ('incidence_angle', 'range_walk'): (0.0010, 0.5)}, set_aside=[lasers])
    d = dg.settle(diag.decide(dg.rank([lasers, walk, inc])), [lasers, walk, inc],
                  diag.naming_fault)
    assert d.missing == 'range_walk' and 'range_walk' not in d.withheld
    assert diag.asked == [('range_walk', 'incidence_angle')]
    assert d.pair_z['incidence_angle']['same_part']['with'] == ['laser_bias']


def test_a_rival_decisively_worse_is_not_weighed_and_a_per_laser_one_never():
    """A rival the named one beats by decide's rule (paired z and the fitted margin) is
    not weighed on top; per-laser offsets never are (they pass beside, as 'also')."""
    inc = cand('incidence_angle', INCIDENCE, 0.0300, 10.0, -2.06, 1)
    walk = cand('range_walk', WALK, 0.0100, 2.0, -2.03, 2)
    lasers = cand('laser_bias', {'offsets_m': [0.01, -0.01, 0.02, -0.02]}, 0.0290, 2.0,
                  -2.059, 3)
    diag = OnTop({})
    d = diag.decide(dg.rank([inc, walk, lasers]))
    assert d.missing == 'incidence_angle' and diag.asked == []
    assert same_part.rivals_of(inc, [inc, walk, lasers], diag.nameable,
                               lambda e: isinstance(e.params.model_dump().get('offsets_m'),
                                                    list),
                               lambda e: True, dg.MIN_SHARE, dg.MIN_TOTAL_GAIN, N) == [walk]


def test_outcome_closed_form():
    def passes(gain, z):
        return gain >= 0.005 and z >= 3.4
    assert same_part.outcome((0.01, 5.0), (0.01, 5.0), passes) == same_part.NAMED
    assert same_part.outcome((0.01, 2.0), (0.01, 5.0), passes) == same_part.RIVAL
    assert same_part.outcome((0.004, 9.0), (0.01, 3.0), passes) == same_part.TIE
