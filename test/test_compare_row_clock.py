"""compare/diagnose/row_clock.py: a residual growing with the row (a rolling shutter
recorded as a global exposure) against a clock offset, a rigid pose error and a range
bias per row."""
import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose import diagnosis, row_clock

SIGMA_M = 0.02
RATE_DPS = 30.0


def _flash(kind: str, seed: int = 0, n: int = 12_000):
    """Three tilted planes 12 x 8 deg across at 10 m seen by a flash array, the target
    turning RATE_DPS about z through its centre, and the clock a fit would name: 50 ms
    (the range change it makes, ``clock_m``). ``kind``: 'rolling' (each row exposed at
    its own time, 0..100 ms from the top row down, every point recorded at the
    exposure's start), 'late' (every row at 50 ms: a clock offset, or on this constant
    turn one rigid pose error), 'pose' (exact timing, the pose 3 cm and 2 cm off
    across the line of sight: no clock), 'row_bias' (no motion; a range offset growing 4 cm from the
    bottom row to the top: the sensor's own) or 'none'. Returns the FitData, the clock's
    column and the closed-form gain of the clock's growth over the rows on top of the
    clock (least squares of the noise-free residual on each model's columns and an
    offset, the mean square it removes over 2 sigma^2, nats per point)."""
    from lidar_sim_ros.compare.model import likelihood as lk
    from lidar_sim_ros.core.effects.base import ReturnContext
    from lidar_sim_ros.core.geometry import Hits
    from lidar_sim_ros.core.pipeline import Prediction
    rng = np.random.default_rng(seed)
    az, el = rng.uniform(-0.1, 0.1, n), rng.uniform(-0.07, 0.07, n)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    normals = np.array([[-0.8, -0.5, 0.33], [-0.9, 0.1, -0.42], [-0.75, 0.6, 0.28]])
    normal = (normals / np.linalg.norm(normals, axis=1, keepdims=True))[
        np.digitize(az, [-0.033, 0.033])]
    centre = np.array([10.0, 0.0, 0.0])

    def ranges(rotvec_rad):
        n_rot = Rotation.from_rotvec(rotvec_rad).apply(normal)
        return np.einsum('ij,ij->i', n_rot, np.tile(centre, (n, 1))) / np.einsum(
            'ij,ij->i', u, n_rot)

    def turned(t_s):
        return ranges(np.outer(np.radians(RATE_DPS) * t_s, [0.0, 0.0, 1.0]))
    t_row = 0.1 * (0.07 - el) / 0.14
    expected = turned(np.zeros(n))
    clock = turned(np.full(n, 0.05)) - expected
    truth = {'rolling': turned(t_row), 'late': expected + clock,
             'pose': _plane_moved(normal, centre, u, [0.0, 0.03, 0.02]),
             'row_bias': expected + 0.04 * (el / 0.14), 'none': expected}[kind]
    tau = el / 0.07

    def left(cols):
        x = np.column_stack([*cols, np.ones(n)])
        d = truth - expected
        return d - x @ np.linalg.lstsq(x, d, rcond=None)[0]
    closed = float(np.mean(left([clock]) ** 2 - left([clock, clock * tau]) ** 2)
                   / (2 * SIGMA_M ** 2))
    measured = truth + SIGMA_M * rng.standard_normal(n)
    one, zero = np.ones(n), np.zeros(n, int)
    ctx = ReturnContext(range_m=expected, incidence_rad=0 * one, material=zero,
                        power_w=1e-6 * one, intensity=one, t_s=0 * one, az_rad=az,
                        el_rad=el, laser=zero, divergence_rad=1e-3, hit=np.ones(n, bool),
                        threshold_power_w=1e-9, direction=u, normal=-normal)
    hits = Hits(np.ones(n, bool), expected, -normal, 0 * one, zero, zero, None, one)
    pred = Prediction(ctx, hits, u, 0 * one, SIGMA_M * one)
    data = lk.FitData(measured_range_m=measured, baseline=pred, cast=lambda e: pred,
                      unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                      range_window_m=(5.0, 15.0))
    return data, clock, closed


def _plane_moved(normal, centre, u, move_m):
    """Range along each ray to its plane moved by ``move_m`` (m)."""
    at = np.tile(centre + np.asarray(move_m, float), (len(u), 1))
    return np.einsum('ij,ij->i', normal, at) / np.einsum('ij,ij->i', u, normal)


def _test(kind: str, seed: int = 0):
    """The row test on ``_flash(kind, seed)`` and the closed form scaled to the sigma
    the likelihood profiles (each material's sigma scale: the residual's spread, which
    the rows widen)."""
    from lidar_sim_ros.compare.diagnose import pose_error
    from lidar_sim_ros.compare.model import likelihood as lk
    data, clock, closed = _flash(kind, seed)
    blocks = np.arange(len(data.measured_range_m)) // 30
    _, sigma, _, _ = pose_error.footing(data, lk.model_on_rays(data, []))
    return row_clock.row_time_test(data, blocks, 3.0, diagnosis.MIN_PRACTICAL_GAIN,
                                   clock, seed), closed * (SIGMA_M / sigma[0]) ** 2


def test_a_rolling_shutter_on_a_turning_target_is_a_clock_growing_over_the_rows():
    """Rows exposed over 100 ms on a target turning 30 deg/s, recorded as one exposure:
    on top of the clock (the mean delay, 50 ms), the clock growing over the rows gains
    what the closed form says (within 15 %), and beyond a range offset growing with the
    row too; one rigid pose correction gains nothing on top of it."""
    rows, closed = _test('rolling')
    assert rows.significant, rows
    assert rows.rate_z > 10 and rows.beyond_range_z > 10 and rows.pose_z < 3.0
    assert closed > 4 * diagnosis.MIN_PRACTICAL_GAIN
    assert abs(rows.rate_gain - closed) < 0.15 * closed


def test_a_late_clock_a_pose_error_a_range_bias_per_row_and_noise_are_not_rows():
    """Every row at one time (a clock offset: the growth over the rows gains nothing), a
    pose turned about the line of sight (it passes on top of the clock over the rows),
    the sensor's range growing 4 cm over the rows (a range offset per row takes it) and
    no error: the row test passes on none."""
    for kind in ('late', 'pose', 'row_bias', 'none'):
        for seed in (1, 2):
            rows, _ = _test(kind, seed)
            assert not rows.significant, (kind, seed, rows)
    pose, _ = _test('pose', 3)
    assert pose.pose_z > 10
