"""loop/user_gnc.py: your own controller and navigation, named in the loop config, flown by
the in-process loop (and so by campaigns). The docs' worked PD example is run from the
text of docs/loop.md and must fly exactly the built-in PD it writes out."""
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip('Basilisk')

from lidar_sim_ros.core.config import ConfigError  # noqa: E402
from lidar_sim_ros.loop.config import LoopConfig, load_loop_config  # noqa: E402
from lidar_sim_ros.loop.step import run_loop  # noqa: E402
from lidar_sim_ros.paths import config_path  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / 'docs' / 'loop.md'
EXAMPLE = Path(__file__).resolve().parents[1] / 'examples' / 'loop_pd_controller.py'


def _docs_example() -> str:
    """The python block under the worked example's heading in docs/loop.md."""
    text = DOCS.read_text()
    section = text[text.index('### Your own GNC in process'):]
    return section.split('```python\n', 1)[1].split('```', 1)[0]


def _config(tmp_path, gnc: dict | None = None) -> LoopConfig:
    base = load_loop_config(config_path('loop.yaml'))[0]
    data = base.model_dump()
    data.update(duration_s=20.0, guidance={**data['guidance'], 'hold_ranges_m': [15.0]},
                initial={**data['initial'], 'position_m': (0.4, -15.6, -0.3), 'position_sigma_m': 0.0,
                         'velocity_sigma_mps': 0.0},
                timing={**data['timing'], 'pose_rate_hz': 20.0})
    if gnc:
        data['gnc'] = gnc
    return LoopConfig.model_validate(data)


def test_the_docs_pd_example_flies_the_built_in_pd(tmp_path):
    code = _docs_example()
    assert code.strip() == EXAMPLE.read_text().split('"""', 2)[2].strip()   # the file is the docs' code
    (tmp_path / 'pd.py').write_text(code)
    built_in = run_loop(_config(tmp_path), cloud=None)
    mine = run_loop(_config(tmp_path, {'controller': f'{tmp_path / "pd.py"}:make_controller'}), cloud=None)
    np.testing.assert_allclose(mine.series['force_lvlh_n'], built_in.series['force_lvlh_n'], rtol=0, atol=1e-9)
    np.testing.assert_allclose(mine.series['rho_true_m'], built_in.series['rho_true_m'], rtol=0, atol=1e-9)
    assert np.abs(built_in.series['force_lvlh_n']).max() > 0.5      # it did act
    # Half the gain is another controller: another flight.
    (tmp_path / 'soft.py').write_text(code.replace('w = config.guidance.natural_frequency_rad_s',
                                                   'w = 0.5 * config.guidance.natural_frequency_rad_s'))
    soft = run_loop(_config(tmp_path, {'controller': f'{tmp_path / "soft.py"}:make_controller'}), cloud=None)
    assert np.abs(soft.series['rho_true_m'] - built_in.series['rho_true_m']).max() > 0.01


NAV = '''
from lidar_sim_ros.loop.guidance import NavState, nav_update

class AlphaBeta:
    """The built-in filter behind the entry-point interface."""
    def __init__(self, config):
        self.cfg, self.nav, self.calls = config.guidance, NavState(), 0
    def update(self, t_s, rho_m):
        self.calls += 1
        if rho_m is not None:
            self.nav = nav_update(self.cfg, self.nav, t_s, rho_m)
    def at(self, t_s):
        return self.nav.at(t_s) if self.nav.valid else None

def make_filter(config):
    return AlphaBeta(config)
'''


def test_a_navigation_entry_point_from_a_file_beside_the_config(tmp_path):
    (tmp_path / 'nav.py').write_text(NAV)
    text = config_path('loop.yaml').read_text().replace(
        'scenario: scenario_all_effects.yaml', f'scenario: {config_path("scenario_all_effects.yaml")}')
    (tmp_path / 'loop.yaml').write_text(text + '\ngnc:\n  navigation: nav.py:make_filter\n')
    cfg = load_loop_config(tmp_path / 'loop.yaml')[0]
    assert cfg.gnc.navigation == f'{(tmp_path / "nav.py").resolve()}:make_filter'   # resolved beside it
    built_in = run_loop(_config(tmp_path), cloud=None)
    mine = run_loop(_config(tmp_path, {'navigation': cfg.gnc.navigation}), cloud=None)
    np.testing.assert_array_equal(mine.series['force_lvlh_n'], built_in.series['force_lvlh_n'])


def test_bad_entry_points_are_named(tmp_path):
    text = config_path('loop.yaml').read_text().replace(
        'scenario: scenario_all_effects.yaml', f'scenario: {config_path("scenario_all_effects.yaml")}')
    (tmp_path / 'loop.yaml').write_text(text + '\ngnc:\n  controller: no_colon_here\n')
    with pytest.raises(ConfigError, match='gnc.controller'):
        load_loop_config(tmp_path / 'loop.yaml')
    (tmp_path / 'bad.py').write_text('def make(config):\n    return lambda *a: [float("nan"), 0, 0]\n')
    with pytest.raises(ValueError, match='bad.py:make returned'):
        run_loop(_config(tmp_path, {'controller': f'{tmp_path / "bad.py"}:make'}), cloud=None, duration_s=1.0)
    with pytest.raises(FileNotFoundError):
        run_loop(_config(tmp_path, {'controller': f'{tmp_path / "none.py"}:make'}), cloud=None, duration_s=1.0)


def test_a_campaign_flies_the_config_s_controller(tmp_path):
    """A closed-loop campaign's worker builds its loop from the loop config (build_context),
    so the docs' PD named there flies every run: the same metrics as the built-in PD."""
    import yaml

    from lidar_sim_ros.campaign.run import run_one
    from lidar_sim_ros.campaign.loop_case import read_result
    from lidar_sim_ros.campaign.spec import load_campaign
    (tmp_path / 'pd.py').write_text(_docs_example())
    text = config_path('loop.yaml').read_text().replace(
        'scenario: scenario_all_effects.yaml', f'scenario: {config_path("scenario_all_effects.yaml")}')
    metrics = {}
    for name, extra in (('built_in', ''), ('mine', '\ngnc:\n  controller: pd.py:make_controller\n')):
        (tmp_path / f'{name}.yaml').write_text(text + extra)
        spec = {'scenario': str(config_path('scenario.yaml')), 'seed': 5, 'runs': 1, 'duration_s': 0.5,
                'loop': {'config': str(tmp_path / f'{name}.yaml'), 'cloud': 'truth'},
                'dispersions': {'initial_distance_m': {'dist': 'uniform', 'low': 20.0, 'high': 25.0}}}
        (tmp_path / f'{name}_c.yaml').write_text(yaml.safe_dump(spec))
        campaign = load_campaign(tmp_path / f'{name}_c.yaml')
        row = run_one(campaign, 0, str(tmp_path / name))
        assert row['status'] == 'ok', row['error']
        metrics[name] = read_result(tmp_path / name, 0)['metrics']
    assert metrics['mine']['delta_v_mps'] > 0
    for key, value in metrics['built_in'].items():
        if isinstance(value, float):
            assert metrics['mine'][key] == pytest.approx(value, rel=1e-9, abs=1e-12, nan_ok=True), key
        else:
            assert metrics['mine'][key] == value, key
