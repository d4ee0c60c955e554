"""A scenario loaded with files given instead of its own (core/scenario.py; the node's
sensor_file, materials_file and mesh_file parameters)."""
import numpy as np
import pytest

from lidar_sim_ros.core.config import ConfigError, load_materials
from conftest import CONFIG

TABLE_2 = load_materials(CONFIG / 'materials.yaml')


def test_a_sensor_given_instead_brings_its_own_range_error():
    """The node loaded the scenario, then swapped the sensor: the P-60 scenario with
    sensor_file livox_mid40.yaml simulated the Mid-40 with the P-60's Table 2 errors, and
    the Mid-40 scenario with the P-60's sensor file kept the Mid-40's 2 cm on every
    material (rc 0 both, the wrong range errors)."""
    from lidar_sim_ros.core.scenario import load_scenario
    mid = load_scenario(CONFIG / 'scenario.yaml', sensor_file=CONFIG / 'livox_mid40.yaml')
    assert mid.sensor.scan.type == 'risley'
    assert set(mid.materials.column('sigma_m')) == {0.02} and set(mid.materials.column('bias_m')) == {0.0}
    p60 = load_scenario(CONFIG / 'scenario_mid40.yaml', sensor_file=CONFIG / 'cepton_vista_p60.yaml')
    np.testing.assert_array_equal(p60.materials.column('bias_m'), TABLE_2.column('bias_m'))
    np.testing.assert_array_equal(p60.materials.column('sigma_m'), TABLE_2.column('sigma_m'))
    # Materials given instead: still the Mid-40's own error on each.
    again = load_scenario(CONFIG / 'scenario_mid40.yaml', materials_file=CONFIG / 'materials.yaml')
    assert set(again.materials.column('sigma_m')) == {0.02}


def test_a_materials_file_given_instead_is_checked_against_mesh_materials(tmp_path):
    lone = tmp_path / 'materials.yaml'
    text = (CONFIG / 'materials_box_wing.yaml').read_text()
    assert 'name: ALUMINIUM' in text
    lone.write_text(text.replace('name: ALUMINIUM', 'name: AL'))
    from lidar_sim_ros.core.scenario import load_scenario
    with pytest.raises(ConfigError, match='mesh_materials.antenna_aluminium.*ALUMINIUM'):
        load_scenario(CONFIG / 'scenario_box_wing.yaml', materials_file=lone)


def test_a_missing_mesh_given_instead_names_the_parameter(tmp_path):
    from lidar_sim_ros.core.scenario import load_scenario
    with pytest.raises(ConfigError, match=r'<parameters>.*mesh_file.*nope.glb.*not found'):
        load_scenario(CONFIG / 'scenario.yaml', mesh_file=tmp_path / 'nope.glb')
    sc = load_scenario(CONFIG / 'scenario.yaml', mesh_file=CONFIG.parent / 'meshes' / 'box_wing_satellite.glb')
    assert sc.mesh_path.name == 'box_wing_satellite.glb'


def test_a_mesh_given_instead_takes_a_mesh_materials_map_checked_as_the_scenarios():
    """The node's mesh_file swapped the mesh but kept the scenario's map: the box-wing .glb
    under the rocket body's scenario could not be mapped at all (no parameter for it). The
    node's mesh_materials (YAML text) now maps it, checked as a scenario's map."""
    from lidar_sim_ros.core.geometry import MeshMaterialError
    from lidar_sim_ros.core.pipeline import Simulator
    from lidar_sim_ros.core.scenario import load_scenario
    glb = CONFIG.parent / 'meshes' / 'box_wing_satellite.glb'
    plain = load_scenario(CONFIG / 'scenario.yaml', mesh_file=glb)
    with pytest.raises(MeshMaterialError, match=r"box_wing_satellite.glb: .*\['antenna_aluminium', "
                                                r"'bus_mli', .*node's mesh_materials parameter"):
        Simulator.from_scenario(plain)
    mapping = '{bus_mli: MLI, solar_cells: PIF, radiator_white_paint: PSS, antenna_aluminium: PAF}'
    sc = load_scenario(CONFIG / 'scenario.yaml', mesh_file=glb, mesh_materials=mapping)
    sim = Simulator.from_scenario(sc)
    used = {sc.materials.names[m] for m in np.unique(sim.target.face_material)}
    assert used == {'MLI', 'PIF', 'PSS', 'PAF'}
    whole = load_scenario(CONFIG / 'scenario.yaml', mesh_file=glb, mesh_materials='MLI')
    assert {whole.materials.names[m] for m in Simulator.from_scenario(whole).target.face_material} == {'MLI'}
    for text, key, words in (('{bus_mli: GOLD}', 'mesh_materials.bus_mli', 'not a material of materials.yaml'),
                             ('{bus_mli: 3}', 'mesh_materials', 'both the mesh'),
                             ('[MLI]', 'mesh_materials', 'one config material name'),
                             ('{a: MLI, a: PIF}', 'mesh_materials', 'twice'),
                             ('{bus_mli: MLI', 'mesh_materials', 'not valid YAML')):
        with pytest.raises(ConfigError, match=rf'<parameters>: key "{key}".*{words}'):
            load_scenario(CONFIG / 'scenario.yaml', mesh_file=glb, mesh_materials=text)
