"""Reference-pose errors (compare/pose_error.py) and the one decision rule
(compare/diagnosis.py: ``total_z``, ``Diagnosis._set_gain``): closed forms, no raycast."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare import diagnosis, pose_error


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
    from lidar_sim_ros.compare import likelihood as lk
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
    np.testing.assert_array_equal(diagnosis.footprint_signature(data, [eff]),
                                  [True, False, True, False, False])
    assert diagnosis.unmatched_credit(data, [eff], eff, 5.0) == 2.0
    # Without measured power, no edge point is credited to a footprint.
    from dataclasses import replace
    assert diagnosis.unmatched_credit(replace(data, unmatched_power_w=None), [eff], eff,
                                      5.0) == 0.0

