"""Publish each frame a fixed time after its scan window ends, as a sensor's pipeline does.

A real sensor delivers frame k a constant processing latency after its scan ends; a
simulated frame is ready when its computation finishes, which varies from frame to
frame (10-20 ms for the P-60 scenario, more with every effect on). With
``publish_latency_s`` > 0 the node hands each packed message to ``DeadlinePublisher``,
which publishes it at window end + latency on the wall clock: the frames' period
jitter is then the thread's wake-up jitter, not the computation's. A frame ready after
its deadline is published at once and counted as late.
"""
from __future__ import annotations

import queue
import threading
import time
from typing import Callable

from lidar_sim_ros.ros.pose_input import NS_PER_S


class DeadlinePublisher:
    """A thread that calls ``publish()`` callables at their deadlines (wall clock, ns),
    in the order they were submitted (deadlines of successive frames increase)."""

    def __init__(self, clock_ns: Callable[[], int] = time.time_ns, name: str = 'deadline_publisher'):
        self._clock_ns = clock_ns
        self._queue: queue.SimpleQueue[tuple[int, Callable[[], None]] | None] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._late = 0
        self._held_ms: list[float] = []
        self._errors: list[str] = []
        self._thread = threading.Thread(target=self._run, daemon=True, name=name)
        self._thread.start()

    def submit(self, deadline_ns: int, publish: Callable[[], None]) -> None:
        """Call ``publish()`` at ``deadline_ns`` (at once if that has passed)."""
        self._queue.put((deadline_ns, publish))

    def take_stats(self) -> tuple[int, list[float], list[str]]:
        """(frames published late, hold times in ms, publish errors) since the last call."""
        with self._lock:
            out = (self._late, self._held_ms, self._errors)
            self._late, self._held_ms, self._errors = 0, [], []
        return out

    def close(self, timeout_s: float = 1.0) -> None:
        """Stop the thread; messages not yet due are dropped."""
        self._stop.set()
        self._queue.put(None)
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while not self._stop.is_set():
            item = self._queue.get()
            if item is None:
                return
            deadline_ns, publish = item
            wait_ns = deadline_ns - self._clock_ns()
            left_ns = wait_ns
            while left_ns > 0:  # the wait runs on the monotonic clock: never publish early
                if self._stop.wait(left_ns / NS_PER_S):
                    return
                left_ns = deadline_ns - self._clock_ns()
            try:
                publish()
            except Exception as exc:  # noqa: BLE001 - reported by the node, the thread goes on
                with self._lock:
                    self._errors.append(f'{type(exc).__name__}: {exc}')
                continue
            with self._lock:
                if wait_ns <= 0:
                    self._late += 1
                self._held_ms.append(max(wait_ns, 0) / 1e6)
