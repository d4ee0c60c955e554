"""The ``lidar-sim`` command. Each subcommand lives with the package it drives.

A command module exposes ``register(subparsers)``, which adds its parser and sets
``func`` to a function taking the parsed args. User errors (bad config, bad bag,
missing file) print one line naming the problem, without a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

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


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:
        # Ctrl-C while the commands load (before _main knows the command and --debug).
        print('lidar-sim: interrupted', file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        # Ctrl-C (SIGINT): one line and the shell's code for it, 128 + 2; files being
        # written were closed by their context managers on the way out.
        if args.debug:
            raise
        print(f'lidar-sim {args.command}: interrupted (Ctrl-C); output written so far is '
              'incomplete', file=sys.stderr)
        return 130
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
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f'lidar-sim {args.command}: error: {msg}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
