"""Argument types shared by the ``lidar-sim`` subcommands: a bad value is one line
naming it (argparse prints it with the option)."""
from __future__ import annotations

import argparse
from typing import Callable


def int_at_least(minimum: int, what: str) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum``, else 'expected WHAT, got VALUE'."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'expected {what}, got {text!r}') from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f'expected {what}, got {value}')
        return value
    return parse


positive_int = int_at_least(1, 'a positive integer')
run_id = int_at_least(0, 'a run id (0, 1, ...)')
