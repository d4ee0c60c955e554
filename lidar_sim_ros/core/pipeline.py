"""The simulator: scan -> raycast -> reflection -> detection, plus enabled effects.

``Simulator.simulate_frame`` reads top to bottom like the paper's Fig. 4. The same
``Simulator.predict`` serves the comparison tool: it runs raycast and reflection
for given rays (measured directions at measured times) without the random draws.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Callable

import numpy as np

from lidar_sim_ros.core import detection, reflection, reflection_kernels, returns
from lidar_sim_ros.core.config import MaterialsConfig, SensorConfig
from lidar_sim_ros.core.scenario import Scenario, scenario_effect_spec
from lidar_sim_ros.core.effects import Effect, ReturnContext, make_effect
from lidar_sim_ros.core.effects.base import ExtraReturns, Scene, apply_effects
from lidar_sim_ros.core.geometry import (Hits, HitRows, Target, cast_at_poses, cast_hits_at_poses,
                                        coherent_order, load_target)
from lidar_sim_ros.core.geometry_kernels import picked_in_order, picked_rows_in_order, points_along
from lidar_sim_ros.core.pose import Poses, PoseSource, PoseTrack, StaticPose
from lidar_sim_ros.core.scan import (Shots, angles_from_directions, frame_shots,
                                     frame_shots_and_directions, varies_by_frame)
from lidar_sim_ros.core.scan_flash import pixel_view_sr
from lidar_sim_ros.core.sun import ScenarioSun, SunSource

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
    hold detected returns only; ``truth_*`` hold every hit without noise or dropouts
    (gathered on first use: most frames never publish their truth).
    ``stamp_s`` is the frame start (absolute seconds); ``t_s`` is since frame start.
    ``face`` (mesh triangle, -1 off the target) and ``true_range_m`` (noise-free range,
    m) of each point serve error statistics (campaigns); a false return keeps the face
    and range of the shot it replaced, or -1 / NaN on a miss. ``return_number`` (uint8):
    1 for a shot's first reported return, 2 for its second, ... (the receiver's
    ``detection.returns``; all 1 for the default single-return sensor); a multipath
    ghost carries the face of the surface seen in the mirror and its path range.
    """

    stamp_s: float
    index: int
    xyz_m: np.ndarray
    range_m: np.ndarray
    intensity: np.ndarray
    t_s: np.ndarray
    ring: np.ndarray
    material: np.ndarray
    stats: dict = field(default_factory=dict)
    truth_source: '_FrameShots | _FrameHits | None' = field(default=None, repr=False)
    face: np.ndarray | None = field(default=None, repr=False)
    true_range_m: np.ndarray | None = field(default=None, repr=False)
    return_number: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.range_m)

    @cached_property
    def truth_range_m(self) -> np.ndarray:
        return self.truth_source.range_m.take(self.truth_source.hit_index)

    @cached_property
    def truth_xyz_m(self) -> np.ndarray:
        return _along(self.truth_source.directions, self.truth_source.hit_index, self.truth_range_m)

    @cached_property
    def truth_intensity(self) -> np.ndarray:
        return self.truth_source.intensity.take(self.truth_source.hit_index)

    @cached_property
    def truth_t_s(self) -> np.ndarray:
        return self.truth_source.t_s.take(self.truth_source.hit_index)

    @cached_property
    def truth_ring(self) -> np.ndarray:
        return self.truth_source.ring.take(self.truth_source.hit_index)

    @cached_property
    def truth_material(self) -> np.ndarray:
        return _material_ids(self.truth_source.material.take(self.truth_source.hit_index))

    @cached_property
    def truth_face(self) -> np.ndarray:
        return self.truth_source.face.take(self.truth_source.hit_index)


@dataclass(frozen=True)
class _FrameShots:
    """Every shot of a frame, noise-free, in cast order: the source of ``Frame.truth_*``.

    cast_position[i] is where firing-order shot i sits in these arrays. measured_range_m:
    every shot's measured range (bias, effects and noise; NaN on a miss), whether the
    detector reported it or not (the Cepton layout keeps saturated returns).
    """

    hit: np.ndarray
    cast_position: np.ndarray
    directions: np.ndarray
    range_m: np.ndarray
    intensity: np.ndarray
    t_s: np.ndarray
    ring: np.ndarray
    material: np.ndarray
    face: np.ndarray
    measured_range_m: np.ndarray | None = None

    @cached_property
    def hit_index(self) -> np.ndarray:
        """The hits, in firing order."""
        return _fired(self.hit, self.cast_position)


class _FrameHits:
    """``_FrameShots`` of a frame simulated on its hits' rows alone (a plain frame): the
    same arrays, every shot's row spread from the hits' on first use (most frames never
    publish their truth): range NaN, intensity 0, material and face -1 and measured range
    NaN on a miss."""

    def __init__(self, n: int, hits: HitRows, intensity: np.ndarray, measured_range_m: np.ndarray,
                 cast_position: np.ndarray, directions: np.ndarray, t_s: np.ndarray,
                 ring: np.ndarray):
        self._n, self._hits = n, hits
        self._intensity, self._measured = intensity, measured_range_m
        self.cast_position, self.directions, self.t_s, self.ring = (cast_position, directions,
                                                                    t_s, ring)

    def _spread(self, values: np.ndarray, miss) -> np.ndarray:
        out = np.full(self._n, miss, dtype=values.dtype)
        out[self._hits.rows] = values
        return out

    @cached_property
    def hit(self) -> np.ndarray:
        return self._spread(np.ones(len(self._hits), bool), False)

    @cached_property
    def range_m(self) -> np.ndarray:
        return self._spread(self._hits.range_m, np.nan)

    @cached_property
    def intensity(self) -> np.ndarray:
        return self._spread(self._intensity, 0.0)

    @cached_property
    def material(self) -> np.ndarray:
        return self._spread(self._hits.material, -1)

    @cached_property
    def face(self) -> np.ndarray:
        return self._spread(self._hits.face, -1)

    @cached_property
    def measured_range_m(self) -> np.ndarray:
        return self._spread(self._measured, np.nan)

    @cached_property
    def hit_index(self) -> np.ndarray:
        """The hits, in firing order."""
        return self._hits.rows.take(picked_rows_in_order(self._hits.rows, self._n,
                                                          self.cast_position))


def _along(directions: np.ndarray, index: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    """Points (N, 3) (m) at range_m along the unit directions picked by index."""
    return points_along(np.ascontiguousarray(directions, dtype=float), np.asarray(index, np.int64),
                        np.asarray(range_m, float))


def _material_ids(material: np.ndarray) -> np.ndarray:
    """Material ids as published (uint8): -1 (not on the target) becomes NO_MATERIAL."""
    return np.where(material < 0, NO_MATERIAL, material).astype(np.uint8)


class Simulator:
    """The paper's four modules around one target, one sensor and a material table."""

    def __init__(self, sensor: SensorConfig, materials: MaterialsConfig, target: Target,
                 seed: int = 0, effects: list[Effect] | None = None,
                 scan_base: Path | None = None, sun: SunSource | None = None,
                 threads: int | None = None):
        """``sun``: the light around the target (None: none). ``threads``: raycast threads
        (``Target.threads``; None keeps the target's). Frames do not depend on it: each
        ray's answer is the same however they are split."""
        self.sensor, self.materials, self.target = sensor, materials, target
        if threads is not None:
            target.threads = int(threads)
        self.seed = int(seed)
        self.effects: list[Effect] = list(effects or [])
        # The light around the target (None: no sun); effects read it from ctx.scene.
        self.sun: SunSource | None = sun
        self._scan_base = scan_base
        self.shots: Shots = frame_shots(sensor, scan_base)
        self.directions = self.shots.directions()
        # Frames are simulated with the shots in a coherent order (neighbouring directions
        # together): Embree traverses its BVH faster and every per-shot pass reads memory
        # in sequence. Published points go back to firing order (``_cast_position``).
        self._plan = _CastPlan.of(self.shots, self.directions, sensor)
        self._cast_order, self._cast_shots = self._plan.order, self._plan.cast_shots
        self._cast_directions, self._cast_position = self._plan.directions, self._plan.position
        # A pattern that does not repeat (the Risley rosette) has each frame's own shots.
        self._by_frame = varies_by_frame(sensor)
        self._last_plan: tuple[int, _CastPlan] = (0, self._plan)
        self._kd, self._ks, self._n = (materials.column(k) for k in ('kd', 'ks', 'n'))
        self._bias, self._sigma = materials.column('bias_m'), materials.column('sigma_m')
        self._variance = self._sigma ** 2
        # A plain frame's per-material numbers (``_plain_returns``), bit for bit as each hit
        # gets them: the BRDF's two terms and sigma.
        self._brdf_terms = reflection_kernels.brdf_terms_of(self._kd, self._ks, self._n)
        self._sigma_of = np.sqrt(self._variance)
        # ... and the sensor's (``plain_returns_of``'s optics and detector arguments).
        optics, det = sensor.optics, sensor.detection
        flood = optics.flood is not None
        self._plain_optics = (
            flood, optics.peak_power_w * optics.transmit_efficiency,
            reflection.flood_solid_angle_sr(np.radians(optics.flood.field_az_deg),
                                            np.radians(optics.flood.field_el_deg))
            if flood else 1.0,
            optics.beam_divergence_rad, optics.receive_efficiency,
            np.pi * (optics.aperture_diameter_m / 2.0) ** 2, det.threshold_power_w,
            det.saturation_power_w, det.min_range_m, det.max_range_m)

    @classmethod
    def from_scenario(cls, scenario: Scenario, effects: list[Effect] | None = None,
                      extra_effects: list[Effect] = (), threads: int | None = None,
                      target: Target | None = None) -> 'Simulator':
        """The scenario's simulator; ``effects`` replaces the scenario's list, ``extra_effects``
        extends it; ``threads`` as in ``__init__``.

        ``target``: an already loaded mesh of the scenario (campaign workers reuse its BVH).
        """
        if target is None:
            target = load_target(scenario.mesh_path, scenario.materials.names,
                                 mesh_materials=scenario.mesh_materials)
        base = scenario.source.parent if scenario.source else None
        if effects is None:
            effects = [make_effect(scenario_effect_spec(e.name, base), e.params)
                       for e in scenario.config.effects]
        sun = ScenarioSun(scenario.config.sun) if scenario.config.sun is not None else None
        return cls(scenario.sensor, scenario.materials, target, scenario.seed,
                   list(effects) + list(extra_effects), base, sun, threads)

    def warm_up(self) -> None:
        """Compile the per-ray kernels now (or load them from numba's on-disk cache), so
        the first real frame does not pay for it: ~0.1 s cached, a few s the first time."""
        self.simulate_frame(0.0, StaticPose((10.0, 0.0, 0.0)), 0)
        # A track the last shots lie past, as the node's are: interpolation and extrapolation.
        track = PoseTrack([0.0, 0.05], np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)),
                          max_extrapolation_s=1.0)
        self.predict(np.array([0.0, 0.5]), self.directions[:2], track)

    @property
    def frame_period_s(self) -> float:
        return self.sensor.frame_period_s

    def frame_rng(self, frame_index: int) -> np.random.Generator:
        """The frame's own generator: seeded by (scenario seed, frame index), order-independent."""
        return np.random.default_rng([self.seed, int(frame_index) & 0x7FFFFFFF])

    # ------------------------------------------------------------------ stages
    def predict(self, t_abs_s: np.ndarray, directions: np.ndarray, pose_source: PoseSource,
                t_frame_s: np.ndarray | None = None, az_rad=None, el_rad=None,
                laser: np.ndarray | None = None, cast_order: np.ndarray | None = None,
                pixel_sr: np.ndarray | None = None,
                each_part: Callable[[slice | np.ndarray, np.ndarray], None] | None = None
                ) -> Prediction:
        """Raycast + reflection + error model for rays at absolute times (no random draws).

        ``cast_order``: optional coherent ray order for Embree (results keep input order).
        ``pixel_sr``: a flash array's pixel field of view per ray (sr, ``scan_flash.
        pixel_view_sr``) when the caller has it (a frame's plan keeps it); else computed.
        ``each_part(rows, hit_rows)``: called on the thread of each part of the raycast once
        its rows (a slice, or indices with ``cast_order``) are reflected, with the rows of
        its hits (indices, increasing within a slice).
        """
        t_abs_s = np.asarray(t_abs_s, dtype=float)
        directions = np.asarray(directions, dtype=float)
        n = len(t_abs_s)
        t_pose = t_abs_s
        for eff in self.effects:
            t_pose = eff.pose_time_s(t_pose)
        poses = _poses_at(pose_source, t_pose)
        optics = self.sensor.optics
        target = self.seen_target()
        laser = np.zeros(n, np.uint16) if laser is None else np.asarray(laser)
        # The beams' own directions (a laser's pointing error): the raycast follows them;
        # the caller's ``directions`` stay those the points are reported along.
        nominal = directions
        for eff in self.effects:
            moved = eff.beam_directions(directions, laser)
            if moved is not None:
                directions = np.asarray(moved, dtype=float)
        hits = None
        for eff in self.effects:
            hits = eff.cast(target, directions, poses, optics.beam_divergence_rad)
            if hits is not None:
                break
        # Reflection and the error model, into these (0, NaN, 0, 0 on a miss): on each part
        # of the raycast's own thread, or after an effect's cast.
        power, rng_m, bias, var = reflected = np.zeros(n), np.full(n, np.nan), np.zeros(n), np.zeros(n)
        def then(part_hits: Hits, rows: slice | np.ndarray) -> None:
            hit_rows = self._reflect(part_hits, rows, directions, pixel_sr, reflected)
            if each_part is not None:
                each_part(rows, hit_rows)
        if hits is None:
            hits = cast_at_poses(target, directions, poses, order=cast_order, then=then)
        else:
            then(hits, slice(0, n))
            if hits.power_fraction is not None:
                power *= hits.power_fraction
        if az_rad is None or el_rad is None:
            az_rad, el_rad = angles_from_directions(nominal)
        det = self.sensor.detection
        ctx = ReturnContext(
            range_m=rng_m, incidence_rad=hits.incidence_rad, material=hits.material,
            power_w=power, intensity=detection.intensity_from_power(power, det),
            t_s=np.zeros(n) if t_frame_s is None else np.asarray(t_frame_s, dtype=float),
            az_rad=np.asarray(az_rad), el_rad=np.asarray(el_rad),
            laser=laser,
            divergence_rad=optics.beam_divergence_rad, hit=hits.hit,
            threshold_power_w=det.threshold_power_w, min_range_m=det.min_range_m,
            max_range_m=det.max_range_m, direction=directions, normal=hits.normal, face=hits.face,
            scene=Scene(target, poses, self.materials, self.sensor,
                        None if self.sun is None else self.sun.at(t_abs_s)),
            time_s=t_abs_s)
        if self.effects:
            ctx, bias, var = apply_effects(ctx, self.effects, bias, var)
            bias = np.where(hits.hit, bias, 0.0)
        return Prediction(ctx, hits, nominal, bias, np.sqrt(var))

    def seen_target(self) -> Target:
        """The surface the sensor sees: the mesh, or the first effect's stand-in for it
        (``Effect.seen_target``: the mesh's faces standing proud)."""
        for eff in self.effects:
            seen = eff.seen_target(self.target)
            if seen is not None:
                return seen
        return self.target

    def _reflect(self, hits: Hits, rows: slice | np.ndarray, directions: np.ndarray,
                 pixel_sr: np.ndarray | None, out: tuple[np.ndarray, ...]) -> np.ndarray:
        """Reflection and the error model of the shots ``rows`` (a slice or indices) that
        hit, gathered once by index, written into ``out``: received power (W), range (m),
        range bias (m) and variance (m^2) of the material hit. Returns those shots' rows."""
        power, rng_m, bias, var = out
        optics = self.sensor.optics
        on = np.flatnonzero(hits.hit[rows])
        if not isinstance(rows, slice):
            on = rows.take(on)
        elif rows.start:
            on += rows.start
        mat = hits.material.take(on)
        range_on = hits.range_m.take(on)
        cos_on = None if hits.cos_incidence is None else hits.cos_incidence.take(on)
        sr = None
        if optics.flood is not None:
            sr = pixel_view_sr(self.sensor, directions[on]) if pixel_sr is None else pixel_sr.take(on)
        incidence_on = hits.incidence_rad.take(on) if cos_on is None else None
        power[on], bias[on], var[on] = self._material_return(range_on, incidence_on, cos_on, mat,
                                                             sr)
        rng_m[on] = range_on
        return on

    def _material_return(self, range_m: np.ndarray, incidence_rad: np.ndarray | None,
                         cos_incidence: np.ndarray | None, material: np.ndarray,
                         pixel_sr: np.ndarray | None) -> tuple[np.ndarray, ...]:
        """Of hits at ``range_m`` on ``material`` (ids): received power (W, the
        reflection model with the material's Phong parameters; the incidence as an angle
        or its cosine), and the material's range bias (m) and variance (m^2)."""
        power = reflection.return_power_w(range_m, incidence_rad, self._kd.take(material),
                                          self._ks.take(material), self._n.take(material),
                                          self.sensor.optics, cos_incidence, pixel_sr)
        return power, self._bias.take(material), self._variance.take(material)

    def shots_of_frame(self, frame_index: int) -> Shots:
        """Frame ``frame_index``'s shots in firing order (``self.shots`` for every frame of a
        repeating pattern)."""
        return self._frame_plan(frame_index).shots

    def _frame_plan(self, frame_index: int) -> '_CastPlan':
        if not self._by_frame:
            return self._plan
        last_index, plan = self._last_plan
        if last_index != frame_index:
            plan = _CastPlan.of(*frame_shots_and_directions(self.sensor, self._scan_base,
                                                            frame_index), self.sensor)
            self._last_plan = (frame_index, plan)
        return plan

    # -------------------------------------------------------------- the frame
    def simulate_frame(self, frame_start_s: float, pose_source: PoseSource,
                       frame_index: int | None = None) -> Frame:
        """Simulate one frame starting at ``frame_start_s`` (absolute s)."""
        if frame_index is None:
            frame_index = int(round(frame_start_s / self.frame_period_s))
        plan = self._frame_plan(frame_index)
        shots = plan.cast_shots
        # The frame's generator; its first draw is the range noise, drawn as the raycast's
        # parts end (``_NoiseInOrder``).
        rng = self.frame_rng(frame_index)
        noise = _NoiseInOrder(rng, len(shots))
        if not self.effects and self.sensor.detection.returns.single:
            return self._plain_frame(frame_start_s, frame_index, pose_source, plan, noise)
        pred = self.predict(frame_start_s + shots.t_s, plan.directions, pose_source, shots.t_s,
                            shots.az_rad, shots.el_rad, shots.laser, pixel_sr=plan.pixel_sr,
                            each_part=noise.part_done)
        ctx, hit = pred.ctx, pred.ctx.hit
        det = self.sensor.detection
        # Misses carry NaN range and zero power: never detected, NaN measured range. The
        # detector and the measurement on the hits' rows alone (a flash frame's 19,000 of
        # 65,536 shots), then spread over the frame's shots.
        on, draws = noise.drawn()
        detected_on = detection.detected_mask(ctx.power_w.take(on), ctx.range_m.take(on), det)
        measured_on = detection.measured_range_m(ctx.range_m.take(on), pred.bias_m.take(on),
                                                 pred.sigma_m.take(on), draws)
        detected, measured = np.zeros(len(hit), bool), np.full(len(hit), np.nan)
        detected[on], measured[on] = detected_on, measured_on
        # Extra returns lie behind their echo: a first-return receiver can report them only
        # where the echo went undetected (no ray needs following elsewhere).
        open_shots = (np.flatnonzero(hit & ~detected) if det.returns.single and self.effects
                      else None)
        extras = [x for x in (eff.extra_returns(ctx, open_shots) for eff in self.effects)
                  if x is not None and len(x)]
        if extras or not det.returns.single:
            return self._multi_return_frame(frame_start_s, frame_index, pred, detected, measured,
                                            extras, rng, plan)
        material, intensity = ctx.material, ctx.intensity
        # The range gate on the measured ranges (NaN off the hits: never in it), the hits' here
        # and each false return's as it replaces its shot's.
        detected[on] &= detection.in_range_gate(measured_on, det)
        for rows, false_m in _false_returns(self.effects, ctx, rng):
            # A few shots each: written by index (measured and detected are this frame's own
            # arrays; material and intensity are the context's, copied before the first write).
            measured[rows] = false_m
            detected[rows] = detection.in_range_gate(false_m, det)
            if material is ctx.material:
                material, intensity = material.copy(), intensity.copy()
            material[rows] = -1
            intensity[rows] = det.threshold_power_w / det.saturation_power_w
        # Index lists once (take() is ~5x cheaper than repeated boolean masks), in firing order.
        out = _fired(detected, plan.position)
        range_out = measured.take(out)
        return Frame(
            stamp_s=float(frame_start_s), index=int(frame_index),
            xyz_m=_along(plan.directions, out, range_out), range_m=range_out,
            intensity=intensity.take(out), t_s=shots.t_s.take(out),
            ring=shots.laser.take(out),
            material=_material_ids(material.take(out)), stats=self._frame_stats(pred, len(out)),
            truth_source=self._truth(pred, measured, plan), face=pred.hits.face.take(out),
            true_range_m=ctx.range_m.take(out), return_number=np.ones(len(out), np.uint8))

    def _plain_frame(self, frame_start_s: float, frame_index: int, pose_source: PoseSource,
                     plan: '_CastPlan', noise: '_NoiseInOrder') -> Frame:
        """A frame with no effect and the paper's single-return receiver, on the hits' rows
        alone (``cast_hits_at_poses``: a flash frame's ~19,000 of 65,536 shots): reflection
        and the material's range error on each part's thread, then the detector, the
        measurement and the range gate. The same frame ``simulate_frame`` makes of every
        shot's row (``predict``), number for number."""
        shots, det, optics = plan.cast_shots, self.sensor.detection, self.sensor.optics
        n = len(shots)
        poses = plan.poses(frame_start_s, pose_source)
        pixel_sr = plan.pixel_sr if optics.flood is not None else None

        def then(part: slice, hits: HitRows) -> tuple:
            returns_of = self._plain_returns(hits, pixel_sr)
            noise.part_done(part, hits.rows)
            return (hits, *returns_of)
        parts = cast_hits_at_poses(self.target, plan.directions, poses, then)
        if len(parts) == 1:
            hits, power, bias, sigma, detected = parts[0]
        else:
            hits = HitRows(*(np.concatenate(a) for a in zip(*(
                (p[0].rows, p[0].range_m, p[0].cos_incidence, p[0].material, p[0].face)
                for p in parts))))
            power, bias, sigma, detected = (np.concatenate([p[k] for p in parts])
                                            for k in (1, 2, 3, 4))
        rows, draws = noise.drawn()
        measured = detection.measured_range_m(hits.range_m, bias, sigma, draws)
        detected &= detection.in_range_gate(measured, det)
        # The detected hits, in firing order.
        on = np.flatnonzero(detected)
        out = on.take(picked_rows_in_order(rows.take(on), n, plan.position))
        cast_rows, range_out = rows.take(out), measured.take(out)
        intensity = detection.intensity_from_power(power, det)
        return Frame(
            stamp_s=float(frame_start_s), index=int(frame_index),
            xyz_m=_along(plan.directions, cast_rows, range_out), range_m=range_out,
            intensity=intensity.take(out), t_s=shots.t_s.take(cast_rows),
            ring=shots.laser.take(cast_rows), material=_material_ids(hits.material.take(out)),
            stats=self._stats(n, power, len(out)),
            truth_source=_FrameHits(n, hits, intensity, measured, plan.position,
                                    plan.directions, shots.t_s, shots.laser),
            face=hits.face.take(out), true_range_m=hits.range_m.take(out),
            return_number=np.ones(len(out), np.uint8))

    def _plain_returns(self, hits: HitRows,
                       pixel_sr: np.ndarray | None) -> tuple[np.ndarray, ...]:
        """Of a plain frame's hits: received power (W), the material's range bias and sigma
        (m) and the detector's mask (``_material_return``, ``np.sqrt`` of its variance and
        ``detection.detected_mask``, number for number), in two compiled passes around
        numpy's power (``reflection_kernels``). ``pixel_sr``: a flood-lit sensor's pixel
        field of view per ray (sr; None for a beam per shot)."""
        flood = self._plain_optics[0]
        lobe = reflection_kernels.lobe_of(hits.cos_incidence, hits.material, self._n)
        return reflection_kernels.plain_returns_of(
            hits.range_m, hits.cos_incidence, hits.material, lobe, hits.rows,
            pixel_sr if flood else _NO_SR, *self._brdf_terms, self._bias,
            self._sigma_of, *self._plain_optics)

    def _frame_stats(self, pred: Prediction, detected: int) -> dict:
        ctx = pred.ctx
        return self._stats(len(ctx.hit), ctx.power_w[ctx.hit], detected)

    def _stats(self, shots: int, hit_power_w: np.ndarray, detected: int) -> dict:
        """A frame's counts: shots, hits (``hit_power_w``: their received power, W),
        detected returns, hits below the threshold and saturated."""
        det = self.sensor.detection
        return {'shots': shots, 'hits': len(hit_power_w), 'detected': detected,
                'below_threshold': int(np.count_nonzero(hit_power_w < det.threshold_power_w)),
                'saturated': int(np.count_nonzero(hit_power_w >= det.saturation_power_w))}

    def _truth(self, pred: Prediction, measured: np.ndarray, plan: '_CastPlan') -> '_FrameShots':
        ctx, shots = pred.ctx, plan.cast_shots
        return _FrameShots(ctx.hit, plan.position, plan.directions, ctx.range_m,
                           ctx.intensity, shots.t_s, shots.laser, ctx.material, pred.hits.face,
                           measured)

    def _multi_return_frame(self, frame_start_s: float, frame_index: int, pred: Prediction,
                            detected: np.ndarray, measured: np.ndarray, extras: list[ExtraReturns],
                            rng: np.random.Generator, plan: '_CastPlan') -> Frame:
        """A frame whose shots may report several returns (``core/returns.py``): each shot's
        echo, the effects' extra returns (multipath ghosts) and false returns are candidates,
        and the receiver keeps those the sensor's ``detection.returns`` asks for. A false
        return replaces its shot's other returns for the single-return receiver (as in the
        default frame: the trigger comes first) and stands beside them for a multi-return
        one; a NaN false return blinds the shot either way."""
        ctx, det, shots = pred.ctx, self.sensor.detection, plan.cast_shots
        n = len(ctx)
        blinded = np.zeros(n, bool)
        false_shot, false_range = [], []
        last_false = np.full(n, np.nan)            # single-return receiver: the last one stands
        for rows, false_m in _false_returns(self.effects, ctx, rng):
            if det.returns.single:
                blinded[rows] = True
                last_false[rows] = false_m
                continue
            finite = np.isfinite(false_m)
            blinded[rows[~finite]] = True
            false_shot.append(rows[finite])
            false_range.append(false_m[finite])
        if det.returns.single:
            rows = np.flatnonzero(np.isfinite(last_false))
            false_shot, false_range = [rows], [last_false.take(rows)]
        split = np.zeros(n, bool)
        for x in extras:
            if x.replaces_echo:
                split[x.shot] = True
        echo = np.flatnonzero(detected & ~blinded & ~split & detection.in_range_gate(measured, det))
        # Extra returns: the detector's window and the bias and noise of their surface, drawn
        # after every other draw of the frame (the other streams stay as they were).
        x_shot = np.concatenate([x.shot for x in extras]) if extras else np.zeros(0, np.int64)
        x_range = np.concatenate([x.range_m for x in extras]) if extras else np.zeros(0)
        x_power = np.concatenate([x.power_w for x in extras]) if extras else np.zeros(0)
        x_mat = np.concatenate([x.material for x in extras]) if extras else np.zeros(0, np.int16)
        x_face = np.concatenate([x.face for x in extras]) if extras else np.zeros(0, np.int64)
        x_via = np.concatenate([x.via_material for x in extras]) if extras else np.zeros(0, np.int16)

        x_meas = detection.measured_range_m(x_range, self._bias.take(x_mat), self._sigma.take(x_mat), rng)
        x_ok = (detection.detected_mask(x_power, x_range, det) & ~blinded.take(x_shot)
                & detection.in_range_gate(x_meas, det))
        f_shot = np.concatenate(false_shot) if false_shot else np.zeros(0, np.int64)
        f_range = np.concatenate(false_range) if false_range else np.zeros(0)
        f_ok = detection.in_range_gate(f_range, det)
        # Candidates: echoes (kind 0), extras (1 or 3), false returns (2).
        cand_shot = np.concatenate([echo, x_shot[x_ok], f_shot[f_ok]])
        # kind 1: returns by way of another surface (multipath ghosts), 3: other extra returns.
        kind = np.concatenate([np.zeros(len(echo), np.int8), np.where(x_via[x_ok] >= 0, 1, 3).astype(np.int8),
                               np.full(np.count_nonzero(f_ok), 2, np.int8)])
        thr = det.threshold_power_w
        cand_range = np.concatenate([measured.take(echo), x_meas[x_ok], f_range[f_ok]])
        cand_power = np.concatenate([ctx.power_w.take(echo), x_power[x_ok], np.full(np.count_nonzero(f_ok), thr)])
        cand_intensity = np.concatenate([ctx.intensity.take(echo),
                                         detection.intensity_from_power(x_power[x_ok], det),
                                         np.full(np.count_nonzero(f_ok), thr / det.saturation_power_w)])
        cand_mat = np.concatenate([ctx.material.take(echo), x_mat[x_ok], np.full(np.count_nonzero(f_ok), -1)])
        cand_face = np.concatenate([pred.hits.face.take(echo), x_face[x_ok], pred.hits.face.take(f_shot[f_ok])])
        cand_true = np.concatenate([ctx.range_m.take(echo), x_range[x_ok], ctx.range_m.take(f_shot[f_ok])])
        keep, number = returns.select_returns(plan.order.take(cand_shot), cand_range,
                                              cand_power, det.returns)
        out = cand_shot.take(keep)
        range_out = cand_range.take(keep)
        stats = self._frame_stats(pred, len(keep))
        ghost = keep[kind.take(keep) == 1]
        stats['multipath'] = len(ghost)
        stats['second_returns'] = int(np.count_nonzero(number > 1))
        stats['split_footprint_returns'] = int(np.count_nonzero(kind.take(keep) == 3))
        if len(ghost):
            via = x_via[x_ok].take(ghost - len(echo))
            names = self.materials.names
            stats['multipath_by_mirror'] = {names[m]: int(c) for m, c in zip(*np.unique(via, return_counts=True))}
            stats['multipath_path_m'] = (cand_true.take(ghost) - ctx.range_m.take(out[kind.take(keep) == 1])).tolist()
        return Frame(
            stamp_s=float(frame_start_s), index=int(frame_index),
            xyz_m=_along(plan.directions, out, range_out), range_m=range_out,
            intensity=cand_intensity.take(keep),
            t_s=shots.t_s.take(out), ring=shots.laser.take(out),
            material=_material_ids(cand_mat.take(keep)), stats=stats, truth_source=self._truth(pred, measured, plan),
            face=cand_face.take(keep), true_range_m=cand_true.take(keep), return_number=number)


_NO_SR = np.zeros(0)


def _poses_at(pose_source: PoseSource, t_s: np.ndarray) -> Poses:
    """The pose at every time, or one pose (one row, which the raycast and the effects
    apply to every shot) when all times are the same (a flash array's global exposure:
    65,536 equal times, one interpolation, one origin in the body frame)."""
    n = len(t_s)
    if n > 1 and t_s[0] == t_s[-1] and bool(np.all(t_s == t_s[0])):
        one = pose_source.at(t_s[:1])
        return Poses.from_quat(np.asarray(one.quat_xyzw, float).reshape(1, 4),
                               np.asarray(one.position_m, float).reshape(1, 3))
    return pose_source.at(t_s)


@dataclass(frozen=True)
class _CastPlan:
    """One frame's shots in firing order and in cast order (coherent: neighbouring
    directions together); ``position[i]``: where firing-order shot i sits in cast order;
    ``pixel_sr``: a flash array's pixel field of view per shot in cast order (sr; None for
    a sensor that fires a beam per shot), computed once with the plan."""

    shots: Shots
    order: np.ndarray
    cast_shots: Shots
    directions: np.ndarray
    position: np.ndarray
    pixel_sr: np.ndarray | None
    one_time: bool = False

    @classmethod
    def of(cls, shots: Shots, directions: np.ndarray, sensor: SensorConfig) -> '_CastPlan':
        order = coherent_order(shots.az_rad, shots.el_rad)
        position = np.empty_like(order)
        position[order] = np.arange(len(order))
        cast_directions = np.ascontiguousarray(directions[order])
        t_s = shots.t_s
        return cls(shots, order, shots.subset(order), cast_directions, position,
                   pixel_view_sr(sensor, cast_directions),
                   bool(len(t_s) > 1 and np.all(t_s == t_s[0])))

    def poses(self, frame_start_s: float, pose_source: PoseSource) -> Poses:
        """The shots' poses (``_poses_at``): one row for a global exposure, found once
        with the plan (every shot at one time)."""
        if self.one_time:
            return _poses_at(pose_source, frame_start_s + self.cast_shots.t_s[:1])
        return _poses_at(pose_source, frame_start_s + self.cast_shots.t_s)


class _NoiseInOrder:
    """A frame's first draw from its generator: one standard normal per hit (a shot with a
    range) in cast order, the range noise (a flash frame's ~19,000 returns, not its 65,536
    pixels). Drawn while the raycast runs: whichever thread ends the next part in cast
    order draws for it and for the ended parts behind it (numpy releases the GIL while it
    draws), so only the last part's draw waits for the cast, and the numbers are those of
    one draw after the cast, for any split (a draw of a then b numbers is the draw of a + b)."""

    def __init__(self, rng: np.random.Generator, n: int):
        self._rng, self._n = rng, n
        self._ended: dict[int, tuple[int, np.ndarray]] = {}    # part start -> (stop, hit rows)
        self._next = 0                                          # rows before it are drawn
        self._rows: list[np.ndarray] = []                       # the parts' hit rows, in order
        self._draws: list[np.ndarray] = []                      # and their draws
        self._lock = threading.Lock()

    def part_done(self, rows: slice | np.ndarray, hit_rows: np.ndarray) -> None:
        """``Simulator.predict``'s ``each_part``: a part (a slice of cast order) has its hits."""
        if not isinstance(rows, slice):
            raise ValueError('the range noise is drawn part by part over slices of cast order')
        with self._lock:
            self._ended[rows.start or 0] = (self._n if rows.stop is None else rows.stop, hit_rows)
            while self._next in self._ended:
                stop, hits = self._ended.pop(self._next)
                self._rows.append(hits)
                self._draws.append(self._rng.standard_normal(len(hits)))
                self._next = stop

    def drawn(self) -> tuple[np.ndarray, np.ndarray]:
        """The hits' rows (increasing) and their standard normal draws, once every part has
        ended."""
        if self._next != self._n:
            raise RuntimeError(f'range noise drawn for {self._next} of {self._n} shots')
        if len(self._rows) == 1:
            return self._rows[0], self._draws[0]
        return (np.concatenate(self._rows) if self._rows else np.zeros(0, np.int64),
                np.concatenate(self._draws) if self._draws else np.zeros(0))


def _false_returns(effects, ctx, rng: np.random.Generator):
    """Per effect that draws false returns, in order (each draw from ``rng``): the shots
    it triggers and their false ranges (m; NaN blinds the shot)."""
    for eff in effects:
        spurious = eff.false_returns(ctx, rng)
        if spurious is not None:
            mask, range_m = spurious
            rows = np.flatnonzero(mask)
            yield rows, range_m[rows]


def _fired(mask: np.ndarray, cast_position: np.ndarray) -> np.ndarray:
    """Indices (into cast-ordered arrays) of the shots in ``mask``, in firing order."""
    return picked_in_order(np.asarray(mask, bool), np.asarray(cast_position, np.int64))
