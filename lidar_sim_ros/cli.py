"""The ``lidar-sim`` command. Each subcommand lives with the package it drives.

A command module exposes ``register(subparsers)``, which adds its parser and sets
``func`` to a function taking the parsed args. User errors (bad config, bad bag,
missing file) print one line naming the problem, without a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading

COMMAND_MODULES = (
    'lidar_sim_ros.offline',             # simulate
    'lidar_sim_ros.compare.command',     # compare
    'lidar_sim_ros.calibrate.command',   # calibrate brdf | range-errors | scan
    'lidar_sim_ros.campaign.command',    # campaign (engine: the [campaign] extra)
)

USER_ERRORS = (ValueError, KeyError, FileNotFoundError, FileExistsError, NotADirectoryError)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='lidar-sim',
        description='LiDAR simulator for rendezvous with space debris: simulate frames to a '
                    'rosbag2, compare the model with measurements, calibrate it from lab data.')
    parser.add_argument('--debug', action='store_true', help='show tracebacks for errors')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and name.startswith(exc.name):
                continue  # command not built yet
            raise
        module.register(sub)
    return parser


class _Sigint:
    """SIGINT raises KeyboardInterrupt as Python's own handler does, and is remembered:
    a library that swallows it (scipy's import-time docstring parsing catches every
    exception) cannot make a Ctrl-C during start-up go unnoticed."""

    seen = False

    @classmethod
    def handler(cls, signum, frame):
        cls.seen = True
        raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    own = (threading.current_thread() is threading.main_thread()
           and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    _Sigint.seen = False
    if own:
        signal.signal(signal.SIGINT, _Sigint.handler)
    try:
        return _main(argv)
    except KeyboardInterrupt:
        # Ctrl-C while the commands load (before _main knows the command and --debug).
        print('lidar-sim: interrupted', file=sys.stderr)
        return 130
    finally:
        if own:
            signal.signal(signal.SIGINT, signal.default_int_handler)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    if _Sigint.seen:           # interrupted while importing, and swallowed there
        raise KeyboardInterrupt
    args = parser.parse_args(argv)
    try:
        code = int(args.func(args) or 0)
        return _interrupted(args.command) if _Sigint.seen else code
    except KeyboardInterrupt:
        # Ctrl-C (SIGINT): one line and the shell's code for it, 128 + 2; files being
        # written were closed by their context managers on the way out.
        if args.debug:
            raise
        return _interrupted(args.command)
    except BrokenPipeError:
        # Output piped into e.g. `head`: stop quietly like other Unix tools.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except MemoryError:
        if args.debug:
            raise
        # The inputs' sizes are limited where they enter; this is the last line of defence.
        print(f'lidar-sim {args.command}: error: out of memory: the input is too large for '
              'this machine (limits: docs/offline.md "Bad configs")', file=sys.stderr)
        return 2
    except USER_ERRORS as exc:
        if args.debug:
            raise
        if _caused_by_interrupt(exc):
            return _interrupted(args.command)
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f'lidar-sim {args.command}: error: {msg}', file=sys.stderr)
        return 2
    except Exception as exc:
        # Ctrl-C inside a library that wraps it (numba loading its cache: SystemError
        # "returned a result with an exception set", caused by the KeyboardInterrupt).
        if args.debug or not _caused_by_interrupt(exc):
            raise
        return _interrupted(args.command)


def _interrupted(command: str) -> int:
    print(f'lidar-sim {command}: interrupted (Ctrl-C); output written so far is incomplete',
          file=sys.stderr)
    return 130


def _caused_by_interrupt(exc: BaseException) -> bool:
    """Whether a KeyboardInterrupt is in ``exc``'s chain of causes and contexts."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


if __name__ == '__main__':
    sys.exit(main())
