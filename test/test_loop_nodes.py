"""The loop's nodes against hostile messages, in process (no second process; marked serial
as it joins a domain, conftest.SERIAL_MODULES):
each node is built in its own rclpy context and its callbacks are called with the
message; what it keeps, publishes or drops is read back. One test per input of issue 29.
"""
from __future__ import annotations

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped, QuaternionStamped
from sensor_msgs.msg import PointCloud2, PointField

from conftest import private_domain_id
from lidar_sim_ros.io.pointcloud import ns_to_stamp
from lidar_sim_ros.paths import config_path

NS = 1_000_000_000


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=private_domain_id(120, 100))   # a node publishes: keep it private
    yield ctx
    rclpy.try_shutdown(context=ctx)


def _node(cls, context, **params):
    from rclpy.parameter import Parameter
    node = cls(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    node.setup()
    return node


def _attitude(stamp_ns, xyzw):
    msg = QuaternionStamped()
    msg.header.frame_id, msg.header.stamp = 'lvlh', ns_to_stamp(stamp_ns, type(msg.header.stamp))
    q = msg.quaternion
    q.x, q.y, q.z, q.w = map(float, xyzw)
    return msg


@pytest.fixture
def controller(context):
    pytest.importorskip('Basilisk')   # the controller reads the Earth's constants from loop.dynamics
    from lidar_sim_ros.loop.controller_node import LoopControllerNode
    node = _node(LoopControllerNode, context, config_file=str(config_path('loop.yaml')))
    yield node
    node.destroy_node()


@pytest.mark.parametrize('xyzw', [[0, 0, 0, 0], [np.nan, 0, 0, 1], [np.inf, 0, 0, 1], [1e300, 1e300, 0, 0],
                                  [0, 0, 0, 2.0]])
def test_controller_drops_a_bad_attitude_and_keeps_running(controller, xyzw):
    controller._on_attitude(_attitude(100 * NS, xyzw))          # killed the node before
    assert not controller.attitudes and controller.dropped['attitude'] == 1
    controller._on_attitude(_attitude(100 * NS, [0, 0, 0.6, 0.8]))
    assert len(controller.attitudes) == 1


def test_a_nan_estimate_does_not_poison_later_commands(controller):
    """One NaN estimate used to turn every later command into NaN."""
    controller._on_attitude(_attitude(100 * NS, [0, 0, 0, 1]))
    good = [30.0, 0.0, 0.0], [0, 0, 0, 1]
    first = controller.command_for('lidar', 100_050_000_000, *good, now_s=100.1)
    assert first is not None and np.isfinite(first[0]).all()
    for position, quat in (([np.nan, 0, 0], [0, 0, 0, 1]), ([30.0, 0, 0], [np.nan, 0, 0, 1]),
                           ([1e300, 0, 0], [0, 0, 0, 1]), ([30.0, 0, 0], [0, 0, 0, 0])):
        assert controller.command_for('lidar', 100_150_000_000, position, quat, now_s=100.2) is None
    assert controller.dropped['non_finite'] == 3 and controller.dropped['range'] == 1
    later = controller.command_for('lidar', 100_150_000_000, *good, now_s=100.2)
    assert later is not None and np.isfinite(later[0]).all()


def test_a_future_or_replayed_estimate_is_dropped(controller):
    """A far-future estimate would freeze the filter (every later one 'older')."""
    controller._on_attitude(_attitude(100 * NS, [0, 0, 0, 1]))
    good = [30.0, 0.0, 0.0], [0, 0, 0, 1]
    assert controller.command_for('lidar', 1_000_100 * NS, *good, now_s=100.1) is None
    assert controller.dropped['future'] == 1
    assert controller.command_for('lidar', 100_050_000_000, *good, now_s=100.1) is not None
    assert controller.command_for('lidar', 100_050_000_000, *good, now_s=100.1) is None   # a replay
    assert controller.command_for('base_link', 100_150_000_000, *good, now_s=100.2) is None
    assert controller.dropped['stale'] == 1 and controller.dropped['frame'] == 1


def _cloud(xyz, stamp_ns=100 * NS, point_step=16, truncate=0):
    msg = PointCloud2()
    msg.header.frame_id, msg.header.stamp = 'lidar', ns_to_stamp(stamp_ns, type(msg.header.stamp))
    msg.height, msg.width = 1, len(xyz)
    msg.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, n in enumerate('xyz')] + [PointField(name='intensity', offset=12,
                                                              datatype=PointField.FLOAT32, count=1)]
    msg.point_step, msg.row_step = point_step, point_step * len(xyz)
    data = np.zeros((len(xyz), 4), np.float32)
    data[:, :3], data[:, 3] = xyz, np.arange(len(xyz))
    raw = data.tobytes()
    msg.data = raw[:len(raw) - truncate]
    return msg


@pytest.fixture
def gate(context):
    from lidar_sim_ros.loop.cloud_gate_node import CloudGateNode
    node = _node(CloudGateNode, context, gate_m=8.0, capture_gate_m=12.0)
    got = []

    class Reader:          # what the node's callback would publish
        def _on_cloud(self, msg):
            out = node.gated(msg)
            if out is not None:
                got.append(out)
    yield node, got, Reader()
    node.destroy_node()


def _estimate(stamp_ns, position):
    msg = PoseStamped()
    msg.header.frame_id, msg.header.stamp = 'lidar', ns_to_stamp(stamp_ns, type(msg.header.stamp))
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, position)
    msg.pose.orientation.w = 1.0
    return msg


def _target_and_far():
    rng = np.random.default_rng(1)
    target = rng.normal([30.0, 0.0, 0.0], 1.0, (200, 3))
    far = rng.uniform([100, -50, -50], [200, 50, 50], (20, 3))
    return np.vstack([target, far])


@pytest.mark.parametrize('bad', ['truncated', 'point_step_0'])
def test_gate_drops_an_unreadable_cloud_and_keeps_going(gate, bad):
    node, got, reader = gate
    xyz = _target_and_far()
    reader._on_cloud(_cloud(xyz, truncate=5) if bad == 'truncated' else _cloud(xyz, point_step=0))
    assert not got and node.dropped['cloud'] == 1
    reader._on_cloud(_cloud(xyz))
    assert len(got) == 1 and got[0].width == 200


def test_gate_after_a_nan_estimate_still_passes_the_target(gate):
    """After one NaN estimate the gate used to pass 0 points forever."""
    node, got, reader = gate
    xyz = _target_and_far()
    node._on_estimate(_estimate(100 * NS - 50_000_000, [np.nan, 0, 0]))
    reader._on_cloud(_cloud(xyz))
    assert node.dropped['non_finite'] == 1 and got[-1].width == 200     # the capture gate
    node._on_estimate(_estimate(100 * NS + 50_000_000, [30.0, 0.0, 0.0]))
    reader._on_cloud(_cloud(xyz, stamp_ns=100 * NS + 100_000_000))
    kept = np.frombuffer(bytes(got[-1].data), np.float32).reshape(-1, 4)
    # The points within 8 m of the estimate (by hand: the target's, none of the far ones),
    # every field kept as it came.
    inside = np.linalg.norm(xyz.astype(np.float32) - [30.0, 0.0, 0.0], axis=1) <= 8.0
    assert got[-1].width == inside.sum() and np.array_equal(kept[:, 3], np.flatnonzero(inside).astype(np.float32))


def test_gate_centres_on_the_estimate_of_the_period_before_not_the_last_to_arrive():
    from lidar_sim_ros.loop.cloud_gate_node import EstimateBook
    book = EstimateBook(100_000_000)
    book.add(100_050_000_000, [30.0, 0, 0])     # period [100.0, 100.1)
    book.add(100_150_000_000, [29.0, 0, 0])     # period [100.1, 100.2): arrived last
    assert book.centre_for(100_100_000_000).tolist() == [30.0, 0, 0]   # cloud of [100.1, 100.2)
    assert book.centre_for(100_200_000_000).tolist() == [29.0, 0, 0]
    assert book.centre_for(100_400_000_000) is None    # the period before had none: re-capture
    assert book.add(100_250_000_000, [1e300, 0, 0]) == 'range'


def test_controller_answers_a_lost_period_from_the_coasting_filter(controller):
    """A period whose cloud gave no estimate (pose_tracker's lost notice) gets a command, from
    the filter as it stands (step.navigate keeps it in process), stamped as the notice."""
    from lidar_sim_ros.loop.step import guide_and_control
    controller._on_attitude(_attitude(100 * NS, [0, 0, 0, 1]))
    controller._on_attitude(_attitude(100_200_000_000, [0, 0, 0, 1]))
    controller.command_for('lidar', 100_050_000_000, [30.2, 0.1, 0.0], [0, 0, 0, 1], now_s=100.1)
    nav, g = controller.nav, controller.guidance
    force, ref = controller.command_for_loss('lidar', 100_150_000_000, now_s=100.2)
    _, ref_hand, force_hand = guide_and_control(controller.config, nav, g, 100.2, controller.n_rad_s)
    assert force.tolist() == force_hand.tolist() and ref.rho_m.tolist() == ref_hand.rho_m.tolist()
    assert controller.nav is nav and controller.last_stamp_s == 100.15
    assert controller.command_for_loss('lidar', 100_150_000_000, now_s=100.2) is None   # replayed


def test_controller_waits_for_the_attitude_at_the_estimate_time(controller):
    controller._on_attitude(_attitude(100 * NS, [0, 0, 0, 1]))
    controller._on_estimate(_estimate(100_050_000_000, [30.0, 0.0, 0.0]))   # its attitude not yet in
    assert controller.last_stamp_s is None and len(controller.waiting) == 1
    controller._on_attitude(_attitude(100_050_000_000, [0, 0, 0.6, 0.8]))
    assert controller.last_stamp_s == 100.05 and not controller.waiting


def test_controller_answers_with_the_nearest_attitude_when_its_sample_never_comes(controller):
    """The attitude samples of the first period lost to discovery must not deadlock a
    lock-step start: after ATTITUDE_WAIT_S the nearest sample answers (logged)."""
    from lidar_sim_ros.loop import controller_node
    controller._on_attitude(_attitude(100 * NS, [0, 0, 0, 1]))
    controller._on_estimate(_estimate(100_050_000_000, [30.0, 0.0, 0.0]))
    controller._flush_waiting()
    assert controller.last_stamp_s is None                       # not yet overdue
    stamp, *rest, since = controller.waiting[0]
    controller.waiting[0] = (stamp, *rest, since - controller_node.ATTITUDE_WAIT_S)
    controller._flush_waiting()
    assert controller.last_stamp_s == 100.05 and not controller.waiting


def test_gate_holds_a_cloud_until_the_period_before_is_answered(gate):
    """DDS does not order the estimate and the next cloud: a cloud that comes first waits for
    the estimate (or the lost notice) of the period before, then is gated about it."""
    from std_msgs.msg import Header
    node, _, _ = gate
    got = []
    node._pass = lambda msg: got.append(node.gated(msg))     # what it would publish
    xyz = _target_and_far()
    node._on_cloud(_cloud(xyz, stamp_ns=100 * NS))                       # the first: no period before
    assert len(got) == 1 and got[0].width == 200                        # captured
    node._on_cloud(_cloud(xyz, stamp_ns=100 * NS + 100_000_000))         # before its estimate
    assert len(got) == 1 and len(node.held) == 1
    node._on_estimate(_estimate(100 * NS + 50_000_000, [30.0, 0.0, 0.0]))
    inside = np.linalg.norm(xyz.astype(np.float32) - [30.0, 0.0, 0.0], axis=1) <= 8.0
    assert len(got) == 2 and got[1].width == inside.sum() and not node.held
    node._on_cloud(_cloud(xyz, stamp_ns=100 * NS + 200_000_000))         # its period was lost
    assert len(node.held) == 1
    node._on_lost(Header(stamp=ns_to_stamp(100 * NS + 150_000_000, type(Header().stamp)), frame_id='lidar'))
    assert len(got) == 3 and got[2].width == 200 and node.counts == {'gated': 1, 'captured': 2, 'unanswered': 0}


@pytest.mark.parametrize('name, value', [('command_timeout_s', -1.0), ('startup_timeout_s', float('nan')),
                                         ('max_clock_skew_s', 1e300), ('clock_delay_s', 5.0), ('epoch_s', 0.0)])
def test_dynamics_refuses_absurd_parameters_naming_them(context, name, value):
    pytest.importorskip('Basilisk')
    from lidar_sim_ros.core.config import ConfigError
    from lidar_sim_ros.loop.dynamics_node import LoopDynamicsNode
    with pytest.raises(ConfigError, match=name):
        _node(LoopDynamicsNode, context, **{name: value})
