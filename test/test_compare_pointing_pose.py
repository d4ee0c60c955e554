"""A few lasers off in pointing, read as the reference pose off (pointpose37).

On a 24-laser P-60 pattern with four lasers' beams turned 0.2-0.3 deg, the rest exact,
exact poses, the lasers' pointing offsets fit the truth (0.53 nats/point) but may be set
aside by a test of their shape; the pose's own test then passed alone (0.013 nats/point,
one rigid correction for the recording) and "the reference pose is off by 3.5 cm and
0.64 deg" was reported. On top of the lasers' offsets that pose gains nothing: it is not
claimed (``run.pose_left_to_pointing``).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from lidar_sim_ros.compare import run
from lidar_sim_ros.compare.diagnose import diagnosis, pose_error
from lidar_sim_ros.compare.model import pointing
from lidar_sim_ros.compare.report.pose_status import pose_status
from lidar_sim_ros.core.effects import get_effect_class


def _pose(gain: float = 0.013, z: float = 5.2, constant: bool = True) -> pose_error.PoseError:
    return pose_error.PoseError(
        clouds=np.arange(2), t_s=np.zeros(2), translation_m=np.full((2, 3), 0.02),
        rotation_deg=np.full((2, 3), 0.4), gain=gain, z=z, significant=True,
        correction_m=np.zeros(10), constant=constant)


def _pointing(score: float, vetoed: str | None) -> diagnosis.Candidate:
    cls = get_effect_class('laser_pointing')
    c = diagnosis.Candidate('laser_pointing', score=score, z=20.0, significant=True,
                            practical=True)
    c.variant, c.effect, c.vetoed = cls, cls(), vetoed
    return c


def _recast(score: float, passes: bool = True):
    """A stand-in for ``recast``: a diagnosis on the corrected pose whose ``score`` gives
    ``score`` (passing the rule or not)."""
    class OnPose:
        def score(self, cls):
            return diagnosis.Candidate('laser_pointing', score=score, z=12.0,
                                       significant=passes, practical=passes)
    return lambda pose: (OnPose(), pose)


def test_pose_alone_not_claimed_where_set_aside_pointing_leaves_it_nothing():
    pose = _pose()
    decision = diagnosis.Decision(None, [], pose=pose)
    asked = []

    def pose_test(on_top, constant=False):
        asked.append(([e.name for e in on_top], constant))
        return replace(pose, gain=-0.001, z=-2.8, significant=False)

    c = _pointing(0.53, 'its offsets follow a pattern the tiles cut up')
    kept, left = run.pose_left_to_pointing(decision, pose, [c], lambda c: None, pose_test,
                                           _recast(0.30))
    assert kept.pose is None and not left.significant
    assert asked == [(['laser_pointing'], True)]
    assert left.left_to_pointing['pose_z_on_top'] == -2.8
    assert left.left_to_pointing['score_on_pose'] == 0.30
    assert left.as_dict()['left_to_pointing']['named'] == 'laser_pointing'
    status = pose_status(left.as_dict(), kept, [], [])
    assert not status['reported'] and 'laser_pointing' in status['reported_because']
    assert pointing.turn_of(c.variant) is not None


def test_pose_kept_where_it_passes_on_top_or_pointing_is_named_or_weaker():
    pose = _pose()
    decision = diagnosis.Decision(None, [], pose=pose)
    passes = lambda on_top, constant=False: pose          # noqa: E731 - the pose stays
    fails = lambda on_top, constant=False: replace(pose, significant=False)  # noqa: E731
    aside = _pointing(0.53, 'set aside')
    on = _recast(0.30)
    # The pose passes on top of the lasers' offsets: it explains a part of its own.
    assert run.pose_left_to_pointing(decision, pose, [aside], lambda c: None,
                                     passes, on)[0].pose is pose
    # A true pose: the offsets gain nothing once it is corrected (nested the other way).
    assert run.pose_left_to_pointing(decision, pose, [aside], lambda c: None, fails,
                                     _recast(0.001, passes=False))[0].pose is pose
    # Not set aside (it would be named), or weaker than the pose's own test: kept.
    for c in (_pointing(0.53, None), _pointing(0.005, 'set aside')):
        assert run.pose_left_to_pointing(decision, pose, [c], lambda c: None,
                                         fails, on)[0].pose is pose
    # Another effect (not the lasers' pointing) set aside: kept.
    bias = _pointing(0.53, 'set aside')
    bias.variant = get_effect_class('laser_bias')
    assert run.pose_left_to_pointing(decision, pose, [bias], lambda c: None,
                                     fails, on)[0].pose is pose
    # A tie holding the pose is the tie's.
    tie = diagnosis.Decision(None, [diagnosis.POSE_ERROR, 'laser_pointing'], pose=pose)
    assert run.pose_left_to_pointing(tie, pose, [aside], lambda c: None, fails,
                                     on)[0].pose is pose
    # Withheld after its fit (not vetoed): judged the same.
    held = _pointing(0.53, None)
    withheld = diagnosis.Decision(None, [], pose=pose, withheld={'laser_pointing': 'at bound'})
    assert run.pose_left_to_pointing(withheld, pose, [held], lambda c: None, fails,
                                     on)[0].pose is None


# pointing_few_c end to end (its second and fifth seeds; el +0.3 deg on lasers 4 and 20,
# -0.3 on 12 and 13, exact poses) is left to `bench/hidden_effect_eval.py --only
# pointing_few_c --seeds 6` (each compare took 20-30 s of the suite's CPU): before
# pointpose37 the second seed's pose was reported off (3.5 cm and 0.64 deg, constant),
# before pointing38/39 the fifth seed's offsets were set aside as "mostly a common turn"
# and range_scale named. The decisions are tested above on stand-ins
# (``run.pose_left_to_pointing``) and in test_compare_pointing.py (the offsets weighed
# against one turn of the sensor, shrunk by their information); a few lasers off in
# pointing are named and fitted end to end on the suite's own data
# (test_compare_pointing.py).
