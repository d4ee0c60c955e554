"""Shots behind the unmatched points (compare/recording/shots.py): hand counts."""
from dataclasses import dataclass, field

import numpy as np
import pytest

from lidar_sim_ros.compare.model.matching import Model
from lidar_sim_ros.compare.recording.shots import missed_per_unmatched
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.geometry import load_target
from lidar_sim_ros.paths import config_path


@dataclass
class Recording:
    """The three things the count reads from a Measurements."""

    n: int
    cloud_stamps_s: np.ndarray
    dropped: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return self.n


def test_scan_pattern_counts_the_shots_of_an_unorganised_cloud():
    # 2 clouds of a 1000-shot pattern: 300 points read, 200 on the target, 100 off it.
    rec = Recording(300, np.zeros(2))
    matched = np.r_[np.ones(200, bool), np.zeros(100, bool)]
    assert missed_per_unmatched(rec, matched, 1000) == pytest.approx((2000 - 200) / 100)


def test_an_analysed_subset_scales_the_shots():
    # 600 finite points read, 300 analysed: half the 2000 shots stand behind them.
    rec = Recording(300, np.zeros(2), {'subsampled': 300})
    matched = np.r_[np.ones(200, bool), np.zeros(100, bool)]
    assert missed_per_unmatched(rec, matched, 1000) == pytest.approx((1000 - 200) / 100)


def test_an_organised_cloud_counts_its_empty_slots():
    # A scan pattern of another sensor (10 shots a frame) is smaller than the recording:
    # the organised cloud's 5000 slots (4700 of them empty) count the shots.
    rec = Recording(300, np.zeros(2), {'non_finite': 4600, 'at_origin': 100})
    matched = np.r_[np.ones(200, bool), np.zeros(100, bool)]
    assert missed_per_unmatched(rec, matched, 10) == pytest.approx((5000 - 200) / 100)


def test_unknown_when_the_pattern_fires_fewer_shots_than_the_points():
    rec = Recording(300, np.zeros(2))
    matched = np.r_[np.ones(200, bool), np.zeros(100, bool)]
    assert missed_per_unmatched(rec, matched, 100) is None     # 200 shots < 300 points
    assert missed_per_unmatched(rec, np.ones(300, bool), 1000) is None   # nothing unmatched


def test_shots_per_frame_of_the_p60_pattern():
    scenario = load_scenario(config_path('scenario.yaml'))
    scan = scenario.sensor.scan
    target = load_target(scenario.mesh_path, scenario.materials.names)
    model = Model(scenario.sensor, scenario.materials, target, (), scenario.seed,
                  scenario.source.parent)
    # What compare passes as the frame's shots: 8 x 3 tiles, one laser each (paper
    # Sec. 3), shots_per_laser each per frame.
    assert len(model.simulator().shots) == scan.tiles_az * scan.tiles_el * scan.shots_per_laser
