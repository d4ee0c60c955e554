"""compare/sunlight.py: the receiver factor fitted back from false returns on sunlit and
shadowed surfaces, and the sun track read from a bag."""
from __future__ import annotations

import numpy as np
import pytest

from lidar_sim_ros.compare.sunlight import (FalseReturnLikelihood, false_return_mask,
                                            fit_background_scale, read_sun_track)
from lidar_sim_ros.core.config import load_scenario
from lidar_sim_ros.core.effects import make_effect
from lidar_sim_ros.core.pipeline import NO_MATERIAL, Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.io.bag import BagWriter
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
