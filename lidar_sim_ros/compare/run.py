"""The comparison loop, top to bottom: load, leave out occlusion, match, calibrate
materials, attribute, diagnose, report.

``run_compare`` is what ``lidar-sim compare`` calls. It reads a bag of measured
points and target poses, predicts every measured ray with the model (the scenario's
sensor and materials, the given mesh, the scenario's effects plus any ``--effect``),
and writes ``summary.json``, ``report.html`` (+ PNGs), ``effects.yaml`` (with
``--fit``), ``materials.yaml`` and one line of ``history.json``. Each stage prints a
progress line on stderr; ``summary.json`` keeps their durations (``stage_seconds``).
``run_compare`` reads as that loop: one function per stage, each with typed inputs and
outputs (``Inputs``, ``Calibrated``, ``Analysed``, ``Diagnosed``) that a test can call
alone. ``--effect pose_error`` is no sensor effect: it corrects the reference pose per
cloud (``pose_error.py``, ``correct_reference_pose``) and the simulator never applies it.

A recording with the sun direction (``/sun/direction`` or ``--sun-topic``) is predicted
under its sun, and the receiver factor of the ``sunlight`` effect is fitted from the
false returns on sunlit versus shadowed rays (``compare/diagnose/sunlight.py``; summary.json's
``sunlight``). Without one nothing changes: the phenomenological ``solar_background``
is the candidate for false returns.

Speed: the headline figures and the per-material statistics use every point
analysed (one raycast); the edge probe, the attribution and the candidate fits use
a random sample of at most DIAGNOSIS_MAX_MATCHED matched (and as many unmatched)
points, which holds ample statistical power for effects that matter.
"""
from __future__ import annotations

import json
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.stats import norm

from lidar_sim_ros.compare.diagnose import (clock_footing, clock_nested, diagnosis,
                                            far_returns, features,
                                            fit_data, intensity_range, laser_gains,
                                            plan as sep_plan, power_incidence,
                                            line_of_sight, mixed_edges, pose_error,
                                            range_alone, region_offset,
                                            row_clock, spin_clock, stamp_place,
                                            silhouette, variants)
from lidar_sim_ros.compare.diagnose.candidate import _num
from lidar_sim_ros.compare.diagnose.scan_clock import ScanClock
from lidar_sim_ros.compare.recording import fields
from lidar_sim_ros.compare.report import history
from lidar_sim_ros.compare.report.pose_status import pose_status
from lidar_sim_ros.compare.model import multiple_returns as mret
from lidar_sim_ros.compare.model import (crosstalk as xtalk, likelihood as lk,
                                         materials as mat, neighbours, occlusion as occ,
                                         point_times, pointing)
from lidar_sim_ros.compare.recording.cepton_pcap import side_bag
from lidar_sim_ros.compare.recording.intensity import IntensityCalibration, calibrate_intensity
from lidar_sim_ros.compare.model.fit import at_bounds
from lidar_sim_ros.compare.model.matching import (Matching, Model, edge_distance_rad, match,
                                                  range_rate_mps)
from lidar_sim_ros.compare.recording.measurements import (Measurements, MeasurementError,
                                                          load_measurements, with_scan_times)
from lidar_sim_ros.compare.recording.shots import missed_per_unmatched
from lidar_sim_ros.compare.recording.scan_rate import figure_period_s
from lidar_sim_ros.compare.diagnose.sunlight import (SunFit, fit_sunlight, read_sun_track,
                                                     short_points, summary_section,
                                                     sunlit_decision)
from lidar_sim_ros.compare.report.verdict import summary_lines, verdict
from lidar_sim_ros.core.config import LissajousArrayScan, MaterialsConfig, resolve
from lidar_sim_ros.core.scenario import Scenario, load_scenario, scenario_effect_spec
from lidar_sim_ros.core.effects import (Effect, catalogue, effect_from_spec, get_effect_class,
                                        parse_effect_spec)
from lidar_sim_ros.core.geometry import load_target
from lidar_sim_ros.core.scan import lissajous_angles, lissajous_lasers, varies_by_frame
from lidar_sim_ros.core.effects.multipath import Multipath
from lidar_sim_ros.core.effects.sunlight import Sunlight
from lidar_sim_ros.core.pipeline import Prediction
from lidar_sim_ros.core.sun import SunTrack
from lidar_sim_ros.io.bag import CLOUD_TOPIC, POSE_TOPIC, SUN_TOPIC, BagContentError, open_bag
from lidar_sim_ros.paths import config_path

DEFAULT_MAX_POINTS = 300_000
# Candidate fits re-run the raycast many times: a random subset of this many matched
# points (and as many unmatched) keeps them fast with ample statistical power.
DIAGNOSIS_MAX_MATCHED = 12_000
# ... but at least this many a cloud (up to MAX_DIAGNOSIS_SAMPLE): the reference pose's
# per-cloud test fits six parameters a cloud on each of two folds, and a cloud needs
# pose_error.MIN_CLOUD_POINTS usable points there (on 300 clouds, 12,000 points left
# 40 a cloud: the test was not run and a jittering pose read as incidence).
SAMPLE_PER_CLOUD = 200
MAX_DIAGNOSIS_SAMPLE = 60_000


# The per-cloud pose test fits six parameters a cloud on one half of its points and
# scores them on the other half: p parameters fitted on m points cost a held-out point
# about p / (2 m) nats, so POSE_PARAMS / n on a cloud of n points. Where the diagnosis
# sample leaves that cost above MIN_PRACTICAL_GAIN (fewer than 1,200 sample points a
# cloud: 80 clouds in 16,000 points leave 200), the test cannot show a pose error that
# matters, and features that grow where a cloud's rigid shift moves ranges most
# (incidence, power) took its residual: the pose tests run on every matched point
# instead (``pose_points``).
POSE_PARAMS = 6


def sample_size(meas: Measurements) -> int:
    """Matched points the diagnosis samples: DIAGNOSIS_MAX_MATCHED, or SAMPLE_PER_CLOUD
    a cloud on a long recording, at most MAX_DIAGNOSIS_SAMPLE."""
    n_clouds = len(np.unique(meas.cloud)) if len(meas.cloud) else 0
    return int(min(MAX_DIAGNOSIS_SAMPLE, max(DIAGNOSIS_MAX_MATCHED, SAMPLE_PER_CLOUD * n_clouds)))
# Candidates fitted on all the diagnosed points (reported parameters and "after"
# figures): the best few; the others report their fit on half of the points.
FINALIZED = 3
SILHOUETTE_NEAR_DIVERGENCES = 2.0
# --effect pose_error: a per-cloud correction of the reference pose (compare/diagnose/pose_error.py),
# not a catalogue effect: the simulator never applies it.
POSE_ERROR = diagnosis.POSE_ERROR
LASER_BIAS, RANGE_WALK = 'laser_bias', 'range_walk'


@dataclass
class CompareOptions:
    bag: Path
    mesh: Path
    out: Path
    config: Path | None = None
    effects: list[str] = field(default_factory=list)
    fit: bool = False
    cloud_topic: str = CLOUD_TOPIC
    pose_topic: str = POSE_TOPIC
    sun_topic: str | None = None            # None: SUN_TOPIC if the bag has it
    history: Path | None = None
    max_points: int = DEFAULT_MAX_POINTS
    candidates: list[str] | None = None     # effect specs to diagnose (default: catalogue)
    seed: int = 0
    report: bool = True
    progress: bool = True                   # one line per stage on stderr
    plan: bool = True                       # a tie: which recording separates it (plan.yaml)
    intensity_field: str | None = None      # field names where the driver's are not known
    time_field: str | None = None           # one field or SECONDS,SUBSECONDS
    laser_field: str | None = None
    poses: Path | None = None               # poses (bag or CSV) apart from the recording


@dataclass
class CompareResult:
    summary: dict
    out: Path
    files: list[Path]
    fitted: list[Effect]
    lines: list[str]


class Stages:
    """Times each stage of the run and prints a progress line per stage on stderr."""

    def __init__(self, show: bool):
        self.show, self.seconds = show, {}
        self._t0 = time.perf_counter()

    @contextmanager
    def __call__(self, name: str, what: str = ''):
        t0 = time.perf_counter()
        yield
        dt = time.perf_counter() - t0
        self.seconds[name] = round(self.seconds.get(name, 0.0) + dt, 3)
        if self.show:
            print(f'lidar-sim compare: {name} {dt:.1f} s{(" (" + what + ")") if what else ""}',
                  file=sys.stderr, flush=True)

    @property
    def total(self) -> float:
        return time.perf_counter() - self._t0


def fit_user_effects(model: Model, base: list[Effect], user: list[Effect], meas: Measurements,
                     power: 'PowerFromIntensity', extra_var: np.ndarray | None,
                     seed: int) -> tuple[list[Effect], SunFit | None]:
    """ML-fit each user effect in turn on top of the base and the previously fitted ones
    (on the diagnosis sample of points), then, several that move no rays, each again
    with all the others in the model until they settle (``variants.refit_in_turn``);
    also the sunlight fit, if one was made.

    The likelihood profiles each material's offset and sigma scale, so a constant
    per-material mismatch does not leak into the effect's parameters. ``sunlight`` is
    fitted instead from which points are false returns, on all the points
    (``sunlight_of_recording``): they are rare, and its likelihood is that of the false returns.
    """
    done: list[Effect] = []
    sun_fit = None
    fixed_of = []
    for eff in user:
        cls = type(eff)
        # Parameters the user gave (e.g. beam_divergence={range_mode: first}) stay fixed.
        fixed = {k: v for k, v in eff.params.model_dump(exclude_unset=True).items()
                 if k not in cls.bounds}
        fixed_of.append(fixed)
        m = match(geometry(model, base + done), meas, model.divergence_rad, edges=False)
        rays = replace(rays_of(m, power(m), model), extra_var_m2=extra_var)
        if isinstance(eff, Sunlight):
            residual, sigma = model_residuals(fit_data.make_fit_data(model, base + done, rays),
                                              rays)
            sun_fit = sunlight_of_recording(m, residual, sigma)
            done.append(Sunlight({'background_scale': sun_fit.background_scale}))
            continue
        data = fit_data.make_fit_data(model, base + done,
                                       rays.sample(sample_size(meas), seed))
        fit, _ = variants.fit_best_variant(cls, data, fixed)
        done.append(variants.plain(cls, fit.effect))
    if len(done) > 1 and sun_fit is None and not lk.moving(done):
        # None moves the rays: the last match above (``geometry`` of the base and the
        # effects before the last) is the base's; the model without them on its sample.
        data = fit_data.make_fit_data(model, base, rays.sample(sample_size(meas), seed))
        done = variants.refit_in_turn(data, done, fixed_of)
    return done, sun_fit


def sunlight_of_recording(m: Matching, residual_m: np.ndarray, sigma_m: np.ndarray) -> SunFit:
    """The receiver factor of ``sunlight`` from the false returns among the measured points
    (``m``: predicted under the recording's sun; residual and sigma (m) under the model)."""
    meas = m.meas
    return fit_sunlight(m.pred.ctx, short_points(meas.range_m, residual_m, sigma_m,
                                                 m.pred.ctx.material, meas.directions,
                                                 meas.cloud))


def recording_sun(opts: CompareOptions, scenario: Scenario,
                  meas: Measurements) -> SunTrack | None:
    """The sun directions the bag carries (``opts.sun_topic``, else SUN_TOPIC if present),
    on the measurements' clock; None without. The scenario's ``sun:`` section, if any,
    supplies the irradiance and the Earth; the recording the direction."""
    topic = opts.sun_topic or SUN_TOPIC
    bag = side_bag(opts.bag, opts.poses)       # a pcap's sun comes from its poses bag
    if bag is None:
        if opts.sun_topic is not None:
            raise MeasurementError(f'--sun-topic: {opts.bag} with poses {opts.poses} holds no '
                                   'bag to read the sun directions from (give --poses BAG)')
        return None
    try:
        track = read_sun_track(bag, scenario.config.sun, topic, meas.epoch_s)
    except BagContentError as exc:
        raise MeasurementError(f'{exc} (choose the topic with --sun-topic)') from None
    if track is None and opts.sun_topic is not None:
        with open_bag(bag) as reader:
            topics = ', '.join(f'{name} ({info.msgtype})'
                               for name, info in sorted(reader.topics.items()))
        raise MeasurementError(
            f'bag {bag} has no sun directions on {opts.sun_topic!r} (--sun-topic: '
            f'geometry_msgs/msg/Vector3Stamped toward the sun, lidar frame); topics in the '
            f'bag: {topics}')
    return track


def geometry(model: Model, effects: list[Effect]):
    """The simulator that casts the model's rays: the ray geometry of ``effects`` only
    (pose time, footprint); their hooks are applied by the likelihood."""
    return model.simulator(effects=[lk.RaysOnly(e) for e in lk.moving(effects)])


def rays_of(m: Matching, measured_power_w: np.ndarray | None,
            model: Model | None = None) -> fit_data.RaySet:
    """The matched and unmatched rays of ``m``; with ``model``, how many shots missed the
    target per unmatched point (``shots.py``)."""
    missed = (missed_per_unmatched(m.meas, m.matched, len(model.simulator().shots))
              if model is not None else None)
    return fit_data.RaySet(m.meas, np.flatnonzero(m.matched), np.flatnonzero(~m.matched),
                            pred=m.pred, measured_power_w=measured_power_w,
                            missed_per_unmatched=missed)


def with_materials(pred: Prediction, materials: MaterialsConfig) -> Prediction:
    """The prediction with other per-material bias and sigma (same rays, no raycast)."""
    mat_id = np.asarray(pred.ctx.material, int)
    hit = np.asarray(pred.ctx.hit, bool) & (mat_id >= 0)
    safe = np.where(hit, mat_id, 0)
    bias = np.where(hit, materials.column('bias_m')[safe], 0.0)
    sigma = np.where(hit, materials.column('sigma_m')[safe], 0.0)
    return replace(pred, bias_m=bias, sigma_m=sigma)


class PowerFromIntensity:
    """Received power from the measured intensity (``compare/recording/intensity.py``), calibrated
    once against the model's power; None for recordings without (usable) intensity.

    Where the intensity carries the measured range (``intensity_range``: a reflectivity
    compensated with it, I ~ P r_meas^2; tested once, with the calibration), it is read at
    each ray's model range, I (r_model / r_meas)^2, before the calibration: otherwise the
    range's own noise is in the power every power-driven effect reads, and a walk fitted on
    it reads the noise back (k of the footprint's sign on an incidence bias: the fourteenth
    holdout's box, 0.19 nats/point "own part" at 0.57 m per neper). ``in_intensity``: the
    test."""

    # The test's points: at most this many matched points, evenly spaced.
    TEST_POINTS = 30_000

    def __init__(self) -> None:
        self.calibration: IntensityCalibration | None = None
        self.in_intensity: intensity_range.RangeInIntensity | None = None
        self.done = False

    def __call__(self, m: Matching) -> np.ndarray | None:
        if m.meas.intensity is None:
            return None
        if not self.done:
            sel = m.matched
            ctx = m.pred.ctx
            self.calibration = calibrate_intensity(m.meas.intensity[sel], m.meas.range_m[sel],
                                                   ctx.power_w[sel], ctx.intensity[sel],
                                                   fields.range_exponents(m.meas.fields),
                                                   cloud=m.meas.cloud[sel],
                                                   material=np.asarray(ctx.material)[sel],
                                                   unit_slope=fields.slope_known(m.meas.fields),
                                                   model_range_m=np.asarray(ctx.range_m)[sel],
                                                   incidence=np.asarray(ctx.incidence_rad)[sel])
            self.in_intensity = self._range_test(m)
            self.done = True
        if self.calibration is None or not self.calibration.usable:
            return None
        intensity, range_m = m.meas.intensity, m.meas.range_m
        if self.in_intensity is not None and (self.in_intensity.re_expressed
                                              or self.in_intensity.free):
            # Carried: moved to the model's range, then read there. Free of it: a
            # compensation for range (I ~ P r^2) read at the model's range as well, the
            # measured range's noise kept out of the power (``free_of_measured_range``).
            r_model = np.asarray(m.pred.ctx.range_m, float)
            if self.in_intensity.re_expressed:
                intensity = intensity_range.on_model_range(intensity, range_m, r_model)
            range_m = np.where(r_model > 0, r_model, range_m)
        return self.calibration.power_w(intensity, range_m, m.pred.ctx.power_w,
                                        cloud=m.meas.cloud)

    def _range_test(self, m: Matching) -> intensity_range.RangeInIntensity | None:
        """``intensity_range`` on the matched points (evenly thinned to TEST_POINTS)."""
        if self.calibration is None or not self.calibration.usable:
            return None
        idx = np.flatnonzero(m.matched)
        idx = idx[::max(1, -(-len(idx) // self.TEST_POINTS))]
        ctx = m.pred.ctx
        return intensity_range.range_in_intensity(
            np.asarray(m.meas.intensity, float)[idx], np.asarray(m.meas.range_m, float)[idx],
            np.asarray(ctx.range_m, float)[idx], np.asarray(ctx.power_w, float)[idx],
            np.asarray(m.meas.directions)[idx], np.asarray(m.meas.cloud)[idx],
            np.asarray(ctx.material, int)[idx])


def frame_period_s(meas: Measurements, scenario: Scenario) -> float:
    """The recording's frame period (s): the median step between cloud stamps, else the
    configured sensor's."""
    steps = np.diff(np.unique(meas.cloud_stamps_s))
    return float(np.median(steps)) if len(steps) else scenario.sensor.frame_period_s


def unknown_time_variance(model: Model, effects: list[Effect], meas: Measurements,
                          scenario: Scenario, seed: int) -> tuple[np.ndarray | None, float]:
    """Clouds without per-point time: the variance (m^2, per point) the unknown point
    times add, and the fitted time spread (s) (``point_times.py``); (None, 0) otherwise."""
    if meas.time_source != 'stamp':
        return None, 0.0
    sim = geometry(model, effects)
    m = match(sim, meas, model.divergence_rad, edges=False)
    rays = rays_of(m, None)
    sample = rays.sample(DIAGNOSIS_MAX_MATCHED, seed)
    data = fit_data.make_fit_data(model, effects, sample)
    on = lk.model_on_rays(data, [])
    sub = meas.subset(sample.matched)
    rr = range_rate_mps(sim, sub, fit_data.take_prediction(m.pred, sample.matched))
    period = frame_period_s(meas, scenario)
    spread = point_times.time_spread_s(data.measured_range_m - on.expected_range_m, on.sigma_m,
                                       np.asarray(data.baseline.ctx.material, int), rr, period)
    if spread <= 0:
        return None, 0.0
    rr_all = np.full(len(meas), np.nan)
    hit = np.flatnonzero(m.matched)
    rr_all[hit] = range_rate_mps(sim, meas.subset(hit), fit_data.take_prediction(m.pred, hit))
    return point_times.extra_variance_m2(rr_all, spread), spread


def _stamp_place(diag, decision, cands, meas: Measurements, scenario: Scenario):
    """Clouds without a per-point time field whose named time offset is the stamp's place
    in the scan (``stamp_place.py``), or None."""
    if decision.missing != 'time_offset' or meas.time_source not in ('stamp', 'scan pattern'):
        return None
    cand = next(c for c in cands if c.name == 'time_offset')
    if cand.effect is None:
        return None
    period = frame_period_s(meas, scenario)

    def total_nll(effect):
        nll = lk.point_nll(diag.full, lk.model_on_rays(diag.full, [effect]))[0]
        return float(np.sum(nll))
    return stamp_place.stamp_place(total_nll, float(cand.effect.params.dt_s), period,
                                   diag.z_crit ** 2, len(diag.rays.matched),
                                   diagnosis.MIN_PRACTICAL_GAIN,
                                   stamp_place.PLACES if meas.time_source == 'stamp'
                                   else stamp_place.SCAN_PLACES)


@dataclass
class Inputs:
    """What the load stage reads: the scenario, the measurements on the model's scan
    times, the recording's sun, the scenario's and the user's effects, the model."""

    scenario: Scenario
    meas: Measurements
    sun: SunTrack | None
    scenario_effects: list[Effect]
    user: list[Effect]
    model: Model
    pose_fit: bool = False        # --effect pose_error: correct the reference pose per cloud
    # Returns from something in front of the target, left out of meas (``occlusion.py``).
    occlusion: occ.Occlusion | None = None
    # Ghost returns of the adjacent laser, left out of meas (``crosstalk.py``).
    crosstalk: xtalk.Crosstalk | None = None
    # Later returns of a shot (a multi-return receiver), left out of meas (``multiple_returns.py``).
    multiple_returns: mret.MultipleReturns | None = None


@dataclass
class Calibrated:
    """The match and materials stages: every analysed ray matched under the model (and
    its residual), the per-material statistics and refit, and the headline figures."""

    model: Model                  # materials refit with --fit
    matching: Matching            # residual_m: under ``model``
    configured: Matching          # residual_m: materials as configured
    rays: fit_data.RaySet
    residual_m: np.ndarray
    sigma_m: np.ndarray
    stats: list
    refit: MaterialsConfig
    nll: float
    rmse_m: float
    calibrated: tuple[float, float, float]    # nll, rmse (m), robust sigma (m)


@dataclass
class Analysed:
    """The diagnosis sample (matched and unmatched points drawn at random, with their
    neighbourhoods and silhouette distances) and the residual's feature attribution."""

    sample: fit_data.RaySet
    picked: np.ndarray            # indices into the measurements: the sample's points
    isolated: np.ndarray          # (len(meas),) bool
    local: Matching               # the sample as a Matching of its own (features, report)
    residual_m: np.ndarray        # matched sample points, per-material offset removed
    values: dict                  # feature values
    labels: dict
    attribution: features.Attribution
    grazing_left_out: int = 0     # matched rays below pose_error.MIN_COS left out (--fit pose)
    # The intensity's test for the measured range in it (None: no usable intensity).
    range_in_intensity: intensity_range.RangeInIntensity | None = None


@dataclass
class Diagnosed:
    """The candidates stage: the scored candidates, the decision, the stamp place and
    reference-pose tests, and the figures of the points the candidates were fitted on."""

    cands: list
    decision: diagnosis.Decision
    stamp: object | None
    pose: object | None
    before: tuple[float, float, float]
    full: object | None = None          # the diagnosed points' FitData (lk.FitData)
    z_crit: float = float(norm.isf(diagnosis.FAMILY_ALPHA / 6))
    pose_on_top: list = field(default_factory=list)   # what the pose test had in the model
    # Whether the named range term stands in for a bias of range alone (``range_alone``).
    range_alone: object | None = None
    # The named effects against the target moved along the line of sight
    # (``Diagnosis.weigh_on_ray_footing``), where it was asked.
    line_of_sight: dict | None = None
    # The recording's mean angular velocity over its two halves (``spin_halves``, deg/s).
    spin_dps: np.ndarray | None = None


@dataclass
class Plan:
    """The separation plan of a tie (``plan.py``): every candidate recording's expected
    separation, best first, and the best as ``plan.yaml``."""

    rows: list[dict]
    pair: list[str]
    yaml: str
    error: str | None = None      # the plan is advice: a failure is noted, not fatal


def run_compare(opts: CompareOptions) -> CompareResult:
    """The comparison loop (module doc): each stage a function below."""
    stage = Stages(opts.progress)
    opts.out = Path(opts.out)
    with stage('load'):
        inp = load_inputs(opts)
    with stage('occlusion, crosstalk, later returns'):
        inp = leave_out_occluded(inp)
    power = PowerFromIntensity()
    with stage('point times'):
        extra_var, time_spread = unknown_time_variance(inp.model, inp.scenario_effects,
                                                       inp.meas, inp.scenario, opts.seed)
    fitted: list[Effect] = []
    sun_fit = None
    user = inp.user
    # Neighbourhoods of the points: directions and clouds, whatever the pose.
    blocks = neighbours.blocks(inp.meas.directions, inp.meas.cloud) if inp.pose_fit else None
    if opts.fit and user and inp.pose_fit:
        # The reference pose first: fitted on an uncorrected pose, an effect takes what
        # the pose error leaves at silhouettes (incidence from a drifting pose), and the
        # correction after it leaves the effect wrong (the fifth holdout). Corrected
        # again below on top of the fitted effects.
        with stage('reference pose', 'before the effects'):
            m0, r0 = match_rays(inp.model, inp.scenario_effects, inp.meas, power, extra_var,
                                opts)
            *_, moved, _ = correct_reference_pose(inp.model, inp.scenario_effects, m0, r0,
                                                  inp.meas, power, opts, blocks)
            inp = replace(inp, meas=moved)
    if opts.fit and user:
        with stage('fit effects', ', '.join(e.name for e in user)):
            user, sun_fit = fit_user_effects(inp.model, inp.scenario_effects, user, inp.meas,
                                             power, extra_var, opts.seed)
            fitted = user
    effects = inp.scenario_effects + user
    with stage('match', f'{len(inp.meas)} rays'):
        matching, rays = match_rays(inp.model, effects, inp.meas, power, extra_var, opts)
    pose_fit = None
    if inp.pose_fit:
        with stage('reference pose', f'{len(inp.meas.cloud_stamps_s)} clouds'):
            matching, rays, moved, pose_fit = correct_reference_pose(
                inp.model, effects, matching, rays, inp.meas, power, opts, blocks)
            inp = replace(inp, meas=moved)
    with stage('materials'):
        cal = calibrate_materials(inp.model, effects, matching, rays, opts.fit,
                                  None if pose_fit is None or pose_fit.passes
                                  else pose_fit.correction_m)
    sunlight = None
    if inp.sun is not None:
        with stage('sunlight', f'{len(inp.sun.t_s)} sun directions'):
            sunlight = sunlight_stage(cal, effects, inp.sun, sun_fit, opts)
    with stage('neighbours'):
        sample, picked, isolated = diagnosis_sample(cal.rays, inp.meas, opts.seed)
        sample, grazing = on_corrected_pose(sample, cal.matching.pred, pose_fit)
        picked = np.sort(np.concatenate([sample.matched, sample.unmatched]))
    with stage('features', f'{len(sample.matched)} matched points'):
        ana = replace(attribute(cal, effects, inp.meas, sample, picked, isolated, opts.seed,
                                power.in_intensity),
                      grazing_left_out=grazing)
    classes = candidate_classes(opts, effects)
    if classes:
        with stage('candidates', ', '.join(c.name for c in classes)):
            diag = diagnose(cal.model, effects, ana, classes, inp.meas, inp.scenario,
                            sunlight, opts.seed, cal.rays)
        decision, pose = pose_beyond_a_bound(diag.decision, diag.pose, fitted)
        decision, pose = pose_beside_a_stand_in(decision, pose, diag.range_alone)
        decision, pose = pose_against_range_alone(decision, pose, diag.z_crit)
        diag = replace(diag, decision=decision, pose=pose)
    else:
        diag = Diagnosed([], diagnosis.Decision(None, []), None, None, cal.calibrated)
    plan = None
    tied = tied_pair(diag)
    rival = pose_rival(diag)
    if rival and opts.plan:
        plan = pose_range_plan(opts, inp, cal, effects, rival)
    elif (motion := pose_motion_rival(diag)) and opts.plan:
        plan = pose_motion_plan(opts, inp, effects, motion)
    elif tied and opts.plan:
        with stage('plan', ' against '.join(c.name for c in tied)):
            try:
                plan = separation_plan(opts, inp, cal, effects, diag, tied)
            except Exception as exc:  # noqa: BLE001 - advice must not stop the comparison
                plan = Plan([], [c.name for c in tied], '', f'{type(exc).__name__}: {exc}')
    summary = build_summary(opts, inp, effects, fitted, cal, ana, diag, sunlight, rays,
                            time_spread, power, pose_fit, plan)
    return write_outputs(opts, summary, stage, inp, effects, fitted, cal, ana, diag, plan)


def tied_pair(diag: Diagnosed) -> list:
    """The first two confounded candidates with a fitted effect (none without a tie)."""
    by_name = {c.name: c for c in diag.cands}
    tied = [by_name[n] for n in diag.decision.confounded_with
            if n in by_name and by_name[n].effect is not None]
    return tied[:2] if len(tied) >= 2 and diag.full is not None else []


def pose_rival(diag: Diagnosed) -> str | None:
    """The range error of the sensor tied with the reference pose, if any (of a walk
    and an incidence bias tied with it together, ``pair_against_moved_target``, the
    first: a static target on a surveyed pose separates the pose from either)."""
    tie = diag.decision.confounded_with
    if diagnosis.POSE_ERROR not in tie:
        return None
    return next((n for n in tie if n in (*diagnosis.POSE_RIVALS, diagnosis.RANGE_OF_RANGE,
                                         *power_incidence.PAIR)), None)


def pose_motion_rival(diag: Diagnosed) -> str | None:
    """The effect tied with the reference pose that a faster tumble or a still target
    separates from it (``plan.MOTION_RIVALS``: a clock offset, lasers off their
    directions), if the tie is of those two alone."""
    tie = diag.decision.confounded_with
    if len(tie) != 2 or diagnosis.POSE_ERROR not in tie:
        return None
    other = next(n for n in tie if n != diagnosis.POSE_ERROR)
    return other if other in sep_plan.MOTION_RIVALS else None


def recorded_span(meas: Measurements, scenario: Scenario) -> tuple[float, float]:
    """(s) the recording's first cloud stamp and the end of its last frame."""
    stamps = meas.cloud_stamps_s
    return float(stamps.min()), float(stamps.max()) + frame_period_s(meas, scenario)


def own_motion(inp: Inputs) -> 'sep_plan.Recording':
    """The recording's own motion as a scenario trajectory (``plan.recorded_motion``),
    over its span (``recorded_span``)."""
    meas, scenario = inp.meas, inp.scenario
    return sep_plan.recorded_motion(meas.poses, *recorded_span(meas, scenario),
                                    scenario.sensor.frame_period_s,
                                    getattr(meas.poses, 't_s', None))


def spin_halves(meas: Measurements, scenario: Scenario) -> np.ndarray:
    """(2, 3) the recording's mean angular velocity (deg/s, lidar frame) over the first
    and the second half of its span (``plan.recorded_motion``)."""
    t0, t1 = recorded_span(meas, scenario)
    mid = 0.5 * (t0 + t1)
    times = getattr(meas.poses, 't_s', None)
    out = []
    for a, b in ((t0, mid), (mid, t1)):
        rec = sep_plan.recorded_motion(meas.poses, a, b, scenario.sensor.frame_period_s, times)
        out.append(rec.tumble_rate_dps * np.asarray(rec.tumble_axis, float))
    return np.array(out)


def sensor_and_materials(scenario) -> tuple[Path, Path]:
    """The scenario's sensor and materials files, resolved against its own folder (a
    plan.yaml names them)."""
    base_dir = scenario.source.parent if scenario.source else config_path('.')
    return (resolve(scenario.config.sensor, base_dir),
            resolve(scenario.config.materials, base_dir))


def pose_motion_plan(opts: CompareOptions, inp: Inputs, effects: list[Effect],
                     rival: str) -> Plan:
    """The recordings that separate ``rival`` (a clock offset, lasers off their
    directions) from a reference pose error (``plan.pose_motion_plan``): the target
    tumbling faster, and static on a surveyed pose."""
    rows, text = sep_plan.pose_motion_plan(own_motion(inp), inp.scenario.seed,
                                           Path(opts.mesh).resolve(),
                                           *sensor_and_materials(inp.scenario), effects, rival)
    return Plan(rows, [diagnosis.POSE_ERROR, rival], text)


def pose_range_plan(opts: CompareOptions, inp: Inputs, cal: Calibrated,
                    effects: list[Effect], rival: str) -> Plan:
    """The recordings that separate a reference pose from a range error of the sensor
    (``plan.pose_range_plan``): a static target on a surveyed pose, near and far."""
    scenario = inp.scenario
    rows, text = sep_plan.pose_range_plan(own_motion(inp), rival, scenario.seed,
                                          Path(opts.mesh).resolve(),
                                          *sensor_and_materials(scenario), effects,
                                          scenario.sensor.frame_period_s)
    return Plan(rows, [diagnosis.POSE_ERROR, rival], text)


def separation_plan(opts: CompareOptions, inp: Inputs, cal: Calibrated, effects: list[Effect],
                    diag: Diagnosed, tied: list) -> Plan:
    """Which recording would separate the tied pair (``plan.py``): both fitted hypotheses
    (materials refit with each) flown on candidate recordings derived from this one."""
    model, scenario = cal.model, inp.scenario
    a, b = sep_plan.hypotheses(model, diag.full, [c.effect for c in tied])
    rows = sep_plan.separation_plan(model, effects, a, b, own_motion(inp), opts.seed,
                                    diag.z_crit, DIAGNOSIS_MAX_MATCHED)
    text = sep_plan.plan_yaml(rows[0], a, b, scenario.seed, Path(opts.mesh).resolve(),
                              *sensor_and_materials(scenario), effects,
                              scenario.sensor.frame_period_s)
    return Plan(rows, [a.name, b.name], text)


def load_inputs(opts: CompareOptions) -> Inputs:
    """The scenario, mesh, measurements, sun track and effects named by ``opts``."""
    scenario = load_scenario(opts.config or config_path('scenario.yaml'))
    target = load_target(opts.mesh, scenario.materials.names,
                         mesh_materials=scenario.mesh_materials)
    meas = load_measurements(opts.bag, opts.cloud_topic, opts.pose_topic, opts.max_points,
                             opts.seed, opts.intensity_field, opts.time_field, opts.laser_field,
                             poses_from=opts.poses)
    sun = recording_sun(opts, scenario, meas)
    base = scenario.source.resolve().parent if scenario.source else None
    scenario_effects = [get_effect_class(scenario_effect_spec(e.name, base))(e.params)
                        for e in scenario.config.effects]
    pose_fit = any(parse_effect_spec(spec)[0] == POSE_ERROR for spec in opts.effects)
    user = [effect_from_spec(spec) for spec in opts.effects
            if parse_effect_spec(spec)[0] != POSE_ERROR]
    if sun is None and any(isinstance(e, Sunlight) for e in user):
        raise ValueError(
            f'--effect sunlight needs the sun direction, and bag {opts.bag} has none on '
            f'{opts.sun_topic or SUN_TOPIC!r} (record it as geometry_msgs/msg/Vector3Stamped '
            'toward the sun in the lidar frame, or name its topic with --sun-topic); '
            'without one, false returns are modelled by solar_background')
    if any(isinstance(e, Sunlight) for e in user):
        # One receiver: the --effect's sunlight replaces the scenario's.
        scenario_effects = [e for e in scenario_effects if not isinstance(e, Sunlight)]
    model = Model(scenario.sensor, scenario.materials, target, (), scenario.seed,
                  scenario.source.parent if scenario.source else None, sun)
    sim = model.simulator()
    # A rosette's frames on the node's clock (ROS time 0) or lidar-sim simulate's (its epoch).
    from lidar_sim_ros.offline import DEFAULT_EPOCH_S
    meas = with_scan_times(meas, sim.shots,
                           sim.shots_of_frame if varies_by_frame(sim.sensor) else None,
                           sim.frame_period_s, (0.0, DEFAULT_EPOCH_S), *scan_curve(sim.sensor))
    return Inputs(scenario, meas, sun, scenario_effects, user, model, pose_fit)


def scan_curve(sensor) -> tuple:
    """(curve, shot interval per laser in s, the figure's period in s) of a Lissajous
    array, else (None, None, None): the continuous curve ``with_scan_times`` matches
    directions to."""
    if not isinstance(sensor.scan, LissajousArrayScan):
        return None, None, None
    lasers = lissajous_lasers(sensor.scan)
    return (partial(lissajous_angles, lasers),
            sensor.frame_period_s / sensor.scan.shots_per_laser,
            figure_period_s(np.concatenate([lasers.freq_az_hz, lasers.freq_el_hz])))


# The kinds of return ``leave_out_occluded`` leaves out, as ``meas.dropped`` counts them.
LEFT_OUT_KINDS = ('occluded', 'crosstalk', 'later_returns')


def left_out_points(meas: Measurements) -> int:
    """How many returns ``leave_out_occluded`` left out of ``meas`` (every kind)."""
    return int(sum(meas.dropped.get(k, 0) for k in LEFT_OUT_KINDS))


def leave_out_occluded(inp: Inputs) -> Inputs:
    """The inputs without the returns of an object between the sensor and the target
    (``occlusion.occluded`` on the model's rays, scenario effects in its geometry; the
    count in ``meas.dropped['occluded']`` and ``Inputs.occlusion``), and without the
    ghost returns of the adjacent laser (``crosstalk.crosstalk_ghosts`` on the same
    rays; ``meas.dropped['crosstalk']`` and ``Inputs.crosstalk``), and without the
    later returns of a shot of a multi-return receiver (``multiple_returns.later_returns``:
    the model reports one return per shot; ``meas.dropped['later_returns']`` and
    ``Inputs.multiple_returns``; crosstalk is looked for among them first, and the
    ghosts it finds are counted there). Before anything is fitted: a hidden material's
    refit, the pose test and the diagnosis never see them."""
    meas, model = inp.meas, inp.model
    m = match(geometry(model, inp.scenario_effects), meas, model.divergence_rad, edges=False)
    expected = np.where(m.matched, m.pred.expected_range_m, np.nan)
    sigma = np.nan_to_num(np.asarray(m.pred.sigma_m, float), nan=0.0)
    mask = occ.occluded(meas.range_m, expected, far_returns.far_threshold_m(sigma),
                        meas.directions, meas.cloud)
    found = occ.summarise(mask, meas.range_m, expected, meas.cloud, len(meas.cloud_stamps_s))
    ghost, xt = xtalk.crosstalk_ghosts(meas.range_m, expected, sigma, meas.t_s, meas.cloud,
                                       meas.laser, meas.has_point_time, meas.intensity)
    ghost &= ~mask
    if ghost.sum() != xt.points:
        xt = replace(xt, points=int(ghost.sum()))
    fmap = meas.fields or {}
    source = (f'the field {fmap["returns"]!r}' if fmap.get('returns')
              else 'the SECOND_RETURN flag' if meas.return_index is not None else None)
    # Shared times tell one shot only when the recording gives them: times taken from the
    # configured scan pattern give two nearby shots the same nearest shot's time.
    later, multi = mret.later_returns(meas.range_m, meas.t_frame_s, meas.cloud, meas.laser,
                                      meas.directions, meas.return_index,
                                      meas.time_source == 'field', meas.time_quantum_s, source,
                                      exclude=ghost)
    if later.any():
        # A film near the target: its first returns in front of the model on their own
        # rays, the target's later return behind them on it (``occlusion.veiled``).
        shot = mret.shot_groups(meas.t_frame_s, meas.cloud, meas.laser, meas.directions,
                                meas.time_quantum_s)
        # Two returns of one shot, the later on the model: the noise's own far threshold
        # (FAR_SIGMAS sigma, without the FAR_MIN_M floor) tells the film from the target.
        tight = np.where(sigma > 0, far_returns.FAR_SIGMAS * sigma, np.nan)
        film = occ.veiled(meas.range_m, expected, tight, shot, later, meas.directions,
                          meas.cloud) & ~mask & ~ghost
        if film.any():
            mask = mask | film
            found = occ.summarise(mask, meas.range_m, expected, meas.cloud,
                                  len(meas.cloud_stamps_s))
    later &= ~mask
    if mask.any() and later.any():
        # The target seen through an occluder: its later return of the shot is kept.
        shot = mret.shot_groups(meas.t_frame_s, meas.cloud, meas.laser, meas.directions,
                                meas.time_quantum_s)
        behind = occ.seen_through(meas.range_m, expected, far_returns.far_threshold_m(sigma),
                                  shot, mask, later)
        if behind.any():
            later &= ~behind
            found = replace(found, seen_through=int(behind.sum()))
            multi = replace(multi, with_first=multi.with_first - int(behind.sum()),
                            behind_first_m=multi.behind_first_m if later.any() else None)
    if later.any():
        # How many lie where the model's own multipath would put a ghost (said, not kept:
        # ``multiple_returns`` module doc).
        gh = lk.ghosts_on(m.pred, Multipath()) if m.pred.ctx.scene is not None else None
        if gh is not None:
            at = later & mret.at_ghost_range(meas.range_m, gh.index, gh.range_m, gh.sigma_m,
                                             lk.UNMATCHED_Z)
            multi = replace(multi, at_model_ghost=int(at.sum()))
    if later.sum() != multi.points:
        multi = replace(multi, points=int(later.sum()))
    inp = replace(inp, occlusion=found, crosstalk=xt, multiple_returns=multi)
    left = dict(zip(LEFT_OUT_KINDS, (found.points, xt.points, multi.points)))
    if not any(left.values()):
        return inp
    dropped = {**meas.dropped, **{k: n for k, n in left.items() if n}}
    kept = replace(meas.subset(~(mask | ghost | later)), dropped=dropped)
    return replace(inp, meas=kept)


def correct_reference_pose(model: Model, effects: list[Effect], matching: Matching,
                           rays: fit_data.RaySet, meas: Measurements,
                           power: PowerFromIntensity, opts: CompareOptions,
                           blocks: np.ndarray
                           ) -> tuple[Matching, fit_data.RaySet, Measurements,
                                      pose_error.PoseError]:
    """``--effect pose_error``: the per-cloud rigid correction of the reference pose
    (``pose_error.fit_reference_pose`` on every matched point), applied to the pose
    itself and the model raycast again (``pose_error.iterate``: refit on the re-matched
    residual and compose, Gauss-Newton), so that rays near silhouettes and depth steps
    meet the surface the corrected pose puts there. Returns the re-cast matching, its
    rays, the measurements with the corrected pose track and the correction (its test
    is the first fit's). A reference error, not a sensor effect: the simulator never
    applies it. A correction that is not significant is applied as the linear range
    change of the matched points (no re-cast: its effect is within the noise).
    ``blocks``: the points' neighbourhoods (``neighbours.blocks``), the same for every
    re-cast and pose."""
    extra_var = rays.extra_var_m2
    scan = scan_clock(meas)
    # The parts of the correction it claims are asked at the diagnosis's bound (the
    # candidates' family), so that --fit claims what the diagnosis said.
    parts_z = float(norm.isf(diagnosis.FAMILY_ALPHA
                             / max(len(candidate_classes(opts, effects)), 1)))

    def fit(r: fit_data.RaySet, applied: pose_error.PoseCorrection | None = None,
            constant: bool = False) -> pose_error.PoseError:
        data = fit_data.make_fit_data(model, effects, r)
        idx = r.matched
        return pose_error.fit_reference_pose(data, meas.cloud[idx], meas.t_s[idx], blocks[idx],
                                             float(norm.isf(diagnosis.FAMILY_ALPHA)),
                                             diagnosis.MIN_PRACTICAL_GAIN, opts.seed,
                                             applied=applied, rate=has_point_times(meas),
                                             constant=constant, scan=scan,
                                             parts_z_crit=parts_z,
                                             step_only=applied is not None,
                                             orientations=False)

    def rematch(corr: pose_error.PoseCorrection):
        moved = replace(meas, poses=pose_error.CorrectedPoses(meas.poses, corr))
        m, r = match_rays(model, effects, moved, power, extra_var, opts)
        return m, r, moved

    # Per cloud or one for the whole recording: the larger held-out gain, as the
    # diagnosis decides it (``Diagnosis.judge_pose``); an extrinsic error fitted per
    # cloud without the materials' configured ranges (``pose_error.explains_material_
    # offsets``) leaves most of it in the materials' offsets.
    first = max((fit(rays), fit(rays, constant=True)),
                key=lambda p: (p.significant, p.gain))
    if not (first.significant or first.joint):
        # Nothing to correct beyond noise: the linear range change, no re-cast (runtime).
        # One correction that took the materials' common offset (``PoseError.joint``: a
        # target recorded nearer or farther) is re-cast even so: its own test is linear
        # and the diagnosis weighs it raycast (``Diagnosis.weigh_line_of_sight``), and
        # applied linearly it leaves the limbs' 1 / cos(incidence) to incidence_angle.
        pred = with_range_correction(matching.pred, rays.matched, first.correction_m)
        return replace(matching, pred=pred), replace(rays, pred=pred), meas, first
    start = pose_error.PoseCorrection.identity(
        np.zeros_like(meas.cloud) if first.constant else meas.cloud, meas.t_s)
    (matching, rays, moved), _, pose = pose_error.iterate(
        first, start, rematch, lambda state, corr: fit(state[1], corr, first.constant),
        pose_error.CONSTANT_RECAST_PASSES if first.constant else pose_error.RECAST_PASSES)
    return matching, rays, moved, pose


def scan_clock(meas: Measurements) -> ScanClock | None:
    """The recording's time base within each cloud's scan (``scan_clock.ScanClock``), for
    one rate of the reference pose for the recording, on the pose track's sample times;
    None without point times."""
    if not has_point_times(meas):
        return None
    return ScanClock.of(meas.cloud, meas.t_s, meas.cloud_stamps_s,
                        getattr(meas.poses, 't_s', None))


def has_point_times(meas: Measurements) -> bool:
    """Whether each point has its own time (a time field or the scan pattern), so that
    a reference pose drifting within a cloud can be told from a rigid one."""
    return meas.time_source in ('field', 'scan pattern')


def with_range_correction(pred: Prediction, idx: np.ndarray,
                          correction_m: np.ndarray) -> Prediction:
    """``pred`` with a reference-pose range correction (m) added to the range bias of the
    rays ``idx`` (the matched ones): the linear form of a corrected pose."""
    bias = np.array(pred.bias_m, float, copy=True)
    bias[idx] += correction_m
    return replace(pred, bias_m=bias)


def match_rays(model: Model, effects: list[Effect], meas: Measurements,
               power: PowerFromIntensity, extra_var: np.ndarray | None,
               opts: CompareOptions) -> tuple[Matching, fit_data.RaySet]:
    """Every analysed ray matched to the model's target (raycast with the effects' ray
    geometry); an error naming the inputs when (almost) none hit."""
    matching = match(geometry(model, effects), meas, model.divergence_rad, edges=False)
    rays = replace(rays_of(matching, power(matching), model), extra_var_m2=extra_var)
    if len(rays.matched) < 10:
        raise ValueError(
            f'only {len(rays.matched)} of {len(meas)} measured rays hit the target mesh '
            f'{opts.mesh}: check the mesh, the pose topic {opts.pose_topic!r} (target body '
            f'pose in the lidar frame) and that the clouds are in the lidar frame')
    return matching, rays


def calibrate_materials(model: Model, effects: list[Effect], matching: Matching,
                        rays: fit_data.RaySet, fit: bool,
                        range_correction_m: np.ndarray | None = None) -> Calibrated:
    """Per-material bias/sigma as measured vs configured; with ``fit`` the model takes
    the refit materials (as the paper's Table 2 calibration); the headline figures.
    ``range_correction_m``: a reference-pose correction per matched point, kept in the
    range bias when the materials' biases are replaced."""
    pred, sel = matching.pred, matching.matched
    residual, sigma = model_residuals(fit_data.make_fit_data(model, effects, rays), rays)
    stats = mat.material_stats(model.materials, replace(pred, sigma_m=sigma), residual, sel,
                               far_returns.far_threshold_m(sigma))
    refit = mat.refit_materials(model.materials, stats)
    configured = replace(matching, residual_m=residual)
    if fit:
        # --fit estimates the model's free parameters: the effects' and, as in the
        # paper's Table 2 calibration, each material's range bias and sigma.
        model = replace(model, materials=refit)
        pred = with_materials(pred, refit)
        if range_correction_m is not None:
            pred = with_range_correction(pred, rays.matched, range_correction_m)
        matching = replace(matching, pred=pred)
        rays = replace(rays, pred=pred)
    everything = fit_data.make_fit_data(model, effects, rays)
    residual, sigma = model_residuals(everything, rays)
    matching = replace(matching, residual_m=residual)
    # Headline: the model (materials as configured, or refit with --fit). Calibrated:
    # each material's offset and sigma scale profiled out (what --fit delivers).
    nll, rmse, _ = lk.evaluate(everything, [], profile_materials=False)
    return Calibrated(model, matching, configured, rays, residual, sigma, stats, refit, nll,
                      rmse, variants.calibrated_figures(everything, []))


def sunlight_stage(cal: Calibrated, effects: list[Effect], sun: SunTrack,
                   sun_fit: SunFit | None, opts: CompareOptions) -> dict:
    """summary.json's ``sunlight``: the receiver factor fitted from the false returns."""
    if sun_fit is None:
        sun_fit = sunlight_of_recording(cal.matching, cal.residual_m, cal.sigma_m)
    in_model = [e.params.background_scale for e in effects if isinstance(e, Sunlight)]
    return summary_section(sun_fit, opts.sun_topic or SUN_TOPIC, len(sun.t_s),
                           in_model[-1] if in_model else None)


def diagnosis_sample(rays: fit_data.RaySet, meas: Measurements,
                     seed: int) -> tuple[fit_data.RaySet, np.ndarray, np.ndarray]:
    """At most ``sample_size`` matched (and as many unmatched) points with their
    neighbourhoods: (sample, its point indices, isolated mask over the measurements)."""
    sample = rays.sample(sample_size(meas), seed)
    picked = np.sort(np.concatenate([sample.matched, sample.unmatched]))
    isolated = np.zeros(len(meas), bool)
    isolated[picked] = neighbours.isolated(meas.directions, meas.range_m, meas.cloud, picked)
    sample = replace(sample, isolated=isolated,
                     blocks=neighbours.blocks(meas.directions, meas.cloud))
    return sample, picked, isolated


def attribute(cal: Calibrated, effects: list[Effect], meas: Measurements,
              sample: fit_data.RaySet, picked: np.ndarray, isolated: np.ndarray,
              seed: int, in_intensity: intensity_range.RangeInIntensity | None = None
              ) -> Analysed:
    """Silhouette distances and range rates of the sample, and what the residual depends
    on (``features.attribute``, each material's offset and sigma scale removed).
    ``in_intensity``: whether the intensity carries the measured range
    (``PowerFromIntensity``; the measured power is then read at the model's range)."""
    model, pred, sel = cal.model, cal.matching.pred, cal.matching.matched
    sub = meas.subset(picked)
    sub_pred = fit_data.take_prediction(pred, picked)
    sim = geometry(model, effects)
    edge = edge_distance_rad(sim.target, sub, sub_pred, model.divergence_rad)
    edge_all = np.full(len(meas), np.nan)
    edge_all[picked] = edge
    sample = replace(sample, edge_rad=edge_all)
    rr = range_rate_mps(sim, sub, sub_pred)
    local = Matching(sub, sub_pred, sel[picked], cal.residual_m[picked], edge, rr)
    lsel = local.matched
    res = cal.residual_m[picked][lsel]
    sig = np.maximum(cal.sigma_m[picked][lsel], 1e-6)
    offset, scale = lk.material_nuisance(res, sig, np.asarray(sub_pred.ctx.material[lsel], int),
                                         np.isfinite(res))
    res = res - offset
    values = features.feature_values(local)
    labels = {}
    if cal.rays.measured_power_w is not None:
        # The measured power, not the raw intensity: a range-compensated reflectivity
        # is computed with the measured range and would leak its noise to the
        # attribution (read at the model's range where it carries the measured range:
        # ``PowerFromIntensity``).
        mp = cal.rays.measured_power_w[picked][lsel]
        values['intensity'] = np.log10(np.where(np.isfinite(mp) & (mp > 0), mp,
                                                np.nanmin(mp[mp > 0]) if np.any(mp > 0)
                                                else 1e-12))
        labels['intensity'] = (features.POWER_LABEL if in_intensity is None
                               or not in_intensity.re_expressed
                               else features.POWER_LABEL_MODEL_RANGE)
    near = ~beyond_the_target(np.asarray(sub.range_m, float)[lsel], res,
                              cal.residual_m[picked][lsel],
                              far_returns.far_threshold_m(sig, scale),
                              np.asarray(sub.cloud)[lsel])
    attribution = features.attribute({k: v[near] for k, v in values.items()}, res[near],
                                     (res / (sig * scale))[near], seed,
                                     sample.blocks[picked][lsel][near])
    return Analysed(sample, picked, isolated, local, res, values, labels, attribution,
                    range_in_intensity=in_intensity)


def beyond_the_target(range_m: np.ndarray, residual_m: np.ndarray, raw_residual_m: np.ndarray,
                      threshold_m: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """Matched points far beyond the noise (|residual| > ``threshold_m``) whose measured
    range lies outside the span of ranges the target model has in their cloud (nearer
    than its nearest surface or farther than its farthest, by the threshold): a surface
    that is not the target (a cable or a fixture in front), or a false return. They are
    an outlier's business, not a shape of the residual: left in, the structure a bias or
    noise effect must explain (``share_veto``) would be theirs. Points far off within
    the target's span (a depth step the footprint straddles) stay."""
    expected = range_m - raw_residual_m
    far = np.abs(residual_m) > threshold_m
    out = np.zeros(len(range_m), bool)
    for c in np.unique(cloud):
        sel = cloud == c
        e = expected[sel][np.isfinite(expected[sel])]
        if not len(e):
            continue
        r, t = range_m[sel], threshold_m[sel]
        out[sel] = far[sel] & ((r < e.min() - t) | (r > e.max() + t))
    return out


def candidate_classes(opts: CompareOptions, effects: list[Effect]) -> list[type[Effect]]:
    """The effects to diagnose: ``--candidates`` or the catalogue, less those in the model."""
    in_model = {e.name for e in effects}
    classes = ([get_effect_class(parse_effect_spec(s)[0]) for s in opts.candidates]
               if opts.candidates is not None else list(catalogue().values()))
    return [c for c in classes if c.name not in in_model]


def rival_classes(effects: list[Effect], classes: list[type[Effect]]) -> list[type[Effect]]:
    """The range terms (POSE_RIVALS) and surface offsets (GEOMETRY_RIVALS) to weigh against
    the decision: those neither in the model (``effects``) nor already scored as a
    candidate (``classes``, e.g. asked for with --candidates): one scored twice would tie
    with itself."""
    taken = {e.name for e in effects} | {c.name for c in classes}
    return [get_effect_class(n) for n in (*diagnosis.POSE_RIVALS, *diagnosis.GEOMETRY_RIVALS)
            if n not in taken]


def diagnose(model: Model, effects: list[Effect], ana: Analysed, classes: list[type[Effect]],
             meas: Measurements, scenario: Scenario, sunlight: dict | None,
             seed: int, rays: fit_data.RaySet) -> Diagnosed:
    """Score every candidate, decide (``diagnosis``), test the reference pose and the
    stamp's place, fit the best few on all the sampled points."""
    sample = ana.sample
    diag = diagnosis.Diagnosis(model, effects, sample, seed)
    diag.set_family(len(classes))
    cands = [diag.score(c) for c in classes]
    for c in cands:
        diag.share_veto(c, ana.attribution)
    cands = diagnosis.rank(cands)
    decision = diag.decide(cands)
    in_model = {e.name for e in effects}
    rivals = [get_effect_class(n) for n in diagnosis.POSE_RIVALS if n not in in_model]
    decision, weighed = diag.weigh_rivals(decision, cands, rival_classes(effects, classes),
                                          ana.attribution)
    cands = diagnosis.rank(cands + weighed)

    # The pose tests' points: the sample, or every matched point where the sample holds
    # too few a cloud for six parameters each (``pose_points``).
    # One FitData for them all: the tests on top of the same effects share their casts.
    tested = pose_points(rays, sample, meas)
    tested_data = (diag.full if tested is sample
                   else fit_data.make_fit_data(model, effects, tested))
    scan = scan_clock(meas)

    def pose_test(on_top: list[Effect], constant: bool = False,
                  data: lk.FitData | None = None,
                  orientations: bool = True) -> pose_error.PoseError:
        idx = tested.matched
        return pose_error.fit_reference_pose(
            tested_data if data is None else data, meas.cloud[idx], meas.t_s[idx],
            sample.blocks[idx], diag.z_crit, diagnosis.MIN_PRACTICAL_GAIN, seed,
            on_top, rate=has_point_times(meas), constant=constant, scan=scan,
            orientations=orientations)
    recast_cache: dict = {}

    def recast(pose: pose_error.PoseError):
        """The diagnosis on the pose-corrected model (one re-cast per kind of correction,
        per cloud or constant, and run: the pose test without effects on top is the same
        fit wherever it is asked). The correction a candidate is weighed against is fitted
        on every matched point (``rays``), as --effect pose_error --fit fits it: six (or,
        with a rate, twelve) parameters per cloud held out on the diagnosis sample's few
        hundred points a cloud lose to their own noise what a drift within the cloud
        gains; and the candidates are scored on a sample drawn anew from the re-cast
        matching (``recast_all_points``), as a --fit run draws it. Whether the pose is
        off stays the sample's test (``pose``)."""
        return recast_with_rays(pose)[:2]

    def recast_with_rays(pose: pose_error.PoseError):
        """``recast``'s diagnosis and correction, and the re-cast matching's rays."""
        if pose.constant not in recast_cache:
            diag_p, report, moved = recast_all_points(model, effects, rays, sample, meas,
                                                      all_points_pose(pose.constant),
                                                      len(classes), seed, pose.constant)
            # The test stays the sample's; its gain is the rigid one's where the rate
            # showed on every matched point only (``PoseError.rate_in_test``).
            recast_cache[pose.constant] = (diag_p, replace(
                report, gain=pose.gain, z=pose.z, significant=pose.significant,
                rate_in_test=bool(pose.rate_supported or not report.rate_supported)), moved)
        return recast_cache[pose.constant]

    def same_points(pose: pose_error.PoseError, effect: Effect | None) -> tuple[float, float]:
        """As --fit leaves them, on the same points: NLL per point of the
        pose-corrected model (raycast again, ``recast``) and of the model with ``effect``
        (as fitted; None: the model without it), on the diagnosis sample's matched
        points that the corrected pose still matches (each sample's own NLL would differ
        by the draw alone)."""
        moved = recast_with_rays(pose)[2]
        common = np.intersect1d(sample.matched, moved.matched)
        none = np.zeros(0, dtype=common.dtype)
        on_pose = variants.calibrated_figures(
            fit_data.make_fit_data(model, effects, replace(moved, matched=common,
                                                            unmatched=none)), [])[0]
        with_effect = variants.calibrated_figures(
            fit_data.make_fit_data(model, effects, replace(sample, matched=common,
                                                            unmatched=none)),
            [effect] if effect is not None else [])[0]
        return on_pose, with_effect

    def all_points_pose(constant: bool) -> pose_error.PoseError:
        if tested is not sample:
            return pose_test([], constant)        # the same fit: every matched point
        idx = rays.matched
        return pose_error.fit_reference_pose(
            fit_data.make_fit_data(model, effects, rays), meas.cloud[idx], meas.t_s[idx],
            sample.blocks[idx], diag.z_crit, diagnosis.MIN_PRACTICAL_GAIN, seed,
            rate=has_point_times(meas), constant=constant, scan=scan)
    # Points without a time within their cloud: a residual growing with the row is a
    # time within the exposure they do not carry (``row_clock``).
    row_test = (None if scan is not None else lambda clock: row_clock.row_time_test(
        tested_data, sample.blocks[tested.matched], diag.z_crit,
        diagnosis.MIN_PRACTICAL_GAIN, row_clock.clock_column_m(tested_data, clock), seed))
    decision = diag.judge_pose(pose_test, cands, decision, recast,
                               lambda on_top: pose_test(on_top, constant=True), same_points,
                               row_test)

    def on_constant_pose(effect: Effect):
        """The diagnosis re-cast with one correction for the recording fitted on every
        matched point on top of ``effect`` (each pass too), its report (the sample's
        test on top of ``effect``) and the per-cloud test on the re-cast matching."""
        idx = rays.matched
        fitted = pose_error.fit_reference_pose(
            fit_data.make_fit_data(model, effects, rays), meas.cloud[idx], meas.t_s[idx],
            sample.blocks[idx], diag.z_crit, diagnosis.MIN_PRACTICAL_GAIN, seed, [effect],
            rate=has_point_times(meas), constant=True)
        diag_c, report, moved = recast_all_points(model, effects, rays, sample, meas, fitted,
                                                  len(classes), seed, True, (effect,))
        test = pose_test([effect], constant=True)
        data_c = fit_data.make_fit_data(model, effects, moved)

        def per_cloud(on_top: list[Effect]) -> pose_error.PoseError:
            at = moved.matched
            return pose_error.fit_reference_pose(
                data_c, meas.cloud[at], meas.t_s[at], sample.blocks[at], diag.z_crit,
                diagnosis.MIN_PRACTICAL_GAIN, seed, on_top, rate=has_point_times(meas))
        return diag_c, replace(report, gain=test.gain, z=test.z,
                               significant=test.significant), per_cloud
    # With the pose alone, the range terms too: the constant pose on top of each.
    extra = diag.rivals_beside_pose(decision, cands, rivals, ana.attribution)
    weighed = [*weighed, *extra]
    cands = diagnosis.rank(cands + extra)
    decision = diag.range_term_beside_constant_pose(
        decision, cands, lambda on_top: pose_test(on_top, constant=True), on_constant_pose)
    constant = decision.pose is not None and decision.pose.constant
    decided = decision
    decision, scored = diag.weigh_pose_rivals(
        decision, rivals, lambda on_top: pose_test(on_top, constant=constant),
        lambda: recast(pose_test([], constant=constant))[0], {c.name: c for c in weighed},
        ana.attribution)
    cands = diagnosis.rank(cands + [c for c in scored if all(c is not w for w in weighed)])
    decision = diag.lasers_beside_rival(decided, decision, cands)
    decision = diag.offsets_beside_also(decision, cands)
    decision = diag.range_offset_beside(decision, cands, pose_test)
    # A part of one material reading off the rest, against the pose (region_offset).
    decision = region_offset.weigh_pose(decision, cands, tested_data,
                                        sample.blocks[tested.matched], pose_test, diag.z_crit,
                                        diagnosis.MIN_PRACTICAL_GAIN, seed)
    # The named sensor effects against the target moved along the line of sight, on
    # the candidates' own footing (``line_of_sight``).
    los = LineOfSight(model, effects, rays, meas, sample.blocks, diag.z_crit, len(classes),
                      seed)
    decision = diag.weigh_on_ray_footing(
        decision, cands, rivals, los.fit, los.diagnosis,
        lambda fit, explains: los.as_pose(pose_test([], constant=True), fit, explains),
        los.versus)
    cands = diagnosis.rank(cands)
    named = [c for c in cands if c.name == decision.missing and c.effect is not None]
    if decision.pose is not None:
        on_top = list(getattr(diag, 'pose_on_top', []))     # as judge_pose tested it
    elif decision.beside_pose is not None:
        # Tested on top of the named effect and its also (``range_offset_beside``).
        on_top = [n for n in (decision.missing, decision.also) if n]
    else:
        on_top = [c.name for c in named]
    pose = (decision.pose if decision.pose is not None else decision.beside_pose
            if decision.beside_pose is not None else pose_test([c.effect for c in named]))
    decision, pose = pose_that_matters(decision, pose, tested_data, meas.cloud[tested.matched])
    decision, pose = pose_across_all_points(decision, pose)
    # The pose reported is the re-cast one (``recast``): its matching of every point,
    # cached, is the corrected pose's; else raycast once more.
    decision, pose = pose_on_silhouette(decision, pose, lambda p: silhouette_of(
        model, effects, rays, meas, sample.blocks, p, diag.z_crit,
        next((moved for _, rep, moved in recast_cache.values() if rep is p), None)))
    pose = pose_left_to_faces(decision, pose, lambda: pose_test([], constant=True))
    for c in cands[:FINALIZED]:
        if (c.significant or c is cands[0]) and not np.isfinite(c.nll_after):
            diag.finalize(c)      # what a run with --effect NAME --fit would show
        if c.significant and np.isfinite(c.nll_after):
            c.false_returns = diag.false_return_budget(c)
    # A named clock against the pose drifting within the cloud, on the pose test's own
    # rays (``clock_footing``): where the points carry their own times, so that a drift
    # within the cloud is a hypothesis of its own. Without them the clock and a rigid pose
    # per cloud are weighed by ``clock_tie`` and ``rows_under_clock``.
    decision = diag.clock_off_footing(decision, cands, (lambda clock: (
        clock_footing.clock_on_pose_footing(
            tested_data, meas.cloud[tested.matched], meas.t_s[tested.matched],
            sample.blocks[tested.matched], diag.z_crit, diagnosis.MIN_PRACTICAL_GAIN,
            row_clock.clock_column_m(tested_data, clock), seed, rate=True)))
        if has_point_times(meas) else None)
    # One rigid correction for the recording reported alone, against a clock offset
    # fitted jointly with it on the same rays (``clock_beside_constant_pose``), on the
    # model that correction leaves (raycast again): what is left of a pose off by
    # centimetres is linear there, on the recorded pose it is not.
    def clock_beside_corrected(clock: Effect) -> clock_footing.ClockFooting:
        moved = recast_with_rays(decision.pose)[2]
        at = moved.matched
        data_m = fit_data.make_fit_data(model, effects, moved)
        return clock_footing.clock_on_pose_footing(
            data_m, meas.cloud[at], meas.t_s[at], sample.blocks[at], diag.z_crit,
            diagnosis.MIN_PRACTICAL_GAIN, row_clock.clock_column_m(data_m, clock), seed,
            constant=True)
    # And nested on the candidates' own footing, raycast (``clock_nested``): the pose
    # alone against the pose fitted on top of the clock, the clock alone against the
    # two, on the same points; this decides.
    # On a spin at a constant rate about a fixed axis a clock offset is one rotation
    # about that axis, which one correction for the recording takes alike: the clock has
    # no part of its own to find there, and a part the nested test finds is not the
    # clock's (``spin_clock.fixed_spin``: no clock named beside the pose; their tie
    # stands, and a pose alone has its rotation said as the clock it equals).
    spin = spin_halves(meas, scenario)
    fixed = spin_clock.fixed_spin(spin)

    def clock_nested_cast(clock: Effect, dt_joint_s: float) -> clock_nested.NestedClock:
        cast = ClockBesidePoseCast(model, effects, rays, meas, sample.blocks, type(clock),
                                   diag.z_crit, seed)
        return replace(cast.weigh(float(clock.params.dt_s), float(dt_joint_s),
                                  diagnosis.MIN_PRACTICAL_GAIN), own_part_possible=not fixed)
    decision, clock = diag.clock_beside_constant_pose(
        decision, cands, clock_beside_corrected, lambda clock: on_constant_pose(clock)[:2],
        clock_nested_cast)
    # The same where the pose test reports a correction per cloud: the clock with one
    # correction against the per-cloud correction, each charged its parameters, on
    # enough clouds for one dt's pattern over them to show (``MIN_CLOUDS_PER_CLOUD``).
    if clock is None and len(np.unique(meas.cloud)) >= clock_nested.MIN_CLOUDS_PER_CLOUD:
        def clock_per_cloud_cast(clock: Effect) -> clock_nested.PerCloudClock:
            cast = ClockBesidePerCloudCast(model, effects, rays, meas, sample.blocks,
                                           type(clock), diag.z_crit, seed)
            return cast.weigh_per_cloud(clock, diagnosis.MIN_PRACTICAL_GAIN)
        decision, clock = diag.clock_beside_per_cloud_pose(
            decision, cands, clock_per_cloud_cast, lambda clock: on_constant_pose(clock)[:2])
    if clock is not None:
        clock_beyond_rigid(clock, meas, tested.matched)
        diag.turn_beside_clock(cands)
        # The clock as scored on the corrected pose is the one the verdict quotes.
        cands = diagnosis.rank([clock if c.name == clock.name else c for c in cands])
        on_top = [clock.name]
        pose = (decision.pose if decision.pose is not None
                else pose_test([clock.effect], constant=True))
    decision = diag.clock_tie(decision, cands, meas.time_source == 'stamp')
    stamp = _stamp_place(diag, decision, cands, meas, scenario)
    decision = sunlit_decision(decision, sunlight)
    # The one gate every name passes (missing, tie, also): the rule and the NLL.
    decision = diagnosis.settle(decision, cands, diag.naming_fault, diag.tile_fault)
    # After the gate: a name it withheld (a fit at its box) leaves the pose alone.
    decision, pose = pose_left_to_pointing(decision, pose, cands, diag.finalized, pose_test,
                                           recast)
    diag.fit_together(decision, cands)
    diag.lasers_beside_named(decision, cands)
    named_effect = next((c.effect for c in cands if c.name == decision.missing), None)
    alone = named_range_alone(decision.missing, named_effect, diag.full,
                              sample.blocks[sample.matched], diag.z_crit, seed)
    return Diagnosed(cands, decision, stamp, pose, variants.calibrated_figures(diag.full, []),
                     diag.full, diag.z_crit, on_top, alone,
                     getattr(diag, 'line_of_sight', None), spin)


def clock_beyond_rigid(clock: diagnosis.Candidate, meas: Measurements,
                       points: np.ndarray) -> None:
    """What the named clock does to the pose test's points ``points`` beyond one rigid
    motion of them all (``clock_nested.clock_beyond_rigid_m``, RMS m), kept as its
    ``against_pose['beyond_rigid_m']`` (the clock that then replaces the candidate it
    came from): the only part of a clock a constant pose correction beside it cannot
    take (0 on a constant-rate turn about a fixed axis). Said, not yet decided on."""
    dt = float(getattr(clock.effect.params, 'dt_s', np.nan)) if clock.effect else np.nan
    beyond = clock_nested.clock_beyond_rigid_m(meas.xyz_m[points], meas.t_s[points],
                                               meas.poses, dt)
    clock.against_pose = {**(clock.against_pose or {}), 'beyond_rigid_m': _num(beyond)}


def named_range_alone(named: str | None, effect: Effect | None, data: lk.FitData,
                      blocks: np.ndarray, z_crit: float, seed: int
                      ) -> 'range_alone.RangeAlone | None':
    """``range_alone.weigh_range_alone`` for the named effect (``effect``: as fitted) on
    the diagnosed points ``data`` (the model without it; the power a power-driven term is
    fitted on: the measured where known and the term reads it, else the model's), or None
    where it is no range term."""
    if named not in range_alone.DRIVER or effect is None:
        return None
    model = lk.model_on_rays(data, [])
    bias = lk.model_on_rays(data, [effect]).expected_range_m - model.expected_range_m
    power = np.asarray(model.ctx.power_w, float)
    if data.measured_power_w is not None and lk.reads_measured_power(effect):
        measured = np.asarray(data.measured_power_w, float)
        power = np.where(np.isfinite(measured) & (measured > 0), measured, power)
    return range_alone.weigh_range_alone(
        named, data.measured_range_m - model.expected_range_m, model.sigma_m,
        np.asarray(model.ctx.range_m, float), power, np.asarray(model.ctx.material),
        blocks, z_crit, diagnosis.MIN_PRACTICAL_GAIN, seed, bias)


def pose_that_matters(decision: diagnosis.Decision, pose: pose_error.PoseError,
                      data: lk.FitData, cloud: np.ndarray
                      ) -> tuple[diagnosis.Decision, pose_error.PoseError]:
    """The decision and its pose, unless the pose it reports (alone or beside a named
    effect; not in a tie, not drifting within the scan) converges to a correction that,
    applied exactly, would gain less than MIN_PRACTICAL_GAIN on ``data``
    (``pose_error.applied_gain``): then the pose is not reported, and carries the
    figures (``too_small``) with its test marked failed."""
    if not pose_reported(decision, pose) or pose.rate_supported:
        return decision, pose
    gain = pose_error.applied_gain(pose, data, cloud)
    if gain >= diagnosis.MIN_PRACTICAL_GAIN:
        return decision, pose
    return withhold_pose(decision, pose, 'too_small',
                         {'applied_gain_per_matched_point': round(gain, 6)})


def pose_across_all_points(decision: diagnosis.Decision, pose: pose_error.PoseError
                           ) -> tuple[diagnosis.Decision, pose_error.PoseError]:
    """The decision and its pose, unless the pose it reports (alone or beside a named
    effect) does not hold across the surfaces' orientations: one rigid correction for
    the recording fitted on every matched point (as --fit fits it) that fails
    ``pose_error.faces_agree`` (the sample's test asked it on fewer), or a per-cloud
    correction (with its rate or not) whose held-out gain loses on a group of them
    (``pose_error.per_cloud_faces``): then the pose is not reported, its test marked
    failed."""
    if not pose_reported(decision, pose) or (pose.rate_supported and pose.constant):
        return decision, pose
    faces = pose.across_faces
    if not faces or faces['transfers']:
        return decision, pose
    return replace(decision, pose=None), replace(pose, significant=False)


def pose_on_silhouette(decision: diagnosis.Decision, pose: pose_error.PoseError,
                       test: Callable[[pose_error.PoseError], silhouette.Silhouette]
                       ) -> tuple[diagnosis.Decision, pose_error.PoseError]:
    """The decision and its pose, asked the silhouette test (``test(pose)``,
    ``silhouette_of``) where a pose is reported (alone or beside a named effect): its
    figures on the pose (``silhouette``); where the edges contradict the correction and
    each of its parts alone they can judge (``Silhouette.withholds``) the pose is not
    reported, and carries them under ``left_to_edges`` with its test marked failed. Where the edges do not support it by
    the rule, or cannot tell, the decision stands (docs/compare.md, "The silhouette test
    of a pose claim": a true per-cloud pose of 0.9 cm / 0.38 deg gains on its edges at
    z 2.2 only)."""
    if not pose_reported(decision, pose):
        return decision, pose
    sil = test(pose)
    pose = replace(pose, silhouette=sil.as_dict())
    if not sil.withholds:
        return replace(decision, pose=pose), pose
    return withhold_pose(decision, pose, 'left_to_edges', sil.as_dict())


def silhouette_of(model: Model, effects: list[Effect], rays: fit_data.RaySet,
                  meas: Measurements, blocks: np.ndarray, pose: pose_error.PoseError,
                  z_crit: float, moved_rays: fit_data.RaySet | None = None,
                  parts: bool = True) -> silhouette.Silhouette:
    """The silhouette test of ``pose``'s correction: every point raycast once more with
    it applied (one correction for the recording or one per cloud, its drift within the
    cloud if any), against ``rays`` (the recorded pose), scored on the rays whose outcome
    it changes (``silhouette.edge_gain``, ``silhouette.judge``). ``moved_rays``: every
    point's matching with the correction applied, where already cast. Where the edges
    contradict it (and ``parts``), its translation alone and its rotation alone (about
    the same centroid, no drift) are asked the same (``Silhouette.parts``)."""
    cloud = np.zeros_like(meas.cloud) if pose.constant else meas.cloud
    corr, _ = pose_error.PoseCorrection.identity(cloud, meas.t_s).compose(pose)
    if moved_rays is None:
        moved = replace(meas, poses=pose_error.CorrectedPoses(meas.poses, corr))
        m = match(geometry(model, effects), moved, model.divergence_rad, edges=False)
        moved_rays = rays_of(m, None)
    before = np.zeros(len(meas), bool)
    before[rays.matched] = True
    after = np.zeros(len(meas), bool)
    after[moved_rays.matched] = True
    on = rays.matched[::max(1, len(rays.matched) // 4000)]
    reach = silhouette.largest_motion_m(corr, meas.xyz_m[on], meas.t_s[on])
    extra = rays.extra_var_m2 if rays.extra_var_m2 is not None else 0.0

    def nll(pred) -> np.ndarray:
        sigma = np.sqrt(np.asarray(pred.sigma_m, float) ** 2 + extra)
        return silhouette.capped_nll(meas.range_m - pred.expected_range_m, sigma)
    with np.errstate(invalid='ignore'):
        gain, edge, counts = silhouette.edge_gain(
            before, after, rays.pred.expected_range_m, moved_rays.pred.expected_range_m,
            nll(rays.pred), nll(moved_rays.pred), reach)
    sil = silhouette.judge(gain, edge, blocks, counts, z_crit, diagnosis.MIN_PRACTICAL_GAIN,
                           reach)
    if sil.outcome != 'contradicts' or not parts:
        return sil
    # Contradicted: each part alone, raycast once more (a true pose beside a range error
    # the correction took too: range_cyclic_pose's 1.18 deg where the pose's is 0.43).
    alone = {'translation': replace(pose, rotation_deg=np.zeros_like(pose.rotation_deg),
                                    rate_supported=False),
             'rotation': replace(pose, translation_m=np.zeros_like(pose.translation_m),
                                 rate_supported=False)}
    return replace(sil, parts={k: silhouette_of(model, effects, rays, meas, blocks, p, z_crit,
                                                parts=False) for k, p in alone.items()})


def pose_left_to_faces(decision: diagnosis.Decision, pose: pose_error.PoseError,
                       constant_test) -> pose_error.PoseError:
    """The pose the summary carries: where nothing is named, no tie and no pose
    reported, and the per-cloud test ``pose`` holds no correction that passed on random
    halves but not across the surfaces' orientations (``pose_error.faces_agree``) nor one
    the silhouette test withheld (``left_to_edges``), the
    one correction for the recording (``constant_test()``) if it is such a one (the
    verdict then says why no pose is claimed); else ``pose``."""
    if (decision.pose is not None or decision.beside_pose is not None or decision.missing
            or decision.confounded_with or pose is None or pose.left_to_edges
            or (pose.across_faces and not pose.across_faces['transfers'])):
        return pose
    constant = constant_test()
    left = constant.across_faces and not constant.across_faces['transfers']
    return constant if left else pose


def pose_reported(decision: diagnosis.Decision, pose: pose_error.PoseError | None) -> bool:
    """Whether ``decision`` reports ``pose`` alone or beside a named effect (not in a
    tie): the pose the checks below may withhold."""
    return (decision.pose is not None and pose is decision.pose
            and diagnosis.POSE_ERROR not in decision.confounded_with)


def withhold_pose(decision: diagnosis.Decision, pose: pose_error.PoseError, why: str,
                  figures: dict) -> tuple[diagnosis.Decision, pose_error.PoseError]:
    """``decision`` without its pose, and the pose with its test marked failed, carrying
    under ``why`` (a PoseError field: ``too_small``, ``left_by_bound``,
    ``left_by_stand_in``, ``left_to_range``) ``figures`` and its test's own."""
    left = replace(pose, significant=False, **{why: {
        **figures, 'test_gain_per_matched_point': round(pose.gain, 6),
        'test_z': round(pose.z, 2), 'translation_rms_cm': round(pose.size_cm, 3),
        'rotation_rms_deg': round(pose.size_deg, 4)}})
    return replace(decision, pose=None), left


def pose_left_to_pointing(decision: diagnosis.Decision, pose: pose_error.PoseError | None,
                          cands: list, finalized, pose_test, recast
                          ) -> tuple[diagnosis.Decision, pose_error.PoseError | None]:
    """The decision and its pose, unless the pose is reported alone (nothing named, no
    tie) while lasers' pointing offsets (``laser_pointing``, fitted with the beams'
    common turn) were set aside by a test of their shape (the own part, the tiles) or
    withheld (``Decision.withheld``: a spurious offset at the fit's box on a laser that
    barely sees the target), and the two are nested one way: the pose's test
    (``pose_test(effects, constant)``, of the kind reported) fails on top of the
    offsets, and the offsets still pass the rule on the pose-corrected model
    (``recast(pose)``: the diagnosis raycast again, scored as the candidates are). The
    offsets then explain all the pose does and more (a few beams off their direction
    read as a turned target on the tiles they hit); the pose is not claimed, and
    carries the offsets' name, the figures both ways and its test's
    (``left_to_pointing``), its test marked failed. A true pose leaves the offsets
    nothing once corrected. ``finalized(c)``: the candidate fitted on all the diagnosed
    points (its ``effect``)."""
    if (not pose_reported(decision, pose) or decision.missing or decision.confounded_with
            or pose.rate_supported):
        return decision, pose
    for c in cands:
        if (c.effect is None or c.error is not None
                or (c.vetoed is None and c.name not in (decision.withheld or {}))
                or pointing.turn_of(c.variant) is None or not c.significant
                or not c.practical or not c.score > pose.gain):
            continue
        finalized(c)
        on_top = pose_test([c.effect], constant=bool(pose.constant))
        if on_top.significant:
            continue
        on_pose = recast(pose)[0].score(type(c.effect))
        if not (on_pose.significant and on_pose.practical):
            continue
        return withhold_pose(decision, pose, 'left_to_pointing', {
            'named': c.name, 'score': round(float(c.score), 6),
            'pose_gain_on_top': round(float(on_top.gain), 6),
            'pose_z_on_top': round(float(on_top.z), 2),
            'score_on_pose': round(float(on_pose.score), 6),
            'z_on_pose': round(float(on_pose.z), 2)})
    return decision, pose


def pose_beyond_a_bound(decision: diagnosis.Decision, pose: pose_error.PoseError | None,
                        fitted: list[Effect]
                        ) -> tuple[diagnosis.Decision, pose_error.PoseError | None]:
    """The decision and its pose, unless an effect ``fitted`` by --fit ended at its
    search bound (``fit.at_bounds``) and the decision reports the pose alone or beside a
    named effect (not in a tie): what the fit left is then at least partly the rest of
    that effect (or of one outside the catalogue that it stood in for), which a per-cloud
    pose takes as readily as a tracking error (a range scale leaves a range offset per
    cloud of an approach). The pose is then not reported; it carries the effects at their
    bound and its test's figures (``left_by_bound``), its test marked failed."""
    bound = {e.name: at_bounds(e) for e in fitted if at_bounds(e)}
    if not bound or not pose_reported(decision, pose):
        return decision, pose
    return withhold_pose(decision, pose, 'left_by_bound', {'effects': bound})


def pose_beside_a_stand_in(decision: diagnosis.Decision, pose: pose_error.PoseError | None,
                           alone: 'range_alone.RangeAlone | None'
                           ) -> tuple[diagnosis.Decision, pose_error.PoseError | None]:
    """The decision and its pose, unless the named range term stands in for a bias of
    range alone (``alone.stands_in``) and the pose is reported beside it (not in a tie):
    the stand-in's form does not follow that bias, so what it leaves is the rest of it, a
    range offset that changes as the range does (from cloud to cloud of an approach),
    which a per-cloud pose takes as readily as a tracking error (the same reason as
    ``pose_beyond_a_bound``). The pose is then not reported; it carries the stand-in's
    name and its test's figures (``left_by_stand_in``), its test marked failed."""
    if (alone is None or not alone.stands_in or decision.missing != alone.name
            or not pose_reported(decision, pose)):
        return decision, pose
    return withhold_pose(decision, pose, 'left_by_stand_in', {'named': alone.name})


def pose_against_range_alone(decision: diagnosis.Decision,
                             pose: pose_error.PoseError | None, z_crit: float
                             ) -> tuple[diagnosis.Decision, pose_error.PoseError | None]:
    """The decision and its pose (reported alone or beside a named effect, not in a tie;
    per cloud or one for the recording, with its rate within the clouds where it has
    one), weighed against a smooth function of range alone on the pose test's own
    halves (``PoseError.against_range``,
    ``range_alone.PoseAgainstRange``): a range error of the sensor that follows range
    moves the clouds of an approach, each at its own range, as a per-cloud pose does
    (the twelfth holdout's out_cyclic, 5 cm cos(2 pi r / 3 m), read as the tracking
    system's). The pose stays where, fitted on top of range alone, it gains beyond it by
    the rule (nested: a pose error beside such a range error stays). Where range alone
    passes the rule and explains the residual at least as well, no pose is claimed
    (``left_to_range``, outcome 'range': a range error outside the catalogue that
    follows range). Otherwise the data cannot tell the two: with nothing named, the tie
    ``confounded_with`` [pose_error, RANGE_OF_RANGE]; beside a named effect, the pose is
    not claimed (outcome 'tie')."""
    if not pose_reported(decision, pose):
        return decision, pose
    against = pose.against_range
    if against is None:
        return decision, pose
    outcome = against.outcome(z_crit, diagnosis.MIN_PRACTICAL_GAIN)
    if outcome == 'pose':
        return decision, pose
    if outcome == 'tie' and not decision.missing and not decision.also:
        return replace(decision, confounded_with=[diagnosis.POSE_ERROR,
                                                  diagnosis.RANGE_OF_RANGE]), pose
    return withhold_pose(decision, pose, 'left_to_range',
                         {'outcome': outcome, 'constant': bool(pose.constant),
                          **against.as_dict()})


def pose_points(rays: fit_data.RaySet, sample: fit_data.RaySet,
                meas: Measurements) -> fit_data.RaySet:
    """The matched points the reference pose is tested on: the diagnosis sample where its
    points a cloud pay for the per-cloud correction's parameters (the held-out cost,
    POSE_PARAMS clouds / points, at most MIN_PRACTICAL_GAIN nats per point), else every
    matched point of ``rays`` (the sample's neighbourhood blocks, no unmatched points:
    the test uses none)."""
    n_clouds = len(np.unique(meas.cloud[sample.matched]))
    cost = POSE_PARAMS * n_clouds / max(len(sample.matched), 1)
    if cost <= diagnosis.MIN_PRACTICAL_GAIN or len(rays.matched) <= len(sample.matched):
        return sample
    return replace(rays, unmatched=np.zeros(0, dtype=rays.matched.dtype),
                   blocks=sample.blocks, edge_rad=None, isolated=None)


def recast_all_points(model: Model, effects: list[Effect], rays: fit_data.RaySet,
                      sample: fit_data.RaySet, meas: Measurements,
                      pose: pose_error.PoseError, n_candidates: int, seed: int,
                      constant: bool = False, on_top: tuple[Effect, ...] = ()
                      ) -> tuple[diagnosis.Diagnosis, pose_error.PoseError, fit_data.RaySet]:
    """The diagnosis on the pose-corrected model as a ``--effect pose_error --fit`` run
    builds it: ``pose`` (a fit on every matched point of ``rays``) applied and every
    ray raycast again (``pose_error.iterate``, each step refit on every re-matched
    point), then a diagnosis sample drawn anew from the re-cast matching
    (``RaySet.sample``, the same seed). Not the old sample re-cast: it holds every
    unmatched point of the recorded pose (the rays just beyond a silhouette), and those
    the corrected pose puts on the target would enter its matched points at about ten
    times their share of the recording (all of them against one matched point in
    ``len(rays.matched) / DIAGNOSIS_MAX_MATCHED``): grazing rays at the silhouette, where
    what is left of a pose error grows with the tangent of the incidence angle, weigh
    in for an incidence-shaped residual a --fit run does not see (docs/compare.md, "A
    sensor effect against the reference pose"). ``sample`` gives the neighbourhood
    blocks. ``on_top``: effects the correction is fitted on top of at every pass (as
    ``pose`` was; they stay out of the re-cast diagnosis's model). Returns the
    diagnosis, the correction (its test ``pose``'s) and the re-cast matching's rays
    (every point)."""
    sim = geometry(model, effects)
    scan = scan_clock(meas)

    def rematch(corr: pose_error.PoseCorrection):
        moved = replace(meas, poses=pose_error.CorrectedPoses(meas.poses, corr))
        m = match(sim, moved, model.divergence_rad, edges=False)
        return m, replace(rays_of(m, rays.measured_power_w, model),
                          extra_var_m2=rays.extra_var_m2), moved

    def refit(state, applied: pose_error.PoseCorrection) -> pose_error.PoseError:
        _, r, moved = state
        idx = r.matched
        return pose_error.fit_reference_pose(fit_data.make_fit_data(model, effects, r),
                                             moved.cloud[idx], moved.t_s[idx],
                                             sample.blocks[idx], float(norm.isf(
                                                 diagnosis.FAMILY_ALPHA)),
                                             diagnosis.MIN_PRACTICAL_GAIN, seed,
                                             list(on_top), applied=applied,
                                             rate=has_point_times(meas), constant=constant,
                                             scan=scan, step_only=True)

    start = pose_error.PoseCorrection.identity(
        np.zeros_like(meas.cloud) if constant else meas.cloud, meas.t_s)
    (m, moved_rays, moved), _, report = pose_error.iterate(
        pose, start, rematch, refit,
        pose_error.CONSTANT_RECAST_PASSES if constant else pose_error.RECAST_PASSES)
    return (diagnosis_on_moved(model, effects, sim, m, moved_rays, moved, n_candidates,
                               seed, constant), report, moved_rays)


# The points the target moved along the line of sight is scored on (``LineOfSight``).
LINE_OF_SIGHT_POINTS = 20_000


def raycast_subset(n: int, seed: int) -> np.ndarray:
    """Sorted indices of the points raycast again per trial (``LineOfSight``,
    ``ClockBesidePoseCast``): all ``n`` up to LINE_OF_SIGHT_POINTS, else that many drawn
    with the run's seed; the same subset for both."""
    if n <= LINE_OF_SIGHT_POINTS:
        return np.arange(n)
    return np.sort(np.random.default_rng([seed, 37]).choice(n, LINE_OF_SIGHT_POINTS, False))


def diagnosis_on_moved(model: Model, effects: list[Effect], sim, m: Matching,
                       moved_rays: fit_data.RaySet, moved: Measurements, n_candidates: int,
                       seed: int, constant: bool) -> diagnosis.Diagnosis:
    """The diagnosis on a re-cast matching ``m`` (its rays ``moved_rays``, the
    measurements with the corrected pose ``moved``): a sample drawn anew from it
    (``recast_sample``), the edge distances cast there (``sim``: ``geometry``)."""
    fresh = recast_sample(moved_rays, moved, seed)
    if not constant:
        fresh = fitted_rays_only(fresh, m.pred)
    picked = np.sort(np.concatenate([fresh.matched, fresh.unmatched]))
    edge = np.full(len(moved), np.nan)
    edge[picked] = edge_distance_rad(sim.target, moved.subset(picked),
                                     fit_data.take_prediction(m.pred, picked),
                                     model.divergence_rad)
    diag = diagnosis.Diagnosis(model, effects, replace(fresh, edge_rad=edge), seed)
    diag.set_family(n_candidates)
    return diag


class LineOfSight:
    """The recording with the target moved (``line_of_sight``): every ray of a random
    subset of the points (LINE_OF_SIGHT_POINTS) raycast again per translation (cached),
    scored by the likelihood the candidates are scored by, and the diagnosis on every
    ray raycast with the best one."""

    def __init__(self, model: Model, effects: list[Effect], rays: fit_data.RaySet,
                 meas: Measurements, blocks: np.ndarray, z_crit: float, n_candidates: int,
                 seed: int):
        self.model, self.effects, self.rays, self.meas = model, effects, rays, meas
        self.z_crit, self.n_candidates, self.seed = z_crit, n_candidates, seed
        self.sim = geometry(model, effects)
        seen = rays.matched
        u = np.mean(meas.directions[seen], axis=0) if len(seen) else np.array([1.0, 0, 0])
        self.direction = u / max(float(np.linalg.norm(u)), 1e-12)
        n = len(meas)
        self.points = raycast_subset(n, seed)
        self.blocks = np.asarray(blocks)[self.points]
        self.part = meas.subset(self.points)
        self.base = pose_error.PoseCorrection.identity(np.zeros_like(meas.cloud), meas.t_s)
        self._cast: dict[tuple, tuple] = {}
        self._fits: dict[tuple, line_of_sight.LineOfSightPose] = {}

    def _moved(self, meas: Measurements, translation_m: np.ndarray) -> Measurements:
        corr = replace(self.base, translation_m=np.asarray(translation_m, float)[None, :],
                       centroid_m=np.zeros((1, 3)))
        return replace(meas, poses=pose_error.CorrectedPoses(meas.poses, corr))

    def _rays(self, m: Matching, idx: np.ndarray | None) -> fit_data.RaySet:
        def take(a):
            return a if a is None or idx is None else a[idx]
        return replace(rays_of(m, take(self.rays.measured_power_w), self.model),
                       extra_var_m2=take(self.rays.extra_var_m2))

    def score(self, translation_m: np.ndarray, on_top: list[Effect]) -> line_of_sight.RayScore:
        """The subset's points scored with the target moved by ``translation_m``."""
        key = tuple(np.round(translation_m, 6))
        if key not in self._cast:
            m = match(self.sim, self._moved(self.part, translation_m),
                      self.model.divergence_rad, edges=False)
            r = self._rays(m, self.points)
            self._cast[key] = (r, fit_data.make_fit_data(self.model, self.effects, r))
        r, data = self._cast[key]
        return line_of_sight.RayScore(r.matched, variants.heldout_nll(data, list(on_top)),
                                      r.unmatched)

    def fit(self, on_top: list[Effect]) -> line_of_sight.LineOfSightPose:
        key = lk.effect_key(on_top)
        if key not in self._fits:
            self._fits[key] = line_of_sight.fit(
                lambda t: self.score(t, on_top), len(self.points), self.blocks,
                self.direction, self.z_crit, diagnosis.MIN_PRACTICAL_GAIN)
        return self._fits[key]

    def versus(self, on_top: list[Effect], los: line_of_sight.LineOfSightPose
               ) -> dict[str, tuple[float, float, bool]]:
        """``on_top`` in the model on the recorded pose against the target moved by
        ``los`` (nothing on top), and against the recorded pose alone, on the subset's
        points as a candidate is scored (``line_of_sight.judge``; parameters fitted on
        both sides, none charged): (gain per point, z, passes the rule) of
        'pair_over_pose', 'pose_over_pair' and 'pair_over_none'."""
        zero = np.zeros(3)
        pair, moved, none = (self.score(zero, on_top), self.score(los.translation_m, []),
                             self.score(zero, []))
        n = len(self.points)

        def over(a, b):
            return line_of_sight.judge(b, a, n, self.blocks, self.z_crit,
                                       diagnosis.MIN_PRACTICAL_GAIN, params=0)[:3]
        return {'pair_over_pose': over(pair, moved), 'pose_over_pair': over(moved, pair),
                'pair_over_none': over(pair, none)}

    def diagnosis(self, los: line_of_sight.LineOfSightPose) -> diagnosis.Diagnosis:
        """The diagnosis with the target moved by ``los``, every ray raycast again."""
        moved = self._moved(self.meas, los.translation_m)
        m = match(self.sim, moved, self.model.divergence_rad, edges=False)
        return diagnosis_on_moved(self.model, self.effects, self.sim, m, self._rays(m, None),
                                  moved, self.n_candidates, self.seed, True)

    def as_pose(self, constant: pose_error.PoseError, los: line_of_sight.LineOfSightPose,
                explains: list[str] | None) -> pose_error.PoseError:
        """``constant`` (one correction for the recording, its own test's figures) as
        the translation ``los``, no turn."""
        return replace(constant, translation_m=np.asarray(los.translation_m)[None, :],
                       rotation_deg=np.zeros((1, 3)), significant=True, joint=False,
                       through_materials=False, rate_supported=False,
                       raycast=None if explains is None else {
                           'explains': list(explains),
                           'fitted_margin_charged': _num(los.gain),
                           'line_of_sight': los.as_dict()})


class ClockBesidePoseCast:
    """The recording raycast on a random subset of its points (LINE_OF_SIGHT_POINTS,
    the same as ``LineOfSight``'s), the pose read ``dt`` later or not, one rigid
    correction for the recording fitted on that model or not (raycast again until it
    settles, ``pose_error.iterate``), scored by the likelihood the candidates are scored
    by (``clock_nested``). The correction beside the clock is fitted with the clock in
    the model at every ``dt`` tried (a profile: the two trade, so a correction fitted
    at one ``dt`` holds the clock there)."""

    def __init__(self, model: Model, effects: list[Effect], rays: fit_data.RaySet,
                 meas: Measurements, blocks: np.ndarray, clock_cls: type[Effect],
                 z_crit: float, seed: int):
        self.model, self.effects, self.clock_cls = model, effects, clock_cls
        self.z_crit, self.seed = z_crit, seed
        n = len(meas)
        self.points = raycast_subset(n, seed)
        self.blocks = np.asarray(blocks)[self.points]
        self.part = meas.subset(self.points)
        take = (lambda a: None if a is None else a[self.points])
        self.power, self.extra_var = take(rays.measured_power_w), take(rays.extra_var_m2)
        self._poses: dict = {}

    def _every(self, dt_s: float | None) -> list[Effect]:
        return [*self.effects, *([] if dt_s is None else [self.clock_cls({'dt_s': dt_s})])]

    def _cast(self, meas: Measurements, dt_s: float | None):
        every = self._every(dt_s)
        m = match(geometry(self.model, every), meas, self.model.divergence_rad, edges=False)
        r = replace(rays_of(m, self.power, self.model), extra_var_m2=self.extra_var)
        return r, fit_data.make_fit_data(self.model, every, r)

    def score(self, meas: Measurements, dt_s: float | None) -> line_of_sight.RayScore:
        """The subset ``meas`` (its poses as they are) with the pose read ``dt_s``
        later (None: not)."""
        r, data = self._cast(meas, dt_s)
        return line_of_sight.RayScore(r.matched, variants.heldout_nll(data, []), r.unmatched)

    def corrected(self, dt_s: float | None) -> Measurements:
        """The subset with one rigid correction for the recording fitted on the model
        with the clock at ``dt_s`` (None: without it), raycast again as it goes."""
        key = None if dt_s is None else round(float(dt_s), 5)
        if key not in self._poses:
            self._poses[key] = self.settled(key, constant=True)
        return self._poses[key]

    def settled(self, dt_s: float | None, constant: bool) -> Measurements:
        """The subset with a rigid correction (one for the recording if ``constant``, else
        one per cloud) fitted on the model with the clock at ``dt_s`` (None: without it),
        raycast again until it settles (``pose_error.iterate``; CONSTANT_RECAST_PASSES for
        one correction). A re-cast step fits its correction alone (``step_only``: the
        first fit's test is the one kept; one correction's is never used)."""
        part = self.part

        def rematch(corr: pose_error.PoseCorrection):
            moved = replace(part, poses=pose_error.CorrectedPoses(part.poses, corr))
            r, data = self._cast(moved, dt_s)
            return r, data, moved

        def refit(state, applied: pose_error.PoseCorrection | None) -> pose_error.PoseError:
            r, data, moved = state
            idx = r.matched
            return pose_error.fit_reference_pose(
                data, moved.cloud[idx], moved.t_s[idx], self.blocks[idx], self.z_crit,
                diagnosis.MIN_PRACTICAL_GAIN, self.seed, [], applied=applied,
                constant=constant, step_only=constant or applied is not None)
        start = pose_error.PoseCorrection.identity(
            np.zeros_like(part.cloud) if constant else part.cloud, part.t_s)
        first = refit(rematch(start), None)
        passes = pose_error.CONSTANT_RECAST_PASSES if constant else pose_error.RECAST_PASSES
        (_, _, moved), _, _ = pose_error.iterate(first, start, rematch, refit, passes)
        return moved

    def weigh(self, dt_alone_s: float, dt_joint_s: float,
              min_gain: float) -> clock_nested.NestedClock:
        """``clock_nested.weigh``: the clock alone at ``dt_alone_s`` (fitted alone on the
        recorded pose), the clock beside the correction profiled from ``dt_joint_s``
        (within 0.06 s, to 3 ms)."""
        nothing = self.score(self.part, None)
        pose = self.score(self.corrected(None), None)
        clock = self.score(self.part, dt_alone_s)
        n = len(self.points)
        both: dict[float, line_of_sight.RayScore] = {}

        def at(d: float) -> line_of_sight.RayScore:
            d = round(float(d), 5)
            if d not in both:
                both[d] = self.score(self.corrected(dt_joint_s + d), dt_joint_s + d)
            return both[d]
        d, _ = line_of_sight.best_shift(
            lambda d: -float(np.sum(line_of_sight.ray_gain(pose, at(d), n))),
            step_m=0.01, span_m=0.06, tol_m=0.003)
        return clock_nested.weigh(nothing, pose, clock, at(d), n, self.blocks, self.z_crit,
                                  min_gain, dt_alone_s, dt_joint_s + d)



class ClockBesidePerCloudCast(ClockBesidePoseCast):
    """``ClockBesidePoseCast`` where the pose test reports a correction per cloud: the
    same points, and a rigid correction per cloud fitted on them too (raycast again as
    it goes, ``pose_error.RECAST_PASSES``), weighed against the clock with one
    correction (``clock_nested.weigh_per_cloud``). The profile over dt starts from the
    clock fitted jointly with one correction, linearly, on the model that correction
    leaves on these points (``clock_footing``, ``constant``)."""

    def per_cloud(self) -> Measurements:
        """The subset with a rigid correction per cloud fitted on the model without the
        clock, raycast again as it goes."""
        if 'per_cloud' not in self._poses:
            self._poses['per_cloud'] = self.settled(None, constant=False)
        return self._poses['per_cloud']

    def dt_joint(self, clock: Effect) -> float:
        """The clock's dt fitted linearly beside one correction on the model that
        correction leaves (its column scaled, ``clock_footing.ClockFooting.clock_scale``);
        the clock's own where that fit fails."""
        dt = float(clock.params.dt_s)
        moved = self.corrected(None)
        r, data = self._cast(moved, None)
        idx = r.matched
        on = clock_footing.clock_on_pose_footing(
            data, moved.cloud[idx], moved.t_s[idx], self.blocks[idx], self.z_crit,
            diagnosis.MIN_PRACTICAL_GAIN, row_clock.clock_column_m(data, clock), self.seed,
            constant=True)
        return float(on.clock_scale * dt) if np.isfinite(on.clock_scale) else dt

    def weigh_per_cloud(self, clock: Effect, min_gain: float) -> clock_nested.PerCloudClock:
        """The constant nested test (``weigh``) and the per-cloud correction against
        its clock with one correction, on the same points."""
        nest = self.weigh(float(clock.params.dt_s), self.dt_joint(clock), min_gain)
        dt = nest.dt_beside_pose_s
        both = self.score(self.corrected(dt), dt)
        per_cloud = self.score(self.per_cloud(), None)
        return clock_nested.weigh_per_cloud(
            nest, self.score(self.part, None), per_cloud, both,
            len(np.unique(self.part.cloud)), self.blocks, self.z_crit, min_gain)


def on_corrected_pose(sample: fit_data.RaySet, pred: Prediction,
                      pose_fit: pose_error.PoseError | None) -> tuple[fit_data.RaySet, int]:
    """The diagnosis sample of a ``--effect pose_error --fit`` run and how many of its
    matched rays were left out: where the correction is per cloud and was raycast again
    (``correct_reference_pose``), the rays it is fitted on (``fitted_rays_only``), as
    the diagnosis scores candidates beside a per-cloud pose (``recast_all_points``);
    what the correction leaves at grazing rays grows as 1 / cos(incidence) and reads as
    a sensor effect there. A constant correction, or one applied linearly (not
    significant), leaves the sample as it is."""
    if pose_fit is None or not pose_fit.passes or pose_fit.constant:
        return sample, 0
    kept = fitted_rays_only(sample, pred)
    return kept, len(sample.matched) - len(kept.matched)


def fitted_rays_only(sample: fit_data.RaySet, pred: Prediction) -> fit_data.RaySet:
    """``sample`` without the matched rays a per-cloud pose correction is not fitted on:
    grazing rays (|cos incidence| below ``pose_error.MIN_COS``, ``pred`` per ray). Their
    range moves with the pose as 1 / cos(incidence), so what the correction leaves
    (a millimetre is a centimetre at cos 0.1) sits there, in the clouds whose other
    rays fix the pose least, and reads as an incidence effect or a noise growing with
    the footprint (docs/compare.md, "What a per-cloud correction leaves at grazing
    rays"). The candidates are scored on the rays the correction was fitted on."""
    inc = np.asarray(pred.hits.incidence_rad, float)[sample.matched]
    with np.errstate(invalid='ignore'):
        keep = np.abs(np.cos(inc)) >= pose_error.MIN_COS
    return replace(sample, matched=sample.matched[keep])


def recast_sample(rays: fit_data.RaySet, meas: Measurements, seed: int) -> fit_data.RaySet:
    """The points the candidates are scored on against a corrected pose: a diagnosis
    sample drawn anew from the re-cast matching ``rays`` (``diagnosis_sample``), as a
    --fit run draws it; not the recorded pose's sample matched anew, whose unmatched
    points (all of them kept) would join the matched ones far above their share
    (``recast_all_points``)."""
    return diagnosis_sample(rays, meas, seed)[0]


def build_summary(opts: CompareOptions, inp: Inputs, effects: list[Effect],
                  fitted: list[Effect], cal: Calibrated, ana: Analysed, diag: Diagnosed,
                  sunlight: dict | None, rays: fit_data.RaySet, time_spread: float,
                  power: PowerFromIntensity,
                  pose_fit: pose_error.PoseError | None = None,
                  plan: Plan | None = None) -> dict:
    """summary.json, with the verdict."""
    meas, scenario, matching = inp.meas, inp.scenario, cal.matching
    sel = matching.matched
    cal_nll, cal_rmse, cal_robust = cal.calibrated
    before, decision = diag.before, diag.decision
    # Left out before anything was fitted (``leave_out_occluded``).
    left_out = left_out_points(meas)
    summary = {
        'bag': str(opts.bag), 'mesh': str(opts.mesh),
        'config': str(scenario.source) if scenario.source else None,
        'effects': [_effect_record(e) for e in effects],
        'points': int(len(meas) + meas.dropped.get('subsampled', 0) + left_out),
        # Analysed: after --max-points; the occluded, the crosstalk ghosts and the later
        # returns of a shot among them are left out (occlusion, crosstalk, multiple_returns).
        'points_analysed': int(len(meas) + left_out),
        'occlusion': inp.occlusion.as_dict() if inp.occlusion is not None else None,
        'crosstalk': inp.crosstalk.as_dict() if inp.crosstalk is not None else None,
        'multiple_returns': (inp.multiple_returns.as_dict() if inp.multiple_returns is not None
                             else None),
        'matched_points': int(sel.sum()),
        'unmatched_points': int((~sel).sum()),
        'unmatched_fraction': float(matching.unmatched_fraction),
        'range_rmse_m': float(cal.rmse_m), 'nll_per_point': float(cal.nll),
        'range_rmse_calibrated_m': float(cal_rmse), 'nll_calibrated': float(cal_nll),
        # Between models that match different returns (a footprint puts edge returns
        # back): the same returns on both sides (``diagnosis.per_return_nll``).
        'nll_per_return': diagnosis.per_return_nll(float(cal_nll),
                                                   float(matching.unmatched_fraction)),
        'range_robust_sigma_calibrated_m': float(cal_robust),
        'materials_refit': bool(opts.fit),
        'range_residual_robust_sigma_m': mat.robust_sigma(ana.residual_m),
        'range_span_m': [float(x) for x in np.percentile(meas.range_m[sel], [5, 95])],
        'intensity_gain': (power.calibration.as_dict() if power.calibration is not None
                           else None),
        'power_driven_effects_use': ('measured intensity' if rays.measured_power_w is not None
                                     else 'model power'),
        'materials': {s.name: s.as_dict() for s in cal.stats},
        'features': [f.as_dict() for f in ana.attribution.features],
        'residual_structure': ana.attribution.as_dict(),
        **({'intensity_measured_range': ana.range_in_intensity.as_dict()}
           if ana.range_in_intensity is not None else {}),
        'candidates': [c.as_dict() for c in diag.cands],
        'candidates_basis': {'points': int(len(ana.sample.matched)),
                             'nll_calibrated': before[0], 'range_rmse_calibrated_m': before[1],
                             'range_robust_sigma_calibrated_m': before[2]},
        'missing_effect': decision.missing,
        'range_alone': diag.range_alone.as_dict() if diag.range_alone is not None else None,
        'confounded_with': decision.confounded_with,
        'also_explains': decision.also,
        'also_explains_more': list(decision.also_more),
        'also_confounded_with': list(decision.beside_tie),
        'withheld': decision.withheld or None,
        'against_named': decision.pair_z,
        # A walk or an incidence bias named beside the other: each one's own part
        # (``Diagnosis.power_or_incidence``).
        'power_incidence': power_incidence.figures_in(decision.pair_z),
        'separation_plan': plan.rows if plan is not None and plan.rows else None,
        'unmatched': _unmatched_summary(ana.local, cal.model.divergence_rad, int((~sel).sum()),
                                        float(matching.unmatched_fraction),
                                        ana.isolated[ana.picked]),
        'fitted_effects': [_effect_record(e, fitted_only=True) for e in fitted],
        'clouds': int(len(meas.cloud_stamps_s)),
        'missed_shots_per_unmatched': rays.missed_per_unmatched,
        'point_times': meas.time_source,
        'point_time_field': meas.time_field,
        'point_time_spread_s': time_spread or None,
        'scan_pattern_match': (None if meas.scan_match_fraction is None
                               else round(meas.scan_match_fraction, 4)),
        # A Lissajous running (1 + eps) fast against the configured one: eps (scan_rate).
        'scan_pattern_rate_error': (None if meas.scan_rate_error is None
                                    else round(meas.scan_rate_error, 6)),
        'stamp_place': diag.stamp.as_dict() if diag.stamp is not None else None,
        'reference_pose': (None if diag.pose is None else {
            **diag.pose.as_dict(),
            **pose_status(diag.pose.as_dict(), decision, diag.cands, diag.pose_on_top),
            **({'clock_equivalent': spin_clock.clock_equivalent(
                diag.pose.rotation_deg, diag.spin_dps)}
               if decision.pose is diag.pose and diag.pose.constant
               and diag.spin_dps is not None else {})}),
        'reference_pose_off': decision.pose is not None,
        'pose_along_line_of_sight': diag.line_of_sight,
        'region_offset': decision.region.as_dict() if decision.region is not None else None,
        'laser_intensity': laser_intensity(decision, diag.cands, effects, cal.rays,
                                           cal.matching.pred, diag.z_crit),
        'pose_correction': pose_fit.as_dict() if pose_fit is not None else None,
        'has_intensity': meas.intensity is not None,
        'point_fields': {**(meas.fields or {}), 'lines': meas.field_lines + [
            fields.intensity_reading(power.calibration.as_dict() if power.calibration else None,
                                     (meas.fields or {}).get('intensity'),
                                     len(fields.range_exponents(meas.fields)) == 1)]},
        'point_flags': {'counts': meas.flag_counts, 'known_misses': meas.known_misses,
                        'saturation': fields.saturation_evidence(
                            None if meas.saturated is None else meas.saturated[sel],
                            matching.pred.ctx.power_w[sel],
                            scenario.sensor.detection.saturation_power_w)},
        'dropped': meas.dropped,
        'notes': list(meas.notes) + _material_name_notes(meas, scenario)
        + ([f'the reference pose corrected per cloud: the candidates are scored on the '
            f'rays its correction is fitted on, {ana.grazing_left_out} grazing rays of the '
            f'sample (|cos incidence| < {pose_error.MIN_COS:g}) left out']
           if ana.grazing_left_out else [])
        + (['--fit without --effect: nothing to fit']
           if opts.fit and not inp.user and not inp.pose_fit else [])
        + ([f'separation plan of {" and ".join(plan.pair)} failed: {plan.error}']
           if plan is not None and plan.error else []),
        **({'sunlight': sunlight} if sunlight is not None else {}),
    }
    if any(diagnosis.rmse_fault(c, before[1]) for c in diag.cands if c.significant):
        # A fit that lowers the NLL and raises the RMSE: where the points off the model lie.
        summary['mixed_edges'] = mixed_edges.between_edge_and_behind(
            meas.directions, meas.range_m, np.asarray(sel, bool),
            np.where(matching.pred.hits.hit, matching.pred.hits.range_m, np.nan))
    # The verdict quotes candidates against the figures of the points they were fitted on.
    basis = {**summary, 'nll_calibrated': before[0], 'range_rmse_calibrated_m': before[1],
             'range_robust_sigma_calibrated_m': before[2]}
    summary['verdict'] = verdict(basis, ana.attribution, diag.cands, decision)
    return summary


def laser_intensity(decision: diagnosis.Decision, cands: list, effects: list[Effect],
                    rays: fit_data.RaySet, pred: Prediction, z_crit: float) -> dict | None:
    """summary.json's ``laser_intensity``: where laser_bias is named (or 'also') beside a
    range walk read from the measured intensity (in the model, named or 'also'), how
    closely its offsets follow k times each laser's mean ln(measured / model power) on
    the matched points (``laser_gains.intensity_tie``): per-laser intensity gains read
    through the walk give the same offsets. None otherwise."""
    said = (decision.missing, decision.also)
    if LASER_BIAS not in said or rays.measured_power_w is None:
        return None
    by_name = {c.name: c for c in cands}
    lasers = by_name.get(LASER_BIAS)
    walk = next((e for e in effects if e.name == RANGE_WALK), None)
    named = by_name.get(decision.missing)
    # The walk and the lasers fitted together where the decision names both
    # (``Diagnosis.fit_together``); the walk in the model: the lasers fitted on top of it.
    tog = (named.together or {}) if named is not None else {}
    both = {decision.missing, tog.get('with')} == {RANGE_WALK, LASER_BIAS}
    if walk is not None:
        k, power = float(walk.params.k_m), walk.params.power
    elif both:
        fitted = (tog.get('params') if decision.missing == RANGE_WALK
                  else tog.get('with_params')) or {}
        k, power = fitted.get('k_m'), fitted.get('power', 'measured')
    else:
        return None
    if lasers is None or k is None or power == 'model':
        return None     # a walk on the model's power reads no laser's intensity gain
    offsets = (tog.get('offsets_m') or {}).get(LASER_BIAS) if both else None
    if offsets is None:
        offsets = [float(lasers.params.get(f'laser_{i}_m', np.nan))
                   for i in range(sum(1 for key in lasers.params if key.startswith('laser_')))]
    idx = rays.matched
    ratio = laser_gains.per_laser_log_ratio(rays.meas.laser[idx], rays.measured_power_w[idx],
                                            np.asarray(pred.ctx.power_w, float)[idx])
    return laser_gains.intensity_tie(offsets, ratio, float(k), z_crit)


def write_outputs(opts: CompareOptions, summary: dict, stage: Stages, inp: Inputs,
                  effects: list[Effect], fitted: list[Effect], cal: Calibrated,
                  ana: Analysed, diag: Diagnosed, plan: Plan | None = None) -> CompareResult:
    """effects.yaml (with --fit), materials.yaml, a line of history.json, the report
    and summary.json."""
    opts.out.mkdir(parents=True, exist_ok=True)
    files = []
    if fitted:
        files.append(_write(opts.out / 'effects.yaml', effects_yaml(fitted)))
    files.append(_write(opts.out / 'materials.yaml', mat.materials_yaml(cal.refit, cal.stats)))
    if plan is not None and plan.yaml:
        files.append(_write(opts.out / 'plan.yaml', plan.yaml))
    hist_path = Path(opts.history) if opts.history else opts.out.resolve().parent / 'history.json'
    names = [e.name for e in effects] + ([POSE_ERROR] if inp.pose_fit else [])
    runs = history.append_run(hist_path, history.run_entry(summary, names, opts.out, opts.bag))
    summary['history'] = str(hist_path)
    if opts.report:
        with stage('report'):
            from lidar_sim_ros.compare.report.page import write_report
            files += write_report(opts.out, summary, ana.local, cal.configured, ana.residual_m,
                                  cal.stats, ana.attribution.features, diag.cands, runs,
                                  cal.model, ana.values, ana.isolated[ana.picked], ana.labels)
    summary['stage_seconds'] = dict(stage.seconds)
    summary['total_seconds'] = round(stage.total, 3)
    files.insert(len(files) - (1 if opts.report else 0),
                 _write(opts.out / 'summary.json', json.dumps(summary, indent=2) + '\n'))
    return CompareResult(summary, opts.out, files, fitted, summary_lines(summary, files))


def model_residuals(data: lk.FitData, rays: fit_data.RaySet) -> tuple[np.ndarray, np.ndarray]:
    """Measured minus expected range (m) and predicted sigma (m) of every measured point
    under the model with its effects (NaN where unmatched)."""
    n = len(rays.meas)
    model = lk.model_on_rays(data, [])
    residual = np.full(n, np.nan)
    sigma = np.full(n, np.nan)
    residual[rays.matched] = data.measured_range_m - model.expected_range_m
    sigma[rays.matched] = model.sigma_m
    return residual, sigma


def effects_yaml(effects: list[Effect]) -> str:
    lines = ['# fitted by lidar-sim compare --fit: paste under "effects:" in the scenario']
    for e in effects:
        lines += [line for line in diagnosis._snippet(e).splitlines()]
    return '\n'.join(lines) + '\n'


def _effect_record(e: Effect, fitted_only: bool = False) -> dict:
    """name and params; ``fitted_only`` keeps the fitted ones and discrete options."""
    params = e.params.model_dump() if hasattr(e.params, 'model_dump') else {}
    if fitted_only:
        # The free parameters, the discrete options, and whatever the fit set away from
        # its default (per-material standoffs, per-laser angles: not in ``bounds`` by name).
        keep = set(type(e).bounds) | set(variants.literal_choices(type(e)))
        defaults = _defaults(type(e))
        params = {k: v for k, v in params.items() if k in keep or v != defaults.get(k, v)}
    bound = at_bounds(e) if fitted_only else []
    return {'name': e.name or type(e).__name__,
            'params': {k: (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                           else v) for k, v in params.items()},
            **({'at_bound': bound} if bound else {})}


def _defaults(effect_cls: type[Effect]) -> dict:
    """The effect's parameters at their defaults ({} where it has none without a value)."""
    try:
        return effect_cls.Params().model_dump()
    except Exception:       # a parameter without a default (a user effect)
        return {}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _material_name_notes(meas: Measurements, scenario: Scenario) -> list[str]:
    names = meas.material_names
    if names is None or names == scenario.materials.names:
        return []
    return [f'bag material names {names} differ from the materials config '
            f'{scenario.materials.names}: the model uses the config and the mesh groups']


def _unmatched_summary(m: Matching, divergence_rad: float, n_all: int, fraction: float,
                       isolated: np.ndarray | None) -> dict:
    """The unmatched points (``m`` is the analysed sample): where they are and what they
    look like: near the silhouette (beam edge, pose), on surfaces that are not the
    target (lab clutter: neighbouring rays see the same range) or isolated (random
    ranges: false returns)."""
    un = ~m.matched
    n = int(un.sum())
    out = {'points': n_all, 'fraction': fraction}
    if n == 0:
        return out
    rng = m.meas.range_m
    r_lo, r_hi = np.percentile(rng[m.matched], [1, 99]) if m.matched.any() else (0.0, 0.0)
    near = m.edge_rad[un] <= SILHOUETTE_NEAR_DIVERGENCES * divergence_rad + 1e-12
    within = (rng[un] >= r_lo - 1.0) & (rng[un] <= r_hi + 1.0)
    alone = (isolated[un] if isolated is not None else np.zeros(n, bool)) & ~near
    surface = ~near & ~alone
    out.update({
        'analysed': n,
        'near_silhouette_fraction': float(near.mean()),
        'surface_fraction': float(surface.mean()),
        'isolated_fraction': float(alone.mean()),
        'within_target_ranges_fraction': float(within.mean()),
        'range_median_m': float(np.median(rng[un])),
        'range_p05_m': float(np.percentile(rng[un], 5)),
        'range_p95_m': float(np.percentile(rng[un], 95)),
        'silhouette_distance_median_mrad': float(np.median(m.edge_rad[un]) * 1e3),
        'interpretation': _unmatched_words(near.mean(), within.mean(), surface.mean(),
                                           alone.mean()),
    })
    return out


def _unmatched_words(near: float, within: float, surface: float, alone: float) -> str:
    if near > 0.6 and within > 0.6:
        return ('mostly just beyond the silhouette at target ranges: returns from the beam '
                'edge (beam divergence) or a pose/mesh offset')
    if surface > 0.6:
        return ('mostly on surfaces that are not the target (neighbouring rays see the same '
                'range): lab clutter such as walls, jigs or cables, not false returns')
    if alone > 0.6:
        return 'isolated returns at random ranges: false returns (background light)'
    return (f'mixed: {100 * near:.0f} % near the silhouette, {100 * surface:.0f} % on other '
            f'surfaces (clutter), {100 * alone:.0f} % isolated')
