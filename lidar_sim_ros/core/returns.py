"""The receiver's choice among a shot's returns: first, last, strongest or all of them.

A shot can make several detected returns: its own echo, a multipath ghost behind a
specular surface (``effects/multipath.py``), a false (background) trigger. The receiver
reports up to ``max_returns`` of them per shot (``config.ReturnsConfig``); each point
carries its return number (1 = the nearest reported return of its shot), which a
vendor layout maps to its own flags (Cepton: SECOND_RETURN for return number 2).
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.core.config import ReturnsConfig


def select_returns(shot: np.ndarray, range_m: np.ndarray, power_w: np.ndarray,
                   cfg: ReturnsConfig) -> tuple[np.ndarray, np.ndarray]:
    """The candidates the receiver reports, and their return numbers.

    shot: shot key of each candidate (int; the output is in increasing key order, so a
    firing position gives firing order); range_m: measured range (m); power_w: received
    power (W), all detected candidates. Returns (index into the candidates, in (shot,
    range) order; return number per kept candidate, uint8, 1 = nearest kept).

    Merging: a candidate closer than ``min_separation_m`` to the candidate before it in
    range, in the same shot, is one pulse with it and dropped (the nearer is kept).
    """
    shot = np.asarray(shot, np.int64)
    range_m = np.asarray(range_m, float)
    power_w = np.asarray(power_w, float)
    order = np.lexsort((range_m, shot))
    s, r = shot[order], range_m[order]
    same = np.zeros(len(order), bool)
    same[1:] = s[1:] == s[:-1]
    merged = same.copy()
    merged[1:] &= (r[1:] - r[:-1]) < cfg.min_separation_m
    order = order[~merged]
    if cfg.mode != 'all':
        s = shot[order]
        if cfg.mode == 'strongest':
            pick = order[np.lexsort((-power_w[order], s))]
        elif cfg.mode == 'last':
            pick = order[::-1][np.lexsort((np.arange(len(order)), s[::-1]))]
        else:
            pick = order
        pick = pick[_rank_in_group(shot[pick]) < cfg.max_returns]
        order = pick[np.lexsort((range_m[pick], shot[pick]))]
    number = _rank_in_group(shot[order]) + 1
    return order, np.minimum(number, 255).astype(np.uint8)


def _rank_in_group(key: np.ndarray) -> np.ndarray:
    """0, 1, 2, ... within each run of equal consecutive keys."""
    n = len(key)
    if n == 0:
        return np.zeros(0, np.int64)
    start = np.ones(n, bool)
    start[1:] = key[1:] != key[:-1]
    first = np.flatnonzero(start)
    run = np.cumsum(start) - 1
    return np.arange(n) - first[run]
