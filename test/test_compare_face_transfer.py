"""A rigid pose correction against a range error that depends on which way a surface
faces (``compare/diagnose/face_transfer.py``, ``pose_error.faces_agree``, the verdict and
``pose_status`` words, ``run.pose_across_all_points``): pure functions over arrays."""
from dataclasses import replace

import numpy as np

from lidar_sim_ros.compare import run
from lidar_sim_ros.compare.diagnose import diagnosis, face_transfer, pose_error
from lidar_sim_ros.compare.report import verdict
from lidar_sim_ros.compare.report.pose_status import pose_status

SIGMA_M = 0.01
Z_CRIT, MIN_GAIN = 3.0, 0.005


def _surface(n: int = 6000, seed: int = 0):
    """Rays at 11 m on a rounded target: unit normals facing the sensor (+x is the
    boresight), the points, the rays; one material, blocks of 50 points."""
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=(n, 3)) * [0.4, 1.0, 1.0] - [1.5, 0.0, 0.0]
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    point = np.array([11.0, 0.0, 0.0]) - 0.8 * normal
    direction = point / np.linalg.norm(point, axis=1)[:, None]
    expected = np.linalg.norm(point, axis=1)
    return rng, normal, direction, expected, np.arange(n) // 50


def _agree(residual: np.ndarray, normal, direction, expected, blocks):
    cloud = np.zeros(len(residual), int)
    a, use = pose_error.design(direction, normal, expected, cloud)
    row = np.zeros(len(residual), int)
    return pose_error.faces_agree(a, residual, np.full(len(residual), SIGMA_M), cloud, use,
                                  np.zeros(1, int), None, normal,
                                  np.zeros(len(residual), int), row, blocks, Z_CRIT, MIN_GAIN)


def test_orientation_groups_split_the_normals_by_the_way_they_face():
    n = np.array([[-1.0, 0.0, 0.0]] * 5 + [[0.0, 0.0, 1.0]] * 5 + [[np.nan] * 3])
    use = np.array([True] * 10 + [True])
    g = face_transfer.orientation_groups(n, use, k=2)
    assert g[-1] == -1
    assert len(set(g[:5])) == 1 and len(set(g[5:10])) == 1 and g[0] != g[5]


def test_halves_along_a_direction():
    n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    got = face_transfer.halves_along(n, np.array([True, True, False]), np.array([0, 0, 1.0]))
    assert got.tolist() == [1, 0, -1]


def test_a_rigid_motion_holds_on_every_orientation():
    """A true reference-pose error (2 cm across the line of sight, 0.1 deg): fitted on
    the surfaces facing some ways, it gains on those facing the others."""
    rng, normal, direction, expected, blocks = _surface()
    cloud = np.zeros(len(normal), int)
    a, _ = pose_error.design(direction, normal, expected, cloud)
    motion = np.array([0.0, 0.02, -0.015, 0.0, 0.0, np.radians(0.1)])
    residual = a @ motion + SIGMA_M * rng.standard_normal(len(normal))
    across = _agree(residual, normal, direction, expected, blocks)
    assert all(g.transfers for g in across)
    assert np.all(across[1].gain > 0)


def test_a_bias_on_the_sunlit_faces_does_not_hold_across_orientations():
    """Faces toward s read long by 4 cm max(0, n.s), the pose exact: the rigid
    correction fitted on one half of the orientations loses on the other."""
    rng, normal, direction, expected, blocks = _surface()
    s = np.array([0.0, 0.34, 0.94])
    residual = 0.04 * np.maximum(0.0, normal @ s) + SIGMA_M * rng.standard_normal(len(normal))
    across = _agree(residual, normal, direction, expected, blocks)
    assert not all(g.transfers for g in across)
    lost = [k for g in across for k in g.losing]
    assert lost


def _failed_pose() -> pose_error.PoseError:
    faces = {'transfers': False, 'halves': {
        'transfers': False, 'total_gain_per_matched_point': -0.05, 'total_z': -9.0,
        'losing_groups': [1],
        'groups': [{'normal': [-0.6, 0.3, -0.7], 'share': 0.4, 'gain_per_matched_point': 0.001,
                    'gain_per_group_point': 0.003, 'z': 2.0},
                   {'normal': [-0.6, 0.2, 0.7], 'share': 0.6, 'gain_per_matched_point': -0.09,
                    'gain_per_group_point': -0.15, 'z': -12.4}]}}
    return pose_error.PoseError(
        clouds=np.zeros(1, int), t_s=np.zeros(1), translation_m=np.full((1, 3), 0.01),
        rotation_deg=np.zeros((1, 3)), gain=0.0133, z=6.4, significant=False,
        correction_m=np.zeros(4), constant=True, across_faces=faces)


def test_pose_status_says_the_correction_does_not_hold_across_the_faces():
    pose = _failed_pose()
    out = pose_status(pose.as_dict(), diagnosis.Decision(None, []), [], [])
    assert not out['reported']
    assert 'across_faces' in out['reported_because']


def test_verdict_words_name_a_range_error_of_the_surface_orientation():
    summary = {'reference_pose': _failed_pose().as_dict()}
    assert verdict.across_faces_left(summary, diagnosis.Decision(None, []))
    assert not verdict.across_faces_left(summary, diagnosis.Decision('range_walk', []))
    words = verdict.across_faces_words(summary['reference_pose'])
    assert 'outside the catalogue' in words and 'which way a surface faces' in words
    assert '0.1500 nats per point' in words and 'no pose error is claimed' in words


def test_a_reported_pose_that_does_not_hold_across_the_faces_is_withheld():
    pose = replace(_failed_pose(), significant=True)
    decision = diagnosis.Decision(None, [], pose=pose)
    out, left = run.pose_across_all_points(decision, pose)
    assert out.pose is None and not left.significant
    holds = replace(pose, across_faces={'transfers': True})
    kept, _ = run.pose_across_all_points(replace(decision, pose=holds), holds)
    assert kept.pose is holds
