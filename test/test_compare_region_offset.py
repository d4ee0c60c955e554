"""One part of a material reading off the rest against a rigid reference-pose error
(``compare/diagnose/region_offset.py``). The target is a cylinder (radius 1.5 m, 4 m
long, its axis the body z) 10 m in front of the sensor, its faces a grid of triangles;
ranges are the exact ray-cylinder intersections, so a moved cylinder's ranges are
computed, not linearised. Two materials: BAND (|z| < 1 m) and END. The ninth holdout's
newmat_y: the BAND faces on one flank (body y > 0) read 4.8 cm long (a material the
configuration does not list), the poses exact."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lidar_sim_ros.compare.diagnose import diagnosis, pose_error, region_offset
from lidar_sim_ros.compare.model import likelihood as lk

RADIUS, HALF_LENGTH, CENTRE = 1.5, 2.0, np.array([10.0, 0.0, 0.0])
N_PHI, N_Z = 72, 16
SIGMA = 0.01


def _mesh():
    """A grid of (N_PHI x N_Z) quads, two triangles each, on the cylinder (body frame)."""
    phi = np.linspace(0, 2 * np.pi, N_PHI + 1)[:-1]
    z = np.linspace(-HALF_LENGTH, HALF_LENGTH, N_Z + 1)
    v = np.array([[RADIUS * np.cos(p), RADIUS * np.sin(p), h] for h in z for p in phi])
    faces = []
    for j in range(N_Z):
        for i in range(N_PHI):
            a, b = j * N_PHI + i, j * N_PHI + (i + 1) % N_PHI
            faces += [[a, b, a + N_PHI], [b, b + N_PHI, a + N_PHI]]
    return v, np.array(faces)


def _cylinder_range(u, centre, axis):
    """Range along unit rays ``u`` (sensor at the origin) to the near side of the
    cylinder (axis unit vector ``axis`` through ``centre``), and the hit points."""
    w = u - np.outer(u @ axis, axis)
    c = centre - (centre @ axis) * axis
    a, b, cc = np.sum(w * w, 1), -2 * (w @ c), c @ c - RADIUS ** 2
    disc = b * b - 4 * a * cc
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    return np.where(disc > 0, t, np.nan)


def _recording(case: str, seed: int = 0, n: int = 24_000):
    """(FitData, cloud, t_s, blocks) of a case: 'region' (the BAND faces with body y > 0
    read 4.8 cm long), 'shift' (the target 3 cm off the recorded pose along y), 'tilt'
    (0.5 deg about the body x), 'none'. One cloud; rays over the cylinder's face."""
    rng = np.random.default_rng(seed)
    u = np.column_stack([np.ones(n), rng.uniform(-0.13, 0.13, n), rng.uniform(-0.19, 0.19, n)])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    z_axis = np.array([0.0, 0.0, 1.0])
    expected = _cylinder_range(u, CENTRE, z_axis)
    p = u * expected[:, None]
    body = p - CENTRE
    keep = np.isfinite(expected) & (np.abs(body[:, 2]) < HALF_LENGTH)
    u, expected, body = u[keep], expected[keep], body[keep]
    m = len(u)
    normal = body * np.array([1.0, 1.0, 0.0]) / RADIUS     # outward, body = lidar axes
    phi = np.mod(np.arctan2(body[:, 1], body[:, 0]), 2 * np.pi)
    i = np.minimum((phi / (2 * np.pi) * N_PHI).astype(int), N_PHI - 1)
    j = np.minimum(((body[:, 2] + HALF_LENGTH) / (2 * HALF_LENGTH) * N_Z).astype(int), N_Z - 1)
    face = 2 * (j * N_PHI + i)
    material = np.where(np.abs(body[:, 2]) < 1.0, 0, 1)
    vertices, faces = _mesh()
    centroid_y = vertices[faces[face]].mean(axis=1)[:, 1]
    if case == 'shift':
        measured = _cylinder_range(u, CENTRE + [0.0, 0.03, 0.0], z_axis)
    elif case == 'tilt':
        a = np.radians(0.5)
        measured = _cylinder_range(u, CENTRE, np.array([0.0, -np.sin(a), np.cos(a)]))
    else:
        measured = expected + np.where((material == 0) & (centroid_y > 0), 0.048, 0.0) * (
            case == 'region')
    ok = np.isfinite(measured)
    measured = np.where(ok, measured, expected) + rng.normal(0, SIGMA, m)
    target = SimpleNamespace(vertices_m=vertices, faces=faces, material_names=['BAND', 'END'])
    data = _fit_data(u, expected, measured, normal, material, face, target)
    order = np.argsort(phi * 10 + body[:, 2])            # neighbourhood blocks on the body
    blocks = np.empty(m, int)
    blocks[order] = np.arange(m) // 40
    return data, np.zeros(m, int), np.zeros(m), blocks


def _fit_data(u, expected, measured, normal, material, face, target) -> lk.FitData:
    from lidar_sim_ros.core.effects.base import ReturnContext
    from lidar_sim_ros.core.geometry import Hits
    from lidar_sim_ros.core.pipeline import Prediction
    m = len(u)
    one, zero = np.ones(m), np.zeros(m, int)
    ctx = ReturnContext(range_m=expected, incidence_rad=0 * one, material=material,
                        power_w=1e-6 * one, intensity=one, t_s=0 * one, az_rad=0 * one,
                        el_rad=0 * one, laser=zero, divergence_rad=1e-3,
                        hit=np.ones(m, bool), threshold_power_w=1e-9, direction=u,
                        normal=normal, face=face, scene=SimpleNamespace(target=target))
    hits = Hits(np.ones(m, bool), expected, normal, 0 * one, material, face, None, one)
    pred = Prediction(ctx, hits, u, 0 * one, SIGMA * one)
    return lk.FitData(measured_range_m=measured, baseline=pred, cast=lambda e: pred,
                      unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                      range_window_m=(5.0, 15.0))


def _pose_test(cloud, t_s, blocks):
    def test(on_top, constant, data, orientations=True):
        return pose_error.fit_reference_pose(data, cloud, t_s, blocks, 3.0,
                                             diagnosis.MIN_PRACTICAL_GAIN, 0, on_top,
                                             constant=constant, orientations=orientations)
    return test


def _weighed(case: str, seed: int = 0, orientations: bool = True):
    data, cloud, t_s, blocks = _recording(case, seed)
    test = _pose_test(cloud, t_s, blocks)
    pose = test([], True, data, orientations)
    decision = diagnosis.Decision(None, [], pose=pose if pose.significant else None)
    return pose, region_offset.weigh_pose(decision, [], data, blocks, test, 3.0,
                                          diagnosis.MIN_PRACTICAL_GAIN)


def test_the_best_split_finds_the_faces_of_one_flank_and_their_step():
    """The split is chosen between faces: on the 'region' case, the BAND faces beyond
    the body's y = 0 plane, 4.8 cm apart from the others (closed form: two weighted
    means), and its held-out gain is what two offsets give a 4.8 cm step."""
    data, _, _, blocks = _recording('region', 1)
    r, s, use = region_offset.footing(data, [])
    body = region_offset.body_points_m(data.baseline.ctx)
    material = np.asarray(data.baseline.ctx.material)
    test = region_offset.heldout_split(r, s, material, body, use, blocks, 0)
    assert test.split.material == 0
    # The plane parts the seen faces as the flank does (y, or a diagonal that parts
    # the same faces over the side seen: the tie of equal gains goes either way).
    side = test.split.side(material, body)
    flank = (material == 0) & (body[:, 1] > 0)
    agree = np.mean((side == 1) == flank) if test.offsets_m[1] > test.offsets_m[0] else \
        np.mean((side == -1) == flank)
    assert agree > 0.99
    step = abs(test.offsets_m[1] - test.offsets_m[0])
    assert step == pytest.approx(0.048, abs=0.002)
    # Held out, each side's offset gains d^2 / (2 s^2) a point (closed form: d its true
    # step, 4.8 cm or 0, from the material's median offset, s the material's sigma).
    raw = data.measured_range_m - data.baseline.ctx.range_m
    band = material == 0
    c = np.median(raw[band])
    d = np.where(flank, 0.048, 0.0) - c
    closed = np.sum(d[band] ** 2 / (2 * s[band] ** 2)) / len(r)
    assert test.gain == pytest.approx(closed, rel=0.1)
    assert test.z > 10


def test_a_part_of_one_material_reading_off_is_not_reported_as_a_reference_pose_error():
    """The ninth holdout's newmat_y on a cylinder: the poses exact, the BAND faces on one
    flank 4.8 cm long. One rigid correction for the recording passes its own test (the
    phantom: it moves the flank toward its ranges), but gains nothing beyond the split's
    two offsets, which gain decisively beyond it: the pose is not reported, and the
    decision keeps the split (part of the target reads off the rest). The correction
    asked across the surfaces' orientations (``pose_error.faces_agree``) fails there
    already; the split is weighed on the phantom as it passed without that question."""
    assert not _weighed('region')[0].significant            # not one rigid motion
    pose, out = _weighed('region', orientations=False)
    assert pose.significant and pose.z > 3.0                # the phantom the old code reported
    assert out.pose is None and out.region is not None
    reg = out.region
    assert reg.outcome == 'region' and reg.material == 'BAND'
    assert abs(reg.step_m) == pytest.approx(0.048, abs=0.003)
    assert not reg.pose_passes_beyond and reg.pose_z_beyond < 3.0
    assert reg.passes_beyond_pose and reg.z_beyond_pose > 10
    d = reg.as_dict()
    assert d['outcome'] == 'region' and d['pose_beyond']['significant'] is False


@pytest.mark.parametrize('case', ['shift', 'tilt'])
def test_a_true_rigid_pose_error_gains_beyond_any_split_and_stays(case):
    """The target 3 cm off its recorded pose across the line of sight, or tilted 0.5
    deg about the body x (ranges of the moved cylinder, not linearised): the best split
    of one material takes part of the pattern on that material, but the rigid
    correction still gains decisively beyond its offsets: the pose stays reported."""
    pose, out = _weighed(case)
    assert pose.significant
    assert out.pose is pose and out.region is not None
    assert out.region.outcome == 'pose' and out.region.pose_z_beyond > 5.0


def test_nothing_to_weigh_without_a_reported_pose_or_faces():
    """No reported pose (a correct one): the decision is unchanged; a pose reported on the
    raycast footing alone (its test failed) is not weighed either."""
    data, cloud, t_s, blocks = _recording('none', 2)
    test = _pose_test(cloud, t_s, blocks)
    pose = test([], True, data)
    assert not pose.significant
    none = diagnosis.Decision(None, [])
    assert region_offset.weigh_pose(none, [], data, blocks, test, 3.0,
                                    diagnosis.MIN_PRACTICAL_GAIN) is none
    raycast = diagnosis.Decision(None, [], pose=pose)
    assert region_offset.weigh_pose(raycast, [], data, blocks, test, 3.0,
                                    diagnosis.MIN_PRACTICAL_GAIN) is raycast
    assert region_offset.body_points_m(SimpleNamespace(face=None, scene=None)) is None


def _region(**kw) -> region_offset.RegionOffset:
    base = dict(material='BAND', axis='y', threshold_m=0.0, step_m=0.048, points=(900, 1100),
                gain=0.05, z=12.0, gain_beyond_pose=0.04, z_beyond_pose=10.0,
                pose_gain_beyond=0.0, pose_z_beyond=0.1, pose_passes_beyond=False,
                passes=True, passes_beyond_pose=True, pose_constant=True)
    return region_offset.RegionOffset(**{**base, **kw})


@pytest.mark.parametrize('kw, outcome, pose_kept', [
    ({}, 'region', False),
    ({'passes_beyond_pose': False}, 'tie', False),
    ({'pose_passes_beyond': True}, 'pose', True),
    # The pose's correction explains the materials' offsets against the configuration
    # (a box seen on two faces of one material, every material read nearer: the eighth
    # holdout's boxwing_h8-mix3, a 3 cm translation the split of one material took on
    # the free-offset footing alone): what one part of one material cannot.
    ({'pose_explains_materials': True}, 'pose', True),
    # The split does not pass alone: no part reads off, the pose judged as before.
    ({'passes': False, 'passes_beyond_pose': False}, 'pose', True),
])
def test_the_pose_is_reported_only_where_it_gains_beyond_the_split(kw, outcome, pose_kept):
    region = _region(**kw)
    assert region.outcome == outcome and region.as_dict()['outcome'] == outcome
    pose = SimpleNamespace(significant=True, constant=True)
    out = region_offset.judge(diagnosis.Decision(None, [], pose=pose), region)
    assert out.region is region and (out.pose is pose) == pose_kept


def test_the_verdict_says_a_part_reads_off_or_the_tie_and_never_the_tracking_system():
    from lidar_sim_ros.compare.report.verdict import region_words
    said = region_words(_region())
    assert 'outside the catalogue' in said and '+4.8 cm' in said and 'BAND' in said
    assert 'no reference-pose error is reported' in said and 'tracking system' not in said
    tie = region_words(_region(passes_beyond_pose=False))
    assert 'cannot tell a reference-pose error from a part of the target' in tie
    assert 'the pose is not asserted' in tie and 'tracking system' not in tie


def test_points_off_the_mesh_and_too_few_points_give_no_split():
    """A point on no face (-1) has no body position and is left out of the split; a
    face index beyond the mesh gives no positions at all; a material with fewer than
    twice MIN_MATERIAL_POINTS usable points is not split (the test then gains 0)."""
    vertices, faces = _mesh()
    target = SimpleNamespace(vertices_m=vertices, faces=faces, material_names=['BAND'])
    ctx = SimpleNamespace(face=np.array([0, -1, 5]), scene=SimpleNamespace(target=target))
    body = region_offset.body_points_m(ctx)
    assert np.all(np.isfinite(body[[0, 2]])) and np.all(np.isnan(body[1]))
    beyond = SimpleNamespace(face=np.array([0, len(faces)]), scene=SimpleNamespace(target=target))
    assert region_offset.body_points_m(beyond) is None
    n = 2 * lk.MIN_MATERIAL_POINTS - 1
    rng = np.random.default_rng(0)
    body = rng.normal(size=(n, 3))
    r = np.where(body[:, 1] > 0, 0.05, 0.0)
    test = region_offset.heldout_split(r, np.full(n, 0.01), np.zeros(n, int), body,
                                       np.ones(n, bool), np.arange(n) // 10)
    assert test.split is None and test.gain == 0.0 and not np.any(test.correction_m)
    r_nan = np.full(2 * n, np.nan)
    none = region_offset.heldout_split(r_nan, np.full(2 * n, 0.01), np.zeros(2 * n, int),
                                       rng.normal(size=(2 * n, 3)), np.zeros(2 * n, bool),
                                       np.arange(2 * n) // 10)
    assert none.split is None and none.gain == 0.0
