"""Tests for lidar_sim_ros/offline.py: `lidar-sim simulate` end to end, in process."""
import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from matplotlib.image import imread
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lidar_sim_ros.cli import main
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.pose import PoseTrack
from lidar_sim_ros.io.bag import read_clouds, read_material_names, read_poses
from lidar_sim_ros.io.pointcloud import POINT_DTYPE
from lidar_sim_ros.core.effects import parse_effect_spec
from lidar_sim_ros.offline import DEFAULT_EPOCH_S, TRUTH_TOPIC
from lidar_sim_ros.paths import config_path
from lidar_sim_ros.viz.figures import FIGURE_NAMES
from lidar_sim_ros.viz.run import RUN_FIGURE_NAMES
from conftest import embree_range_tol_m

SCENARIO = config_path('scenario.yaml')
EPOCH_NS = int(DEFAULT_EPOCH_S * 1e9)
PERIOD_NS = 100_000_000  # P-60 at 10 Hz
FRAMES = 2


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    """`lidar-sim simulate` of the default scenario, 2 frames: (out dir, stdout, exit code)."""
    out = tmp_path_factory.mktemp('offline') / 'out'
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(['simulate', str(SCENARIO), '--frames', str(FRAMES), '--out', str(out)])
    return out, buf.getvalue(), code


def test_prints_bag_and_figure_paths(run):
    out, stdout, code = run
    assert code == 0
    lines = stdout.splitlines()
    assert lines[0].startswith(f'bag: {out / "bag"}')
    printed = [Path(line.removeprefix('figure: ')) for line in lines[1:]]
    assert printed == [out / 'figures' / f'{name}.png'
                       for name in (*FIGURE_NAMES, *RUN_FIGURE_NAMES)]


def test_bag_topics_and_counts_with_rosbags(run):
    out, _, _ = run
    with AnyReader([out / 'bag'], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        counts = {c.topic: 0 for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        clouds = []
        for conn, log_ns, raw in reader.messages():
            counts[conn.topic] += 1
            if conn.topic == '/lidar/points':
                clouds.append((log_ns, reader.deserialize(raw, conn.msgtype)))
    assert types == {'/lidar/points': 'sensor_msgs/msg/PointCloud2',
                     TRUTH_TOPIC: 'sensor_msgs/msg/PointCloud2',
                     '/target/pose': 'geometry_msgs/msg/PoseStamped',
                     '/lidar/material_names': 'std_msgs/msg/String'}
    # 10 poses per frame plus one at the end of the last frame
    assert counts == {'/lidar/points': FRAMES, TRUTH_TOPIC: FRAMES,
                      '/target/pose': 10 * FRAMES + 1, '/lidar/material_names': 1}

    # Second decoder: the raw PointCloud2 bytes as the documented 24-byte layout.
    ours = read_clouds(out / 'bag')
    for (log_ns, msg), frame in zip(clouds, ours):
        assert msg.header.frame_id == 'lidar' == frame.frame_id
        assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'intensity', 't', 'ring', 'material',
                                                    'return']
        assert (msg.point_step, msg.height, msg.is_bigendian) == (24, 1, False)
        raw_points = np.frombuffer(bytes(msg.data), dtype=POINT_DTYPE)
        assert len(raw_points) == msg.width == len(frame.points) > 10_000
        for name in POINT_DTYPE.names:
            np.testing.assert_array_equal(raw_points[name], frame.points[name], err_msg=name)
        assert log_ns == frame.stamp_ns


def test_cloud_stamps_are_frame_starts_one_period_apart(run):
    out, _, _ = run
    for topic in ('/lidar/points', TRUTH_TOPIC):
        stamps = [c.stamp_ns for c in read_clouds(out / 'bag', topic)]
        assert stamps == [EPOCH_NS + i * PERIOD_NS for i in range(FRAMES)]
    for cloud in read_clouds(out / 'bag'):
        t = cloud.points['t']
        assert t.min() >= 0.0 and t.max() < PERIOD_NS / 1e9


def test_pose_stamps_cover_every_frame(run):
    out, _, _ = run
    poses = read_poses(out / 'bag')
    assert poses.frame_id == 'lidar'
    for i in range(FRAMES):
        start, end = EPOCH_NS + i * PERIOD_NS, EPOCH_NS + (i + 1) * PERIOD_NS
        inside = poses.stamp_ns[(poses.stamp_ns >= start) & (poses.stamp_ns <= end)]
        assert len(inside) >= 5
        assert inside[0] == start and inside[-1] == end


def test_poses_follow_the_scenario_closed_form(run):
    out, _, _ = run
    cfg = yaml.safe_load(SCENARIO.read_text())
    poses = read_poses(out / 'bag')
    t = (poses.stamp_ns - EPOCH_NS) / 1e9
    p0 = np.array(cfg['initial_pose']['position_m'])
    speed = cfg['motion']['approach_speed_mps']
    # float64 end to end (PoseStamped holds float64): 1e-12 m is ~500 ulps at 10 m.
    np.testing.assert_allclose(poses.position_m, p0 - speed * t[:, None] * p0 / np.linalg.norm(p0),
                               atol=1e-12)
    axis = np.array(cfg['motion']['tumble_axis'], float)
    axis /= np.linalg.norm(axis)
    # after t seconds the body has turned rate * t about the (lidar-frame) tumble axis
    rel = Rotation.from_quat(poses.quat_xyzw) * Rotation.from_quat(poses.quat_xyzw[0]).inv()
    # float64 quaternions; as_rotvec of a small rotation is good to ~1e-15 rad.
    np.testing.assert_allclose(rel.as_rotvec(),
                               np.radians(cfg['motion']['tumble_rate_dps']) * t[:, None] * axis,
                               atol=1e-9)


def surface_distance_m(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Exact distance of each point to the mesh (candidate faces by centroid radius)."""
    tri = mesh.triangles
    centroid = tri.mean(axis=1)
    radius = np.linalg.norm(tri - centroid[:, None], axis=2).max()
    tree = cKDTree(centroid)
    out = np.empty(len(points))
    for i, p in enumerate(points):  # test helper, 150 points
        faces = tree.query_ball_point(p, radius + 0.05)
        if not faces:
            out[i] = np.inf
            continue
        closest = trimesh.triangles.closest_point(tri[faces], np.repeat(p[None], len(faces), 0))
        out[i] = np.linalg.norm(closest - p, axis=1).min()
    return out


def test_truth_points_lie_on_the_mesh_at_their_own_time(run):
    """Stamps, point times and poses in the bag agree: noise-free points sit on the surface."""
    out, _, _ = run
    scenario = load_scenario(SCENARIO)
    mesh = trimesh.load(scenario.mesh_path, force='mesh', process=False)
    poses = read_poses(out / 'bag')
    track = PoseTrack(poses.stamp_ns / 1e9 - DEFAULT_EPOCH_S, poses.position_m, poses.quat_xyzw)
    cloud = read_clouds(out / 'bag', TRUTH_TOPIC)[-1]
    pts = cloud.points[np.random.default_rng(0).choice(len(cloud.points), 150, replace=False)]
    t_s = (cloud.stamp_ns - EPOCH_NS) / 1e9 + pts['t'].astype(float)
    xyz = np.column_stack([pts['x'], pts['y'], pts['z']]).astype(float)
    distance = surface_distance_m(mesh, track.at(t_s).to_body(xyz))
    # Embree's float32 range (8 ulps) plus the float32 x, y, z fields (half an ulp each).
    range_m = np.linalg.norm(xyz, axis=1)
    packed_m = np.sqrt(3) * 0.5 * float(np.spacing(np.float32(range_m.max())))
    assert distance.max() < embree_range_tol_m(range_m) + packed_m
    # the same points taken at the frame start (motion during the frame ignored) are off it
    at_start = surface_distance_m(mesh, track.at(np.full_like(t_s, t_s.min())).to_body(xyz))
    assert at_start.max() > 5 * distance.max()


def test_material_names_and_measured_materials(run):
    out, _, _ = run
    # The table as materials.yaml lists it (read here, not through the package's loader):
    # list order is the material id in the clouds.
    names = [m['name'] for m in yaml.safe_load(config_path('materials.yaml').read_text())['materials']]
    assert read_material_names(out / 'bag') == names
    # What any other reader sees: a std_msgs/String holding a JSON array of the names.
    with AnyReader([out / 'bag'], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic == '/lidar/material_names']
        texts = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages(connections=conns)]
    assert len(texts) == 1 and json.loads(texts[0]) == names
    material = read_clouds(out / 'bag')[0].points['material']
    assert set(np.unique(material)) <= set(range(len(names)))
    assert {'PIF', 'MLI'} <= {names[m] for m in np.unique(material)}


def test_figures_are_readable_pngs(run):
    out, _, _ = run
    for name in FIGURE_NAMES:
        path = out / 'figures' / f'{name}.png'
        assert path.stat().st_size > 30_000, name
        image = imread(path)
        assert image.ndim == 3 and image.shape[0] > 500 and image.shape[1] > 900, name
        rgb = image[..., :3]
        # not blank: a good share of non-white pixels and many distinct colours
        assert (rgb.min(axis=2) < 0.9).mean() > 0.05, name
        # Distinct colours, each packed into one integer (np.unique by rows is ~20x slower).
        r, g, b = np.moveaxis((rgb * 255).astype(np.uint8).astype(np.uint32), -1, 0)
        assert len(np.unique(r << 16 | g << 8 | b)) > 50, name


def test_existing_bag_is_an_error(run, capsys):
    out, _, _ = run
    before = (out / 'bag' / 'metadata.yaml').read_bytes()
    code = main(['simulate', str(SCENARIO), '--frames', '1', '--out', str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and 'already exists' in err and str(out / 'bag') in err
    assert (out / 'bag' / 'metadata.yaml').read_bytes() == before


def test_bad_scenario_key_is_a_one_line_error(tmp_path, capsys):
    data = yaml.safe_load(SCENARIO.read_text())
    data['motion']['tumble_speed_dps'] = 3.0  # not a key of the motion section
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump(data))
    code = main(['simulate', str(bad), '--frames', '1', '--out', str(tmp_path / 'out')])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1
    assert 'motion.tumble_speed_dps' in err and str(bad) in err and 'Traceback' not in err
    assert not (tmp_path / 'out' / 'bag').exists()


def test_unknown_effect_is_a_one_line_error(tmp_path, capsys):
    code = main(['simulate', str(SCENARIO), '--frames', '1', '--out', str(tmp_path),
                 '--effect', 'no_such_effect'])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and 'no_such_effect' in err


SHIFT_EFFECT = """
import numpy as np
from pydantic import BaseModel
from lidar_sim_ros.core.effects import Effect

class Shift(Effect):
    name = 'test_shift'

    class Params(BaseModel):
        offset_m: float = 0.0

    def range_bias_m(self, ctx):
        return np.full(len(ctx), self.params.offset_m)
"""


def test_user_effect_from_the_command_line(tmp_path, capsys):
    """A file.py:Class effect adding 1 m of bias moves every point 1 m out along its ray."""
    effect = tmp_path / 'shift.py'
    effect.write_text(SHIFT_EFFECT)
    base = ['simulate', str(SCENARIO), '--frames', '1', '--no-figures']
    assert main(base + ['--out', str(tmp_path / 'plain')]) == 0
    assert main(base + ['--out', str(tmp_path / 'shift'),
                        '--effect', f'{effect}:Shift={{offset_m: 1.0}}']) == 0
    plain = read_clouds(tmp_path / 'plain' / 'bag')[0].points
    shifted = read_clouds(tmp_path / 'shift' / 'bag')[0].points
    np.testing.assert_array_equal(plain['ring'], shifted['ring'])
    np.testing.assert_array_equal(plain['t'], shifted['t'])

    def range_m(p):
        return np.linalg.norm(np.column_stack([p['x'], p['y'], p['z']]).astype(float), axis=1)

    # Both clouds went through float32 x, y, z fields: each range is good to sqrt(3)/2 ulps.
    ulp_m = float(np.spacing(np.float32(range_m(shifted).max())))
    np.testing.assert_allclose(range_m(shifted) - range_m(plain), 1.0, atol=np.sqrt(3) * ulp_m)

    code = main(base + ['--out', str(tmp_path / 'bad'),
                        '--effect', f'{effect}:Shift={{offset_m: far}}'])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert '--effect' in err and 'Shift.offset_m' in err and "'far'" in err


def test_sqlite3_start_time_and_no_figures(tmp_path, capsys):
    code = main(['simulate', str(SCENARIO), '--frames', '1', '--out', str(tmp_path),
                 '--start-s', '0.35', '--storage', 'sqlite3', '--no-figures', '--epoch-s', '100'])
    assert code == 0
    assert 'figure:' not in capsys.readouterr().out
    assert not (tmp_path / 'figures').exists()
    assert [p.suffix for p in (tmp_path / 'bag').iterdir() if p.suffix != '.yaml'] == ['.db3']
    assert [c.stamp_ns for c in read_clouds(tmp_path / 'bag')] == [100_350_000_000]
    stamps = read_poses(tmp_path / 'bag').stamp_ns
    np.testing.assert_array_equal(stamps, 100_350_000_000 + 10_000_000 * np.arange(11))


def test_parse_effect_spec():
    assert parse_effect_spec('range_walk') == ('range_walk', {})
    assert parse_effect_spec('range_walk={k_m: 0.02}') == ('range_walk', {'k_m': 0.02})
    assert parse_effect_spec('my.mod:Cls={"a": 1}') == ('my.mod:Cls', {'a': 1})
    with pytest.raises(ValueError, match='mapping'):
        parse_effect_spec('range_walk=3')


# --------------------------------------------------------------------- sunlight
SUNLIT_FRAMES = 10


@pytest.fixture(scope='module')
def sunlit_run(tmp_path_factory):
    """`lidar-sim simulate` of config/scenario_sunlit.yaml: the bag and figures."""
    out = tmp_path_factory.mktemp('sunlit') / 'out'
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(['simulate', str(config_path('scenario_sunlit.yaml')), '--frames',
                     str(SUNLIT_FRAMES), '--out', str(out)])
    assert code == 0
    return out


def what_shots_see(bag_points, stamp_ns, poses, sun_dir, target):
    """For points of one cloud: does the shot's ray hit the target, and is that surface point
    in direct sunlight (facing the sun, shadow ray clear)? Posed at each shot's own time."""
    from lidar_sim_ros.core.geometry import cast_at_poses
    xyz = np.column_stack([bag_points['x'], bag_points['y'], bag_points['z']]).astype(float)
    d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    pose = poses.at((stamp_ns - EPOCH_NS) / 1e9 + bag_points['t'].astype(float))
    hits = cast_at_poses(target, d, pose)
    point = d * np.where(hits.hit, hits.range_m, 0.0)[:, None]
    origin = point + 2e-3 * hits.normal
    blocked = cast_at_poses(target, np.broadcast_to(sun_dir, d.shape), pose, origin_lidar_m=origin).hit
    sunlit = hits.hit & (hits.normal @ sun_dir > 0) & ~blocked
    return hits.hit, sunlit, hits.range_m


def test_sunlit_bag_false_returns_come_from_sunlit_surfaces(sunlit_run):
    """The issue's check on a recorded bag: false returns (material 255) come from shots that
    see sunlit surfaces; their rate on shadowed surfaces is at most a tenth of the sunlit one."""
    from lidar_sim_ros.core.geometry import load_target
    from lidar_sim_ros.io.bag import read_vectors
    bag = sunlit_run / 'bag'
    scenario = load_scenario(config_path('scenario_sunlit.yaml'))
    target = load_target(scenario.mesh_path, scenario.materials.names)
    p = read_poses(bag)
    poses = PoseTrack((p.stamp_ns - EPOCH_NS) / 1e9, p.position_m, p.quat_xyzw)
    sun = read_vectors(bag, '/sun/direction')
    clouds, truth = read_clouds(bag), read_clouds(bag, TRUTH_TOPIC)
    assert len(sun.stamp_ns) == SUNLIT_FRAMES and sun.frame_id == 'lidar'
    np.testing.assert_allclose(sun.vector[0], np.array([0.0, 0.34, 0.94]) / np.hypot(0.34, 0.94))
    counts = dict(false_sunlit=0, false_shadowed=0, false_space=0, sunlit=0, shadowed=0)
    for cloud, all_hits, s_ns, s_dir in zip(clouds, truth, sun.stamp_ns, sun.vector):
        assert cloud.stamp_ns == all_hits.stamp_ns == s_ns
        hit, sunlit, _ = what_shots_see(all_hits.points, cloud.stamp_ns, poses, s_dir, target)
        assert hit.mean() > 0.999                     # the truth cloud is every hit
        counts['sunlit'] += int(sunlit.sum())
        counts['shadowed'] += int((hit & ~sunlit).sum())
        false = cloud.points[cloud.points['material'] == 255]
        hit, sunlit, range_m = what_shots_see(false, cloud.stamp_ns, poses, s_dir, target)
        r_false = np.linalg.norm(np.column_stack([false['x'], false['y'], false['z']]), axis=1)
        assert np.all(r_false[hit] < range_m[hit] + 0.01)   # the first crossing precedes the echo
        counts['false_sunlit'] += int(sunlit.sum())
        counts['false_shadowed'] += int((hit & ~sunlit).sum())
        counts['false_space'] += int((~hit).sum())
    rate_sunlit = counts['false_sunlit'] / counts['sunlit']
    rate_shadowed = counts['false_shadowed'] / counts['shadowed']
    assert counts['sunlit'] > 30_000 and counts['shadowed'] > 30_000, counts
    assert counts['false_sunlit'] >= 30, counts
    assert rate_shadowed <= 0.1 * rate_sunlit, counts
    assert counts['false_sunlit'] > 3 * (counts['false_shadowed'] + counts['false_space']), counts


def test_sunlit_run_draws_the_sunlight_figure(sunlit_run):
    path = sunlit_run / 'figures' / 'sunlight.png'
    img = imread(path)
    assert img.shape[0] > 800 and img.shape[1] > 800


@pytest.mark.parametrize('where', ['under a file', 'sysfs', 'the bag', 'in the bag'])
def test_pcap_that_cannot_be_written_stops_before_the_bag(tmp_path, capsys, where):
    """Before: a --pcap in a read-only place (sysfs refuses even root) was a PermissionError
    traceback (rc 1), and either failure left DIR/bag behind, so the corrected command
    was refused with 'bag already exists'."""
    if where == 'sysfs':
        if not Path('/sys/kernel').is_dir():
            pytest.skip('no sysfs')
        pcap = Path('/sys/kernel/lidar_sim_test.pcap')
    elif where == 'under a file':
        (tmp_path / 'afile').write_text('x')
        pcap = tmp_path / 'afile' / 'out.pcap'
    else:
        pcap = tmp_path / 'out' / 'bag' / ('x.pcap' if where == 'in the bag' else '')
    out = tmp_path / 'out'
    cmd = ['simulate', str(config_path('scenario.yaml')), '--frames', '1', '--out', str(out),
           '--no-figures']
    assert main(cmd + ['--pcap', str(pcap)]) == 2
    err = capsys.readouterr().err
    assert f'--pcap {pcap}' in err and 'Traceback' not in err
    assert not (out / 'bag').exists()
    assert main(cmd + ['--pcap', str(tmp_path / 'ok.pcap')]) == 0
    assert (tmp_path / 'ok.pcap').stat().st_size > 24
