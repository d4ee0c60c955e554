"""A clock offset beside one constant reference-pose error on a target turning about a
moving axis (a spin on a tumble): the clock and one rigid correction for the recording
fitted jointly on the pose test's rays (``clock_footing.clock_on_pose_footing`` with
``constant``), and the clock named with the pose beside it
(``Diagnosis.clock_beside_constant_pose``)."""
import numpy as np
from conftest import plane_fit_data, three_planes, turned_plane_ranges

from lidar_sim_ros.compare.diagnose import clock_footing, diagnosis

SIGMA_M = 0.005
SPIN_DPS = 25.0
DT_S = 0.03
CLOUDS = 8
OFFSET_M = np.array([0.0, 0.03, 0.02])


def _planes(axis: str, clock: bool, offset: bool, seed: int = 0, n: int = 16_000):
    """Three tilted planes at 10 m (``three_planes``), eight clouds 0.5 s apart, each
    point with its time; the recorded pose read ``DT_S`` late on a body turning
    SPIN_DPS about an axis that turns from +z to +y over the recording (``axis``
    'moving') or stays on +z ('fixed'), and/or the recorded target off by OFFSET_M.
    Returns the FitData (the model at the recorded pose), each point's cloud, its time
    and the range change the true clock offset makes at each point."""
    rng = np.random.default_rng(seed)
    _, _, u, normal, centre = three_planes(rng, n)
    cloud = np.sort(rng.integers(0, CLOUDS, n))
    t_s = cloud * 0.5 + rng.uniform(0.0, 0.1, n)
    angle = np.radians(90.0) * t_s / (CLOUDS * 0.5) if axis == 'moving' else 0 * t_s
    spin_axis = np.column_stack([0 * t_s, np.sin(angle), np.cos(angle)])
    turn = np.radians(SPIN_DPS) * DT_S * spin_axis
    recorded = turned_plane_ranges(normal, u, centre, 0 * turn)
    clock_m = turned_plane_ranges(normal, u, centre, turn) - recorded
    true_centre = centre - OFFSET_M if offset else centre
    truth = turned_plane_ranges(normal, u, true_centre, turn if clock else 0 * turn)
    measured = truth + SIGMA_M * rng.standard_normal(n)
    data = plane_fit_data(recorded, measured, normal, u, t_s, SIGMA_M, (5.0, 15.0))(
        np.arange(n))
    return data, cloud, t_s, clock_m


def _footing(axis: str, clock: bool, offset: bool, seed: int = 0,
             constant: bool = True) -> clock_footing.ClockFooting:
    data, cloud, t_s, clock_m = _planes(axis, clock, offset, seed)
    blocks = np.arange(len(t_s)) // 40
    return clock_footing.clock_on_pose_footing(data, cloud, t_s, blocks, 3.0,
                                               diagnosis.MIN_PRACTICAL_GAIN, clock_m, seed,
                                               constant=constant)


def test_a_clock_on_a_moving_spin_axis_has_a_part_beside_one_constant_pose():
    """A 30 ms clock with the pose off by (0, 3, 2) cm, the spin axis turning 90 deg
    over the recording: fitted jointly with one rigid correction for the recording, the
    clock passes on top of it and the correction on top of the clock; the clock's
    column is scaled by about 1 (the true dt), not by what the pose took."""
    for seed in (1, 2):
        on = _footing('moving', True, True, seed)
        assert on.constant and on.clock_passes_over_pose, on.as_dict()
        assert on.pose_passes_over_clock, on.as_dict()
        assert 0.8 < on.clock_scale < 1.2, on.as_dict()


def test_a_constant_pose_alone_or_a_clock_about_a_fixed_axis_gives_the_clock_no_part():
    """The pose off by (0, 3, 2) cm and no clock: the clock has no part on top of the
    constant correction. A clock about a fixed spin axis is one constant rotation: the
    same data as a constant pose, no part of its own either."""
    for seed in (1, 2):
        pose = _footing('moving', False, True, seed)
        assert not pose.clock_passes_over_pose and pose.pose_passes_over_clock, \
            pose.as_dict()
        fixed = _footing('fixed', True, True, seed)
        assert not fixed.clock_passes_over_pose, fixed.as_dict()


class _Judge(diagnosis.Diagnosis):
    def __init__(self):
        self.z_crit = 3.0

    def nameable(self, c):
        return c.significant and c.practical


class _Pose:
    """A reported constant pose (``pose_error.PoseError``'s fields read here)."""
    constant = True
    significant = True


def _clock():
    """clock_pose_spin seed 0's clock fitted alone: 52 ms, 0.287 nats/point, z 9.3."""
    from lidar_sim_ros.core.effects import get_effect_class
    effect = get_effect_class('time_offset')({'dt_s': 0.052})
    return diagnosis.Candidate('time_offset', score=0.287, z=9.3, significant=True,
                               practical=True, effect=effect, params={'dt_s': 0.052})


def _on(clock_over: bool, pose_over: bool, scale: float = 0.6,
        alone: bool = True) -> clock_footing.ClockFooting:
    """The joint footing's figures: the clock's own part on top of the constant pose
    (``clock_over``), the pose's on top of the clock, the clock alone passing or not
    (``alone``; clock_pose_spin seed 1: 0.0106, z 1.9)."""
    return clock_footing.ClockFooting(
        0.05 if alone else 0.0106, 12.0 if alone else 1.9, 0.06, 13.0,
        0.008 if clock_over else 0.0001, 6.0 if clock_over else 0.2,
        0.01 if pose_over else 0.0, 7.0 if pose_over else 0.1, 9000, 12000, False, alone,
        pose_over, clock_scale=scale, constant=True, z_crit=3.0,
        min_gain=diagnosis.MIN_PRACTICAL_GAIN)


class _OnPose:
    """The re-cast diagnosis on the corrected pose: the clock scored again there at the
    dt it is given (``dt_on_pose``), nameable or not."""

    def __init__(self, dt_on_pose: float, nameable: bool = True):
        self.dt, self.ok = dt_on_pose, nameable

    def score(self, cls):
        return diagnosis.Candidate('time_offset', score=0.03, z=6.0, significant=True,
                                   practical=True, effect=cls({'dt_s': self.dt}),
                                   params={'dt_s': self.dt})

    def naming_fault(self, c):
        return None if self.ok else 'its held-out gain does not pass the rule'


class _OnClock:
    significant = True
    constant = True


def _nest(clock_over: bool, pose_over: bool = True, dt: float = 0.030):
    """A nested test on the raycast footing (``clock_nested``) whose clock and pose own
    parts pass or not (both pass alone)."""
    from lidar_sim_ros.compare.diagnose import clock_nested

    def part(ok, gain):
        return clock_nested.Part(gain if ok else 0.0001, 8.0 if ok else 0.1, ok, 0)

    def nested(effect, dt_joint):
        return clock_nested.NestedClock(part(True, 0.7), part(True, 0.2),
                                        part(clock_over, 0.04), part(pose_over, 0.5),
                                        float(effect.params.dt_s), dt, 20000)
    return nested


def test_a_clock_with_its_own_part_beside_a_constant_pose_is_named_with_the_pose():
    """The constant pose reported alone at first (clock_pose_spin seed 0 before: 4.6 cm
    and 0.82 deg, nothing named). The linear joint footing no longer names: with its
    own part passing there but not on the raycast nested test, or no nested test, the
    decision stands. With it passing on the raycast footing, the pose is fitted again
    on top of the clock at the nested profile's dt, the clock scored again there and
    named, its own raycast part quoted, the pose beside it. A clock not nameable on the
    corrected pose, a pose per cloud, a name already given or no test: as it was."""
    judge = _Judge()
    pose = _Pose()
    alone = diagnosis.Decision(None, [], pose=pose)
    fitted = []

    def on_clock(effect, nameable=True):
        fitted.append(effect.params.dt_s)
        return _OnPose(0.031, nameable), _OnClock()
    for nested in (None, _nest(False)):
        assert judge.clock_beside_constant_pose(
            alone, [_clock()], lambda e: _on(True, True), on_clock, nested) == (alone, None)
    out, again = judge.clock_beside_constant_pose(alone, [_clock()], lambda e: _on(True, True),
                                                  on_clock, _nest(True))
    assert out.missing == 'time_offset' and out.confounded_with == []
    assert isinstance(out.pose, _OnClock)
    assert fitted == [0.03]
    assert again.params == {'dt_s': 0.031}
    # Quoted: its own part on top of the correction (raycast), not its score on a
    # correction fitted beside the clock it assumed.
    assert again.score == 0.04 and again.z == 8.0
    footing = again.against_pose['constant_pose_footing']
    assert np.isclose(footing['dt_joint_s'], 0.6 * 0.052) and footing['constant']
    assert footing['dt_beside_pose_s'] == 0.03 and footing['dt_rescored_on_pose_s'] == 0.031
    assert footing['passes_on_pose']
    assert again.against_pose['recorded_pose']['params'] == {'dt_s': 0.052}
    settled = diagnosis.settle(out, [again], lambda c: None)
    assert settled.missing == 'time_offset'
    out, _ = judge.clock_beside_constant_pose(alone, [_clock()], lambda e: _on(True, True),
                                              on_clock, _nest(True, pose_over=False))
    assert out.missing == 'time_offset' and out.pose is None
    # The clock fitted alone fails the rule (its dt fights the pose's offset): weighed
    # all the same (clock_pose_spin seed 1: -0.10 nats/point alone).
    failing = _clock()
    failing.score, failing.z, failing.significant = -0.1037, -3.7, False
    out, again = judge.clock_beside_constant_pose(
        alone, [failing], lambda e: _on(True, True, alone=False), on_clock, _nest(True))
    assert out.missing == 'time_offset' and again.score == 0.04
    assert judge.clock_beside_constant_pose(
        alone, [_clock()], lambda e: _on(True, True), lambda e: on_clock(e, nameable=False),
        _nest(True)) == (alone, None)

    class _PerCloud(_Pose):
        constant = False
    for other in (diagnosis.Decision(None, [], pose=_PerCloud()),
                  diagnosis.Decision('range_walk', [], pose=pose),
                  diagnosis.Decision(None, ['pose_error', 'time_offset'], pose=pose),
                  diagnosis.Decision(None, [])):
        assert judge.clock_beside_constant_pose(other, [_clock()], lambda e: _on(True, True),
                                                on_clock, _nest(True)) == (other, None)
    assert judge.clock_beside_constant_pose(alone, [_clock()], None, on_clock,
                                            _nest(True)) == (alone, None)


def test_the_verdict_gives_the_clock_fitted_beside_the_constant_pose():
    """The named clock's sentence: its own part on top of the correction on the raycast
    footing and the clock offset fitted beside it, not the one fitted alone as if it
    were the answer."""
    from lidar_sim_ros.compare.report import verdict
    judge = _Judge()
    _, again = judge.clock_beside_constant_pose(
        diagnosis.Decision(None, [], pose=_Pose()), [_clock()], lambda e: _on(True, True),
        lambda e: (_OnPose(0.031), _OnClock()), _nest(True))
    words = verdict.clock_beside_pose_words(again)
    assert 'dt_s = 0.0300' in words and '0.0520' in words
    assert 'part of its own: 0.0400 nats/point' in words and 'raycast again' in words
    assert '0.2870 nats/point held out, z = 9.3' in words and 'correct the pose too' in words


def test_a_clock_part_decisive_but_below_the_margin_is_said_not_named():
    """clock_pose_spin seed 0 on the corrected pose: the clock's own part 0.0042
    nats/point, z 5.2, below the margin that matters: the pose alone stands, the
    clock's figures on it and the verdict says the clock may sit beside the pose. A
    pose alone (the own part z -0.3): nothing said."""
    from lidar_sim_ros.compare.report import verdict
    judge = _Judge()
    alone = diagnosis.Decision(None, [], pose=_Pose())

    def below(e, z=5.2):
        return clock_footing.ClockFooting(
            0.0, 0.03, -0.0004, -3.1, 0.0042, z, 0.0038, 4.8, 31942, 34266, False, False,
            False, clock_scale=0.31, constant=True, z_crit=3.0,
            min_gain=diagnosis.MIN_PRACTICAL_GAIN)
    clock = _clock()
    out = judge.clock_beside_constant_pose(alone, [clock], below,
                                           lambda e: (_OnPose(0.03), _OnClock()))
    assert out == (alone, None)
    on = clock.against_pose['constant_pose_footing']
    assert on['clock_decisive_over_pose'] and not on['clock_passes_over_pose']
    words = verdict.clock_below_margin_words([clock])
    assert 'z = 5.2' in words and '0.0042 nats/point' in words and 'not named' in words
    clock = _clock()
    judge.clock_beside_constant_pose(alone, [clock], lambda e: below(e, z=-0.3),
                                     lambda e: (_OnPose(0.03), _OnClock()))
    assert verdict.clock_below_margin_words([clock]) == ''
