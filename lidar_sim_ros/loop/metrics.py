"""A closed-loop run's figures of merit, from time series (numpy only): the same function
scores the in-process loop (``step.run_loop``) and the DDS loop (``loop.demo``).

The truth enters here only, after the run.
"""
from __future__ import annotations

import numpy as np


def hold_windows(t_s: np.ndarray, ref_y_m: np.ndarray, hold_time_s: float) -> np.ndarray:
    """Samples (mask) in the dwell of each hold: the last ``hold_time_s`` before the reference
    leaves a hold point (guidance leaves only after that long settled), and the last
    ``hold_time_s`` of the run if the reference then stands still (the final hold)."""
    t, y = np.asarray(t_s, float), np.asarray(ref_y_m, float)
    mask = np.zeros(len(t), bool)
    if len(t) < 2:
        return mask
    moving = np.abs(np.diff(y)) > 1e-9
    # Runs of a still reference: a hold only if it stood at least hold_time_s (a missed
    # reference sample in a transfer repeats the last one: not a hold).
    edges = np.flatnonzero(np.diff(np.concatenate([[1], moving.astype(int), [1]])))
    for a, b in zip(edges[::2], edges[1::2]):        # y[a..b] stands still
        if b < len(t) - 1 and t[b] - t[a] >= hold_time_s - 1e-9:
            mask |= (t > t[b] - hold_time_s) & (t <= t[b])
    still_since = t[0]
    changed = np.flatnonzero(moving)
    if len(changed):
        still_since = t[changed[-1] + 1]
    if t[-1] - still_since >= hold_time_s:
        mask |= t > t[-1] - hold_time_s
    return mask


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float('nan')


def loop_metrics(t_s, rho_true_m, ref_m, range_m, force_lvlh_n, period_s: float, mass_kg: float,
                 hold_time_s: float, est_t_s, est_trans_err_m, est_axis_err_deg, losses: int) -> dict:
    """The keys of loop.json for one run.

    Per control period (N): t_s, true relative position rho_true_m (N, 3) and guidance
    reference ref_m (N, 3), LVLH (m); range_m lidar -> target centre; force_lvlh_n (N, 3)
    commanded for the next period. Per estimate (M): est_t_s, translation error (m), long
    axis pointing error (deg). hold_error_m: RMS along-track (V-bar: the line of sight)
    error of the truth from the hold point over the hold dwells (``hold_windows``).
    """
    t = np.asarray(t_s, float)
    rho, ref = np.asarray(rho_true_m, float).reshape(-1, 3), np.asarray(ref_m, float).reshape(-1, 3)
    force = np.asarray(force_lvlh_n, float).reshape(-1, 3)
    dwell = hold_windows(t, ref[:, 1], hold_time_s)
    est_t = np.asarray(est_t_s, float)
    return {
        'hold_error_m': _rms((rho[:, 1] - ref[:, 1])[dwell]),
        'delta_v_mps': float(np.linalg.norm(force, axis=1).sum() * period_s / mass_kg),
        'min_range_m': float(np.min(range_m)) if len(t) else float('nan'),
        'est_trans_rms_m': _rms(est_trans_err_m),
        'est_axis_rms_deg': _rms(est_axis_err_deg),
        'acquired_at_s': float(est_t.min()) if len(est_t) else None,
        'losses': int(losses),
        'hold_samples': int(dwell.sum()),
        'final_error_m': float(np.linalg.norm(rho[-1] - ref[-1])) if len(t) else None,
        'estimates': int(len(est_t)),
        'periods': int(len(t)),
    }
