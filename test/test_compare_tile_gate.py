"""The naming gate asks per-laser names the tile test where they are named (bend53).

A rocket body bent off its CAD leaves a range residual that the P-60's 24 tiles cut up:
lasers' range offsets fit part of it. Every per-laser name (missing, tie, 'also') must
hold across the tiles where it is named (``Diagnosis.tile_fault`` in ``settle``), and a
range term 'also' beside lasers' offsets must pass the cross-material test it would face
named. Stand-ins: a diagnosis of N matched points whose tests are given by hand.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from lidar_sim_ros.compare.diagnose import diagnosis as dg
from lidar_sim_ros.core.effects import make_effect

N = 2400
BEFORE_NLL = -2.0


class Hand(dg.Diagnosis):
    """N matched points on 24 lasers; the tile test and the cross-material test given by
    hand (``tiles``: the reason per (name, beside names); ``material``: per name)."""

    def __init__(self, tiles=None, material=None):
        meas = SimpleNamespace(laser=np.arange(N) % 24)
        self.rays = SimpleNamespace(matched=np.arange(N), unmatched=np.arange(0), meas=meas)
        self.fold_order = np.arange(N)
        self.tiles = tiles or {}
        self.material = material or {}
        self.asked: list[tuple] = []

    def _tile_test(self, cand, on_top):
        key = (cand.name, tuple(e.name for e in on_top))
        self.asked.append(key)
        why = self.tiles.get(key)
        return why, {'beside': list(key[1]), 'passes': why is None}

    def material_veto(self, cand, on_top=()):
        return self.material.get(cand.name)


def cand(name, effect=None):
    """A candidate that passes the rule, fitted below the NLL without it."""
    c = dg.Candidate(name, score=0.04, matched_gain=0.04, z=11.4, significant=True,
                     practical=True, nll_after=BEFORE_NLL - 0.04)
    c.heldout_nll = np.zeros(N)
    c.variant = object
    c.effect = effect if effect is not None else type(name, (), {'name': name})()
    return c


def fault(c):
    return dg.naming_fault(c, BEFORE_NLL)


def lasers():
    return cand('laser_bias', make_effect('laser_bias', {'offsets_m': [0.01] * 24}))


def test_a_per_laser_name_is_withheld_where_its_offsets_do_not_hold_across_the_tiles():
    """The missing effect: laser_bias withheld with the tile test's reason; the figures
    kept on the candidate; a second ask in the same context costs nothing (memo)."""
    bias = lasers()
    hand = Hand(tiles={('laser_bias', ()): 'the residual follows a pattern on the target'})
    s = dg.settle(dg.Decision('laser_bias', []), [bias], fault, hand.tile_fault)
    assert s.missing is None
    assert 'pattern on the target' in s.withheld['laser_bias']
    assert bias.tile_test == {'beside': [], 'passes': False}
    dg.settle(dg.Decision('laser_bias', []), [bias], fault, hand.tile_fault)
    assert hand.asked == [('laser_bias', ())]
    # Lasers whose offsets hold across the tiles are named.
    held = Hand()
    assert dg.settle(dg.Decision('laser_bias', []), [lasers()], fault,
                     held.tile_fault).missing == 'laser_bias'


def test_a_per_laser_also_is_asked_beside_the_named_one():
    """An 'also' of lasers' offsets: the tile test with the named effect in the model."""
    walk, bias = cand('range_walk'), lasers()
    hand = Hand(tiles={('laser_bias', ('range_walk',)): 'a pattern the tiles cut up'})
    s = dg.settle(dg.Decision('range_walk', [], also='laser_bias'), [walk, bias], fault,
                  hand.tile_fault)
    assert s.missing == 'range_walk' and s.also is None
    assert hand.asked == [('laser_bias', ('range_walk',))]


def test_a_range_term_also_beside_lasers_faces_the_cross_material_test_alone():
    """range_scale 'also' beside laser_bias: the cross-material test it would face named
    (alone) sets it aside; beside a named effect with one parameter it is not asked."""
    bias, scale = lasers(), cand('range_scale')
    hand = Hand(material={'range_scale': 'part of the target reads off the rest'})
    s = dg.settle(dg.Decision('laser_bias', [], also='range_scale'), [bias, scale], fault,
                  hand.tile_fault)
    assert s.missing == 'laser_bias' and s.also is None
    assert 'reads off the rest' in s.withheld['range_scale']
    walk = cand('range_walk')
    s = dg.settle(dg.Decision('range_walk', [], also='range_scale'), [walk, scale], fault,
                  hand.tile_fault)
    assert s.also == 'range_scale'


def test_a_candidate_scored_on_another_model_is_left_to_its_own_tile_test():
    """A candidate re-scored on a corrected pose (another point count) is not tested on
    this diagnosis's points."""
    bias = lasers()
    bias.heldout_nll = np.zeros(N - 7)
    hand = Hand(tiles={('laser_bias', ()): 'a pattern'})
    assert hand.tile_fault(bias) is None and hand.asked == []
