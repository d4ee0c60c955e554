"""Reference-pose errors (compare/diagnose/pose_error.py) and the one decision rule
(compare/diagnose/diagnosis.py: ``total_z``, ``Diagnosis._set_gain``): closed forms, no raycast."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose import diagnosis, fit_data, pose_error
from lidar_sim_ros.compare.diagnose import unmatched_credit as credit

from conftest import plane_fit_data, three_plane_rays
from test_compare_pose_status import _Judge


def _plane_range(origin, normal, u):
    """Range along unit rays u (N, 3) from the sensor to the plane (point, normal)."""
    return (normal @ origin) / (u @ normal)


def test_design_gives_the_exact_range_change_of_a_small_rigid_motion():
    """A tilted plane at 10 m, moved by 1 mm and rotated 0.5 mrad about the points'
    centroid: the linear range change matches the exact ray-plane intersection."""
    rng = np.random.default_rng(3)
    u = np.column_stack([np.ones(200), rng.uniform(-0.05, 0.05, (200, 2))])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    n = np.array([-0.8, 0.36, 0.48])
    n /= np.linalg.norm(n)
    origin = np.array([10.0, 0.0, 0.0])
    e = _plane_range(origin, n, u)
    p = u * e[:, None]
    a, use = pose_error.design(u, np.tile(n, (200, 1)), e, np.zeros(200, int))
    assert use.all()
    d = np.array([1e-3, -0.5e-3, 0.7e-3])
    w = np.array([0.3e-3, -0.4e-3, 0.2e-3])
    g = p.mean(axis=0)
    rot = Rotation.from_rotvec(w)
    exact = _plane_range(rot.apply(origin - g) + g + d, rot.apply(n), u) - e
    linear = a @ np.concatenate([d, w])
    np.testing.assert_allclose(linear, exact, atol=2e-6)


def test_fit_clouds_recovers_each_clouds_correction():
    rng = np.random.default_rng(5)
    n_pts, clouds = 600, np.array([0, 1, 2])
    cloud = np.repeat(clouds, n_pts)
    a = rng.normal(size=(3 * n_pts, 6))
    truth = rng.normal(0, 0.01, (3, 6))
    sigma = np.full(3 * n_pts, 0.002)
    r = np.einsum('ij,ij->i', a, truth[cloud]) + rng.normal(0, 0.002, 3 * n_pts)
    x = pose_error.fit_clouds(a, r, sigma, cloud, np.ones(3 * n_pts, bool), clouds)
    np.testing.assert_allclose(x, truth, atol=6 * 0.002 / np.sqrt(n_pts))


def _facets(seed: int, n_pts: int = 3000, own: bool = False):
    """Rays 0.4 rad across at 10 m on nine facets (three of each material; ``own``: each
    its own material), each the plane through a point of the target, a facet per band of
    azimuth and elevation: (the generator, the design matrix, its usable rays, each
    ray's material)."""
    rng = np.random.default_rng(seed)
    u = np.column_stack([np.ones(n_pts), rng.uniform(-0.2, 0.2, (n_pts, 2))])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    facet = 3 * np.digitize(u[:, 1] / u[:, 0], [-0.07, 0.07]) + np.digitize(
        u[:, 2] / u[:, 0], [-0.07, 0.07])
    tilt = rng.normal(0, 0.5, (9, 3)) + [-1.0, 0.0, 0.0]
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    at = np.column_stack([10 + rng.uniform(-0.5, 0.5, 9), np.zeros((9, 2))])
    normal = tilt[facet]
    e = np.einsum('ij,ij->i', at[facet], normal) / np.einsum('ij,ij->i', u, normal)
    a, use = pose_error.design(u, normal, e, np.zeros(n_pts, int))
    return rng, a, use, facet if own else facet % 3


def test_a_translation_along_the_line_of_sight_is_fitted_jointly_with_the_material_offsets():
    """Three materials on planes of different tilts, 4 m across at 10 m, moved 5 cm along
    the line of sight: every material's ranges move by about 5 cm, which a per-material
    offset takes, and by n.d / n.u, which it does not. Fitted jointly with one offset per
    material (``group``), the translation is the truth (to the ridge); with the offsets
    subtracted first, as before, most of it is lost in them."""
    rng, a, use, group = _facets(21)
    n_pts, cloud = len(group), np.zeros(len(group), int)
    truth = np.array([-0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    offsets = np.array([0.004, -0.003, 0.001])        # a calibration mismatch per material
    r = a @ truth + offsets[group] + rng.normal(0, 1e-3, n_pts)
    sigma, clouds = np.full(n_pts, 1e-3), np.array([0])
    joint = pose_error.fit_clouds(a, r, sigma, cloud, use, clouds, None,
                                  pose_error.TEST_RIDGE, group)
    np.testing.assert_allclose(joint[0, :3], truth[:3], atol=1e-3)
    damped = pose_error.fit_clouds(a, r, sigma, cloud, use, clouds, None,
                                   pose_error.CONSTANT_RIDGE, group)
    assert -0.06 < damped[0, 0] < -0.04               # the constant correction's ridge
    medians = np.array([np.median(r[group == g]) for g in range(3)])
    apart = pose_error.fit_clouds(a, r - medians[group], sigma, cloud, use, clouds)
    assert abs(apart[0, 0]) < 0.5 * abs(truth[0])


def test_a_joint_fit_that_leaves_the_materials_a_common_offset_is_not_taken():
    """explains_common_offset(): the joint fit may take the materials' common offset
    into a translation along the line of sight, never leave them one they did not
    show. A residual that is only a pattern at grazing rays (as a footprint's first
    returns at the edges; no common offset): refused; a common offset of 5 cm that the
    translation explains is kept; a common offset of 5 cm beside which the translation
    pattern is weak (a sensor's offset, a third of the pattern) is refused."""
    _, a, use, group = _facets(22)
    n_pts = len(group)
    cloud, clouds = np.zeros(n_pts, int), np.array([0])
    sigma = np.full(n_pts, 1e-3)
    los = a @ np.array([-0.05, 0, 0, 0, 0, 0])
    for raw, kept in ((los - np.median(los), False), (los, True),
                      (0.3 * (los - np.median(los)) - 0.05, False)):
        # raw - its materials' medians, as fit_reference_pose hands it over
        med = np.array([np.median(raw[group == g]) for g in range(3)])[group]
        joint = pose_error.fit_clouds(a, raw - med, sigma, cloud, use, clouds, None,
                                      pose_error.CONSTANT_RIDGE, group)
        assert pose_error.explains_common_offset(a @ joint[0], raw - med, group, use,
                                                 med) is kept


def test_total_z_closed_form():
    # 1000 matched points gaining 0.01 +- 0.002 (SE of the mean), 40 unmatched points.
    z = diagnosis.total_z(0.01, 0.002, 1000, 40.0)
    total = 10.0 + diagnosis.UNMATCHED_NATS * 40
    se = np.sqrt(2.0 ** 2 + diagnosis.UNMATCHED_NATS ** 2 * 40)
    assert z == pytest.approx(total / se)
    assert diagnosis.total_z(0.01, 0.002, 1000, 0.0) == pytest.approx(5.0)


class _Stub(diagnosis.Diagnosis):
    """A diagnosis with a given baseline held-out NLL and no data (the rule alone)."""

    def __init__(self, n_matched: int, n_unmatched: int):
        self.n_total = n_matched + n_unmatched
        self.blocks = np.arange(n_matched) // 10
        self._base = np.zeros(n_matched)
        self.model = type('M', (), {'divergence_rad': 1e-3})()
        self._z_crit = 2.94

    def base_heldout(self):
        return self._base


class _Shift:
    """An effect that only moves the rays (no footprint), like a time offset."""

    outlier_fraction = diagnosis.Effect.outlier_fraction
    false_returns = diagnosis.Effect.false_returns

    def cast_reach_rad(self, divergence_rad):
        return None


@pytest.mark.parametrize('matched_gain, expect', [(0.0005, False), (0.01, True)])
def test_points_put_back_count_only_when_the_matched_points_show_the_effect(matched_gain,
                                                                          expect):
    """A time-offset-like candidate that puts 600 unmatched points back (pose errors
    do that too) is significant only when its matched gain is decisive on its own;
    and the z it carries is that of the score the verdict quotes."""
    diag = _Stub(20_000, 1000)
    rng = np.random.default_rng(1)
    nll = -(matched_gain + rng.normal(0, 0.05, 20_000))
    cand = diagnosis.Candidate('shift', effect=_Shift())
    diag._set_gain(cand, nll, 600.0)
    assert cand.significant is expect
    assert cand.z == pytest.approx(diagnosis.total_z(
        cand.matched_gain, cand.matched_gain / cand.z_matched, 20_000,
        cand.unmatched_gain_points), rel=1e-6)
    assert (cand.unmatched_gain_points > 0) is expect


def _edge_rays(power_fraction: float, measured_w: np.ndarray) -> 'lk.FitData':
    """Four unmatched rays that a footprint puts back on a plate at 10 m with
    ``power_fraction`` of the full beam's 1e-6 W; their measured power ``measured_w``."""
    from lidar_sim_ros.compare.model import likelihood as lk
    from lidar_sim_ros.core.effects.base import ReturnContext
    from lidar_sim_ros.core.geometry import Hits
    from lidar_sim_ros.core.pipeline import Prediction
    m = len(measured_w)
    one = np.ones(m)
    frac = np.full(m, power_fraction)
    ctx = ReturnContext(range_m=10 * one, incidence_rad=0 * one, material=np.zeros(m, int),
                        power_w=1e-6 * frac, intensity=frac, t_s=0 * one, az_rad=0 * one,
                        el_rad=0 * one, laser=np.zeros(m, int), divergence_rad=1e-3,
                        hit=np.ones(m, bool), threshold_power_w=1e-9)
    hits = Hits(np.ones(m, bool), 10 * one, np.tile([-1.0, 0, 0], (m, 1)), 0 * one,
                np.zeros(m, int), np.zeros(m, int), frac, one)
    pred = Prediction(ctx, hits, np.tile([1.0, 0, 0], (m, 1)), 0 * one, 0.01 * one)
    return lk.FitData(measured_range_m=np.zeros(0), baseline=None, cast=lambda e: pred,
                      unmatched_range_m=10 * one, cast_unmatched=lambda e: pred,
                      range_window_m=(5.0, 15.0), unmatched_power_w=measured_w)


def test_footprint_is_credited_only_with_edge_returns_at_its_power_fraction():
    """Points put back on the target by a footprint count for it only where the measured
    power is the footprint's fraction (0.2 of the beam), not the full beam (a pose error
    moved the silhouette), nor unknown."""
    from lidar_sim_ros.core.effects.beam_divergence import BeamDivergence
    eff = BeamDivergence({'footprint_scale': 4.0})
    measured = np.array([2e-7, 1e-6, 2.4e-7, np.nan, 9e-7])
    data = _edge_rays(0.2, measured)
    np.testing.assert_array_equal(credit.footprint_signature(data, [eff]),
                                  [True, False, True, False, False])
    assert credit.unmatched_credit(data, [eff], eff, 5.0) == 2.0
    # Without measured power, no edge point is credited to a footprint.
    from dataclasses import replace
    assert credit.unmatched_credit(replace(data, unmatched_power_w=None), [eff], eff,
                                      5.0) == 0.0



def test_a_rigid_effect_is_credited_only_with_points_that_return_a_whole_beam():
    """A surface standing proud places the whole beam on the target, so the points it
    puts back beyond the silhouette return the full power it predicts, as the matched
    points do (their measured / predicted ratio: ln spread 0.1 here); a footprint's edge
    returns carry a fifth of it and are not credited to the standoff. Unknown power
    keeps its credit; without measured power nothing changes."""
    from dataclasses import replace
    from lidar_sim_ros.core.effects.surface_offset import SurfaceOffset
    eff = SurfaceOffset({'standoff_m': 0.03})
    # The rays are placed with the whole beam (fraction 1, 1e-6 W predicted).
    measured = np.array([2e-7, 1e-6, 2.4e-7, np.nan, 9e-7])
    data = _edge_rays(1.0, measured)
    rng = np.random.default_rng(3)
    base_w = np.full(400, 1e-6)
    baseline = type('B', (), {'ctx': type('C', (), {'power_w': base_w})()})()
    data = replace(data, baseline=baseline,
                   measured_power_w=base_w * np.exp(rng.normal(0.0, 0.1, 400)))
    np.testing.assert_array_equal(credit.full_power_placed(data, [eff]),
                                  [False, True, False, True, True])
    assert credit.unmatched_credit(data, [eff], eff, 5.0) == 3.0
    # Weak everywhere (the matched points too, an intensity scale): a whole beam still.
    data_dim = replace(data, measured_power_w=0.2 * data.measured_power_w)
    assert credit.unmatched_credit(data_dim, [eff], eff, 5.0) == 5.0
    assert credit.unmatched_credit(replace(data, unmatched_power_w=None), [eff], eff,
                                      5.0) == 5.0
    # Point times unknown: nothing is re-cast, so nothing is judged.
    assert credit.full_power_placed(replace(data, placement_uncertain=True), [eff]) is None


class _RangeSplit(diagnosis.Diagnosis):
    """A diagnosis whose candidates, fitted on the nearer half of 4000 matched points
    (ranges 6-9 m) and scored on the farther and back, leave the per-point held-out
    NLLs ``transfer`` gives (the rule alone; no data)."""

    def __init__(self, transfer: dict):
        n = 4000
        meas = type('Meas', (), {'range_m': np.linspace(6.0, 9.0, n)})()
        self.rays = fit_data.RaySet.__new__(fit_data.RaySet)
        object.__setattr__(self.rays, 'meas', meas)
        object.__setattr__(self.rays, 'matched', np.arange(n))
        object.__setattr__(self.rays, 'unmatched', np.zeros(0, int))
        self.n_total = n
        self.matched_blocks = np.arange(n) // 10
        self._z_crit = 2.94
        self._transfer = transfer

    def transfer_nll(self, variant, halves, on_top=()):
        return self._transfer[variant]


def test_a_footprint_and_a_standoff_are_told_apart_by_the_one_that_carries_over_in_range():
    """A footprint's dilation grows with range, a standoff's does not: of the two, not
    set apart on random halves, the one that fitted near still fits far is kept; equal
    transfers leave them untold; a pair that is not a footprint and a standoff is not
    weighed this way."""
    from lidar_sim_ros.core.effects.beam_divergence import BeamDivergence
    from lidar_sim_ros.core.effects.incidence_angle import IncidenceAngle
    from lidar_sim_ros.core.effects.surface_offset import SurfaceOffset
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 0.5, 4000)
    beam = diagnosis.Candidate('beam_divergence', effect=BeamDivergence({'footprint_scale': 4.0}),
                               variant=BeamDivergence)
    proud = diagnosis.Candidate('surface_offset', effect=SurfaceOffset({'standoff_m': 0.03}),
                                variant=SurfaceOffset)
    incid = diagnosis.Candidate('incidence_angle', effect=IncidenceAngle({'bias_gain': 1.0}),
                                variant=IncidenceAngle)
    # The standoff fitted near loses 0.1 nats/point on the far points (and back).
    diag = _RangeSplit({BeamDivergence: -1.0 + noise, SurfaceOffset: -0.9 + noise,
                        IncidenceAngle: -0.9 + noise})
    pair_z = {}
    assert diag.range_decides(proud, beam, pair_z) is beam
    assert diag.range_decides(beam, proud, {}) is beam
    assert pair_z['surface_offset']['range_split_by'] == 'beam_divergence'
    assert pair_z['surface_offset']['range_split_margin'] == pytest.approx(0.1)
    # The verdict says why the standoff is not named, with the split's figures.
    from types import SimpleNamespace
    from lidar_sim_ros.compare.report.verdict import range_split_words
    words = range_split_words(SimpleNamespace(pair_z=pair_z))
    assert len(words) == 1 and words[0].startswith('surface_offset explains about as much')
    assert '0.1000 nats/point worse than beam_divergence' in words[0]
    assert diag.range_decides(beam, incid, {}) is None
    same = _RangeSplit({BeamDivergence: -1.0 + noise, SurfaceOffset: -1.0 + noise + 1e-4})
    untold = {}
    assert same.range_decides(proud, beam, untold) is None
    assert 'range_split_by' not in untold['beam_divergence']


def _roof_and_wall():
    """Body frame: a roof (ridge along z at x = 9.5 m, eaves at x = 10 m, y = +-0.5 m)
    in front of a wall at x = 11 m: two silhouette edges with a 1 m depth step."""
    from lidar_sim_ros.core.geometry import Target
    v = np.array([[9.5, 0, -0.5], [9.5, 0, 0.5], [10, 0.5, -0.5], [10, 0.5, 0.5],
                  [10, -0.5, -0.5], [10, -0.5, 0.5],
                  [11, -1, -1], [11, 1, -1], [11, 1, 1], [11, -1, 1]], float)
    f = np.array([[0, 2, 3], [0, 3, 1], [0, 1, 5], [0, 5, 4], [6, 7, 8], [6, 8, 9]])
    return Target(v, f, np.zeros(len(f), np.int16), ['ROOF'])


def _step(hits, measured_m, t_s, cloud):
    """One linear fit (design + fit_clouds) on the rays that hit in both, away from the
    depth steps (|residual| < 5 cm), as a PoseError."""
    r = measured_m - hits.range_m
    both = hits.hit & np.isfinite(measured_m) & np.isfinite(r)
    a, usable = pose_error.design(np.asarray(_step.dirs), hits.normal,
                                  np.where(both, hits.range_m, 0.0), cloud)
    use = both & usable & (np.abs(np.where(both, r, 1.0)) < 0.05)
    clouds = np.unique(cloud)
    x = pose_error.fit_clouds(a, np.where(use, r, 0.0), np.full(len(r), 1e-3), cloud, use,
                              clouds)
    p = _step.dirs * np.where(use, hits.range_m, 0.0)[:, None]
    g = p[use].mean(axis=0)[None, :]
    return pose_error.PoseError(clouds, np.array([t_s.mean()]), x[:, :3],
                                np.degrees(x[:, 3:]), 0.0, 0.0, True, a @ x[0], g)


def test_recast_with_the_corrected_pose_removes_the_silhouette_residual():
    """A target moved 2 cm sideways and 1 cm back, turned 0.3 deg about z, against a
    recorded pose without that motion. The linear correction fits the faces but leaves
    the rays that cross the eaves (roof in one pose, wall 1 m behind in the other) with
    ~1 m residuals; the correction applied to the pose and the rays cast again
    (CorrectedPoses, iterate) put every ray on the surface it really meets."""
    from lidar_sim_ros.core.geometry import cast_at_poses
    from lidar_sim_ros.core.pose import PoseTrack
    target = _roof_and_wall()
    yy, zz = np.meshgrid(np.linspace(-0.065, 0.065, 27), np.linspace(-0.035, 0.035, 11))
    dirs = np.column_stack([np.ones(yy.size), yy.ravel(), zz.ravel()])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    _step.dirs = dirs
    t_s = np.linspace(0.0, 1.0, len(dirs))
    cloud = np.zeros(len(dirs), int)
    recorded = PoseTrack(np.array([0.0, 1.0]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    rot = Rotation.from_rotvec([0, 0, np.radians(0.3)])
    centre = np.array([10.0, 0.0, 0.0])          # turned about the roof's eaves line
    shift = centre - rot.apply(centre) + [0.01, 0.02, 0.0]
    true = PoseTrack(np.array([0.0, 1.0]), np.tile(shift, (2, 1)),
                     np.tile(rot.as_quat(), (2, 1)))
    meas = cast_at_poses(target, dirs, true.at(t_s))
    measured = np.where(meas.hit, meas.range_m, np.nan)

    def cast(corr):
        return cast_at_poses(target, dirs, pose_error.CorrectedPoses(recorded, corr).at(t_s))

    first_hits = cast(pose_error.PoseCorrection.identity(cloud, t_s))
    first = _step(first_hits, measured, t_s, cloud)
    # The linear correction: faces right, silhouette rays not.
    both = first_hits.hit & meas.hit
    linear = measured - first_hits.range_m - first.correction_m
    switched = both & (np.abs(measured - first_hits.range_m) > 0.5)
    assert switched.sum() >= 5
    assert np.all(np.abs(linear[switched]) > 0.5)
    assert np.median(np.abs(linear[both & ~switched])) < 2e-3

    hits, corr, report = pose_error.iterate(
        first, pose_error.PoseCorrection.identity(cloud, t_s), cast,
        lambda h, _corr: _step(h, measured, t_s, cloud))
    assert report.passes >= 2
    assert np.array_equal(hits.hit, meas.hit)
    residual = measured[meas.hit] - hits.range_m[meas.hit]
    assert np.max(np.abs(residual)) < 2e-3
    assert np.sqrt(np.mean(residual ** 2)) < 5e-4
    # The composed correction is the true pose (up to z, which the faces cannot see).
    fixed = pose_error.CorrectedPoses(recorded, corr).at(np.array([0.5]))
    assert np.degrees((fixed.rotation * rot.inv()).magnitude()[0]) < 0.03
    np.testing.assert_allclose(fixed.position_m[0, :2], shift[:2], atol=2e-3)


def test_gauss_newton_step_damps_the_total_correction_not_the_step():
    """The ridge acts on the correction already applied plus the step: a step fitted to
    what is left of a motion, on top of any ``prior``, ends where the one-shot ridge fit
    of the whole motion does (so re-casting does not walk along the damped motions)."""
    rng = np.random.default_rng(8)
    cloud = np.zeros(300, int)
    a = rng.normal(size=(300, 6)) * [1, 1, 1, 0.05, 0.05, 0.05]   # weak rotations
    truth = np.array([[0.01, -0.02, 0.005, 0.01, -0.004, 0.006]])
    prior = np.array([[0.004, 0.003, -0.002, 0.02, 0.01, -0.01]])
    sigma, use, clouds = np.full(300, 0.003), np.ones(300, bool), np.array([0])
    once = pose_error.fit_clouds(a, a @ truth[0], sigma, cloud, use, clouds)
    step = pose_error.fit_clouds(a, a @ (truth - prior)[0], sigma, cloud, use, clouds, prior)
    np.testing.assert_allclose(prior + step, once, rtol=0, atol=1e-9)
    assert np.max(np.abs(once - truth)) > 1e-4      # the ridge does damp the weak motions


@dataclass
class _Recording:
    """What ``run.diagnosis_sample`` reads from a Measurements."""

    directions: np.ndarray
    range_m: np.ndarray
    cloud: np.ndarray

    def __len__(self) -> int:
        return len(self.range_m)


def test_the_corrected_pose_is_scored_on_a_sample_drawn_anew_not_the_old_one_re_cast():
    """Which points the candidates are scored on against the corrected pose (issue 30,
    drift_in_cloud_5cm_s1, pose_jitter_s2). 120 000 matched rays and 400 just beyond the
    silhouette; the corrected pose puts 300 of those on the target. The diagnosis
    sample holds DIAGNOSIS_MAX_MATCHED matched rays and every unmatched one: re-cast, as
    the weighing did, all 300 enter its matched points (2.4 %, ten times their share of
    the recording, 0.25 %): grazing rays where what is left of the pose error grows with
    tan(incidence), an incidence-shaped residual a --fit run never sees. Drawn anew
    from the re-cast matching (``recast_sample``), they enter at their share:
    300 x 12000 / 120300 = 30 expected (binomial sd ~5.5)."""
    from lidar_sim_ros.compare import run
    rng = np.random.default_rng(0)
    n, u, moved_in = 120_000, 400, 300
    d = rng.normal(size=(n + u, 3)) * [0.05, 0.05, 0.05] + [1.0, 0.0, 0.0]
    rec = _Recording(d / np.linalg.norm(d, axis=1, keepdims=True),
                     10.0 + rng.normal(0, 0.01, n + u), np.arange(n + u) % 4)
    before = fit_data.RaySet(rec, np.arange(n), np.arange(n, n + u))
    sample, _, _ = run.diagnosis_sample(before, rec, 0)
    assert len(sample.matched) == run.DIAGNOSIS_MAX_MATCHED and len(sample.unmatched) == u
    newly = np.arange(n, n + moved_in)                 # on the target once corrected
    after = fit_data.RaySet(rec, np.r_[np.arange(n), newly], np.arange(n + moved_in, n + u))
    # The old sample re-cast: its points, matched anew.
    picked = np.r_[sample.matched, sample.unmatched]
    recast_old = np.intersect1d(picked, after.matched)
    old_share = np.isin(recast_old, newly).mean()
    assert old_share == pytest.approx(moved_in / (run.DIAGNOSIS_MAX_MATCHED + moved_in))
    # Drawn anew, as a --fit run draws it: the recording's share.
    fresh = run.recast_sample(after, rec, 0)
    expected = moved_in * run.DIAGNOSIS_MAX_MATCHED / (n + moved_in)
    assert abs(np.isin(fresh.matched, newly).sum() - expected) < 4 * np.sqrt(expected)
    assert np.isin(fresh.matched, newly).mean() < old_share / 5


def test_fit_corrects_the_reference_pose_before_it_fits_the_effects(tmp_path, capfd):
    """``--effect pose_error --effect X --fit``: the reference pose is corrected before X
    is fitted (and again on top of it). Fitted on the recorded pose, X takes what a pose
    error leaves at silhouettes, and the correction after it leaves X wrong: on the
    fifth holdout's range walk beside a drifting pose, the loop's NLL rose when the
    phantom incidence_angle was added with the pose (-1.934 -> -1.874 nats/point)."""
    import sys
    sys.path.insert(0, str(Path(__file__).parent))
    from foreign_sim import battery, generate

    from lidar_sim_ros.cli import main
    spec = battery(['pose_drift_within'])[0]
    ds = generate(replace(spec, frames=3), tmp_path / 'rec')
    assert main(['compare', str(ds.bag), '--mesh', str(ds.mesh), '--config',
                 str(ds.scenario), '--out', str(tmp_path / 'out'), '--no-report', '--no-plan',
                 '--candidates', 'range_walk', '--effect', 'pose_error',
                 '--effect', 'range_walk', '--fit']) == 0
    lines = [ln for ln in capfd.readouterr().err.splitlines()
             if ln.startswith('lidar-sim compare: ')]
    stages = [ln.split(': ', 1)[1].rsplit(' ', 2)[0] for ln in lines]
    order = [s.split(' (')[0] for s in stages]
    first_pose = next(i for i, ln in enumerate(lines) if 'reference pose' in ln)
    fit = next(i for i, ln in enumerate(lines) if 'fit effects' in ln)
    assert first_pose < fit, order
    assert sum('reference pose' in ln for ln in lines) == 2, order


def _jittered_planes(n_clouds: int, per_cloud: int, sigma_m: float, seed: int = 0,
                     jitter: float = 1.0, step_m: float = 0.0, turn: float | None = None):
    """Three tilted planes 12 x 8 deg across at 10 m, seen in ``n_clouds`` clouds whose
    recorded pose is off by an independent rigid motion each (``jitter`` x 1 cm and 0.2
    deg per axis, about the target's centre), range noise ``sigma_m``, and every range
    ``step_m`` longer from the middle cloud on (a sensor's range step): (recording,
    FitData of the rays ``idx``, as a function). ``turn``: the rotation's factor instead
    of ``jitter`` (0: translation only)."""
    rng = np.random.default_rng(seed)
    n = n_clouds * per_cloud
    cloud, t, u, normal = three_plane_rays(rng, n_clouds, per_cloud)
    centre = np.array([10.0, 0.0, 0.0])
    turn = jitter if turn is None else turn
    rot = Rotation.from_rotvec(np.radians(rng.normal(0, 0.2 * turn, (n_clouds, 3))))[cloud]
    move = rng.normal(0, 0.01 * jitter, (n_clouds, 3))[cloud]
    measured = _plane_range_each(rot.apply(np.zeros((n, 3))) + centre + move, rot.apply(normal),
                                 u) + sigma_m * rng.standard_normal(n)
    measured = measured + np.where(cloud >= n_clouds // 2, step_m, 0.0)
    expected = _plane_range_each(np.tile(centre, (n, 1)), normal, u)

    data = plane_fit_data(expected, measured, normal, u, t, sigma_m, (5.0, 15.0))
    return _Recording(u, measured, cloud), data, t


def _planes_pose(**kw) -> tuple['_Recording', pose_error.PoseError]:
    """The per-cloud pose test on 20 clouds of 1500 rays over the three planes
    (``_jittered_planes`` with ``kw``, seed 3, 1 cm noise), every ray tested: the
    recording and the test."""
    rec, data, t = _jittered_planes(20, 1500, 0.01, seed=3, **kw)
    idx = np.arange(len(rec))
    return rec, pose_error.fit_reference_pose(data(idx), rec.cloud, t, idx // 30, 3.0,
                                              diagnosis.MIN_PRACTICAL_GAIN)


def _plane_range_each(origin, normal, u):
    """Range along each unit ray of u (N, 3) to its own plane (origin, normal: N, 3)."""
    return np.einsum('ij,ij->i', normal, origin) / np.einsum('ij,ij->i', u, normal)


def test_a_pose_jittering_over_many_clouds_is_tested_on_enough_points_a_cloud():
    """80 clouds, each recorded 1 cm / 0.2 deg off (per axis), range noise 5 cm (the
    seventh holdout's h7-n80-jitB: 80 clouds in a 16,000-point sample). On the sample's
    150 points a cloud, fitting six parameters costs the held-out test about 6 / 150 =
    0.04 nats per point, more than the jitter gains: the test failed (z below 0) and the
    features took the residual (incidence_angle named). ``pose_points`` gives the test
    every matched point (1,000 a cloud): it passes, decisively. With 1,200 or more
    sample points a cloud (5 clouds) the sample stays the test's footing."""
    from lidar_sim_ros.compare import run
    rec, data, t = _jittered_planes(80, 1000, 0.05)
    n = len(rec)
    blocks = np.arange(n) // 30
    rays = fit_data.RaySet(rec, np.arange(n), np.zeros(0, int), blocks=blocks)
    sample = rays.sample(12_000, 0)

    def test(points):
        idx = points.matched
        return pose_error.fit_reference_pose(data(idx), rec.cloud[idx], t[idx], blocks[idx],
                                             3.0, diagnosis.MIN_PRACTICAL_GAIN)
    on_sample = test(sample)
    assert not on_sample.significant and on_sample.z < 1.0
    tested = run.pose_points(rays, sample, rec)
    assert len(tested.matched) == n and len(tested.unmatched) == 0
    on_all = test(tested)
    assert on_all.significant and on_all.z > 10 and on_all.gain > 0.01
    # the translation recovered: 1 cm per axis is 1.73 cm RMS (the rotation, over
    # planes 2 m across, is known far less well)
    assert 1.4 < on_all.size_cm < 2.2
    few, _, _ = _jittered_planes(5, 3000, 0.05)
    rays5 = fit_data.RaySet(few, np.arange(len(few)), np.zeros(0, int))
    sample5 = rays5.sample(12_000, 0)
    assert run.pose_points(rays5, sample5, few) is sample5


def test_a_pose_part_is_claimed_only_where_it_passes_the_rule_on_its_own():
    """Twenty clouds, the recorded pose off by 1 cm per axis in translation only (the
    twelfth holdout's translation-only jitter, which was reported with a rotation the
    data did not have): the rotation beside the translation gains nothing held out, so
    the correction is the translation alone, its rotation zero, and the verdict's words
    give the rotation as a bound. A rotation about the points' centroid alone (0.2 deg
    per axis) is the attitude alone; both at once are both."""
    def test(jitter, turn):
        return _planes_pose(jitter=jitter, turn=turn)[1]
    moved = test(1.0, 0.0)
    assert moved.significant and moved.parts == 'translation'
    assert moved.size_deg == 0.0 and 1.4 < moved.size_cm < 2.2
    rot = moved.parts_test['rotation']
    assert not rot['shown'] and rot['z'] < 3.0
    assert moved.parts_test['translation']['shown']
    assert 0.0 < moved.parts_test['rotation_bound_deg'] < 0.5
    words = moved.words()
    assert 'in translation alone (no rotation shows: below about' in words
    assert moved.as_dict()['parts']['reported'] == 'translation'
    turned = test(0.0, 1.0)
    assert turned.significant and turned.parts == 'attitude'
    assert turned.size_cm < 0.05 and turned.size_deg > 0.2
    assert 'in attitude alone' in turned.words()
    both = test(1.0, 1.0)
    assert both.significant and both.parts == 'both' and both.size_deg > 0.2


def test_a_pose_part_not_shown_is_not_claimed_after_the_re_casts_either():
    """``--effect pose_error --fit`` composes the first fit with refits on the re-cast
    model (``iterate``): the report keeps the first fit's claim (a translation alone, no
    rotation said), while the correction applied stays the six-parameter fit, the best
    estimate, whose rotation is within the bound said (applied alone, a part not shown
    on the test's footing lost a tie on the rays it leaves out)."""
    rec, data, t = _jittered_planes(20, 1500, 0.01, seed=3, jitter=1.0, turn=0.0)
    idx = np.arange(len(rec))
    first = pose_error.fit_reference_pose(data(idx), rec.cloud, t, idx // 30, 3.0,
                                          diagnosis.MIN_PRACTICAL_GAIN)
    assert first.parts == 'translation' and first.size_deg == 0.0
    start = pose_error.PoseCorrection.identity(rec.cloud, t)
    still = replace(first, translation_m=0 * first.translation_m,
                    rotation_deg=0 * first.rotation_deg)     # a re-cast that moves nothing
    _, corr, report = pose_error.iterate(first, start, lambda c: c, lambda c, a: still)
    assert report.parts == 'translation' and report.size_deg == 0.0
    assert report.as_dict()['rotation_rms_deg'] == 0.0
    assert 1.4 < report.size_cm < 2.2
    bound = first.parts_test['rotation_bound_deg']
    applied_deg = np.degrees(np.linalg.norm(corr.rotation.as_rotvec(), axis=1))
    assert np.sqrt(np.mean(applied_deg ** 2)) <= bound
    refit = pose_error.fit_reference_pose(data(idx), rec.cloud, t, idx // 30, 3.0,
                                          diagnosis.MIN_PRACTICAL_GAIN, applied=corr)
    assert refit.parts_test is None          # a refit does not decide the claim again


def test_a_range_step_of_the_sensor_is_no_more_than_one_range_offset_per_cloud():
    """Every range 2 cm longer from the middle of 20 clouds on, the pose exact (the
    eighth holdout's h8-tstep): a rigid correction per cloud takes the step (the clouds
    moved along the line of sight) and passes its test, but one range offset per cloud,
    on the same held-out halves, gains as much with a sixth of the parameters, and the
    correction gains nothing beyond it. A pose jittering by 1 cm and 0.2 deg per axis
    gains beyond the offsets (rotations, motions across the line of sight): it stays."""
    def test(jitter, step_m):
        return _planes_pose(jitter=jitter, step_m=step_m)[1]
    step = test(0.0, 0.02)
    assert step.significant and step.z > 10
    assert step.offset_z > 10 and step.offset_gain >= step.gain
    assert step.beyond_offset_z < 3.0 and step.beyond_offset_gain < diagnosis.MIN_PRACTICAL_GAIN
    rp = step.as_dict()['per_cloud_range_offset']
    assert rp['pose_z_beyond'] == pytest.approx(step.beyond_offset_z, abs=1e-3)
    jit = test(1.0, 0.0)
    assert jit.significant and jit.beyond_offset_z > 10
    assert jit.beyond_offset_gain > diagnosis.MIN_PRACTICAL_GAIN


def test_a_pose_that_only_moves_clouds_as_a_range_offset_is_a_tie_with_range_drift():
    """``Diagnosis.range_offset_beside``: a per-cloud pose reported beside a named
    effect (the eighth holdout's range step beside a walk: 'check the tracking system')
    whose test on top of the named effect gains nothing beyond one range offset per
    cloud is the tie [pose_error, range_drift] beside it, the pose no longer reported
    alone; with nothing named, the tie itself (range_drift passing the rule). A pose
    that gains beyond the offsets, or one correction for the recording, stays."""
    _, step = _planes_pose(jitter=0.0, step_m=0.02)
    _, jit = _planes_pose()

    class Judge:                      # the two attributes the weighing reads
        z_crit = 3.0

        @staticmethod
        def nameable(c):
            return c.significant and c.practical

    walk = diagnosis.Candidate('range_walk', score=0.05, z=11.0, significant=True,
                               practical=True, effect=object())
    drift = diagnosis.Candidate('range_drift', score=0.03, z=16.0, significant=True,
                                practical=True, effect=object())
    asked = []

    def pose_test(pose):
        def run(on_top):
            asked.append(list(on_top))
            return pose
        return run
    named = diagnosis.Decision('range_walk', [], pose=step)
    out = diagnosis.Diagnosis.range_offset_beside(Judge(), named, [walk, drift],
                                                  pose_test(step))
    assert out.missing == 'range_walk' and out.pose is None
    assert out.beside_tie == ['pose_error', 'range_drift'] and out.beside_pose is step
    assert asked == [[walk.effect]]          # the pose tested with the named effect in
    alone = diagnosis.Diagnosis.range_offset_beside(
        Judge(), diagnosis.Decision(None, [], pose=step), [walk, drift], pose_test(step))
    assert alone.confounded_with == ['pose_error', 'range_drift'] and alone.pose is step
    # the pose gains beyond the offsets, or a constant correction: unchanged
    kept = diagnosis.Decision('range_walk', [], pose=jit)
    assert diagnosis.Diagnosis.range_offset_beside(Judge(), kept, [walk, drift],
                                                   pose_test(jit)) is kept
    const = diagnosis.Decision(None, [], pose=replace(step, constant=True))
    assert diagnosis.Diagnosis.range_offset_beside(Judge(), const, [walk, drift],
                                                   pose_test(step)) is const
    # nothing named and range_drift not passing the rule: nothing to tie it with
    weak = replace(drift, significant=False)
    none = diagnosis.Decision(None, [], pose=step)
    assert diagnosis.Diagnosis.range_offset_beside(Judge(), none, [weak],
                                                   pose_test(step)) is none


def test_a_range_drift_beside_a_constant_pose_along_the_line_of_sight_is_named_with_it():
    """``Diagnosis.range_term_beside_constant_pose`` (the ninth holdout's drift+pose_los:
    the range drifting 4 cm/min, the pose 3 cm off along the line of sight): on the
    recorded pose ``surface_offset`` was named (it took the constant pose's pattern at
    the limbs) and ``range_drift`` set aside by the cross-material test. Fitted on top
    of range_drift, one correction for the recording passes and took the materials'
    common offset (joint); on that corrected pose range_drift passes every test,
    surface_offset gains nothing, nor does a correction per cloud on top of the drift:
    range_drift is named, the constant pose reported beside it. Each condition failing
    leaves the decision as it was; held out within the margin of the per-cloud
    correction alone it is the tie [pose_error, range_drift]."""
    from types import SimpleNamespace as NS

    class Drift:
        pass

    class Surface:
        pass

    def cand(name, kind, score, z, vetoed=None):
        return diagnosis.Candidate(name, score=score, z=z, significant=z >= 3.0,
                                   practical=score >= diagnosis.MIN_PRACTICAL_GAIN,
                                   effect=kind(), vetoed=vetoed, params={'x': score})

    class OnPose:                     # the re-cast diagnosis: scores and the rule
        def __init__(self, scores):
            self.scores = scores

        def score(self, cls):
            name, kind = {Drift: ('range_drift', Drift), Surface: ('surface_offset',
                                                                   Surface)}[cls]
            return cand(name, kind, *self.scores[name])

        @staticmethod
        def nameable(c):
            return c.significant and c.practical and c.vetoed is None

        def naming_fault(self, c):
            return None if self.nameable(c) else 'not nameable'

    class Judge:
        @staticmethod
        def nameable(c):
            return c.significant and c.practical and c.vetoed is None

    veto = 'fitted on the PSS points it explains less than fitted at random'
    constant = NS(size_cm=2.92, constant=True)

    def judge(joint=True, surface_on_pose=(-0.0004, -0.5), drift_on_pose=(0.0618, 16.1),
              per_cloud_on_top=False, per_cloud_alone=0.045, named='surface_offset'):
        surface = cand('surface_offset', Surface, 0.0543, 9.3)
        drift = cand('range_drift', Drift, 0.0488, 12.1, vetoed=veto)
        asked = []

        def constant_test(on_top):
            asked.append([type(e).__name__ for e in on_top])
            return NS(significant=True, joint=joint, gain=0.0222, z=25.0)

        def per_cloud(on_top):
            if on_top:
                return NS(significant=per_cloud_on_top, gain=0.01 if per_cloud_on_top
                          else -0.001, z=12.0 if per_cloud_on_top else -8.0)
            return NS(significant=True, gain=per_cloud_alone, z=20.0)

        def on_constant_pose(effect):
            return (OnPose({'range_drift': drift_on_pose, 'surface_offset': surface_on_pose}),
                    constant, per_cloud)
        decision = (diagnosis.Decision(None, named) if isinstance(named, list)
                    else diagnosis.Decision(named, []))
        out = diagnosis.Diagnosis.range_term_beside_constant_pose(
            Judge(), decision, [surface, drift], constant_test, on_constant_pose)
        return out, decision, drift, asked

    out, _, drift, asked = judge()
    assert out.missing == 'range_drift' and out.pose is constant and not out.confounded_with
    assert 'surface_offset' in out.withheld and asked == [['Drift']]
    assert drift.vetoed is None                # asked again on the corrected pose
    ap = drift.against_pose
    assert ap['veto_on_recorded_pose'] == veto and ap['passes_on_pose']
    assert ap['displaced'] == {'surface_offset': [-0.0004, -0.5]}
    assert ap['heldout_margin'] == pytest.approx(0.0618 - 0.045)
    # the constant test on top of the term is recorded whatever it says (where it is not
    # joint, the path stops there: a scale on a hold took the common offset itself)
    assert ap['constant_on_top'] == {'gain': 0.0222, 'z': 25.0, 'significant': True,
                                     'joint': True, 'line_of_sight_share': None,
                                     'translation_cm': None}
    from lidar_sim_ros.compare.report.verdict import constant_pose_beside_words
    said = ' '.join(constant_pose_beside_words(drift))
    assert 'moves the target 2.9 cm' in said and 'surface_offset gains -0.0004' in said
    assert 'set aside (' + veto in said
    # held out within the margin of the per-cloud correction alone: the tie
    tie, _, _, _ = judge(per_cloud_alone=0.06)
    assert tie.missing is None and tie.confounded_with == ['pose_error', 'range_drift']
    assert tie.pose is not constant and tie.pose.gain == 0.06    # the per-cloud one
    # each condition failing: the decision stands
    for kw in ({'joint': False}, {'surface_on_pose': (0.0056, 5.4)},
               {'drift_on_pose': (0.0010, 1.0)}, {'per_cloud_on_top': True}):
        kept, before, drift, _ = judge(**kw)
        assert kept is before, kw
        assert drift.vetoed == veto, kw
        assert drift.against_pose['constant_on_top']['joint'] is kw.get('joint', True), kw
    # range_drift already named: not asked; one of a tie with surface_offset: asked
    kept, before, _, asked = judge(named='range_drift')
    assert kept is before and asked == []
    tied, _, _, asked = judge(named=['surface_offset', 'range_drift'])
    assert tied.missing == 'range_drift' and not tied.confounded_with and asked == [['Drift']]


def test_a_motion_across_the_line_of_sight_on_faces_of_one_material_each_is_fitted_through_them():
    """Nine facets, each its own material (a box satellite's sides), the target moved
    (3, 2, -3) cm: every facet's ranges move by about n.d / n.u, which free per-material
    offsets take almost whole, so the correction fitted on top of them is a fraction of
    the motion (here 0.2 cm for 4.7; the foreign extrinsic_mixed: 0.5 cm). Fitted with
    the materials
    at their configured ranges it is the motion, and it explains the materials'
    offsets (``explains_material_offsets``). Refused: a common offset alone (a range
    offset of the sensor, as much as the pose), and offsets of the materials' own that
    no rigid motion gives (each facet off by its own 4 cm)."""
    rng, a, use, facet = _facets(23, 6000, own=True)
    n_pts, cloud, clouds = len(facet), np.zeros(len(facet), int), np.array([0])
    sigma = np.full(n_pts, 2e-3)
    truth = np.array([-0.03, -0.02, 0.03, 0.0, 0.0, 0.0])

    def through(raw):
        med = np.array([np.median(raw[use & (facet == g)]) for g in range(9)])[facet]
        x = pose_error.fit_clouds(a, raw, sigma, cloud, use, clouds, None,
                                  pose_error.CONSTANT_RIDGE)
        kept = pose_error.explains_material_offsets(a @ x[0], raw, facet, use, med)
        apart = pose_error.fit_clouds(a, raw - med, sigma, cloud, use, clouds, None,
                                      pose_error.CONSTANT_RIDGE)
        return x[0], kept, apart[0]
    moved = a @ truth + rng.normal(0, 2e-3, n_pts)
    x, kept, apart = through(moved)
    assert kept
    np.testing.assert_allclose(x[:3], truth[:3], atol=3e-3)
    assert np.linalg.norm(apart[:3]) < 0.2 * np.linalg.norm(truth[:3])
    _, kept, _ = through(np.full(n_pts, 0.03) + rng.normal(0, 2e-3, n_pts))
    assert not kept
    own = rng.choice([-0.04, 0.04], 9)
    _, kept, _ = through(own[facet] + rng.normal(0, 2e-3, n_pts))
    assert not kept


def test_one_correction_for_the_recording_is_re_cast_until_its_steps_are_small():
    """``iterate`` with CONSTANT_RECAST_PASSES: each re-cast sees a fraction (0.6) of
    what is left (the seventh holdout's h7-mount1: a mount tilted 1 deg moved the
    target 14 cm at its points' centroid, seen mostly where it ends; three passes gave
    7.8 cm and 3.0 deg). Hand sum: a first step of 0.4 x 10 cm and steps 0.4 x 0.6^k x
    10 cm after it; three passes stop at 7.8 cm, the constant correction's passes run
    until the step is under RECAST_STEP_M, within a millimetre of the 10 cm."""
    def step(size_m):
        return pose_error.PoseError(np.array([0]), np.array([0.5]),
                                    np.array([[0.0, 0.0, -size_m]]), np.zeros((1, 3)), 0.0,
                                    0.0, True, np.zeros(4), np.array([[8.0, 0.0, 0.0]]))
    truth, share = 0.10, 0.4

    def run(passes_max):
        start = pose_error.PoseCorrection.identity(np.zeros(4, int), np.linspace(0, 1, 4))
        left = [truth * (1 - share)]

        def refit(state, corr):
            s = share * left[0]
            left[0] -= s
            return step(s)
        _, corr, report = pose_error.iterate(step(truth * share), start, lambda c: c, refit,
                                             passes_max)
        return -float(report.translation_m[0, 2]), report.passes
    short, passes = run(pose_error.RECAST_PASSES)
    assert passes == 3 and short == pytest.approx(truth * (1 - 0.6 ** 3), abs=1e-9)
    full, passes = run(pose_error.CONSTANT_RECAST_PASSES)
    assert 3 < passes <= pose_error.CONSTANT_RECAST_PASSES
    assert full == pytest.approx(truth, abs=1e-3)


def test_beside_a_per_cloud_pose_the_candidates_are_scored_on_the_rays_it_is_fitted_on():
    """What a per-cloud correction leaves (here 1 mm across the line of sight) moves a
    ray's range as n.d / (n.u) (``pose_error.design``): d tan(incidence) cos(azimuth of
    the normal), closed form; at most 1 mm x tan(acos MIN_COS) = 4.9 mm on the rays the
    correction is fitted on, up to 11 cm at 89.5 deg on the grazing rays it leaves out,
    where on the eighth holdout's 120 clouds of jitter the residual was 1.7 sigmas RMS
    and incidence_angle's whole gain on the corrected pose. ``run.fitted_rays_only``
    keeps exactly the rays the fit uses."""
    from types import SimpleNamespace
    from lidar_sim_ros.compare import run
    rng = np.random.default_rng(3)
    n = 4000
    inc = np.radians(rng.uniform(0.0, 89.5, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    u = np.tile([1.0, 0.0, 0.0], (n, 1))
    normal = -np.column_stack([np.cos(inc), np.sin(inc) * np.cos(phi),
                               np.sin(inc) * np.sin(phi)])
    a, use = pose_error.design(u, normal, np.full(n, 10.0), np.zeros(n, int))
    leftover = a[:, :3] @ np.array([0.0, 0.001, 0.0])
    assert np.allclose(leftover[use], (0.001 * np.tan(inc) * np.cos(phi))[use])
    assert np.array_equal(use, np.cos(inc) >= pose_error.MIN_COS)
    tan_max = np.sqrt(1 - pose_error.MIN_COS ** 2) / pose_error.MIN_COS
    assert np.max(np.abs(leftover[use])) <= 0.001 * tan_max
    grazing = np.abs(0.001 * np.tan(inc) * np.cos(phi))[~use]
    assert np.max(grazing) > 0.05 > 0.001 * tan_max
    rec = _Recording(u, np.full(n, 10.0), np.zeros(n, int))
    sample = fit_data.RaySet(rec, np.arange(n), np.zeros(0, int))
    kept = run.fitted_rays_only(sample, SimpleNamespace(hits=SimpleNamespace(
        incidence_rad=inc)))
    assert np.array_equal(np.isin(np.arange(n), kept.matched), use)


def test_a_pose_that_gains_nothing_beyond_the_named_effect_and_its_also_is_not_claimed():
    """``Diagnosis.pose_beside_named``: a range walk named, per-laser offsets 'also'
    (the ninth holdout's walk+laser, exact poses). One rigid correction for the
    recording passes on top of each alone (the lasers' offsets are a fixed pattern over
    the target, each laser's tile, which a rigid motion partly fits), but not on top of
    both fitted together: the pose is judged against them as against a named effect
    that leaves it nothing, and the walk, passing on the corrected pose, stands with its
    'also'; no pose is reported. A pose that still passes on top of them both is
    reported beside the named effect, as before."""
    walk = diagnosis.Candidate('range_walk', score=0.08, z=12.0, significant=True,
                               practical=True, effect=object(), nll_after=-1.86)
    lasers = diagnosis.Candidate('laser_bias', score=0.18, z=28.0, significant=True,
                                 practical=True, effect=object(), nll_after=-1.96)

    def pose(significant, constant=True):
        return pose_error.PoseError(
            clouds=np.zeros(1, int), t_s=np.zeros(1), translation_m=np.zeros((1, 3)),
            rotation_deg=np.zeros((1, 3)), gain=0.007 if significant else 0.0004,
            z=4.1 if significant else 0.3, significant=significant,
            correction_m=np.zeros(4), constant=constant)
    asked = []

    def constant_test(beside_both):
        def run(on_top):
            asked.append([getattr(e, 'together', e) for e in on_top])
            together = any(hasattr(e, 'together') for e in on_top)
            return pose(not (together and not beside_both))
        return run

    decision = diagnosis.Decision('range_walk', [], also='laser_bias')
    out = _Judge().judge_pose(constant_test(False), [walk, lasers], decision)
    assert out.pose is None and out.missing == 'range_walk' and out.also == 'laser_bias'
    assert [walk.effect, lasers.effect] in asked       # tested on top of both together
    assert walk.pose_beside == {'with': ['laser_bias'], 'pose_constant': True,
                                'gain': 0.0004, 'z': 0.3, 'significant': False}
    kept = _Judge().judge_pose(constant_test(True), [walk, lasers], decision)
    assert kept.pose is not None and kept.pose.significant and kept.missing == 'range_walk'


def test_lasers_set_aside_by_the_tile_test_are_put_in_when_their_tiles_hold_beside_both():
    """``pose_beside_named`` (the ninth holdout's walk+laser+bg: false returns named,
    the walk 'also', the lasers set aside by the tile test beside the false returns
    alone): lasers whose tile test passes with the named effect and its 'also' in the
    model are fitted with them before the pose is tested; lasers whose tile test still
    fails stay out (their offsets follow a pattern on the target, which may be the pose)."""
    bg = diagnosis.Candidate('solar_background', score=0.13, z=23.0, significant=True,
                             practical=True, effect='bg', nll_after=-1.9)
    walk = diagnosis.Candidate('range_walk', score=0.08, z=11.0, significant=True,
                               practical=True, effect='walk', nll_after=-1.86)
    lasers = diagnosis.Candidate('laser_bias', score=0.16, z=26.0, significant=True,
                                 practical=True, effect='lasers', nll_after=-1.96,
                                 vetoed='tiles', tile_vetoed=True)
    pose = pose_error.PoseError(
        clouds=np.zeros(1, int), t_s=np.zeros(1), translation_m=np.zeros((1, 3)),
        rotation_deg=np.zeros((1, 3)), gain=0.01, z=5.9, significant=True,
        correction_m=np.zeros(4), constant=True)

    class Judge(diagnosis.Diagnosis):
        def __init__(self, tiles_hold):
            self.tiles_hold, self.asked = tiles_hold, []

        def set_aside_beside(self, best, cands, but=()):
            return []

        def _fitted_together(self, effects):
            return list(effects)

        def tile_veto(self, cand, on_top=()):
            self.asked.append(list(on_top))
            return None if self.tiles_hold else 'a pattern on the target'

    def test(on_top):                 # the pose takes only what the lasers explain
        return replace(pose, gain=0.0, z=0.0, significant=False) if 'lasers' in on_top \
            else pose
    decision = diagnosis.Decision('solar_background', [], also='range_walk')
    judge = Judge(True)
    assert judge.pose_beside_named(test, pose, decision, [lasers, bg, walk]) == [bg]
    assert judge.asked == [['bg', 'walk']]              # the tiles asked beside both
    assert bg.pose_beside['with'] == ['range_walk', 'laser_bias']
    assert not bg.pose_beside['significant']
    assert Judge(False).pose_beside_named(test, pose, decision, [lasers, bg, walk]) == []
    assert bg.pose_beside['with'] == ['range_walk'] and bg.pose_beside['significant']


def test_a_fit_of_the_pose_per_cloud_scores_the_candidates_on_the_rays_it_is_fitted_on():
    """``--effect pose_error --fit`` (``run.on_corrected_pose``): after a per-cloud
    correction raycast again, the diagnosis run on the corrected pose scores the rays
    the correction is fitted on, as beside a per-cloud pose the diagnosis does
    (``fitted_rays_only``): what it leaves at a grazing ray grows as 1 / cos(incidence)
    (the eighth holdout's h8-n120-jitB_s10 with --effect pose_error --fit named
    incidence_angle on it). A constant correction, or one applied linearly (not
    significant: no re-cast), leaves the sample whole."""
    from types import SimpleNamespace
    from lidar_sim_ros.compare import run
    n = 1000
    inc = np.radians(np.linspace(0.0, 89.0, n))
    rec = _Recording(np.tile([1.0, 0.0, 0.0], (n, 1)), np.full(n, 10.0), np.zeros(n, int))
    sample = fit_data.RaySet(rec, np.arange(n), np.array([5000]))
    pred = SimpleNamespace(hits=SimpleNamespace(incidence_rad=inc))

    def fit(constant, passes):
        return replace(pose_error.PoseError(
            clouds=np.zeros(1, int), t_s=np.zeros(1), translation_m=np.zeros((1, 3)),
            rotation_deg=np.zeros((1, 3)), gain=0.1, z=40.0, significant=passes > 0,
            correction_m=np.zeros(n), constant=constant), passes=passes)
    kept, left = run.on_corrected_pose(sample, pred, fit(False, 3))
    grazing = np.cos(inc) < pose_error.MIN_COS
    assert left == grazing.sum() > 0
    assert np.array_equal(kept.matched, np.flatnonzero(~grazing))
    assert np.array_equal(kept.unmatched, sample.unmatched)
    for whole in (fit(True, 4), fit(False, 0), None):
        same, none = run.on_corrected_pose(sample, pred, whole)
        assert none == 0 and np.array_equal(same.matched, sample.matched)


def test_a_pose_whose_correction_would_gain_less_than_the_margin_is_not_reported():
    """``run.pose_that_matters``: the eleventh holdout's beam_1 (exact poses, a beam
    divergence) reported 'the reference pose is off by 0.1 cm and 0.01 deg': the linear
    test's gain (0.024 nats/point, z 21) came from a 1.5 cm fit the re-casts took back to
    0.08 cm. A correction is reported only if, applied exactly, it gains the practical
    margin (a 0.1 sigma shift): here the fitted 1.7 cm at 5 cm noise gains about
    (0.35)^2 / 2 and stays; the same correction at a twentieth of its size does not."""
    from lidar_sim_ros.compare import run
    rec, data, t = _jittered_planes(20, 1000, 0.05)
    n = len(rec)
    idx = np.arange(n)
    fitted = pose_error.fit_reference_pose(data(idx), rec.cloud, t, idx // 30, 3.0,
                                           diagnosis.MIN_PRACTICAL_GAIN)
    assert fitted.significant
    gain = pose_error.applied_gain(fitted, data(idx), rec.cloud)
    assert 0.02 < gain < 0.2
    decision = diagnosis.Decision(None, [], pose=fitted)
    kept, pose = run.pose_that_matters(decision, fitted, data(idx), rec.cloud)
    assert kept.pose is fitted and pose is fitted and pose.too_small is None
    tiny = replace(fitted, translation_m=fitted.translation_m / 20,
                   rotation_deg=fitted.rotation_deg / 20)
    assert pose_error.applied_gain(tiny, data(idx), rec.cloud) == pytest.approx(gain / 400,
                                                                                 rel=1e-6)
    dropped, pose = run.pose_that_matters(diagnosis.Decision(None, [], pose=tiny), tiny,
                                          data(idx), rec.cloud)
    assert dropped.pose is None and not pose.significant
    assert pose.too_small['applied_gain_per_matched_point'] < diagnosis.MIN_PRACTICAL_GAIN
    # In a tie the pose stays as the tie says it.
    tie = diagnosis.Decision(None, [diagnosis.POSE_ERROR, 'range_drift'], pose=tiny)
    assert run.pose_that_matters(tie, tiny, data(idx), rec.cloud)[0].pose is tiny


def test_a_range_scale_beside_a_pose_reported_alone_is_weighed_with_the_constant_pose_on_top():
    """A 1 % range scale on a hold beside the pose 6 cm off along the line of sight, the
    body tilted toward the line of sight: nothing was named (the pose fitted alone, 1 cm
    turned and across the line of sight, took the scale: a turn of a tilted body moves
    its ranges in proportion to depth), and range_scale, scored only beside a name
    (``weigh_rivals``), never reached ``range_term_beside_constant_pose``. Now the range
    terms are scored where the pose is reported alone (``rivals_beside_pose``) and the
    constant pose fitted on top of the scale (5 cm along the line of sight, joint with
    the materials) leaves it passing: range_scale is named, that pose beside it. Beside
    a name, or without a pose, nothing is scored here; one scored already is not again."""
    from types import SimpleNamespace as NS

    class Scale:
        name = 'range_scale'

    class Drift:
        name = 'range_drift'

    def cand(name, kind, score, z):
        return diagnosis.Candidate(name, score=score, z=z, significant=z >= 3.0,
                                   practical=score >= diagnosis.MIN_PRACTICAL_GAIN,
                                   effect=kind(), params={'x': score})

    class Judge:
        def __init__(self):
            self.scored, self.vetoed = [], []

        def score(self, cls):
            self.scored.append(cls.name)
            return (cand('range_scale', Scale, 0.0124, 7.5) if cls is Scale
                    else cand('range_drift', Drift, -0.0001, -0.7))

        def share_veto(self, c, attribution):
            self.vetoed.append(c.name)

        scored_with_vetoes = diagnosis.Diagnosis.scored_with_vetoes

        @staticmethod
        def nameable(c):
            return c.significant and c.practical and c.vetoed is None

    class OnPose:
        @staticmethod
        def score(cls):
            return cand('range_scale', Scale, 0.0150, 9.4)

        @staticmethod
        def nameable(c):
            return True

        @staticmethod
        def naming_fault(c):
            return None

    alone = NS(significant=True, gain=0.0062, z=8.0, constant=False)
    constant = NS(size_cm=5.2, constant=True)

    def constant_test(on_top):
        return (NS(significant=True, joint=True, gain=0.0116, z=7.2, size_cm=5.2,
                   line_of_sight_share=0.99) if on_top else
                NS(significant=True, joint=False, gain=0.0213, z=10.4))

    def per_cloud(on_top):
        return NS(significant=False, gain=-0.0038, z=-6.9) if on_top else alone

    def on_constant_pose(effect):
        return OnPose(), constant, per_cloud

    weigh = diagnosis.Diagnosis.range_term_beside_constant_pose
    reported = diagnosis.Decision(None, [], pose=NS(constant=True, size_cm=0.9))
    # as before: nothing scored beside the pose alone, nothing weighed
    assert weigh(Judge(), reported, [], constant_test, on_constant_pose) is reported
    judge = Judge()
    extra = diagnosis.Diagnosis.rivals_beside_pose(judge, reported, [], [Drift, Scale])
    assert [c.name for c in extra] == ['range_drift', 'range_scale']
    assert judge.vetoed == ['range_drift', 'range_scale']     # the vetoes of every candidate
    out = weigh(judge, reported, extra, constant_test, on_constant_pose)
    assert out.missing == 'range_scale' and out.pose is constant and not out.confounded_with
    scale = extra[1]
    assert scale.against_pose['constant_on_top']['translation_cm'] == 5.2
    assert scale.against_pose['heldout_margin'] == pytest.approx(0.0150 - 0.0062)
    # not beside a name, a tie, or without a pose; not one scored already
    for d in (diagnosis.Decision('incidence_angle', [], pose=reported.pose),
              diagnosis.Decision(None, ['a', 'b'], pose=reported.pose),
              diagnosis.Decision(None, [])):
        assert diagnosis.Diagnosis.rivals_beside_pose(Judge(), d, [], [Drift, Scale]) == []
    judge = Judge()
    have = [cand('range_scale', Scale, 0.0124, 7.5)]
    assert [c.name for c in diagnosis.Diagnosis.rivals_beside_pose(
        judge, reported, have, [Drift, Scale])] == ['range_drift']
    assert judge.scored == ['range_drift']


@pytest.mark.parametrize('constant', [False, True])
def test_a_step_of_the_re_casts_is_the_full_fits_correction_without_its_test(constant,
                                                                             monkeypatch):
    """``fit_reference_pose(step_only=True)``, as ``iterate``'s refits call it (the
    report keeps the first fit's test): without a rate, the correction, its range
    change and centroid are the full fit's, bit for bit, per cloud and for the
    recording; the test (held-out halves, the range-alone rival) is not asked."""
    rec, data, t = _jittered_planes(8, 1500, 0.01, seed=5)
    idx = np.arange(len(rec))
    applied = pose_error.PoseCorrection.identity(rec.cloud, t)
    args = (data(idx), rec.cloud, t, idx // 30, 3.0, diagnosis.MIN_PRACTICAL_GAIN)
    full = pose_error.fit_reference_pose(*args, applied=applied, constant=constant)
    assert full.z > 3.0                            # a correction that is there

    def no_test(*a, **k):
        raise AssertionError('the test is asked in a step')
    monkeypatch.setattr(pose_error.range_alone, 'range_fit', no_test)
    step = pose_error.fit_reference_pose(*args, applied=applied, constant=constant,
                                         step_only=True)
    for k in ('clouds', 'translation_m', 'rotation_deg', 'correction_m', 'centroid_m'):
        np.testing.assert_array_equal(getattr(step, k), getattr(full, k), err_msg=k)
    assert (step.constant, step.joint, step.through_materials) == (
        full.constant, full.joint, full.through_materials)
    assert not step.significant and step.gain == 0.0


def _cylinder_range(u: np.ndarray, centre: np.ndarray, radius_m: float):
    """Range (m) along unit rays ``u`` to an infinite cylinder along z through ``centre``
    (N, 3; its x and y), its outward unit normal there, and whether the ray meets it."""
    a = u[:, 0] ** 2 + u[:, 1] ** 2
    b = -2 * (u[:, 0] * centre[:, 0] + u[:, 1] * centre[:, 1])
    c = centre[:, 0] ** 2 + centre[:, 1] ** 2 - radius_m ** 2
    disc = b * b - 4 * a * c
    s = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
    p = s[:, None] * u
    normal = np.column_stack([p[:, 0] - centre[:, 0], p[:, 1] - centre[:, 1], 0 * s]) / radius_m
    return s, normal, disc > 0


def test_a_shift_across_a_cylinder_is_said_at_its_size_as_either_part_alone():
    """Twenty clouds of a cylinder (radius 1.5 m, 10 m away), each recorded 3 cm off
    sideways (a translation only). On a cylinder a sideways shift is also a turn about the
    centroid of the points seen, so neither part passes beyond the other ('either'); fitted
    side by side the ridge split the shift into 1.1 cm and 0.87 deg, and the verdict said
    "about 1.1 cm and 0.87 deg" for a 3.2 cm RMS shift (the eighteenth holdout's jitter, said
    as half its size). Each part is now said as fitted alone: the translation alone within
    15 % of the truth."""
    rng = np.random.default_rng(3)
    n_clouds, per = 20, 1500
    n = n_clouds * per
    az, el = rng.uniform(-0.11, 0.11, n), rng.uniform(-0.1, 0.1, n)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    cloud = np.repeat(np.arange(n_clouds), per)
    t = cloud * 0.1 + rng.uniform(0.0, 0.09, n)
    dy = rng.normal(0.0, 0.03, n_clouds)
    nominal = np.tile([10.0, 0.0, 0.0], (n, 1))
    expected, normal, met = _cylinder_range(u, nominal, 1.5)
    shifted = nominal + np.column_stack([0 * dy, dy, 0 * dy])[cloud]
    measured, _, met_too = _cylinder_range(u, shifted, 1.5)
    measured = measured + 0.01 * rng.standard_normal(n)
    data = plane_fit_data(expected, measured, normal, u, t, 0.01, (5.0, 15.0))
    idx = np.flatnonzero(met & met_too)
    pose = pose_error.fit_reference_pose(data(idx), cloud[idx], t[idx], idx // 30, 3.0,
                                         diagnosis.MIN_PRACTICAL_GAIN)
    truth_cm = 100 * np.sqrt(np.mean(dy ** 2))
    assert pose.significant and pose.parts == 'either'
    alone = pose.parts_test['translation_alone_cm']
    assert abs(alone - truth_cm) < 0.15 * truth_cm
    assert pose.size_cm < 0.6 * truth_cm          # the split's share: not what is said
    words = pose.words()
    assert f'{alone:.1f} cm as a translation alone, or' in words
    assert f'{pose.size_cm:.1f} cm and' not in words
    moved = replace(pose, parts='translation')
    assert moved.size_cm == alone
