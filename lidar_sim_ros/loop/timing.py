"""When the dynamics advances: the two timing modes, free of rclpy (the dynamics node asks).

- ``lockstep``: after publishing period k (truth over [t_k, t_k+1], then /clock t_k+1)
  the dynamics waits for the force command computed from that period's frame (stamped
  at or after t_k). It goes on when the command is there, or after ``timeout_s`` of
  wall time with no force (a logged timeout). As fast as the slowest node allows.
- ``realtime``: one period per ``period_s`` of wall time, whatever has arrived; the
  command in force is the newest one received, and a period whose command had not
  arrived when it started is counted late (it flies on the newest earlier command, or
  none if that is more than two periods old).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STAMP_TOLERANCE_S = 1e-6


@dataclass
class CommandGate:
    """Commands in (``on_command``), the decision to advance out (``due``, ``take``).

    Times: ``t_s`` simulated seconds since the loop start, ``wall_s`` a monotonic clock.
    """

    mode: str
    period_s: float
    timeout_s: float
    period_start_s: float = 0.0          # t_k of the period last published
    published_wall_s: float | None = None
    next_wall_s: float | None = None     # real time: when the next period is due (a fixed grid)
    newest_stamp_s: float | None = None
    newest_force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    commands: int = 0
    timeouts: int = 0
    late: int = 0

    def on_command(self, stamp_s: float, force: np.ndarray) -> None:
        """A force command stamped ``stamp_s`` (the estimate's time it was computed from)."""
        self.commands += 1
        if self.newest_stamp_s is None or stamp_s >= self.newest_stamp_s:
            self.newest_stamp_s, self.newest_force = float(stamp_s), np.asarray(force, float)

    def published(self, period_start_s: float, wall_s: float) -> None:
        """Period [period_start_s, +period_s] and its /clock are out at ``wall_s``."""
        self.period_start_s, self.published_wall_s = period_start_s, wall_s
        # Real time keeps an absolute grid: a late tick does not push the later ones back.
        self.next_wall_s = wall_s + self.period_s if self.next_wall_s is None else self.next_wall_s + self.period_s

    def _arrived(self) -> bool:
        return self.newest_stamp_s is not None and \
            self.newest_stamp_s >= self.period_start_s - STAMP_TOLERANCE_S

    def due(self, wall_s: float) -> bool:
        """Whether to advance now."""
        if self.published_wall_s is None:
            return True
        waited = wall_s - self.published_wall_s
        if self.mode == 'lockstep':
            return self._arrived() or waited >= self.timeout_s
        return wall_s >= self.next_wall_s - 1e-4

    def take(self) -> tuple[np.ndarray, str | None]:
        """The force (N) for the next period and what went wrong (None: the command was there)."""
        if self.published_wall_s is None:
            return np.zeros(3), None
        if self._arrived():
            return self.newest_force, None
        if self.mode == 'lockstep':
            self.timeouts += 1
            return np.zeros(3), 'timeout'
        self.late += 1
        fresh = self.newest_stamp_s is not None and \
            self.newest_stamp_s >= self.period_start_s - 2 * self.period_s - STAMP_TOLERANCE_S
        return (self.newest_force if fresh else np.zeros(3)), 'late'
