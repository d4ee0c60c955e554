"""Hostile configs (issue 22, parts 2-3): non-finite or impossible values, sizes past the
limits, alias bombs and non-YAML files each get one ConfigError naming file, key and a
truncated value, before anything is simulated."""

import pytest
import yaml

from lidar_sim_ros.core.config import (MAX_SHOTS_PER_FRAME, MAX_VALUE_CHARS, ConfigError,
                                       load_materials, load_sensor)
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.effects import make_effect
from conftest import CONFIG, copy_config, edit_yaml

SENSOR, MATERIALS = 'cepton_vista_p60.yaml', 'materials.yaml'


@pytest.fixture
def cfg(tmp_path):
    return copy_config(tmp_path, ('scenario.yaml', SENSOR, MATERIALS))


_edit = edit_yaml


@pytest.mark.parametrize('edit, key, value', [
    (lambda s: s['scan'].update(phase_az_rad=float('nan')), 'scan.phase_az_rad', 'nan'),
    (lambda s: s['scan'].update(fov_az_deg=float('inf')), 'scan.fov_az_deg', 'inf'),
    (lambda s: s['scan'].update(fov_el_deg=200.0), 'scan.fov_el_deg', '200.0'),
    (lambda s: s.update(frame_rate_hz=float('inf')), 'frame_rate_hz', 'inf'),
    (lambda s: s.update(frame_rate_hz=1e-9), 'frame_rate_hz', '1e-09'),
    (lambda s: s['scan'].update(shots_per_laser=100_000_000), 'scan', ''),
])
def test_sensor_values_must_be_finite_and_possible(cfg, edit, key, value):
    _edit(cfg / SENSOR, edit)
    with pytest.raises(ConfigError) as err:
        load_sensor(cfg / SENSOR)
    assert err.value.key == key and SENSOR in str(err.value) and value in str(err.value)


def test_shot_limit_names_the_count(cfg):
    _edit(cfg / SENSOR, lambda s: s['scan'].update(shots_per_laser=100_000_000))
    with pytest.raises(ConfigError, match=f'2400000000 shots per frame exceed the limit of {MAX_SHOTS_PER_FRAME}'):
        load_sensor(cfg / SENSOR)


@pytest.mark.parametrize('field, value', [('bias_m', float('nan')), ('sigma_m', float('inf')),
                                           ('bias_m', 1e300)])
def test_material_range_errors_finite_and_bounded(cfg, field, value):
    _edit(cfg / MATERIALS, lambda m: m['materials'][0].update({field: value}))
    with pytest.raises(ConfigError) as err:
        load_materials(cfg / MATERIALS)
    assert err.value.key == f'materials.0.{field}'


def test_effect_params_must_be_finite(cfg):
    _edit(cfg / 'scenario.yaml', lambda s: s.update(effects=[
        {'name': 'range_walk', 'params': {'k_m': float('nan')}}]))
    with pytest.raises(ConfigError) as err:
        load_scenario(cfg / 'scenario.yaml')
    assert err.value.key == 'effects.0.params.k_m' and 'nan' in str(err.value)
    # Said as "finite", not as the parameter's bound (issue 29).
    with pytest.raises(ValueError, match='finite'):
        make_effect('range_walk', {'k_m': float('inf')})
    with pytest.raises(ValueError, match='finite'):
        make_effect('range_walk', {'reference_power_w': None, 'k_m': 0.0,
                                   'offset_m': float('nan')})


def test_quaternion_accepted_only_near_unit_norm(cfg):
    _edit(cfg / 'scenario.yaml', lambda s: s['initial_pose'].update(quat_xyzw=[1.0, 1.0, 0.0, 0.0]))
    with pytest.raises(ConfigError, match='not within 0.01 of 1'):
        load_scenario(cfg / 'scenario.yaml')


def test_alias_bomb_refused_quickly_with_a_short_message(cfg):
    # 9 levels of 9 aliases: 9**9 = 387 million values once expanded, 1 kB of text.
    lines = ['a0: &a0 [x, x, x, x, x, x, x, x, x]']
    for k in range(1, 10):
        lines.append(f'a{k}: &a{k} [' + ', '.join([f'*a{k - 1}'] * 9) + ']')
    lines.append('materials: *a9')
    (cfg / MATERIALS).write_text('\n'.join(lines) + '\n')
    with pytest.raises(ConfigError, match='alias bomb') as err:
        load_materials(cfg / MATERIALS)
    assert len(str(err.value)) < 400


def test_long_values_are_truncated_in_messages(cfg):
    _edit(cfg / MATERIALS, lambda m: m['materials'][0].update(name={f'k{i}': 'v' * 1000 for i in range(1000)}))
    with pytest.raises(ConfigError) as err:
        load_materials(cfg / MATERIALS)
    assert len(str(err.value)) < 2 * MAX_VALUE_CHARS + 200


def test_sensor_path_that_is_not_yaml_does_not_print_it(cfg):
    secret = 'root:x:0:0:this line must not be printed'
    (cfg / SENSOR).write_text(secret + '\n')
    with pytest.raises(ConfigError, match='expected a YAML mapping') as err:
        load_sensor(cfg / SENSOR)
    assert 'printed' not in str(err.value)


def test_frame_rate_override_is_validated_like_the_file():
    # The node's rate_hz parameter: a copy with update= skipped validation.
    from lidar_sim_ros.core.config import with_frame_rate
    sensor = load_sensor(CONFIG / SENSOR)
    assert with_frame_rate(sensor, 20.0, '<parameters>').frame_period_s == pytest.approx(0.05)
    with pytest.raises(ConfigError, match=r'<parameters>: key "rate_hz" = 1e-09'):
        with_frame_rate(sensor, 1e-9, '<parameters>')


@pytest.mark.parametrize('args', [['--epoch-s', 'nan'], ['--epoch-s', 'inf'], ['--epoch-s', '3e9'],
                                  ['--start-s', 'nan']])
def test_simulate_refuses_non_finite_clock_arguments(args, capsys):
    from lidar_sim_ros.cli import build_parser
    with pytest.raises(SystemExit):
        build_parser().parse_args(['simulate', 'x.yaml', '--frames', '1', '--out', 'o', *args])
    assert 'expected' in capsys.readouterr().err


def test_simulate_refuses_stamps_past_int32(tmp_path):
    from lidar_sim_ros.offline import simulate_to_bag
    with pytest.raises(ValueError, match=r'stamps must lie in \[0, 2\*\*31\) s'):
        simulate_to_bag(CONFIG / 'scenario.yaml', tmp_path, frames=10**12, figures=False)
    assert not (tmp_path / 'bag').exists()


def test_out_of_memory_is_one_line(monkeypatch, capsys):
    from lidar_sim_ros import cli
    def boom(args):
        raise MemoryError()
    parser = cli.build_parser()
    monkeypatch.setattr(cli, 'build_parser', lambda: parser)
    parser.set_defaults(func=boom)
    for action in parser._subparsers._group_actions[0].choices.values():
        action.set_defaults(func=boom)
    assert cli.main(['simulate', 'x.yaml', '--frames', '1', '--out', 'o']) == 2
    assert 'out of memory' in capsys.readouterr().err


def test_campaign_runs_are_limited(tmp_path):
    from lidar_sim_ros.campaign.spec import MAX_RUNS, load_campaign
    path = tmp_path / 'c.yaml'
    path.write_text(yaml.safe_dump({'scenario': str(CONFIG / 'scenario.yaml'), 'seed': 1,
                                    'runs': 10 * MAX_RUNS, 'duration_s': 0.1}))
    with pytest.raises(ConfigError) as err:
        load_campaign(path)
    assert err.value.key == 'runs' and str(10 * MAX_RUNS) in str(err.value)


def _set(section, key, index, value):
    def edit(doc):
        where = doc[section] if section else doc
        if index is None:
            where[key] = value
        else:
            where[key][index] = value
    return edit


@pytest.mark.parametrize('file, edit, key, value', [
    # A wedge of 1e-300 deg: its prism adds nothing (both: every shot on the boresight).
    ('livox_mid40.yaml', _set('scan', 'prism_deviation_deg', 0, 1e-300), 'scan.prism_deviation_deg.0', '1e-300'),
    # A prism turning at 1e-300 rev/s stands still; two rates 1e-9 apart draw one circle.
    ('livox_mid40.yaml', _set('scan', 'prism_rates_hz', 1, 1e-300), 'scan', '1e-300'),
    ('livox_mid40.yaml', _set('scan', 'prism_rates_hz', 1, 121.56666666666666 + 1e-9), 'scan', '121.56666'),
    # A footprint of 1e-300 rad underflowed to 0 (infinite irradiance, warnings, no point);
    # a beam wider than a hemisphere is none.
    ('livox_mid40.yaml', _set('optics', 'beam_divergence_rad', None, 1e-300), 'optics.beam_divergence_rad', '1e-300'),
    ('flash_256.yaml', _set('optics', 'beam_divergence_rad', None, 1e300), 'optics.beam_divergence_rad', '1e+300'),
    # An aperture of 1e300 m: OverflowError out of the frame.
    ('flash_256.yaml', _set('optics', 'aperture_diameter_m', None, 1e300), 'optics.aperture_diameter_m', '1e+300'),
    # A peak power of 1e300 W (or any beyond MAX_PEAK_POWER_W, a 5 J pulse of 5 ns):
    # every pixel saturated, no point, rc 0.
    ('flash_256.yaml', _set('optics', 'peak_power_w', None, 1e300), 'optics.peak_power_w', '1e+300'),
    ('cepton_vista_p60.yaml', _set('optics', 'peak_power_w', None, 1.5e9), 'optics.peak_power_w', '1500000000.0'),
    # A Lissajous field or frequency of 1e-300: every laser fires in one direction.
    ('cepton_vista_p60.yaml', _set('scan', 'fov_el_deg', None, 1e-300), 'scan.fov_el_deg', '1e-300'),
    ('cepton_vista_p60.yaml', _set('scan', 'freq_az_hz', None, 1e-300), 'scan.freq_az_hz', '1e-300'),
    # A spinning sensor's sweep of 1e-300 deg.
    ('spinning_32.yaml', _set('scan', 'az_max_deg', None, -180.0 + 1e-12), 'scan', '-180'),
])
def test_tiny_positive_values_that_collapse_the_scan_are_refused(tmp_path, file, edit, key, value):
    """Positive but degenerate: each was accepted and gave a scan of no size or no motion,
    a frame of warnings and no point, or an OverflowError from the frame (the hostile
    sweep of this round over livox_mid40.yaml and flash_256.yaml); now one ConfigError
    naming the file, key and value at load."""
    copy_config(tmp_path, (file,))
    _edit(tmp_path / file, edit)
    with pytest.raises(ConfigError) as err:
        load_sensor(tmp_path / file)
    assert err.value.key == key and file in str(err.value) and value in str(err.value)


def test_the_peak_power_bound_is_physical():
    """MAX_PEAK_POWER_W (1e9 W) takes every shipped laser and a GLAS-class pulse (75 mJ in
    6 ns, 1.25e7 W), and says why it stops in the message: file, key, value, bound."""
    from lidar_sim_ros.core.config import MAX_PEAK_POWER_W
    for name in ('cepton_vista_p60.yaml', 'livox_mid40.yaml', 'flash_256.yaml', 'spinning_32.yaml'):
        assert load_sensor(CONFIG / name).optics.peak_power_w <= MAX_PEAK_POWER_W / 1000
    assert 0.075 / 6e-9 < MAX_PEAK_POWER_W <= 5.0 / 5e-9


def test_a_peak_power_at_the_bound_loads_and_one_beyond_names_file_key_value(tmp_path):
    copy_config(tmp_path, ('flash_256.yaml',))
    _edit(tmp_path / 'flash_256.yaml', _set('optics', 'peak_power_w', None, 1.0e9))
    assert load_sensor(tmp_path / 'flash_256.yaml').optics.peak_power_w == 1.0e9
    _edit(tmp_path / 'flash_256.yaml', _set('optics', 'peak_power_w', None, 1.0000001e9))
    with pytest.raises(ConfigError, match=r'flash_256.yaml: key "optics.peak_power_w" = '
                                          r'1000000100.0: .*less than or equal to 1000000000'):
        load_sensor(tmp_path / 'flash_256.yaml')


def test_a_negative_seed_is_refused_at_load(cfg):
    """seed: -1 loaded and every frame then failed in numpy ('expected non-negative
    integer'), after the mesh was read."""
    _edit(cfg / 'scenario.yaml', lambda s: s.update(seed=-1))
    with pytest.raises(ConfigError) as err:
        load_scenario(cfg / 'scenario.yaml')
    assert err.value.key == 'seed' and '-1' in str(err.value)


@pytest.mark.parametrize('key, value, words', [
    # Each of these crashed the sunlit flash frame (ZeroDivisionError, OverflowError x 2).
    ('bandwidth_hz', 1e-300, 'greater than or equal to 1000'),
    ('responsivity_a_per_w', 1e-300, 'greater than or equal to 0.001'),
    ('amplifier_noise_a_per_rthz', 1e300, 'less than or equal to 0.000001'),
    # Physical limits: one electron a photon (1572 nm: 1.268 A/W), F <= M, a hemisphere,
    # a filter narrower than the wavelength, a point-source transmittance of at most 1.
    ('responsivity_a_per_w', 1.5, 'quantum limit at 1572 nm'),
    ('excess_noise_factor', 25.0, 'exceeds apd_gain 20'),
    ('ifov_sr', 1e300, 'less than 6.28'),
    ('bandpass_nm', 1e300, 'wider than the wavelength'),
    ('stray_light_pst_at_1deg', 1e300, 'less than or equal to 1'),
    ('wavelength_nm', 1e-300, 'greater than or equal to 200'),
    # Beyond any receiver: every pixel a sunlit false return.
    ('apd_gain', 1e300, 'less than or equal to 10000'),
    ('dark_current_a', 1e300, 'less than or equal to 0.001'),
    ('dark_count_rate_hz', 1e300, 'less than or equal to 10000000000'),
])
def test_receiver_values_that_break_the_noise_model_are_refused(tmp_path, key, value, words):
    """The sweep of this round over flash_256.yaml in a sunlit scenario: each was loaded,
    and the frame crashed or every one of the 65,536 pixels fired on noise (or, for a
    field wider than a hemisphere or a 1e300 nm filter, the background had no meaning)."""
    copy_config(tmp_path, ('flash_256.yaml',))
    _edit(tmp_path / 'flash_256.yaml', lambda s: s['receiver'].update({key: value}))
    with pytest.raises(ConfigError, match=words) as err:
        load_sensor(tmp_path / 'flash_256.yaml')
    assert err.value.key.startswith('receiver') and 'flash_256.yaml' in str(err.value)


def test_a_range_gate_of_1e300_m_is_refused(tmp_path):
    """Sunlit false returns fall anywhere in the gate: at 1e300 m every pixel of the sunlit
    flash frame had one, out to 1e8 m (median 25 km)."""
    copy_config(tmp_path, ('flash_256.yaml',))
    _edit(tmp_path / 'flash_256.yaml', lambda s: s['detection'].update(max_range_m=1e300))
    with pytest.raises(ConfigError, match='less than or equal to 1000000') as err:
        load_sensor(tmp_path / 'flash_256.yaml')
    assert err.value.key == 'detection.max_range_m'


@pytest.mark.parametrize('key, value, words', [
    ('spectral_irradiance_w_m2_nm', 1e300, 'less than or equal to 100000'),
    ('deep_space_radiance_w_m2_sr_nm', 1e300, 'less than or equal to 100000'),
    ('orbit_rate_dps', 1e300, 'less than or equal to 3600'),
])
def test_sunlight_beyond_the_sun_is_refused(tmp_path, key, value, words):
    """A spectral irradiance of 1e300 (the photosphere gives ~4e4 at 905 nm) blinded the
    sunlit flash frame (446 of 20,349 points); an orbit rate of 1e300 deg/s makes the
    sun's direction arbitrary after any time at all."""
    copy_config(tmp_path, ('scenario_sunlit.yaml', SENSOR, MATERIALS))
    _edit(tmp_path / 'scenario_sunlit.yaml', lambda s: s['sun'].update({key: value}))
    _edit(tmp_path / 'scenario_sunlit.yaml',
          lambda s: s.update(mesh=str(CONFIG.parent / 'meshes' / 'rocket_body.obj')))
    with pytest.raises(ConfigError, match=words) as err:
        load_scenario(tmp_path / 'scenario_sunlit.yaml')
    assert err.value.key == f'sun.{key}' and 'scenario_sunlit.yaml' in str(err.value)


def _laser0(**override):
    return lambda doc: doc['scan'].update(lasers=[override] + [{}] * 23)


@pytest.mark.parametrize('edit, key, value', [
    # Each was accepted and sent shots to arbitrary directions (1e300 deg, or a phase whose
    # float64 spacing is ~1e284 rad), rc 0.
    (_set('scan', 'overlap', None, 1e300), 'scan.overlap', '1e+300'),
    (_set('scan', 'freq_az_hz', None, 1e300), 'scan.freq_az_hz', '1e+300'),
    (_set('scan', 'phase_az_rad', None, 1e300), 'scan.phase_az_rad', '1e+300'),
    (_set('scan', 'phase_step_rad', None, -1e300), 'scan.phase_step_rad', '-1e+300'),
    (_laser0(center_az_deg=1e300), 'scan.lasers.0.center_az_deg', '1e+300'),
    (_laser0(amp_el_deg=1e300), 'scan.lasers.0.amp_el_deg', '1e+300'),
    (_laser0(phase_el_rad=1e300), 'scan.lasers.0.phase_el_rad', '1e+300'),
    (_laser0(freq_el_hz=1e300), 'scan.lasers.0.freq_el_hz', '1e+300'),
])
def test_lissajous_values_that_scatter_the_shots_are_refused(cfg, edit, key, value):
    _edit(cfg / SENSOR, edit)
    with pytest.raises(ConfigError) as err:
        load_sensor(cfg / SENSOR)
    assert err.value.key == key and SENSOR in str(err.value) and value in str(err.value)
