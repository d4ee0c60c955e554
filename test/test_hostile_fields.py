"""Hostile recordings, second round (issue 29): Cepton time and laser fields that cannot
mean what their names say are refused naming the bag, the field and the value, never read
into a plausible-looking answer (compare/recording/fields.py, compare/recording/measurements.py).

The bags hold the SDK3 driver's point, built here from the driver's published field list
(docs/real-data.md), with one field's datatype or value broken.
"""
import numpy as np
import pytest

from lidar_sim_ros.compare.recording.fields import FieldError, point_time_ns, resolve_fields
from lidar_sim_ros.compare.recording.measurements import (MeasurementError, find_time_field,
                                                          load_measurements)
from lidar_sim_ros.core.config import MAX_LASERS
from lidar_sim_ros.io.bag import BagWriter

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
N = 300


def sdk3_dtype(ts='<i4', tus='<i4', channel='<u2'):
    return np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('intensity', '<f4'),
                     ('timestamp_s', ts), ('timestamp_us', tus), ('flags', '<u2'),
                     ('channel_id', channel)])


def write_cepton_bag(path, dtype=None, edit=None):
    """Two SDK3 clouds of N points 5-15 m away and five poses around them."""
    dtype = dtype or sdk3_dtype()
    rng = np.random.default_rng(3)
    with BagWriter(path) as bag:
        for s in T0_NS + np.arange(-1, 4) * PERIOD_NS // 2:
            bag.write_pose('/target/pose', int(s), 'lidar', [10.0, 0.0, 0.0], [0, 0, 0, 1])
        for k in range(2):
            stamp = T0_NS + k * PERIOD_NS
            t_us = stamp // 1000 + np.sort(rng.integers(0, 90_000, N))
            rec = np.zeros(N, dtype)
            for f in 'xyz':
                rec[f] = rng.uniform(5, 15, N)
            rec['intensity'] = 0.3
            rec['timestamp_s'] = t_us // 1_000_000
            rec['timestamp_us'] = t_us % 1_000_000
            rec['channel_id'] = np.arange(N) % 24
            if edit:
                edit(rec)
            bag.write_cloud('/lidar/points', rec, stamp, 'lidar')
    return path


def test_the_driver_layout_loads_with_exact_times(tmp_path):
    meas = load_measurements(write_cepton_bag(tmp_path / 'ok'))
    assert len(meas) == 2 * N and meas.time_source == 'field'
    # Times since the stamp lie within the frame (0..90 ms) at whole microseconds.
    assert 0 <= meas.t_frame_s.min() and meas.t_frame_s.max() < 0.09
    assert np.allclose(meas.t_frame_s * 1e6, np.round(meas.t_frame_s * 1e6), atol=1e-3)
    assert any('read as integer nanoseconds' in line for line in meas.field_lines)
    assert any(line.startswith('  point time read as: absolute') for line in meas.field_lines)


@pytest.mark.parametrize('ts, tus, member, kind', [
    ('<f4', '<f4', 'timestamp_s', 'FLOAT32'),       # issue 29: rc 0, RMSE 0.032 -> 0.051 m
    ('<i4', '<f4', 'timestamp_us', 'FLOAT32'),
    ('<i4', 'u1', 'timestamp_us', 'UINT8'),         # issue 29: rc 0, RMSE 0.089 m
    ('<i2', '<i4', 'timestamp_s', 'INT16'),
])
def test_a_time_pair_that_is_not_wide_integers_is_refused(tmp_path, ts, tus, member, kind):
    with pytest.raises(MeasurementError, match=f'{member} is {kind}'):
        load_measurements(write_cepton_bag(tmp_path / 'b', sdk3_dtype(ts, tus)))
    # The same pair named on the command line is refused alike; 'none' reads no time.
    with pytest.raises(FieldError, match=f'{member} is {kind}'):
        resolve_fields(sdk3_dtype(ts, tus), time_field='timestamp_s,timestamp_us')
    fm = resolve_fields(sdk3_dtype(ts, tus), time_field='none', find_time=find_time_field)
    assert fm.time == () and 'integer nanoseconds' not in '\n'.join(fm.lines())


def test_microseconds_beyond_a_second_are_refused_naming_the_value(tmp_path):
    def late(rec):
        rec['timestamp_us'][7] = 2_000_000_000      # issue 29: absorbed as "another clock"
    with pytest.raises(MeasurementError, match=r'cloud #0: timestamp_us = 2000000000 '
                                               r'\(1 point\(s\)\).*\[0, 999,999\]'):
        load_measurements(write_cepton_bag(tmp_path / 'b', edit=late))
    rec = np.zeros(2, sdk3_dtype())
    rec['timestamp_us'] = [0, -1]
    with pytest.raises(FieldError, match='timestamp_us = -1'):
        point_time_ns(rec, ('timestamp_s', 'timestamp_us'))
    rec['timestamp_us'] = [0, 999_999]
    assert point_time_ns(rec, ('timestamp_s', 'timestamp_us'))[0].tolist() == [0, 999_999_000]


@pytest.mark.parametrize('value', [60_000, MAX_LASERS, -1])
def test_a_laser_id_beyond_any_sensor_is_refused(tmp_path, value):
    channel = '<i4' if value < 0 else '<u2'

    def wild(rec):
        rec['channel_id'][5:9] = value     # issue 29: 60,024 laser_bias offsets, rc 0
    with pytest.raises(MeasurementError, match=f"laser field 'channel_id' = {value} "
                                               r'\(4 point\(s\)\).*\[0, 1024\)'):
        load_measurements(write_cepton_bag(tmp_path / 'b', sdk3_dtype(channel=channel), wild))


def test_the_last_valid_laser_id_loads(tmp_path):
    def top(rec):
        rec['channel_id'][0] = MAX_LASERS - 1
    meas = load_measurements(write_cepton_bag(tmp_path / 'b', edit=top))
    assert meas.laser.max() == MAX_LASERS - 1


def test_calibration_refuses_the_same_fields(tmp_path):
    """calibrate range-errors and scan read the clouds with their own loops: the same laser
    and sub-second checks, naming bag, topic and cloud."""
    from lidar_sim_ros.calibrate.common import CalibrationInputError
    from lidar_sim_ros.calibrate.range_errors import _static_frames
    from lidar_sim_ros.calibrate.scan_pattern import read_scan_samples

    def wild(rec):
        rec['channel_id'][2] = 60_000

    def late(rec):
        rec['timestamp_us'][3] = 2_000_000_000
    bag = write_cepton_bag(tmp_path / 'wild', edit=wild)
    with pytest.raises(MeasurementError, match="cloud #0: laser field 'channel_id' = 60000"):
        _static_frames(bag, '/lidar/points', '/target/pose', {k: 0 for k in (
            'frames', 'frames_no_pose', 'frames_moving', 'points')})
    with pytest.raises(MeasurementError, match="cloud #0: laser field 'channel_id' = 60000"):
        read_scan_samples(bag, '/lidar/points')
    bag = write_cepton_bag(tmp_path / 'late', edit=late)
    with pytest.raises(CalibrationInputError, match='cloud #0: timestamp_us = 2000000000'):
        _static_frames(bag, '/lidar/points', '/target/pose', {k: 0 for k in (
            'frames', 'frames_no_pose', 'frames_moving', 'points')})
    with pytest.raises(CalibrationInputError, match='cloud #0: timestamp_us = 2000000000'):
        read_scan_samples(bag, '/lidar/points')
