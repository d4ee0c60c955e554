"""The node's Cepton UDP output (ros/cepton_udp.py), live on loopback: simulated frames
handed to the sender as the node's frame timer does, paced at the shots' times, and
Cepton's SDK2 (the optional extra [cepton], a child process listening on a private port)
decodes every point. Serial (test/conftest.py SERIAL_MODULES): its timing matters.
Also the sender's parameter checks and its never-blocking hand-over."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.driver_layout import wire_packets
from lidar_sim_ros.ros import cepton_udp
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.ros.cepton_udp import CeptonUdpSender, UdpConfigError, check_parameters

from datasets import REPO
from test_cepton_sdk import CHILD, check_points, expected, sdk_or_skip

FRAMES = 5
PERIOD_NS = 100_000_000
pytestmark = pytest.mark.timeout(180)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


@pytest.mark.parametrize('address, port, frames, match', [
    ('example.com', 8808, 4, 'cepton_udp_address'), ('1.2.3', 8808, 4, 'cepton_udp_address'),
    ('0.0.0.0', 8808, 4, 'cepton_udp_address.*where a driver listens'),
    ('127.0.0.1', 0, 4, 'cepton_udp_port'), ('127.0.0.1', 70000, 4, 'cepton_udp_port'),
    ('127.0.0.1', 8808, 0, 'cepton_udp_queue_frames')])
def test_bad_parameters_are_named(address, port, frames, match):
    with pytest.raises(UdpConfigError, match=match):
        check_parameters(address, port, frames)


def test_submit_never_blocks_and_counts_dropped_frames():
    """A sender stuck on its first frame (clock standing still): further frames beyond
    the queue are dropped at once, counted."""
    stuck = CeptonUdpSender('127.0.0.1', free_port(), lambda f, s, st: [
        type('P', (), {'t_us': 0, 'payload': b'x'})(), type('P', (), {'t_us': 10**9, 'payload': b'y'})()],
        now_ns=lambda: 0, sim_time=True, queue_frames=2)
    try:
        t0 = time.perf_counter()
        results = [stuck.submit(object(), 0) for _ in range(50)]
        assert time.perf_counter() - t0 < 0.05
        time.sleep(0.2)
        stats = stuck.take_stats()
        assert results.count(False) >= 47 and stats['dropped_frames'] == results.count(False)
    finally:
        stuck.close()


def test_live_udp_decoded_by_sdk2(tmp_path):
    sdk_or_skip('cepton_sdk2')
    scenario = load_scenario(REPO / 'config' / 'scenario.yaml')
    sim = Simulator.from_scenario(scenario)
    trajectory = ScenarioTrajectory.from_config(scenario.config)
    port = free_port()
    env = {**os.environ, 'HOME': str(tmp_path), 'XDG_CACHE_HOME': str(tmp_path / 'cache')}
    out = tmp_path / 'live.npz'
    child = subprocess.Popen([sys.executable, str(CHILD), 'sdk2', 'udp', str(port), str(out),
                              '6', '100'], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and 'READY' not in (child.stdout.readline() or ''):
            assert child.poll() is None, child.stderr.read()[-2000:]
        frames = [sim.simulate_frame(k * sim.frame_period_s, trajectory, k) for k in range(FRAMES)]
        base_ns = (time.time_ns() // PERIOD_NS + 1) * PERIOD_NS
        stamps = [base_ns + k * PERIOD_NS for k in range(FRAMES)]
        sender = CeptonUdpSender('127.0.0.1', port,
                                 lambda f, start, st: wire_packets(f, sim, start, st),
                                 time.time_ns, queue_frames=FRAMES)
        t0 = time.monotonic()
        for frame, stamp in zip(frames, stamps):
            assert sender.submit(frame, stamp)
        sent = {'frames': 0, 'packets': 0, 'errors': 0}
        while sent['frames'] < FRAMES and time.monotonic() - t0 < 10:
            time.sleep(0.01)
            for k, v in sender.take_stats().items():
                if k in sent:
                    sent[k] += v
        elapsed = time.monotonic() - t0
        sender.close()
        stdout, stderr = child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == 0, stderr[-2000:]
    assert sent['frames'] == FRAMES and sent['errors'] == 0
    # Paced at the shots' times: five frames of 0.1 s take ~0.5 s, not one burst.
    assert elapsed > 0.35, elapsed
    with np.load(out) as d:
        sdk = {k: d[k] for k in d.files}
    exp = expected({'frames': frames, 'stamps_ns': stamps, 'sensor': sim.sensor,
                    'shots': sim.shots})
    res = check_points(sdk, exp, stamps)
    # Every decoded point matched (check_points); whole frames: SDK2 holds the last one, and
    # a starved receiver on a loaded machine may lose a datagram of another.
    complete = [k for k, n in res['per_frame'].items() if n == len(sim.shots)]
    assert len(complete) >= FRAMES - 2, res['per_frame']


def test_paced_on_the_node_clock_under_sim_time():
    """Under use_sim_time the packets follow /clock: each leaves only when the clock has
    advanced by its time since the frame's first packet."""
    from lidar_sim_ros.io.cepton_wire import Packet
    clock = {'ns': 5_000_000_000}
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(('127.0.0.1', 0))
    rx.settimeout(0.3)
    packets = [Packet(1_000_000, b'a'), Packet(1_050_000, b'b'), Packet(1_100_000, b'c')]
    sender = CeptonUdpSender('127.0.0.1', rx.getsockname()[1], lambda f, s, st: packets,
                             now_ns=lambda: clock['ns'], sim_time=True)

    def received() -> list[bytes]:
        got = []
        try:
            while True:
                got.append(rx.recv(100))
        except socket.timeout:
            return got
    try:
        assert sender.submit(object(), 0)
        assert received() == [b'a']                      # due at once
        clock['ns'] += 49_999_000
        assert received() == []                          # 1 us early
        clock['ns'] += 1_000
        assert received() == [b'b']
        clock['ns'] += 10**9
        assert received() == [b'c']
    finally:
        sender.close()
        rx.close()


def test_a_clock_jumping_back_keeps_the_stream_going_and_is_counted():
    """Before: after the node clock jumped back 500 s (a sim restarting its /clock, a wall
    clock stepped), every frame raised 'before the previous point': no packet went out
    until the clock passed the old time, only 'send errors' said so."""
    from lidar_sim_ros.io.cepton_wire import frame_packets
    from test_cepton_wire import T0_US, decode, driver_frame
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(('127.0.0.1', 0))
    rx.settimeout(0.5)
    sender = CeptonUdpSender('127.0.0.1', rx.getsockname()[1],
                             lambda frame, start_ns, state: frame_packets(frame, state),
                             now_ns=lambda: 2**62, sim_time=True)
    try:
        back = T0_US - 500 * 10**6
        # (first point, header time): a new stream's header carries its first point's
        # time; a continuing one's the previous point's (10 us before).
        for t0, header_us in ((T0_US, T0_US), (back, back), (back + 1440, back + 1430)):
            assert sender.submit(driver_frame(t0, n=144), 0)
            header, _ = decode(rx.recv(2000))
            assert header['timestamp_us'] == header_us and header['count'] == 144
        time.sleep(0.1)
        stats = sender.take_stats()
        assert stats['errors'] == 0 and stats['restarts'] == 1 and stats['packets'] == 3
        assert 'stream begun afresh 1 times' in cepton_udp.stats_text(stats)
    finally:
        sender.close()
        rx.close()


def test_the_udp_parameters_cannot_change_at_run_time():
    """Where the packets go is the operator's start-up choice: set_parameters (what a
    remote `ros2 param set` calls) cannot switch the output on or point it elsewhere."""
    import rclpy
    from rclpy.parameter import Parameter

    from lidar_sim_ros.ros.lidar_sim_node import LidarSimNode
    from conftest import private_domain_id
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=private_domain_id(160, 20))
    node = LidarSimNode(context=ctx)
    try:
        node.setup()
        assert node.udp is None
        for name, kind, value in (('cepton_udp', Parameter.Type.BOOL, True),
                                  ('cepton_udp_address', Parameter.Type.STRING, '255.255.255.255'),
                                  ('cepton_udp_port', Parameter.Type.INTEGER, 9),
                                  ('cepton_udp_queue_frames', Parameter.Type.INTEGER, 100)):
            result = node.set_parameters([Parameter(name, kind, value)])[0]
            assert not result.successful and 'read-only' in result.reason, (name, result.reason)
        assert node.udp is None and node.get_parameter('cepton_udp_address').value == '127.0.0.1'
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
