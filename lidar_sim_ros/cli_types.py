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


def float_in(low: float, high: float, what: str, open_low: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite float in [low, high] ((low, high] with ``open_low``),
    else 'expected WHAT, got VALUE' (NaN and infinities included)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'expected {what}, got {text!r}') from None
        above = value > low if open_low else value >= low
        if not (above and value <= high):
            raise argparse.ArgumentTypeError(f'expected {what}, got {text}')
        return value
    return parse


MAX_STAMP_S = 2**31 - 1.0e6
"""builtin_interfaces/Time.sec is an int32: scenario clocks stay below this (s)."""
finite_seconds = float_in(-MAX_STAMP_S, MAX_STAMP_S, 'seconds within the int32 stamp range')
epoch_seconds = float_in(0.0, MAX_STAMP_S, 'ROS time in seconds, 0 to 2**31 - 1e6')
positive_float = float_in(0.0, 1e12, 'a positive finite number', open_low=True)
