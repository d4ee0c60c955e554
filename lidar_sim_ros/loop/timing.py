"""When the dynamics advances, and which force commands it flies, free of rclpy (the
dynamics node asks; the tests call it alone).

A command answers one control period: the one whose frame it was computed from. After
publishing period k (truth over [t_k, t_k+1], then /clock t_k+1) the period *pending* is
k, and the gate accepts only a command stamped in [t_k, t_k+1) (``offer``): the first
such command is the period's; every other command is refused, counted by cause and
never flown:

- ``non_finite``: a NaN or infinite force component;
- ``frame``: a frame_id other than ``lvlh`` or ``chaser``;
- ``stale``: stamped before t_k (an older period's answer, or a replay);
- ``future``: stamped at or after t_k+1 (no frame of that time exists yet);
- ``duplicate``: a second command for the pending period (the first one stands);
- ``sent_early``: sent (its DDS source time, wall clock) before the /clock that closed
  its period went out: it cannot have been computed from that period's frame.

A command accepted is clipped per LVLH axis to the thrust limit (``thrust_limit``) or
zeroed under the dead band (``dead_band``), each counted (``admit_force``).

- ``lockstep``: the dynamics goes on when the pending period's command is accepted, or
  after a timeout of wall time with no force (a counted, logged timeout). Until the first
  command of the run is accepted the timeout is ``startup_timeout_s`` (the first
  acquisition takes 0.5-3 s of compute), then ``timeout_s``.
- ``realtime``: one period per ``period_s`` of wall time, whatever has arrived; a period
  whose command had not been accepted when the next one is due is counted late and flies
  the newest command if it is at most two periods old, else none. A command that answers
  an earlier period arrives late is not the pending period's, but it is the newest one
  (``late_arrivals``). The wall-clock pacing starts with the run's first command: until
  the GNC's first answer (the first acquisition, 0.5-3 s of compute) the periods wait as
  in lock-step (``startup_timeout_s``), so that the start-up is not counted late.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STAMP_TOLERANCE_S = 1e-6
FRAMES = ('lvlh', 'chaser')
REFUSAL_CAUSES = ('non_finite', 'frame', 'stale', 'future', 'duplicate', 'sent_early')
CLIP_CAUSES = ('thrust_limit', 'dead_band')


def admit_force(frame_id: str, force_n, R_HB: np.ndarray, thrust_limit_n: float,
                dead_band_n: float) -> tuple[np.ndarray | None, str | None, str | None]:
    """A command's force as flown: (force (N, LVLH) or None, refusal cause, clip cause).

    ``force_n`` in ``frame_id`` (``lvlh``, or ``chaser``: the body frame, turned with the
    chaser's attitude R_HB); clipped per LVLH axis to +-``thrust_limit_n``, zeroed when its
    norm after clipping is under ``dead_band_n``."""
    f = np.asarray(force_n, float).reshape(3)
    if not np.isfinite(f).all():
        return None, 'non_finite', None
    if frame_id not in FRAMES:
        return None, 'frame', None
    if frame_id == 'chaser':
        f = R_HB @ f
    clip = None
    if np.abs(f).max() > thrust_limit_n:
        f, clip = np.clip(f, -thrust_limit_n, thrust_limit_n), 'thrust_limit'
    if f.any() and np.linalg.norm(f) < dead_band_n:
        f, clip = np.zeros(3), clip or 'dead_band'
    return f, None, clip


@dataclass
class CommandGate:
    """Commands in (``offer``), the decision to advance out (``due``, ``take``).

    Times: stamps ``t_s`` in simulated seconds since the loop start; ``wall_s`` a monotonic
    clock; ``sent_s``/``closed_sent_s`` the wall clock (s since the Unix epoch) of DDS
    source times.
    """

    mode: str
    period_s: float
    timeout_s: float
    startup_timeout_s: float = 30.0
    max_clock_skew_s: float = 0.0
    pending_start_s: float | None = None   # t_k of the period whose command is awaited
    closed_sent_s: float | None = None     # wall clock (epoch s) its /clock went out
    published_wall_s: float | None = None
    next_wall_s: float | None = None       # real time: when the next period is due (a fixed grid)
    accepted: tuple[float, np.ndarray] | None = None   # the pending period's command
    newest: tuple[float, np.ndarray] | None = None     # the newest accepted command
    commands: int = 0
    timeouts: int = 0
    startup_timeouts: int = 0
    late: int = 0
    late_arrivals: int = 0
    refused: dict = field(default_factory=lambda: dict.fromkeys(REFUSAL_CAUSES, 0))
    clipped: dict = field(default_factory=lambda: dict.fromkeys(CLIP_CAUSES, 0))
    realtime_waits_for_first_command: bool = True
    _paced: bool = False

    @property
    def window_s(self) -> tuple[float, float] | None:
        """[t_k, t_k+1) of the pending period (None before the first period is out)."""
        if self.pending_start_s is None:
            return None
        return self.pending_start_s, self.pending_start_s + self.period_s

    def offer(self, stamp_s: float, force_lvlh_n: np.ndarray, sent_s: float | None = None,
              clip: str | None = None) -> str | None:
        """A command (force already through ``admit_force``) stamped ``stamp_s``: None when it
        is the pending period's command, else the cause it is refused for (counted).
        ``clip``: the clip cause ``admit_force`` gave, counted when the command is accepted."""
        cause = self._refusal(float(stamp_s), sent_s)
        if cause == 'stale' and self.mode == 'realtime' and self._newer(float(stamp_s)):
            # Real time: an earlier period's answer, late but the freshest command there is.
            self.newest = (float(stamp_s), np.asarray(force_lvlh_n, float).copy())
            self.late_arrivals += 1
            return None
        if cause is not None:
            return self.refuse(cause)
        self.accepted = self.newest = (float(stamp_s), np.asarray(force_lvlh_n, float).copy())
        self.commands += 1
        if clip is not None:
            self.clipped[clip] += 1
        return None

    def _newer(self, stamp_s: float) -> bool:
        return (self.newest is None or stamp_s > self.newest[0] + STAMP_TOLERANCE_S) and \
            stamp_s >= self.pending_start_s - 2 * self.period_s - STAMP_TOLERANCE_S

    def refuse(self, cause: str) -> str:
        self.refused[cause] += 1
        return cause

    def _refusal(self, stamp_s: float, sent_s: float | None) -> str | None:
        window = self.window_s
        if window is None or not np.isfinite(stamp_s) or stamp_s >= window[1] - STAMP_TOLERANCE_S:
            return 'future'
        if stamp_s < window[0] - STAMP_TOLERANCE_S:
            return 'stale'
        if self.accepted is not None:
            return 'duplicate'
        if (sent_s is not None and self.closed_sent_s is not None
                and sent_s < self.closed_sent_s - self.max_clock_skew_s):
            return 'sent_early'
        return None

    def published(self, period_start_s: float, wall_s: float, sent_s: float | None = None) -> None:
        """Period [period_start_s, +period_s] and its /clock are out at ``wall_s`` (monotonic;
        ``sent_s``: the wall clock, epoch s, just before the /clock was published)."""
        self.pending_start_s, self.published_wall_s = float(period_start_s), wall_s
        self.closed_sent_s, self.accepted = sent_s, None
        # Real time keeps an absolute grid from the first period after the first command: a
        # late tick does not push the later ones back.
        started = self.next_wall_s is not None and self._paced
        self.next_wall_s = self.next_wall_s + self.period_s if started else wall_s + self.period_s
        self._paced = self.commands > 0 or not self.realtime_waits_for_first_command

    @property
    def starting(self) -> bool:
        """Real time before the first command, when it waits for it."""
        return self.mode == 'realtime' and self.realtime_waits_for_first_command and not self.commands

    @property
    def current_timeout_s(self) -> float:
        """The lock-step wait: the start-up one until the run's first command is accepted."""
        return self.timeout_s if self.commands else self.startup_timeout_s

    def due(self, wall_s: float) -> bool:
        """Whether to advance now."""
        if self.published_wall_s is None:
            return True
        if self.mode == 'lockstep' or self.starting:   # real time: paced from the first command on
            return self.accepted is not None or wall_s - self.published_wall_s >= self.current_timeout_s
        return wall_s >= self.next_wall_s - 1e-4

    def take(self) -> tuple[np.ndarray, str | None]:
        """The force (N, LVLH) for the next period and what went wrong: None (the command
        was there), 'startup_timeout' or 'timeout' (lock-step), 'late' (real time)."""
        if self.published_wall_s is None:
            return np.zeros(3), None
        if self.accepted is not None:
            return self.accepted[1], None
        if self.mode == 'lockstep' and not self.commands or self.starting:
            self.startup_timeouts += 1
            return np.zeros(3), 'startup_timeout'
        if self.mode == 'lockstep':
            self.timeouts += 1
            return np.zeros(3), 'timeout'
        self.late += 1
        fresh = self.newest is not None and \
            self.newest[0] >= self.pending_start_s - 2 * self.period_s - STAMP_TOLERANCE_S
        return (self.newest[1] if fresh else np.zeros(3)), 'late'

    def statistics(self) -> dict:
        """The counts, as loop.json and the statistics log line give them."""
        return {'commands': self.commands, 'timeouts': self.timeouts,
                'startup_timeouts': self.startup_timeouts, 'late_periods': self.late,
                'late_arrivals': self.late_arrivals,
                'refused_commands': dict(self.refused), 'clipped_commands': dict(self.clipped)}
