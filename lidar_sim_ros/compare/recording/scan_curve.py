"""Point times on the scan curve, for clouds without a time field whose shots may sit at
other instants of the configured curve than ours.

A Lissajous laser traces a continuous curve; a sensor may fire it at instants other than
our sampling (a start phase, lasers firing together instead of round-robin). Each
measured direction is put on the curve near its nearest sampled shots (a 1-D search in
time along each candidate laser's curve) and takes the time there. A sensor fires at a
uniform rate, so within one cloud each laser's times sit on a grid t0 + k dt (dt its
shot interval, t0 unknown): the offsets from our samples must agree per laser and cloud
(``on_shot_grid``). A pattern whose frequencies differ from the configuration can still
lie on the same closed figure (a Lissajous of 110:100 Hz scaled by 1.005 traces it
again), but its offsets drift through the frame and fail that check.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from lidar_sim_ros.core.shots import Shots, directions_from_angles

Curve = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""(laser, t since frame start in s) -> (az, el) in rad."""

CANDIDATES = 3          # nearest sampled shots refined per point
GRID_POINTS = 17        # samples per pass of the search along the curve
PASSES = 4              # each pass narrows the window by (GRID_POINTS - 1) / 2
CHUNK = 20_000          # points per vectorised block (memory: CHUNK x 3 x 17 vectors)
GRID_TOL = 0.1          # shot intervals: an offset this far from its laser's is off-grid


def nearest_on_curve(directions: np.ndarray, shots: Shots, curve: Curve,
                     interval_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per unit direction (N, 3): angular distance (rad) to the nearest point of the curve
    within one shot interval ``interval_s`` of its CANDIDATES nearest sampled shots, the
    time there (s since frame start), the laser, and the time of the sampled shot it
    started from."""
    k = min(CANDIDATES, len(shots))
    _, idx = cKDTree(shots.directions()).query(directions, k=k)
    idx = idx.reshape(len(directions), k)
    n = len(directions)
    best_d, best_t = np.full(n, np.inf), np.zeros(n)
    best_l, best_t0 = np.zeros(n, np.uint16), np.zeros(n)
    for lo in range(0, n, CHUNK):
        rows = slice(lo, min(lo + CHUNK, n))
        cand = idx[rows]
        laser, t0 = shots.laser[cand], shots.t_s[cand]
        t, d = _search(directions[rows], laser, t0, curve, interval_s)
        j = np.argmin(d, axis=1)
        pick = np.arange(len(j))
        best_d[rows], best_t[rows] = d[pick, j], t[pick, j]
        best_l[rows], best_t0[rows] = laser[pick, j], t0[pick, j]
    return best_d, best_t, best_l, best_t0


def _search(directions: np.ndarray, laser: np.ndarray, t0: np.ndarray, curve: Curve,
            interval_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and angular distance (rad) of the curve point nearest each direction (M, 3)
    for each candidate (M, K) in [t0 - interval, t0 + interval]: a grid search narrowed
    PASSES times."""
    centre, half = t0.astype(float), float(interval_s)
    steps = np.linspace(-1.0, 1.0, GRID_POINTS)
    for _ in range(PASSES):
        t = centre[..., None] + half * steps                       # (M, K, G)
        az, el = curve(np.broadcast_to(laser[..., None], t.shape), t)
        cos = np.einsum('mkgi,mi->mkg', directions_from_angles(az, el), directions)
        g = np.argmax(cos, axis=-1)
        centre = np.take_along_axis(t, g[..., None], axis=-1)[..., 0]
        half *= 2.0 / (GRID_POINTS - 1)
    az, el = curve(laser, centre)
    cos = np.einsum('mki,mi->mk', directions_from_angles(az, el), directions)
    return centre, np.arccos(np.clip(cos, -1.0, 1.0))


def on_shot_grid(t_s: np.ndarray, t_sample_s: np.ndarray, group: np.ndarray,
                 ok: np.ndarray, interval_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Per point: on its group's shot grid (offset from our sampled shot within GRID_TOL
    intervals of the group's circular mean offset) and its time snapped to that grid (s).
    ``group``: one id per (cloud, laser); ``ok``: points that take part."""
    phase = (t_s - t_sample_s) / interval_s
    z = np.exp(2j * np.pi * phase)
    keys, inv = np.unique(group, return_inverse=True)
    total = np.zeros(len(keys), complex)
    np.add.at(total, inv[ok], z[ok])
    mean = np.angle(total)[inv] / (2 * np.pi)
    off = (phase - mean + 0.5) % 1.0 - 0.5
    return ok & (np.abs(off) < GRID_TOL), t_s - off * interval_s
