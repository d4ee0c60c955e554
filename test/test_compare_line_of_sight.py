"""The target moved on the candidates' footing (``compare/diagnose/line_of_sight.py``)
and the named sensor effects weighed against it (``Diagnosis.weigh_on_ray_footing``).

A constant reference pose 6 cm off along the line of sight on the rocket held tilted
toward it: the pose's own (linear) test counted 0.014 nats/point where laser_pointing
and surface_offset gained 0.12, and with a 1 % range scale beside the pose
beam_divergence and incidence_angle were tied. Small synthetic cases, no recording.
"""
from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np

from lidar_sim_ros.compare.diagnose import diagnosis, line_of_sight as los_mod
from lidar_sim_ros.compare.diagnose.candidate import POSE_ERROR, UNMATCHED_NATS


def test_ray_gain_counts_returns_put_back_as_a_candidates_unmatched_points():
    before = los_mod.RayScore(np.array([0, 1, 3]), np.array([-2.0, -2.0, -1.0]), np.array([2]))
    after = los_mod.RayScore(np.array([0, 1, 2]), np.array([-2.1, -2.0, 5.0]), np.array([3]))
    g = los_mod.ray_gain(before, after, 5)
    # Matched in both: the NLL's fall; put back: the credit alone, whatever its NLL;
    # lost: the credit taken; point 4 in neither.
    assert np.allclose(g, [0.1, 0.0, UNMATCHED_NATS, -UNMATCHED_NATS, 0.0])


def test_best_shift_brackets_away_from_zero_and_narrows():
    calls = []

    def cost(t):
        calls.append(t)
        return abs(t + 0.061)
    t, n = los_mod.best_shift(cost)
    assert abs(t + 0.061) <= los_mod.TOL_M
    assert n == len(set(round(c, 5) for c in calls))


def _limb_scores(truth_m, n=4000, seed=0):
    """A recording whose points near the limb are matched only when the target is
    within their reach of ``truth_m`` and whose ranges fit best there."""
    rng = np.random.default_rng(seed)
    reach = rng.uniform(0.005, 0.1, n)
    limb = rng.random(n) < 0.1
    truth = np.asarray(truth_m, float)

    def score(t):
        d = float(np.linalg.norm(np.asarray(t) - truth))
        on = ~limb | (reach > d)
        idx = np.flatnonzero(on)
        nll = -2.0 + 40.0 * d ** 2 + 0.01 * rng.standard_normal(len(idx))
        return los_mod.RayScore(idx, nll, np.flatnonzero(~on))
    return score, n


def test_the_target_is_moved_where_its_limbs_put_the_returns_back():
    truth = np.array([-0.06, 0.004, 0.0])
    score, n = _limb_scores(truth)
    fit = los_mod.fit(score, n, np.arange(n) % 40, np.array([1.0, 0.0, 0.0]), 3.0, 0.005)
    assert np.linalg.norm(fit.translation_m - truth) < 0.006
    assert fit.significant and fit.put_back > 0 and fit.gain > 0.1
    # A recording the recorded pose fits: nothing to gain, the search stops there.
    score0, n0 = _limb_scores(np.zeros(3))
    still = los_mod.fit(score0, n0, np.arange(n0) % 40, np.array([1.0, 0.0, 0.0]), 3.0, 0.005)
    assert not still.significant and np.linalg.norm(still.translation_m) < 0.006


class _Pointing:
    name = 'laser_pointing'


class _Footprint:
    name = 'beam_divergence'


class _Scale:
    name = 'range_scale'


class _Drift:
    name = 'range_drift'


def _cand(name, kind, score, z):
    return diagnosis.Candidate(name, score=score, z=z, significant=z >= 3.0,
                               practical=score >= diagnosis.MIN_PRACTICAL_GAIN, effect=kind(),
                               params={'x': score})


def _judge():
    class Judge:
        weigh_on_ray_footing = diagnosis.Diagnosis.weigh_on_ray_footing

        @staticmethod
        def nameable(c):
            return c.significant and c.practical and c.vetoed is None
    return Judge()


def _on_moved(scores):
    """A diagnosis on the moved target whose candidates score ``scores`` (name -> (gain, z))."""
    kinds = {'laser_pointing': _Pointing, 'beam_divergence': _Footprint,
             'range_scale': _Scale, 'range_drift': _Drift, 'incidence_angle': _Incidence,
             'range_walk': _Walk, 'laser_bias': _Lasers}

    class OnPose:
        @staticmethod
        def score(cls):
            gain, z = scores.get(cls.name, (0.0, 0.0))
            return _cand(cls.name, kinds[cls.name], gain, z)

        @staticmethod
        def nameable(c):
            return c.significant and c.practical

        @staticmethod
        def naming_fault(c):
            return None if c.significant and c.practical else 'short of the rule'
    return OnPose()


def _los(significant=True, gain=0.09, shift=-0.06):
    return los_mod.LineOfSightPose(np.array([shift, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                                   gain, 12.0 if significant else 1.0, significant, 216, 30)


def _as_pose(fit, explains):
    return NS(translation_m=fit.translation_m, explains=explains)


def test_a_sensor_effect_the_moved_target_leaves_nothing_is_not_named():
    """The lab's first variant: laser_pointing named, the target moved along the line of
    sight gains as much and leaves it nothing: the pose is reported, nothing named."""
    cands = [_cand('laser_pointing', _Pointing, 0.118, 12.6)]
    decision = diagnosis.Decision('laser_pointing', [])
    out = _judge().weigh_on_ray_footing(decision, cands, [_Drift, _Scale],
                                        lambda on_top: _los(),
                                        lambda fit: _on_moved({'laser_pointing': (-0.017, -4.3)}),
                                        _as_pose)
    assert out.missing is None and out.confounded_with == []
    assert out.pose is not None and out.pose.explains == ['laser_pointing']
    assert 'laser_pointing' in out.withheld
    assert cands[0].against_pose['line_of_sight']['passes_on_pose'] is False


def test_a_sensor_effect_that_keeps_a_decisive_part_on_the_moved_target_stands():
    cands = [_cand('laser_pointing', _Pointing, 0.12, 12.0)]
    decision = diagnosis.Decision('laser_pointing', [])
    out = _judge().weigh_on_ray_footing(decision, cands, [_Drift, _Scale],
                                        lambda on_top: _los(),
                                        lambda fit: _on_moved({'laser_pointing': (0.10, 11.0)}),
                                        _as_pose)
    assert out is decision
    # A move that does not pass the rule changes nothing either.
    out = _judge().weigh_on_ray_footing(decision, cands, [_Drift, _Scale],
                                        lambda on_top: _los(significant=False),
                                        lambda fit: _on_moved({}), _as_pose)
    assert out is decision


def test_a_range_scale_passing_on_the_moved_target_is_named_with_the_pose_beside():
    """The lab's second variant: a footprint and incidence tied on the recorded pose; on
    the target moved along the line of sight they gain nothing and range_scale (the
    wrong sign on the recorded pose) passes: it is named, its figures those on the moved
    target, and the pose beside it where the move still passes with the scale in."""
    scale = _cand('range_scale', _Scale, 0.0035, 2.9)
    cands = [_cand('beam_divergence', _Footprint, 0.036, 4.1),
             _cand('laser_pointing', _Pointing, 0.021, 6.9), scale]
    decision = diagnosis.Decision(None, ['beam_divergence', 'laser_pointing'])
    on_top_seen = []

    def fit(on_top):
        on_top_seen.append([e.name for e in on_top])
        return _los(significant=True)
    out = _judge().weigh_on_ray_footing(
        decision, cands, [_Drift, _Scale], fit,
        lambda f: _on_moved({'beam_divergence': (0.006, 2.9), 'range_scale': (0.0091, 5.9)}),
        _as_pose)
    assert out.missing == 'range_scale' and out.pose is not None
    assert out.pose.explains is None
    assert scale.score == 0.0091 and scale.against_pose['line_of_sight']['scored_on_moved_target']
    assert on_top_seen == [[], ['range_scale']]
    # The move does not pass with the scale in: the scale alone.
    out = _judge().weigh_on_ray_footing(
        diagnosis.Decision('beam_divergence', []),
        [_cand('beam_divergence', _Footprint, 0.036, 4.1)], [_Drift, _Scale],
        lambda on_top: _los(significant=not on_top),
        lambda f: _on_moved({'range_scale': (0.0091, 5.9)}), _as_pose)
    assert out.missing == 'range_scale' and out.pose is None


def test_a_range_term_the_moved_target_takes_while_the_move_fails_on_top_of_it_is_a_tie():
    scale = _cand('range_scale', _Scale, 0.012, 7.0)
    cands = [_cand('beam_divergence', _Footprint, 0.036, 4.1), scale]
    out = _judge().weigh_on_ray_footing(
        diagnosis.Decision('beam_divergence', []), cands, [_Drift, _Scale],
        lambda on_top: _los(significant=not on_top),
        lambda f: _on_moved({'range_scale': (0.001, 0.5)}), _as_pose)
    assert out.missing is None and out.confounded_with == [POSE_ERROR, 'range_scale']
    assert out.pose.explains == ['beam_divergence']


def test_one_member_of_a_tie_that_keeps_its_part_on_the_moved_target_is_named():
    cands = [_cand('beam_divergence', _Footprint, 0.036, 4.1),
             _cand('range_scale', _Scale, 0.012, 5.0)]
    out = _judge().weigh_on_ray_footing(
        diagnosis.Decision(None, ['beam_divergence', 'range_scale']), cands, [_Drift, _Scale],
        lambda on_top: _los(significant=not on_top),
        lambda f: _on_moved({'beam_divergence': (0.004, 1.0), 'range_scale': (0.0095, 6.1)}),
        _as_pose)
    assert out.missing == 'range_scale' and out.confounded_with == [] and out.pose is None
    assert cands[1].score == 0.0095 and 'beam_divergence' in out.withheld


class _Walk:
    name = 'range_walk'

    def __init__(self, k=0.02):
        self.params = NS(model_dump=lambda: {'k_m': k})


class _Incidence:
    name = 'incidence_angle'

    def __init__(self, g=-1.2):
        self.params = NS(model_dump=lambda: {'bias_gain': g})


def _pair_judge(on_top_passes=(True, True)):
    """``_judge`` that can weigh a walk and an incidence bias together: refitted
    together they are themselves (``_fitted_together``), each passes on top of the
    other as ``on_top_passes`` says (``each_on_top``)."""
    class Judge:
        weigh_on_ray_footing = diagnosis.Diagnosis.weigh_on_ray_footing
        pair_against_moved_target = diagnosis.Diagnosis.pair_against_moved_target

        @staticmethod
        def nameable(c):
            return c.significant and c.practical and c.vetoed is None

        @staticmethod
        def passes_rule(gain, z):
            return z >= 3.0 and gain >= diagnosis.MIN_PRACTICAL_GAIN

        @staticmethod
        def _fitted_together(effects):
            return list(effects)

        @staticmethod
        def each_on_top(named, other):
            g = [(0.01, 5.0) if p else (0.0, 0.2) for p in on_top_passes]
            return np.zeros(3), g[0], g[1]
    return Judge()


def _walk_incidence_cands():
    """The lab's box-wing: incidence_angle named alone, the walk's lone fit the wrong sign
    and nothing to name."""
    inc = _cand('incidence_angle', _Incidence, 0.019, 3.5)
    walk = _cand('range_walk', _Walk, 0.0019, 0.7)
    for c in (inc, walk):
        c.variant, c.heldout_nll = type(c.effect), np.zeros(3)
    return [inc, walk]


def _versus(pair_over_pose, pose_over_pair, pair_over_none=(0.03, 7.0, True)):
    seen = []

    def versus(effects, los):
        seen.append(sorted(e.name for e in effects))
        return {'pair_over_pose': pair_over_pose, 'pose_over_pair': pose_over_pair,
                'pair_over_none': pair_over_none}
    return versus, seen


def _weigh_pair(judge, versus, pose_on_top_of_pair=False):
    cands = _walk_incidence_cands()
    out = judge.weigh_on_ray_footing(
        diagnosis.Decision('incidence_angle', []), cands, [_Drift, _Scale],
        lambda on_top: _los(significant=pose_on_top_of_pair or not on_top),
        lambda f: _on_moved({}), _as_pose, versus)
    return out, cands


def test_a_walk_and_incidence_pair_as_good_as_the_moved_target_is_tied_with_the_pose():
    """The lab's box-wing (walk 0.02 beside -0.04 (1/cos - 1)): incidence alone gains
    nothing on the target moved along the line of sight, the pose was claimed alone.
    The pair fitted together does as well as the moved target: their tie, no pose alone."""
    versus, seen = _versus((0.001, 0.9, False), (-0.001, -0.9, False))
    out, cands = _weigh_pair(_pair_judge(), versus)
    assert out.missing is None and out.pose is not None
    assert out.confounded_with == [POSE_ERROR, 'incidence_angle', 'range_walk']
    assert seen == [['incidence_angle', 'range_walk']]
    assert all(c.jointly['passes'] for c in cands)
    assert 'incidence_angle' not in out.withheld


def test_a_walk_and_incidence_pair_that_fits_better_than_the_moved_target_is_named():
    versus, _ = _versus((0.012, 6.0, True), (-0.012, -6.0, False))
    out, _ = _weigh_pair(_pair_judge(), versus)
    assert out.missing == 'incidence_angle' and out.also == 'range_walk'
    assert out.pose is None and out.confounded_with == []
    # Neither passing on top of the other: the pair's tie, still no pose.
    out, _ = _weigh_pair(_pair_judge((False, True)), versus)
    assert out.missing is None and out.pose is None
    assert out.confounded_with == ['incidence_angle', 'range_walk']


class _Lasers:
    name = 'laser_bias'


def test_the_pair_is_weighed_against_the_moved_target_whatever_was_named():
    """The lab's walk_incneg_1 (walk 0.02 beside -0.04 (1/cos - 1), exact pose):
    laser_bias, not the walk or the incidence bias, was named on the recorded pose and
    gained nothing on the moved target; the pair was not asked and the pose was claimed
    alone. Before the move is reported alone the pair is weighed against it, whichever
    candidate the move set aside."""
    versus, seen = _versus((0.001, 0.9, False), (-0.001, -0.9, False))
    cands = [_cand('laser_bias', _Lasers, 0.021, 6.0), *_walk_incidence_cands()]
    out = _pair_judge().weigh_on_ray_footing(
        diagnosis.Decision('laser_bias', []), cands, [_Drift, _Scale],
        lambda on_top: _los(significant=not on_top),
        lambda f: _on_moved({'laser_bias': (0.001, 0.4)}), _as_pose, versus)
    assert seen == [['incidence_angle', 'range_walk']]
    assert out.missing is None and out.pose is not None
    assert out.confounded_with == [POSE_ERROR, 'incidence_angle', 'range_walk']
    assert 'laser_bias' in out.withheld
    # The moved target better than the pair by the rule: the pose alone, as before.
    versus, _ = _versus((-0.012, -6.0, False), (0.012, 6.0, True))
    out = _pair_judge().weigh_on_ray_footing(
        diagnosis.Decision('laser_bias', []),
        [_cand('laser_bias', _Lasers, 0.021, 6.0), *_walk_incidence_cands()], [_Drift, _Scale],
        lambda on_top: _los(significant=not on_top),
        lambda f: _on_moved({'laser_bias': (0.001, 0.4)}), _as_pose, versus)
    assert out.missing is None and out.confounded_with == [] and out.pose is not None


def test_the_pose_stays_where_it_beats_the_walk_and_incidence_pair():
    # The moved target fits better than the pair by the rule.
    versus, _ = _versus((-0.012, -6.0, False), (0.012, 6.0, True))
    out, _ = _weigh_pair(_pair_judge(), versus)
    assert out.missing is None and out.confounded_with == [] and out.pose is not None
    # The move still passes on top of the pair.
    versus, _ = _versus((0.001, 0.9, False), (-0.001, -0.9, False))
    out, _ = _weigh_pair(_pair_judge(), versus, pose_on_top_of_pair=True)
    assert out.missing is None and out.confounded_with == [] and out.pose is not None
    # The pair gains nothing over the recorded pose: not weighed further.
    versus, _ = _versus((0.001, 0.9, False), (-0.001, -0.9, False), (0.001, 0.5, False))
    out, _ = _weigh_pair(_pair_judge(), versus)
    assert out.confounded_with == [] and out.pose is not None


def test_the_pose_and_pair_tie_is_said_with_its_separating_recording():
    from lidar_sim_ros.compare import run
    from lidar_sim_ros.compare.report import verdict

    summary = {'pose_along_line_of_sight': {
        'shift_cm': -4.6, 'gain_per_point': 0.021, 'z': 6.2,
        'pair': {'pair_over_pose': [0.0008, 0.7, False],
                 'pose_on_top': {'gain': 0.0004, 'z': 0.9}}},
        'separation_plan': [{'distance_m': 8.0}, {'distance_m': 16.0}]}
    words = verdict.pair_pose_tie_words(summary)
    assert 'range_walk and incidence_angle fitted together' in words
    assert 'cannot be told' in words and 'plan.yaml' in words and '-4.6 cm' in words
    tie = NS(decision=diagnosis.Decision(None, [POSE_ERROR, 'incidence_angle', 'range_walk']))
    assert run.pose_rival(tie) == 'incidence_angle'
