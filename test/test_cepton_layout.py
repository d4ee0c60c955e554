"""The Cepton driver's layouts: our clouds in it (io/cepton.py, core/driver_layout.py) and
recordings in it read by compare (compare/recording/fields.py, compare/recording/measurements.py).

The decoder below is written here from the driver's published field list, by field name
and PointField datatype (as sensor_msgs_py.point_cloud2.read_points decodes), not with
lidar_sim_ros.io.pointcloud.
"""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from lidar_sim_ros.compare.recording.fields import FieldError, point_time_ns, resolve_fields
from lidar_sim_ros.compare.recording.measurements import find_time_field, load_measurements
from lidar_sim_ros.compare.run import CompareOptions, run_compare
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.driver_layout import reflectivity_estimate
from lidar_sim_ros.io.bag import read_clouds, read_poses
from lidar_sim_ros.offline import simulate_to_bag
from lidar_sim_ros.core.driver_layout import OutputLayout

from datasets import REPO

# The SDK3 driver's fields, in order (issue 20): name -> PointField datatype code.
DRIVER_FIELDS = [('x', 7), ('y', 7), ('z', 7), ('intensity', 7), ('timestamp_s', 5),
                 ('timestamp_us', 5), ('flags', 4), ('channel_id', 4)]
_STRUCT = {2: 'B', 4: 'H', 5: 'i', 7: 'f', 8: 'd'}      # PointField code -> struct letter
SATURATED, NO_RETURN = 1, 32
FRAMES = 2


def read_points(msg) -> list[dict]:
    """A subscriber's decoder: by field name and datatype, point by point."""
    data = bytes(np.asarray(msg.data, np.uint8))
    fmt = '>' if msg.is_bigendian else '<'
    out = []
    for k in range(msg.width * msg.height):
        base = k * msg.point_step
        out.append({f.name: struct.unpack_from(fmt + _STRUCT[f.datatype], data,
                                               base + f.offset)[0] for f in msg.fields})
    return out


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    root = tmp_path_factory.mktemp('cepton')
    scenario = REPO / 'config' / 'scenario.yaml'
    native = simulate_to_bag(scenario, root / 'native', FRAMES, figures=False)
    cep = simulate_to_bag(scenario, root / 'cepton', FRAMES, figures=False,
                          layout=OutputLayout(point_layout='cepton', no_return_points=True))
    walk = ['range_walk={k_m: 0.02}']
    walk_native = simulate_to_bag(scenario, root / 'walk_native', FRAMES, figures=False,
                                  effects=walk)
    # The same frames also as the sensor sends them (a pcap) and their poses as a CSV
    # (test_compare_cepton_pcap.py's recording): their verdict is the bag's.
    walk_cep = simulate_to_bag(scenario, root / 'walk_cepton', FRAMES, figures=False,
                               effects=walk, layout=OutputLayout(point_layout='cepton'),
                               pcap=root / 'walk_cepton.pcap')
    poses = read_poses(walk_cep.bag_path)
    csv = root / 'poses.csv'
    rows = np.column_stack([poses.stamp_ns / 1e9, poses.position_m, poses.quat_xyzw])
    np.savetxt(csv, rows, delimiter=',', fmt='%.9f', header='t_s,x_m,y_m,z_m,qx,qy,qz,qw',
               comments='')
    return {'native': native.bag_path, 'cepton': cep.bag_path, 'root': root,
            'walk_native': walk_native.bag_path, 'walk_cepton': walk_cep.bag_path,
            'walk_pcap': root / 'walk_cepton.pcap', 'walk_csv': csv,
            'mesh': load_scenario(scenario).mesh_path, 'walk_compares': {}}


WALK_CANDIDATES = ['range_walk', 'incidence_angle', 'laser_bias']


def walk_compare(bags, kind: str) -> dict:
    """compare's summary on the walk's frames read as ``kind`` (the native bag, the Cepton
    driver's bag, its pcap with the bag's poses), on 6000 points with
    WALK_CANDIDATES; each run once in the module."""
    done = bags['walk_compares']
    if kind not in done:
        source = {'native': dict(bag=bags['walk_native'], cloud_topic='/lidar/points'),
                  'cepton': dict(bag=bags['walk_cepton'], cloud_topic='/cepton_pcl2'),
                  'pcap': dict(bag=bags['walk_pcap'], poses=bags['walk_cepton'])}[kind]
        done[kind] = run_compare(CompareOptions(
            mesh=bags['mesh'], out=bags['root'] / f'out_walk_{kind}', max_points=6000,
            report=False, progress=False, candidates=WALK_CANDIDATES, **source)).summary
    return done[kind]


def test_cepton_cloud_is_the_driver_layout(bags):
    from rosbags.highlevel import AnyReader
    with AnyReader([bags['cepton']]) as reader:
        conns = [c for c in reader.connections if c.topic == '/cepton_pcl2']
        assert conns, [c.topic for c in reader.connections]
        c, _, raw = next(reader.messages(connections=conns))
        msg = reader.deserialize(raw, c.msgtype)
    assert msg.header.frame_id == 'cepton3'
    assert [(f.name, f.datatype) for f in msg.fields] == DRIVER_FIELDS
    assert not msg.is_bigendian and all(f.count == 1 for f in msg.fields)
    pts = read_points(msg)
    stamp_us = msg.header.stamp.sec * 1_000_000 + msg.header.stamp.nanosec // 1000
    t_us = np.array([p['timestamp_s'] * 1_000_000 + p['timestamp_us'] for p in pts])
    # Header stamp = frame start: every point at or after it, within one frame (0.1 s).
    assert t_us.min() >= stamp_us and t_us.max() - stamp_us < 100_000
    flags = np.array([p['flags'] for p in pts])
    inten = np.array([p['intensity'] for p in pts])
    # Reflectivity in 1 % steps.
    assert np.allclose(inten * 100, np.round(inten * 100), atol=1e-3)
    ret = flags == 0
    assert ret.sum() > 1000 and np.any(flags & SATURATED) and np.any(flags & NO_RETURN)
    xyz = np.array([[p['x'], p['y'], p['z']] for p in pts])
    assert np.all(xyz[flags == NO_RETURN] == 0) and np.all(np.linalg.norm(xyz[ret], axis=1) > 1)
    # The same returns as the native layout of the same frame (same seed, same shots).
    native = read_clouds(bags['native'])[0].points
    assert ret.sum() == len(native)


def test_reflectivity_reads_a_30_percent_lambertian_plate_as_030():
    sensor = load_scenario(REPO / 'config' / 'scenario.yaml').sensor
    o = sensor.optics
    for r in (2.0, 20.0, 150.0):
        # Hand link budget of a Lambertian plate at normal incidence (config comment):
        # P = P0 tau_t tau_r (rho / pi) pi (D/2)^2 / r^2.
        p = (o.peak_power_w * o.transmit_efficiency * o.receive_efficiency * 0.30
             * (o.aperture_diameter_m / 2) ** 2 / r ** 2)
        assert reflectivity_estimate(p, r, sensor) == pytest.approx(0.30, rel=1e-9)


def test_fields_of_the_sdk2_driver_and_named_fields():
    sdk2 = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('reflectivity', '<f4'),
                     ('relative_timestamp', 'u1'), ('flags', 'u1'), ('channel_id', 'u1'),
                     ('valid', 'u1')])
    fm = resolve_fields(sdk2, find_time=find_time_field)
    assert (fm.intensity, fm.laser, fm.flags, fm.valid, fm.time) == \
        ('reflectivity', 'channel_id', 'flags', 'valid', ())
    assert 'relative_timestamp' in fm.ignored and fm.layout == 'cepton sdk2 driver'
    text = '\n'.join(fm.lines())
    assert 'relative_timestamp (UINT8): ignored' in text and 'reflectivity (FLOAT32)' in text
    other = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('amp', '<u2'),
                      ('sec', '<u4'), ('nsec', '<u4'), ('beam', 'u1')])
    fm = resolve_fields(other, 'amp', 'sec,nsec', 'beam', find_time_field)
    assert (fm.intensity, fm.time, fm.laser) == ('amp', ('sec', 'nsec'), 'beam')
    rec = np.zeros(2, other)
    rec['sec'], rec['nsec'] = 1_700_000_000, [5, 999_999_999]
    ns, unit = point_time_ns(rec, ('sec', 'nsec'))
    assert unit == 'ns' and ns.tolist() == [1_700_000_000_000_000_005, 1_700_000_000_999_999_999]
    with pytest.raises(FieldError, match="--time-field 'stamp'.*fields present"):
        resolve_fields(other, time_field='stamp')


def test_compare_reads_the_cepton_bag_like_the_native_one(bags, capsys):
    meas = load_measurements(bags['cepton'], '/cepton_pcl2')
    assert meas.time_source == 'field'
    assert meas.time_field['name'] == 'timestamp_s+timestamp_us'
    assert meas.known_misses > 1000 and meas.saturated.sum() > 0
    native = load_measurements(bags['native'])
    # Point times agree with ours to the driver's microsecond.
    n_ret = ~meas.saturated
    assert np.allclose(np.sort(meas.t_frame_s[n_ret]), np.sort(native.t_frame_s), atol=1.1e-6)
    summaries = {}
    for kind, topic in (('native', '/lidar/points'), ('cepton', '/cepton_pcl2')):
        res = run_compare(CompareOptions(
            bag=bags[kind], mesh=bags['mesh'], out=bags['root'] / f'out_{kind}',
            cloud_topic=topic, max_points=6000, report=False, progress=False,
            candidates=['time_offset', 'range_walk']))
        summaries[kind] = res.summary
    nat, cep = summaries['native'], summaries['cepton']
    assert cep['point_time_field']['name'] == 'timestamp_s+timestamp_us'
    assert nat['missing_effect'] is None and cep['missing_effect'] is None
    assert cep['point_fields']['layout'] == 'cepton sdk3 driver'
    assert any('range-compensated reflectivity' in line for line in cep['point_fields']['lines'])
    assert 'grows with the received power' in nat['point_fields']['lines'][-1]
    assert cep['range_rmse_m'] == pytest.approx(nat['range_rmse_m'], rel=0.1)
    # Our sensor saturates exactly at the configured power: every SATURATED return the
    # model places is at or above it.
    sat = cep['point_flags']['saturation']
    assert sat['points'] > 0 and sat['saturated_below_configured'] == 0.0
    assert nat['point_flags']['saturation'] is None
    json.dumps(cep)


def test_saturated_returns_below_the_configured_level_say_so():
    from lidar_sim_ros.compare.recording.fields import saturation_evidence, saturation_line
    power = np.array([1e-5, 2e-5, 5e-5, 1e-6, 2e-6])
    ev = saturation_evidence(np.array([True, True, True, False, False]), power, 3e-4)
    assert ev['saturated_below_configured'] == 1.0
    assert 'saturates earlier than configured' in saturation_line(ev)
    ev = saturation_evidence(np.array([True, False, False, False, False]), power * 100, 3e-4)
    assert ev['saturated_below_configured'] == 0.0 and 'earlier' not in saturation_line(ev)


def test_same_verdict_on_a_walk_in_both_layouts(bags):
    """The same simulated frames with a range walk (k_m 0.02): both layouts name it and fit
    the same slope and figures, up to what the 1 % reflectivity steps lose of the power."""
    out = {f'walk_{kind}': walk_compare(bags, kind) for kind in ('native', 'cepton')}
    nat, cep = out['walk_native'], out['walk_cepton']
    assert nat['missing_effect'] == cep['missing_effect'] == 'range_walk'
    k = {n: next(c for c in s['candidates'] if c['name'] == 'range_walk')
         for n, s in out.items()}
    assert k['walk_native']['params']['k_m'] == pytest.approx(0.02, rel=0.05)
    assert k['walk_cepton']['params']['k_m'] == pytest.approx(
        k['walk_native']['params']['k_m'], rel=0.06)
    assert k['walk_cepton']['range_rmse_after_m'] == pytest.approx(
        k['walk_native']['range_rmse_after_m'], rel=0.05)
    assert cep['intensity_gain']['range_exponent'] == -2.0


def test_pcap_gives_the_bags_verdict(bags):
    """compare / a Cepton pcap (compare/recording/cepton_pcap.py) with poses from the bag or
    a CSV: the bag's verdict on the same frames (test_compare_cepton_pcap.py tests the
    decoder; the bag's run is test_same_verdict_on_a_walk_in_both_layouts's). The CSV's
    poses give the pcap the same recording as the bag's (the same points, the same pose
    at every point time): compare runs on that recording as on the bag's (a full compare
    of it gave the pcap's k to 1e-6)."""
    bag, pcap = (walk_compare(bags, kind) for kind in ('cepton', 'pcap'))
    assert bag['missing_effect'] == pcap['missing_effect'] == 'range_walk'
    k = {n: next(c for c in s['candidates'] if c['name'] == 'range_walk')['params']['k_m']
         for n, s in (('bag', bag), ('pcap', pcap))}
    # The wire's 5 mm positions against the driver's float32: the same slope to a few %.
    assert k['pcap'] == pytest.approx(k['bag'], rel=0.06)
    via_bag, via_csv = (load_measurements(bags['walk_pcap'], poses_from=bags[src], max_points=6000)
                        for src in ('walk_cepton', 'walk_csv'))
    assert np.array_equal(via_csv.xyz_m, via_bag.xyz_m) and np.array_equal(via_csv.t_s, via_bag.t_s)
    at_bag, at_csv = via_bag.poses.at(via_bag.t_s), via_csv.poses.at(via_bag.t_s)
    # The CSV's 9 decimals: 1 nm, and 1e-7 rad (1 um at 10 m).
    assert np.abs(at_csv.position_m - at_bag.position_m).max() < 1e-8
    assert (at_csv.rotation * at_bag.rotation.inv()).magnitude().max() < 1e-7


def test_cli_compare_pcap_needs_poses(bags, capsys):
    from lidar_sim_ros import cli
    rc = cli.main(['compare', str(bags['walk_pcap']), '--mesh', str(bags['mesh']),
                   '--out', str(bags['root'] / 'cli')])
    assert rc == 2
    assert '--poses BAG_OR_CSV' in capsys.readouterr().err


def test_no_return_points_are_misses_wherever_the_driver_puts_them(bags, tmp_path):
    """NO_RETURN points count as known misses by their flag, not by sitting at the origin
    (here moved to 100 m ahead); SATURATED returns are marked."""
    from lidar_sim_ros.io.bag import BagWriter, read_poses
    clouds = read_clouds(bags['cepton'], '/cepton_pcl2')
    poses = read_poses(bags['cepton'])
    path = tmp_path / 'moved'
    with BagWriter(path) as bag:
        for s, p, q in zip(poses.stamp_ns, poses.position_m, poses.quat_xyzw):
            bag.write_pose('/target/pose', int(s), poses.frame_id, p, q)
        for c in clouds:
            pts = c.points.copy()
            pts['x'][(pts['flags'] & NO_RETURN) != 0] = 100.0
            bag.write_cloud('/cepton_pcl2', pts, c.stamp_ns, c.frame_id)
    moved = load_measurements(path, '/cepton_pcl2')
    orig = load_measurements(bags['cepton'], '/cepton_pcl2')
    assert len(moved) == len(orig) and moved.known_misses == orig.known_misses > 1000
    assert moved.dropped['at_origin'] == 0
    assert moved.saturated.sum() == sum(int(np.sum(c.points['flags'] & SATURATED))
                                        for c in clouds) > 0


def test_mount_transform_message_layout():
    """The node's static transform, built with rosbags' Jazzy types (no tf2_msgs wheel):
    serialises as tf2_msgs/msg/TFMessage and reads back parent -> sensor frame."""
    from rosbags.typesys import Stores, get_typestore
    from lidar_sim_ros.ros.mount import check_mount, mount_message
    store = get_typestore(Stores.ROS2_JAZZY)
    msg = mount_message(lambda name: store.types[name], 'base_link', 'cepton3',
                        [1.0, 0.0, 0.5], [0.0, 0.0, 0.38268343, 0.92387953], 12 * 10**9 + 5)
    back = store.deserialize_cdr(store.serialize_cdr(msg, 'tf2_msgs/msg/TFMessage'),
                                 'tf2_msgs/msg/TFMessage')
    (tf,) = back.transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ('base_link', 'cepton3')
    assert (tf.header.stamp.sec, tf.header.stamp.nanosec) == (12, 5)
    assert (tf.transform.translation.x, tf.transform.translation.z) == (1.0, 0.5)
    assert tf.transform.rotation.w == pytest.approx(0.92387953)
    assert check_mount([0, 0, 0], [0, 0, 0, 1]) is None
    assert 'unit quaternion' in check_mount([0, 0, 0], [0, 0, 1, 1])
    assert '3 finite numbers' in check_mount([0, float('nan'), 0], [0, 0, 0, 1])


def test_polar_fields_follow_the_driver_fields():
    """The optional azimuth, elevation, range (FLOAT32) come after channel_id and agree with
    x, y, z (REP-103: azimuth from x toward y, elevation up)."""
    from rosbags.typesys import Stores, get_typestore
    from lidar_sim_ros.io.cepton import cepton_points
    from lidar_sim_ros.io.pointcloud import to_rosbags_msg
    xyz = np.array([[10.0, 0.0, 0.0], [0.0, 5.0, 0.0], [3.0, 0.0, 4.0], [0.0, 0.0, 0.0]])
    pts = cepton_points(xyz, np.full(4, 0.3), np.arange(4) + 10**18, [0, 0, 1, 32], [1, 2, 3, 4],
                        polar=True)
    msg = to_rosbags_msg(pts, 10**18, 'cepton3', get_typestore(Stores.ROS2_JAZZY))
    assert [(f.name, f.datatype) for f in msg.fields] == DRIVER_FIELDS + [
        ('azimuth', 7), ('elevation', 7), ('range', 7)]
    rows = read_points(msg)
    assert [round(r['range'], 5) for r in rows] == [10.0, 5.0, 5.0, 0.0]
    assert rows[1]['azimuth'] == pytest.approx(np.pi / 2)
    assert rows[2]['elevation'] == pytest.approx(np.arcsin(0.8))
    assert [r['flags'] for r in rows] == [0, 0, 1, 32]


def test_sdk2_layout_loads_with_its_names(bags, tmp_path):
    """The SDK2 driver's point (reflectivity, relative_timestamp, flags, channel_id, valid;
    UINT8 each): reflectivity is the intensity, channel_id the laser, valid = 0 dropped,
    relative_timestamp ignored (times from the scan pattern, the directions match it)."""
    from lidar_sim_ros.compare.recording.measurements import with_scan_times
    from lidar_sim_ros.core.pipeline import Simulator
    from lidar_sim_ros.io.bag import BagWriter, read_poses
    sdk2 = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('reflectivity', '<f4'),
                     ('relative_timestamp', 'u1'), ('flags', 'u1'), ('channel_id', 'u1'),
                     ('valid', 'u1')])
    clouds = read_clouds(bags['native'])
    poses = read_poses(bags['native'])
    path = tmp_path / 'sdk2'
    n_invalid = 0
    with BagWriter(path) as bag:
        for s, p, q in zip(poses.stamp_ns, poses.position_m, poses.quat_xyzw):
            bag.write_pose('/target/pose', int(s), poses.frame_id, p, q)
        for c in clouds:
            rec = np.zeros(len(c.points), sdk2)
            for f in 'xyz':
                rec[f] = c.points[f]
            rec['reflectivity'] = c.points['intensity'] * 7.0
            rec['channel_id'] = c.points['ring']
            rec['relative_timestamp'] = np.arange(len(rec)) % 256
            rec['valid'] = np.arange(len(rec)) % 10 != 0
            n_invalid += int(np.sum(rec['valid'] == 0))
            bag.write_cloud('/lidar/points', rec, c.stamp_ns, c.frame_id)
    meas = load_measurements(path)
    native = load_measurements(bags['native'])
    assert len(meas) == len(native) - n_invalid and meas.dropped['invalid'] == n_invalid
    assert meas.intensity is not None and meas.time_source == 'stamp'
    assert meas.fields['layout'] == 'cepton sdk2 driver' and meas.fields['laser'] == 'channel_id'
    assert any('relative_timestamp (UINT8): ignored' in line for line in meas.field_lines)
    scenario = load_scenario(REPO / 'config' / 'scenario.yaml')
    timed = with_scan_times(meas, Simulator.from_scenario(scenario).shots)
    assert timed.time_source == 'scan pattern'
    # The pattern's laser of each matched shot is the channel_id the cloud carried.
    assert np.mean(timed.laser == meas.laser) > 0.99


def test_second_returns_carry_the_return_field_and_the_second_return_flag():
    """A two-return receiver with multipath: points after a shot's first return carry
    return >= 2 in our layout and SECOND_RETURN in the driver's; first returns neither."""
    from lidar_sim_ros.core import pipeline
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.driver_layout import cepton_frame_points
    from lidar_sim_ros.core.effects import make_effect
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    from lidar_sim_ros.io import cepton
    from lidar_sim_ros.io.pointcloud import frame_points
    from lidar_sim_ros.paths import config_path
    scenario = load_scenario(config_path('scenario.yaml'))
    det = scenario.sensor.detection
    returns = det.returns.model_copy(update={'max_returns': 2, 'mode': 'all', 'min_separation_m': 0.03})
    scenario.sensor = scenario.sensor.model_copy(update={'detection': det.model_copy(update={'returns': returns})})
    sim = pipeline.Simulator.from_scenario(scenario, effects=[make_effect('multipath', None)])
    traj = ScenarioTrajectory.from_config(scenario.config)
    frame = next(f for f in (sim.simulate_frame(40.0 + 0.1 * i, traj, 400 + i) for i in range(10))
                 if np.any(f.return_number > 1))
    native = frame_points(frame)
    np.testing.assert_array_equal(native['return'], frame.return_number)
    pts = cepton_frame_points(frame, scenario.sensor, 0)
    second = (pts['flags'] & cepton.SECOND_RETURN) != 0
    assert second.sum() == np.count_nonzero(frame.return_number > 1) > 0
