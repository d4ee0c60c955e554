"""Beam divergence: the beam is a cone, not a ray.

The paper's raycast follows the beam axis. A real beam lights a footprint, so a
shot whose axis just misses the target still returns if enough of the footprint
lands on it (points beyond the geometric silhouette), and a footprint straddling a
depth step returns a mix of the two ranges (points between the surfaces).

Forward model (the ``cast`` hook): K sub-rays cover a cone of full angle
``footprint_scale * divergence``: the axis plus ``rings`` rings at radii rho = i /
rings of the cone's half-angle, 6 i rays on ring i (K = 7, 19, 37 for 1, 2, 3
rings; a fixed pattern, so the model stays deterministic). Each carries the
Gaussian beam's share of energy, e_j ~ exp(-2 rho_j^2) (1/e^2 at the cone edge).
The shot hits if any sub-ray does; its received power is the full-beam power at the
strongest hit sub-ray times the hit energy fraction f = sum_hit e_j / sum e_j (the
detector threshold then decides), and its range is the energy-weighted mean of the
hit sub-rays' ranges (``range_mode: mean``) or the nearest one (``first``).
Reflectance differences between sub-rays are ignored in the weights.

Fit: 1-D search of footprint_scale on the likelihood of matched points plus the
unmatched points it puts back on the target; the smallest scale within 2 nats of
the best (the likelihood goes flat once every edge point is explained).
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect
from lidar_sim_ros.core.geometry import Hits


def footprint_pattern(rings: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-ray layout: normalised radius rho (0..1), azimuth phi (rad), energy weight."""
    rho, phi = [0.0], [0.0]
    for i in range(1, rings + 1):
        k = 6 * i
        rho += [i / rings] * k
        # Stagger alternate rings so sub-rays do not line up radially.
        phi += list(2 * np.pi * (np.arange(k) + 0.5 * (i % 2)) / k)
    rho, phi = np.array(rho), np.array(phi)
    return rho, phi, np.exp(-2.0 * rho ** 2)


def perpendicular_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) perpendicular to unit vectors d and to each other."""
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(d, u)


@register
class BeamDivergence(Effect):
    """Footprint sampled by K sub-rays: returns beyond silhouettes, mixed depths."""

    name = 'beam_divergence'
    bounds = {'footprint_scale': (0.0, 30.0)}
    initial = {'footprint_scale': 0.0}
    needs_repredict = True
    # The likelihood goes flat once every edge point is explained: the smallest scale
    # within 2 nats of the best.
    fit_options = {'n_grid': 16, 'prefer_low': 2.0}

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        footprint_scale: float = Field(
            0.0, ge=0.0, description='cone full angle / beam divergence (-); 0 = single ray')
        rings: int = Field(2, ge=1, le=5, description='sub-ray rings (K = 1 + 3 rings (rings + 1))')
        range_mode: Literal['mean', 'first'] = 'mean'

    def cast_reach_rad(self, divergence_rad: float) -> float:
        """Half-angle of the cone (rad): rays farther from an edge see one plane only."""
        return 0.5 * self.params.footprint_scale * divergence_rad

    def cast(self, target, directions_lidar: np.ndarray, poses,
             divergence_rad: float) -> Hits | None:
        half_angle = 0.5 * self.params.footprint_scale * divergence_rad
        if half_angle <= 0:
            return None
        d = np.asarray(directions_lidar, float)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        n = len(d)
        origin_b = poses.to_body(np.zeros((n, 3)))
        d_b = poses.vector_to_body(d)
        u, v = perpendicular_basis(d_b)
        rho, phi, energy = footprint_pattern(self.params.rings)
        k = len(rho)
        tilt = np.tan(half_angle * rho)
        sub = d_b[:, None, :] + tilt[None, :, None] * (
            np.cos(phi)[None, :, None] * u[:, None, :] + np.sin(phi)[None, :, None] * v[:, None, :])
        sub /= np.linalg.norm(sub, axis=2, keepdims=True)
        h = target.cast(np.repeat(origin_b, k, axis=0), sub.reshape(-1, 3))
        hit_k = h.hit.reshape(n, k)
        e_hit = np.where(hit_k, energy[None, :], 0.0)
        fraction = e_hit.sum(axis=1) / energy.sum()
        hit = fraction > 0
        range_k = np.where(hit_k, h.range_m.reshape(n, k), np.inf)
        if self.params.range_mode == 'first':
            range_m = range_k.min(axis=1)
        else:
            with np.errstate(invalid='ignore'):
                range_m = (e_hit * np.where(hit_k, range_k, 0.0)).sum(axis=1) / e_hit.sum(axis=1)
        range_m = np.where(hit, range_m, np.inf)
        rep = np.argmax(e_hit, axis=1) + np.arange(n) * k       # strongest hit sub-ray
        normal = np.zeros((n, 3))
        normal[hit] = h.normal[rep[hit]]
        normal = np.where(hit[:, None], poses.vector_to_lidar(normal), 0.0)
        incidence = np.where(hit, h.incidence_rad[rep], np.nan)
        material = np.where(hit, h.material[rep], -1).astype(np.int16)
        face = np.where(hit, h.face[rep], -1)
        return Hits(hit, range_m, normal, incidence, material, face, power_fraction=fraction)
