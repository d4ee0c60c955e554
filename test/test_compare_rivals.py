"""The range terms and surface offsets weighed beside the decision (``run.rival_classes``,
``Diagnosis.weigh_rivals``)."""
from __future__ import annotations

from lidar_sim_ros.compare.diagnose import diagnosis
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
