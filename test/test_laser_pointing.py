"""core/effects/laser_pointing.py: each laser's beam off its configured direction.

Closed form: a flat plate at distance d on the lidar x axis, turned by yaw about lidar z
(incidence = |yaw| head-on). A beam along (az, el) meets it at
r = d cos(yaw) / (cos(el) cos(az - yaw)), so a laser whose beam is off by (a, e) measures,
for a shot configured along (phi, 0), r = d cos(yaw) / (cos(e) cos(phi + a - yaw)), to first
order d (1 - tan(yaw) a) head-on: r tan(theta) times the offset along the slope.
"""
from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from lidar_sim_ros.core.config import ConfigError
from lidar_sim_ros.core.effects import effect_from_spec, make_effect
from lidar_sim_ros.core.effects.laser_pointing import offset_directions
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.scan import directions_from_angles
from conftest import embree_range_tol_m, materials, plate_target
from test_effects import facing_plate, line_sensor

D_M, YAW_DEG = 10.0, 50.0


def exact_range_m(az_rad, el_rad, d_m=D_M, yaw_deg=YAW_DEG):
    yaw = np.radians(yaw_deg)
    return d_m * np.cos(yaw) / (np.cos(el_rad) * np.cos(az_rad - yaw))


def test_each_laser_measures_the_range_along_its_own_beam():
    az_deg = [0.0, 0.08, -0.2, 0.03, 0.0]
    el_deg = [0.0, 0.0, 0.05, -0.1, 0.3]
    eff = make_effect('laser_pointing', {'az_offsets_deg': az_deg, 'el_offsets_deg': el_deg})
    sim = Simulator(line_sensor(), materials(), plate_target(6.0), effects=[eff])
    laser = np.arange(len(az_deg) + 1)               # the last laser has no offsets: 0
    nominal = directions_from_angles(np.zeros(len(laser)), np.zeros(len(laser)))
    pred = sim.predict(np.zeros(len(laser)), nominal, facing_plate(D_M, YAW_DEG), laser=laser)
    a = np.radians(np.append(az_deg, 0.0))
    e = np.radians(np.append(el_deg, 0.0))
    expected = exact_range_m(a, e)
    np.testing.assert_allclose(pred.ctx.range_m, expected, atol=embree_range_tol_m(expected))
    # First order: the error is r tan(theta) times the offset along the slope (azimuth
    # here; an offset across it, in elevation, is of second order).
    first = -D_M * np.tan(np.radians(YAW_DEG)) * a
    second = D_M * (a ** 2 + e ** 2) * 3 + 1e-5
    assert np.all(np.abs(pred.ctx.range_m - D_M - first) <= second)
    assert np.abs(first[2]) > 10 * second[2]      # the first-order term is what is seen
    # The prediction keeps the configured directions; the context carries the beams'.
    np.testing.assert_array_equal(pred.directions, nominal)
    np.testing.assert_allclose(pred.ctx.direction, directions_from_angles(a, e), atol=1e-12)


@pytest.mark.parametrize('yaw_deg', [0.0, 30.0, 60.0])
def test_points_lie_on_the_configured_direction_at_the_true_beam_range(yaw_deg):
    a_deg = 0.15
    eff = make_effect('laser_pointing', {'az_offsets_deg': [a_deg], 'el_offsets_deg': [0.0]})
    sim = Simulator(line_sensor(), materials(), plate_target(6.0), seed=2, effects=[eff])
    frame = sim.simulate_frame(0.0, facing_plate(D_M, yaw_deg), 0)
    assert len(frame) > 300
    phi = np.arctan2(frame.xyz_m[:, 1], frame.xyz_m[:, 0])     # the reported direction
    assert np.all(np.abs(phi) <= np.radians(1.0) + 1e-9)       # the configured sweep
    expected = exact_range_m(phi + np.radians(a_deg), 0.0, yaw_deg=yaw_deg)
    np.testing.assert_allclose(frame.range_m, expected, atol=embree_range_tol_m(expected) + 1e-6)
    np.testing.assert_allclose(np.linalg.norm(frame.xyz_m, axis=1), frame.range_m, rtol=1e-6)


def test_no_offsets_change_nothing():
    plain = Simulator(line_sensor(), materials(), plate_target(6.0), seed=4)
    zero = Simulator(line_sensor(), materials(), plate_target(6.0), seed=4,
                     effects=[make_effect('laser_pointing', {'az_offsets_deg': [0.0, 0.0]})])
    pose = facing_plate(D_M, 30.0)
    a, b = plain.simulate_frame(0.0, pose, 0), zero.simulate_frame(0.0, pose, 0)
    np.testing.assert_array_equal(a.xyz_m, b.xyz_m)


def test_offset_directions_turn_by_the_laser_own_angles():
    d = directions_from_angles(np.radians([10.0, -20.0]), np.radians([5.0, -8.0]))
    out = offset_directions(d, np.array([1, 7]), [0.0, 0.5], [0.0, -0.25])
    np.testing.assert_allclose(out, directions_from_angles(np.radians([10.5, -20.0]),
                                                           np.radians([4.75, -8.0])), atol=1e-12)


@pytest.mark.parametrize('params, key', [
    ({'az_offsets_deg': [0.1, float('nan')]}, 'az_offsets_deg'),
    ({'el_offsets_deg': [6.0]}, 'el_offsets_deg'),
    ({'az_offsets_deg': [1e300]}, 'az_offsets_deg'),
    ({'az_offsets_deg': [0.1, 0.2], 'el_offsets_deg': [0.1]}, ''),
    ({'az_offsets_deg': 'x'}, 'az_offsets_deg'),
    ({'pointing': [0.1]}, 'pointing'),
])
def test_bad_offsets_are_refused_naming_the_key(params, key):
    with pytest.raises(ValidationError) as err:
        make_effect('laser_pointing', params)
    assert key in str(err.value)
    import yaml
    with pytest.raises(ConfigError) as cerr:
        effect_from_spec('laser_pointing=' + yaml.safe_dump(params, default_flow_style=True).strip())
    assert 'laser_pointing' in str(cerr.value)


def test_snippet_round_trips():
    eff = make_effect('laser_pointing', {'az_offsets_deg': [0.01, -0.02], 'el_offsets_deg': [0.03, 0.0]})
    snip = eff.to_yaml_snippet()
    assert snip.startswith('- {name: laser_pointing')
    import yaml
    entry = yaml.safe_load(snip)[0]
    assert make_effect(entry['name'], entry['params']).params == eff.params
    assert eff.rms_offset_deg() == pytest.approx(np.sqrt((0.01**2 + 0.02**2 + 0.03**2) / 2))
