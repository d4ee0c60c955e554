"""Clouds without per-point time: which stamp convention a fitted time offset equals."""
import pytest

from lidar_sim_ros.compare.diagnose.stamp_place import stamp_place

PERIOD = 0.1


def quadratic_nll(best_dt: float, curvature: float):
    """Total NLL (nats) of a time offset: a parabola with its minimum at ``best_dt``
    (curvature in nats / s^2), as a large sample gives."""
    return lambda effect: 0.5 * curvature * (effect.params.dt_s - best_dt) ** 2


@pytest.mark.parametrize('fitted, place', [(0.0502, 'start'), (-0.0497, 'end')])
def test_half_a_frame_is_the_stamp_at_start_or_end(fitted, place):
    st = stamp_place(quadratic_nll(fitted, 1e6), fitted, PERIOD, bound=8.6, n_points=10_000,
                     margin=0.005)
    assert st is not None and st.place == place
    assert st.dt_s == pytest.approx(0.5 * PERIOD if place == 'start' else -0.5 * PERIOD)
    # LR = curvature (dt - T/2)^2, the parabola's closed form.
    assert st.likelihood_ratio == pytest.approx(1e6 * (fitted - st.dt_s) ** 2, rel=1e-6)


def test_an_offset_far_from_half_a_frame_is_a_clock_offset():
    # 0.17 s: a start stamp plus a 0.12 s clock offset. The convention costs
    # 1e6 (0.12)^2 = 14 400 nats, 0.72 nats per point: decisive and it matters.
    assert stamp_place(quadratic_nll(0.17, 1e6), 0.17, PERIOD, 8.6, 10_000, 0.005) is None
    # -30 ms, 20 ms from a stamp at the end, with a sharp likelihood: a clock offset.
    assert stamp_place(quadratic_nll(-0.03, 1e9), -0.03, PERIOD, 8.6, 10_000, 0.005) is None


def test_a_remainder_that_does_not_matter_is_the_convention():
    # 2 ms short of half a frame on 10 000 points: LR 40 (significant) but 0.002 nats per
    # point, below the 0.005 margin: a scan that does not fill the frame.
    st = stamp_place(quadratic_nll(0.048, 1e7), 0.048, PERIOD, 8.6, 10_000, 0.005)
    assert st is not None and st.place == 'start' and st.likelihood_ratio == pytest.approx(40.0)


@pytest.mark.parametrize('fitted, place, dt', [(-0.1012, 'end', -PERIOD),
                                               (-0.0495, 'middle', -0.5 * PERIOD)])
def test_times_from_the_scan_pattern_are_read_from_a_start_stamp(fitted, place, dt):
    # Points timed from the matched scan pattern assume a stamp at the scan start: a stamp
    # at the end is a whole frame (-T), one in the middle half a frame (-T/2). With the
    # stamp-only conventions (+-T/2) the -T of an end stamp would be read as a clock offset.
    from lidar_sim_ros.compare.diagnose.stamp_place import SCAN_PLACES
    st = stamp_place(quadratic_nll(fitted, 1e6), fitted, PERIOD, 8.6, 10_000, 0.005,
                     places=SCAN_PLACES)
    assert st is not None and st.place == place and st.dt_s == pytest.approx(dt)
    if place == 'end':
        assert stamp_place(quadratic_nll(fitted, 1e6), fitted, PERIOD, 8.6, 10_000,
                           0.005) is None
    # A start stamp is what the scan pattern assumes: a positive offset is a clock offset.
    assert stamp_place(quadratic_nll(0.05, 1e6), 0.05, PERIOD, 8.6, 10_000, 0.005,
                       places=SCAN_PLACES) is None


def test_the_place_of_the_stamp_is_not_told_from_a_clock_offset():
    """Scan-pattern times (read as stamped at the scan start), stamps at the scan END and
    the poses stamped 50 ms late: the net -50 ms fitted is what a stamp in the middle
    gives with the clocks in step, and as well the end with the poses 50 ms late or the
    start with them 50 ms early. Without point times these give the same data: the
    summary names no place and lists every reading; the verdict says the two cannot be
    told apart and what separates them."""
    from lidar_sim_ros.compare.diagnose.stamp_place import SCAN_PLACES
    from lidar_sim_ros.compare.report.verdict import stamp_place_words
    st = stamp_place(quadratic_nll(-0.05, 1e6), -0.05, PERIOD, 8.6, 10_000, 0.005,
                     places=SCAN_PLACES)
    d = st.as_dict()
    assert d['place'] is None and d['separable_from_clock_offset'] is False
    got = {r['place']: r['clock_offset_s'] for r in d['readings']}
    # dt = stamp place's offset + clock offset: -0.1 (end) + 0.05 (poses late) = -0.05.
    assert got == pytest.approx({'start': -0.05, 'middle': 0.0, 'end': 0.05})
    words = stamp_place_words(d)
    assert 'cannot be told' in words and 'per-point time field' in words
    for place in ('start', 'middle', 'end'):
        assert f'at the {place} with' in words
    assert '50 ms late' in words and '50 ms early' in words
    assert 'here it is what stamps at' not in words


def test_a_stamp_only_offset_reads_against_a_middle_stamp():
    # Clouds timed by their stamps: the model assumes the middle, so +T/2 is a stamp at
    # the start with the clocks in step, the middle with the poses 50 ms late, or the end
    # with them 100 ms late.
    d = stamp_place(quadratic_nll(0.0502, 1e6), 0.0502, PERIOD, 8.6, 10_000, 0.005).as_dict()
    got = {r['place']: r['clock_offset_s'] for r in d['readings']}
    assert got == pytest.approx({'start': 0.0, 'middle': 0.05, 'end': 0.1})
