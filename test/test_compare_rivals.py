"""The range terms and surface offsets weighed beside the decision (``run.rival_classes``,
``Diagnosis.weigh_rivals``)."""
from __future__ import annotations

from types import SimpleNamespace

from lidar_sim_ros.compare.diagnose import diagnosis, range_outside
from lidar_sim_ros.compare.diagnose.candidate import Candidate, Decision
from lidar_sim_ros.compare.run import rival_classes
from lidar_sim_ros.core.effects import get_effect_class


def test_a_rival_asked_for_as_a_candidate_is_not_scored_again():
    """--candidates range_scale: range_scale is a candidate, so it is no rival as well (it
    would tie with itself); the other rivals are still weighed."""
    names = [c.name for c in rival_classes([], [get_effect_class('range_scale')])]
    assert 'range_scale' not in names
    assert set(names) == set(diagnosis.POSE_RIVALS + diagnosis.GEOMETRY_RIVALS) - {'range_scale'}


def test_every_rival_is_weighed_beside_the_default_candidates():
    names = [c.name for c in rival_classes([], [get_effect_class('range_walk')])]
    assert names == [*diagnosis.POSE_RIVALS, *diagnosis.GEOMETRY_RIVALS]


class _Stub:
    """Just what ``Diagnosis.weigh_rivals`` asks of a diagnosis: the rivals scored as
    given (``scored``) and ``decide`` naming the first admissible one."""

    def __init__(self, scored):
        self.scored, self.calls = scored, 0

    def scored_with_vetoes(self, classes, attribution=None):
        self.calls += 1
        return [c for c in self.scored if c.name in {k.name for k in classes}]

    def decide(self, cands):
        ok = [c for c in cands if c.admissible]
        return Decision(ok[0].name if ok else None, [])


def _weigh(share, significant=True):
    scale = Candidate('range_scale', score=0.0045, z=5.6, significant=True, practical=True,
                      share=share)
    walk = Candidate('range_walk', score=0.0016, z=2.2)
    stub = _Stub([scale])
    attribution = SimpleNamespace(significant=significant)
    rivals = rival_classes([], [get_effect_class('range_walk')])
    decision, weighed = diagnosis.Diagnosis.weigh_rivals(stub, Decision(None, []), [walk],
                                                        rivals, attribution)
    return decision, weighed, stub


def test_a_range_term_explaining_most_of_the_structure_is_named_where_nothing_else_is():
    decision, weighed, _ = _weigh(share=0.8)
    assert decision.missing == 'range_scale'
    assert [c.name for c in weighed] == ['range_scale']


def test_a_range_term_explaining_a_part_only_leaves_it_outside_the_catalogue_and_says_so():
    decision, weighed, _ = _weigh(share=0.28)
    assert decision.missing is None and weighed == []
    said = range_outside.words({'against_named': decision.pair_z})
    assert 'range_scale 0.0045' in said and '28 %' in said and 'z = 5.6' in said


def test_no_structure_no_range_term_weighed():
    decision, weighed, stub = _weigh(share=0.8, significant=False)
    assert decision.missing is None and weighed == [] and stub.calls == 0
