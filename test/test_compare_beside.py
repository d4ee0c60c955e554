"""compare/diagnose/beside.py: beside the named effect, the pose, the clock and the
'also' asked on top of each other both ways (``Diagnosis.judge_pose`` ->
``beside.weigh_beside``), on the eleventh holdout's toff_incid figures."""
import numpy as np
import pytest

from lidar_sim_ros.compare.diagnose import beside, diagnosis, pose_error


class _Effect:
    def __init__(self, name):
        self.name = name


def _cls(name):
    return type(name, (_Effect,), {'name': name})


INC, CLOCK, LASERS = _cls('incidence_angle'), _cls('time_offset'), _cls('laser_bias')


def _cand(cls, score, z, significant=True):
    return diagnosis.Candidate(cls.name, score=score, z=z, significant=significant,
                               practical=significant, effect=cls(cls.name), variant=cls,
                               nll_after=-1.9)


def _pose(significant: bool, gain: float = None):
    return pose_error.PoseError(
        clouds=np.zeros(1, int), t_s=np.zeros(1), translation_m=np.zeros((1, 3)),
        rotation_deg=np.zeros((1, 3)),
        gain=gain if gain is not None else (0.011 if significant else 0.0004),
        z=22.2 if significant else 0.3, significant=significant,
        correction_m=np.zeros(4), constant=True)


class _Together:
    def __init__(self, effects):
        self.names = tuple(sorted(e.name for e in effects))
        self.name = '+'.join(self.names)


def _names(on_top):
    out = []
    for e in on_top:
        out.extend(getattr(e, 'names', (e.name,)))
    return tuple(sorted(out))


class _OnPose:
    """The diagnosis on the corrected pose: every candidate scored there; which passes
    on top of which (``on_top``: {(other, *on_top names): passes})."""

    before_nll = -1.74

    def __init__(self, alone, on_top):
        self.alone, self.on_top = alone, on_top

    def score(self, cls):
        return _cand(cls, 0.13 if self.alone.get(cls.name) else 0.0, 11.0,
                     bool(self.alone.get(cls.name)))

    def nameable(self, c):
        return c.significant

    def decide(self, again):
        return diagnosis.Decision('incidence_angle', [])

    def _passes_on_top(self, on_top, other, practical=True):
        return self.on_top.get((other.name, *_names(on_top)), False)


class _Judge(diagnosis.Diagnosis):
    """The recorded pose's diagnosis: which candidate passes on top of which
    (``on_top``), the clock fitted on top of the named effect as ``clock_on_top``
    fits it, and the corrected pose's diagnosis ``on_pose``."""

    def __init__(self, on_top, on_pose):
        self.z_crit, self.on_top, self.on_pose = 3.0, on_top, on_pose

    def nameable(self, c):
        return c.significant and c.practical

    def set_aside_beside(self, best, cands, but=()):
        return []

    def finalized(self, *cands):
        pass

    def _fitted_together(self, effects):
        return [_Together(effects)]

    def _passes_on_top(self, on_top, other, practical=True):
        return self.on_top.get((other.name, *_names(on_top)), False)

    def pose_corrected(self, correction_m):
        return self.on_pose


@pytest.fixture
def clock_fitted(monkeypatch):
    """The clock fitted on top of incidence_angle where it passes there (figures of
    toff_incid_1: 0.0457 nats/point, z 9.7, dt -0.032 s)."""
    def fitted(diag, best, clock):
        if clock is None or not diag._passes_on_top([best.effect], clock):
            return None
        return {'effect': CLOCK('time_offset'), 'gain': 0.0457, 'z': 9.7, 'dt_s': -0.032}
    monkeypatch.setattr(beside, 'clock_on_top', fitted)


def _pose_test(on_top):
    """The constant pose test of toff_incid_1: passes on top of incidence_angle alone
    (z 22), not beside the lasers or the clock."""
    return _pose(_names(on_top) == ('incidence_angle',))


def _toff_incid(clock_on_pose: bool, lasers_on_pose: bool = False):
    inc, clock, lasers = _cand(INC, 0.267, 13.8), _cand(CLOCK, 0.0065, 1.0, False), \
        _cand(LASERS, 0.0385, 9.3)
    on_top = {('time_offset', 'incidence_angle'): True,
              ('laser_bias', 'incidence_angle'): True,
              ('laser_bias', 'incidence_angle', 'time_offset'): False,
              ('time_offset', 'incidence_angle', 'laser_bias'): True}
    on_pose = _OnPose({'incidence_angle': True},
                      {('time_offset', 'incidence_angle'): clock_on_pose,
                       ('laser_bias', 'incidence_angle'): lasers_on_pose})
    judge = _Judge(on_top, on_pose)
    decision = diagnosis.Decision('incidence_angle', [], also='laser_bias')
    return judge.judge_pose(_pose_test, [inc, lasers, clock], decision), (inc, clock, lasers)


def test_lasers_standing_in_for_a_clock_beside_the_named_effect_give_way_to_a_tie(clock_fitted):
    """toff_incid_1 (an incidence elongation, poses 30 ms late on a tumble): the pose
    passes on top of incidence_angle alone but not beside the lasers, so it was dropped
    and laser_bias stayed 'also'. Asked both ways: the clock passes on top of incidence
    and the lasers, the lasers not on top of incidence and the clock (they stood in for
    it); the pose does not pass on top of incidence and the clock, nor the clock on top
    of incidence on the corrected pose: the tie [pose_error, time_offset] beside the
    named incidence_angle, laser_bias no longer 'also'."""
    out, (inc, clock, lasers) = _toff_incid(clock_on_pose=False)
    assert out.missing == 'incidence_angle' and out.also is None and out.pose is None
    assert out.beside_tie == ['pose_error', 'time_offset']
    assert out.beside_pose is not None and out.beside_pose.significant
    assert lasers.against_pose['beside_clock'] == {'passes_on_top_of_clock': False,
                                                   'clock_passes_on_top': True}
    assert clock.against_pose['beside'] == {'on_top_of': 'incidence_angle', 'gain': 0.0457,
                                            'z': 9.7, 'dt_s': -0.032}


def test_a_clock_that_passes_on_the_corrected_pose_keeps_its_place_beside(clock_fitted):
    """The clock passing on top of incidence_angle on the corrected pose too, and the
    pose not on top of both: the clock explains what the pose cannot, it is 'also', no
    tie and no pose."""
    out, _ = _toff_incid(clock_on_pose=True)
    assert out.missing == 'incidence_angle' and out.also == 'time_offset'
    assert out.beside_tie == [] and out.pose is None


def test_lasers_beside_the_named_effect_without_a_clock_are_asked_on_the_corrected_pose(
        monkeypatch):
    """No clock beside incidence_angle: the lasers, which the pose does not pass on top
    of, are asked on top of incidence_angle on the corrected pose. Passing there, they
    keep their place ('also', as before); not passing, the two are a tie beside the
    named effect ([pose_error, laser_bias]): never laser_bias alone as 'also'."""
    monkeypatch.setattr(beside, 'clock_on_top', lambda diag, best, clock: None)
    kept, _ = _toff_incid(clock_on_pose=False, lasers_on_pose=True)
    assert kept.also == 'laser_bias' and kept.beside_tie == [] and kept.pose is None
    tied, _ = _toff_incid(clock_on_pose=False, lasers_on_pose=False)
    assert tied.missing == 'incidence_angle' and tied.also is None
    assert tied.beside_tie == ['pose_error', 'laser_bias']


def test_a_clock_beside_the_named_effect_is_judged_on_its_gain_on_top_of_it():
    """``settle``: a clock offset 'also' beside incidence_angle whose own gain alone is
    not decisive (0.0065, z 1.0: an incidence residual ten times its size swamps it) but
    that passed the rule on top of incidence_angle (``clock_on_top``'s record) stays
    'also'; without that record, or recorded on top of another effect, it is withheld."""
    inc = _cand(INC, 0.267, 13.8)
    clock = _cand(CLOCK, 0.0065, 1.0, False)
    decision = diagnosis.Decision('incidence_angle', [], also='time_offset')

    def fault(c):
        return None if c.significant else 'its held-out gain is not decisive'
    assert diagnosis.settle(decision, [inc, clock], fault).also is None
    clock.against_pose = {'beside': {'on_top_of': 'range_walk', 'gain': 0.0457, 'z': 9.7}}
    assert diagnosis.settle(decision, [inc, clock], fault).also is None
    clock.against_pose = {'beside': {'on_top_of': 'incidence_angle', 'gain': 0.0457,
                                     'z': 9.7, 'dt_s': -0.032}}
    settled = diagnosis.settle(decision, [inc, clock], fault)
    assert settled.also == 'time_offset' and settled.missing == 'incidence_angle'
