"""The comparison loop, top to bottom: load, match, calibrate materials, attribute,
diagnose, report.

``run_compare`` is what ``lidar-sim compare`` calls. It reads a bag of measured
points and target poses, predicts every measured ray with the model (the scenario's
sensor and materials, the given mesh, the scenario's effects plus any ``--effect``),
and writes ``summary.json``, ``report.html`` (+ PNGs), ``effects.yaml`` (with
``--fit``), ``materials.yaml`` and one line of ``history.json``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from lidar_sim_ros.compare import diagnosis, features, history, likelihood as lk, materials as mat
from lidar_sim_ros.compare.intensity import IntensityCalibration, calibrate_intensity
from lidar_sim_ros.compare.matching import Matching, Model, match
from lidar_sim_ros.compare.measurements import (Measurements, load_measurements,
                                                 with_scan_times)
from lidar_sim_ros.core.config import Scenario, load_scenario
from lidar_sim_ros.core.effects import (Effect, catalogue, effect_from_spec, get_effect_class,
                                        parse_effect_spec)
from lidar_sim_ros.core.geometry import load_target
from lidar_sim_ros.io.bag import CLOUD_TOPIC, POSE_TOPIC
from lidar_sim_ros.paths import config_path

DEFAULT_MAX_POINTS = 300_000
# Candidate fits re-run the raycast many times: a random subset of this many matched
# points (and as many unmatched) keeps them fast with ample statistical power.
DIAGNOSIS_MAX_MATCHED = 30_000
SILHOUETTE_NEAR_DIVERGENCES = 2.0


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
    history: Path | None = None
    max_points: int = DEFAULT_MAX_POINTS
    candidates: list[str] | None = None     # effect specs to diagnose (default: catalogue)
    seed: int = 0
    report: bool = True


@dataclass
class CompareResult:
    summary: dict
    out: Path
    files: list[Path]
    fitted: list[Effect]
    lines: list[str]


def fit_user_effects(model: Model, base: list[Effect], user: list[Effect],
                     meas: Measurements, power: PowerFromIntensity) -> list[Effect]:
    """ML-fit each user effect in turn on top of the base and the previously fitted ones.

    The likelihood profiles each material's offset and sigma scale, so a constant
    per-material mismatch does not leak into the effect's parameters.
    """
    done: list[Effect] = []
    for eff in user:
        cls = type(eff)
        # Parameters the user gave (e.g. beam_divergence={range_mode: first}) stay fixed.
        fixed = {k: v for k, v in eff.params.model_dump(exclude_unset=True).items()
                 if k not in cls.bounds}
        m = match(geometry(model, base + done), meas, model.divergence_rad, edges=False)
        rays = rays_of(m, power(m))
        data = diagnosis.make_fit_data(model, base + done, rays.sample(DIAGNOSIS_MAX_MATCHED, 0))
        fit, _ = diagnosis.fit_best_variant(cls, data, fixed)
        done.append(diagnosis.plain(cls, fit.effect))
    return done


def geometry(model: Model, effects: list[Effect]):
    """The simulator that casts the model's rays: the ray geometry of ``effects`` only
    (pose time, footprint); their hooks are applied by the likelihood."""
    return model.simulator(effects=[lk.RaysOnly(e) for e in lk.moving(effects)])


def rays_of(m: Matching, measured_power_w: np.ndarray | None) -> diagnosis.RaySet:
    return diagnosis.RaySet(m.meas, np.flatnonzero(m.matched), np.flatnonzero(~m.matched),
                            pred=m.pred, measured_power_w=measured_power_w)


class PowerFromIntensity:
    """Received power from the measured intensity (``compare/intensity.py``), calibrated
    once against the model's power; None for recordings without (usable) intensity."""

    def __init__(self) -> None:
        self.calibration: IntensityCalibration | None = None
        self.done = False

    def __call__(self, m: Matching) -> np.ndarray | None:
        if m.meas.intensity is None:
            return None
        if not self.done:
            sel = m.matched
            self.calibration = calibrate_intensity(m.meas.intensity[sel], m.meas.range_m[sel],
                                                   m.pred.ctx.power_w[sel])
            self.done = True
        if self.calibration is None or not self.calibration.usable:
            return None
        return self.calibration.power_w(m.meas.intensity, m.meas.range_m)


def run_compare(opts: CompareOptions) -> CompareResult:
    opts.out = Path(opts.out)
    scenario = load_scenario(opts.config or config_path('scenario.yaml'))
    target = load_target(opts.mesh, scenario.materials.names)
    meas = load_measurements(opts.bag, opts.cloud_topic, opts.pose_topic, opts.max_points,
                             opts.seed)
    scenario_effects = [get_effect_class(e.name)(e.params) for e in scenario.config.effects]
    user = [effect_from_spec(spec) for spec in opts.effects]
    model = Model(scenario.sensor, scenario.materials, target, (), scenario.seed,
                  scenario.source.parent if scenario.source else None)

    meas = with_scan_times(meas, model.simulator().shots)
    power = PowerFromIntensity()

    fitted: list[Effect] = []
    if opts.fit and user:
        user = fitted = fit_user_effects(model, scenario_effects, user, meas, power)
    effects = scenario_effects + user
    notes = list(meas.notes) + _material_name_notes(meas, scenario)
    if opts.fit and not user:
        notes.append('--fit without --effect: nothing to fit')

    # Predict every measured ray; per-material bias/sigma as measured vs configured.
    matching = match(geometry(model, effects), meas, model.divergence_rad, edges=not opts.fit)
    rays = rays_of(matching, power(matching))
    pred, sel = matching.pred, matching.matched
    residual, sigma = model_residuals(diagnosis.make_fit_data(model, effects, rays), rays)
    stats = mat.material_stats(model.materials, replace(pred, sigma_m=sigma), residual, sel)
    refit = mat.refit_materials(model.materials, stats)
    configured = replace(matching, residual_m=residual)
    if opts.fit:
        # --fit estimates the model's free parameters: the effects' and, as in the
        # paper's Table 2 calibration, each material's range bias and sigma.
        model = replace(model, materials=refit)
        matching = match(geometry(model, effects), meas, model.divergence_rad)
        rays = rays_of(matching, rays.measured_power_w)
        pred = matching.pred
    if len(rays.matched) < 10:
        raise ValueError(
            f'only {len(rays.matched)} of {len(meas)} measured rays hit the target mesh '
            f'{opts.mesh}: check the mesh, the pose topic {opts.pose_topic!r} (target body '
            f'pose in the lidar frame) and that the clouds are in the lidar frame')
    everything = diagnosis.make_fit_data(model, effects, rays)
    residual, sigma = model_residuals(everything, rays)
    matching = replace(matching, residual_m=residual)
    # Headline: the model (materials as configured, or refit with --fit). Calibrated:
    # each material's offset and sigma scale profiled out (what --fit delivers); the
    # candidates' "after" figures are on this basis too.
    nll, rmse, _ = lk.evaluate(everything, [], profile_materials=False)
    cal_nll, cal_rmse, cal_robust = diagnosis.calibrated_figures(everything, [])

    # Where the residual depends, model-free, once the material offsets are removed.
    res = residual[sel]
    sig = np.maximum(sigma[sel], 1e-6)
    offset, scale = lk.material_nuisance(res, sig, np.asarray(pred.ctx.material[sel], int),
                                         np.isfinite(res))
    res = res - offset
    feats = features.score_features(features.feature_values(matching), res,
                                    res / (sig * scale), opts.seed)

    # Which effect is missing.
    in_model = {e.name for e in effects}
    classes = ([get_effect_class(parse_effect_spec(s)[0]) for s in opts.candidates]
               if opts.candidates is not None else list(catalogue().values()))
    classes = [c for c in classes if c.name not in in_model]
    cands = []
    if classes:
        diag = diagnosis.Diagnosis(model, effects, rays.sample(DIAGNOSIS_MAX_MATCHED, opts.seed),
                                   opts.seed, frame_time_spread_s(meas, scenario))
        cands = diagnosis.rank([diag.score(c) for c in classes])
        for c in cands:
            if c.effect is not None:   # what a run with --effect NAME --fit would show
                c.nll_after, c.range_rmse_after_m, c.range_robust_sigma_after_m = \
                    diagnosis.calibrated_figures(everything, [c.effect])
    missing = diagnosis.missing_effect(cands)

    summary = {
        'bag': str(opts.bag), 'mesh': str(opts.mesh),
        'config': str(scenario.source) if scenario.source else None,
        'effects': [_effect_record(e) for e in effects],
        'points': int(len(meas) + meas.dropped.get('subsampled', 0)),
        'points_analysed': int(len(meas)),
        'matched_points': int(sel.sum()),
        'unmatched_points': int((~sel).sum()),
        'unmatched_fraction': float(matching.unmatched_fraction),
        'range_rmse_m': float(rmse), 'nll_per_point': float(nll),
        'range_rmse_calibrated_m': float(cal_rmse), 'nll_calibrated': float(cal_nll),
        'range_robust_sigma_calibrated_m': float(cal_robust),
        'materials_refit': bool(opts.fit),
        'range_residual_robust_sigma_m': mat.robust_sigma(res),
        'intensity_gain': (power.calibration.as_dict() if power.calibration is not None
                           else None),
        'power_driven_effects_use': ('measured intensity' if rays.measured_power_w is not None
                                     else 'model power'),
        'materials': {s.name: s.as_dict() for s in stats},
        'features': [f.as_dict() for f in feats],
        'candidates': [c.as_dict() for c in cands],
        'missing_effect': missing,
        'unmatched': _unmatched_summary(matching, model.divergence_rad),
        'fitted_effects': [_effect_record(e, fitted_only=True) for e in fitted],
        'clouds': int(len(meas.cloud_stamps_s)),
        'point_times': meas.time_source,
        'point_time_field': meas.time_field,
        'has_intensity': meas.intensity is not None,
        'dropped': meas.dropped,
        'notes': notes,
    }
    summary['verdict'] = verdict(summary, feats, cands)

    opts.out.mkdir(parents=True, exist_ok=True)
    files = []
    if fitted:
        files.append(_write(opts.out / 'effects.yaml', effects_yaml(fitted)))
    files.append(_write(opts.out / 'materials.yaml', mat.materials_yaml(refit, stats)))
    hist_path = Path(opts.history) if opts.history else opts.out.resolve().parent / 'history.json'
    runs = history.append_run(hist_path, history.run_entry(
        summary, [e.name for e in effects], opts.out, opts.bag))
    summary['history'] = str(hist_path)
    files.append(_write(opts.out / 'summary.json', json.dumps(summary, indent=2) + '\n'))
    if opts.report:
        from lidar_sim_ros.compare.report import write_report
        files += write_report(opts.out, summary, matching, configured, res, stats, feats,
                              cands, runs, model)
    return CompareResult(summary, opts.out, files, fitted, summary_lines(summary, files))


def model_residuals(data: lk.FitData, rays: diagnosis.RaySet) -> tuple[np.ndarray, np.ndarray]:
    """Measured minus expected range (m) and predicted sigma (m) of every measured point
    under the model with its effects (NaN where unmatched)."""
    n = len(rays.meas)
    model = lk.model_on_rays(data, [])
    residual = np.full(n, np.nan)
    sigma = np.full(n, np.nan)
    residual[rays.matched] = data.measured_range_m - model.expected_range_m
    sigma[rays.matched] = model.sigma_m
    return residual, sigma


def frame_time_spread_s(meas: Measurements, scenario: Scenario) -> float | None:
    """Standard deviation (s) of the unknown true point times within a frame when every
    point carries its cloud stamp (no time field, no scan-pattern match); else None.
    The points spread over about one frame period (the clouds' median stamp step, or
    the configured frame rate for a single cloud)."""
    if meas.time_source != 'stamp':
        return None
    steps = np.diff(np.unique(meas.cloud_stamps_s))
    period = (float(np.median(steps)) if len(steps)
              else scenario.sensor.frame_period_s)
    return period / np.sqrt(12.0)


def effects_yaml(effects: list[Effect]) -> str:
    lines = ['# fitted by lidar-sim compare --fit: paste under "effects:" in the scenario']
    for e in effects:
        lines += [line for line in diagnosis._snippet(e).splitlines()]
    return '\n'.join(lines) + '\n'


def _effect_record(e: Effect, fitted_only: bool = False) -> dict:
    """name and params; ``fitted_only`` keeps the fitted ones and discrete options."""
    params = e.params.model_dump() if hasattr(e.params, 'model_dump') else {}
    if fitted_only:
        keep = set(type(e).bounds) | set(diagnosis.literal_choices(type(e)))
        params = {k: v for k, v in params.items() if k in keep}
    return {'name': e.name or type(e).__name__,
            'params': {k: (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                           else v) for k, v in params.items()}}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _material_name_notes(meas: Measurements, scenario: Scenario) -> list[str]:
    names = meas.material_names
    if names is None or names == scenario.materials.names:
        return []
    return [f'bag material names {names} differ from the materials config '
            f'{scenario.materials.names}: the model uses the config and the mesh groups']


def _unmatched_summary(m: Matching, divergence_rad: float) -> dict:
    un = ~m.matched
    n = int(un.sum())
    out = {'points': n, 'fraction': float(m.unmatched_fraction)}
    if n == 0:
        return out
    rng = m.meas.range_m
    r_lo, r_hi = np.percentile(rng[m.matched], [1, 99]) if m.matched.any() else (0.0, 0.0)
    near = m.edge_rad[un] <= SILHOUETTE_NEAR_DIVERGENCES * divergence_rad + 1e-12
    within = (rng[un] >= r_lo - 1.0) & (rng[un] <= r_hi + 1.0)
    out.update({
        'near_silhouette_fraction': float(near.mean()),
        'within_target_ranges_fraction': float(within.mean()),
        'range_median_m': float(np.median(rng[un])),
        'range_p05_m': float(np.percentile(rng[un], 5)),
        'range_p95_m': float(np.percentile(rng[un], 95)),
        'silhouette_distance_median_mrad': float(np.median(m.edge_rad[un]) * 1e3),
        'interpretation': _unmatched_words(near.mean(), within.mean()),
    })
    return out


def _unmatched_words(near: float, within: float) -> str:
    if near > 0.6 and within > 0.6:
        return ('mostly just beyond the silhouette at target ranges: returns from the beam '
                'edge (beam divergence) or a pose/mesh offset')
    if near < 0.4 and within < 0.6:
        return 'spread over the field of view at random ranges: false returns (background light)'
    return 'mixed: part near the silhouette, part elsewhere'


EFFECT_WORDS = {
    'range_walk': 'range walk (intensity-dependent timing bias)',
    'incidence_angle': 'footprint elongation at oblique incidence',
    'snr_noise': 'range noise growing as the signal falls',
    'solar_background': 'false returns from background light (outliers at random ranges)',
    'beam_divergence': 'returns from the beam edge beyond the silhouette and mixed ranges at '
                       'depth steps',
    'time_offset': 'a clock offset between the pose and LiDAR stamps',
}
# The feature whose profile shows each catalogue effect best.
EFFECT_FEATURE = {'range_walk': 'intensity', 'incidence_angle': 'incidence',
                  'snr_noise': 'intensity', 'beam_divergence': 'edge'}


def verdict(summary: dict, feats: list, cands: list) -> str:
    """One plain-language paragraph: where it fails, which effect, what adding it brings."""
    by_name = {f.name: f for f in feats}
    top = feats[0] if feats else None
    parts = []
    if top is not None and top.significance > 5 and top.score > 1e-3:
        parts.append(f'The range residual depends most on {top.name}: {top.trend}.')
    missing = summary['missing_effect']
    if missing:
        c = next(c for c in cands if c.name == missing)
        feat = by_name.get(EFFECT_FEATURE.get(missing, ''))
        seen = (f'Against {feat.name}, {feat.trend}: ' if feat is not None and feat is not top
                and feat.score > 0 else '')
        params = ', '.join(f'{k} = {v:.4g}' if isinstance(v, float) else f'{k} = {v}'
                           for k, v in c.params.items())
        gain, caveat = _gain_words(summary, c)
        parts.append(
            f'{seen}this is {EFFECT_WORDS.get(missing, missing)}. With per-material offsets '
            f'and sigmas refit (as --fit does), adding {missing} with {params} {gain} '
            f'(held-out gain {c.score:.4f} nats/point, z = {c.z:.1f}).{caveat} '
            f'Run again with --effect {missing} --fit to add it.')
        parts[-1] = parts[-1][0].upper() + parts[-1][1:]
    else:
        parts.append('No catalogue effect improves the held-out likelihood significantly: '
                     'the model matches the measurements up to noise.')
        if top is not None and top.significance > 8 and top.score > 0.01 and top.name != 'material':
            parts[-1] = ('No catalogue effect improves the held-out likelihood significantly, '
                         f'yet the residual depends on {top.name}: an effect outside the '
                         'catalogue. Write one (docs/effects.md, "Write your own effect") and add it '
                         'with --effect file.py:Class --fit.')
    vetoed = [c for c in cands if c.vetoed and c.significant and c.name != missing]
    if vetoed:
        parts.append(f'{vetoed[0].name} would raise the likelihood but is not the missing '
                     f'effect: {vetoed[0].vetoed}.')
    mats = summary['materials']
    bad = [n for n, m in mats.items() if m['bias_mismatch'] or m['sigma_mismatch']]
    if bad:
        def row(n: str) -> str:
            m = mats[n]
            return (f'{n} (bias {100 * (m["measured_bias_m"] - m["model_bias_m"]):+.1f} cm, '
                    f'sigma x {m["measured_sigma_m"] / max(m["model_sigma_m"], 1e-9):.2f})')
        rows = ', '.join(row(n) for n in bad)
        parts.append(f'Per-material range bias/sigma differ from the configuration for {rows}: '
                     'see materials.yaml (--fit refits them).')
    un = summary['unmatched']
    if un['points']:
        parts.append(f'{un["points"]} points ({100 * un["fraction"]:.2f} %) miss the target '
                     f'model: {un.get("interpretation", "")}.')
    return ' '.join(parts)


def _change(what: str, before: float, after: float, unit: str, fmt: str, down: str,
            up: str = 'raises') -> str:
    """'cuts WHAT from a to b', 'raises WHAT from a to b' or 'leaves WHAT at a'."""
    a, b = f'{before:{fmt}}', f'{after:{fmt}}'
    if a == b:
        return f'leaves {what} at {a}{unit}'
    return f'{down if after < before else up} {what} from {a}{unit} to {b}{unit}'


def _gain_words(summary: dict, c) -> tuple[str, str]:
    """What adding candidate ``c`` brings, before and after on one basis (each
    material's offset and sigma scale refit, as --fit does), and any caveat sentence.
    An outlier effect is judged by the NLL and the robust (MAD) spread: a plain RMSE is
    dominated by the far outliers, which stay in the data whether or not the model
    expects them."""
    nll = _change('the NLL', summary['nll_calibrated'], c.nll_after, '', '.3f',
                  'lowers') + ' per point'
    if c.effect is None or not diagnosis.is_outlier_effect(type(c.effect)):
        rmse = _change('the range RMSE', summary['range_rmse_calibrated_m'],
                       c.range_rmse_after_m, ' m', '.4f', 'cuts')
        return f'{rmse} and {nll}', ''
    text = nll
    before = summary.get('range_robust_sigma_calibrated_m', float('nan'))
    after = c.range_robust_sigma_after_m
    if np.isfinite(before) and np.isfinite(after):
        text += ' and ' + _change('the robust (MAD) spread of the range residual', before,
                                  after, ' m', '.4f', 'narrows', 'widens')
    caveat = (f' The plain range RMSE ({summary["range_rmse_calibrated_m"]:.4g} m) is '
              'dominated by the far outliers, which stay in the data: it does not measure '
              'this effect.')
    if c.unmatched_explained > 0.01:
        caveat += (f' It also explains {100 * c.unmatched_explained:.0f} % of the points '
                   'that miss the target.')
    return text, caveat


def summary_lines(s: dict, files: list[Path]) -> list[str]:
    lines = [f'points: {s["points"]} ({s["matched_points"]} matched, '
             f'{s["unmatched_points"]} unmatched = {100 * s["unmatched_fraction"]:.2f} %)',
             f'range RMSE: {s["range_rmse_m"]:.4f} m   NLL: {s["nll_per_point"]:.3f} per point'
             f'   (per-material offsets refit: {s["range_rmse_calibrated_m"]:.4f} m, '
             f'{s["nll_calibrated"]:.3f})']
    for e in s['fitted_effects']:
        params = ', '.join(f'{k} = {v:.6g}' if isinstance(v, float) else f'{k} = {v}'
                           for k, v in e['params'].items())
        lines.append(f'fitted {e["name"]}: {params}')
    lines.append('features: ' + ', '.join(f'{f["name"]} {f["score"]:.4f}'
                                          for f in s['features'][:4]))
    lines.append('candidates: ' + ', '.join(
        f'{c["name"]} {c["score"]:.4f}' if c['score'] is not None else f'{c["name"]} failed'
        for c in s['candidates']))
    lines.append(f'missing effect: {s["missing_effect"]}')
    lines.append(f'verdict: {s["verdict"]}')
    lines += [f'wrote {p}' for p in files]
    return lines
