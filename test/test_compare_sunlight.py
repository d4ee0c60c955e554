"""compare/diagnose/sunlight.py: the receiver factor fitted back from false returns on sunlit and
shadowed surfaces, the sun track read from a bag, and ``lidar-sim compare`` on recordings
with and without the sun."""
from __future__ import annotations

import json

import numpy as np
import pytest

from lidar_sim_ros.cli import main
from lidar_sim_ros.compare.run import CompareOptions, run_compare
from lidar_sim_ros.compare.diagnose.sunlight import (FalseReturnLikelihood, false_return_mask,
                                                     fit_background_scale, read_sun_track,
                                                     short_points)
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.effects import make_effect
from lidar_sim_ros.core.geometry import load_target
from lidar_sim_ros.core.pipeline import NO_MATERIAL, Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.core.sun import ScenarioSun
from lidar_sim_ros.io.bag import BagWriter
from lidar_sim_ros.offline import simulate_to_bag
from lidar_sim_ros.paths import config_path

TRUE_SCALE = 3.0
FRAMES = 4


@pytest.fixture(scope='module')
def recording():
    """Frames of the sunlit scenario whose receiver collects 3x the sensor file's background."""
    scenario = load_scenario(config_path('scenario_sunlit.yaml'))
    traj = ScenarioTrajectory.from_config(scenario.config)
    truth = Simulator.from_scenario(scenario, effects=[
        make_effect('sunlight', {'background_scale': TRUE_SCALE})])
    frames = [truth.simulate_frame(k * 0.1, traj, k) for k in range(FRAMES)]
    return scenario, traj, frames


def test_fit_recovers_the_receiver_factor(recording):
    scenario, traj, frames = recording
    model = Simulator.from_scenario(scenario)              # background_scale 1: the file's receiver
    t = np.concatenate([f.stamp_s + f.t_s for f in frames])
    xyz = np.concatenate([f.xyz_m for f in frames])
    measured = np.linalg.norm(xyz, axis=1)
    pred = model.predict(t, xyz / measured[:, None], traj)
    is_false = false_return_mask(measured, pred.expected_range_m, pred.sigma_m)
    # The range rule finds the simulated false returns on target rays (material 255), all
    # but those within 5 sigma of the echo.
    material = np.concatenate([f.material for f in frames])
    simulated = (material == NO_MATERIAL) & pred.ctx.hit
    found = is_false & pred.ctx.hit
    assert np.all(simulated[found])
    missed = simulated & ~found
    assert missed.sum() <= 0.05 * simulated.sum()
    assert np.all(measured[missed] > pred.expected_range_m[missed] - 6 * pred.sigma_m[missed])

    fit = fit_background_scale(pred.ctx, is_false)
    nll = FalseReturnLikelihood(pred.ctx, is_false)
    # The truth lies inside the 2-nat likelihood interval (about 2 sigma), g = 1 far outside.
    assert nll(TRUE_SCALE) - fit.nll < 2.0, fit
    assert fit.nll_unit - fit.nll > 10, fit
    assert fit.sunlit_false > 50 and fit.shadowed_rate < 0.1 * fit.sunlit_rate, fit
    assert fit.predicted_sunlit_rate == pytest.approx(fit.sunlit_rate, rel=0.3)
    assert fit.yaml_snippet.startswith('- {name: sunlight, params: {background_scale: ')


def test_read_sun_track_from_a_bag(tmp_path):
    bag = tmp_path / 'bag'
    with BagWriter(bag) as writer:
        writer.write_vector3('/sun/direction', 2_000_000_000, 'lidar', (0.0, 2.0, 0.0))
        writer.write_vector3('/sun/direction', 1_000_000_000, 'lidar', (2.0, 0.0, 0.0))
        writer.write_string('/other', 1, 'x')
    track = read_sun_track(bag)
    light = track.at(np.array([0.5, 1.5, 3.0]))
    np.testing.assert_allclose(light.sun_direction, [[1, 0, 0], [np.sqrt(0.5), np.sqrt(0.5), 0],
                                                     [0, 1, 0]], atol=1e-12)
    assert read_sun_track(bag, topic='/no_sun') is None


# ------------------------------------------------ lidar-sim compare on a recording with the sun
BAG_SCALE = 2.5      # the receiver factor hidden in the recorded bag
BAG_SEED = 11        # not the scenario's own


def _bag(root, name: str, with_sun: bool):
    """3 frames of the sunlit scenario as a bag: with the sun (and its /sun/direction
    topic) and sunlight at BAG_SCALE, or without either."""
    scenario = load_scenario(config_path('scenario_sunlit.yaml'))
    target = load_target(scenario.mesh_path, scenario.materials.names)
    sun = ScenarioSun(scenario.config.sun) if with_sun else None
    effects = [make_effect('sunlight', {'background_scale': BAG_SCALE})] if with_sun else []
    sim = Simulator(scenario.sensor, scenario.materials, target, BAG_SEED, effects,
                    scenario.source.parent, sun)
    simulate_to_bag(scenario, root / name, 3, start_s=0.4, simulator=sim, figures=False)
    return root / name / 'bag', scenario.mesh_path


@pytest.fixture(scope='module')
def sunlit_bag(tmp_path_factory):
    return _bag(tmp_path_factory.mktemp('sun_bag'), 'sunlit', with_sun=True)


def _compare(bag, mesh, out, **kw):
    kw = {'candidates': [], **kw}
    return run_compare(CompareOptions(bag=bag, mesh=mesh, out=out, report=False,
                                      progress=False, **kw)).summary


def test_compare_fits_the_receiver_factor_of_a_recording_with_the_sun(sunlit_bag, tmp_path):
    bag, mesh = sunlit_bag
    s = _compare(bag, mesh, tmp_path / 'base', candidates=['solar_background'])
    sun = s['sunlight']
    lo, hi = sun['background_scale_interval_95']
    assert lo <= BAG_SCALE <= hi, sun
    assert abs(sun['background_scale'] - BAG_SCALE) <= 2 * sun['background_scale_sigma'], sun
    assert sun['background_scale_sigma'] < 0.1 * BAG_SCALE          # the data do constrain it
    assert sun['sun_samples'] == 3 and sun['topic'] == '/sun/direction'
    assert sun['sunlit_false_returns'] >= 50
    assert sun['shadowed_rate'] <= 0.1 * sun['sunlit_rate']
    assert sun['supported'] and sun['excess_p_value'] < 1e-6
    assert sun['predicted_sunlit_rate'] == pytest.approx(sun['sunlit_rate'], rel=0.3)
    assert sun['model_background_scale'] is None
    assert '--effect sunlight --fit' in s['verdict']
    # The false returns are named as what the sun test showed them to be, not as the
    # phenomenological candidate that scored them.
    assert s['missing_effect'] == 'sunlight', s['verdict']
    assert s['verdict'].startswith('This is false returns from sunlight') or \
        'This is false returns from sunlight' in s['verdict']

    # The loop's next step: the fitted sunlight in the model explains the false returns.
    out = tmp_path / 'fit'
    code = main(['compare', str(bag), '--mesh', str(mesh), '--out', str(out), '--effect',
                 'sunlight', '--fit', '--candidates', 'solar_background', '--no-report'])
    assert code == 0
    fitted = json.loads((out / 'summary.json').read_text())
    assert fitted['sunlight']['background_scale'] == pytest.approx(sun['background_scale'],
                                                                    rel=1e-3)
    assert fitted['fitted_effects'][0]['params']['background_scale'] == pytest.approx(
        sun['background_scale'], rel=1e-3)
    assert 'name: sunlight' in (out / 'effects.yaml').read_text()
    assert fitted['nll_calibrated'] < s['nll_calibrated'] - 0.01
    assert fitted['missing_effect'] is None, fitted['verdict']  # nothing left to name


def test_compare_without_the_sun_is_unchanged(tmp_path, capsys):
    bag, mesh = _bag(tmp_path, 'dark', with_sun=False)
    s = _compare(bag, mesh, tmp_path / 'out')
    assert 'sunlight' not in s and 'sun direction' not in s['verdict']
    # Sunlight needs the sun: one clear error, naming the topic.
    code = main(['compare', str(bag), '--mesh', str(mesh), '--out', str(tmp_path / 'x'),
                 '--effect', 'sunlight', '--candidates', '--no-report'])
    assert code == 2 and "'/sun/direction'" in capsys.readouterr().err
    code = main(['compare', str(bag), '--mesh', str(mesh), '--out', str(tmp_path / 'y'),
                 '--sun-topic', '/my/sun', '--candidates', '--no-report'])
    assert code == 2 and "no sun directions on '/my/sun'" in capsys.readouterr().err


def test_short_points_tell_clutter_from_false_returns():
    """A cable 3 m in front of a plate at 10 m is a surface; isolated early returns are not."""
    az, el = np.meshgrid(np.radians(np.linspace(-5, 5, 41)), np.radians(np.linspace(-5, 5, 41)))
    d = np.column_stack([np.cos(el.ravel()) * np.cos(az.ravel()),
                         np.cos(el.ravel()) * np.sin(az.ravel()), np.sin(el.ravel())])
    n = len(d)
    sigma = np.full(n, 0.02)
    rng = np.random.default_rng(3)
    measured = 10.0 + rng.normal(0.0, 0.02, n)
    cable = np.flatnonzero(np.abs(el.ravel()) < np.radians(0.1))      # one row of rays
    measured[cable] = 3.0 + rng.normal(0.0, 0.02, len(cable))
    false = np.setdiff1d(rng.choice(n, 30, replace=False), cable)
    measured[false] = rng.uniform(1.0, 9.0, len(false))
    pts = short_points(measured, measured - 10.0, sigma, np.zeros(n, int), d, np.zeros(n, int))
    assert pts.short[cable].all() and pts.short[false].all()
    assert pts.short.sum() == len(cable) + len(false)
    assert pts.on_surface[cable].mean() > 0.9
    assert not pts.on_surface[false].any()
    np.testing.assert_allclose(pts.counted_below_m[0], 10.0 - 5 * 0.02, atol=0.01)
