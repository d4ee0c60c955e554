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


class LoopScore:
    """``loop_metrics`` computed as the periods come, in memory bounded by the hold time
    (not the run's length): a day's run (864,000 periods) kept 5.5 kB a period before.

    ``add`` one period at a time (times increasing); ``result()`` gives the keys of
    ``loop_metrics`` for the periods so far. The hold dwells are ``hold_windows``' (the last
    ``hold_time_s`` of each still stretch of the reference that it then leaves, and the
    last ``hold_time_s`` of the run when the reference stands still since at least that
    long), found with a buffer of the current stretch's last ``hold_time_s``.
    """

    def __init__(self, period_s: float, mass_kg: float, hold_time_s: float):
        self.period_s, self.mass_kg, self.hold_time_s = period_s, mass_kg, hold_time_s
        self.periods = self.estimates = self.losses = self.hold_samples = 0
        self.force_sum_n = 0.0
        self.hold_sq_sum = self.trans_sq_sum = self.axis_sq_sum = 0.0
        self.min_range_m = float('inf')
        self.acquired_at_s: float | None = None
        self.last: tuple | None = None           # (t, rho, ref) of the last period
        self.still_since_s: float | None = None  # when the reference stopped moving
        self.stretch: list[tuple[float, float]] = []   # (t, along-track error) of the still stretch

    def add(self, t_s: float, rho_true_m, ref_m, range_m: float, force_lvlh_n,
            est_t_s: float | None = None, est_trans_err_m: float = float('nan'),
            est_axis_err_deg: float = float('nan'), lost: bool = False) -> None:
        rho, ref = np.asarray(rho_true_m, float), np.asarray(ref_m, float)
        if self.last is not None and abs(ref[1] - self.last[2][1]) > 1e-9:
            self._close_stretch()
            self.still_since_s, self.stretch = t_s, []
        if self.still_since_s is None:
            self.still_since_s = t_s
        self.stretch.append((t_s, rho[1] - ref[1]))
        while self.stretch and self.stretch[0][0] <= t_s - self.hold_time_s - 2 * self.period_s:
            self.stretch.pop(0)    # never in a dwell: the stretch's end is t_s or later
        self.periods += 1
        self.force_sum_n += float(np.linalg.norm(force_lvlh_n))
        self.min_range_m = min(self.min_range_m, float(range_m))
        if est_t_s is not None:
            self.estimates += 1
            self.trans_sq_sum += est_trans_err_m ** 2
            self.axis_sq_sum += est_axis_err_deg ** 2
            self.acquired_at_s = est_t_s if self.acquired_at_s is None else min(self.acquired_at_s, est_t_s)
        self.losses += bool(lost)
        self.last = (t_s, rho, ref)

    def _dwell(self, end_s: float) -> list[float]:
        return [e for t, e in self.stretch if end_s - self.hold_time_s < t <= end_s]

    def _close_stretch(self) -> None:
        """The reference leaves a still stretch: its last hold_time_s is a dwell if it stood that long."""
        end_s = self.last[0]
        if end_s - self.still_since_s >= self.hold_time_s - 1e-9:
            errors = self._dwell(end_s)
            self.hold_samples += len(errors)
            self.hold_sq_sum += float(np.sum(np.square(errors)))

    def result(self) -> dict:
        samples, sq = self.hold_samples, self.hold_sq_sum
        if self.last is not None and self.last[0] - self.still_since_s >= self.hold_time_s:
            final = self._dwell(self.last[0])
            samples, sq = samples + len(final), sq + float(np.sum(np.square(final)))
        nan = float('nan')
        return {
            'hold_error_m': float(np.sqrt(sq / samples)) if samples else nan,
            'delta_v_mps': float(self.force_sum_n * self.period_s / self.mass_kg),
            'min_range_m': self.min_range_m if self.periods else nan,
            'est_trans_rms_m': float(np.sqrt(self.trans_sq_sum / self.estimates)) if self.estimates else nan,
            'est_axis_rms_deg': float(np.sqrt(self.axis_sq_sum / self.estimates)) if self.estimates else nan,
            'acquired_at_s': self.acquired_at_s,
            'losses': int(self.losses),
            'hold_samples': int(samples),
            'final_error_m': float(np.linalg.norm(self.last[1] - self.last[2])) if self.last is not None else None,
            'estimates': int(self.estimates),
            'periods': int(self.periods),
        }
