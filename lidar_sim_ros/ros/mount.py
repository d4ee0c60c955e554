"""The sensor mount as a static transform (``tf2_msgs/msg/TFMessage`` on /tf_static).

``mount_message`` builds the message from any message classes that take keyword
arguments: rclpy's (the node, where ROS's tf2_msgs is installed) or a rosbags typestore's
(the tests: no tf2_msgs wheel exists), looked up by their ROS type names.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

QUAT_NORM_TOL = 1e-6


def check_mount(translation_m: Sequence[float], quat_xyzw: Sequence[float]) -> str | None:
    """Why a mount is unusable (3 finite numbers, a unit quaternion), or None."""
    t = np.asarray(translation_m, float)
    q = np.asarray(quat_xyzw, float)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        return f'mount_translation_m must be 3 finite numbers (m), got {list(translation_m)}'
    if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > QUAT_NORM_TOL:
        return f'mount_quat_xyzw must be a unit quaternion (x, y, z, w), got {list(quat_xyzw)}'
    return None


def mount_message(lookup: Callable[[str], Any], parent: str, child: str,
                  translation_m: Sequence[float], quat_xyzw: Sequence[float],
                  stamp_ns: int) -> Any:
    """A TFMessage holding parent -> child (the sensor frame): translation (m) and
    rotation of the sensor in the parent frame. ``lookup('geometry_msgs/msg/Vector3')``
    returns a message class."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    x, y, z = (float(v) for v in translation_m)
    qx, qy, qz, qw = (float(v) for v in quat_xyzw)
    tf = lookup('geometry_msgs/msg/TransformStamped')(
        header=lookup('std_msgs/msg/Header')(
            stamp=lookup('builtin_interfaces/msg/Time')(sec=sec, nanosec=nanosec),
            frame_id=parent),
        child_frame_id=child,
        transform=lookup('geometry_msgs/msg/Transform')(
            translation=lookup('geometry_msgs/msg/Vector3')(x=x, y=y, z=z),
            rotation=lookup('geometry_msgs/msg/Quaternion')(x=qx, y=qy, z=qz, w=qw)))
    return lookup('tf2_msgs/msg/TFMessage')(transforms=[tf])


def rclpy_lookup(name: str) -> Any:
    """The rclpy message class of a ROS type name (ImportError where it is not installed)."""
    import importlib
    package, _, cls = name.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), cls)
