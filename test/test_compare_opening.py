"""Tests for lidar_sim_ros/compare/report/opening.py: the report's first lines from summary.json."""
import shlex

from lidar_sim_ros.compare.report import opening
from lidar_sim_ros.paths import config_path


def summary(**over) -> dict:
    """A range-walk run as compare writes it: two significant candidates, one vetoed."""
    s = {
        'bag': 'measured/bag', 'mesh': 'meshes/rocket_body.obj',
        'config': str(config_path('scenario.yaml')), 'effects': [], 'fitted_effects': [],
        'missing_effect': 'range_walk', 'range_rmse_calibrated_m': 0.0340,
        'candidates_basis': {'range_rmse_calibrated_m': 0.0337},
        'verdict': 'The range residual depends on four features together. This is range walk.',
        'candidates': [
            {'name': 'range_walk', 'score': 0.0599, 'z': 9.8, 'significant': True,
             'practical': True, 'structure_share': 1.03, 'range_rmse_after_m': 0.0317},
            {'name': 'incidence_angle', 'score': 0.0331, 'z': 9.0, 'significant': True,
             'practical': True, 'structure_share': 0.57, 'range_rmse_after_m': 0.0326},
            {'name': 'snr_noise', 'score': 0.0003, 'z': 1.1, 'significant': False,
             'vetoed': 'the residual has another shape than this effect'},
            {'name': 'time_offset', 'score': -0.002, 'z': -1.3, 'significant': False},
        ],
    }
    s.update(over)
    return s


def test_title_is_the_recording_not_its_bag_folder():
    assert opening.title(summary()) == 'lidar-sim compare: measured'
    assert opening.title(summary(bag='/data/flight_03.mcap')) == 'lidar-sim compare: flight_03'


def test_headline_names_the_effect_and_its_numbers_in_one_line():
    line = opening.headline(summary())
    assert line == ('Missing effect: range_walk. Adding it cuts the range RMSE from 0.0337 m to '
                    '0.0317 m (held-out gain 0.0599 nats/point, z = 9.8).')
    assert '\n' not in line


def test_headline_without_a_missing_effect_is_the_verdicts_first_sentence():
    s = summary(missing_effect=None, verdict='No catalogue effect improves it: noise. More text.')
    assert opening.headline(s) == 'No catalogue effect improves it: noise.'


def test_action_is_a_command_that_parses_and_reruns_with_the_effect():
    what, cmd = opening.next_command(summary(effects=[{'name': 'beam_divergence'}]),
                                     'runs/baseline')
    assert what.startswith('Add range_walk')
    assert shlex.split(cmd) == ['lidar-sim', 'compare', 'measured/bag', '--mesh',
                                'meshes/rocket_body.obj', '--effect', 'beam_divergence',
                                '--effect', 'range_walk', '--fit', '--out', 'runs/range_walk']
    # a scenario of the user's own is passed on; paths with spaces stay one argument
    _, cmd = opening.next_command(summary(config='/my cfg/s.yaml'), 'runs/baseline')
    assert shlex.split(cmd)[5:7] == ['--config', '/my cfg/s.yaml']


def test_nothing_missing_after_a_fit_points_at_the_snippet():
    s = summary(missing_effect=None, fitted_effects=[{'name': 'range_walk'}])
    assert opening.next_command(s, 'runs/range_walk')[1] == 'cat runs/range_walk/effects.yaml'
    assert opening.next_command(summary(missing_effect=None), 'runs/x') is None


def test_materials_off_the_configuration_get_a_refit_command():
    s = summary(missing_effect=None, materials={
        'PIF': {'bias_mismatch': True, 'sigma_mismatch': False},
        'MLI': {'bias_mismatch': False, 'sigma_mismatch': False}})
    what, cmd = opening.next_command(s, 'runs/baseline')
    assert 'PIF' in what and 'MLI' not in what
    assert shlex.split(cmd)[-3:] == ['--fit', '--out', 'runs/materials_fit']


def test_why_the_named_effect_beat_the_other_significant_one():
    why = opening.candidate_reasons(summary())
    assert why['range_walk'].startswith('named: the largest held-out gain')
    assert why['incidence_angle'] == (
        "significant, but range_walk explains more: gain 0.0331 < 0.0599 nats/point; explains "
        "57 % of the residual's structure, range_walk 103 %; RMSE after 0.0326 m vs 0.0317 m")
    assert why['snr_noise'] == 'vetoed: the residual has another shape than this effect'
    assert why['time_offset'] == 'not significant (z = -1.3)'
