"""The loop's DDS shells over REAL DDS: loop_dynamics and loop_controller as processes.

The test process stands in for the lidar and the tracker: on each /clock it relays the
true pose at the period's mid time as /target/pose_estimate (what pose_tracker would
publish). Checked: lock-step advances /clock on each command and gives the estimate's
period its command (no timeouts), the poses come at 100 Hz, the controller drives the
chaser toward its hold; with the relay stopped, lock-step waits for the timeout, logs
it, and goes on.
"""
from __future__ import annotations

import os
import re
import threading
import time

import pytest

pytest.importorskip('Basilisk')

import rclpy  # noqa: E402
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402

from conftest import private_domain_id  # noqa: E402
from lidar_sim_ros.demo import start as start_ros_process  # noqa: E402
from lidar_sim_ros.demo import stop as stop_ros_process  # noqa: E402
from lidar_sim_ros.io.pointcloud import stamp_to_ns  # noqa: E402
from lidar_sim_ros.paths import config_path  # noqa: E402

pytestmark = pytest.mark.timeout(150)
DOMAIN_ID = int(os.environ.get('ROS_DOMAIN_ID') or private_domain_id(120, 100))
NS = 1_000_000_000
EPOCH_NS = 100 * NS
PERIOD_NS = 100_000_000
RELIABLE = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)


def write_config(path, duration_s: float, mode: str = 'lockstep') -> None:
    text = config_path('loop.yaml').read_text()
    text = text.replace('scenario: scenario_all_effects.yaml', f'scenario: {config_path("scenario.yaml")}')
    text = text.replace('duration_s: 150.0', f'duration_s: {duration_s}')
    text = text.replace('position_m: [0.0, -30.0, 0.0]       # at the first hold point',
                        'position_m: [0.0, -31.0, 0.0]')
    text = text.replace('position_sigma_m: 0.5', 'position_sigma_m: 0.0')
    text = text.replace('velocity_sigma_mps: 0.005', 'velocity_sigma_mps: 0.0')
    text = text.replace('command_timeout_s: 2.0', 'command_timeout_s: 0.5')
    text = text.replace('mode: lockstep', f'mode: {mode}\n  realtime_waits_for_first_command: false')
    assert 'duration_s: 150.0' not in text and 'position_sigma_m: 0.0' in text
    path.write_text(text)


class Relay:
    """Truth as the estimate, one per period, stamped at the period's mid time."""

    def __init__(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.node = rclpy.create_node('loop_test_relay', context=self.context)
        self.poses: dict[int, PoseStamped] = {}
        self.clocks: list[int] = []
        self.commands: list[WrenchStamped] = []
        self.chaser: list[PoseStamped] = []
        self.rosout: list[Log] = []
        self.relaying = True
        self.relayed: set[int] = set()
        self.est_pub = self.node.create_publisher(PoseStamped, '/target/pose_estimate', QoSProfile(depth=20))
        n = self.node
        n.create_subscription(PoseStamped, '/target/pose', self._on_pose, RELIABLE)
        n.create_subscription(Clock, '/clock', self._on_clock, QoSProfile(depth=10))
        n.create_subscription(WrenchStamped, '/chaser/force_command', self.commands.append, QoSProfile(depth=50))
        n.create_subscription(PoseStamped, '/loop/chaser_pose', self.chaser.append, QoSProfile(depth=50))
        n.create_subscription(Log, '/rosout', self.rosout.append,
                              QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                         durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(n)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()

    def _on_pose(self, msg: PoseStamped) -> None:
        self.poses[stamp_to_ns(msg.header.stamp)] = msg
        self._relay()

    def _on_clock(self, msg: Clock) -> None:
        self.clocks.append(stamp_to_ns(msg.clock))
        self._relay()

    def _relay(self) -> None:
        """The pose at the mid time of the period the clock just closed, once both are in
        (the two topics arrive in either order)."""
        if not self.clocks:
            return
        mid = self.clocks[-1] - PERIOD_NS // 2
        if self.relaying and mid in self.poses and mid not in self.relayed:
            self.relayed.add(mid)
            self.est_pub.publish(self.poses[mid])

    def wait(self, predicate, timeout_s: float, what: str) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if predicate():
                return
            time.sleep(0.02)
        raise AssertionError(f'timed out waiting for {what}')

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def test_lock_step_loop_over_dds(tmp_path):
    cfg = tmp_path / 'loop.yaml'
    write_config(cfg, duration_s=8.0)
    relay = Relay()
    env = {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1'}
    logs = {name: tmp_path / f'{name}.log' for name in ('dynamics', 'controller')}
    controller = start_ros_process('lidar_sim_ros.loop.controller_node',
                                   ['-p', f'config_file:={cfg}', '-p', 'use_sim_time:=true'], env, logs['controller'])
    dynamics = None
    try:
        n = relay.node
        relay.wait(lambda: n.count_publishers('/chaser/force_command') > 0, 60, 'the controller')
        dynamics = start_ros_process('lidar_sim_ros.loop.dynamics_node', ['-p', f'config_file:={cfg}'],
                                     env, logs['dynamics'])
        # 4 s with the relay: one command per period, no timeouts.
        relay.wait(lambda: relay.clocks and relay.clocks[-1] >= EPOCH_NS + 4 * NS, 90, '4 s of /clock')
        relay.relaying = False
        stopped_at = relay.clocks[-1]
        t0 = time.monotonic()
        relay.wait(lambda: relay.clocks[-1] >= stopped_at + 2 * PERIOD_NS, 10, 'the clock after timeouts')
        waited = time.monotonic() - t0
        relay.relaying = True
        relay.wait(lambda: relay.clocks[-1] >= EPOCH_NS + 8 * NS, 60, 'the end of the run')
        time.sleep(0.5)
    finally:
        codes = [stop_ros_process(p) for p in (dynamics, controller) if p is not None]
        text = {k: p.read_text() for k, p in logs.items() if p.exists()}
        relay.close()
        print(text)
    assert codes == [0, 0], text
    # /clock in whole periods, never back, from the epoch on.
    # (Loop time zero is repeated until the first period, so that no node misses it.)
    clocks = relay.clocks[next(i for i, c in enumerate(relay.clocks) if c != EPOCH_NS) - 1:]
    assert set(relay.clocks[:len(relay.clocks) - len(clocks) + 1]) == {EPOCH_NS}
    steps = [b - a for a, b in zip(clocks, clocks[1:])]
    assert set(steps) == {PERIOD_NS}, sorted(set(steps))[:5]
    # Poses at 100 Hz: every 10 ms of the 8 s.
    stamps = sorted(relay.poses)
    assert stamps[0] == EPOCH_NS and stamps[-1] == EPOCH_NS + 8 * NS and len(stamps) == 801
    # Without commands the clock waited for the timeouts (0.5 s each) and said so: the
    # two periods about the last relayed clock. (On a starved machine a command can miss
    # its 0.5 s elsewhere too: a few more are tolerated.)
    assert waited > 0.4
    warnings = [m.msg for m in relay.rosout if m.name == 'loop_dynamics' and m.level == Log.WARN]
    timeouts = [w for w in warnings if 'no command for the period' in w]
    stopped_s = (stopped_at - EPOCH_NS) / NS
    starts = [float(w.split('from ')[1].split(' s')[0]) for w in timeouts]
    assert sum(abs(t - stopped_s) < 0.15 for t in starts) >= 2, (stopped_s, timeouts)
    assert len(timeouts) <= 6, timeouts
    # Every relayed estimate got its command, stamped as the estimate (the period it answers).
    cmd_stamps = {stamp_to_ns(c.header.stamp) for c in relay.commands}
    assert all(s % PERIOD_NS == PERIOD_NS // 2 for s in cmd_stamps)
    assert len(cmd_stamps) >= 70
    # The controller pulls the chaser from 31 m toward its 30 m hold point.
    y = [m.pose.position.y for m in relay.chaser]
    assert y[0] < -30.9 and y[-1] > y[0] + 0.5, (y[0], y[-1])


def test_real_time_paces_on_the_wall(tmp_path):
    """Real time: the clock keeps wall pace (commands or not) and late commands are counted."""
    cfg = tmp_path / 'loop.yaml'
    write_config(cfg, duration_s=4.0, mode='realtime')
    relay = Relay()
    env = {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1'}
    log = tmp_path / 'dynamics.log'
    dynamics = start_ros_process('lidar_sim_ros.loop.dynamics_node',
                                 ['-p', f'config_file:={cfg}', '-p', 'wait_for_peers:=false'], env, log)
    wall: list[float] = []
    try:
        relay.wait(lambda: relay.clocks, 60, 'the first /clock')
        relay.relaying = False     # no GNC at all: real time must not wait
        wall.append(time.monotonic())
        first = relay.clocks[-1]
        relay.wait(lambda: relay.clocks[-1] >= EPOCH_NS + 4 * NS, 30, 'the end of the run')
        wall.append(time.monotonic())
        last = relay.clocks[-1]
        relay.wait(lambda: 'done' in log.read_text(), 10, 'the summary')
    finally:
        code = stop_ros_process(dynamics)
        text = log.read_text()
        relay.close()
        print(text)
    assert code == 0, text
    rate = (last - first) / NS / (wall[1] - wall[0])
    assert 0.8 < rate < 1.1, rate          # simulated seconds per wall second
    stats = [line for line in text.splitlines() if ', late ' in line][-1]
    late = int(re.search(r', late (\d+)', stats).group(1))
    assert late >= 30, stats               # every period after the relay stopped was late


def _run_twice_leg(tmp_path, name: str, hostile: bool):
    """One short lock-step run (dynamics and controller processes, the relay as the
    navigation); with ``hostile``, a 1 kHz publisher on the command topic too. Returns the
    true chaser track (stamp, pose) and the dynamics' statistics."""
    import json
    import math

    from geometry_msgs.msg import WrenchStamped as Wrench
    from lidar_sim_ros.io.pointcloud import ns_to_stamp

    cfg = tmp_path / f'{name}.yaml'
    write_config(cfg, duration_s=3.0)
    stats = tmp_path / f'{name}_stats.json'
    relay = Relay()
    env = {**os.environ, 'ROS_DOMAIN_ID': str(DOMAIN_ID), 'PYTHONUNBUFFERED': '1'}
    logs = {k: tmp_path / f'{name}_{k}.log' for k in ('dynamics', 'controller')}
    sent = [0]
    if hostile:
        pub = relay.node.create_publisher(Wrench, '/chaser/force_command', QoSProfile(depth=100))
        kinds = [('lvlh', [0.0, 20.0, 0.0], 1000.0), ('lvlh', [20.0, 20.0, 20.0], -0.2),
                 ('lvlh', [math.nan, 0.0, 0.0], -0.05), ('lvlh', [1e9, 0.0, 0.0], -0.15),
                 ('base_link', [1.0, 0.0, 0.0], -0.05), ('lvlh', [math.inf, 0.0, 0.0], -0.05),
                 ('lvlh', [1e9, -1e9, 0.0], 0.1)]

        def attack():
            if not relay.clocks:
                return
            frame, force, offset_s = kinds[sent[0] % len(kinds)]
            msg = Wrench()
            msg.header.frame_id = frame
            msg.header.stamp = ns_to_stamp(relay.clocks[-1] + round(offset_s * NS), type(msg.header.stamp))
            msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = force
            pub.publish(msg)
            sent[0] += 1
        relay.node.create_timer(0.001, attack)
    controller = start_ros_process('lidar_sim_ros.loop.controller_node',
                                   ['-p', f'config_file:={cfg}', '-p', 'use_sim_time:=true'], env, logs['controller'])
    dynamics = None
    try:
        relay.wait(lambda: relay.node.count_publishers('/chaser/force_command') >= 1 + hostile, 60, 'the controller')
        dynamics = start_ros_process('lidar_sim_ros.loop.dynamics_node',
                                     ['-p', f'config_file:={cfg}', '-p', f'stats_file:={stats}', '-p',
                                      "wait_for_subscribers:=['/target/pose', '/chaser/attitude']"],
                                     env, logs['dynamics'])
        relay.wait(lambda: stats.exists(), 90, 'the end of the run')
    finally:
        codes = [stop_ros_process(p) for p in (dynamics, controller) if p is not None]
        text = {k: p.read_text() for k, p in logs.items() if p.exists()}
        relay.close()
        print(name, text)     # shown when the test fails
    assert codes == [0, 0], text
    track = [(stamp_to_ns(m.header.stamp), m.pose.position.x, m.pose.position.y, m.pose.position.z,
              m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w)
             for m in relay.chaser]
    return track, json.loads(stats.read_text()), sent[0], text


def test_two_lock_step_runs_are_identical_over_dds_even_under_attack(tmp_path):
    """The same seed twice over DDS, bit for bit, the second time with a 1 kHz publisher on
    /chaser/force_command sending far-future, stale, NaN, infinite, 1e9 N and wrong-frame
    commands: none is flown, none releases or stalls a period, each is counted by cause."""
    clean, clean_stats, _, _ = _run_twice_leg(tmp_path, 'clean', hostile=False)
    attacked, stats, sent, logs = _run_twice_leg(tmp_path, 'attacked', hostile=True)
    assert len(clean) == 30 and clean == attacked
    assert clean_stats['commands'] == stats['commands'] == 29       # every period after the first
    assert stats['timeouts'] == stats['startup_timeouts'] == clean_stats['timeouts'] == 0
    refused = stats['refused_commands']
    # (The attacker goes on after the run's statistics are written: it sent more than counted.)
    assert sent > 300 and sum(refused.values()) > 200, (sent, refused)
    assert all(refused[c] > 0 for c in ('future', 'stale', 'non_finite', 'frame')), refused
    assert 'refused force command stamped' in logs['dynamics'] and 'non_finite' in logs['dynamics']
    assert stats['timing_mode'] == 'lockstep' and stats['wall_s'] > 0
