"""The node's sun input over REAL DDS: the sun direction from the topic (and the parameter)
changes the published clouds; bad sun messages are dropped with a warning.

One node process runs config/scenario_sunlit.yaml (the `sunlight` effect on) under
use_sim_time; the test process publishes /clock, poses and /sun/direction with the
harness of test_node_dds.py.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import Log
from rclpy.parameter import Parameter

from lidar_sim_ros.core.scan import directions_from_angles
from lidar_sim_ros.demo import stop as stop_ros_process
from lidar_sim_ros.io.pointcloud import from_pointcloud2
from lidar_sim_ros.paths import config_path
from test_node_dds import NS, PARAMS, PERIOD_NS, RELIABLE, Harness, start_process

pytestmark = pytest.mark.timeout(120)
SUN_S = 30                                          # simulated-time block (s)
# Toward the sun inside the field of view, beside the target (az 28 deg, el 9 deg): stray
# light floods the shots near it with false returns.
IN_VIEW = directions_from_angles(np.radians([28.0]), np.radians([9.0]))[0]


@pytest.fixture(scope='module')
def harness():
    h = Harness()
    yield h
    h.close()


@pytest.fixture(scope='module')
def node(harness, tmp_path_factory):
    log = tmp_path_factory.mktemp('sun_node') / 'lidar_sim_node.log'
    proc = start_process('lidar_sim_ros.ros.lidar_sim_node', '--params-file', str(PARAMS),
                         '-p', f'scenario_file:={config_path("scenario_sunlit.yaml")}',
                         '-p', 'use_sim_time:=true', '-p', 'qos_reliability:=reliable',
                         '-p', 'pose_qos_reliability:=reliable', log=log)
    n = harness.node
    try:
        harness.wait(lambda: proc.poll() is not None or (
            n.count_publishers('/lidar/points') and n.count_subscribers('/target/pose')
            and n.count_subscribers('/clock') and n.count_subscribers('/sun/direction')),
            timeout_s=30, what='the node to come up')
        assert proc.poll() is None, log.read_text()
        time.sleep(0.5)
        yield proc
    finally:
        code = stop_ros_process(proc)
        print(log.read_text())
    assert code == 0, f'node exited with {code}'


def false_returns(harness, first: int, last: int) -> list[int]:
    """Material-255 points in frames first..last of the block."""
    return [int(np.count_nonzero(from_pointcloud2(harness.points[harness.block_ns + i * PERIOD_NS])
                                 ['material'] == 255)) for i in range(first, last + 1)]


def test_sun_direction_from_the_topic_changes_the_clouds(harness, node):
    sun_pub = harness.node.create_publisher(Vector3Stamped, '/sun/direction', RELIABLE)
    harness.wait(lambda: sun_pub.get_subscription_count() > 0, what='the sun subscription')

    def publish_sun(vector, frame_id='lidar'):
        msg = Vector3Stamped()
        msg.header.frame_id = frame_id
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(harness.clock_ns, NS)
        msg.vector.x, msg.vector.y, msg.vector.z = map(float, vector)
        sun_pub.publish(msg)
        time.sleep(0.3)   # delivered before the next frame is due

    harness.begin_block(SUN_S * NS)
    harness.step_frames(0, 1)
    side_lit = false_returns(harness, 0, 1)
    assert max(side_lit) < 40, side_lit               # the scenario's sun: a few on sunlit faces

    publish_sun(2.0 * IN_VIEW)                         # any length: normalised
    harness.step_frames(2, 3)
    in_view = false_returns(harness, 2, 3)
    assert min(in_view) > 200, in_view

    mark = len(harness.rosout)
    publish_sun((1e-12, 0.0, 0.0))
    publish_sun((1e-300, 0.0, 0.0))                    # nearly zero: dropped, not "hidden"
    publish_sun((0.0, 1.0, 0.0), frame_id='map')
    publish_sun((np.nan, 1.0, 0.0))
    harness.step_frames(4, 4)
    assert false_returns(harness, 4, 4)[0] > 200      # the last good direction holds
    warnings = '\n'.join(harness.rosout_since(mark, Log.WARN))
    # (1e-300 once underflowed to "sun hidden": frame 4 would have been dark. Its warning
    # shares the 1e-12 one's kind and falls in the same throttle second.)
    for reason in ('[1e-12, 0.0, 0.0] is nearly zero',
                   "frame_id 'map' is not the node frame_id 'lidar'", 'is not finite'):
        assert 'dropped sun direction on /sun/direction: ' in warnings and reason in warnings, reason
    assert node.poll() is None

    # The parameter sets it too; a zero vector is refused there with the reason.
    bad = harness.set_parameter('sun_direction', Parameter.Type.DOUBLE_ARRAY, [0.0, 0.0, 0.0])
    assert not bad.successful and 'direction is zero' in bad.reason
    assert harness.set_parameter('sun_direction', Parameter.Type.DOUBLE_ARRAY,
                                 [0.0, 0.34, 0.94]).successful
    harness.step_frames(5, 5)
    assert false_returns(harness, 5, 5)[0] < 40

    # An exact zero on the topic hides the sun (the Earth's shadow, as loop_dynamics says
    # it): no stray light from a sun in view; the next direction brings it back whole.
    publish_sun(IN_VIEW)
    harness.step_frames(6, 6)
    assert false_returns(harness, 6, 6)[0] > 200
    mark = len(harness.rosout)
    publish_sun((0.0, 0.0, 0.0))
    harness.step_frames(7, 7)
    assert false_returns(harness, 7, 7)[0] < 40
    assert 'sun hidden' in '\n'.join(harness.rosout_since(mark, Log.INFO))
    publish_sun(IN_VIEW)
    harness.step_frames(8, 8)
    assert false_returns(harness, 8, 8)[0] > 200

    # Finite but huge: its norm overflows, yet it is a direction like any other (this once
    # normalised to zero and killed the node), on the topic and as the parameter.
    publish_sun((0.0, 1.0, 0.0))
    harness.step_frames(9, 9)
    assert false_returns(harness, 9, 9)[0] < 40
    publish_sun(1e300 * IN_VIEW)
    harness.step_frames(10, 10)
    assert false_returns(harness, 10, 10)[0] > 200
    assert harness.set_parameter('sun_direction', Parameter.Type.DOUBLE_ARRAY,
                                 [1e300, 1e300, 0.0]).successful
    assert node.poll() is None
