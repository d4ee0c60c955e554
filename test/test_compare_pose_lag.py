"""A tracking lag tied to the motion: the reference pose read later and later over each
scan, against a named clock offset (compare/diagnose/clock_footing.py: the clock weighed
against its own growth over the scan). Closed forms on turning planes: the model is cast
again at a later pose time, no raycast."""
from __future__ import annotations

import numpy as np
from conftest import three_planes, turned_plane_ranges

from lidar_sim_ros.compare.diagnose import clock_footing, diagnosis
from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.core.effects.base import ReturnContext
from lidar_sim_ros.core.geometry import Hits
from lidar_sim_ros.core.pipeline import Prediction

SIGMA_M = 0.01
RATE_DPS = 20.0
LAG_S = 0.096
CLOUDS = 4
SCAN_S = 0.09


def _turned(t_s: np.ndarray) -> np.ndarray:
    return np.outer(np.radians(RATE_DPS) * t_s, [0.0, 0.0, 1.0])


def _scene(kind: str, seed: int, n: int = 12_000, clouds: int = CLOUDS, lag_s: float = LAG_S):
    """Three planes at 10 m turning RATE_DPS about z through their centre, four clouds
    of a raster (each ray's time within its cloud follows its elevation, SCAN_S long),
    the model reading the recorded pose at each point's time (plus any clock offset of
    the effects it is cast with). ``kind``: 'lag' (the target really is where the pose
    says it is LAG_S x u later, u the point's place in its scan: a tracking lag growing
    over each scan), 'clock' (a constant half of it: a clock offset), 'clock_rows' (the
    clock and a range bias of the sensor growing over the scan, 2 cm) or 'none'; ``clouds``
    and ``lag_s`` instead of CLOUDS and LAG_S. Returns the FitData, each point's cloud
    and time."""
    rng = np.random.default_rng(seed)
    _, el, u, normal, centre = three_planes(rng, n)
    cloud = np.sort(rng.integers(0, clouds, n))
    place = (el + 0.07) / 0.14
    t_s = cloud * 0.1 + place * SCAN_S
    truth = turned_plane_ranges(normal, u, centre, _turned(t_s))
    if kind == 'lag':
        truth = turned_plane_ranges(normal, u, centre, _turned(t_s + lag_s * place))
    elif kind == 'clock':
        truth = turned_plane_ranges(normal, u, centre, _turned(t_s + 0.5 * lag_s))
    elif kind == 'clock_rows':
        truth = turned_plane_ranges(normal, u, centre, _turned(t_s + 0.5 * lag_s)) \
            + 0.02 * place
    measured = truth + SIGMA_M * rng.standard_normal(n)

    def pred(dt_s: float) -> Prediction:
        r = turned_plane_ranges(normal, u, centre, _turned(t_s + dt_s))
        one, zero = np.ones(n), np.zeros(n, int)
        ctx = ReturnContext(range_m=r, incidence_rad=0 * one, material=zero, power_w=1e-6 * one,
                            intensity=one, t_s=t_s, az_rad=0 * one, el_rad=el, laser=zero,
                            divergence_rad=1e-3, hit=np.ones(n, bool), threshold_power_w=1e-9,
                            direction=u, normal=-normal)
        hits = Hits(np.ones(n, bool), r, -normal, 0 * one, zero, zero, None, one)
        return Prediction(ctx, hits, u, 0 * one, SIGMA_M * one)

    def cast(effects) -> Prediction:
        return pred(sum(float(e.params.dt_s) for e in effects if e.name == 'time_offset'))
    data = lk.FitData(measured_range_m=measured, baseline=pred(0.0), cast=cast,
                      unmatched_range_m=np.zeros(0), cast_unmatched=cast,
                      range_window_m=(5.0, 15.0))
    return data, cloud, t_s


def _footing(kind: str, seed: int) -> clock_footing.ClockFooting:
    """The clock's footing on sixteen clouds of a lag of 15 ms over the scan: twelve
    parameters per cloud pay for what the one column of the clock's growth takes."""
    data, cloud, t_s = _scene(kind, seed, clouds=16, lag_s=0.015)
    column = lk.model_on_rays(data, [_clock(0.05)]).expected_range_m - \
        lk.model_on_rays(data, []).expected_range_m
    return clock_footing.clock_on_pose_footing(data, cloud, t_s, np.arange(len(t_s)) // 30,
                                               3.0, diagnosis.MIN_PRACTICAL_GAIN, column, 0,
                                               rate=True)


def _clock(dt_s: float):
    from lidar_sim_ros.core.effects.time_offset import TimeOffset
    return TimeOffset({'dt_s': dt_s})


def test_a_named_clock_does_not_stand_for_a_lag_growing_over_the_scan():
    """The clock at the lag's mean passes on the pose test's rays and the per-cloud pose
    with its rate does not pass on top of it (sixteen clouds of twelve parameters), but
    the clock's growth over each scan does (and beyond a range line over the scan): the
    clock does not stand (before, it stood). A true clock offset: no growth, the clock
    stands."""
    for seed in (5, 6):
        lag = _footing('lag', seed)
        assert lag.clock_passes and not lag.pose_passes_over_clock, lag
        assert not lag.stands, lag
        assert lag.drift_passes and lag.drift_z > 3.0, lag
        clock = _footing('clock', seed)
        assert clock.clock_passes and not clock.drift_passes and clock.stands, clock


def test_a_range_growing_over_the_scan_beside_a_clock_is_no_growth_of_the_clock():
    """A clock offset and the sensor's range growing over each scan (2 cm): the clock's
    growth does not pass beyond a range line over the scan (what the per-cloud pose with
    its rate makes of the range line is the footing's other question)."""
    for seed in (7, 8):
        on = _footing('clock_rows', seed)
        assert on.clock_passes and not on.drift_passes, on
        assert on.drift_beyond_range_z < 3.0, on


def test_the_tie_says_the_pose_is_read_later_within_each_scan():
    """The tie's words, where the clock's growth over the scan passed: the pose read later
    and later within each scan, no constant clock offset; else the per-cloud pose's."""
    from lidar_sim_ros.compare.report.verdict import clock_off_footing_words
    lag = _footing('lag', 5).as_dict()
    words = clock_off_footing_words(lag, '')
    assert 'later and later within each scan' in words and 'no' in words
    assert f'{lag["drift_gain"]:.4f}' in words
    clock = _footing('clock', 5).as_dict()
    assert 'later and later' not in clock_off_footing_words(clock, '')
