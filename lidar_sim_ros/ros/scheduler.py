"""Which frames are due, free of rclpy.

Frame k covers ``[k T, (k + 1) T)`` of the node clock (T = 1 / frame rate), so frames
sit on a fixed grid of the clock: under ``use_sim_time`` they follow ``/clock``
exactly, one per period of simulated time, and never drift. Frame times are integer
nanoseconds computed from an exact rational period, so ``start_ns(k)`` is the same
number however long the node runs.

A frame is computed once its scan window has ended and the pose history covers the
window (``readiness``); frames are handled in order, each exactly once.
"""
from __future__ import annotations

import math

import numpy as np
from dataclasses import dataclass
from fractions import Fraction

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class Poll:
    """Result of ``FrameScheduler.poll``.

    due: frame indices whose windows have ended, oldest first (handle in order, call
    ``done`` on each handled one). skipped: frames dropped because the clock jumped
    further than the catch-up cap. reset: the clock went back by more than a period.
    """

    due: range
    skipped: int = 0
    reset: bool = False


class FrameScheduler:
    """The frame grid of one node and the index of the next frame to handle."""

    def __init__(self, rate_hz: float, max_catch_up: int = 10):
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f'frame rate must be positive and finite, got {rate_hz!r} Hz')
        if max_catch_up < 1:
            raise ValueError(f'max_catch_up must be >= 1, got {max_catch_up}')
        self.rate_hz = float(rate_hz)
        self.period_ns = Fraction(NS_PER_S) / Fraction(self.rate_hz).limit_denominator(1_000_000)
        self.max_catch_up = int(max_catch_up)
        self.next_index: int | None = None

    @property
    def period_s(self) -> float:
        return float(self.period_ns) / NS_PER_S

    def start_ns(self, k: int) -> int:
        """Start of frame k (its header stamp), ns on the node clock."""
        return round(k * self.period_ns)

    def end_ns(self, k: int) -> int:
        return self.start_ns(k + 1)

    def index_at(self, now_ns: int) -> int:
        """The frame whose window contains ``now_ns``."""
        return math.floor(Fraction(int(now_ns)) / self.period_ns)

    def poll(self, now_ns: int) -> Poll:
        """Frames due at ``now_ns``: every frame from the next one whose window has ended."""
        current = self.index_at(now_ns)
        if self.next_index is None:
            # Start with the frame in progress: it is due when its window ends.
            self.next_index = current
            return Poll(range(current, current))
        if current < self.next_index - 1:
            # The clock went back further than one period (sim time restarted,
            # wall clock stepped): restart the grid at the present.
            self.next_index = current
            return Poll(range(current, current), reset=True)
        skipped = 0
        if current - self.next_index > self.max_catch_up:
            skipped = current - self.max_catch_up - self.next_index
            self.next_index = current - self.max_catch_up
        return Poll(range(self.next_index, max(current, self.next_index)), skipped)

    def done(self, k: int) -> None:
        """Frame k was handled (published or dropped): the next one is k + 1."""
        self.next_index = k + 1


# ------------------------------------------------------------------ readiness
COMPUTE = 'compute'
WAIT = 'wait'
SKIP = 'skip'


@dataclass(frozen=True)
class Readiness:
    """What to do with a due frame: COMPUTE, WAIT (poses may still come) or SKIP.

    kind names the cause for WAIT/SKIP: 'no_pose', 'before_first_pose', 'pose_lag',
    'pose_gap'.
    """

    action: str
    kind: str = ''
    reason: str = ''


def pose_window_ns(start_ns: int, last_shot_ns: int, effects) -> tuple[int, int]:
    """The pose times (ns) a frame starting at ``start_ns`` reads: its first shot (0) and
    its last (``last_shot_ns`` after the start) through the effects' pose clock
    (``time_offset`` shifts it by dt_s), so that a frame waits for the poses it will
    evaluate, not for those of its own window. Times relative to the frame start, as the
    node computes the frame."""
    t_s = np.array([0.0, last_shot_ns / NS_PER_S])
    for eff in effects:
        t_s = np.asarray(eff.pose_time_s(t_s), float)
    return (start_ns + int(np.floor(t_s.min() * NS_PER_S)),
            start_ns + int(np.ceil(t_s.max() * NS_PER_S)))


def readiness(start_ns: int, last_shot_ns: int, end_ns: int, now_ns: int,
              history_start_ns: int | None, history_end_ns: int | None,
              max_extrapolation_s: float, pose_wait_s: float,
              max_gap_ns: int = 0) -> Readiness:
    """Decide on a frame whose window [start_ns, end_ns) has ended at ``now_ns``.

    The history must reach back to the frame start (it never grows backwards, so a
    frame starting before the first pose is skipped) and forward to the last shot,
    allowing ``max_extrapolation_s`` past the newest pose. A frame the poses do not
    yet reach waits up to ``pose_wait_s`` after its window ended, then is skipped.
    Poses more than ``pose_wait_s`` apart within the frame (``max_gap_ns``, the stream
    was interrupted) are not interpolated across: the frame is skipped.
    """
    if history_start_ns is None or history_end_ns is None:
        return Readiness(SKIP, 'no_pose', 'no pose received yet')
    if history_start_ns > start_ns:
        return Readiness(SKIP, 'before_first_pose',
                         f'frame starts {(history_start_ns - start_ns) / NS_PER_S:.3f} s '
                         'before the oldest pose held')
    reach_ns = history_end_ns + round(max_extrapolation_s * NS_PER_S)
    if last_shot_ns <= reach_ns:
        if max_gap_ns > round(pose_wait_s * NS_PER_S):
            return Readiness(SKIP, 'pose_gap', f'poses {max_gap_ns / NS_PER_S:.3f} s apart within '
                                               f'the frame (limit {pose_wait_s:g} s)')
        return Readiness(COMPUTE)
    lag_s = (last_shot_ns - reach_ns) / NS_PER_S
    reason = (f'poses reach {lag_s:.3f} s short of the frame end (newest pose '
              f'{(end_ns - history_end_ns) / NS_PER_S:.3f} s before it, max_extrapolation_s '
              f'{max_extrapolation_s:g})')
    if now_ns - end_ns > round(pose_wait_s * NS_PER_S):
        return Readiness(SKIP, 'pose_lag', reason)
    return Readiness(WAIT, 'pose_lag', reason)
