"""What a clock offset does to the target's points beyond one rigid motion
(``clock_nested.clock_beyond_rigid_m``): nothing on a constant-rate turn about a fixed
axis at a steady speed (there a clock is one constant pose correction), centimetres on a
spin whose axis turns with a tumble."""
import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose import clock_nested
from lidar_sim_ros.core.pose import Poses


class _Track:
    """A pose source: ``rotation(t)`` and ``position(t)`` (lidar frame)."""

    def __init__(self, rotation, position):
        self.rotation, self.position = rotation, position

    def at(self, t):
        t = np.atleast_1d(np.asarray(t, float))
        return Poses(self.rotation(t), self.position(t))


def _points(track, n=4000, seed=0):
    """Points on a 4 m x 1.5 m body seen over 12 clouds in 5.5 s, in the lidar frame."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, 5.5, n))
    body = rng.uniform([-2.0, -0.75, -0.75], [2.0, 0.75, 0.75], (n, 3))
    return track.at(t).to_lidar(body), t


def test_a_constant_rate_turn_about_a_fixed_axis_leaves_nothing_beyond_one_rigid_motion():
    """30 deg/s about a fixed axis, closing at 2 cm/s from 10 m, a 20 ms clock: what the
    clock does is one rigid motion to well under a millimetre (an independent lab's
    constant-rate tumble; the approach adds 0.3 mm), so no clock can be told from the
    pose there."""
    axis = np.array([0.2, 0.0, 1.0]) / np.hypot(0.2, 1.0)
    track = _Track(lambda t: Rotation.from_rotvec(np.radians(30.0) * t[:, None] * axis),
                   lambda t: np.column_stack([10.0 - 0.02 * t, 0 * t, 0 * t]))
    xyz, t = _points(track)
    beyond = clock_nested.clock_beyond_rigid_m(xyz, t, track, 0.020)
    assert beyond < 1e-3


def test_a_spin_on_a_tumble_moves_the_points_beyond_one_rigid_motion():
    """25 deg/s about the body's long axis, that axis precessing at 8 deg/s about another,
    a 30 ms clock (our CLOCK_SPIN items): the turn the clock reads about a moving axis is
    no single rigid motion over 5.5 s: millimetres beyond it (4 mm). A 3 ms clock: a
    tenth of that."""
    tumble = np.array([0.2, 0.0, 1.0]) / np.hypot(0.2, 1.0)

    def rotation(t):
        return (Rotation.from_rotvec(np.radians(8.0) * t[:, None] * tumble)
                * Rotation.from_rotvec(np.radians(25.0) * t[:, None] * np.array([1.0, 0, 0])))
    track = _Track(rotation, lambda t: np.column_stack([10.0 - 0.3 * t, 0 * t, 0 * t]))
    xyz, t = _points(track)
    beyond = clock_nested.clock_beyond_rigid_m(xyz, t, track, 0.030)
    assert beyond > 2e-3
    assert clock_nested.clock_beyond_rigid_m(xyz, t, track, 0.003) < beyond / 5
