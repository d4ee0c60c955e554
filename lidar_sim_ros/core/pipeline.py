"""The simulator: scan -> raycast -> reflection -> detection, plus enabled effects.

``Simulator.simulate_frame`` reads top to bottom like the paper's Fig. 4. The same
``Simulator.predict`` serves the comparison tool: it runs raycast and reflection
for given rays (measured directions at measured times) without the random draws.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lidar_sim_ros.core import detection, reflection
from lidar_sim_ros.core.config import MaterialsConfig, Scenario, SensorConfig
from lidar_sim_ros.core.effects import Effect, ReturnContext, make_effect
from lidar_sim_ros.core.effects.base import apply_effects
from lidar_sim_ros.core.geometry import Hits, Target, cast_at_poses, coherent_order, load_target
from lidar_sim_ros.core.pose import PoseSource
from lidar_sim_ros.core.scan import Shots, angles_from_directions, frame_shots

NO_MATERIAL = 255  # material id of a return that is not on the target (e.g. solar background)


@dataclass(frozen=True)
class Prediction:
    """Model prediction for a set of rays: geometry, power and range error model.

    expected_range_m = true range + bias (the mean of the measured range);
    sigma_m is the predicted 1-sigma noise of the measured range.
    """

    ctx: ReturnContext
    hits: Hits
    directions: np.ndarray
    bias_m: np.ndarray
    sigma_m: np.ndarray

    @property
    def expected_range_m(self) -> np.ndarray:
        return self.ctx.range_m + self.bias_m


@dataclass(frozen=True)
class Frame:
    """One simulated frame: the published points and the noise-free truth.

    Point arrays (``xyz_m``, ``range_m``, ``intensity``, ``t_s``, ``ring``, ``material``)
    hold detected returns only; ``truth_*`` hold every hit without noise or dropouts.
    ``stamp_s`` is the frame start (absolute seconds); ``t_s`` is since frame start.
    """

    stamp_s: float
    index: int
    xyz_m: np.ndarray
    range_m: np.ndarray
    intensity: np.ndarray
    t_s: np.ndarray
    ring: np.ndarray
    material: np.ndarray
    truth_xyz_m: np.ndarray
    truth_range_m: np.ndarray
    truth_intensity: np.ndarray
    truth_t_s: np.ndarray
    truth_ring: np.ndarray
    truth_material: np.ndarray
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.range_m)


def _scenario_relative(spec: str, base: Path | None) -> str:
    """``file.py:Class`` effect specs resolve next to the scenario file when they exist there."""
    where, _, cls_name = spec.rpartition(':')
    if base is None or not where.endswith('.py') or Path(where).is_absolute():
        return spec
    candidate = base / where
    return f'{candidate}:{cls_name}' if candidate.is_file() else spec


class Simulator:
    """The paper's four modules around one target, one sensor and a material table."""

    def __init__(self, sensor: SensorConfig, materials: MaterialsConfig, target: Target,
                 seed: int = 0, effects: list[Effect] | None = None,
                 scan_base: Path | None = None):
        self.sensor, self.materials, self.target = sensor, materials, target
        self.seed = int(seed)
        self.effects: list[Effect] = list(effects or [])
        self.shots: Shots = frame_shots(sensor, scan_base)
        self.directions = self.shots.directions()
        self._cast_order = coherent_order(self.shots.az_rad, self.shots.el_rad)
        self._kd, self._ks, self._n = (materials.column(k) for k in ('kd', 'ks', 'n'))
        self._bias, self._sigma = materials.column('bias_m'), materials.column('sigma_m')

    @classmethod
    def from_scenario(cls, scenario: Scenario, effects: list[Effect] | None = None,
                      extra_effects: list[Effect] = ()) -> 'Simulator':
        """The scenario's simulator; ``effects`` replaces the scenario's list, ``extra_effects`` extends it."""
        target = load_target(scenario.mesh_path, scenario.materials.names)
        base = scenario.source.parent if scenario.source else None
        if effects is None:
            effects = [make_effect(_scenario_relative(e.name, base), e.params)
                       for e in scenario.config.effects]
        return cls(scenario.sensor, scenario.materials, target, scenario.seed,
                   list(effects) + list(extra_effects), base)

    @property
    def frame_period_s(self) -> float:
        return self.sensor.frame_period_s

    def frame_rng(self, frame_index: int) -> np.random.Generator:
        """The frame's own generator: seeded by (scenario seed, frame index), order-independent."""
        return np.random.default_rng([self.seed, int(frame_index) & 0x7FFFFFFF])

    # ------------------------------------------------------------------ stages
    def predict(self, t_abs_s: np.ndarray, directions: np.ndarray, pose_source: PoseSource,
                t_frame_s: np.ndarray | None = None, az_rad=None, el_rad=None,
                laser: np.ndarray | None = None, cast_order: np.ndarray | None = None) -> Prediction:
        """Raycast + reflection + error model for rays at absolute times (no random draws).

        ``cast_order``: optional coherent ray order for Embree (results keep input order).
        """
        t_abs_s = np.asarray(t_abs_s, dtype=float)
        n = len(t_abs_s)
        t_pose = t_abs_s
        for eff in self.effects:
            t_pose = eff.pose_time_s(t_pose)
        poses = pose_source.at(t_pose)
        optics = self.sensor.optics
        hits = None
        for eff in self.effects:
            hits = eff.cast(self.target, directions, poses, optics.beam_divergence_rad)
            if hits is not None:
                break
        if hits is None:
            hits = cast_at_poses(self.target, directions, poses, order=cast_order)
        mat = np.where(hits.hit, hits.material, 0).astype(np.intp)
        rng_m = np.where(hits.hit, hits.range_m, np.nan)
        power = np.where(hits.hit, reflection.return_power_w(
            np.where(hits.hit, hits.range_m, 1.0), np.where(hits.hit, hits.incidence_rad, 0.0),
            self._kd[mat], self._ks[mat], self._n[mat], optics), 0.0)
        if hits.power_fraction is not None:
            power = power * hits.power_fraction
        if az_rad is None or el_rad is None:
            az_rad, el_rad = angles_from_directions(directions)
        det = self.sensor.detection
        ctx = ReturnContext(
            range_m=rng_m, incidence_rad=hits.incidence_rad, material=hits.material,
            power_w=power, intensity=detection.intensity_from_power(power, det),
            t_s=np.zeros(n) if t_frame_s is None else np.asarray(t_frame_s, dtype=float),
            az_rad=np.asarray(az_rad), el_rad=np.asarray(el_rad),
            laser=np.zeros(n, np.uint16) if laser is None else np.asarray(laser),
            divergence_rad=optics.beam_divergence_rad, hit=hits.hit,
            threshold_power_w=det.threshold_power_w, min_range_m=det.min_range_m,
            max_range_m=det.max_range_m)
        ctx, bias, var = apply_effects(ctx, self.effects, np.where(hits.hit, self._bias[mat], 0.0),
                                       np.where(hits.hit, self._sigma[mat] ** 2, 0.0))
        bias = np.where(hits.hit, bias, 0.0)
        return Prediction(ctx, hits, np.asarray(directions, dtype=float), bias, np.sqrt(var))

    # -------------------------------------------------------------- the frame
    def simulate_frame(self, frame_start_s: float, pose_source: PoseSource,
                       frame_index: int | None = None) -> Frame:
        """Simulate one frame starting at ``frame_start_s`` (absolute s)."""
        if frame_index is None:
            frame_index = int(round(frame_start_s / self.frame_period_s))
        rng = self.frame_rng(frame_index)
        shots = self.shots
        t_abs = frame_start_s + shots.t_s
        pred = self.predict(t_abs, self.directions, pose_source, shots.t_s,
                            shots.az_rad, shots.el_rad, shots.laser, self._cast_order)
        ctx, hit = pred.ctx, pred.ctx.hit
        det = self.sensor.detection
        true_range = np.where(hit, ctx.range_m, 0.0)
        detected = hit & detection.detected_mask(ctx.power_w, true_range, det)
        measured = detection.measured_range_m(true_range, pred.bias_m, pred.sigma_m, rng)
        material = np.where(hit, ctx.material, NO_MATERIAL).astype(np.uint8)
        intensity = ctx.intensity.copy()
        for eff in self.effects:
            spurious = eff.false_returns(ctx, rng)
            if spurious is None:
                continue
            mask, rng_false = spurious
            measured = np.where(mask, rng_false, measured)
            detected = detected | mask
            material = np.where(mask, NO_MATERIAL, material).astype(np.uint8)
            intensity = np.where(mask, det.threshold_power_w / det.saturation_power_w, intensity)
        detected &= np.isfinite(measured) & (measured > 0)
        # Index lists once: take() is ~5x cheaper than repeated boolean masks.
        out, true = np.flatnonzero(detected), np.flatnonzero(hit)
        dirs = self.directions
        stats = {'shots': len(shots), 'hits': len(true), 'detected': len(out),
                 'below_threshold': int((hit & (ctx.power_w < det.threshold_power_w)).sum()),
                 'saturated': int((hit & (ctx.power_w >= det.saturation_power_w)).sum())}
        range_out, range_true = measured.take(out), ctx.range_m.take(true)
        return Frame(
            stamp_s=float(frame_start_s), index=int(frame_index),
            xyz_m=dirs.take(out, axis=0) * range_out[:, None], range_m=range_out,
            intensity=intensity.take(out), t_s=shots.t_s.take(out), ring=shots.laser.take(out),
            material=material.take(out),
            truth_xyz_m=dirs.take(true, axis=0) * range_true[:, None], truth_range_m=range_true,
            truth_intensity=ctx.intensity.take(true), truth_t_s=shots.t_s.take(true),
            truth_ring=shots.laser.take(true), truth_material=material.take(true), stats=stats)
