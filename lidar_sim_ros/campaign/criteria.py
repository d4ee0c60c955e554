"""Pass/fail criteria of a campaign (CAMPAIGN.yaml ``criteria``), evaluated per run.

A criterion is the text ``METRIC OP THRESHOLD``, e.g. ``hold_error_m < 0.3``: ``METRIC``
one of the campaign's metrics, ``OP`` one of ``<  <=  >  >=  ==  !=``, ``THRESHOLD`` a
finite decimal number (ASCII). A run passes a criterion when its metric has a finite
value that satisfies it: a missing metric (a run that never reached a hold has no
``hold_error_m``) or a failed run passes none.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

OPERATORS = {'<': np.less, '<=': np.less_equal, '>': np.greater, '>=': np.greater_equal,
             '==': np.equal, '!=': np.not_equal}
MAX_CRITERIA = 100
"""Criteria in one spec."""

_NUMBER = r'[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?'
_TEXT = re.compile(r'\s*(?P<metric>[A-Za-z_][A-Za-z0-9_.]*)\s*(?P<op>[<>=!]+)\s*(?P<value>\S+)\s*')


@dataclass(frozen=True)
class Criterion:
    """``metric op threshold``; ``threshold`` is finite (``number``: as the spec wrote it)."""

    metric: str
    op: str
    threshold: float
    number: str = field(default='', compare=False)

    def __str__(self) -> str:
        return f'{self.metric} {self.op} {self.number or repr(self.threshold)}'

    def passes(self, values) -> np.ndarray:
        """Bool per run: the value (NaN = missing) is finite and satisfies the criterion."""
        x = np.asarray(values, dtype=float)
        with np.errstate(invalid='ignore'):
            return OPERATORS[self.op](x, self.threshold) & np.isfinite(x)


def parse_criterion(text: str, metrics: Sequence[str]) -> Criterion:
    """The criterion ``text`` names; ValueError saying what is wrong with it otherwise."""
    match = _TEXT.fullmatch(text)
    if match is None:
        raise ValueError('not a criterion: write METRIC OP THRESHOLD, e.g. "hold_error_m < 0.3"')
    metric, op, value = match['metric'], match['op'], match['value']
    if metric not in metrics:
        raise ValueError(f'unknown metric {metric!r} (known: {", ".join(metrics)})')
    if op not in OPERATORS:
        raise ValueError(f'unknown operator {op!r} (one of {" ".join(OPERATORS)})')
    if re.fullmatch(_NUMBER, value) is None:
        raise ValueError(f'threshold {value!r} is not a decimal number')
    threshold = float(value)
    if not math.isfinite(threshold):
        raise ValueError(f'threshold {value!r} is not finite')
    return Criterion(metric, op, threshold, value)
