"""lidar_sim_node in process: its effect plugins (a scenario's plugin loads from beside the
scenario only, and once running no parameter value outside the allow-list loads anything)
and its file parameters."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import rclpy
from rclpy.parameter import Parameter

from lidar_sim_ros.paths import config_path
from lidar_sim_ros.ros.lidar_sim_node import LidarSimNode
from conftest import private_domain_id

PLUGIN = '''
from pathlib import Path
Path(__file__).with_suffix('.ran').write_text('imported')  # proof that this file ran
from lidar_sim_ros.core.effects import Effect

class Mine(Effect):
    name = 'mine'
    where = {where!r}
'''


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=private_domain_id(160, 20))
    yield ctx
    rclpy.shutdown(context=ctx)


def test_scenario_plugin_beside_the_scenario_and_an_allow_list_at_run_time(tmp_path, context,
                                                                          monkeypatch):
    scenario_dir, elsewhere = tmp_path / 'scenario', tmp_path / 'cwd'
    scenario_dir.mkdir(), elsewhere.mkdir()
    (scenario_dir / 'my_effect.py').write_text(PLUGIN.format(where='beside'))
    (elsewhere / 'my_effect.py').write_text(PLUGIN.format(where='cwd'))   # must never run
    text = Path(config_path('scenario.yaml')).read_text()
    base = Path(config_path('scenario.yaml')).parent
    for key in ('sensor', 'materials', 'mesh'):              # the shipped files, absolute
        text = text.replace(f'{key}: ', f'{key}: {base}/', 1)
    text = text.replace('effects: []', 'effects: [{name: "my_effect.py:Mine"}]')
    (scenario_dir / 'scenario.yaml').write_text(text)
    monkeypatch.chdir(elsewhere)

    node = LidarSimNode(context=context, parameter_overrides=[
        Parameter('scenario_file', Parameter.Type.STRING, str(scenario_dir / 'scenario.yaml'))])
    try:
        node.setup()
        assert [type(e).where for e in node.sim.effects] == ['beside']
        assert not (elsewhere / 'my_effect.ran').exists(), 'a file in the current directory ran'

        (tmp_path / 'a=b').mkdir()
        planted = tmp_path / 'a=b' / 'evil.py'
        planted.write_text(PLUGIN.format(where='network'))
        for value in ([f'{planted}:Mine'], [str(planted)], ['my_effect.py:Mine', f'{planted}:Mine'],
                      [f'{elsewhere}/my_effect.py:Mine'], ['os.path:join']):
            result = node.set_parameters([Parameter('effects', Parameter.Type.STRING_ARRAY, value)])[0]
            assert not result.successful and 'never load code' in result.reason, (value, result)
        assert not planted.with_suffix('.ran').exists()
        assert not (elsewhere / 'my_effect.ran').exists()
        # The catalogue and the plugin loaded at start-up switch on and off.
        for value in (['range_walk'], [], ['my_effect.py:Mine', 'range_walk']):
            result = node.set_parameters([Parameter('effects', Parameter.Type.STRING_ARRAY, value)])[0]
            assert result.successful, (value, result.reason)
        assert [type(e).__name__ for e in node.sim.effects] == ['Mine', 'RangeWalk']
        assert type(node.sim.effects[0]).where == 'beside'
    finally:
        node.destroy_node()


def test_a_sensor_file_parameter_brings_the_sensors_own_range_error(context):
    """sensor_file swapped the sensor after the scenario was loaded: the P-60 scenario with
    the Mid-40's sensor file published Mid-40 clouds with the P-60's Table 2 range errors."""
    node = LidarSimNode(context=context, parameter_overrides=[
        Parameter('sensor_file', Parameter.Type.STRING, str(config_path('livox_mid40.yaml')))])
    try:
        node.setup()
        assert node.scenario.sensor.scan.type == 'risley'
        assert set(node.sim.materials.column('sigma_m')) == {0.02}
        assert set(node.sim.materials.column('bias_m')) == {0.0}
    finally:
        node.destroy_node()


def test_a_mesh_file_parameter_takes_its_own_mesh_materials(context):
    """mesh_file = the box-wing .glb under the rocket body's scenario: no parameter could map
    its names. mesh_materials (YAML text) maps them; without it start-up stops in one line
    naming the names and the parameter."""
    from lidar_sim_ros.core.geometry import MeshMaterialError
    glb = str(Path(config_path('scenario.yaml')).parent.parent / 'meshes' / 'box_wing_satellite.glb')
    mesh = Parameter('mesh_file', Parameter.Type.STRING, glb)
    node = LidarSimNode(context=context, parameter_overrides=[mesh])
    try:
        with pytest.raises(MeshMaterialError, match=r"\['antenna_aluminium', 'bus_mli', "
                                                    r"'radiator_white_paint', 'solar_cells'\] not "
                                                    r"mapped.*mesh_materials parameter") as err:
            node.setup()
        assert '\n' not in str(err.value)
    finally:
        node.destroy_node()
    node = LidarSimNode(context=context, parameter_overrides=[mesh, Parameter(
        'mesh_materials', Parameter.Type.STRING, '{bus_mli: MLI, solar_cells: PIF, '
        'radiator_white_paint: PSS, antenna_aluminium: PAF}')])
    try:
        node.setup()
        names = node.sim.materials.names
        assert {names[m] for m in node.sim.target.face_material} == {'MLI', 'PIF', 'PSS', 'PAF'}
    finally:
        node.destroy_node()
