"""The whole pipeline on closed-form scenes: moving target, dropouts, error model, seeds."""
from dataclasses import dataclass

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.geometry import load_target
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import Poses, ScenarioTrajectory, StaticPose
from lidar_sim_ros.core.scan import directions_from_angles
from conftest import (CONFIG, EMBREE_RTOL, embree_range_tol_m, materials, paper_power_w,
                      plate_target, sensor)

FACING = Rotation.from_euler('y', -90, degrees=True)  # plate normal (body +z) toward the sensor (-x)


@dataclass(frozen=True)
class FastPlate:
    """A plate rushing toward the sensor and spinning about its normal during the frame."""

    speed_mps: float = 20.0
    spin_rad_s: float = 3.0

    def at(self, t_s):
        t = np.atleast_1d(np.asarray(t_s, float))
        pos = np.column_stack([8.0 - self.speed_mps * t, 0.3 * t, np.zeros_like(t)])
        rot = Rotation.from_rotvec(np.outer(self.spin_rad_s * t, [1.0, 0, 0])) * FACING
        return Poses(rot, pos)


def grid_sensor(**det):
    return sensor({'type': 'rotating', 'elevations_deg': list(np.linspace(-10, 10, 9)),
                   'az_min_deg': -10.0, 'az_max_deg': 10.0, 'shots_per_beam': 200}, **det)


def test_each_point_lies_on_the_target_at_its_own_shot_time():
    sim = Simulator(grid_sensor(), materials(sigma_m=0.02, bias_m=-0.1), plate_target(3.0), seed=1)
    motion = FastPlate()
    frame = sim.simulate_frame(0.1, motion, frame_index=1)
    assert len(frame.truth_range_m) > 500
    t_abs = frame.stamp_s + frame.truth_t_s
    body = motion.at(t_abs).to_body(frame.truth_xyz_m)
    on_plane_m = embree_range_tol_m(frame.truth_range_m)      # float32 Embree range, ~8e-6 m
    assert np.abs(body[:, 2]).max() < on_plane_m               # on the plate plane at its own time
    assert np.abs(body[:, :2]).max() <= 1.5 + on_plane_m      # and inside the plate
    # Using the frame-start pose instead would put them centimetres to metres off the plane.
    body0 = motion.at(np.full(len(t_abs), frame.stamp_s)).to_body(frame.truth_xyz_m)
    assert np.abs(body0[:, 2]).max() > 1.0
    # Noisy points: the along-ray error against the plate plane at each shot's own time
    # (ray-plane intersection: r = n.p / n.d) has the material's bias and sigma.
    poses = motion.at(frame.stamp_s + frame.t_s)
    normal = poses.vector_to_lidar(np.tile([0.0, 0, 1], (len(frame), 1)))
    dirs = frame.xyz_m / frame.range_m[:, None]
    true_range = np.einsum('ij,ij->i', normal, poses.position_m) / np.einsum('ij,ij->i', normal, dirs)
    err = frame.range_m - true_range
    assert np.mean(err) == pytest.approx(-0.1, abs=4 * 0.02 / np.sqrt(len(err)))
    assert np.std(err) == pytest.approx(0.02, rel=0.1)


def test_plate_power_and_intensity_match_closed_form():
    s = grid_sensor()
    sim = Simulator(s, materials(kd=0.4, ks=0.3, n=6.0), plate_target(3.0), seed=0)
    frame = sim.simulate_frame(0.0, StaticPose((8.0, 0, 0), tuple(FACING.as_quat())))
    assert len(frame.truth_range_m) > 1000
    dirs = frame.truth_xyz_m / frame.truth_range_m[:, None]
    # The plane x = 8 m faces the sensor: range 8 / d_x, incidence = angle of d to the x axis.
    range_m, inc = 8.0 / dirs[:, 0], np.arccos(dirs[:, 0])
    np.testing.assert_allclose(frame.truth_range_m, range_m, rtol=EMBREE_RTOL, atol=0)
    p = paper_power_w(range_m, inc, 0.4, 0.3, 6.0, s.optics)
    # P ~ r^-2: twice the float32 range error; the rest is float64.
    np.testing.assert_allclose(frame.truth_intensity * s.detection.saturation_power_w, p,
                               rtol=2 * EMBREE_RTOL, atol=0)


def test_every_material_of_the_table_reaches_its_own_faces(tmp_path, default_scenario):
    """Seven plates, one per material, in an OBJ whose groups are shuffled against the
    table (neither the file order nor its reverse is the table's: the mesh loader may
    read groups either way): each plate's power is Eqs. 1-3 and 5 with its own kd, ks,
    n from materials.yaml, and its range error model its own bias and sigma."""
    table = yaml.safe_load((CONFIG / 'materials.yaml').read_text())['materials']
    names = [m['name'] for m in table]
    lines, centre_y = [], {}
    for k, name in enumerate(names[3:] + names[:3]):    # body +z normal, 1 m squares along y
        y = 1.25 * (k - 3)
        centre_y[name] = y
        lines += [f'v {x} {y + dy} 0.0' for x, dy in ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5))]
        lines += [f'o {name}', f'g {name}', f'usemtl {name}',
                  f'f {4 * k + 1} {4 * k + 2} {4 * k + 3}', f'f {4 * k + 1} {4 * k + 3} {4 * k + 4}']
    (tmp_path / 'plates.mtl').write_text(''.join(f'newmtl {n}\nKd 0.5 0.5 0.5\n' for n in names))
    (tmp_path / 'plates.obj').write_text('mtllib plates.mtl\n' + '\n'.join(lines) + '\n')
    target = load_target(tmp_path / 'plates.obj', default_scenario.materials.names)
    sim = Simulator(default_scenario.sensor, default_scenario.materials, target)
    # FACING puts body y on lidar y: plate centres at (10, y, 0); two rays per plate,
    # at its centre and 0.3 m above it (two incidence angles, 0-21 deg).
    points = np.array([[10.0, centre_y[name], z] for name in names for z in (0.0, 0.3)])
    range_m = np.linalg.norm(points, axis=1)
    pred = sim.predict(np.zeros(len(points)), points / range_m[:, None],
                       StaticPose((10.0, 0, 0), tuple(FACING.as_quat())))
    assert pred.ctx.hit.all()
    assert [names[m] for m in pred.ctx.material[::2]] == names
    kd, ks, n = (np.repeat([m[key] for m in table], 2) for key in ('kd', 'ks', 'n'))
    expected = paper_power_w(range_m, np.arccos(10.0 / range_m), kd, ks, n, default_scenario.sensor.optics)
    np.testing.assert_allclose(pred.ctx.power_w, expected, rtol=2 * EMBREE_RTOL, atol=0)
    # and its own range bias and noise (Table 2 rows); sigma goes through a variance and
    # back (float64: a few ulps)
    for key, got in (('bias_m', pred.bias_m), ('sigma_m', pred.sigma_m)):
        np.testing.assert_allclose(got, np.repeat([m[key] for m in table], 2),
                                   rtol=4 * np.finfo(float).eps, atol=0, err_msg=key)


@pytest.mark.parametrize('yaw_deg', [0.0, 35.0])
def test_back_face_returns_like_the_front_face(yaw_deg):
    """Surfaces are two-sided: a ray meeting a plate from behind sees the same range,
    incidence (the geometric angle, < 90 deg) and power as from the front."""
    s = grid_sensor()
    front = Rotation.from_euler('z', yaw_deg, degrees=True) * FACING
    back = front * Rotation.from_euler('x', 180, degrees=True)    # same square, normal turned away
    normal = front.apply([0.0, 0, 1])                               # toward the sensor
    assert normal[0] < 0 and back.apply([0.0, 0, 1])[0] > 0
    az = np.radians([-20.0, -5.0, 0.0, 10.0, 25.0])
    dirs = directions_from_angles(az, np.zeros_like(az))
    plate = (8.0, 0.0, 0.0)
    range_m = (normal @ plate) / (dirs @ normal)                    # ray-plane intersection
    cos_i = -(dirs @ normal)
    mat = materials(kd=0.3, ks=0.5, n=8.0)
    for rot in (front, back):
        pred = Simulator(s, mat, plate_target(12.0)).predict(np.zeros(len(az)), dirs,
                                                             StaticPose(plate, tuple(rot.as_quat())))
        assert pred.ctx.hit.all()
        np.testing.assert_allclose(pred.ctx.range_m, range_m, rtol=EMBREE_RTOL, atol=0)
        np.testing.assert_allclose(np.cos(pred.ctx.incidence_rad), cos_i, rtol=1e-12)  # float64 normals
        assert np.all(pred.ctx.incidence_rad < np.pi / 2)
        np.testing.assert_allclose(pred.hits.normal, np.tile(normal, (len(az), 1)), atol=1e-12)
        np.testing.assert_allclose(pred.ctx.power_w,
                                   paper_power_w(range_m, np.arccos(cos_i), 0.3, 0.5, 8.0, s.optics),
                                   rtol=2 * EMBREE_RTOL, atol=0)


def test_saturation_and_threshold_dropouts_in_a_frame():
    """A specular plate facing the sensor saturates near the normal and is too weak far
    off it; only the band in between is reported (paper Sec. 7)."""
    s = grid_sensor()
    mats = materials(kd=0.0, ks=1.0, n=50.0)
    plate = StaticPose((8.0, 0, 0), tuple(FACING.as_quat()))
    probe = Simulator(s, mats, plate_target(6.0)).simulate_frame(0.0, plate)
    p = probe.truth_intensity * s.detection.saturation_power_w
    sat, thr = np.quantile(p, 0.9), np.quantile(p, 0.3)
    s2 = grid_sensor(threshold_power_w=float(thr), saturation_power_w=float(sat))
    frame = Simulator(s2, mats, plate_target(6.0)).simulate_frame(0.0, plate)
    expected = int(((p >= thr) & (p < sat)).sum())
    assert len(frame) == expected
    assert frame.stats['saturated'] == int((p >= sat).sum()) > 0
    assert frame.stats['below_threshold'] == int((p < thr).sum()) > 0


def test_per_material_bias_and_sigma_recovered():
    s = grid_sensor()
    sim = Simulator(s, materials(bias_m=-0.1349, sigma_m=0.03075), plate_target(6.0), seed=5)
    plate = StaticPose((8.0, 0, 0), tuple(FACING.as_quat()))
    errs = []
    for k in range(20):
        f = sim.simulate_frame(k * 0.1, plate, frame_index=k)
        truth = f.xyz_m / f.range_m[:, None] * (8.0 / (f.xyz_m[:, 0] / f.range_m))[:, None]
        errs.append(f.range_m - np.linalg.norm(truth, axis=1))
    e = np.concatenate(errs)
    n = len(e)
    assert n > 20000
    assert e.mean() == pytest.approx(-0.1349, abs=5 * 0.03075 / np.sqrt(n))
    assert e.std() == pytest.approx(0.03075, rel=5 / np.sqrt(2 * n))


def test_reproducible_from_seed_and_frame_index(default_scenario):
    sim = Simulator.from_scenario(default_scenario)
    traj = ScenarioTrajectory.from_config(default_scenario.config)
    a = sim.simulate_frame(0.3, traj)
    b = sim.simulate_frame(0.3, traj)
    c = sim.simulate_frame(0.4, traj)
    assert np.array_equal(a.range_m, b.range_m)
    assert a.index == 3 and c.index == 4
    assert not np.array_equal(a.range_m[:100], c.range_m[:100])
    # Same pose and start time, another frame index: the same truth, other noise (a
    # generator that ignored the index passed the check above, whose frames differ in pose).
    static = StaticPose(default_scenario.config.initial_pose.position_m,
                        default_scenario.config.initial_pose.quat_xyzw)
    d, e = sim.simulate_frame(0.3, static, 3), sim.simulate_frame(0.3, static, 4)
    assert np.array_equal(d.truth_xyz_m, e.truth_xyz_m)
    assert not np.array_equal(d.range_m, e.range_m)
    # all seven materials are seen from the default pose? at least foam, MLI and a metal
    names = default_scenario.materials.names
    seen = {names[m] for m in np.unique(a.material)}
    assert {'PIF', 'MLI'} <= seen and seen & {'PSS', 'PAF', 'ADAPTER', 'NOZZLE', 'BULKHEAD'}


def test_default_scenario_frame_is_sensible(default_scenario):
    sim = Simulator.from_scenario(default_scenario)
    frame = sim.simulate_frame(0.0, ScenarioTrajectory.from_config(default_scenario.config))
    assert frame.stats['shots'] == 21120
    assert 5000 < len(frame) <= frame.stats['hits']
    assert 6.0 < frame.range_m.min() and frame.range_m.max() < 14.0
    assert np.all((frame.intensity > 0) & (frame.intensity < 1))
    assert np.all(frame.t_s < 0.1)


def test_points_come_out_in_firing_order_and_truth_matches(default_scenario):
    # Shots are simulated in a coherent angular order; published points go back to
    # the order the lasers fired, and the lazy truth to the same order.
    sim = Simulator.from_scenario(default_scenario)
    frame = sim.simulate_frame(0.0, ScenarioTrajectory.from_config(default_scenario.config))
    assert not np.all(np.diff(sim._cast_shots.t_s) >= 0)  # the cast order really differs
    fired = np.searchsorted(sim.shots.t_s, frame.t_s)  # firing index of each point
    assert np.all(np.diff(fired) > 0)
    np.testing.assert_array_equal(frame.ring, sim.shots.laser[fired])
    np.testing.assert_allclose(frame.xyz_m / frame.range_m[:, None], sim.directions[fired], atol=1e-12)
    truth_fired = np.searchsorted(sim.shots.t_s, frame.truth_t_s)
    assert len(truth_fired) == frame.stats['hits'] and np.all(np.diff(truth_fired) > 0)
    assert set(fired) <= set(truth_fired)
    # Each detected point is its truth point plus range error only.
    at = np.searchsorted(truth_fired, fired)
    np.testing.assert_array_equal(frame.material, frame.truth_material[at])
    np.testing.assert_allclose(frame.intensity, frame.truth_intensity[at])
    assert np.abs(frame.range_m - frame.truth_range_m[at]).max() < 0.5


@pytest.mark.parametrize('scenario_name', ['scenario.yaml', 'scenario_flash.yaml',
                                           'scenario_flash_all_effects.yaml'])
def test_frames_are_the_same_for_any_thread_count(scenario_name):
    """The raycast, the reflection and the measurement run in parts of the frame, one per
    thread, and the range noise is drawn as the parts end: every array of the frame,
    its truth and its statistics are the same to the bit on 1, 2 and 3 threads."""
    from lidar_sim_ros.core.scenario import load_scenario
    scenario = load_scenario(CONFIG / scenario_name)
    traj = ScenarioTrajectory.from_config(scenario.config)
    target = load_target(scenario.mesh_path, scenario.materials.names)
    frames = [Simulator.from_scenario(scenario, threads=n, target=target).simulate_frame(0.3, traj, 3)
              for n in (1, 2, 3)]
    assert len(frames[0]) > 5000
    for frame in frames[1:]:
        for key in ('xyz_m', 'range_m', 'intensity', 'material', 't_s', 'ring', 'face',
                    'true_range_m', 'return_number', 'truth_range_m', 'truth_intensity',
                    'truth_face'):
            np.testing.assert_array_equal(getattr(frame, key), getattr(frames[0], key), err_msg=key)
        np.testing.assert_array_equal(frame.truth_source.measured_range_m,
                                      frames[0].truth_source.measured_range_m)
        assert frame.stats == frames[0].stats


@pytest.mark.parametrize('scenario_name', ['scenario.yaml', 'scenario_flash.yaml',
                                           'scenario_mid40.yaml'])
@pytest.mark.parametrize('threads', [1, 2])
def test_a_plain_frame_on_its_hits_alone_is_the_frame_of_every_shot(scenario_name, threads):
    """A frame with no effect runs on its hits' rows alone (``Simulator._plain_frame``);
    with an effect that changes nothing the frame goes through every shot's row
    (``predict``, ``ReturnContext``): the two frames, their truth, every shot's measured
    range and the statistics are the same to the bit."""
    from lidar_sim_ros.core.effects import Effect
    from lidar_sim_ros.core.scenario import load_scenario

    class Nothing(Effect):
        name = 'nothing'
    scenario = load_scenario(CONFIG / scenario_name)
    traj = ScenarioTrajectory.from_config(scenario.config)
    target = load_target(scenario.mesh_path, scenario.materials.names)
    plain = Simulator.from_scenario(scenario, effects=[], threads=threads, target=target)
    every = Simulator.from_scenario(scenario, effects=[Nothing()], threads=threads, target=target)
    for index in (0, 4):
        start = index * plain.frame_period_s
        a, b = plain.simulate_frame(start, traj, index), every.simulate_frame(start, traj, index)
        assert type(a.truth_source).__name__ == '_FrameHits'
        assert type(b.truth_source).__name__ == '_FrameShots'
        assert len(a) > 1000 and a.stats == b.stats
        for key in ('xyz_m', 'range_m', 'intensity', 'material', 't_s', 'ring', 'face',
                    'true_range_m', 'return_number', 'truth_range_m', 'truth_xyz_m',
                    'truth_intensity', 'truth_t_s', 'truth_ring', 'truth_material', 'truth_face'):
            x, y = getattr(a, key), getattr(b, key)
            assert x.dtype == y.dtype, key
            np.testing.assert_array_equal(x, y, err_msg=key)
        for key in ('hit', 'range_m', 'intensity', 'material', 'face', 'measured_range_m',
                    'hit_index'):
            x, y = getattr(a.truth_source, key), getattr(b.truth_source, key)
            assert x.dtype == y.dtype, key
            np.testing.assert_array_equal(x, y, err_msg=key)


def test_range_noise_is_one_draw_per_hit_in_cast_order_whatever_order_the_parts_end():
    """The frame's first draw is one standard normal per hit, in cast order; the parts of
    a raycast end in any order on any thread, and each part's noise is drawn once the
    parts before it have theirs: the numbers are those of one draw after the cast."""
    from lidar_sim_ros.core.pipeline import _NoiseInOrder
    n = 10_000
    rng = np.random.default_rng(5)
    hit = rng.random(n) < 0.3
    bounds = np.unique(np.concatenate([[0], rng.integers(0, n, 9), [n]]))
    parts = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
    expected = np.random.default_rng([7, 3]).standard_normal(np.count_nonzero(hit))
    for ending in (range(len(parts)), reversed(range(len(parts))), rng.permutation(len(parts))):
        noise = _NoiseInOrder(np.random.default_rng([7, 3]), n)
        for k in ending:
            noise.part_done(parts[k], parts[k].start + np.flatnonzero(hit[parts[k]]))
        rows, draws = noise.drawn()
        np.testing.assert_array_equal(rows, np.flatnonzero(hit))
        np.testing.assert_array_equal(draws, expected)
    unfinished = _NoiseInOrder(np.random.default_rng(1), n)
    unfinished.part_done(parts[-1], np.zeros(0, np.int64))
    with pytest.raises(RuntimeError, match='drawn for 0 of 10000'):
        unfinished.drawn()
