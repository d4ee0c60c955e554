"""Whether per-laser range offsets are a property of the lasers.

Each laser of a multi-laser sensor scans its own tile of the field (the P-60's 24
Lissajous tiles), so an offset per laser can also fit any pattern that the tiles lay
over the target: solar wings a little off their CAD (a range error that grows along the
wing's span), or the range-rate pattern of a clock offset. A laser's own offset is the
same wherever its tile falls on the target. The test: the offsets fitted on one half of
every laser's points, scored on the other half, held out both ways, against the same
offsets fitted on a random half (the candidate's own score). Halves of each tile in
azimuth and in elevation (about the laser's median direction), and early against late
in the recording (the target turns under the tile). For a laser's own offset the three
transfers lose nothing against the random split; for a pattern on the target they lose
what the pattern varies across the tile (``Diagnosis.tile_veto`` applies the naming
rule's z and margin to that loss).

Pure functions over numpy arrays: which half each point is in.
"""
from __future__ import annotations

import numpy as np

SPLITS = ('azimuth', 'elevation', 'time')


def above_laser_median(laser: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Per point: whether ``value`` lies above the median of its laser's points (the
    two halves of each laser's tile along ``value``)."""
    laser = np.asarray(laser)
    value = np.asarray(value, float)
    out = np.zeros(len(value), bool)
    for one in np.unique(laser):
        sel = laser == one
        out[sel] = value[sel] > np.median(value[sel])
    return out


def tile_halves(laser: np.ndarray, directions: np.ndarray, t_s: np.ndarray
                ) -> dict[str, np.ndarray]:
    """The halves of every laser's points (SPLITS -> bool per point): its tile's halves
    in azimuth and elevation (``directions``: unit vectors in the lidar frame) and its
    early and late points (``t_s``, s)."""
    d = np.asarray(directions, float)
    azimuth = np.arctan2(d[:, 1], d[:, 0])
    elevation = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
    values = {'azimuth': azimuth, 'elevation': elevation, 'time': np.asarray(t_s, float)}
    return {name: above_laser_median(laser, values[name]) for name in SPLITS}


# A half of a laser's points determines its offsets as a random half would when the
# variance of its least known direction is at most twice a random half's: the smaller
# eigenvalue of its information at least half of the mean of the two halves'.
MIN_INFORMATION_SHARE = 0.5


def undetermined(train_information: np.ndarray | None,
                 other_information: np.ndarray | None) -> np.ndarray | None:
    """Per laser (bool): a fit on one half of each laser's points (``train_information``,
    (L, k, k): the information on its k offsets, e.g. ``laser_pointing``'s 2 x 2) does
    not determine its offsets as a random half would (the mean of both halves'
    information, ``other_information`` the other half's), by the smaller eigenvalue
    (MIN_INFORMATION_SHARE). None without information (one offset per laser, known from
    any half)."""
    if train_information is None or other_information is None:
        return None
    a = np.asarray(train_information, float)
    b = np.asarray(other_information, float)
    n = min(len(a), len(b))
    if n == 0 or a.ndim != 3:
        return None
    own = np.linalg.eigvalsh(a[:n])[:, 0]
    random_half = np.linalg.eigvalsh(0.5 * (a[:n] + b[:n]))[:, 0]
    out = np.zeros(len(a), bool)
    out[:n] = own < MIN_INFORMATION_SHARE * random_half
    return out


def offset_information(cells: np.ndarray) -> np.ndarray:
    """(L, L) information on the lasers' additive range offsets (1/m^2) with one
    intercept per material profiled out, from ``cells`` (L, M): the summed weights
    1/sigma^2 of each laser's points on each material. The Schur complement
    ``D_L - B D_M^-1 B^T``: a weighted Laplacian of the lasers, linked through the
    materials they share (a material's intercept takes any common shift of the lasers
    that alone see it)."""
    b = np.asarray(cells, float)
    on_material = b.sum(axis=0)
    seen = on_material > 0
    b_seen = b[:, seen]
    return np.diag(b.sum(axis=1)) - (b_seen / on_material[seen]) @ b_seen.T


def poorly_linked(train_cells: np.ndarray | None,
                  other_cells: np.ndarray | None) -> np.ndarray | None:
    """(L, k) directions in the lasers' offsets (columns, largest element 1) that a fit
    on one half of each laser's points (``train_cells``, (L, M) as
    ``offset_information`` takes them) determines less well than a random half would:
    the generalized eigenvectors of its information against a random half's (the two
    halves' mean cells, ``other_cells`` the other half's) whose ratio is below
    MIN_INFORMATION_SHARE, i.e. whose variance is over twice a random half's. A half
    whose lasers fall into groups that share a material through a few points only
    leaves the groups' relative level so (the materials' intercepts take it). Such a
    level is no evidence against the lasers: the transfer scores it refitted (``Diagnosis.
    transfer_nll``). None without cells (an effect that keeps none)."""
    if train_cells is None or other_cells is None:
        return None
    a = np.asarray(train_cells, float)
    b = np.asarray(other_cells, float)
    n_lasers = max(a.shape[0], b.shape[0])
    n_materials = max(a.shape[1], b.shape[1])
    pad = [np.pad(c, ((0, n_lasers - c.shape[0]), (0, n_materials - c.shape[1]))) for c in (a, b)]
    # Only the lasers with points (a sensor of up to MAX_LASERS ids): L x L stays small.
    seen = np.flatnonzero((pad[0] + pad[1]).sum(axis=1) > 0)
    own = offset_information(pad[0][seen])
    random_half = offset_information(0.5 * (pad[0][seen] + pad[1][seen]))
    # The random half's information on the contrasts it determines (the lasers' mean and
    # a laser with no point on either half are no one's: the materials carry the mean).
    values, vectors = np.linalg.eigh(random_half)
    keep = values > 1e-9 * max(float(values.max(initial=0.0)), 1e-300)
    if not keep.any():
        return np.zeros((n_lasers, 0))
    whiten = vectors[:, keep] / np.sqrt(values[keep])
    ratio, turn = np.linalg.eigh(whiten.T @ own @ whiten)
    free_seen = whiten @ turn[:, ratio < MIN_INFORMATION_SHARE]
    scale = np.abs(free_seen).max(axis=0, initial=0.0)
    free = np.zeros((n_lasers, free_seen.shape[1]))
    free[seen] = free_seen / np.where(scale > 0, scale, 1.0)
    return free


def per_laser(effect) -> bool:
    """Whether ``effect`` carries a parameter per laser (a list among its params, e.g.
    ``laser_bias``'s ``offsets_m``): it can fit any pattern the lasers' tiles lay over
    the target."""
    params = getattr(effect, 'params', None)
    dump = getattr(params, 'model_dump', None)
    return dump is not None and any(isinstance(v, list) for v in dump().values())
