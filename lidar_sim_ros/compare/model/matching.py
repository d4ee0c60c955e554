"""Ray-matched prediction: what the model expects on every measured ray.

Each measured point's own direction is cast at the target pose of its own time
through ``Simulator.predict`` (raycast, reflection, material bias and noise, enabled
effects; no random draws). A point is *matched* when its ray hits the target; the
others are *unmatched* and analysed apart (their range and angular distance to the
target's silhouette), never dropped.

The edge feature is the angular distance from each ray to the nearest silhouette or
depth step: rings of offset rays at a few multiples of the beam divergence are cast
and the smallest ring that misses the target or jumps off the local plane wins.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lidar_sim_ros.compare.recording.measurements import Measurements
from lidar_sim_ros.core.config import MaterialsConfig, SensorConfig
from lidar_sim_ros.core.effects import Effect
from lidar_sim_ros.core.geometry import Target, cast_at_poses
from lidar_sim_ros.core.pipeline import Prediction, Simulator
from lidar_sim_ros.core.pose import Poses
from lidar_sim_ros.core.sun import SunSource

# Ring radii of the edge probe, in beam divergences (full angle).
EDGE_RING_DIVERGENCES = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
EDGE_RING_RAYS = 8
# Past the largest ring: "far from any edge".
EDGE_FAR = 32.0


@dataclass(frozen=True)
class Model:
    """What the comparison predicts with: sensor, materials, target and effects."""

    sensor: SensorConfig
    materials: MaterialsConfig
    target: Target
    effects: tuple[Effect, ...] = ()
    seed: int = 0
    scan_base: Path | None = None
    # The recording's sun (its /sun/direction track), None without one: effects that
    # need the light (``sunlight``) read it from every prediction's scene.
    sun: SunSource | None = None
    # Simulators built so far, by materials: building one (scan pattern, cast order)
    # costs ~25 ms, and the fits ask for one per trial value.
    _built: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def simulator(self, materials: MaterialsConfig | None = None,
                  effects: list[Effect] | tuple[Effect, ...] | None = None) -> Simulator:
        materials = materials or self.materials
        key = id(materials)
        if key not in self._built:
            self._built[key] = (materials, Simulator(self.sensor, materials, self.target,
                                                     self.seed, [], self.scan_base, self.sun))
        sim = copy.copy(self._built[key][1])     # shares scan, target and tables
        sim.effects = list(self.effects if effects is None else effects)
        return sim

    @property
    def divergence_rad(self) -> float:
        return self.sensor.optics.beam_divergence_rad


def predict_rays(sim: Simulator, meas: Measurements) -> Prediction:
    """``Simulator.predict`` on the measured rays at their own times."""
    return sim.predict(meas.t_s, meas.directions, meas.poses, t_frame_s=meas.t_frame_s,
                       laser=meas.laser)


@dataclass(frozen=True)
class Matching:
    """Measured points against the model's prediction on the same rays.

    matched: bool (N,), the ray hits the target; residual_m: measured minus expected
    range (NaN where unmatched); edge_rad: angular distance to the nearest silhouette or
    depth step (N,); for unmatched points it is the distance to the silhouette.
    """

    meas: Measurements
    pred: Prediction
    matched: np.ndarray
    residual_m: np.ndarray
    edge_rad: np.ndarray
    range_rate_mps: np.ndarray | None = None    # (N,) m/s, see range_rate_mps()

    @property
    def n_matched(self) -> int:
        return int(self.matched.sum())

    @property
    def unmatched_fraction(self) -> float:
        return float(1.0 - self.matched.mean()) if len(self.matched) else 0.0


def match(sim: Simulator, meas: Measurements, divergence_rad: float,
          edges: bool = True) -> Matching:
    """Predict every measured ray; ``edges`` also probes the distance to edges (slower)."""
    pred = predict_rays(sim, meas)
    matched = np.asarray(pred.ctx.hit, bool)
    residual = np.where(matched, meas.range_m - pred.expected_range_m, np.nan)
    edge = (edge_distance_rad(sim.target, meas, pred, divergence_rad) if edges
            else np.full(len(meas), np.nan))
    return Matching(meas, pred, matched, residual, edge)


def edge_distance_rad(target: Target, meas: Measurements, pred: Prediction,
                      divergence_rad: float) -> np.ndarray:
    """Angular distance (rad) of each ray to the nearest silhouette or depth step.

    For a hit: the smallest ring radius where an offset ray misses the target or lands
    off the plane of the central hit by more than max(5 cm, 0.5 % of range). For a
    miss: the smallest ring radius where an offset ray hits the target. Rays with no
    change within the largest ring get EDGE_FAR divergences.
    """
    n = len(meas)
    dirs = meas.directions
    hit = np.asarray(pred.ctx.hit, bool)
    poses = meas.poses.at(meas.t_s)
    # Two unit vectors perpendicular to each ray span its ring.
    helper = np.where(np.abs(dirs[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(dirs, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(dirs, u)
    rng0 = np.where(hit, pred.ctx.range_m, np.nan)
    normal = pred.hits.normal
    plane_d = np.einsum('ij,ij->i', dirs * rng0[:, None], normal)  # p . n of the hit
    tol = np.maximum(0.05, 0.005 * np.nan_to_num(rng0, nan=0.0))
    found = np.full(n, EDGE_FAR * divergence_rad)
    pending = np.ones(n, bool)
    phi = 2 * np.pi * np.arange(EDGE_RING_RAYS) / EDGE_RING_RAYS
    for mult in EDGE_RING_DIVERGENCES:
        idx = np.flatnonzero(pending)
        if len(idx) == 0:
            break
        rho = mult * divergence_rad
        k = len(idx)
        offs = (np.cos(phi)[None, :, None] * u[idx, None, :]
                + np.sin(phi)[None, :, None] * v[idx, None, :])
        ring = dirs[idx, None, :] * np.cos(rho) + offs * np.sin(rho)
        ring = ring.reshape(-1, 3)
        rep = np.repeat(idx, EDGE_RING_RAYS)
        ring_hits = cast_at_poses(target, ring, _take_poses(poses, rep))
        h = ring_hits.hit.reshape(k, EDGE_RING_RAYS)
        r = np.where(ring_hits.hit, ring_hits.range_m, np.nan).reshape(k, EDGE_RING_RAYS)
        on_target = hit[idx]
        # Where the ring ray would meet the central hit's plane.
        denom = np.einsum('ij,ij->i', ring, normal[rep]).reshape(k, EDGE_RING_RAYS)
        with np.errstate(divide='ignore', invalid='ignore'):
            r_plane = plane_d[idx, None] / denom
            jump = np.abs(r - r_plane) > tol[idx, None]
        edge_hit = on_target & (np.any(~h, axis=1) | np.any(h & jump, axis=1))
        edge_miss = ~on_target & np.any(h, axis=1)
        done = edge_hit | edge_miss
        found[idx[done]] = rho
        pending[idx[done]] = False
    return found


def _take_poses(poses: Poses, index: np.ndarray) -> Poses:
    return Poses(poses.rotation[index], poses.position_m[index])


def range_rate_mps(sim: Simulator, meas: Measurements, pred: Prediction,
                   dt_s: float = 0.005) -> np.ndarray:
    """How fast the range along each measured ray changes with the target's motion (m/s):
    the model's range at the point's time + dt minus at its time, over dt. NaN where the
    ray misses at either time or jumps to another surface (|change| > 2.5 cm)."""
    later = sim.predict(meas.t_s + dt_s, meas.directions, meas.poses, t_frame_s=meas.t_frame_s,
                        laser=meas.laser)
    hit = np.asarray(pred.ctx.hit, bool) & np.asarray(later.ctx.hit, bool)
    with np.errstate(invalid='ignore'):
        change = later.ctx.range_m - pred.ctx.range_m
        return np.where(hit & (np.abs(change) <= 0.025), change / dt_s, np.nan)
