"""compare/diagnose/row_clock.py: a residual growing with the row (a rolling shutter
recorded as a global exposure) against a clock offset, a rigid pose error and a range
bias per row."""
import numpy as np
from conftest import plane_fit_data, three_planes, turned_plane_ranges

from lidar_sim_ros.compare.diagnose import diagnosis, row_clock

SIGMA_M = 0.02
RATE_DPS = 30.0
from test_compare_pose_status import _Judge as PoseStatusJudge


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
    rng = np.random.default_rng(seed)
    az, el, u, normal, centre = three_planes(rng, n)

    def turned(t_s):
        return turned_plane_ranges(normal, u, centre,
                                   np.outer(np.radians(RATE_DPS) * t_s, [0.0, 0.0, 1.0]))
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
    data = plane_fit_data(expected, measured, normal, u, np.zeros(n), SIGMA_M, (5.0, 15.0),
                          az, el)(np.arange(n))
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


def _judged(rows_significant: bool | None):
    """``judge_pose`` on the eleventh holdout's flash_rolling figures: time_offset named
    (0.343, z 22), one correction for the recording passing alone and on top of the
    clock (0.016, z 7.3), the clock not passing on the corrected pose; ``row_test``
    answering ``rows_significant`` (None: not asked, the points carry times)."""
    from lidar_sim_ros.compare.diagnose import pose_error
    clock = diagnosis.Candidate('time_offset', score=0.343, z=22.5, significant=True,
                                practical=True, effect=object(), nll_after=-1.5,
                                params={'dt_s': 0.060})

    def pose(on_top):
        return pose_error.PoseError(
            clouds=np.zeros(1, int), t_s=np.zeros(1), translation_m=np.zeros((1, 3)),
            rotation_deg=np.zeros((1, 3)), gain=0.19 if not on_top else 0.016,
            z=20.8 if not on_top else 7.3, significant=True, correction_m=np.zeros(4),
            constant=True)

    class OnPose:
        before_nll = -1.5

        @staticmethod
        def score(cls):
            return diagnosis.Candidate('time_offset', score=-0.057, z=-11.2)

        @staticmethod
        def nameable(c):
            return False

    class Judge(PoseStatusJudge):   # the pose_status tests' judge, on this OnPose
        def pose_corrected(self, correction_m):
            return OnPose()
    asked = []

    def row_test(effect):
        asked.append(effect)
        return row_clock.RowTime(0.0105, 9.6, 0.0105, 9.7, -0.0002, -0.8,
                                 bool(rows_significant), 0.0044, 6.1, False)
    out = Judge().judge_pose(pose, [clock], diagnosis.Decision('time_offset', []),
                             row_test=None if rows_significant is None else row_test)
    return out, clock, asked


def test_a_pose_that_takes_a_named_clock_is_tied_with_it_where_the_rows_grow():
    """flash_rolling: the pose passes on top of the named clock and the clock not on the
    corrected pose, so the pose alone was reported off on exact poses. Where the rows
    grow (``row_test`` passes, asked with the clock's effect) the two are the tie
    [pose_error, time_offset], the figures on the clock; where they do not, or the test
    is not asked, the pose stands alone as before."""
    out, clock, asked = _judged(True)
    assert out.missing is None and out.confounded_with == ['pose_error', 'time_offset']
    assert out.pose is not None and asked == [clock.effect]
    assert clock.against_pose['row_time']['significant']
    for rows in (False, None):
        alone, _, _ = _judged(rows)
        assert alone.confounded_with == [] and alone.pose is not None


def test_the_verdict_says_the_rows_time_the_clock_and_pose_stand_in_for():
    """pose_tie_words on the tie the rows made: a time within the exposure the points do
    not carry, outside the catalogue, the clock's dt as the rows' mean delay, none named;
    with the rows' growth short of the rule on top of the clock and the pose, the turn
    of the pose about the line of sight is said as the other reading."""
    from lidar_sim_ros.compare.report.verdict import pose_tie_words
    out, clock, _ = _judged(True)
    words = pose_tie_words(out, {'point_times': 'field'}, [clock])
    assert 'time within the exposure that the points do not carry' in words
    assert 'outside the catalogue' in words and 'none is named' in words
    assert 'dt = +0.060 s' in words and 'turn of the pose about the line of sight' in words
