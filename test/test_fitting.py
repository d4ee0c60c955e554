"""Fitting effects to measurements: the likelihood, and recovery of hidden effects.

Measured data come from the simulator with one effect added, on a scene of our own
(a two-material cylinder in front of a panel, tumbling and approaching; P-60 optics
with half the shots), other magnitudes than the defaults and fixed seeds. Each fit
must recover its parameters and bring the NLL / RMSE down to what the true model
gives; on clean data (and on a per-material bias/sigma mismatch) no fit may gain.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import (EffectConfig, MaterialsConfig, SensorConfig, parse)
from lidar_sim_ros.compare.model.fit import fit_data_from_rays, fit_effect
from lidar_sim_ros.compare.model.likelihood import (MISS_WEIGHT, MODEL_FLOOR, FitData, evaluate,
                                                    model_on_rays, point_nll)
from lidar_sim_ros.core.effects import catalogue, get_effect_class, make_effect
from lidar_sim_ros.core.geometry import Hits, Target
from lidar_sim_ros.core.pipeline import Prediction, Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory

REPO = Path(__file__).resolve().parents[1]
DRIFT = f"{REPO / 'examples' / 'drift_effect.py'}:DriftInFrame"

MATERIALS = MaterialsConfig(materials=[
    dict(name='PAINT', kd=0.5, ks=0.05, n=2.0, bias_m=-0.06, sigma_m=0.02),
    dict(name='FOIL', kd=0.1, ks=0.6, n=15.0, bias_m=-0.09, sigma_m=0.025),
    dict(name='PANEL', kd=0.3, ks=0.2, n=5.0, bias_m=-0.07, sigma_m=0.022)])


def scene_target() -> Target:
    """Cylinder (r 1 m, 4 m long; PAINT side, FOIL caps) and a PANEL plate 2.5 m behind it."""
    cyl = trimesh.creation.cylinder(radius=1.0, height=4.0, sections=48)
    caps = np.abs(cyl.face_normals[:, 2]) > 0.9
    panel = trimesh.creation.box(extents=(3.0, 0.05, 5.0))
    panel.apply_translation((0.0, 2.5, 0.0))
    faces = np.vstack([cyl.faces, panel.faces + len(cyl.vertices)])
    material = np.concatenate([np.where(caps, 1, 0), np.full(len(panel.faces), 2)])
    return Target(np.vstack([cyl.vertices, panel.vertices]), faces, material, MATERIALS.names)


@functools.lru_cache(maxsize=1)
def scene() -> tuple[SensorConfig, Target, ScenarioTrajectory]:
    data = yaml.safe_load((REPO / 'config' / 'cepton_vista_p60.yaml').read_text())
    data['scan']['shots_per_laser'] = 440
    sensor = parse(SensorConfig, data, 'test sensor')
    # Cylinder axis (body z) across the view (lidar y), panel (body +y) behind it (+x),
    # yawed 25 deg so a cap shows; tumbling at 15 deg/s and closing at 0.3 m/s.
    rot0 = (Rotation.from_euler('z', 25, degrees=True)
            * Rotation.from_matrix([[0, 1, 0], [0, 0, 1], [1, 0, 0]]))
    axis = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    traj = ScenarioTrajectory(np.array([8.0, 0.3, -0.2]), rot0, 0.3, axis, np.radians(15.0))
    return sensor, scene_target(), traj


def model_sim(effects=(), materials=MATERIALS, seed=5) -> Simulator:
    sensor, target, _ = scene()
    return Simulator(sensor, materials, target, seed=seed, effects=list(effects))


@functools.lru_cache(maxsize=None)
def dataset(case: str, seed: int = 5, frame: int = 3) -> tuple[FitData, list]:
    """FitData of one simulated frame with the case's hidden effect, against the clean model."""
    hidden = HIDDEN[case]
    effects = [] if hidden is None else [make_effect(*hidden)]
    materials = MISMATCHED if case == 'materials' else MATERIALS
    truth = model_sim(effects, materials, seed)
    traj = scene()[2]
    fr = truth.simulate_frame(frame * truth.frame_period_s, traj, frame)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    clean = model_sim()
    data = fit_data_from_rays(clean, fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s,
                              laser=fr.ring, n_shots=len(clean.shots))
    return data, effects


MISMATCHED = MaterialsConfig(materials=[
    m.model_copy(update={'bias_m': m.bias_m + 0.04, 'sigma_m': m.sigma_m * 1.3})
    for m in MATERIALS.materials])

HIDDEN = {
    'clean': None,
    'materials': None,
    'range_walk': ('range_walk', {'k_m': 0.015}),
    'incidence_angle': ('incidence_angle', {'bias_gain': -1.5, 'sigma_gain': 0.8}),
    'snr_noise': ('snr_noise', {'c_m': 0.4}),
    # Over the whole 250 m gate: a first-return receiver records on the target (~10 m)
    # only the crossings before the echo, ~4 % of them.
    'solar_background': ('solar_background', {'probability': 0.3}),
    'beam_divergence': ('beam_divergence', {'footprint_scale': 6.0}),
    'time_offset': ('time_offset', {'dt_s': -0.07}),
    'drift': (DRIFT, {'rate_m_per_s': 0.6}),
}


def all_candidates() -> dict:
    return {**catalogue(), 'drift_in_frame': get_effect_class(DRIFT)}


@functools.lru_cache(maxsize=None)
def fits(case: str) -> dict:
    data, _ = dataset(case)
    return {name: fit_effect(cls, data) for name, cls in all_candidates().items()}


# ------------------------------------------------------------------ the likelihood
def handmade_data(residual_m, sigma_m, window=(0.0, 100.0)) -> FitData:
    """Matched points with a known expected range, sigma and residual."""
    from lidar_sim_ros.core.effects import ReturnContext
    n = len(residual_m)
    rng = np.full(n, 10.0)
    ctx = ReturnContext(range_m=rng, incidence_rad=np.zeros(n), material=np.zeros(n, int),
                        power_w=np.ones(n), intensity=np.ones(n), t_s=np.zeros(n),
                        az_rad=np.zeros(n), el_rad=np.zeros(n), laser=np.zeros(n, int),
                        divergence_rad=0.002, hit=np.ones(n, bool), threshold_power_w=0.1)
    hits = Hits(np.ones(n, bool), rng, np.zeros((n, 3)), np.zeros(n), np.zeros(n, int),
                np.zeros(n, int))
    pred = Prediction(ctx, hits, np.tile([1.0, 0, 0], (n, 1)), np.zeros(n), np.full(n, sigma_m))
    return FitData(measured_range_m=rng + residual_m, baseline=pred, cast=lambda e: pred,
                   unmatched_range_m=np.zeros(0), cast_unmatched=lambda e: pred,
                   range_window_m=window)


def test_nll_is_the_gaussian_and_outlier_mixture():
    z = np.array([0.0, 1.0, -2.0, 3.0])
    sigma = 0.03
    data = handmade_data(z * sigma, sigma)
    gauss = 0.5 * z ** 2 + np.log(sigma) + 0.5 * np.log(2 * np.pi)
    floor = MODEL_FLOOR                 # the least outlier weight of the predictive density
    mixed = (1 - floor) * np.exp(-gauss) + floor / 100.0
    nll, rmse, _ = evaluate(data, [], profile_materials=False)
    assert nll == pytest.approx(np.mean(-np.log(mixed)), rel=1e-12)
    assert nll == pytest.approx(gauss.mean(), abs=1e-5)
    assert rmse == pytest.approx(np.sqrt(np.mean((z * sigma) ** 2)), rel=1e-12)
    p = 0.1
    w = 1 - (1 - p) * (1 - floor)
    mixed = (1 - w) * np.exp(-gauss) + w / 100.0
    nll_p, _, _ = evaluate(data, [make_effect('solar_background', {'probability': p,
                                                                   'first_return': False})],
                           profile_materials=False)
    assert nll_p == pytest.approx(np.mean(-np.log(mixed)), rel=1e-12)


def test_material_nuisance_absorbs_a_constant_offset_and_scale():
    rng = np.random.default_rng(0)
    z = rng.standard_normal(4000)
    data = handmade_data(0.05 + 1.5 * 0.02 * z, 0.02)
    truth = handmade_data(1.5 * 0.02 * z, 1.5 * 0.02)
    nll, rmse, _ = evaluate(data, [])
    nll_true, rmse_true, _ = evaluate(truth, [], profile_materials=False)
    assert nll == pytest.approx(nll_true, abs=0.01)
    assert rmse == pytest.approx(rmse_true, rel=0.01)


def test_fit_data_splits_matched_and_unmatched_rays():
    data, _ = dataset('beam_divergence')
    assert len(data.measured_range_m) > 2000
    assert len(data.unmatched_range_m) > 50                 # returns beyond the silhouettes
    assert data.baseline.ctx.hit.all()
    assert not data.cast_unmatched([]).ctx.hit.any()
    assert data.n_shots == len(model_sim().shots)


# ---------------------------------------------------------------- no false alarms
def noise_gain_per_point(k: int, n_points: int) -> float:
    """What a fit of k free parameters can gain on pure noise (nats a point): twice the
    NLL gain is chi-square with k degrees of freedom, so mean k / 2 plus 4 sd (sqrt(2k) / 2)
    over the points; at least 0.002. laser_bias frees 24 per-laser offsets: on clean data
    it gains 0.0003-0.0025 a point by seed (seeds 5-7, 4,375 points), its chi-square mean
    being 0.0027 (the 0.002 that held for seed 5 was that seed's luck: seed 7 broke it)."""
    return max(0.002, (k + 4.0 * np.sqrt(2.0 * k)) / (2.0 * n_points))


@pytest.mark.parametrize('case', ['clean', 'materials'])
def test_no_effect_gains_on_clean_data_or_a_material_mismatch(case):
    results = fits(case)
    n_points = len(dataset(case)[0].measured_range_m)
    for name, r in results.items():
        allowed = noise_gain_per_point(len(r.params), n_points)
        assert r.robust_gain_per_point < allowed, name
        assert r.nll_gain_per_point < allowed, name
        assert r.range_rmse_m > r.range_rmse_before_m - 2e-4, name
        assert r.unmatched_explained == 0.0, name
    p = {name: r.params for name, r in results.items()}
    assert abs(p['range_walk']['k_m']) < 0.003
    assert abs(p['incidence_angle']['bias_gain']) < 0.25
    assert p['solar_background']['probability'] < 1e-3
    assert p['beam_divergence']['footprint_scale'] < 1.0
    assert abs(p['time_offset']['dt_s']) < 0.005
    assert abs(p['drift_in_frame']['rate_m_per_s']) < 0.1


# ------------------------------------------------------------------- recovery
RECOVERY = {
    # case: {param: (true value, absolute tolerance)}
    'range_walk': {'k_m': (0.015, 0.002)},
    'incidence_angle': {'bias_gain': (-1.5, 0.25), 'sigma_gain': (0.8, 0.3)},
    'snr_noise': {'c_m': (0.4, 0.15)},
    'solar_background': {'probability': (0.3, 0.08)},
    'beam_divergence': {'footprint_scale': (6.0, 1.0)},
    'time_offset': {'dt_s': (-0.07, 0.005)},
    'drift': {'rate_m_per_s': (0.6, 0.08)},
}
BIAS_TYPE = {'range_walk', 'incidence_angle', 'beam_divergence', 'time_offset', 'drift'}


def tolerance_nll(case: str, data: FitData) -> float:
    """How far above the true model's NLL a fit may end (nats per point).

    Effects that move the raycast (pose time, footprint) have a likelihood with
    steps: a ray within a fraction of a millimetre of a depth step changes surface
    when the parameter moves by a hair, costing ~15 nats. The true parameter puts
    those rays exactly where the simulation did; a fit a hair away may lose a few.
    """
    raycast = case in ('time_offset', 'beam_divergence')
    return 0.005 + (3 * 15.0 / len(data.measured_range_m) if raycast else 0.0)


@pytest.mark.parametrize('case', list(RECOVERY))
def test_fit_recovers_the_hidden_effect_and_reaches_the_noise_floor(case):
    data, true_effects = dataset(case)
    results = fits(case)
    name = 'drift_in_frame' if case == 'drift' else case
    r = results[name]
    for param, (value, tol) in RECOVERY[case].items():
        assert r.params[param] == pytest.approx(value, abs=tol), param
    # The floor: what the model with the true effect scores on the same data.
    nll_true, rmse_true, _ = evaluate(data, true_effects)
    assert r.nll_per_point < nll_true + tolerance_nll(case, data)
    assert r.nll_per_point < r.nll_before_per_point - 0.01
    if case in BIAS_TYPE:
        assert r.range_rmse_m < 1.02 * rmse_true
        assert r.range_rmse_m < 0.95 * r.range_rmse_before_m
    # The hidden effect is the best candidate by the robust gain.
    best = max(results, key=lambda k: results[k].robust_gain_per_point)
    assert best == name
    # Its snippet is a scenario entry that loads the fitted effect back.
    entry = EffectConfig(**yaml.safe_load(r.yaml_snippet)[0])
    again = make_effect(entry.name, entry.params)
    for param in RECOVERY[case]:
        assert getattr(again.params, param) == pytest.approx(r.params[param], rel=1e-5)


def test_outlier_and_edge_effects_explain_the_unmatched_points():
    solar = fits('solar_background')
    assert solar['solar_background'].unmatched_explained > 0.6
    assert solar['beam_divergence'].unmatched_explained < 0.1
    beam = fits('beam_divergence')
    assert beam['beam_divergence'].unmatched_explained > 0.9
    assert beam['solar_background'].unmatched_explained < 0.1   # edge points are not uniform
    offset = fits('time_offset')
    assert offset['time_offset'].unmatched_explained > 0.9


def test_fit_on_top_of_another_effect():
    """Two hidden effects: fit the time offset first, then the walk on top of it."""
    sensor, target, traj = scene()
    hidden = [make_effect('time_offset', {'dt_s': 0.05}), make_effect('range_walk', {'k_m': -0.02})]
    truth = model_sim(hidden, seed=8)
    fr = truth.simulate_frame(0.4, traj, 4)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    data = fit_data_from_rays(model_sim(), fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s)
    offset = fit_effect(get_effect_class('time_offset'), data)
    # The offset fitted first, the walk not yet modelled, comes out low: 0.041-0.046 s over
    # seeds 8-11 with either draw of the range noise (0.0438 here).
    assert offset.params['dt_s'] == pytest.approx(0.05, abs=0.01)
    walk = fit_effect(get_effect_class('range_walk'), data, [offset.effect])
    assert walk.params['k_m'] == pytest.approx(-0.02, abs=0.003)
    nll_true, _, _ = evaluate(data, hidden)
    assert walk.nll_per_point < nll_true + tolerance_nll('time_offset', data)
    assert walk.nll_before_per_point == pytest.approx(offset.nll_per_point)


@pytest.mark.parametrize('seed', [8, 10])
def test_two_effects_that_share_the_residual_are_refitted_together(seed):
    """A range walk (k 0.02) and an incidence elongation (bias_gain 0.5) at once: grazing
    returns are weak and long, so the walk fitted first takes much of the incidence's
    share (k 0.030-0.032, the incidence on top 0.10-0.12 over seeds 8-10); refitted each
    with the other in the model until they settle (``variants.refit_in_turn``, what --fit does
    with several effects), both come back to the truth."""
    from lidar_sim_ros.compare.diagnose.variants import refit_in_turn
    sensor, target, traj = scene()
    hidden = [make_effect('range_walk', {'k_m': 0.02}),
              make_effect('incidence_angle', {'bias_gain': 0.5})]
    fr = model_sim(hidden, seed=seed).simulate_frame(0.0, traj, 0)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    data = fit_data_from_rays(model_sim(), fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s)
    walk = fit_effect(get_effect_class('range_walk'), data)
    inc = fit_effect(get_effect_class('incidence_angle'), data, [walk.effect])
    assert walk.params['k_m'] > 0.027 and inc.params['bias_gain'] < 0.2   # in turn
    walk_j, inc_j = refit_in_turn(data, [walk.effect, inc.effect], [{}, {}])
    assert walk_j.params.k_m == pytest.approx(0.02, rel=0.1)
    assert inc_j.params.bias_gain == pytest.approx(0.5, rel=0.1)


def test_unplaced_points_score_as_spurious_returns():
    data, _ = dataset('clean')
    far = make_effect('time_offset', {'dt_s': 0.5})                   # the target has moved on
    model = model_on_rays(data, [far])
    assert 0 < (~model.placed).sum() < len(model.placed)
    nll, _ = point_nll(data, model)
    assert np.all(np.isfinite(nll))
    # An unplaced point is a spurious return of weight MISS_WEIGHT, uniform over the window.
    assert nll[~model.placed] == pytest.approx(-np.log(MISS_WEIGHT / data.window_width_m))


# ------------------------------------------------------- surface offset: fitted jointly
def box_target(extents_m) -> Target:
    """A box about the body origin, one material per axis (PAINT x, FOIL y, PANEL z):
    the plane of each face lies half its extent from the origin."""
    box = trimesh.creation.box(extents=extents_m)
    material = np.argmax(np.abs(box.face_normals), axis=1)
    return Target(np.asarray(box.vertices, float), np.asarray(box.faces), material,
                  MATERIALS.names)


def test_surface_offset_fit_recovers_a_box_standing_proud():
    """The recording is a raycast of a real box 3 cm proud of the mesh on every face
    (extents + 6 cm); the model is the mesh box. The surface_offset fit estimates the
    standoff on 1 / cos(theta) and the scale on d / cos(theta) (d = 0.6 to 1.5 m, the
    faces' planes) with the material intercepts as nuisance, and keeps the parameter the
    data pay for: the standoff (0.0269 m, seed 9), no scale. Before, only the scale was
    fitted: a uniform standoff could not be represented (no standoff_m in the fit)."""
    sensor, _, traj = scene()
    extents = np.array([3.0, 2.0, 1.2])
    truth_sim = Simulator(sensor, MATERIALS, box_target(extents + 0.06), seed=9, effects=[])
    fr = truth_sim.simulate_frame(0.3, traj, 3)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    model = Simulator(sensor, MATERIALS, box_target(extents), seed=9, effects=[])
    data = fit_data_from_rays(model, fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s)
    assert len(data.measured_range_m) > 2000
    r = fit_effect(get_effect_class('surface_offset'), data)
    assert r.params['standoff_m'] == pytest.approx(0.03, rel=0.15)
    assert r.params['scale'] == 0.0
    assert r.nll_per_point < r.nll_before_per_point - 0.005


def test_surface_offset_fit_recovers_one_material_standing_proud():
    """The same box with only its PANEL faces (the z pair) 3 cm proud,
    blankets over one material: a standoff of PANEL's own (1 / cos(theta) over its
    surfaces), none on the others, no common standoff. A common standoff alone would be
    the 3 cm diluted by the FOIL face's 0. (A face seen at one angle cannot show its
    standoff: after the material's intercept only the spread of 1 / cos(theta) over it
    does: on frame 3, FOIL at 28-35 deg, the common 3.4 cm fits as well and is kept,
    being first.)"""
    sensor, _, traj = scene()
    extents = np.array([3.0, 2.0, 1.2])
    truth_sim = Simulator(sensor, MATERIALS, box_target(extents + [0.0, 0.0, 0.06]), seed=9,
                          effects=[])
    fr = truth_sim.simulate_frame(1.2, traj, 12)   # both faces at 42-57 deg, spread 7-9 deg
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    model = Simulator(sensor, MATERIALS, box_target(extents), seed=9, effects=[])
    data = fit_data_from_rays(model, fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s)
    r = fit_effect(get_effect_class('surface_offset'), data)
    assert r.params['standoff_PANEL_m'] == pytest.approx(0.03, rel=0.15)
    assert r.params['standoff_m'] == 0.0 and r.params['scale'] == 0.0
    assert 'standoff_FOIL_m' not in r.params
    assert r.effect.params.material_standoff_m == {'PANEL': r.params['standoff_PANEL_m']}


def cylinder_only(radius_m: float, height_m: float, sections: int = 256) -> Target:
    """A closed faceted cylinder about the body z axis, PAINT side, FOIL caps."""
    cyl = trimesh.creation.cylinder(radius=radius_m, height=height_m, sections=sections)
    caps = np.abs(cyl.face_normals[:, 2]) > 0.9
    return Target(np.asarray(cyl.vertices, float), np.asarray(cyl.faces),
                  np.where(caps, 1, 0), MATERIALS.names)


@pytest.mark.parametrize('seed', [9])
def test_surface_offset_fit_recovers_a_cylinder_standing_proud(seed):
    """The recording is a raycast of a real cylinder 4 cm proud of the mesh (radius and
    length: trimesh's cylinder of radius 1.04 m, 4.08 m long, an offset built apart from
    the effect's), the model the bare cylinder. The first-order columns alone (the fit
    before its refinement on the exact surface) gave 2.54 cm on every ray (docs/compare.md,
    "Why surface_offset's fitted standoffs run low"): the grazing rays' change is bounded by
    sqrt(2 R s) where -s / cos(theta) grows without bound. Refined on the exact surface
    the standoff is the truth within 5 %."""
    sensor, _, traj = scene()
    truth_sim = Simulator(sensor, MATERIALS, cylinder_only(1.04, 4.08), seed=seed, effects=[])
    fr = truth_sim.simulate_frame(0.3, traj, 3)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    model = Simulator(sensor, MATERIALS, cylinder_only(1.0, 4.0), seed=seed, effects=[])
    data = fit_data_from_rays(model, fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s)
    assert len(data.measured_range_m) > 2000
    r = fit_effect(get_effect_class('surface_offset'), data)
    standoff = r.params['standoff_m'] + r.params.get('standoff_PAINT_m', 0.0)
    assert standoff == pytest.approx(0.04, rel=0.05)
    assert r.nll_per_point < r.nll_before_per_point - 0.005
