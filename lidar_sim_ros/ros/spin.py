"""Run one node as a process: set it up, spin until interrupted, shut down cleanly."""
from __future__ import annotations

import re
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

# How long an error raised while spinning waits for a SIGINT's shutdown to show (s).
SHUTDOWN_WAIT_S = 0.5


def run_node(make_node: Callable[[], Node], args: list[str] | None,
             startup_errors: tuple[type[BaseException], ...]) -> int:
    """Exit code 2 with one line on stderr when the ROS arguments are wrong (a parameters
    file that is missing or not parameters YAML, an unknown ``--ros-args`` option), and
    after a fatal log naming the problem when ``setup()`` rejects the config."""
    argv = sys.argv if args is None else list(args)
    prog = Path(argv[0]).stem if argv else 'node'
    problem = ros_args_problem(argv)
    if problem is None:
        try:
            rclpy.init(args=args)
        except Exception as exc:  # noqa: BLE001 - rcl's RCLError / UnknownROSArgsError
            problem = rcl_error_line(exc)
    if problem is not None:
        print(f'{prog}: error: {problem}', file=sys.stderr)
        return 2
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
        # which then fails to build its wait set (RCLError) or to take a message from a
        # subscription torn down under it (RuntimeError): a clean stop all the same.
        if not shutting_down():
            raise
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def shutting_down(wait_s: float = SHUTDOWN_WAIT_S) -> bool:
    """Whether the ROS context is shut down, or goes down within ``wait_s`` (s). rclpy's
    SIGINT handler shuts the contexts down from its own thread, so the executor can fail
    on an entity torn down under it a moment before ``rclpy.ok()`` turns False."""
    deadline = time.monotonic() + wait_s
    try:
        while rclpy.ok():
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
    except KeyboardInterrupt:
        return True
    return True


def ros_args_problem(argv: Sequence[str]) -> str | None:
    """What rcl would reject in ``argv`` that a user can be told plainly (None: nothing):
    a ``--params-file`` that does not exist or is not a file."""
    args = list(argv)
    for i, arg in enumerate(args):
        if arg == '--params-file':
            if i + 1 >= len(args):
                return '--params-file needs a file name'
            path = Path(args[i + 1])
            if not path.is_file():
                what = 'is a directory' if path.is_dir() else 'does not exist'
                return f'parameters file {args[i + 1]!r} {what} (--params-file)'
    return None


def rcl_error_line(exc: BaseException, limit: int = 300) -> str:
    """rcl's initialisation error as one line, without its C source locations."""
    text = re.sub(r',? at /\S+:\d+', '', str(exc))
    text = ' '.join(text.split())
    if type(exc).__name__ == 'UnknownROSArgsError':
        text = f'unknown ROS arguments {text}'
    return text if len(text) <= limit else text[:limit - 3] + '...'
