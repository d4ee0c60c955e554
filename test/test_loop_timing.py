"""loop/timing.py: which command answers which period, what is refused and clipped, when
the dynamics advances, in lock-step and in real time (no rclpy)."""
import numpy as np
import pytest

from lidar_sim_ros.loop.timing import CommandGate, admit_force

T = 0.1


def test_lock_step_waits_for_the_period_s_command_or_the_timeout():
    gate = CommandGate('lockstep', period_s=T, timeout_s=2.0, startup_timeout_s=30.0)
    assert gate.due(0.0)                          # the first period needs nothing
    assert gate.take()[1] is None
    gate.published(0.0, wall_s=10.0)              # period [0, 0.1] out
    assert not gate.due(10.5)
    assert gate.offer(-0.05, np.ones(3)) == 'stale'   # an older period's answer: not this one
    assert not gate.due(11.9)
    assert gate.offer(0.05, np.array([1.0, 2.0, 3.0])) is None
    assert gate.due(10.6)
    force, problem = gate.take()
    assert problem is None and force.tolist() == [1.0, 2.0, 3.0]
    gate.published(0.1, wall_s=11.0)              # the next period: nothing comes
    assert not gate.due(12.99) and gate.due(13.0)
    force, problem = gate.take()
    assert problem == 'timeout' and not force.any() and gate.timeouts == 1


def test_the_first_command_has_its_own_start_up_timeout():
    """The first acquisition (0.5-3 s of compute) must not trip the 2 s timeout."""
    gate = CommandGate('lockstep', period_s=T, timeout_s=2.0, startup_timeout_s=30.0)
    gate.take()
    gate.published(0.0, wall_s=0.0)
    assert not gate.due(2.5) and not gate.due(29.9) and gate.due(30.0)
    assert gate.take()[1] == 'startup_timeout' and gate.startup_timeouts == 1 and gate.timeouts == 0
    gate.published(0.1, wall_s=30.0)
    assert gate.offer(0.15, np.ones(3)) is None and gate.due(30.1)
    gate.take()
    gate.published(0.2, wall_s=31.0)
    assert not gate.due(32.9) and gate.due(33.0)   # after the first command: the 2 s one


@pytest.mark.parametrize('stamp_s, cause', [
    (0.2999, 'stale'), (0.2, 'stale'), (0.4, 'future'), (0.3 + 0.1, 'future'), (0.45, 'future'),
    (1000.3, 'future'), (-1e9, 'stale'), (float('nan'), 'future')])
def test_only_a_stamp_in_the_pending_period_is_its_command(stamp_s, cause):
    gate = CommandGate('lockstep', period_s=T, timeout_s=2.0)
    gate.published(0.3, wall_s=0.0)               # pending [0.3, 0.4)
    got = gate.offer(stamp_s, np.ones(3))
    assert got == cause and gate.refused[cause] == 1 and gate.accepted is None and not gate.due(1.0)


def test_window_ends_are_half_open():
    gate = CommandGate('lockstep', period_s=T, timeout_s=2.0)
    gate.published(0.3, wall_s=0.0)
    assert gate.offer(0.4, np.ones(3)) == 'future'     # t_k+1: the next period's
    assert gate.offer(0.3, np.ones(3)) is None         # t_k: this one's
    assert gate.offer(0.35, 2 * np.ones(3)) == 'duplicate'
    assert gate.take()[0].tolist() == [1.0, 1.0, 1.0]  # the first stands


def test_a_command_sent_before_its_period_closed_is_refused():
    """Stamped in the window but sent (DDS source time) before the /clock that closed the
    period went out: a publisher stamping with the clock it saw, in flight across the tick."""
    gate = CommandGate('lockstep', period_s=T, timeout_s=2.0)
    gate.published(0.3, wall_s=0.0, sent_s=1000.0)
    assert gate.offer(0.3, np.ones(3), sent_s=999.9995) == 'sent_early'
    assert gate.offer(0.35, np.ones(3), sent_s=1000.002) is None
    skewed = CommandGate('lockstep', period_s=T, timeout_s=2.0, max_clock_skew_s=0.01)
    skewed.published(0.3, wall_s=0.0, sent_s=1000.0)
    assert skewed.offer(0.35, np.ones(3), sent_s=999.995) is None


def test_admit_force_refuses_and_clips_by_cause():
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # body x -> LVLH y
    f, refused, clip = admit_force('lvlh', [1e9, -3.0, 0.5], R, 20.0, 0.02)
    assert refused is None and clip == 'thrust_limit' and f.tolist() == [20.0, -3.0, 0.5]
    f, refused, clip = admit_force('chaser', [2.0, 0.0, 0.0], R, 20.0, 0.02)
    assert (refused, clip) == (None, None) and np.allclose(f, [0.0, 2.0, 0.0])
    f, refused, clip = admit_force('lvlh', [0.01, 0.01, 0.0], R, 20.0, 0.02)
    assert clip == 'dead_band' and not f.any()
    assert admit_force('lvlh', [0.0, 0.0, 0.0], R, 20.0, 0.02)[2] is None   # zero is no clip
    for bad in ([np.nan, 0, 0], [np.inf, 0, 0], [0, -np.inf, 0]):
        assert admit_force('lvlh', bad, R, 20.0, 0.02)[:2] == (None, 'non_finite')
    assert admit_force('base_link', [1.0, 0, 0], R, 20.0, 0.02)[:2] == (None, 'frame')
    # The cause of a NaN force in a wrong frame is the force, not the frame.
    assert admit_force('base_link', [np.nan, 0, 0], R, 20.0, 0.02)[1] == 'non_finite'


def _fly(periods: int, hostile: bool) -> tuple[list, CommandGate]:
    """A lock-step run on the gate alone: the honest controller answers each period with a
    force of its own (stamped at the frame's middle, sent 5 ms after the clock); the hostile
    publisher sends before and after it: far-future stamps, a 1 kHz stream stamped with the
    clock it last saw (some still in flight across the tick), NaN, 1e9 N stamped an old
    period. Returns the forces flown."""
    gate = CommandGate('lockstep', period_s=T, timeout_s=2.0, startup_timeout_s=30.0)
    cfg = dict(R_HB=np.eye(3), thrust_limit_n=20.0, dead_band_n=0.02)
    flown, wall, epoch = [], 0.0, 1e9

    def send(frame, force, stamp, sent):
        f, refused, clip = admit_force(frame, force, **cfg)
        return gate.refuse(refused) if refused else gate.offer(stamp, f, sent, clip)

    for k in range(periods):
        assert gate.due(wall)
        flown.append(gate.take())
        t_k = k * T                                    # the period just simulated: [t_k, t_k+1]
        gate.published(t_k, wall, sent_s=epoch + wall)
        if hostile:
            for j in range(20):                        # 1 kHz around the tick
                send('lvlh', [20.0, 20.0, 20.0], t_k + (0 if j < 3 else T), epoch + wall - 0.003 + j * 1e-3)
            send('lvlh', [0.0, 20.0, 0.0], t_k + 1000.0, epoch + wall + 0.001)
            send('lvlh', [np.nan, 0.0, 0.0], t_k + T / 2, epoch + wall + 0.001)
            send('lvlh', [1e9, 0.0, 0.0], t_k - T / 2, epoch + wall + 0.002)
        assert not gate.due(wall + 1.9), k             # nothing hostile releases the period
        honest = [np.sin(k), np.cos(k), 0.1 * k]
        assert send('lvlh', honest, t_k + T / 2, epoch + wall + 0.005) is None
        if hostile:
            send('lvlh', [5.0, 5.0, 5.0], t_k + T / 2, epoch + wall + 0.006)   # a replay after it
        wall += 0.01
    return flown, gate


def test_a_hostile_publisher_cannot_advance_stall_or_change_a_lock_step_run():
    clean, _ = _fly(30, hostile=False)
    attacked, gate = _fly(30, hostile=True)
    assert [f.tolist() for f, _ in clean] == [f.tolist() for f, _ in attacked]
    assert all(p is None for _, p in attacked) and gate.timeouts == gate.startup_timeouts == 0
    assert gate.commands == 30
    assert gate.refused == {'non_finite': 30, 'frame': 0, 'stale': 30, 'future': 30 * 18,
                            'duplicate': 30, 'sent_early': 30 * 3}


def test_real_time_paces_on_the_wall_and_counts_late_commands():
    gate = CommandGate('realtime', period_s=T, timeout_s=2.0, realtime_waits_for_first_command=False)
    gate.published(0.0, wall_s=5.0)
    assert not gate.due(5.05) and gate.due(5.1)   # one period of wall time, command or not
    gate.offer(0.05, np.array([1.0, 0.0, 0.0]))
    assert gate.take()[1] is None and gate.late == 0
    gate.published(0.1, wall_s=5.1)
    force, problem = gate.take()                  # its command has not come: late,
    assert problem == 'late' and gate.late == 1 and force.tolist() == [1.0, 0.0, 0.0]  # flies on the last
    assert gate.offer(0.05, np.ones(3)) == 'stale'  # the old period's answer, again: refused
    gate.published(0.2, wall_s=5.2)
    assert gate.offer(0.15, 2 * np.ones(3)) is None and gate.late_arrivals == 1   # late, but the newest
    force, problem = gate.take()
    assert problem == 'late' and force.tolist() == [2.0, 2.0, 2.0]
    gate.published(0.5, wall_s=5.5)               # three periods on, the last is too old to fly
    force, problem = gate.take()
    assert problem == 'late' and not force.any() and gate.late == 3


def test_real_time_paces_from_the_first_command():
    """The first acquisition (seconds of compute) is waited for, not counted late; then the
    wall grid starts from the first command's period."""
    gate = CommandGate('realtime', period_s=T, timeout_s=2.0, startup_timeout_s=30.0)
    gate.take()
    gate.published(0.0, wall_s=0.0)
    assert not gate.due(0.1) and not gate.due(2.9)     # the GNC is still acquiring
    assert gate.offer(0.05, np.ones(3)) is None and gate.due(2.9)
    assert gate.take()[1] is None
    gate.published(0.1, wall_s=3.0)                    # paced from here
    assert not gate.due(3.05) and gate.due(3.1)
    assert gate.take()[1] == 'late' and gate.late == 1
    gate.published(0.2, wall_s=3.1)
    assert not gate.due(3.15) and gate.due(3.2)        # the grid, not the late tick
    assert gate.startup_timeouts == 0
