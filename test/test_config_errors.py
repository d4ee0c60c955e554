"""Config errors that help: the wrong kind of file, a typo's nearest key, no dumps."""

import pytest
import yaml

from lidar_sim_ros.cli import main as cli_main
from lidar_sim_ros.core.config import (ConfigError, WrongFileKindError, file_kind, load_materials,
                                       load_sensor, read_yaml)
from lidar_sim_ros.core.scenario import load_scenario
from conftest import CONFIG, edit_yaml
from conftest import copy_config as copy_files


def copy_config(tmp_path, edit_file: str, edit) -> None:
    copy_files(tmp_path, ('scenario.yaml', 'cepton_vista_p60.yaml', 'materials.yaml',
                          'campaign_example.yaml'))
    edit_yaml(tmp_path / edit_file, edit)


@pytest.mark.parametrize('name, kind', [('campaign_example.yaml', 'campaign spec'),
                                        ('scenario.yaml', 'scenario'),
                                        ('cepton_vista_p60.yaml', 'sensor file'),
                                        ('materials.yaml', 'materials file')])
def test_each_shipped_file_is_recognised(name, kind):
    assert file_kind(yaml.safe_load((CONFIG / name).read_text())) == kind


def test_campaign_spec_given_as_scenario():
    with pytest.raises(WrongFileKindError) as err:
        load_scenario(CONFIG / 'campaign_example.yaml')
    assert str(err.value).endswith('campaign_example.yaml: this is a campaign spec, not a '
                                   'scenario: use lidar-sim campaign '
                                   f'{CONFIG / "campaign_example.yaml"}')


def test_scenario_given_as_sensor_names_its_sensor_file():
    with pytest.raises(WrongFileKindError, match="its sensor file is 'cepton_vista_p60.yaml'"):
        load_sensor(CONFIG / 'scenario.yaml')
    with pytest.raises(WrongFileKindError, match='this is a sensor file, not a materials file'):
        load_materials(CONFIG / 'cepton_vista_p60.yaml')


@pytest.mark.parametrize('argv', [
    ['simulate', str(CONFIG / 'campaign_example.yaml'), '--frames', '1', '--out', 'OUT'],
    ['calibrate', 'scan', 'BAG', '--sensor', str(CONFIG / 'campaign_example.yaml'), '--out', 'S'],
])
def test_cli_says_use_lidar_sim_campaign(tmp_path, capsys, argv):
    argv = [a.replace('OUT', str(tmp_path / 'o')).replace('BAG', str(tmp_path)) for a in argv]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'this is a campaign spec' in err[0]
    assert err[0].endswith('use lidar-sim campaign ' + str(CONFIG / 'campaign_example.yaml'))


@pytest.mark.parametrize('file, edit, key, suggestion', [
    ('scenario.yaml', lambda d: d.update(sed=d.pop('seed')), 'sed', 'seed'),
    ('scenario.yaml', lambda d: d['motion'].update(tumble_rate=d['motion'].pop('tumble_rate_dps')),
     'motion.tumble_rate', 'tumble_rate_dps'),
    # inside the tagged scan union and inside a list
    ('cepton_vista_p60.yaml', lambda d: d['scan'].update(tile_az=d['scan'].pop('tiles_az')),
     'scan.tile_az', 'tiles_az'),
    ('materials.yaml', lambda d: d['materials'][2].update(kdd=d['materials'][2].pop('kd')),
     'materials.2.kdd', 'kd'),
])
def test_unknown_key_suggests_the_nearest(tmp_path, file, edit, key, suggestion):
    copy_config(tmp_path, file, edit)
    with pytest.raises(ConfigError) as err:
        load_scenario(tmp_path / 'scenario.yaml')
    assert err.value.key == key
    assert f'unknown key; did you mean "{suggestion}"?' in str(err.value)


def test_no_suggestion_for_a_key_like_nothing(tmp_path):
    copy_config(tmp_path, 'scenario.yaml', lambda d: d.update(zzzz=1))
    with pytest.raises(ConfigError) as err:
        load_scenario(tmp_path / 'scenario.yaml')
    assert str(err.value).endswith('key "zzzz" = 1: unknown key')


def test_a_mapping_value_is_cut_not_dumped(tmp_path):
    big = {f'key_{i}': list(range(20)) for i in range(30)}
    copy_config(tmp_path, 'scenario.yaml', lambda d: d.update(motions=big))
    with pytest.raises(ConfigError) as err:
        load_scenario(tmp_path / 'scenario.yaml')
    message = str(err.value)
    assert len(message) < 300 and "...: unknown key; did you mean \"motion\"?" in message


def test_a_key_written_twice_is_refused_naming_it_and_its_line(tmp_path):
    """PyYAML keeps the last of two equal keys: a mesh_materials map naming a part twice
    (bus_mli: MLI, then bus_mli: ALUMINIUM) silently made the bus aluminium."""
    text = (CONFIG / 'scenario_box_wing.yaml').read_text()
    for key in ('sensor', 'materials', 'mesh'):                  # the shipped files, absolute
        text = text.replace(f'{key}: ', f'{key}: {CONFIG}/', 1)
    text = text.replace('  bus_mli: MLI\n', '  bus_mli: MLI\n  bus_mli: ALUMINIUM\n')
    path = tmp_path / 'twice.yaml'
    path.write_text(text)
    line = text.splitlines().index('  bus_mli: ALUMINIUM') + 1
    with pytest.raises(ConfigError, match=rf"twice.yaml.*found the key 'bus_mli' twice.*line {line}") as err:
        load_scenario(path)
    assert '\n' not in str(err.value)
    # A merge's keys may still be overridden, as YAML says.
    merged = tmp_path / 'merged.yaml'
    merged.write_text('a: &base {x: 1, y: 2}\nb:\n  <<: *base\n  x: 3\n')
    assert read_yaml(merged)['b'] == {'x': 3, 'y': 2}


@pytest.mark.parametrize('value, words', [
    ({'bus_mli': 3}, "entry 'bus_mli': 3: both the mesh's name and the config material must be strings"),
    ({1: 'MLI'}, "entry 1: 'MLI': both"),
    (['MLI'], 'must be one config material name .* \\(list given\\)'),
])
def test_a_mesh_materials_value_of_the_wrong_shape_names_the_entry(value, words):
    """pydantic's union error said key "mesh_materials.str": "Input should be a valid
    string" for a map whose value was 3 (the map's branch and the entry unnamed)."""
    from lidar_sim_ros.core.config import ScenarioConfig, parse
    data = {**yaml.safe_load((CONFIG / 'scenario_box_wing.yaml').read_text()), 'mesh_materials': value}
    with pytest.raises(ConfigError, match=r'x.yaml: key "mesh_materials" = .*' + words):
        parse(ScenarioConfig, data, 'x.yaml')
