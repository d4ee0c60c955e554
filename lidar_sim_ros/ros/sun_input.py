"""Sun direction input of the node, free of rclpy: validate a direction and turn it into
the simulator's sun.

The direction is a vector toward the sun in the lidar frame, from the ``sun_direction``
parameter or a ``geometry_msgs/Vector3Stamped`` on the sun topic (whose ``frame_id`` must
be the node's). Any finite vector that is not nearly zero is accepted and normalised
(scaled first, so ``[1e300, 1e300, 0]`` is a direction like any other). On the topic, a zero
vector says the sun is hidden (the chaser in the Earth's shadow, as ``loop_dynamics``
publishes it): the frames then have no sun until a direction comes again.
"""
from __future__ import annotations

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
