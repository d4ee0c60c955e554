"""loop/timing.py: when the dynamics advances, in lock-step and in real time (no rclpy)."""
import numpy as np

from lidar_sim_ros.loop.timing import CommandGate


def test_lock_step_waits_for_the_period_s_command_or_the_timeout():
    gate = CommandGate('lockstep', period_s=0.1, timeout_s=2.0)
    assert gate.due(0.0)                          # the first period needs nothing
    assert gate.take()[1] is None
    gate.published(0.0, wall_s=10.0)              # period [0, 0.1] out
    assert not gate.due(10.5)
    gate.on_command(-0.05, np.ones(3))            # an older period's answer: not this one
    assert not gate.due(11.9)
    gate.on_command(0.05, np.array([1.0, 2.0, 3.0]))
    assert gate.due(10.6)
    force, problem = gate.take()
    assert problem is None and force.tolist() == [1.0, 2.0, 3.0]
    gate.published(0.1, wall_s=11.0)              # the next period: nothing comes
    assert not gate.due(12.99) and gate.due(13.0)
    force, problem = gate.take()
    assert problem == 'timeout' and not force.any() and gate.timeouts == 1


def test_real_time_paces_on_the_wall_and_counts_late_commands():
    gate = CommandGate('realtime', period_s=0.1, timeout_s=2.0)
    gate.published(0.0, wall_s=5.0)
    assert not gate.due(5.05) and gate.due(5.1)   # one period of wall time, command or not
    gate.on_command(0.05, np.array([1.0, 0.0, 0.0]))
    assert gate.take() == (gate.newest_force, None) and gate.late == 0
    gate.published(0.1, wall_s=5.1)
    force, problem = gate.take()                  # its command has not come: late,
    assert problem == 'late' and gate.late == 1 and force.tolist() == [1.0, 0.0, 0.0]  # flies on the last
    gate.published(0.4, wall_s=5.4)               # three periods on, the last is too old to fly
    force, problem = gate.take()
    assert problem == 'late' and not force.any() and gate.late == 2
