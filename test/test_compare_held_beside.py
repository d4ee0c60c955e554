"""A candidate withheld beside a rival the rule keeps from naming (``Diagnosis.rival_takes``):
one of the two explains the part they share, so the reference pose and the sensor's range
terms are judged on top of what explains that part (``Decision.held_beside``,
``Diagnosis.held_effects``, ``pose_weighing.with_held``, ``range_term_on_held``), not on a
model that explains none of it. Another lab's incidence bias on the rocket, with a
footprint cast on every face: incidence withheld beside the footprint, then the pose judged
alone took the incidence bias and was tied with range_scale (docs/compare.md). Hand-made
candidates and pose tests (the decision's arithmetic, not a dataset)."""
from __future__ import annotations

from types import SimpleNamespace

from lidar_sim_ros.compare.diagnose import diagnosis as dg
from lidar_sim_ros.compare.diagnose import pose_weighing as pw
from lidar_sim_ros.compare.report import verdict as vd

from test_compare_same_part import BEFORE_NLL, INCIDENCE, WALK, OnTop, cand


def tied():
    """walk_graze s1 step 1's figures: incidence withheld beside the walk, neither passing
    on top of the other."""
    inc = cand('incidence_angle', INCIDENCE, 0.0218, 8.3, -2.045, 1)
    walk = cand('range_walk', WALK, 0.0212, 2.7, -2.044, 2)
    diag = OnTop({('incidence_angle', 'range_walk'): (0.0012, 1.1),
                  ('range_walk', 'incidence_angle'): (0.0009, 0.6)})
    return inc, walk, diag


def pose_test_of(asked: list, gain_alone: float = 0.02):
    """A per-cloud pose test that passes alone (it takes the bias neither candidate was
    named for) and gains nothing on top of either."""
    def test(on_top):
        asked.append([e.name for e in on_top])
        alone = not on_top
        return SimpleNamespace(significant=alone, gain=gain_alone if alone else 0.0011,
                               z=9.0 if alone else 0.8, joint=False, constant=False)
    return test


def test_a_name_withheld_beside_a_rival_holds_both_for_what_comes_after():
    inc, walk, diag = tied()
    d = diag.decide(dg.rank([inc, walk]))
    assert d.missing is None and 'incidence_angle' in d.withheld
    # Neither passes on top of the other: the withheld one explains the part they share.
    assert d.held_beside == ['incidence_angle']
    assert diag.held_effects(d, [inc, walk]) == [inc.effect]
    # The rival explaining all it explains and more: the rival.
    walk_kept = cand('range_walk', WALK, 0.0290, 9.0, -2.049, 2, share=0.16,
                     vetoed='it explains only 16 % of the residual\'s dependence on intensity')
    diag2 = OnTop({('incidence_angle', 'range_walk'): (0.0010, 0.9),
                   ('range_walk', 'incidence_angle'): (0.0090, 7.5)})
    d2 = diag2.decide(dg.rank([inc, walk_kept]))
    assert 'incidence_angle' in d2.withheld and d2.held_beside == ['range_walk']
    # Nothing withheld so: nothing held, the pose judged as before.
    assert diag.held_effects(dg.Decision('incidence_angle', []), [inc, walk]) == []


def test_the_pose_is_judged_on_top_of_the_held_effects_not_alone():
    """The pose test passes alone and not on top of incidence: it is not reported (before,
    judged alone with nothing named, it was, and was then tied with range_scale)."""
    inc, walk, diag = tied()
    d = diag.decide(dg.rank([inc, walk]))
    held = diag.held_effects(d, [inc, walk])
    asked = []
    test = pose_test_of(asked)
    out = diag.judge_pose(lambda on_top: test(pw.with_held(held, on_top)), [inc, walk], d)
    assert out.pose is None and out.missing is None and out.confounded_with == []
    assert out.withheld == d.withheld
    assert asked == [['incidence_angle']]
    # With a named effect in the model too, each effect is there once.
    assert pw.with_held([inc.effect, walk.effect], [inc.effect]) == [walk.effect, inc.effect]
    assert pw.with_held([], [inc.effect]) == [inc.effect]


def test_a_range_term_is_weighed_against_the_pose_only_on_top_of_the_held_effects():
    """range_scale passes the rule alone but not on top of the incidence bias: it is not
    weighed against a reported pose (before it was, and tied with it)."""
    inc, walk, _ = tied()
    scale = cand('range_scale', {'scale': 3e-4}, 0.0200, 6.0, -2.042, 4)
    diag = OnTop({('range_scale', 'incidence_angle'): (0.0008, 0.7)})
    assert diag.range_term_on_held(scale)          # nothing held: as before
    diag.held_on_top = [inc.effect]
    assert not diag.range_term_on_held(scale)
    assert scale.against_pose['on_held'] == {'with': ['incidence_angle'],
                                             'gain': 0.0008, 'z': 0.7, 'passes': False}
    asked = []
    pose = SimpleNamespace(constant=False, significant=True, gain=0.02, z=9.0)
    d = dg.Decision(None, [], pose=pose)

    def on_pose():
        raise AssertionError('a range term that fails on top of the held is not re-cast')
    out, scored = diag.weigh_pose_rivals(d, [type(scale.effect)], pose_test_of(asked),
                                         on_pose, {'range_scale': scale})
    assert out is d and scored == [scale] and asked == []
    # Passing on top of them, it is weighed as before.
    diag.on_top[('range_scale', 'incidence_angle')] = (0.0150, 6.0)
    assert diag.range_term_on_held(scale) and scale.against_pose['on_held']['passes']


def test_the_verdict_says_what_the_pose_was_judged_on_top_of():
    inc, walk, diag = tied()
    d = dg.settle(diag.decide(dg.rank([inc, walk])), [inc, walk], diag.naming_fault)
    assert d.held_beside == ['incidence_angle']
    text = vd.verdict({'materials': {}, 'unmatched': {'points': 0}, 'withheld': d.withheld,
                       'against_named': d.pair_z, 'nll_calibrated': BEFORE_NLL,
                       'reference_pose': {'gain_per_matched_point': 0.0011, 'z': 0.8,
                                          'significant': False}},
                      None, [inc, walk], d)
    assert ('judged on top of incidence_angle, not alone: incidence_angle explains the part '
            'of the residual it shares with range_walk' in text)
    assert 'gains 0.0011 nats/point (z = 0.8) and does not pass the rule there' in text
    assert 'is not named: range_walk explains the same part' in text
