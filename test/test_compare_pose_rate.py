"""A reference pose that drifts within a cloud (compare/diagnose/pose_error.py: ``time_scale``,
``rate_columns``, ``fit_reference_pose(rate=True)``, ``PoseCorrection`` with a rate):
closed forms on a plane, no raycast."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from conftest import three_planes

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.diagnose import pose_error, scan_clock
from lidar_sim_ros.core.effects.base import ReturnContext
from lidar_sim_ros.core.geometry import Hits
from lidar_sim_ros.core.pipeline import Prediction
from lidar_sim_ros.core.pose import PoseTrack

SIGMA_M = 0.01


def _planes(n: int, seed: int):
    """Rays over 12 x 8 deg on three planes at ~10 m (normals tilted differently by
    azimuth), and each ray's time within one of four 0.1 s clouds (the scan sweeps
    elevation with time, as a raster does)."""
    rng = np.random.default_rng(seed)
    _, el, u, normal, centre = three_planes(rng, n)
    cloud = rng.integers(0, 4, n)
    t = cloud * 0.1 + (el + 0.07) / 0.14 * 0.09
    return u, normal, centre, cloud, t, rng


def _range(origin, normal, u):
    return np.einsum('ij,ij->i', normal, origin) / np.einsum('ij,ij->i', u, normal)


def _data(u, normal, measured_m, expected_m, t):
    """FitData of matched rays whose model range is ``expected_m`` (one material)."""
    n = len(u)
    one = np.ones(n)
    ctx = ReturnContext(range_m=expected_m, incidence_rad=0 * one, material=np.zeros(n, int),
                        power_w=1e-6 * one, intensity=one, t_s=t, az_rad=0 * one,
                        el_rad=0 * one, laser=np.zeros(n, int), divergence_rad=1e-3,
                        hit=np.ones(n, bool), threshold_power_w=1e-9, direction=u,
                        normal=-normal)
    hits = Hits(np.ones(n, bool), expected_m, -normal, 0 * one, np.zeros(n, int),
                np.zeros(n, int), None, one)
    pred = Prediction(ctx, hits, u, 0 * one, SIGMA_M * one)
    return lk.FitData(measured_range_m=measured_m, baseline=pred, cast=lambda e: pred,
                      unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                      range_window_m=(5.0, 15.0))


def _drifting(rate_deg_s: float, rigid_deg: float, seed: int = 0, n: int = 12_000):
    """Measured ranges of planes turned about the z axis through (10, 0, 0) by
    ``rigid_deg`` per cloud plus ``rate_deg_s`` times the time from the cloud's centre."""
    u, normal, centre, cloud, t, rng = _planes(n, seed)
    tau_s = t - (cloud * 0.1 + 0.045)
    angle = np.radians(rigid_deg * (cloud - 1.5) + rate_deg_s * tau_s)
    rot = Rotation.from_rotvec(np.outer(angle, [0.0, 0.0, 1.0]))
    origin = np.tile(centre, (len(u), 1))
    moved_n = rot.apply(normal)
    measured = _range(origin, moved_n, u) + SIGMA_M * rng.standard_normal(len(u))
    expected = _range(origin, normal, u)
    return _data(u, normal, measured, expected, t), cloud, t


def test_a_drift_within_each_cloud_is_found_and_measured():
    """20 deg/s about z (0.9 deg over a 0.045 s half-scan) on top of a rigid turn per
    cloud: the rate passes the rule on top of the rigid correction and is recovered."""
    data, cloud, t = _drifting(20.0, 0.5)
    blocks = np.arange(len(t)) // 30
    pe = pose_error.fit_reference_pose(data, cloud, t, blocks, 3.0, 0.005, rate=True)
    assert pe.rate_tested and pe.rate_supported and pe.rate_z > 3.0
    assert pe.significant
    np.testing.assert_allclose(pe.rate_rotation_deg_s[:, 2], 20.0, rtol=0.15)
    assert np.all(np.abs(pe.rate_rotation_deg_s[:, :2]) < 3.0)
    rigid = pose_error.fit_reference_pose(data, cloud, t, blocks, 3.0, 0.005, rate=False)
    assert not rigid.rate_tested and rigid.gain < pe.gain
    assert 'drifts within each cloud' in pe.words()
    assert pe.as_dict()['rate']['supported'] is True


def test_a_rigid_error_per_cloud_gives_no_rate():
    data, cloud, t = _drifting(0.0, 0.5, seed=1)
    pe = pose_error.fit_reference_pose(data, cloud, t, np.arange(len(t)) // 30, 3.0, 0.005,
                                       rate=True)
    assert pe.significant and pe.rate_tested and not pe.rate_supported
    assert pe.rate_translation_mps is None and 'drifts' not in pe.words()


def test_corrected_poses_apply_the_rate_within_the_cloud():
    """A correction with a rate turns the target by rate x (t - t_c) about the cloud's
    centroid on top of its rigid part: a body point's position follows in closed form."""
    track = PoseTrack(np.array([0.0, 1.0]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    g = np.array([[10.0, 0.0, 0.0]])
    w = np.radians([[0.0, 0.0, 0.9]])            # per unit tau
    corr = pose_error.PoseCorrection(np.array([0]), np.array([0.0]), np.array([0.09]),
                                     Rotation.identity(1), np.zeros((1, 3)), g,
                                     rate_m=np.array([[0.0, 0.002, 0.0]]), rate_rotvec_rad=w,
                                     t_centre_s=np.array([0.045]), half_span_s=np.array([0.045]))
    poses = pose_error.CorrectedPoses(track, corr).at(np.array([0.0, 0.045, 0.09]))
    point = np.array([11.0, 0.5, 0.0])           # body = lidar frame under the track
    got = poses.rotation.apply(np.tile(point, (3, 1))) + poses.position_m
    for tau, p in zip((-1.0, 0.0, 1.0), got):
        rot = Rotation.from_rotvec(w[0] * tau)
        want = rot.apply(point - g[0]) + g[0] + tau * np.array([0.0, 0.002, 0.0])
        np.testing.assert_allclose(p, want, atol=1e-12)


def test_a_constant_pose_error_is_one_correction_for_all_clouds():
    """``constant``: planes turned by the same 0.3 deg about z in every cloud (an
    extrinsic error): one rigid correction, rotation about the centroid of all the
    points, recovers it; the report says it is the same in every cloud."""
    u, normal, centre, cloud, t, rng = _planes(12_000, 3)
    rot = Rotation.from_rotvec([0.0, 0.0, np.radians(0.3)])
    origin = np.tile(centre, (len(u), 1))
    measured = _range(origin, rot.apply(normal), u) + SIGMA_M * rng.standard_normal(len(u))
    data = _data(u, normal, measured, _range(origin, normal, u), t)
    blocks = np.arange(len(t)) // 30
    pe = pose_error.fit_reference_pose(data, cloud, t, blocks, 3.0, 0.005, rate=True,
                                       constant=True)
    assert pe.constant and pe.significant and len(pe.clouds) == 1
    assert pe.rate_tested and not pe.rate_supported    # one rate for the recording: none
    np.testing.assert_allclose(pe.rotation_deg[0, 2], 0.3, rtol=0.1)
    assert 'the same in every cloud' in pe.words() and pe.as_dict()['constant'] is True
    per_cloud = pose_error.fit_reference_pose(data, cloud, t, blocks, 3.0, 0.005)
    assert not per_cloud.constant and len(per_cloud.clouds) == 4


def test_a_rate_held_out_on_few_points_a_cloud_loses_its_gain_to_the_fit_noise():
    """Why the pose a named effect is weighed against is fitted on every matched point
    (``run.diagnose``'s ``recast``), as --effect pose_error --fit fits it: six more
    parameters per cloud, fitted on half of 300 points a cloud, lose about
    6 / (2 x 150) nats/point of held-out gain to their own noise, which is what a
    10 deg/s drift gains (0.9 deg over the scan); on 3 000 points a cloud it is found."""
    few = _drifting(10.0, 0.5, seed=2, n=1200)
    many = _drifting(10.0, 0.5, seed=2, n=12_000)
    got = [pose_error.fit_reference_pose(data, cloud, t, np.arange(len(t)) // 30, 3.0,
                                         0.005, rate=True) for data, cloud, t in (few, many)]
    assert got[0].significant and not got[0].rate_supported and got[0].rate_gain < 0.005
    assert got[1].rate_supported and got[1].rate_gain > 2 * got[0].rate_gain
    np.testing.assert_allclose(np.mean(got[1].rate_rotation_deg_s[:, 2]), 10.0, rtol=0.15)


def _held(rate_mps: float, offset_m: float, seed: int, n: int = 12_000, along=(0.0, 1.0, 0.0),
          raster: bool = False):
    """Planes moved by ``offset_m + rate_mps x (time since the cloud's start)`` along
    ``along`` in every cloud: a tracking pose sampled at each cloud's start and held
    over its scan (a sample-and-hold pose of a target moving at ``rate_mps``). Each
    ray's time within the scan is drawn at random over 0.09 s (a pattern that meets
    each direction at several times, as a Lissajous does), or with ``raster`` follows
    its elevation (``_planes``: the time fixed by the direction)."""
    u, normal, centre, cloud, t, rng = _planes(n, seed)
    if not raster:
        t = cloud * 0.1 + rng.uniform(0.0, 0.09, len(t))
    since = t - cloud * 0.1
    shift = np.outer(offset_m + rate_mps * since, along)
    origin = np.tile(centre, (len(u), 1))
    measured = _range(origin + shift, normal, u) + SIGMA_M * rng.standard_normal(len(u))
    return _data(u, normal, measured, _range(origin, normal, u), t), cloud, t


def test_the_same_drift_in_every_cloud_is_one_rate_for_the_recording():
    """0.4 m/s across the line of sight, reset at each cloud's start (0 -> 3.6 cm over the
    0.09 s scan): one correction for the recording with one rate over the scan finds it
    (on a time base from each cloud's start), and reports its size per 0.1 s."""
    data, cloud, t = _held(0.4, 0.0, seed=4)
    blocks = np.arange(len(t)) // 30
    pe = pose_error.fit_reference_pose(data, cloud, t, blocks, 3.0, 0.005, rate=True,
                                       constant=True)
    assert pe.constant and pe.rate_tested and pe.rate_supported and pe.significant
    assert pe.rate_z > 3.0 and pe.rate_gain >= 0.005 and pe.n_params == 12
    np.testing.assert_allclose(pe.rate_translation_mps[0], [0.0, 0.4, 0.0], atol=0.05)
    rate = pe.as_dict()['rate']
    assert rate['supported'] and rate['same_in_every_cloud']
    np.testing.assert_allclose(rate['drift_per_0_1_s_cm'], 4.0, rtol=0.12)
    assert 'drifts within each cloud' in pe.words() and 'per 0.1 s' in pe.words()
    # The mean over the scan is the rigid part: about half the drift.
    np.testing.assert_allclose(pe.translation_m[0, 1], 0.4 * 0.045, atol=0.006)


def test_a_constant_pose_error_gives_no_rate():
    data, cloud, t = _held(0.0, 0.03, seed=5)
    pe = pose_error.fit_reference_pose(data, cloud, t, np.arange(len(t)) // 30, 3.0, 0.005,
                                       rate=True, constant=True)
    assert pe.constant and pe.significant and pe.rate_tested and not pe.rate_supported
    assert pe.n_params == 6 and 'drifts' not in pe.words()
    assert pe.as_dict()['rate']['supported'] is False


def test_a_raster_cannot_tell_one_rate_from_a_pattern_over_the_directions():
    """A raster's time within the scan follows its rows: one rate for the recording is
    then a fixed pattern over the field of view, which a sensor's own pattern passes for.
    A range bias of the sensor that follows the elevation (the rows) is not read as a
    drift of the pose; the same bias with a time that the direction does not fix is."""
    u, normal, centre, cloud, t, rng = _planes(12_000, 8)
    el = np.degrees(np.arcsin(u[:, 2]))
    origin = np.tile(centre, (len(u), 1))
    expected = _range(origin, normal, u)
    measured = expected + 0.01 * el + SIGMA_M * rng.standard_normal(len(u))
    data = _data(u, normal, measured, expected, t)
    pe = pose_error.fit_reference_pose(data, cloud, t, np.arange(len(t)) // 30, 3.0, 0.005,
                                       rate=True, constant=True)
    assert pe.rate_tested and not pe.rate_supported
    # A pose drifting with the same raster timing is not claimed either: the data cannot
    # tell it from a pattern over the directions.
    data_d, cloud_d, t_d = _held(0.4, 0.0, seed=9, raster=True)
    pe_d = pose_error.fit_reference_pose(data_d, cloud_d, t_d, np.arange(len(t_d)) // 30,
                                         3.0, 0.005, rate=True, constant=True)
    assert pe_d.rate_tested and not pe_d.rate_supported


def test_no_pose_error_gives_no_rate():
    data, cloud, t = _held(0.0, 0.0, seed=6)
    pe = pose_error.fit_reference_pose(data, cloud, t, np.arange(len(t)) // 30, 3.0, 0.005,
                                       rate=True, constant=True)
    assert not pe.significant and not pe.rate_supported


def test_the_scan_clock_reads_tau_at_the_pose_samples():
    """Stamps at each scan's start (0.1 s frames), pose samples at 100 Hz: a sample at a
    stamp is its scan's first (tau -1, also a hair before it), and between a scan's last
    sample (0.09 s in, tau 0.8) and the next scan's first the pose's tau runs back, as
    the interpolated pose does."""
    stamps = np.array([0.0, 0.1, 0.2])
    cloud = np.repeat([0, 1, 2], 100)
    t = stamps[cloud] + np.tile(np.linspace(0.0, 0.1, 100, endpoint=False), 3)
    samples = np.round(np.arange(0.0, 0.3001, 0.01), 6) - 1e-9 * (np.arange(31) % 2)
    clock = scan_clock.ScanClock.of(cloud, t, stamps, samples)
    assert clock.period_s == pytest.approx(0.1) and clock.centre_s == pytest.approx(0.0495, abs=2e-4)
    h = clock.half_s
    np.testing.assert_allclose(clock.tau(np.array([0.1, 0.19])),
                               [(0 - clock.centre_s) / h, (0.09 - clock.centre_s) / h], atol=1e-6)
    # Half-way between 0.19 s (tau ~0.82) and 0.2 s (tau ~-0.99): their mean.
    mid = clock.tau(np.array([0.195]))[0]
    np.testing.assert_allclose(mid, 0.5 * ((0.09 - clock.centre_s) + (0 - clock.centre_s)) / h,
                               atol=1e-6)
    # Without samples: tau at the time itself.
    plain = scan_clock.ScanClock.of(cloud, t, stamps)
    np.testing.assert_allclose(plain.tau(np.array([0.195])), (0.095 - plain.centre_s) / h,
                               atol=1e-6)


def test_a_drift_of_the_pose_samples_is_measured_whole():
    """A pose drifting 0.4 m/s across the line of sight from each scan's start, sampled
    at 100 Hz and interpolated between the samples as the model reads it (running back
    to zero between a scan's last sample and the next scan's first): fitted on tau at
    the samples, 4 cm per 0.1 s; on tau at the point times, about 2.9 cm."""
    u, normal, centre, cloud, _, rng = _planes(12_000, 7)
    since = rng.uniform(0.0, 0.0999, len(u))
    t = cloud * 0.1 + since
    samples = np.arange(0.0, 0.4001, 0.01)
    held = 0.4 * 0.01 * (np.round(samples * 100).astype(int) % 10)   # 0.4 m/s x time in scan
    error = np.interp(t, samples, held)
    origin = np.tile(centre, (len(u), 1))
    measured = _range(origin + np.outer(error, [0.0, 1.0, 0.0]), normal, u) \
        + SIGMA_M * rng.standard_normal(len(u))
    data = _data(u, normal, measured, _range(origin, normal, u), t)
    blocks = np.arange(len(t)) // 30
    stamps = np.array([0.0, 0.1, 0.2, 0.3])

    def fitted(clock):
        pe = pose_error.fit_reference_pose(data, cloud, t, blocks, 3.0, 0.005, rate=True,
                                           constant=True, scan=clock)
        assert pe.rate_supported
        return pe.as_dict()['rate']['drift_per_0_1_s_cm']
    assert fitted(scan_clock.ScanClock.of(cloud, t, stamps, samples)) == pytest.approx(4.0, rel=0.08)
    assert fitted(scan_clock.ScanClock.of(cloud, t, stamps)) == pytest.approx(2.9, rel=0.1)


def test_corrected_poses_apply_one_rate_on_the_scan_clock():
    """One correction for the recording with a rate: at time t the target is moved by
    tau(t) x the rate, tau on each cloud's own scan (the rate resets at each stamp)."""
    track = PoseTrack(np.array([0.0, 1.0]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    stamps = np.array([0.0, 0.1, 0.2])
    cloud = np.repeat([0, 1, 2], 50)
    t = stamps[cloud] + np.tile(np.linspace(0.0, 0.099, 50), 3)
    clock = scan_clock.ScanClock.of(cloud, t, stamps)
    rate = np.array([[0.0, 0.02, 0.0]])                 # m per unit tau
    corr = pose_error.PoseCorrection(np.array([0]), np.array([0.0]), np.array([0.3]),
                                     Rotation.identity(1), np.array([[0.01, 0.0, 0.0]]),
                                     np.array([[10.0, 0.0, 0.0]]), rate_m=rate,
                                     rate_rotvec_rad=np.zeros((1, 3)),
                                     t_centre_s=np.array([clock.centre_s]),
                                     half_span_s=np.array([clock.half_s]), scan=clock)
    at = np.array([0.0, 0.099, 0.1, 0.15, 0.299])
    got = pose_error.CorrectedPoses(track, corr).at(at).position_m
    tau = (at - np.floor(at * 10 + 1e-9) / 10 - clock.centre_s) / clock.half_s
    np.testing.assert_allclose(got[:, 1], 0.02 * tau, atol=1e-12)
    np.testing.assert_allclose(got[:, 0], 0.01, atol=1e-12)
    np.testing.assert_allclose(got[[0, 2], 1], -0.02, atol=1e-3)   # each scan starts anew


def test_the_scan_clock_takes_bad_times():
    """No finite time, no span within the clouds, no clouds: no time base (no rate is
    tested); pose samples at NaN, inf or 1e300 are left out or read at the recording's
    edge, and a stamp that is NaN drops its cloud."""
    cloud = np.zeros(5, int)
    t = np.linspace(0.0, 0.09, 5)
    assert scan_clock.ScanClock.of(cloud, np.full(5, np.nan)) is None
    assert scan_clock.ScanClock.of(cloud, np.zeros(5)) is None
    assert scan_clock.ScanClock.of(np.zeros(0, int), np.zeros(0)) is None
    clock = scan_clock.ScanClock.of(cloud, t, np.array([0.0]),
                                    np.array([np.nan, np.inf, 0.0, 0.05, 1e300, -1e300]))
    tau = clock.tau(np.array([0.0, 0.05, 1e9, -1e9]))
    assert np.all(np.isfinite(tau)) and np.all(np.abs(tau) <= 1.1)
    two = scan_clock.ScanClock.of(np.array([0, 0, 1, 1]), np.array([0.0, 0.05, np.nan, 1e300]),
                                  np.array([0.0, np.nan]))
    assert len(two.stamps_s) == 1


def test_one_rate_for_the_recording_composes_into_the_correction():
    """``--effect pose_error --fit``'s first pass: the fitted correction and its rate,
    composed on no correction, move the target by the fitted rate times tau on the
    recording's scan clock, reset in each cloud (the rate per second as reported)."""
    data, cloud, t = _held(0.4, 0.0, seed=10)
    pe = pose_error.fit_reference_pose(data, cloud, t, np.arange(len(t)) // 30, 3.0, 0.005,
                                       rate=True, constant=True)
    assert pe.rate_supported and pe.scan is not None
    corr, _ = pose_error.PoseCorrection.identity(np.zeros_like(cloud), t).compose(pe)
    assert corr.scan is pe.scan
    track = PoseTrack(np.array([-1.0, 1.0]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    moved = pose_error.CorrectedPoses(track, corr)
    g = corr.centroid_m[0]
    at = np.array([0.01, 0.08, 0.11, 0.18])      # early and late in two clouds
    p = moved.at(at)
    shift = p.rotation.apply(np.tile(g, (4, 1))) + p.position_m - g
    # Late minus early in each cloud: 0.07 s of the fitted rate (about 0.4 m/s across).
    for a, b in ((0, 1), (2, 3)):
        np.testing.assert_allclose(shift[b] - shift[a], 0.07 * pe.rate_translation_mps[0],
                                   atol=2e-4)
    np.testing.assert_allclose(shift[2], shift[0], atol=2e-4)    # reset at the next cloud
    np.testing.assert_allclose((shift[1] - shift[0])[1], 0.028, atol=0.004)


def _over_scan(range_rate_mps: float, seed: int, n: int = 12_000):
    """Planes whose measured range grows by ``range_rate_mps x (time since the cloud's
    start)`` on every ray, the same in every cloud: the sensor's range changing over its
    scan (docs/compare.md's walkthrough recording), not the pose."""
    u, normal, centre, cloud, t, rng = _planes(n, seed)
    t = cloud * 0.1 + rng.uniform(0.0, 0.09, len(t))
    origin = np.tile(centre, (len(u), 1))
    expected = _range(origin, normal, u)
    measured = expected + range_rate_mps * (t - cloud * 0.1) \
        + SIGMA_M * rng.standard_normal(len(u))
    return _data(u, normal, measured, expected, t), cloud, t


@pytest.mark.parametrize('seed', [10, 11])
def test_a_range_growing_over_the_scan_is_no_rate_of_the_pose(seed):
    """A range offset of the sensor growing over each scan, the same in every cloud, is
    what one rate of the pose along the line of sight does: the rate passes its own test
    but not beyond that offset, so it is not claimed, and the tie is recorded; a drift
    across the line of sight is claimed (the test above)."""
    data, cloud, t = _over_scan(0.4, seed)
    pe = pose_error.fit_reference_pose(data, cloud, t, np.arange(len(t)) // 30, 3.0, 0.005,
                                       rate=True, constant=True)
    assert pe.rate_tested and not pe.rate_supported
    tie = pe.as_dict()['rate']['tied_with_range_over_scan']
    assert tie['rate_gain'] >= 0.005 and tie['z'] < 3.0
    data_c, cloud_c, t_c = _held(0.4, 0.0, seed=seed)
    pe_c = pose_error.fit_reference_pose(data_c, cloud_c, t_c, np.arange(len(t_c)) // 30,
                                         3.0, 0.005, rate=True, constant=True)
    assert pe_c.rate_supported and 'tied_with_range_over_scan' not in pe_c.as_dict()['rate']


def test_a_rate_per_cloud_claims_a_part_only_where_it_passes_the_rule_on_its_own():
    """A translation growing over each cloud (0.4 m/s across the line of sight, no
    turning): the per-cloud rate passes, and on top of the rigid part its turning gains
    nothing beyond its translation, so the drift is a translation alone, with no
    rotation said (the twelfth holdout's translation-only jitter was reported with a
    drift of 1.1 deg within each cloud). A turning about a point near the planes'
    centroid (20 deg/s) is an attitude alone."""
    data, cloud, t = _held(0.4, 0.0, seed=5)
    blocks = np.arange(len(t)) // 30
    moved = pose_error.fit_reference_pose(data, cloud, t, blocks, 3.0, 0.005, rate=True)
    assert moved.rate_supported and moved.rate_parts == 'translation'
    assert moved.drift_deg == 0.0 and 3.0 < moved.drift_cm < 4.5
    assert not moved.rate_parts_test['rotation']['shown']
    assert 'drifts within each cloud by about' in moved.words()
    assert 'in translation alone (no rotation within the cloud shows' in moved.words()
    assert moved.rate_dict()['parts']['reported'] == 'translation'
    turned = pose_error.fit_reference_pose(*_drifting(20.0, 0.5), blocks, 3.0, 0.005,
                                           rate=True)
    assert turned.rate_supported and turned.rate_parts == 'attitude'
    np.testing.assert_allclose(turned.rate_rotation_deg_s[:, 2], 20.0, rtol=0.15)


def test_a_rate_decisive_but_short_of_the_margin_is_said_not_claimed():
    """The nineteenth holdout's lagdrift: a pose turning 0 -> 0.57 deg over each scan was
    said as one rigid correction (its mean); the rate over it, 0.0046 nats/point at
    z 9.6, was decisive but short of the margin and went unsaid. It is said, with its
    figures, and not claimed; without it (or below the bound) the words are as before."""
    def pose(decisive, constant=True):
        return pose_error.PoseError(
            clouds=np.arange(2), t_s=np.zeros(2), translation_m=np.full((2, 3), 0.004),
            rotation_deg=np.full((2, 3), 0.16), gain=0.0204, z=8.4, significant=True,
            correction_m=np.zeros(4), constant=constant, rate_tested=True,
            rate_gain=0.004552, rate_z=9.628, rate_decisive=decisive)
    for constant in (True, False):
        said = pose(True, constant).words()
        assert 'it may also drift within each cloud' in said
        assert '0.0046 nats/point' in said and 'z = 9.6' in said and 'not claimed' in said
        assert 'drift within each cloud' not in pose(False, constant).words()
    assert pose(True).as_dict()['rate']['decisive_short_of_margin'] is True
