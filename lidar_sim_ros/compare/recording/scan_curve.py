"""Point times on the scan curve, for clouds without a time field whose shots may sit at
other instants of the configured curve than ours.

A Lissajous laser traces a continuous curve; a sensor may fire it at instants other than
our sampling (a start phase, lasers firing together instead of round-robin). Each
measured direction is put on the curve near its nearest sampled shots (a 1-D search in
time along each candidate laser's curve) and takes the time there. A sensor fires at a
uniform rate, so within one cloud each laser's times sit on a grid t0 + k dt (dt its
shot interval, t0 unknown): the offsets from our samples must agree per laser and cloud
(``times_on_grid``). A pattern whose frequencies differ from the configuration can still
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

CANDIDATES = 8          # nearest sampled shots refined per point (loops of the curve pass close)
GRID_POINTS = 17        # samples per pass of the search along the curve
PASSES = 4              # each pass narrows the window by (GRID_POINTS - 1) / 2
CHUNK = 8_000           # points per vectorised block (memory: CHUNK x 8 x 17 vectors)
TIE_RAD = 1e-6          # candidates this close in distance (rad) are a tie
GRID_TOL = 0.1          # shot intervals: an offset this far from its laser's is off-grid


def nearest_on_curve(directions: np.ndarray, shots: Shots, curve: Curve,
                     interval_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per unit direction (N, 3) and each of its CANDIDATES nearest sampled shots (N, K):
    angular distance (rad) to the nearest point of that shot's laser curve within one shot
    interval ``interval_s`` of it, the time there (s since frame start), the laser, and the
    sampled shot's time."""
    k = min(CANDIDATES, len(shots))
    _, idx = cKDTree(shots.directions()).query(directions, k=k)
    idx = idx.reshape(len(directions), k)
    laser, t0 = shots.laser[idx], shots.t_s[idx]
    dist, t = np.zeros(idx.shape), np.zeros(idx.shape)
    for lo in range(0, len(directions), CHUNK):
        rows = slice(lo, min(lo + CHUNK, len(directions)))
        t[rows], dist[rows] = _search(directions[rows], laser[rows], t0[rows], curve, interval_s)
    return dist, t, laser, t0


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


def times_on_grid(dist: np.ndarray, t_s: np.ndarray, laser: np.ndarray, t_sample_s: np.ndarray,
                  cloud: np.ndarray, tol_rad: float,
                  interval_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per point, from its candidates (N, K) of ``nearest_on_curve``: matched (within
    ``tol_rad`` of the curve and on its laser's shot grid in its cloud), the time (s, snapped
    to that grid) and laser. The grid's offset per (cloud, laser) comes from each point's
    nearest candidate; a point then takes the nearest candidate on its grid (where two
    lasers' curves, or one curve's loops, cross, the nearest is not always the shot)."""
    rows = np.arange(len(dist))
    cloud = np.repeat(np.asarray(cloud, np.int64)[:, None], dist.shape[1], axis=1)
    group = cloud * (int(laser.max(initial=0)) + 1) + laser
    near = np.argmin(dist, axis=1)
    mean = grid_offsets(t_s[rows, near] - t_sample_s[rows, near], group[rows, near],
                        dist[rows, near] < tol_rad, interval_s)
    keys = np.unique(group[rows, near])
    pos = np.clip(np.searchsorted(keys, group), 0, len(keys) - 1)
    known = keys[pos] == group
    phase = (t_s - t_sample_s) / interval_s
    off = (phase - np.where(known, mean[pos], 0.0) + 0.5) % 1.0 - 0.5
    good = known & (dist < tol_rad) & (np.abs(off) < GRID_TOL)
    # Ties (the figure revisits a direction) go to the nearest sampled shot, as before.
    pick = np.argmin(np.where(good, np.floor(dist / TIE_RAD), np.inf), axis=1)
    ok = good[rows, pick]
    return ok, (t_s - off * interval_s)[rows, pick], laser[rows, pick]


def grid_offsets(offset_s: np.ndarray, group: np.ndarray, ok: np.ndarray,
                 interval_s: float) -> np.ndarray:
    """Circular mean of ``offset_s`` (s) modulo ``interval_s`` per group (sorted unique ids),
    as a fraction of the interval, over the ``ok`` points."""
    keys, inv = np.unique(group, return_inverse=True)
    total = np.zeros(len(keys), complex)
    np.add.at(total, inv[ok], np.exp(2j * np.pi * offset_s[ok] / interval_s))
    return np.angle(total) / (2 * np.pi)
