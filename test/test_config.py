"""Config loading: defaults reproduce the paper; bad files name file, key and value."""
import shutil

import numpy as np
import pytest
import yaml

from lidar_sim_ros.core.config import ConfigError, load_materials, load_sensor
from lidar_sim_ros.core.scenario import load_scenario
from conftest import CONFIG, copy_config, edit_yaml

# Paper Table 2 (bias, 1-sigma random error), rows at 5 m and 15 m.
TABLE2 = {
    'PIF': ((-0.1417, -0.1349), (0.0228, 0.0334)),
    'MLI': ((-0.1361, -0.1337), (0.0228, 0.0387)),
    'BULKHEAD': ((-0.1334, -0.1093), (0.0306, 0.0344)),
    'PSS': ((-0.1179, -0.1053), (0.0357, 0.0390)),
    'PAF': ((-0.1146, -0.1199), (0.0437, 0.0472)),
    'ADAPTER': ((-0.1329, -0.1304), (0.0338, 0.0393)),
}


def test_materials_default_to_table2_means():
    mats = {m.name: m for m in load_materials(CONFIG / 'materials.yaml').materials}
    assert list(mats) == ['PIF', 'MLI', 'PAF', 'PSS', 'NOZZLE', 'BULKHEAD', 'ADAPTER']
    for name, (bias, sigma) in TABLE2.items():
        assert mats[name].bias_m == pytest.approx(np.mean(bias), abs=1e-6)
        assert mats[name].sigma_m == pytest.approx(np.mean(sigma), abs=1e-6)
    metals = ['PAF', 'PSS', 'BULKHEAD', 'ADAPTER']
    assert mats['NOZZLE'].bias_m == pytest.approx(np.mean([np.mean(TABLE2[m][0]) for m in metals]))
    # qualitative BRDF findings: PIF diffuse, MLI and PSS strongly specular
    assert mats['PIF'].ks < 0.1 < mats['PIF'].kd
    assert mats['MLI'].ks > 0.6 and mats['PSS'].ks > 0.6


def test_detection_threshold_matches_range_spec():
    """Table 1: 200 m at 30 % reflectivity sits exactly at the detection threshold."""
    from lidar_sim_ros.core.reflection import return_power_w
    s = load_sensor(CONFIG / 'cepton_vista_p60.yaml')
    p = return_power_w(200.0, 0.0, 0.3, 0.0, 1.0, s.optics)
    assert p == pytest.approx(s.detection.threshold_power_w, rel=1e-6)


_copy_config, _edit = copy_config, edit_yaml


def test_unknown_key_names_file_and_key(tmp_path):
    d = _copy_config(tmp_path)
    _edit(d / 'cepton_vista_p60.yaml', lambda s: s['optics'].update(peak_pwr_w=3))
    with pytest.raises(ConfigError) as exc:
        load_scenario(d / 'scenario.yaml')
    msg = str(exc.value)
    assert 'cepton_vista_p60.yaml' in msg and 'optics.peak_pwr_w' in msg and 'unknown key' in msg


def test_missing_key(tmp_path):
    d = _copy_config(tmp_path)
    _edit(d / 'scenario.yaml', lambda s: s.pop('seed'))
    with pytest.raises(ConfigError, match=r'scenario.yaml: key "seed".*missing key'):
        load_scenario(d / 'scenario.yaml')


def test_negative_sigma_names_value(tmp_path):
    d = _copy_config(tmp_path)
    _edit(d / 'materials.yaml', lambda m: m['materials'][1].update(sigma_m=-0.01))
    with pytest.raises(ConfigError) as exc:
        load_scenario(d / 'scenario.yaml')
    assert exc.value.key == 'materials.1.sigma_m' and exc.value.value == -0.01
    assert 'materials.yaml' in exc.value.file


def test_bad_scan_type_and_energy(tmp_path):
    d = _copy_config(tmp_path)
    _edit(d / 'materials.yaml', lambda m: m['materials'][0].update(kd=0.8, ks=0.5))
    with pytest.raises(ConfigError, match='energy'):
        load_materials(d / 'materials.yaml')
    _edit(d / 'cepton_vista_p60.yaml', lambda s: s['scan'].update(type='spiral'))
    with pytest.raises(ConfigError, match='scan'):
        load_sensor(d / 'cepton_vista_p60.yaml')


def test_unknown_material_in_mesh(tmp_path):
    from lidar_sim_ros.core.geometry import MeshMaterialError, load_target
    obj = tmp_path / 'm.obj'
    (tmp_path / 'm.mtl').write_text('newmtl PIF\nKd 1 1 1\nnewmtl GOLD_FOIL\nKd 1 1 0\n')
    obj.write_text('mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n'
                   'g PIF\nusemtl PIF\nf 1 2 3\ng GOLD_FOIL\nusemtl GOLD_FOIL\nf 1 2 4\n')
    with pytest.raises(MeshMaterialError, match='GOLD_FOIL'):
        load_target(obj, ['PIF', 'MLI'])
    assert load_target(obj, ['PIF', 'GOLD_FOIL']).n_faces == 2


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match='file not found'):
        load_sensor(tmp_path / 'nope.yaml')
    (tmp_path / 'bad.yaml').write_text('a: [1, 2\n')
    with pytest.raises(ConfigError, match='not valid YAML'):
        load_sensor(tmp_path / 'bad.yaml')


def test_bad_effect_stops_at_load(tmp_path):
    d = _copy_config(tmp_path)
    _edit(d / 'scenario.yaml', lambda s: s.update(effects=[{'name': 'range_wlak'}]))
    with pytest.raises(ConfigError) as exc:
        load_scenario(d / 'scenario.yaml')
    assert exc.value.key == 'effects.0.name' and exc.value.value == 'range_wlak'
    _edit(d / 'scenario.yaml', lambda s: s.update(effects=[{'name': 'range_walk', 'params': {'kk': 1}}]))
    with pytest.raises(ConfigError) as exc:
        load_scenario(d / 'scenario.yaml')
    assert exc.value.key == 'effects.0.params.kk'


def test_sunlit_scenario_loads_its_sun():
    sc = load_scenario(CONFIG / 'scenario_sunlit.yaml')
    d = np.array(sc.config.sun.direction)
    np.testing.assert_allclose(d, np.array([0.0, 0.34, 0.94]) / np.hypot(0.34, 0.94))
    assert sc.config.sun.spectral_irradiance_w_m2_nm == 0.92
    assert [e.name for e in sc.config.effects] == ['sunlight']
    assert load_scenario(CONFIG / 'scenario.yaml').config.sun is None


@pytest.mark.parametrize('file, edit, key, value, words', [
    ('scenario_sunlit.yaml', lambda d: d['sun'].update(direction=[0, 0, 0]), 'sun.direction',
     [0, 0, 0], 'non-zero finite vector'),
    ('scenario_sunlit.yaml', lambda d: d['sun'].update(spectral_irradiance_w_m2_nm=-1),
     'sun.spectral_irradiance_w_m2_nm', -1, 'greater than 0'),
    ('scenario_sunlit.yaml', lambda d: d['sun'].update(earth={'direction': [0, 0, -1], 'albedo': 2}),
     'sun.earth.albedo', 2, 'less than or equal to 1'),
    ('cepton_vista_p60.yaml', lambda d: d['receiver'].update(bandpass_nm=-5), 'receiver.bandpass_nm',
     -5, 'greater than 0'),
    ('cepton_vista_p60.yaml', lambda d: d['receiver'].update(detector='geiger'), 'receiver.detector',
     'geiger', "'linear' or 'photon_counting'"),
    ('cepton_vista_p60.yaml', lambda d: d['receiver'].update(apd_gain=0.5), 'receiver.apd_gain', 0.5,
     'greater than or equal to 1'),
])
def test_bad_sun_and_receiver_values_name_file_key_and_value(tmp_path, file, edit, key, value, words):
    data = yaml.safe_load((CONFIG / file).read_text())
    edit(data)
    is_scenario = file.startswith('scenario')
    if is_scenario:   # the files it names, next to it
        for name in ('cepton_vista_p60.yaml', 'materials.yaml'):
            shutil.copy(CONFIG / name, tmp_path / name)
        data['mesh'] = str(CONFIG.parent / 'meshes' / 'rocket_body.obj')
    path = tmp_path / file
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        (load_scenario if is_scenario else load_sensor)(path)
    assert err.value.file == str(path) and err.value.key == key and err.value.value == value
    assert words in err.value.reason
