"""loop/metrics.py, step.score, guidance and the gate, against hand calculations: the four
loop mutations of issue 29 that no test caught (each test fails with its bug put back)."""
import numpy as np
import pytest

from lidar_sim_ros.loop.config import GuidanceConfig, LoopConfig, load_loop_config
from lidar_sim_ros.loop.guidance import GuidanceState, Reference, guidance_step
from lidar_sim_ros.loop.step import LoopState, StepOutput, TruthSamples, score, tracker_cloud
from lidar_sim_ros.paths import config_path

T = 0.1


def _config(**guidance) -> LoopConfig:
    cfg = load_loop_config(config_path('loop.yaml'))[0]
    return cfg.model_copy(update={'guidance': cfg.guidance.model_copy(update=guidance)})


def _output(t_end: float, rho_true, rho_est, ref_y: float, force, index=0) -> StepOutput:
    """A period of a synthetic run: the chaser at rho_true (LVLH), the estimate's rho_est,
    the target 10 m ahead of the lidar."""
    k = 2
    truth = TruthSamples(
        t_s=np.array([t_end - T, t_end - T / 2, t_end]), R_LT=np.repeat(np.eye(3)[None], 3, 0),
        t_L_m=np.tile([10.0, 0.0, 0.0], (3, 1)), sun_lidar=np.tile([1.0, 0, 0], (3, 1)),
        R_HB=np.repeat(np.eye(3)[None], 3, 0), rho_m=np.tile(rho_true, (k + 1, 1)),
        rho_dot_mps=np.zeros((3, 3)), n_rad_s=0.0011, eclipsed=np.zeros(3, bool))
    pose = np.eye(4)
    pose[:3, 3] = [10.0, 0.0, 0.0]
    ref = Reference(np.array([0.0, ref_y, 0.0]), np.zeros(3), 'hold', index, True)
    return StepOutput(truth, t_end - T / 2, pose, pose, ref, np.asarray(force, float), False, False,
                      np.asarray(rho_est, float))


def test_hold_error_is_the_truth_from_the_hold_and_delta_v_sums_the_magnitudes():
    """Hold 30 m for 12 s, then move: the true chaser sits 0.2 m short of the hold point
    while the estimate reads it 0.5 m past; the force alternates +-2 N along x (a signed
    sum would give 0) with 1 N along y."""
    cfg = _config(hold_time_s=5.0)
    outputs = []
    for i in range(150):
        t = (i + 1) * T
        ref_y = -30.0 if t <= 12.0 + 1e-9 else -30.0 + 0.1 * (t - 12.0)
        outputs.append(_output(t, [0.0, -30.2, 0.0], [0.0, -29.5, 0.0], ref_y,
                               [2.0 if i % 2 else -2.0, 1.0, 0.0]))
    m = score(cfg, outputs).metrics
    # By hand: the dwell is the 5 s before the reference leaves (t in (7, 12]): 50 samples,
    # each 0.2 m from the hold along V-bar (the estimate's 0.5 m must not enter).
    assert m['hold_samples'] == 50
    assert abs(m['hold_error_m'] - 0.2) < 1e-12
    # sum |F| dt / m = 150 x sqrt(5) x 0.1 / 500
    assert abs(m['delta_v_mps'] - 150 * np.sqrt(5.0) * T / cfg.chaser.mass_kg) < 1e-12


def test_a_hold_dwells_only_once_slow_as_well_as_near():
    """Within the settle radius but faster than settle_speed_mps: the dwell does not start;
    it starts when the chaser is slow, and the reference leaves hold_time_s after that."""
    cfg = GuidanceConfig(hold_ranges_m=[30.0, 15.0], hold_time_s=5.0, settle_radius_m=0.3,
                         settle_speed_mps=0.02)
    g = GuidanceState()
    near = np.array([0.0, -30.1, 0.0])
    for k in range(100):                     # 10 s near but at 0.05 m/s
        g, ref = guidance_step(cfg, g, k * T, near, np.array([0.0, 0.05, 0.0]))
        assert not ref.settled and ref.phase == 'hold' and g.settled_since_s is None
    left = None
    for k in range(100, 200):                # then slow
        g, ref = guidance_step(cfg, g, k * T, near, np.zeros(3))
        if ref.phase == 'transfer' and left is None:
            left = k * T
    assert abs(left - (10.0 + 5.0)) < 1e-9   # settled at 10 s, left 5 s later


def test_after_a_loss_the_gate_recaptures_about_the_cloud_not_the_stale_estimate():
    cfg = _config()
    rng = np.random.default_rng(3)
    target = rng.normal([14.0, 1.0, 0.0], 1.5, (300, 3))   # the target moved 4 m from the last estimate
    far = rng.uniform(60.0, 200.0, (30, 3))
    xyz = np.vstack([target, far])
    stale = np.eye(4)
    stale[:3, 3] = [10.0, -6.0, 0.0]
    lost = LoopState(tracking=False, last_estimate=stale)
    got = tracker_cloud(cfg, xyz, lost)
    # By hand: the points within capture_gate_m of the cloud's per-axis median.
    median = np.array([np.sort(xyz[:, i])[len(xyz) // 2 - 1: len(xyz) // 2 + 1].mean() for i in range(3)])
    expected = xyz[np.linalg.norm(xyz - median, axis=1) <= cfg.capture_gate_m]
    np.testing.assert_array_equal(got, expected)
    assert len(got) >= 295                                  # the target kept ...
    assert not np.array_equal(got, xyz[np.linalg.norm(xyz - stale[:3, 3], axis=1) <= cfg.cloud_gate_m])
    # ... while tracking, the gate is about the last estimate.
    tracking = LoopState(tracking=True, last_estimate=stale)
    np.testing.assert_array_equal(tracker_cloud(cfg, xyz, tracking),
                                  xyz[np.linalg.norm(xyz - stale[:3, 3], axis=1) <= cfg.cloud_gate_m])



def _approach(n: int, seed: int = 0):
    """A perfect follower of the guidance through three holds, with noise on the truth: per
    period t, rho, reference, range, force (and estimates on most periods)."""
    cfg = GuidanceConfig(hold_ranges_m=[30.0, 15.0, 8.0], hold_time_s=5.0)
    rng = np.random.default_rng(seed)
    g, ref = GuidanceState(), None
    rows = []
    for k in range(n):
        t = (k + 1) * T
        target = ref.rho_m if ref is not None else np.array([0, -30.0, 0])
        g, ref = guidance_step(cfg, g, t, target, ref.rho_dot_mps if ref is not None else np.zeros(3))
        rho = ref.rho_m + rng.normal(0, 0.05, 3)
        est = None if k % 7 == 3 else (t - T / 2, abs(rng.normal(0, 0.1)), abs(rng.normal(0, 1.0)))
        rows.append((t, rho, ref.rho_m.copy(), 10.0 + abs(rho[1]), rng.normal(0, 2.0, 3), est, k % 50 == 10))
    return rows


def test_the_streaming_score_is_the_batch_metrics():
    """metrics.LoopScore (a buffer of one hold time) against metrics.loop_metrics (the whole
    series), a second implementation, over an approach with three holds."""
    from lidar_sim_ros.loop.metrics import LoopScore, loop_metrics
    rows = _approach(2500)
    stream = LoopScore(T, 500.0, 5.0)
    for t, rho, ref, rng, force, est, lost in rows:
        stream.add(t, rho, ref, rng, force, *(est or (None,)), lost=lost)
    got = stream.result()
    est = [r[5] for r in rows if r[5] is not None]
    batch = loop_metrics([r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows], [r[3] for r in rows],
                         [r[4] for r in rows], T, 500.0, 5.0, [e[0] for e in est], [e[1] for e in est],
                         [e[2] for e in est], sum(r[6] for r in rows))
    assert got['hold_samples'] == batch['hold_samples'] > 100
    for key, value in batch.items():
        assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_a_long_run_keeps_bounded_memory_and_decimated_series():
    import tracemalloc

    from lidar_sim_ros.loop.step import RunRecord
    cfg = _config(hold_time_s=5.0)
    outputs = [_output(t, rho, rho, ref[1], force) for t, rho, ref, _, force, _, _ in _approach(3000, seed=1)]
    full, small = RunRecord(cfg), RunRecord(cfg, max_rows=100)
    for o in outputs:
        full.add(o)
    tracemalloc.start()
    for i, o in enumerate(outputs):
        small.add(o)
        if i == 999:
            before = tracemalloc.get_traced_memory()[0]
    after = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    a, b = full.result(), small.result()
    assert a.metrics == b.metrics                         # every period scored either way
    assert len(b.series['t_s']) < 100 and b.series['every_periods'] == 32
    np.testing.assert_array_equal(b.series['t_s'], a.series['t_s'][::32])
    # 2000 more periods cost no memory that grows with them (was 5.5 kB a period)
    assert after - before < 40_000, after - before
