"""compare/diagnose/spin_clock.py: a constant pose rotation about the tumble axis said as
the clock offset it equals on a constant spin (the eighteenth holdout's clock of 20 ms on
a 25 deg/s tumble beside a pose offset: the pose was claimed right, 0.50 deg of rotation
with it, and the clock never mentioned)."""
from types import SimpleNamespace

import numpy as np
import pytest

from lidar_sim_ros.compare.diagnose import spin_clock
from lidar_sim_ros.compare.report import verdict as vd

SPIN = np.array([[0.0, 7.5, 23.85]] * 2)      # deg/s, 25 deg/s, the same in both halves


def test_a_rotation_along_a_constant_spin_is_its_clock_offset():
    """0.5 deg about the spin axis at 25 deg/s is 20 ms; the sign follows the rotation."""
    axis = SPIN[0] / np.linalg.norm(SPIN[0])
    said = spin_clock.clock_equivalent(np.tile(0.5 * axis, (4, 1)), SPIN)
    assert said['shown'] and said['dt_s'] == pytest.approx(0.020, abs=1e-5)
    assert said['alignment'] == pytest.approx(1.0)
    assert spin_clock.clock_equivalent(-0.5 * axis, SPIN)['dt_s'] == pytest.approx(-0.020,
                                                                                abs=1e-5)


@pytest.mark.parametrize('rotation, spin', [
    ([0.5, 0.0, 0.0], SPIN),                                  # across the spin axis
    ([0.0, 0.006, 0.019], SPIN),                              # too small to say
    ([0.0, 0.15, 0.48], [[0.0, 0.0, 0.5], [0.0, 0.0, 0.5]]),  # a spin too slow
    ([0.0, 0.15, 0.48], [[0.0, 0.0, 20.0], [0.0, 0.0, 30.0]]),  # a spin-up: no constant turn
    ([0.0, 0.15, 0.48], [[0.0, 0.0, 25.0], [0.0, 8.0, 24.0]]),  # the axis moves
])
def test_no_clock_is_said_where_the_rotation_is_no_constant_turn_of_the_spin(rotation, spin):
    said = spin_clock.clock_equivalent(np.array(rotation), np.array(spin))
    assert said is None or not said['shown']


def test_the_verdict_says_the_clock_beside_a_constant_pose_claimed_alone():
    """verdict(): the pose reported alone with its rotation along the spin gets the
    clock's sentence; without the figures, none."""
    figures = spin_clock.clock_equivalent(np.array([0.146, 0.032, 0.479]),
                                          np.array([[7.5, 1.6, 23.8]] * 2))
    assert figures['shown'] and figures['dt_s'] == pytest.approx(0.020, abs=1e-3)
    text = spin_clock.words(figures)
    assert '+20.' in text and 'ms between the pose and LiDAR stamps' in text
    from lidar_sim_ros.compare.diagnose import diagnosis as dg
    pose = SimpleNamespace(gain=0.05, z=12.0, constant=True, line_of_sight_share=0.1,
                           raycast=None, rate_supported=False,
                           words=lambda: ("the reference pose is off by about 6.0 cm and "
                                          "0.50 deg"))
    base = {'nll_calibrated': -2.0, 'range_rmse_calibrated_m': 0.03, 'materials': {},
            'unmatched': {'points': 0}, 'point_times': 'field'}
    decision = dg.Decision(None, [], pose=pose)
    said = vd.verdict({**base, 'reference_pose': {'clock_equivalent': figures}}, None, [],
                      decision)
    assert said.startswith('The reference pose is off by about 6.0 cm')
    assert 'ms between the pose and LiDAR stamps' in said
    not_along = {**figures, 'shown': False}
    assert 'LiDAR stamps' not in vd.verdict(
        {**base, 'reference_pose': {'clock_equivalent': not_along}}, None, [], decision)


def test_on_a_fixed_spin_the_clock_has_no_part_of_its_own_to_say():
    """fixed_spin: a constant rate about a fixed axis (the seventeenth holdout's 30 deg/s
    tumble, where a clock was named beside a constant pose on a spurious own part of
    0.0074 nats/point, dt 32.6 ms for 20) is one; a spin-up, a moving axis, a slow turn are
    not. There the nested test names no clock (its own part is not the clock's; a tie
    stands) and the verdict says no clock part."""
    assert spin_clock.fixed_spin(np.array([[0.0, 9.0, 28.6], [0.1, 9.1, 28.5]]))
    assert not spin_clock.fixed_spin(np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 50.0]]))
    assert not spin_clock.fixed_spin(np.array([[0.0, 0.0, 25.0], [0.0, 8.0, 24.0]]))
    assert not spin_clock.fixed_spin(np.array([[0.0, 0.0, 0.4], [0.0, 0.0, 0.4]]))
    clock = SimpleNamespace(name='time_offset', against_pose={'constant_pose_footing': {
        'clock_decisive_over_pose': True, 'clock_passes_over_pose': False,
        'clock_over_pose_z': 4.0, 'clock_over_pose_gain': 0.003,
        'nested': {'fixed_spin': 'a spin at a constant rate about a fixed axis'}}})
    assert vd.clock_below_margin_words([clock]) == ''
    del clock.against_pose['constant_pose_footing']['nested']
    assert 'keeps a part of its own' in vd.clock_below_margin_words([clock])


def test_a_clock_part_on_a_fixed_spin_names_no_clock_but_the_tie_stands():
    """clock_nested.NestedClock: with ``own_part_possible`` False (a fixed spin) an own
    part that passes is no outcome 'clock'; the tie (each alone, neither over the other:
    the seventeenth holdout's clock alone on a 35 deg/s spin) is kept."""
    from dataclasses import replace
    from lidar_sim_ros.compare.diagnose.clock_nested import NestedClock, Part
    yes, no = Part(0.01, 4.0, True, 0), Part(0.0, 0.0, False, 0)
    named = NestedClock(yes, no, yes, yes, 0.05, 0.03, 20_000)
    assert named.outcome == 'clock'
    spun = replace(named, own_part_possible=False)
    assert spun.outcome is None and 'fixed_spin' in spun.as_dict()
    tie = NestedClock(yes, yes, no, no, 0.015, 0.015, 20_000, own_part_possible=False)
    assert tie.outcome == 'tie'
