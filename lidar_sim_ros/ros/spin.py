"""Run one node as a process: set it up, spin until interrupted, shut down cleanly."""
from __future__ import annotations

from typing import Callable

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def run_node(make_node: Callable[[], Node], args: list[str] | None,
             startup_errors: tuple[type[BaseException], ...]) -> int:
    """Exit code 2 (after a fatal log naming the problem) when ``setup()`` rejects the config."""
    rclpy.init(args=args)
    node = make_node()
    try:
        node.setup()
    except startup_errors as exc:
        node.get_logger().fatal(f'cannot start: {type(exc).__name__}: {exc}')
        node.destroy_node()
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: BLE001 - re-raised unless it is the shutdown race below
        # SIGINT landing between two waits shuts the context down under the executor,
        # which then fails to build its wait set (RCLError): a clean stop all the same.
        if rclpy.ok():
            raise
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
