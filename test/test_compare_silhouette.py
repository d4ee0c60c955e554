"""The silhouette test of a pose claim (``compare.diagnose.silhouette``), on a plate with
a raised block in front of a sensor, raycast in closed form: a true shift of the target is
supported by its edges, a range bias with an exact pose is not, and a plate filling the
view cannot tell."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose import pose_error, silhouette

RANGE_M = 7.0
SIGMA_M = 0.01
HALF_M = 0.5          # the plate: |y|, |z| <= HALF_M at x = RANGE_M
BLOCK_M = 0.2         # a block standing 0.2 m proud over y in [0, 0.25], every z
Z_CRIT = 3.0
MIN_GAIN = 0.005


def rays(span_rad: float, n: int = 120) -> np.ndarray:
    """(n * n, 3) unit directions on a grid of +-span_rad about +x."""
    a = np.linspace(-span_rad, span_rad, n)
    ay, az = np.meshgrid(a, a, indexing='ij')
    d = np.stack([np.ones_like(ay), np.tan(ay), np.tan(az)], axis=-1).reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def cast(d: np.ndarray, shift_y: float, fill: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(hit, range m) of each ray on the target moved by ``shift_y`` along y: the plate
    (unbounded with ``fill``) and the block standing proud of it."""
    t_plate = RANGE_M / d[:, 0]
    y_p, z_p = t_plate * d[:, 1] - shift_y, t_plate * d[:, 2]
    on_plate = fill | ((np.abs(y_p) <= HALF_M) & (np.abs(z_p) <= HALF_M))
    t_block = (RANGE_M - BLOCK_M) / d[:, 0]
    y_b, z_b = t_block * d[:, 1] - shift_y, t_block * d[:, 2]
    on_block = (y_b >= 0.0) & (y_b <= 0.25) & (np.abs(z_b) <= HALF_M)
    rng = np.where(on_block, t_block, np.where(on_plate, t_plate, np.inf))
    return on_block | on_plate, rng


def blocks_of(n: int, side: int = 120, cell: int = 6) -> np.ndarray:
    i, j = np.divmod(np.arange(n), side)
    return (i // cell) * side + j // cell


def score(d: np.ndarray, measured_m: np.ndarray, returned: np.ndarray, claimed_y: float,
          fill: bool = False) -> silhouette.Silhouette:
    """The silhouette test of a correction moving the model by ``claimed_y`` (m) on the
    returns ``measured_m`` (those ``returned``)."""
    d, measured_m = d[returned], measured_m[returned]
    hit_b, rng_b = cast(d, 0.0, fill)
    hit_a, rng_a = cast(d, claimed_y, fill)
    sigma = np.full(len(d), SIGMA_M)
    with np.errstate(invalid='ignore'):
        gain, edge, counts = silhouette.edge_gain(
            hit_b, hit_a, rng_b, rng_a, silhouette.capped_nll(measured_m - rng_b, sigma),
            silhouette.capped_nll(measured_m - rng_a, sigma), abs(claimed_y))
    return silhouette.judge(gain, edge, blocks_of(len(returned))[returned], counts, Z_CRIT,
                            MIN_GAIN, abs(claimed_y))


def measured(d: np.ndarray, shift_y: float, bias_m: float = 0.0, fill: bool = False,
             seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The returns of the real target moved by ``shift_y``: noisy ranges, the plate's
    half y > 0 reading ``bias_m`` long (a face-fixed range bias)."""
    hit, rng = cast(d, shift_y, fill)
    noise = np.random.default_rng(seed).normal(0.0, SIGMA_M, len(d))
    y = rng * d[:, 1]
    return np.where(hit, rng + noise + bias_m * (y > 0), np.nan), hit


def test_a_true_shift_is_supported_by_the_edges():
    d = rays(0.1)
    meas, hit = measured(d, 0.03)
    sil = score(d, meas, hit, 0.03)
    assert sil.outcome == 'supports' and not sil.withholds
    assert sil.put_back > 50 and sil.lost == 0 and sil.jumped > 20
    assert sil.gain > 1.0 and sil.z > 5


def test_a_correction_fitted_to_a_range_bias_is_contradicted():
    # The pose exact, half the plate reading 4 cm long; a correction claiming the target
    # 3 cm over moves the outline off returns that lay on it.
    d = rays(0.1)
    meas, hit = measured(d, 0.0, bias_m=0.04)
    sil = score(d, meas, hit, 0.03)
    assert sil.outcome == 'contradicts' and sil.withholds
    assert sil.lost > 50 and sil.put_back == 0
    assert sil.gain < -0.5 and sil.z < -Z_CRIT


def test_half_the_true_shift_still_supported_and_the_wrong_sign_contradicted():
    d = rays(0.1)
    meas, hit = measured(d, 0.03)
    assert score(d, meas, hit, 0.015).outcome == 'supports'
    assert score(d, meas, hit, -0.03).outcome == 'contradicts'


def test_a_target_filling_the_view_cannot_tell():
    # No silhouette in view and the shift along the block's long side only: no ray
    # changes its outcome; the decision is left as it is.
    d = rays(0.02)
    meas, hit = measured(d, 0.0, fill=True)
    hit_b, rng_b = cast(d, 0.0, True)
    assert hit_b.all()
    sil = score(d, meas, hit, 0.0005, fill=True)
    assert sil.outcome == 'cannot_tell' and not sil.withholds
    assert sil.edge_rays < silhouette.MIN_EDGE_RAYS


def test_a_range_change_within_the_correction_is_no_jump():
    # Matched both ways, the expected range moves by less than JUMP_M plus the
    # correction's own motion: not an edge ray, whatever its NLL does.
    n = 5
    gain, edge, counts = silhouette.edge_gain(
        np.ones(n, bool), np.ones(n, bool), np.full(n, 7.0), np.full(n, 7.06),
        np.full(n, 3.0), np.zeros(n), reach_m=0.02)
    assert not edge.any() and counts['jumped'] == 0
    gain, edge, counts = silhouette.edge_gain(
        np.ones(n, bool), np.ones(n, bool), np.full(n, 7.0), np.full(n, 7.2),
        np.full(n, 3.0), np.zeros(n), reach_m=0.02)
    assert edge.all() and np.allclose(gain, 3.0)


def test_largest_motion_of_a_turn_per_cloud():
    # Two clouds: the second turned 1 deg about z through the origin and moved 1 cm in y.
    corr = pose_error.PoseCorrection(
        clouds=np.array([0, 1]), t0_s=np.array([0.0, 1.0]), t1_s=np.array([0.5, 1.5]),
        rotation=Rotation.from_rotvec([[0, 0, 0], [0, 0, np.radians(1.0)]]),
        translation_m=np.array([[0.0, 0, 0], [0, 0.01, 0]]))
    p = np.array([[7.0, 0, 0], [7.0, 0, 0]])
    got = silhouette.largest_motion_m(corr, p, np.array([0.2, 1.2]))
    want = np.linalg.norm(Rotation.from_rotvec([0, 0, np.radians(1.0)]).apply(p[1])
                          + [0, 0.01, 0] - p[1])
    assert np.isclose(got, want) and got > 0.12


def _claimed():
    pose = pose_error.PoseError(
        clouds=np.arange(2), t_s=np.zeros(2), translation_m=np.full((2, 3), 0.004),
        rotation_deg=np.full((2, 3), 0.4), gain=0.047, z=4.1, significant=True,
        correction_m=np.zeros(4), constant=False)
    from lidar_sim_ros.compare.diagnose import diagnosis
    return diagnosis.Decision(None, [], pose=pose), pose


def test_the_gate_withholds_a_pose_its_edges_contradict_and_says_why():
    from lidar_sim_ros.compare import run
    from lidar_sim_ros.compare.report.pose_status import pose_status
    from lidar_sim_ros.compare.report.verdict import silhouette_words
    decision, pose = _claimed()
    against = silhouette.Silhouette(400, 60, 250, 90, -1.1, -6.3, 'contradicts', 0.016)
    decision, left = run.pose_on_silhouette(decision, pose, lambda p: against)
    assert decision.pose is None and not left.significant
    figures = left.as_dict()
    assert figures['silhouette']['outcome'] == 'contradicts'
    assert figures['left_to_edges']['lost'] == 250
    status = pose_status(figures, decision, [], [])
    assert not status['reported'] and 'outline contradicts' in status['reported_because']
    words = silhouette_words(figures)
    assert '250 fall off the model' in words and 'no pose error is claimed' in words


def test_the_gate_keeps_a_pose_its_edges_do_not_contradict():
    from lidar_sim_ros.compare import run
    for outcome, z in (('supports', 4.0), ('no_support', 2.2), ('cannot_tell', 0.0)):
        decision, pose = _claimed()
        sil = silhouette.Silhouette(300, 90, 50, 160, 0.46, z, outcome, 0.028)
        kept, after = run.pose_on_silhouette(decision, pose, lambda p: sil)
        assert kept.pose is after and after.significant
        assert after.as_dict()['silhouette']['outcome'] == outcome
        assert 'left_to_edges' not in after.as_dict()


def test_a_contradicted_correction_with_a_part_left_is_kept():
    # A true pose beside a range error the correction took too: the whole loses on its
    # edges, its translation alone does not; only where every part the edges can judge
    # loses is the claim withheld.
    whole = silhouette.Silhouette(116, 6, 25, 85, -0.76, -3.6, 'contradicts', 0.067)
    part = {'translation': silhouette.Silhouette(147, 15, 8, 124, -0.05, -0.3, 'no_support'),
            'rotation': silhouette.Silhouette(50, 2, 30, 18, -1.99, -7.1, 'contradicts')}
    kept = replace(whole, parts=part)
    assert kept.part_left and not kept.withholds
    assert kept.as_dict()['parts']['translation']['outcome'] == 'no_support'
    lost = replace(whole, parts={**part, 'translation': silhouette.Silhouette(
        10, 0, 10, 0, -3.0, 0.0, 'cannot_tell')})
    assert not lost.part_left and lost.withholds
