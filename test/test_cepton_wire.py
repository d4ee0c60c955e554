"""Cepton's wire (io/cepton_wire.py, io/pcap.py): STDV packets checked against the
numbers of Cepton's public "Cepton Sensor Communication Specifications" (section 3,
"Point Data Packet"), written here as literals, and decoded by a small struct-based
reader written here from the specification, not with the module's dtypes.

Also two mutation survivors of issue 29 in the driver layout (core/driver_layout.py):
the SECOND_RETURN bit checked against Cepton's published value, and channel ids that
must follow their points when the frame is sorted by time.
"""
from __future__ import annotations

import struct

import numpy as np
import pytest

from lidar_sim_ros.io import cepton, cepton_wire
from lidar_sim_ros.io.pcap import PcapWriter, ipv4_checksum

# Cepton's published point flag values (specification, section 3, point flags; the same
# in cepton_sdk3.h): literals, not the module's constants.
SPEC_FLAGS = {'SATURATED': 1, 'BLOOMING': 2, 'FRAME_PARITY': 4, 'FRAME_BOUNDARY': 8,
              'SECOND_RETURN': 16, 'NO_RETURN': 32, 'NOISE': 64, 'BLOCKED': 128}
T0_US = 1_700_000_000_000_000


def decode(payload: bytes) -> tuple[dict, list[tuple]]:
    """STDV header V2 (24 bytes) and V0 points (10 bytes), by hand from the spec."""
    sig, hver, hsize, flags, ts, pver, psize, count, seq = struct.unpack_from(
        '<4sBBHQBBHI', payload, 0)
    header = dict(signature=sig, header_version=hver, header_size=hsize, flags=flags,
                  timestamp_us=ts, point_version=pver, point_size=psize, count=count, seq=seq)
    assert len(payload) == hsize + count * psize
    points = [struct.unpack_from('<hHhBBBB', payload, hsize + k * psize) for k in range(count)]
    return header, points


def absolute_times(header: dict, points: list[tuple]) -> list[int]:
    """Point time = header timestamp + the relative timestamps up to and including it."""
    return list(header['timestamp_us'] + np.cumsum([p[4] for p in points]))


def test_point_flags_are_cepton_published_values():
    """Issue 29 survivor: SECOND_RETURN on bit 3 (the SDK's FRAME_BOUNDARY) round-tripped
    because tests read the module's constant. Checked against the published values."""
    assert cepton.FLAGS == SPEC_FLAGS


def test_second_return_points_carry_the_published_bit():
    """A frame whose shots return twice: the driver layout flags the later return with
    16 (SECOND_RETURN), never 8 (FRAME_BOUNDARY, the SDK's own)."""
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.driver_layout import cepton_frame_points
    from lidar_sim_ros.core.pipeline import Frame
    sensor = load_scenario(REPO_SCENARIO).sensor
    n = 4
    frame = Frame(stamp_s=0.0, index=0, xyz_m=np.tile([5.0, 0, 0], (n, 1)),
                  range_m=np.full(n, 5.0), intensity=np.full(n, 0.1),
                  t_s=np.array([0.0, 0.0, 1e-5, 1e-5]), ring=np.array([3, 3, 4, 4]),
                  material=np.zeros(n, np.uint8), return_number=np.array([1, 2, 1, 2], np.uint8))
    pts = cepton_frame_points(frame, sensor, 1_000_000_000)
    assert list(pts['flags']) == [0, 16, 0, 16]


def test_channel_ids_follow_their_points_when_sorted_by_time(tmp_path):
    """Issue 29 survivor: channel_id not reordered with the points (20,278 of 21,120
    mislabelled). Independent reference: the scan pattern's laser of the shot fired at
    each point's time."""
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.driver_layout import cepton_frame_points
    from lidar_sim_ros.core.pipeline import Simulator
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    scenario = load_scenario(REPO_SCENARIO)
    sim = Simulator.from_scenario(scenario)
    frame = sim.simulate_frame(0.0, ScenarioTrajectory.from_config(scenario.config), 0)
    stamp_ns = 1_700_000_000 * 10**9
    pts = cepton_frame_points(frame, sim.sensor, stamp_ns, no_return=True)
    shot_us = (stamp_ns + np.rint(sim.shots.t_s * 1e9).astype(np.int64)) // 1000
    assert len(np.unique(shot_us)) == len(shot_us)       # one shot a microsecond at most
    laser_at = dict(zip(shot_us.tolist(), sim.shots.laser.tolist()))
    t_us = pts['timestamp_s'].astype(np.int64) * 1_000_000 + pts['timestamp_us']
    expected = np.array([laser_at[t] for t in t_us.tolist()])
    assert len(pts) == len(sim.shots)                     # every shot once (no_return)
    assert np.array_equal(pts['channel_id'], expected)


def test_header_and_point_layout_are_section_3():
    """One point, hand-encoded: x right, y forward, z up, 5 mm units; header V2."""
    state = cepton_wire.WireStream()
    # Our frame: 10 m forward, 0.5 m left, 0.25 m down -> Cepton x = -0.5 (right is +),
    # y = 10, z = -0.25 -> -100, 2000, -50 units.
    pts, t_abs = cepton_wire.stream_points(
        np.array([T0_US]), np.array([[10.0, 0.5, -0.25]]), np.array([0.30]), np.array([7]),
        np.array([SPEC_FLAGS['SATURATED']]), parity=False, last_t_us=None)
    (pkt,) = cepton_wire.packets(pts, t_abs, state)
    assert pkt.payload[:4] == b'STDV'
    header, points = decode(pkt.payload)
    assert header == dict(signature=b'STDV', header_version=2, header_size=24, flags=0,
                          timestamp_us=T0_US, point_version=0, point_size=10, count=1, seq=0)
    assert points == [(-100, 2000, -50, 30, 0, 7, 1)]
    assert len(pkt.payload) == 34 and pkt.t_us == T0_US
    assert state.sequence_id == 1


def test_reflectivity_code_linear_then_log():
    """0-127: 1 % steps; 128-255 log-spaced from 127 % to 5000 % (code 128 = 130.7 %,
    150 = 245.7 %, 200 = 1031.7 %, 255 = 5000 %: Cepton's published decoding)."""
    code = cepton_wire.reflectivity_code(np.array([0.0, 0.004, 0.3, 1.0, 1.27, 1.307, 2.457,
                                                   10.317, 50.0, 1e300, np.nan, -1.0, np.inf]))
    assert list(code) == [0, 0, 30, 100, 127, 128, 150, 200, 255, 255, 0, 0, 255]
    back = cepton_wire.reflectivity_from_code(np.array([0, 30, 127, 128, 150, 200, 255]))
    np.testing.assert_allclose(back, [0.0, 0.30, 1.27, 1.307, 2.457, 10.317, 50.0], atol=5e-4)
    every = np.arange(256)
    assert np.array_equal(cepton_wire.reflectivity_code(cepton_wire.reflectivity_from_code(every)),
                          every)


def test_packets_hold_at_most_144_points_and_times_are_exact():
    n = 300
    t = T0_US + np.arange(n) * 5          # 5 us apart
    xyz = np.column_stack([np.full(n, 12.0), np.zeros(n), np.zeros(n)])
    pts, t_abs = cepton_wire.stream_points(t, xyz, np.full(n, 0.2), np.arange(n) % 24,
                                           np.zeros(n), parity=True, last_t_us=T0_US - 3)
    pk = cepton_wire.packets(pts, t_abs, cepton_wire.WireStream(sequence_id=2**32 - 1))
    assert [decode(p.payload)[0]['count'] for p in pk] == [144, 144, 12]
    assert [decode(p.payload)[0]['seq'] for p in pk] == [2**32 - 1, 0, 1]
    times, flags, chans = [], [], []
    for p in pk:
        h, ps = decode(p.payload)
        times += absolute_times(h, ps)
        flags += [q[6] for q in ps]
        chans += [q[5] for q in ps]
        assert p.t_us == absolute_times(h, ps)[-1]
    assert times == list(t)
    assert set(flags) == {SPEC_FLAGS['FRAME_PARITY']}    # an odd frame: parity on every point
    assert chans == list(np.arange(n) % 24)


def test_gaps_over_255_us_get_no_return_fillers():
    """Gaps of 255, 256, 600 us: none, one and two fillers of 255 us, NO_RETURN."""
    t = T0_US + np.array([0, 255, 511, 1111])
    xyz = np.tile([5.0, 0, 0], (4, 1))
    pts, t_abs = cepton_wire.stream_points(t, xyz, np.full(4, 0.1), np.array([1, 2, 3, 4]),
                                           np.zeros(4), parity=False, last_t_us=None)
    rel = list(pts['relative_timestamp_us'])
    assert rel == [0, 255, 255, 1, 255, 255, 90]
    assert list(t_abs) == [T0_US, T0_US + 255, T0_US + 510, T0_US + 511, T0_US + 766,
                           T0_US + 1021, T0_US + 1111]
    filler = pts['flags'] == SPEC_FLAGS['NO_RETURN']
    assert list(filler) == [False, False, True, False, True, True, False]
    assert not pts['x'][filler].any() and not pts['y'][filler].any()


def test_fillers_before_a_frame_keep_the_previous_frames_parity():
    t = np.array([T0_US + 1000])
    pts, _ = cepton_wire.stream_points(t, np.array([[5.0, 0, 0]]), np.array([0.1]),
                                       np.array([0]), np.zeros(1), parity=True,
                                       last_t_us=T0_US)
    assert list(pts['flags']) == [32, 32, 32, 4]


def driver_frame(t0_us: int, n: int = 300) -> np.ndarray:
    """n points 10 us apart from t0_us, 12 m ahead, in the SDK3 driver's layout."""
    p = np.zeros(n, cepton.SDK3_DTYPE)
    t = t0_us + np.arange(n) * 10
    p['timestamp_s'], p['timestamp_us'] = t // 10**6, t % 10**6
    p['x'], p['intensity'] = 12.0, 0.3
    return p


@pytest.mark.parametrize('jump_us, restarts', [(999_000, 0), (1_000 * 10**6, 1),
                                               (-500 * 10**6, 1)])
def test_a_clock_jump_begins_the_stream_afresh(jump_us, restarts):
    """The node's clock jumping 1000 s ahead made 3.9 million fillers (27,238 packets,
    240 MB); one jumping back made every later frame raise 'before the previous point' until
    the clock passed the old time (no UDP output). A gap up to 1 s is still bridged."""
    state = cepton_wire.WireStream()
    cepton_wire.frame_packets(driver_frame(T0_US), state)
    t1 = T0_US + 2990 + jump_us
    pk = cepton_wire.frame_packets(driver_frame(t1), state)
    times, flags = [], []
    for p in pk:
        h, ps = decode(p.payload)
        times += absolute_times(h, ps)
        flags += [q[6] for q in ps]
    real = [t for t, f in zip(times, flags) if not f & SPEC_FLAGS['NO_RETURN']]
    assert real == list(t1 + np.arange(300) * 10)
    fillers = len(times) - 300
    assert fillers == (0 if restarts else (jump_us - 1) // 255)
    assert state.restarts == restarts
    assert set(f & SPEC_FLAGS['FRAME_PARITY'] for f, t in zip(flags, times) if t >= t1) == \
        {SPEC_FLAGS['FRAME_PARITY']}                   # the second frame: parity toggled


def test_unencodable_positions_go_as_no_return_and_bad_times_are_refused():
    t = T0_US + np.arange(4)
    xyz = np.array([[-1.0, 0, 0], [400.0, 0, 0], [5.0, 200.0, 0], [np.nan, 0, 0]])
    pts, _ = cepton_wire.stream_points(t, xyz, np.full(4, 0.5), np.zeros(4),
                                       np.full(4, SPEC_FLAGS['SATURATED']), False, None)
    assert set(pts['flags']) == {SPEC_FLAGS['NO_RETURN']}
    assert not pts['reflectivity'].any()
    with pytest.raises(ValueError, match='decrease'):
        cepton_wire.stream_points(t[::-1], xyz, np.zeros(4), np.zeros(4), np.zeros(4), False, None)
    with pytest.raises(ValueError, match='before the previous point'):
        cepton_wire.stream_points(t, xyz, np.zeros(4), np.zeros(4), np.zeros(4), False,
                                  int(t[-1]) + 1)


def test_pcap_records_are_ethernet_ipv4_udp(tmp_path):
    path = tmp_path / 'x.pcap'
    with PcapWriter(path, '192.168.1.201', '255.255.255.255', 8808) as w:
        w.write(T0_US + 7, b'STDVpayload')
    data = path.read_bytes()
    magic, vmaj, vmin, _, _, snap, link = struct.unpack_from('<IHHiIII', data, 0)
    assert (magic, vmaj, vmin, snap, link) == (0xA1B2C3D4, 2, 4, 65535, 1)
    sec, usec, incl, orig = struct.unpack_from('<IIII', data, 24)
    assert sec * 1_000_000 + usec == T0_US + 7 and incl == orig == 14 + 20 + 8 + 11
    frame = data[40:]
    assert frame[12:14] == b'\x08\x00'
    ip = frame[14:34]
    assert ip[0] == 0x45 and ip[9] == 17 and ipv4_checksum(ip) == 0
    assert ip[12:16] == bytes([192, 168, 1, 201]) and ip[16:20] == b'\xff' * 4
    sport, dport, ulen, _ = struct.unpack('!HHHH', frame[34:42])
    assert (sport, dport, ulen) == (8808, 8808, 8 + 11) and frame[42:] == b'STDVpayload'
    with pytest.raises(FileExistsError):
        PcapWriter(path).__enter__()


from datasets import REPO  # noqa: E402

REPO_SCENARIO = REPO / 'config' / 'scenario.yaml'
