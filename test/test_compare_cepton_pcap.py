"""A Cepton sensor's pcap as a recording (compare/recording/cepton_pcap.py): the decoder against
hand-packed packets (struct, from the specification's section 3), its refusals, and
``calibrate range-errors`` on a pcap with poses from a CSV: the same biases as from the bag.
``lidar-sim compare`` on ``simulate --pcap`` output (the same verdict as the bag of the same
frames) is in test_cepton_layout.py, beside that bag's own run."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from lidar_sim_ros.compare.recording.cepton_pcap import (PcapError, PcapStats, frame_count,
                                                         is_pcap, iter_frames, read_pose_csv)
from lidar_sim_ros.io.pcap import PcapWriter, udp_frame


T0_US = 1_700_000_000_000_000


def stdv(t_us: int, points: list[tuple], version: int = 2) -> bytes:
    """Header V1 (20 bytes) or V2 (24), point V0: packed by hand."""
    head = struct.pack('<4sBBHQBBH', b'STDV', version, 20 if version == 1 else 24, 0, t_us,
                       0, 10, len(points))
    if version == 2:
        head += struct.pack('<I', 0)
    return head + b''.join(struct.pack('<hHhBBBB', *p) for p in points)


def write_pcap(path, payloads, port=8808):
    with PcapWriter(path, dst_port=port) as w:
        for t, p in payloads:
            w.write(t, p)
    return path


def test_decoder_reads_hand_packed_packets(tmp_path):
    # Cepton x right 100 (0.5 m), y forward 2000 (10 m), z up -50: ours x 10, y -0.5, z -0.25.
    a = [(100, 2000, -50, 30, 0, 7, 0), (0, 0, 0, 0, 200, 3, 32)]
    b = [(-20, 1000, 10, 200, 5, 1, 4 | 16), (-20, 1000, 10, 128, 0, 1, 4 | 16 | 8)]
    path = write_pcap(tmp_path / 'a.pcap', [(T0_US, stdv(T0_US, a)),
                                             (T0_US + 300, stdv(T0_US + 200, b, version=1)),
                                             (T0_US + 400, b'INFZ' + bytes(100))])
    assert is_pcap(path)
    stats = PcapStats()
    frames = list(iter_frames(path, stats=stats))
    assert len(frames) == 2 and stats.frames == 2 and stats.stdv_packets == 2
    assert stats.skipped == {'not STDV (INFO or other)': 1}
    f0, f1 = (f.points for f in frames)
    np.testing.assert_allclose(np.column_stack([f0['x'], f0['y'], f0['z']])[0], [10, -0.5, -0.25])
    assert list(f0['timestamp_us'] + (f0['timestamp_s'] - T0_US // 10**6) * 10**6) == [0, 200]
    assert list(f0['channel_id']) == [7, 3] and list(f0['flags']) == [0, 32]
    np.testing.assert_allclose(f0['intensity'], [0.30, 0.0], atol=1e-6)
    # Second packet: header V1, relative times 5 and 0 from 200 us; parity 1: a new frame.
    t1 = (f1['timestamp_s'].astype(np.int64) * 10**6 + f1['timestamp_us']) - T0_US
    assert list(t1) == [205, 205]
    np.testing.assert_allclose(f1['intensity'], [10.317, 1.307], atol=1e-3)
    assert list(f1['flags']) == [20, 20]              # FRAME_BOUNDARY is the SDK's: cleared
    assert frames[1].stamp_ns == (T0_US + 205) * 1000


def test_other_traffic_and_bad_files(tmp_path):
    good = stdv(T0_US, [(0, 100, 0, 1, 0, 0, 0)])
    path = write_pcap(tmp_path / 'other.pcap', [(T0_US, good)], port=2368)
    assert frame_count(path) == 0 and frame_count(path, port=2368) == 1
    # An 802.1Q-tagged frame and an IPv4 fragment, written as raw records.
    frame = udp_frame(good, '10.0.0.2', '10.0.0.1', 8808, 8808)
    tagged = frame[:12] + b'\x81\x00\x00\x05' + frame[12:]
    frag = bytearray(frame)
    frag[14 + 6] |= 0x20                                # more fragments
    raw = tmp_path / 'raw.pcap'
    with open(raw, 'wb') as f:
        f.write(struct.pack('<IHHiIII', 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
        for rec in (tagged, bytes(frag)):
            f.write(struct.pack('<IIII', 1, 0, len(rec), len(rec)) + rec)
    stats = PcapStats()
    assert len(list(iter_frames(raw, stats=stats))) == 1
    assert stats.skipped == {'IPv4 fragment': 1}
    ng = tmp_path / 'x.pcapng'
    ng.write_bytes(b'\x0a\x0d\x0d\x0a' + bytes(60))
    with pytest.raises(PcapError, match='pcapng'):
        list(iter_frames(ng))
    bad = tmp_path / 'bad.pcap'
    bad.write_bytes(struct.pack('<IHHiIII', 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)
                    + struct.pack('<IIII', 0, 0, 10**9, 10**9))
    with pytest.raises(PcapError, match='corrupt'):
        list(iter_frames(bad))


def test_header_times_beyond_2_31_s_are_skipped_and_counted(tmp_path):
    """A header timestamp of 2^64 - 1 us overflowed int64 (a traceback); 2^62 us wrapped the
    driver layout's int32 seconds to a negative time (rc 0, a wrong stamp)."""
    pt = [(0, 100, 0, 1, 0, 0, 0)]
    path = write_pcap(tmp_path / 'far.pcap', [(T0_US, stdv(2**64 - 1, pt)), (T0_US, stdv(2**62, pt)),
                                               (T0_US, stdv(2**31 * 10**6 - 1, pt)),
                                               (T0_US, stdv(T0_US, pt))])
    stats = PcapStats()
    frames = list(iter_frames(path, stats=stats))
    assert stats.skipped == {'STDV timestamp beyond 2^31 s': 3} and stats.stdv_packets == 1
    assert [f.stamp_ns for f in frames] == [T0_US * 1000]


@pytest.mark.parametrize('cut', [7, 16 + 30])
def test_a_capture_cut_short_keeps_its_whole_records_and_counts_the_cut(tmp_path, cut):
    """A record header or body cut by the end of the file (a capture stopped mid-write)
    ends the pcap; before, silently (no count said the file was cut)."""
    pt = [(0, 100, 0, 1, 0, 0, 0)]
    path = write_pcap(tmp_path / 'cut.pcap', [(T0_US, stdv(T0_US, pt)),
                                               (T0_US + 10, stdv(T0_US + 10, pt))])
    data = path.read_bytes()
    last = 16 + len(udp_frame_of(stdv(T0_US + 10, pt)))
    path.write_bytes(data[:len(data) - last + cut])
    stats = PcapStats()
    frames = list(iter_frames(path, stats=stats))
    assert stats.skipped == {'truncated record at the end': 1} and stats.stdv_packets == 1
    assert [len(f.points) for f in frames] == [1]


def udp_frame_of(payload: bytes) -> bytes:
    from lidar_sim_ros.io.pcap import udp_frame
    return udp_frame(payload, '192.168.1.201', '255.255.255.255', 8808, 8808)


def test_pose_csv_errors_name_file_and_row(tmp_path):
    p = tmp_path / 'p.csv'
    p.write_text('t,x,y,z\n1,2,3,4\n')
    with pytest.raises(PcapError, match='header must be t_s,x_m'):
        read_pose_csv(p)
    p.write_text('t_s,x_m,y_m,z_m,qx,qy,qz,qw\n1,2,3,4,0,0,0,1\n2,nan,3,4,0,0,0,1\n')
    with pytest.raises(PcapError, match='row 3'):
        read_pose_csv(p)
    p.write_text('t_s,x_m,y_m,z_m,qx,qy,qz,qw\n2,1,0,0,0,0,0,1\n1,5,0,0,0,0,0,1\n')
    s = read_pose_csv(p)
    assert list(s.stamp_ns) == [10**9, 2 * 10**9] and s.position_m[0, 0] == 5


@pytest.mark.parametrize('row, match', [
    ('5,1e300,0,0,0,0,0,1', r'row 3 has a position component beyond 100000 m'),
    ('5,10,0,0,0,0,0,0', r'row 3 has a quaternion whose norm is not within 0.01 of 1'),
    ('5,10,0,0,0,0,0,5', r'row 3 has a quaternion whose norm'),
    ('1.0,11,0,0,0,0,0,1', r'rows 2 and 3 have the same time 1.0 s'),
    ('1e300,10,0,0,0,0,0,1', r'row 3 has a time beyond 2\^31 s'),
    ('\u0661,10,0,0,0,0,0,1', r'could not convert'),
])
def test_pose_csv_absurd_rows_are_refused_naming_the_row(tmp_path, row, match):
    """Before: a 1e300 m position and a zero or non-unit quaternion were read at rc 0 (compare
    then blamed the pcap's '/target/pose' topic, or matched no ray), two poses at one time
    were both kept (the interpolation picked one)."""
    p = tmp_path / 'p.csv'
    p.write_text(f't_s,x_m,y_m,z_m,qx,qy,qz,qw\n1,10,0,0,0,0,0,1\n{row}\n', encoding='utf-8')
    with pytest.raises(PcapError, match=match) as err:
        read_pose_csv(p)
    assert str(p) in str(err.value)


def test_pose_csv_text_a_spreadsheet_writes(tmp_path):
    """A byte-order mark (Excel's 'CSV UTF-8') was read as part of the header and refused;
    a Latin-1 byte gave "'utf-8' codec can't decode byte 0xe9" naming no file; a file
    without a newline was read whole as its header line."""
    p = tmp_path / 'p.csv'
    p.write_bytes('\ufefft_s,x_m,y_m,z_m,qx,qy,qz,qw\r\n1,10,0,0,0,0,0,1\r\n'.encode())
    assert list(read_pose_csv(p).stamp_ns) == [10**9]
    p.write_bytes(b't_s,x_m,y_m,z_m,qx,qy,qz,qw\n1,10,0,0,0,0,0,1\n# caf\xe9\n')
    with pytest.raises(PcapError, match=f"{p}: not UTF-8 text"):
        read_pose_csv(p)
    p.write_bytes(b'x' * 1_000_000)
    with pytest.raises(PcapError, match='header must be') as err:
        read_pose_csv(p)
    assert len(str(err.value)) < 500


def test_pose_csv_rows_are_bounded_and_quaternions_normalised(tmp_path, monkeypatch):
    from lidar_sim_ros.compare.recording import cepton_pcap
    p = tmp_path / 'p.csv'
    p.write_text('t_s,x_m,y_m,z_m,qx,qy,qz,qw\n' + ''.join(
        f'{t},10,0,0,0,0,0.6,0.805\n' for t in range(4)))
    s = read_pose_csv(p)                                # |q| = 1.0040: within 0.01, normalised
    np.testing.assert_allclose(s.quat_xyzw[0], [0, 0, 0.6 / 1.00401, 0.805 / 1.00401], rtol=1e-5)
    monkeypatch.setattr(cepton_pcap, 'MAX_POSE_ROWS', 3)
    with pytest.raises(PcapError, match='more than 3 rows'):
        read_pose_csv(p)


# compare on ``simulate --pcap`` output with poses from the bag or a CSV (the bag's verdict)
# and the CLI refusing a pcap without --poses: test_cepton_layout.py, whose walk bag is
# the same frames (its compare of the bag is the one the pcap's verdict is checked against).


def test_calibrate_range_errors_from_a_pcap(tmp_path):
    """The static plate lab of test_calibrate_range.py sent as a Cepton sensor would, with
    its poses in a CSV: the same per-material biases as from its bag."""
    from lidar_sim_ros.calibrate.range_errors import run_range_errors
    from lidar_sim_ros.io.cepton import cepton_points
    from lidar_sim_ros.io.cepton_wire import WireStream, frame_packets
    from test_calibrate_range import (TRUTH, materials_yaml, simulate_frames, write_bag,
                                      write_plate)
    mesh = write_plate(tmp_path)
    frames = simulate_frames(mesh)
    state, rows = WireStream(), {}
    with PcapWriter(tmp_path / 'lab.pcap') as w:
        for stamp, (pose_ns, pos, q), pts in frames:
            rows[pose_ns] = [pose_ns / 1e9, *pos, *q]
            order = np.argsort(pts['t'], kind='stable')
            p = pts[order]
            xyz = np.column_stack([p['x'], p['y'], p['z']]).astype(float)
            t_ns = stamp + np.round(p['t'] * 1e9).astype(np.int64)
            driver = cepton_points(xyz, np.full(len(p), 0.3), t_ns, np.zeros(len(p)), p['ring'])
            for pkt in frame_packets(driver, state):
                w.write(pkt.t_us, pkt.payload)
    csv = tmp_path / 'poses.csv'
    np.savetxt(csv, np.array(list(rows.values())), delimiter=',', fmt='%.9f',
               header='t_s,x_m,y_m,z_m,qx,qy,qz,qw', comments='')
    mats = materials_yaml(tmp_path)
    from_pcap = run_range_errors(tmp_path / 'lab.pcap', mesh, tmp_path / 'a.yaml',
                                 materials=mats, poses_from=csv)
    from_bag = run_range_errors(write_bag(tmp_path / 'bag', frames), mesh, tmp_path / 'b.yaml',
                                materials=mats)
    for name, truth in TRUTH.items():
        a = from_pcap.written[name]['bias_m']
        b = from_bag.written[name]['bias_m']
        assert a == pytest.approx(b, abs=0.002) and a == pytest.approx(truth['bias_m'], abs=0.006)


def test_what_the_reader_skipped_is_in_the_notes(tmp_path):
    """Packets skipped while reading a pcap (INFO, a fragment, a cut...) reach the
    comparison's notes (terminal and summary.json), not only the reader's counters."""
    from lidar_sim_ros.compare.recording.measurements import load_measurements
    a = [(100, 2000, -50, 30, 0, 7, 0)] * 40
    b = [(100, 2000, -50, 30, 0, 7, 4)] * 40                 # parity 1: the second frame
    pcap = write_pcap(tmp_path / 'a.pcap', [(T0_US, stdv(T0_US, a)),
                                            (T0_US + 50_000, b'INFZ' + bytes(100)),
                                            (T0_US + 100_000, stdv(T0_US + 100_000, b))])
    csv = tmp_path / 'poses.csv'
    t0 = T0_US / 1e6
    csv.write_text('t_s,x_m,y_m,z_m,qx,qy,qz,qw\n'
                   f'{t0 - 1:.6f},10,0,0,0,0,0,1\n{t0 + 1:.6f},10,0,0,0,0,0,1\n')
    meas = load_measurements(pcap, poses_from=csv)
    assert ('pcap: 2 STDV packet(s) read into 2 frame(s); skipped: 1 not STDV (INFO or other)'
            in meas.notes), meas.notes
