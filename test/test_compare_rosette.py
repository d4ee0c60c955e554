"""Point times from a sensor's own timing (compare.recording.measurements.with_scan_times) when a
cloud has none: the Risley rosette (each frame its own shots) and the flash array."""
import numpy as np
import pytest

from lidar_sim_ros.compare.recording.measurements import load_measurements, with_scan_times
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.scan import varies_by_frame
from lidar_sim_ros.io.bag import BagWriter, read_clouds, read_poses
from lidar_sim_ros.offline import DEFAULT_EPOCH_S, simulate_to_bag
from conftest import CONFIG


def without_time(src, dst):
    """``src`` with its clouds' per-point time field removed (a driver that sends none)."""
    poses = read_poses(src)
    fields = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('intensity', '<f4')])
    truth = []
    with BagWriter(dst) as bag:
        for s, p, q in zip(poses.stamp_ns, poses.position_m, poses.quat_xyzw):
            bag.write_pose('/target/pose', int(s), poses.frame_id, p, q)
        for c in read_clouds(src):
            rec = np.zeros(len(c.points), fields)
            for f in ('x', 'y', 'z', 'intensity'):
                rec[f] = c.points[f]
            bag.write_cloud('/lidar/points', rec, c.stamp_ns, c.frame_id)
            truth.append(np.asarray(c.points['t'], float))
    return np.concatenate(truth)


@pytest.mark.parametrize('scenario, start_s', [('scenario_mid40.yaml', 0.7),
                                               ('scenario_flash.yaml', 0.0)])
def test_point_times_from_the_sensors_own_timing(tmp_path, scenario, start_s):
    sc = load_scenario(CONFIG / scenario)
    sim = Simulator.from_scenario(sc)
    run = simulate_to_bag(sc, tmp_path / 'run', frames=3, start_s=start_s, figures=False,
                          simulator=sim)
    t_true = without_time(run.bag_path, tmp_path / 'stripped')
    meas = load_measurements(tmp_path / 'stripped')
    assert meas.time_source == 'stamp'
    by_frame = sim.shots_of_frame if varies_by_frame(sim.sensor) else None
    timed = with_scan_times(meas, sim.shots, by_frame, sim.frame_period_s, (0.0, DEFAULT_EPOCH_S))
    assert timed.time_source == 'scan pattern'
    # Points come in cloud order, as the bag wrote them: each takes its own shot's time.
    np.testing.assert_allclose(timed.t_frame_s, t_true, atol=1e-6)
    if by_frame is not None:
        # The frame's pattern matters: frame 0's shots leave most points of later frames unmatched.
        wrong = with_scan_times(meas, sim.shots)
        assert wrong.time_source == 'stamp'


def test_a_global_exposure_on_another_pixel_grid_keeps_the_stamp_as_every_points_time(
        tmp_path):
    """A flash without a row readout exposes every pixel at the frame's start: a recorded
    pixel grid that is not the configured one (here turned by half a pixel) leaves each
    point's time at its cloud stamp all the same, known, not "the scan pattern is off"."""
    from dataclasses import replace
    from lidar_sim_ros.compare.report import verdict
    from lidar_sim_ros.core.scan_flash import pixel_pitch
    sc = load_scenario(CONFIG / 'scenario_flash.yaml')
    sim = Simulator.from_scenario(sc)
    assert np.ptp(sim.shots.t_s) == 0.0
    run = simulate_to_bag(sc, tmp_path / 'run', frames=2, figures=False, simulator=sim)
    without_time(run.bag_path, tmp_path / 'stripped')
    meas = load_measurements(tmp_path / 'stripped')
    half = 0.5 * pixel_pitch(sim.sensor.scan)[0]
    c, s = np.cos(half), np.sin(half)
    d = meas.directions @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    timed = with_scan_times(replace(meas, directions=d), sim.shots)
    assert timed.time_source == 'scan pattern' and timed.scan_match_fraction is None
    np.testing.assert_array_equal(timed.t_frame_s, 0.0)
    np.testing.assert_allclose(timed.t_s, meas.cloud_stamps_s[meas.cloud])
    assert not verdict.scan_pattern_off({'point_times': timed.time_source,
                                         'scan_pattern_match': timed.scan_match_fraction})
