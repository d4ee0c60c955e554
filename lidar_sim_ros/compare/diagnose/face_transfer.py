"""Does a rigid pose correction hold across the surfaces' orientations?

A reference pose that is off is one rigid motion of the target: every surface agrees on
it, whichever way it faces. A range error that depends on which way a surface faces (a
sunlit face warmer and read long, outside the catalogue) shifts the target's apparent
centroid and attitude a little, so one rigid correction takes part of it, and passes the
pose test on random halves of the points; but fitted on the surfaces facing some ways it
does not hold on the surfaces facing the others.

The test: the matched points grouped by their surface normal in the sensor frame (a few
clusters of unit normals, ``orientation_groups``; and the two halves facing along and
against the fitted translation, ``halves_along``), the correction fitted on every group
but one and scored held out on that one (``across_orientations``), for each group.
A pose error gains on every held-out group (or nothing, where the other groups do not
see the motion); a face-dependent bias loses on some. A group loses by the rule of every
candidate mirrored: its held-out loss at least the practical margin (nats per point of
the group) at a z of the family's bound (``by_group``). A per-cloud correction is scored
otherwise (``pose_error.per_cloud_faces``): its own held-out gain on random halves summed
within each group (fitted per cloud on some groups, a true jitter's motion the held-out
group does not see is left to its noise). Gains in nats per point.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from lidar_sim_ros.compare.diagnose.features import block_mean_z

GROUPS = 4              # clusters of surface normals
GROUP_ITERATIONS = 25   # k-means passes on the unit normals
MIN_GROUP_SHARE = 0.05  # a group holding fewer of the usable points is not scored alone


def orientation_groups(normal: np.ndarray, use: np.ndarray, k: int = GROUPS) -> np.ndarray:
    """(N,) each usable point's group by its unit surface normal (sensor frame): k-means
    on the normals, started from the normal nearest their mean and then, one by one,
    the normal farthest from the centres so far (deterministic); -1 where not ``use``."""
    n = np.asarray(normal, float)
    ok = np.asarray(use, bool) & np.all(np.isfinite(n), axis=1)
    out = np.full(len(n), -1)
    at = np.flatnonzero(ok)
    if len(at) < k:
        return out
    x = n[at] / np.maximum(np.linalg.norm(n[at], axis=1), 1e-12)[:, None]
    centres = [x[np.argmax(x @ x.mean(axis=0))]]
    for _ in range(k - 1):
        near = np.max(x @ np.array(centres).T, axis=1)
        centres.append(x[np.argmin(near)])
    c = np.array(centres)
    label = np.zeros(len(x), int)
    for _ in range(GROUP_ITERATIONS):
        label = np.argmax(x @ c.T, axis=1)
        new = np.array([x[label == j].sum(axis=0) if np.any(label == j) else c[j]
                        for j in range(k)])
        new /= np.maximum(np.linalg.norm(new, axis=1), 1e-12)[:, None]
        if np.allclose(new, c):
            break
        c = new
    out[at] = label
    return out


def halves_along(normal: np.ndarray, use: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(N,) 1 where the unit surface normal has a positive component along
    ``direction`` ((N, 3) or (3,), sensor frame: the fitted translation of the point's
    cloud), else 0; -1 where not ``use``. A range bias on the surfaces facing one way
    moves the target toward them: fitted on that half, the motion lengthens the ranges of
    the other half, which the bias leaves alone."""
    n = np.asarray(normal, float)
    along = np.einsum('ij,ij->i', np.nan_to_num(n),
                      np.broadcast_to(np.asarray(direction, float), n.shape))
    out = np.where(along > 0, 1, 0)
    return np.where(np.asarray(use, bool) & np.all(np.isfinite(n), axis=1), out, -1)


@dataclass(frozen=True)
class AcrossOrientations:
    """The rigid correction fitted on the other orientation groups, held out on each."""

    normals: np.ndarray        # (G, 3) each group's mean unit normal, sensor frame
    share: np.ndarray          # (G,) share of the usable points in each group
    gain: np.ndarray           # (G,) held-out gain on the group, nats per matched point (all)
    mean: np.ndarray           # (G,) the same per point of the group
    z: np.ndarray              # (G,) its z over neighbourhood blocks
    total_gain: float          # summed over the groups, nats per matched point
    total_z: float
    losing: tuple[int, ...]    # groups whose loss passes the rule mirrored

    @property
    def transfers(self) -> bool:
        """Whether the correction holds on every group (no group loses by the rule)."""
        return not self.losing

    def as_dict(self) -> dict:
        return {'transfers': self.transfers,
                'total_gain_per_matched_point': round(self.total_gain, 6),
                'total_z': round(self.total_z, 2),
                'losing_groups': list(self.losing),
                'groups': [{'normal': [round(float(v), 3) for v in nrm],
                            'share': round(float(sh), 3),
                            'gain_per_matched_point': round(float(g), 6),
                            'gain_per_group_point': round(float(m), 6),
                            'z': round(float(zz), 2)}
                           for nrm, sh, g, m, zz in zip(self.normals, self.share, self.gain,
                                                        self.mean, self.z)]}


def across_orientations(fit: Callable[[np.ndarray], np.ndarray], residual_m: np.ndarray,
                        sigma_m: np.ndarray, groups: np.ndarray, normal: np.ndarray,
                        blocks: np.ndarray, z_crit: float, min_gain: float,
                        n_points: int | None = None) -> AcrossOrientations:
    """For each orientation group (``groups``, -1 not used) holding at least
    MIN_GROUP_SHARE of the used points: the correction ``fit(train)`` (N,) range m at
    every point, fitted on the other groups' points, scored on this group's
    (Gaussian gain, ``residual_m`` and ``sigma_m`` in m), its sum over the group per
    matched point (``n_points``; default N) and its z over ``blocks``. A group loses
    where its gain per point of the group is at most -``min_gain`` at z at most
    -``z_crit`` (``by_group``: the rule of a candidate, scored on the group's points,
    mirrored)."""
    r = np.asarray(residual_m, float)
    s = np.asarray(sigma_m, float)
    g = np.asarray(groups, int)
    per_point = np.zeros(len(r))
    for j in scored_groups(g):
        test = g == j
        corr = fit((g >= 0) & ~test)
        per_point[test] = (r[test] ** 2 - (r[test] - corr[test]) ** 2) / (2 * s[test] ** 2)
    return by_group(per_point, g, normal, blocks, z_crit, min_gain, n_points)


def scored_groups(groups: np.ndarray) -> list:
    """The groups (labels >= 0) holding at least MIN_GROUP_SHARE of the used points."""
    g = np.asarray(groups, int)
    used = g >= 0
    return [j for j in np.unique(g[used]) if np.mean(g[used] == j) >= MIN_GROUP_SHARE]


def by_group(gain: np.ndarray, groups: np.ndarray, normal: np.ndarray, blocks: np.ndarray,
             z_crit: float, min_gain: float, n_points: int | None = None
             ) -> AcrossOrientations:
    """A held-out gain per point (``gain``, nats; 0 where not scored) summed over each
    orientation group (``groups``, -1 not used; groups under MIN_GROUP_SHARE of the used
    points left out) per matched point (``n_points``; default N), its mean per point of
    the group and its z over ``blocks``. A group loses where its mean is at most
    -``min_gain`` at z at most -``z_crit``. Asked of a per-cloud correction with the gain
    of its random held-out halves (``per_cloud_faces``): fitted on every group at once, a
    true pose error per cloud gains on each (or nothing where a group does not see the
    motion); a face-dependent range bias is taken where it lies and paid for on the
    surfaces it leaves alone."""
    d_all = np.asarray(gain, float)
    g = np.asarray(groups, int)
    n_all = max(int(n_points if n_points is not None else len(d_all)), 1)
    labels = scored_groups(g)
    normals, share, gains, means, zs, losing = [], [], [], [], [], []
    used = g >= 0
    for j in labels:
        test = g == j
        d = d_all[test]
        z = block_mean_z(d, np.asarray(blocks)[test])[1] if test.sum() > 1 else 0.0
        m = np.asarray(normal, float)[test].mean(axis=0)
        normals.append(m / max(np.linalg.norm(m), 1e-12))
        share.append(float(test.sum() / max(used.sum(), 1)))
        gains.append(float(d.sum() / n_all))
        means.append(float(d.mean()))
        zs.append(float(z))
        if d.mean() <= -min_gain and z <= -z_crit:
            losing.append(int(j))
    scored = np.isin(g, labels)
    total_z = block_mean_z(d_all[scored], np.asarray(blocks)[scored])[1] \
        if scored.sum() > 1 else 0.0
    return AcrossOrientations(np.array(normals).reshape(-1, 3), np.array(share),
                              np.array(gains), np.array(means), np.array(zs),
                              float(d_all[scored].sum() / n_all), float(total_z),
                              tuple(losing))
