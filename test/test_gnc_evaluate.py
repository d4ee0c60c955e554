"""gnc/evaluate.py and gnc/report.py: errors against the truth, split as GNC engineers read them."""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.gnc.evaluate import tracking_errors

NS = 1_000_000_000


def truth_stream():
    """50 Hz truth: the body drifts along x and turns about lidar z."""
    stamps = (np.arange(0, 51) * NS // 50).astype(np.int64)
    t = stamps / NS
    positions = np.column_stack([10.0 - 0.1 * t, 1.0 + 0 * t, 0 * t])
    rotations = Rotation.from_rotvec(np.outer(0.2 * t, [0, 0, 1])) * Rotation.from_euler('x', 80, degrees=True)
    return stamps, positions, rotations


def test_errors_split_into_line_of_sight_axis_pointing_and_roll():
    stamps, positions, rotations = truth_stream()
    est_stamps = np.array([NS // 4 + 5_000_000, NS // 2 + 10_000_000], dtype=np.int64)  # between samples
    t = est_stamps / NS
    true_pos = np.column_stack([10.0 - 0.1 * t, [1.0, 1.0], [0.0, 0.0]])
    true_rot = Rotation.from_rotvec(np.outer(0.2 * t, [0, 0, 1])) * Rotation.from_euler('x', 80, degrees=True)
    los = true_pos / np.linalg.norm(true_pos, axis=1, keepdims=True)
    # Frame 0: 0.13 m toward the sensor and 7 deg of roll about the body long axis (+z).
    # Frame 1: 2 cm sideways and the long axis tilted by 3 deg (about body x).
    est_pos = true_pos + np.array([-0.13 * los[0], [0.0, 0.0, 0.02]])
    est_rot = Rotation.concatenate([true_rot[0] * Rotation.from_euler('z', 7, degrees=True),
                                    true_rot[1] * Rotation.from_euler('x', 3, degrees=True)])
    e = tracking_errors(est_stamps, est_pos, est_rot.as_quat(), stamps, positions, rotations.as_quat())
    assert len(e) == 2
    np.testing.assert_allclose(e.los_m, [-0.13, 0.02 * los[1, 2]], atol=1e-9)
    np.testing.assert_allclose(e.rotation_deg, [7.0, 3.0], atol=1e-6)
    np.testing.assert_allclose(e.roll_deg, [7.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(e.axis_deg, [0.0, 3.0], atol=1e-6)
    s = e.summary()
    assert s['frames'] == 2
    assert s['trans_rms_m'] == pytest.approx(np.sqrt((0.13 ** 2 + 0.02 ** 2) / 2))
    assert s['rot_rms_deg'] == pytest.approx(np.sqrt((49 + 9) / 2))


def test_estimates_outside_the_truth_are_left_out():
    stamps, positions, rotations = truth_stream()
    est = np.array([-NS // 10, NS // 2, 2 * NS], dtype=np.int64)
    e = tracking_errors(est, np.tile([9.95, 1.0, 0.0], (3, 1)), np.tile([0, 0, 0, 1.0], (3, 1)),
                        stamps, positions, rotations.as_quat())
    assert len(e) == 1 and e.t_s[0] == pytest.approx(0.5)


def test_report_writes_the_keys_and_the_figure(tmp_path):
    from lidar_sim_ros.gnc.report import write_report
    stamps, positions, rotations = truth_stream()
    e = tracking_errors(stamps[5:40], positions[5:40] + 0.01, rotations[5:40].as_quat(),
                        stamps, positions, rotations.as_quat())
    json_path, figure = write_report({'truth_cloud': e, 'model_cloud': e}, tmp_path,
                                     {'model_cloud': {'clouds': 40}}, {'seconds': 1.0})
    doc = json.loads(json_path.read_text())
    for key in ('truth_cloud', 'model_cloud'):
        assert {'trans_rms_m', 'rot_rms_deg', 'frames'} <= set(doc[key])
        assert doc[key]['frames'] == 35
        assert doc[key]['trans_rms_m'] == pytest.approx(0.01 * np.sqrt(3))
    assert doc['model_cloud']['clouds'] == 40 and doc['seconds'] == 1.0
    assert figure.stat().st_size > 10_000
