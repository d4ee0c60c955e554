"""Tests for lidar_sim_ros/viz/figures.py: the paper's figures as PNG."""
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from lidar_sim_ros.core.config import load_sensor
from lidar_sim_ros.core.scan import frame_shots
from lidar_sim_ros.io.bag import BagContentError, BagWriter
from lidar_sim_ros.io.pointcloud import make_points
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.viz import figures
from lidar_sim_ros.viz.figures import FIGURE_NAMES, render_bag_figures, render_frame_figures

NAMES = ['PIF', 'MLI', 'PAF']
T0_NS = 1_700_000_000_000_000_000


@pytest.fixture(scope='module')
def p60_shots():
    return frame_shots(load_sensor(config_path('cepton_vista_p60.yaml')))


def plate_points(n_side: int = 60, range_m: float = 10.0, seed: int = 0) -> np.ndarray:
    """A wall at x = range_m seen over +-10 deg, three materials in vertical bands."""
    az, el = np.meshgrid(np.radians(np.linspace(-10, 10, n_side)),
                         np.radians(np.linspace(-5, 5, n_side // 2)))
    az, el = az.ravel(), el.ravel()
    xyz = range_m * np.column_stack([np.ones_like(az), np.tan(az), np.tan(el) / np.cos(az)])
    rng = np.random.default_rng(seed)
    material = np.digitize(az, np.radians([-3.0, 3.0])).astype(np.uint8)
    return make_points(xyz, 10 ** rng.uniform(-4, 0, len(az)), rng.uniform(0, 0.1, len(az)),
                       (np.arange(len(az)) % 24).astype(np.uint16), material)


def test_tile_grid_of_the_p60_is_its_8x3_array(p60_shots):
    """Edges from the shots alone: 60 x 22 deg split into 7.5 deg columns and 22/3 deg rows."""
    grid = figures._tile_grid(np.degrees(p60_shots.az_rad), np.degrees(p60_shots.el_rad),
                              p60_shots.laser)
    assert grid is not None
    az_edges, el_edges = grid
    np.testing.assert_allclose(az_edges, np.linspace(-30, 30, 9), atol=0.02)
    np.testing.assert_allclose(el_edges, np.linspace(-11, 11, 4), atol=0.02)


def test_no_tile_grid_for_a_spinning_sensor():
    az = np.tile(np.linspace(-180, 180, 100), 4)
    el = np.repeat([-2.0, 0.0, 2.0, 4.0], 100)
    assert figures._tile_grid(az, el, np.repeat(np.arange(4), 100)) is None


def test_frame_figures_sizes_and_order(tmp_path, p60_shots):
    paths = render_frame_figures(plate_points(), tmp_path, NAMES, p60_shots, prefix='p_')
    assert paths == [tmp_path / f'p_{name}.png' for name in FIGURE_NAMES]
    for path in paths:
        image = imread(path)
        assert path.stat().st_size > 20_000
        # 150 dpi on a 10 x 5 in (angular), 10 x 5.5 in (scan pattern) or 9 x 7 in (3D) canvas
        assert image.shape[:2] in {(750, 1500), (825, 1500), (1050, 1350)}, (path.name, image.shape)
        assert (image[..., :3].min(axis=2) < 0.9).mean() > 0.02, path.name


def test_material_legend_names_and_counts():
    pts = plate_points()
    material = pts['material'].astype(np.int64)
    material[:5] = 255  # false returns carry no material
    az, el = np.zeros(len(pts)), np.zeros(len(pts))
    fig = figures._materials(az, el, material, NAMES, '')
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    counts = np.bincount(material[material != 255], minlength=3)
    assert texts == [f'PIF: poly-isocyanate foam (insulation) ({counts[0]})',
                     f'MLI: multi-layer insulation ({counts[1]})',
                     f'PAF: payload attachment fitting ({counts[2]})',
                     'no material (false return) (5)']


def test_small_material_drawn_on_top_and_absent_ones_named():
    """A 5-point class gets larger dots above the others; a material not in view is
    still in the legend (with 0), so the legend names every material of the file."""
    names = ['PIF', 'MLI', 'NOZZLE', 'ADAPTER']
    material = np.array([0] * 500 + [1] * 300 + [2] * 5)
    az = np.linspace(-10, 10, len(material))
    fig = figures._materials(az, np.zeros_like(az), material, names, '')
    ax = fig.axes[0]
    nozzle = next(c for c in ax.collections if c.get_label().startswith('NOZZLE'))
    pif = next(c for c in ax.collections if c.get_label().startswith('PIF'))
    assert nozzle.get_sizes()[0] > 4 * pif.get_sizes()[0]
    assert nozzle.get_zorder() > pif.get_zorder()
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert texts[2] == 'NOZZLE: engine nozzle (5)' and texts[3] == 'ADAPTER (0)'


def test_scan_pattern_outlines_the_fov_and_names_absent_rings(p60_shots):
    pts = plate_points()
    pts['ring'] = np.where(np.isin(pts['ring'], [3, 23]), 4, pts['ring'])
    az, el = figures.angles_from_directions(np.column_stack([pts['x'], pts['y'], pts['z']]))
    layout = figures.ScanLayout(60.0, 22.0, 8, 3)
    fig = figures._scan_pattern(p60_shots, np.degrees(az), np.degrees(el), pts, '', layout)
    ax = fig.axes[0]
    assert 'returns in 22 rings, none from rings 3, 23' in ax.get_title()
    (fov,) = [p for p in ax.patches if type(p).__name__ == 'Rectangle']
    assert (fov.get_x(), fov.get_y(), fov.get_width(), fov.get_height()) == (-30, -11, 60, 22)
    # 7 inner azimuth and 2 inner elevation tile edges
    assert len(ax.lines) == 9
    # 24 lasers, 24 different colours
    assert len({tuple(c) for c in figures.palette(24)}) == 24


def test_3d_z_label_reads_upright():
    fig = figures._points_3d(np.array([[10.0, 0, 0], [11.0, 1, 1]]), np.array([10.0, 11.5]), '')
    ax = fig.axes[0]
    assert ax.get_zlabel() == 'z [m]\n(up)'
    assert not ax.zaxis.get_rotate_label(ax.get_zlabel())


def test_azimuth_grows_to_the_left():
    fig = figures._range_image(np.array([-5.0, 5.0]), np.array([0.0, 1.0]), np.array([9.0, 11.0]), '')
    left, right = fig.axes[0].get_xlim()
    assert left > right  # REP-103: +y (positive azimuth) is on the sensor's left


def test_missing_fields_skip_their_figures(tmp_path):
    pts = plate_points()
    xyz_only = np.empty(len(pts), dtype=[('x', 'f4'), ('y', 'f4'), ('z', 'f4')])
    for name in 'xyz':
        xyz_only[name] = pts[name]
    paths = render_frame_figures(xyz_only, tmp_path, None)
    assert [p.stem for p in paths] == ['points_3d_range', 'range_image']


def test_empty_frame_still_renders(tmp_path):
    empty = make_points(np.zeros((0, 3)), 0.0, 0.0, 0, 0)
    paths = render_frame_figures(empty, tmp_path, NAMES)
    assert [p.stem for p in paths] == list(FIGURE_NAMES)
    assert all(p.stat().st_size > 5_000 for p in paths)


def test_not_a_point_array_is_rejected(tmp_path):
    with pytest.raises(ValueError, match='x, y, z'):
        render_frame_figures(np.zeros((10, 3)), tmp_path, NAMES)


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp('bag') / 'bag'
    with BagWriter(path) as bag:
        bag.write_material_names('/lidar/material_names', T0_NS, NAMES)
        for i in range(3):
            bag.write_cloud('/lidar/points', plate_points(40, 10.0 + i, seed=i),
                            T0_NS + i * 100_000_000, 'lidar')
    return path


def test_bag_figures_last_frame(tmp_path, small_bag):
    paths = render_bag_figures(small_bag, tmp_path)
    # no truth cloud in this bag: of the run figures only run.png
    assert paths == [tmp_path / f'{name}.png' for name in (*FIGURE_NAMES, 'run')]
    assert all(imread(p).shape[2] == 4 for p in paths)


def test_bag_figures_frame_selection(tmp_path, small_bag):
    paths = render_bag_figures(small_bag, tmp_path, material_names=['a', 'b', 'c'], frames=[0, -1],
                               run_figures=False)
    assert [p.name for p in paths] == ([f'frame_0000_{n}.png' for n in FIGURE_NAMES]
                                       + [f'frame_0002_{n}.png' for n in FIGURE_NAMES])
    with pytest.raises(ValueError, match='index 3'):
        render_bag_figures(small_bag, tmp_path, frames=3)
    with pytest.raises(ValueError, match="'every'"):
        render_bag_figures(small_bag, tmp_path, frames='every')


def test_bag_without_clouds(tmp_path):
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        bag.write_material_names('/lidar/material_names', T0_NS, NAMES)
    with pytest.raises(BagContentError, match='/lidar/points'):
        render_bag_figures(path, tmp_path / 'fig')


def test_scan_pattern_of_a_flash_array_counts_its_silent_rows():
    """256 lasers (a flash array's rows): no 256 labels, no 255 'tile' edges and no list
    of ~200 silent rows running off the title (what a user saw of scenario_flash.yaml)."""
    sensor = load_sensor(config_path('flash_256.yaml'))
    shots = frame_shots(sensor)
    pts = plate_points()
    pts['ring'] = np.arange(len(pts)) % 50 + 100           # returns from rows 100-149
    az, el = figures.angles_from_directions(np.column_stack([pts['x'], pts['y'], pts['z']]))
    fig = figures._scan_pattern(shots, np.degrees(az), np.degrees(el), pts, '',
                                figures.ScanLayout(20.0, 20.0, None, None))
    ax = fig.axes[0]
    assert ax.get_title().startswith('Scan pattern of one frame (cf. paper Fig. 6): 65536 shots, '
                                     '256 lasers; returns in 50 rings, none from 206 of 256')
    assert len(ax.lines) == 0
    assert [t.get_text() for t in ax.texts] == ['field of view 20 x 20 deg']
    assert ax.get_xlabel().endswith('colour = laser id; faint: every shot, full colour: returns')


def test_box_wing_materials_named_in_full():
    """points_material.png of the box-wing (config/materials_box_wing.yaml): each part's
    material says what it is, as the rocket body's do."""
    names = ['MLI', 'SOLAR_ARRAY', 'WHITE_PAINT', 'ALUMINIUM']
    material = np.repeat(np.arange(4), 50)
    az = np.linspace(-10, 10, len(material))
    fig = figures._materials(az, np.zeros_like(az), material, names, '')
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert texts == ['MLI: multi-layer insulation (50)', 'SOLAR_ARRAY: solar cells under cover glass (50)',
                     'WHITE_PAINT: white radiator paint (50)', 'ALUMINIUM: bare aluminium (antenna, booms) (50)']


def test_scan_pattern_of_a_rosette_outlines_its_circular_field():
    """The Mid-40: the 38.4 deg circle drawn (every rim point 19.2 deg off +x), its
    10,000 shots inside it."""
    sensor = load_sensor(config_path('livox_mid40.yaml'))
    layout = figures.ScanLayout.of_sensor(sensor)
    assert layout.field_half_angle_deg == pytest.approx(19.2)
    shots = frame_shots(sensor)
    pts = plate_points()
    pts['ring'] = 0
    az, el = figures.angles_from_directions(np.column_stack([pts['x'], pts['y'], pts['z']]))
    fig = figures._scan_pattern(shots, np.degrees(az), np.degrees(el), pts, '', layout)
    ax = fig.axes[0]
    (rim,) = ax.lines
    r_az, r_el = np.radians(rim.get_xdata()), np.radians(rim.get_ydata())
    np.testing.assert_allclose(np.degrees(np.arccos(np.cos(r_el) * np.cos(r_az))), 19.2, atol=1e-9)
    off = np.degrees(np.arccos(np.cos(shots.el_rad) * np.cos(shots.az_rad)))
    assert len(off) == 10_000 and off.max() <= 19.2 + 1e-9
    assert 'field of view 38.4 deg circle' in [t.get_text() for t in ax.texts]
