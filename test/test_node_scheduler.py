"""Tests for lidar_sim_ros/ros/scheduler.py: the frame grid and readiness, without ROS."""
import pytest

from lidar_sim_ros.ros.scheduler import (COMPUTE, NS_PER_S, SKIP, WAIT, FrameScheduler,
                                         pose_window_ns, readiness)

MS = 1_000_000


def test_grid_is_exact_for_non_integer_periods():
    sched = FrameScheduler(15.0)  # T = 66.666... ms
    k = 25_500_000_000  # ~54 years of frames at 15 Hz
    assert sched.start_ns(k) == k * NS_PER_S // 15 + (1 if (k * NS_PER_S) % 15 * 2 >= 15 else 0)
    assert sched.start_ns(3) == 200 * MS
    assert sched.end_ns(2) == 200 * MS
    assert sched.index_at(200 * MS - 1) == 2 and sched.index_at(200 * MS) == 3


def test_one_frame_per_period_of_the_clock():
    sched = FrameScheduler(10.0)
    assert list(sched.poll(1_000 * MS).due) == []  # starts with the frame in progress: 10
    handled = []
    for step in range(1, 6):  # clock advances by exactly one period each time
        now = 1_000 * MS + step * 100 * MS
        due = list(sched.poll(now).due)
        assert list(sched.poll(now).due) == due  # polling twice changes nothing
        for k in due:
            sched.done(k)
        handled += due
    assert handled == [10, 11, 12, 13, 14]
    assert [sched.start_ns(k) for k in handled] == [k * 100 * MS for k in handled]


def test_frames_are_due_only_after_their_window_ends():
    sched = FrameScheduler(10.0)
    sched.poll(1_050 * MS)
    assert list(sched.poll(1_099 * MS).due) == []
    assert list(sched.poll(1_100 * MS).due) == [10]


def test_clock_jump_catches_up_within_the_cap():
    sched = FrameScheduler(10.0, max_catch_up=4)
    sched.poll(1_000 * MS)
    poll = sched.poll(1_300 * MS)  # three periods at once
    assert list(poll.due) == [10, 11, 12] and poll.skipped == 0
    for k in poll.due:
        sched.done(k)
    poll = sched.poll(2_300 * MS)  # ten periods: only the newest four are computed
    assert list(poll.due) == [19, 20, 21, 22] and poll.skipped == 6


def test_waiting_frame_stays_due_until_done():
    sched = FrameScheduler(10.0)
    sched.poll(1_000 * MS)
    assert list(sched.poll(1_150 * MS).due) == [10]
    assert list(sched.poll(1_250 * MS).due) == [10, 11]  # 10 not done yet
    sched.done(10)
    assert list(sched.poll(1_250 * MS).due) == [11]


def test_clock_going_back_restarts_the_grid():
    sched = FrameScheduler(10.0)
    sched.poll(5_000 * MS)
    for k in sched.poll(5_200 * MS).due:
        sched.done(k)
    assert sched.poll(5_150 * MS).reset is False  # within a period: nothing due, no reset
    poll = sched.poll(1_000 * MS)
    assert poll.reset and list(poll.due) == []
    assert list(sched.poll(1_100 * MS).due) == [10]


@pytest.mark.parametrize('rate', [0.0, -1.0, float('inf'), float('nan')])
def test_bad_rate_is_rejected(rate):
    with pytest.raises(ValueError, match='frame rate'):
        FrameScheduler(rate)


def ready(h_start_ms, h_end_ms, now_ms, extrap_s=0.05, wait_s=0.5, gap_ms=20):
    """Frame [1000, 1100) ms with its last shot at 1099.99 ms."""
    return readiness(1_000 * MS, 1_100 * MS - 10_000, 1_100 * MS, now_ms * MS,
                     None if h_start_ms is None else h_start_ms * MS,
                     None if h_end_ms is None else h_end_ms * MS, extrap_s, wait_s, gap_ms * MS)


def test_readiness():
    assert ready(None, None, 1_100) .action == SKIP and ready(None, None, 1_100).kind == 'no_pose'
    assert ready(1_001, 1_200, 1_100).kind == 'before_first_pose'
    assert ready(900, 1_100, 1_100).action == COMPUTE
    assert ready(900, 1_050, 1_100).action == COMPUTE  # 49.99 ms extrapolation
    assert ready(900, 1_050, 1_100, extrap_s=0.0499).action == WAIT
    lag = ready(900, 1_040, 1_100)
    assert lag.action == WAIT and lag.kind == 'pose_lag' and '0.010 s short' in lag.reason
    assert ready(900, 1_040, 1_600).action == WAIT  # waits pose_wait_s after the window
    assert ready(900, 1_040, 1_601).action == SKIP
    gap = ready(900, 1_100, 1_100, gap_ms=501)
    assert gap.action == SKIP and gap.kind == 'pose_gap'


def test_a_frame_waits_for_the_poses_its_pose_clock_reads():
    """With time_offset dt = +30 ms a frame evaluates poses up to its last shot + 30 ms: it
    waits until the history reaches them (it used to compute and fail on half its poses)."""
    from lidar_sim_ros.core.effects import make_effect
    start, last = 10 * NS_PER_S, 99_000_000
    assert pose_window_ns(start, last, []) == (start, start + last)
    shift = [make_effect('time_offset', {'dt_s': 0.03})]
    first, end = pose_window_ns(start, last, shift)
    assert (first, end) == (start + 30_000_000, start + last + 30_000_000)
    now = start + 100_000_000
    # Poses up to the last shot: enough without the offset, not with it.
    assert readiness(start, start + last, start + 100_000_000, now, start - NS_PER_S,
                     start + last, 0.0, 0.5).action == COMPUTE
    assert readiness(first, end, start + 100_000_000, now, start - NS_PER_S,
                     start + last, 0.0, 0.5).action == WAIT
    early = pose_window_ns(start, last, [make_effect('time_offset', {'dt_s': -0.03})])
    assert early == (start - 30_000_000, start + last - 30_000_000)
