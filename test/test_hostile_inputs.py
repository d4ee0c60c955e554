"""Hostile inputs, second round (issue 29): effect parameters bounded where they enter,
the range gate holding after every effect, and scenario / command-line inputs refused
with one line naming file, key and value."""
import numpy as np
import pytest
from pydantic import ValidationError

from lidar_sim_ros.core.effects import REGISTRY, Effect, catalogue, get_effect_class
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import StaticPose
from conftest import materials, plate_target, sensor

FACING = (0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5))    # plate normal (body +z) toward the sensor


def _numeric_fields(cls):
    """(name, lower, upper) of every float/int parameter of an effect's Params, its
    pydantic bounds read from the field metadata (None: unbounded)."""
    out = []
    for name, info in cls.Params.model_fields.items():
        ann = str(info.annotation)
        if not any(t in ann for t in ('float', 'int')) or 'list' in ann or 'dict' in ann:
            continue
        lo = hi = None
        for m in info.metadata:
            lo = getattr(m, 'ge', None) if getattr(m, 'ge', None) is not None else (
                getattr(m, 'gt', None) if getattr(m, 'gt', None) is not None else lo)
            hi = getattr(m, 'le', None) if getattr(m, 'le', None) is not None else (
                getattr(m, 'lt', None) if getattr(m, 'lt', None) is not None else hi)
        out.append((name, lo, hi))
    return out


def _all_effects():
    catalogue()
    get_effect_class('sunlight')
    get_effect_class('range_scale')
    return sorted(REGISTRY.items())


@pytest.mark.parametrize('name, cls', _all_effects())
def test_every_effect_parameter_is_bounded(name, cls):
    """Issue 29: range_walk k_m = -1e6 was accepted. Every numeric parameter of every
    catalogue effect has a lower and an upper bound, refuses +-1e6, and the fit's search
    box lies inside them (a fit never proposes a value the Params refuse)."""
    fields = _numeric_fields(cls)
    assert fields or name in ('laser_bias', 'laser_pointing')   # lists per laser
    for field, lo, hi in fields:
        assert lo is not None and hi is not None, (name, field)
        assert hi < 1e6 and lo > -1e6, (name, field, lo, hi)
        for bad in (1e6, -1e6):
            with pytest.raises(ValidationError):
                cls({field: bad})
    for field, info in cls.Params.model_fields.items():     # a table of numbers by name
        if 'dict' in str(info.annotation):
            for bad in (1e6, -1e6, float('nan')):
                with pytest.raises(ValidationError):
                    cls({field: {'PIF': bad}})
    for field, (lo, hi) in cls.bounds.items():
        if field in ('offsets_m', 'az_offsets_deg', 'el_offsets_deg'):
            cls({field: [lo, hi]})
            with pytest.raises(ValidationError):
                cls({field: [0.0, 1e6]})
        else:
            cls({field: lo}), cls({field: hi})


@pytest.mark.parametrize('name, field', [('laser_bias', 'offsets_m'),
                                         ('laser_pointing', 'az_offsets_deg'),
                                         ('laser_pointing', 'el_offsets_deg')])
def test_per_laser_offsets_are_limited_in_number(name, field):
    from lidar_sim_ros.core.config import MAX_LASERS
    cls = get_effect_class(name)
    cls({field: [0.0] * MAX_LASERS})
    with pytest.raises(ValidationError, match='at most 1024'):
        cls({field: [0.0] * (MAX_LASERS + 1)})


def test_range_walk_bound_is_named_on_the_command_line():
    from lidar_sim_ros.core.config import ConfigError
    from lidar_sim_ros.core.effects import effect_from_spec
    with pytest.raises(ConfigError, match=r'range_walk.k_m" = .-1e6.: Input should be greater '
                                          r'than or equal to -2'):
        effect_from_spec('range_walk={k_m: -1e6}')


class _FarBias(Effect):
    """A user effect with no bounds of its own: shifts every range by ``shift_m``."""

    name = 'far_bias_test'

    def __init__(self, shift_m):
        super().__init__()
        self.shift_m = shift_m

    def range_bias_m(self, ctx):
        return np.full(len(ctx), self.shift_m)


@pytest.mark.parametrize('returns', [{}, {'returns': {'max_returns': 2, 'mode': 'all'}}])
def test_no_published_range_lies_outside_the_gate_whatever_the_effects(returns):
    """The detector gates the true range; the gate now holds for the published (measured)
    range too, after bias, noise and every effect, for the single- and multi-return
    receiver. A plate at 20 m, gate [5, 50] m: +40 m and -17 m publish nothing, +10 m all."""
    s = sensor(min_range_m=5.0, max_range_m=50.0, **returns)
    pose = StaticPose((20.0, 0.0, 0.0), FACING)
    counts = {}
    for shift in (0.0, 10.0, 40.0, -17.0):
        frame = Simulator(s, materials(), plate_target(6.0), seed=1,
                          effects=[_FarBias(shift)]).simulate_frame(0.0, pose, 0)
        counts[shift] = len(frame.range_m)
        if len(frame.range_m):
            assert frame.range_m.min() >= 5.0 and frame.range_m.max() <= 50.0
            assert np.allclose(frame.range_m, np.linalg.norm(frame.xyz_m, axis=1))
    assert counts[0.0] == counts[10.0] == 8 and counts[40.0] == counts[-17.0] == 0


# ----------------------------------------------------------- scenario and command line
@pytest.fixture
def cfg(tmp_path):
    from conftest import copy_config
    return copy_config(tmp_path, ('scenario.yaml', 'cepton_vista_p60.yaml', 'materials.yaml'))


@pytest.mark.parametrize('key, edit, value', [
    ('initial_pose.position_m.0', lambda s: s['initial_pose'].update(position_m=[1e300, 0, 0]),
     '1e+300'),
    ('initial_pose.position_m', lambda s: s['initial_pose'].update(position_m=[0, 0, 0]), '0'),
    ('motion.approach_speed_mps', lambda s: s['motion'].update(approach_speed_mps=-1e300), 'e+300'),
    ('motion.tumble_rate_dps', lambda s: s['motion'].update(tumble_rate_dps=1e6), '1000000'),
])
def test_absurd_start_and_motion_are_refused_naming_file_key_value(cfg, key, edit, value):
    """Issue 29: a 1e300 m start gave an overflow warning and a message naming neither file
    nor key."""
    from conftest import edit_yaml
    from lidar_sim_ros.core.config import ConfigError
    from lidar_sim_ros.core.scenario import load_scenario
    edit_yaml(cfg / 'scenario.yaml', edit)
    with pytest.raises(ConfigError) as err:
        load_scenario(cfg / 'scenario.yaml')
    assert err.value.key == key and 'scenario.yaml' in str(err.value) and value in str(err.value)


def test_a_huge_tumble_axis_is_a_direction(cfg):
    from conftest import edit_yaml
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.pose import ScenarioTrajectory
    edit_yaml(cfg / 'scenario.yaml', lambda s: s['motion'].update(tumble_axis=[1e300, 1e300, 0]))
    traj = ScenarioTrajectory.from_config(load_scenario(cfg / 'scenario.yaml').config)
    assert np.allclose(traj.tumble_axis, [np.sqrt(0.5), np.sqrt(0.5), 0.0])


def _file_scan_sensor(cfg, scan_name):
    from conftest import edit_yaml
    edit_yaml(cfg / 'cepton_vista_p60.yaml',
              lambda s: s.update(scan={'type': 'file', 'path': scan_name}))
    return cfg / 'cepton_vista_p60.yaml'


@pytest.mark.parametrize('name, write, key, value', [
    ('one.npy', lambda p: np.save(p, np.arange(8.0)), 'shape', '[8]'),
    ('lasers.csv', lambda p: p.write_text('t_s,az_deg,el_deg,laser\n0.0,1,2,3\n0.01,1,2,70000\n'),
     'laser', '70000'),
    ('minus.csv', lambda p: p.write_text('t_s,az_deg,el_deg,laser\n0.0,1,2,-1\n'), 'laser', '-1'),
    ('half.csv', lambda p: p.write_text('t_s,az_deg,el_deg,laser\n0.0,1,2,2.5\n'), 'laser', '2.5'),
])
def test_a_bad_scan_file_is_refused_naming_file_and_value(cfg, name, write, key, value):
    """Issue 29: a 1-D .npy gave an IndexError traceback; lasers 70000 and -1 gave rc 0 with
    rings 4464 and 65535."""
    from lidar_sim_ros.core.config import ConfigError, load_sensor
    from lidar_sim_ros.core.scan import frame_shots
    write(cfg / name)
    sensor_cfg = load_sensor(_file_scan_sensor(cfg, name))
    with pytest.raises(ConfigError) as err:
        frame_shots(sensor_cfg, cfg)
    assert err.value.key == key and name in str(err.value) and value in str(err.value)


def test_a_good_scan_file_loads_sorted_with_its_lasers(cfg):
    from lidar_sim_ros.core.config import load_sensor
    from lidar_sim_ros.core.scan import frame_shots
    (cfg / 'ok.csv').write_text('t_s,az_deg,el_deg,laser\n0.02,1,2,1023\n0.0,3,4,0\n')
    shots = frame_shots(load_sensor(_file_scan_sensor(cfg, 'ok.csv')), cfg)
    assert shots.laser.tolist() == [0, 1023] and shots.t_s.tolist() == [0.0, 0.02]
    assert np.allclose(np.degrees(shots.az_rad), [3, 1])


def test_an_effect_file_that_is_not_python_is_one_line(tmp_path, capsys):
    """Issue 29: --effect README.md:X printed "'NoneType' object has no attribute 'loader'"."""
    from lidar_sim_ros.cli import main
    from conftest import CONFIG
    (tmp_path / 'README.md').write_text('# not python\n')
    code = main(['simulate', str(CONFIG / 'scenario.yaml'), '--frames', '1', '--out',
                 str(tmp_path / 'o'), '--effect', f'{tmp_path / "README.md"}:X'])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "effect file is Python source ending in .py, not 'README.md'" in err
    assert not (tmp_path / 'o' / 'bag').exists()


PLUGIN = '''
from lidar_sim_ros.core.effects import Effect
class Shift(Effect):
    name = 'shift_test'
    def range_bias_m(self, ctx):
        return {bias}
'''


def test_a_scenario_plugin_resolves_beside_the_scenario_only(cfg, tmp_path, monkeypatch):
    """Issue 29: a plugin missing beside the scenario was taken from the current directory.
    Now only the scenario's folder is looked in, by load_scenario, the simulator and compare."""
    from conftest import edit_yaml
    from lidar_sim_ros.core.config import ConfigError
    from lidar_sim_ros.core.scenario import load_scenario
    edit_yaml(cfg / 'scenario.yaml', lambda s: s.update(effects=[{'name': 'shift.py:Shift'}]))
    elsewhere = tmp_path / 'cwd'
    elsewhere.mkdir()
    (elsewhere / 'shift.py').write_text(PLUGIN.format(bias=5.0))
    monkeypatch.chdir(elsewhere)
    with pytest.raises(ConfigError) as err:
        load_scenario(cfg / 'scenario.yaml')
    assert err.value.key == 'effects.0.name' and str(cfg / 'shift.py') in str(err.value)
    (cfg / 'shift.py').write_text(PLUGIN.format(bias=0.25))
    scenario = load_scenario(cfg / 'scenario.yaml')
    sim = Simulator.from_scenario(scenario)
    assert sim.effects[0].range_bias_m(None) == 0.25
    assert type(sim.effects[0]).load_spec == f"{(cfg / 'shift.py').resolve()}:Shift"


def test_simulate_bounds_the_output_before_writing(tmp_path, capsys):
    """Issue 29: --frames 1000000000 started writing ~200 TB without an estimate. The bound
    (every shot a point) is checked against --max-output-gb before anything is written."""
    from lidar_sim_ros.cli import main
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.io.pointcloud import POINT_DTYPE
    from lidar_sim_ros.offline import check_output_size, output_bound_bytes
    from lidar_sim_ros.core.driver_layout import OutputLayout
    from conftest import CONFIG
    code = main(['simulate', str(CONFIG / 'scenario.yaml'), '--frames', '1000000000',
                 '--out', str(tmp_path / 'o')])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and not (tmp_path / 'o').exists()
    assert '--frames 1000000000: the bag may reach 1.02 PB' in err and '--max-output-gb 20' in err
    # The bound by hand: 21120 shots x (24 B cloud + 24 B truth) + 14 messages x 256 B a frame.
    sim = Simulator.from_scenario(load_scenario(CONFIG / 'scenario.yaml'))
    assert POINT_DTYPE.itemsize == 24 and len(sim.shots) == 21120
    assert output_bound_bytes(sim, OutputLayout(), 10) == 10 * (21120 * 48 + 14 * 256) + 256
    # A run under the limit writes no more than the bound; one of 1 GB or more says its
    # estimate on stderr before it starts.
    assert check_output_size(sim, OutputLayout(), 2000, tmp_path, 20.0).startswith(
        'estimate: the bag takes at most 2.03 GB (1.02 MB a frame, every shot a point)')
    code = main(['simulate', str(CONFIG / 'scenario.yaml'), '--frames', '2', '--no-figures',
                 '--out', str(tmp_path / 'small'), '--max-output-gb', '0.01'])
    assert code == 0 and capsys.readouterr().err == ''
    written = sum(f.stat().st_size for f in (tmp_path / 'small' / 'bag').rglob('*') if f.is_file())
    assert 0 < written <= output_bound_bytes(sim, OutputLayout(), 2)
    code = main(['simulate', str(CONFIG / 'scenario.yaml'), '--frames', '2', '--no-figures',
                 '--out', str(tmp_path / 'tiny'), '--max-output-gb', '0.001'])
    assert code == 2 and 'above --max-output-gb 0.001' in capsys.readouterr().err


def test_ctrl_c_is_one_line_and_rc_130(monkeypatch, capsys):
    """Issue 29: Ctrl-C printed a traceback. In-process: the command raises KeyboardInterrupt."""
    from lidar_sim_ros import cli

    def interrupted(args):
        raise KeyboardInterrupt

    def wrapped(args):       # numba loading its cache when the signal came
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError('returned a result with an exception set') from exc

    def unrelated(args):
        raise SystemError('a real bug')
    parser = cli.build_parser()
    monkeypatch.setattr(cli, 'build_parser', lambda: parser)
    for func in (interrupted, wrapped):
        for action in parser._subparsers._group_actions[0].choices.values():
            action.set_defaults(func=func)
        assert cli.main(['simulate', 'x.yaml', '--frames', '1', '--out', 'o']) == 130
        err = capsys.readouterr().err.strip()
        assert err == 'lidar-sim simulate: interrupted (Ctrl-C); output written so far is incomplete'
    for action in parser._subparsers._group_actions[0].choices.values():
        action.set_defaults(func=unrelated)
    with pytest.raises(SystemError, match='a real bug'):
        cli.main(['simulate', 'x.yaml', '--frames', '1', '--out', 'o'])


def test_sigint_during_a_run_exits_130_without_a_traceback(tmp_path):
    """The real signal, to a real `lidar-sim simulate` writing frames."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from conftest import CONFIG, REPO
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [sys.executable, '-m', 'lidar_sim_ros.cli', 'simulate', str(CONFIG / 'scenario.yaml'),
         '--frames', '5000', '--no-figures', '--out', str(tmp_path / 'o')],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # Interrupted once a frame is in the bag (its file has grown past the header: a
        # loaded machine may take seconds for the first frame after the bag appears).
        bag = tmp_path / 'o' / 'bag'

        def written() -> int:
            return sum(f.stat().st_size for f in bag.glob('*')) if bag.exists() else 0
        deadline = time.monotonic() + 120
        while written() < 50_000 and time.monotonic() < deadline:
            time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert 'Traceback' not in err
    assert err.strip().splitlines()[-1] == ('lidar-sim simulate: interrupted (Ctrl-C); output '
                                            'written so far is incomplete')
    # The bag was closed on the way out: it reads, with the frames done.
    from lidar_sim_ros.io.bag import read_clouds
    assert len(read_clouds(tmp_path / 'o' / 'bag')) >= 1


def test_ctrl_c_swallowed_by_a_library_during_start_up_still_stops(monkeypatch, capsys):
    """scipy's import-time docstring parsing catches every exception, a KeyboardInterrupt
    too: a Ctrl-C then went unnoticed and the run went on. The signal is remembered."""
    import signal
    from lidar_sim_ros import cli
    real = cli.build_parser

    def swallowing_import():
        try:
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)    # the handler main set
        except KeyboardInterrupt:
            pass                                                    # as scipy does
        return real()
    monkeypatch.setattr(cli, 'build_parser', swallowing_import)
    # Python's own handler, as a shell's foreground job starts with: a suite started in
    # the background of a non-interactive shell inherits SIGINT ignored, and main then
    # rightly leaves it so.
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert cli.main(['simulate', 'x.yaml', '--frames', '1', '--out', 'o']) == 130
        assert capsys.readouterr().err.strip() == 'lidar-sim: interrupted'
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler     # restored
    finally:
        signal.signal(signal.SIGINT, inherited)
