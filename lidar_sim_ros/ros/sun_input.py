"""Sun direction input of the node, free of rclpy: validate a direction and turn it into
the simulator's sun.

The direction is a vector toward the sun in the lidar frame, from the ``sun_direction``
parameter or a ``geometry_msgs/Vector3Stamped`` on the sun topic (whose ``frame_id`` must
be the node's). Any finite vector that is not nearly zero is accepted and normalised
(scaled first, so ``[1e300, 1e300, 0]`` is a direction like any other). On the topic, a zero
vector says the sun is hidden (the chaser in the Earth's shadow, as ``loop_dynamics``
publishes it): the frames then have no sun until a direction comes again. Topic samples
apply by their stamps (``SunTrack``): a frame takes the newest at or before its start.
"""
from __future__ import annotations

import bisect

import numpy as np

from lidar_sim_ros.core.config import SunConfig
from lidar_sim_ros.core.sun import ScenarioSun
from lidar_sim_ros.core.vectors import unit_vector
from lidar_sim_ros.ros.pose_input import Rejection


def check_sun_direction(vector, frame_id: str | None = None, node_frame_id: str | None = None,
                        zero_is_dark: bool = False) -> tuple[np.ndarray | None, Rejection | None]:
    """(unit vector, None), or (None, why not). ``frame_id`` None skips the frame check.
    With ``zero_is_dark`` an exact zero vector gives (None, None): the sun is hidden."""
    if frame_id is not None and frame_id != node_frame_id:
        return None, Rejection('sun_frame_id', f'frame_id {frame_id!r} is not the node '
                                               f'frame_id {node_frame_id!r}')
    v = np.asarray(vector, dtype=float)
    if zero_is_dark and v.shape == (3,) and not v.any():
        return None, None
    try:
        return unit_vector(v), None
    except ValueError as exc:
        kind = ('sun_shape' if v.shape != (3,) else 'sun_finite' if not np.isfinite(v).all()
                else 'sun_zero')
        return None, Rejection(kind, f'direction {exc}')


def sun_with_direction(current: ScenarioSun | None, direction: np.ndarray) -> ScenarioSun:
    """The node's sun pointing along ``direction`` (fixed: no orbit motion at run time);
    irradiance, Earth and the rest stay as the scenario set them (defaults without a sun)."""
    if current is None:
        return ScenarioSun(SunConfig(direction=tuple(float(x) for x in direction)))
    return current.with_direction(direction)


class SunTrack:
    """Sun directions from the topic by stamp (ns): a frame takes the newest at or before
    its start, so which sun lights a frame does not depend on when the message arrived
    (the same run over DDS gives the same clouds). ``None`` = the sun hidden.

    At most ``keep`` samples are held: the oldest go first, and every sample older than
    the one a frame used is dropped when that frame takes it.
    """

    def __init__(self, keep: int = 64):
        self.keep = keep
        self._stamps: list[int] = []
        self._units: list[np.ndarray | None] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp_ns: int, unit: np.ndarray | None) -> None:
        """A checked direction (or None: hidden); a second sample at one stamp replaces it."""
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            self._units[i] = unit
            return
        self._stamps.insert(i, stamp_ns)
        self._units.insert(i, unit)
        if len(self._stamps) > self.keep:
            del self._stamps[0], self._units[0]

    def at(self, start_ns: int) -> tuple[bool, np.ndarray | None]:
        """(found, direction or None) of the newest sample stamped at or before ``start_ns``;
        (False, None) when every sample is newer (the sun stays as it was)."""
        i = bisect.bisect_right(self._stamps, start_ns) - 1
        if i < 0:
            return False, None
        del self._stamps[:i], self._units[:i]
        return True, self._units[0]

    def clear(self) -> None:
        self._stamps.clear()
        self._units.clear()
