"""loop/bag.py and the demo's statistics: the run's bag read back with rosbags' own reader."""
import json

import numpy as np
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation

from lidar_sim_ros.loop.bag import foxglove_layout, write_loop_bag
from lidar_sim_ros.loop.demo import _per_window, run_statistics

NS = 1_000_000_000


def _recording():
    q = Rotation.from_euler('z', 30, degrees=True).as_quat()
    stamps = [100 * NS + k * 100_000_000 for k in range(1, 4)]
    chaser = [[s, 0.0, -30.0 + 0.1 * k, 0.0, *q] for k, s in enumerate(stamps)]
    target = [[s, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] for s in stamps]
    truth = [[s, 30.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] for s in stamps]
    return {'chaser': np.array(chaser), 'target': np.array(target), 'truth': np.array(truth),
            'estimate': np.array(truth[:2]), 'command': np.array([[s - 50_000_000, 1.0, -2.0, 0.5] for s in stamps]),
            'reference': np.array([[s - 50_000_000, 0.0, -30.0, 0.0] for s in stamps]), 'clouds': []}


def test_the_bag_holds_tf_as_tf2_messages_lvlh_chaser_lidar_and_target(tmp_path):
    rec = _recording()
    counts = write_loop_bag(tmp_path / 'bag', rec, (0.8, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0))
    assert counts == {'/tf': 3, '/target/pose': 3, '/target/pose_estimate': 2,
                      '/chaser/force_command': 3, '/loop/reference': 3}
    assert (tmp_path / 'bag' / 'bag.mcap').is_file()
    with AnyReader([tmp_path / 'bag']) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types['/tf'] == 'tf2_msgs/msg/TFMessage'
        assert types['/chaser/force_command'] == 'geometry_msgs/msg/WrenchStamped'
        tf = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
              if c.topic == '/tf']
        force = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
                 if c.topic == '/chaser/force_command']
    first = tf[0].transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in first] == [
        ('lvlh', 'chaser'), ('chaser', 'lidar'), ('lvlh', 'target')]
    assert first[0].transform.translation.y == -30.0 and abs(first[0].transform.rotation.z - np.sin(np.pi / 12)) < 1e-12
    assert (first[1].transform.translation.x, first[1].transform.translation.z) == (0.8, 0.2)
    assert first[0].header.stamp.sec == 100 and first[0].header.stamp.nanosec == 100_000_000
    assert (force[2].wrench.force.x, force[2].wrench.force.y) == (1.0, -2.0)


def test_the_foxglove_layout_names_the_bag_s_topics():
    text = json.dumps(foxglove_layout())
    layout = json.loads(text)
    assert layout['configById']['3D!loop']['followTf'] == 'lvlh'
    assert '/loop/points_gated' in layout['configById']['3D!loop']['topics']
    assert set(layout['configById']) == {layout['layout']['first'], layout['layout']['second']['first'],
                                         layout['layout']['second']['second']}


def test_run_statistics_count_late_periods_per_window(tmp_path):
    stats = tmp_path / 'stats.json'
    stats.write_text(json.dumps({'timing_mode': 'realtime', 'periods': 250, 'late_periods': 3,
                                 'late_period_indices': [0, 99, 100], 'timeouts': 0, 'startup_timeouts': 0,
                                 'timeout_period_indices': [], 'wall_s': 25.1,
                                 'refused_commands': {'future': 2}, 'clipped_commands': {'thrust_limit': 1}}))
    log = tmp_path / 'pose_tracker.log'
    log.write_text('x acquisition at 100.05 s: acquired, 76 hypotheses in 0.52 s\n'
                   'y acquisition at 103.05 s: failed, 0 hypotheses in 0.01 s (bound)\n')
    got = run_statistics(stats, log, 0.1)
    assert got['late_periods_per_10_s'] == [2, 1, 0] and got['late_fraction'] == 3 / 250
    assert got['acquisitions'] == 2 and got['acquisition_compute_s'] == 0.53
    assert got['timing_mode'] == 'realtime' and got['refused_commands'] == {'future': 2}
    assert _per_window([], 5, 100) == [0]
    assert run_statistics(tmp_path / 'none.json', log, 0.1)['statistics'].startswith('missing')
