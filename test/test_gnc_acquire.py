"""gnc/acquire.py: the first pose from the cloud alone.

The rocket body's clouds come from the core Simulator at fixed poses (StaticPose), one
frame each; the box's from the closed form of test_gnc_tracker. Errors are read modulo
what the body does not show: roll about the rocket's long axis, the box's two-fold turns.
"""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip('small_gicp')

from lidar_sim_ros.core.scenario import load_scenario  # noqa: E402
from lidar_sim_ros.core.pipeline import Simulator  # noqa: E402
from lidar_sim_ros.core.pose import StaticPose  # noqa: E402
from lidar_sim_ros.gnc.acquire import (AcquisitionConfig, acquire, candidate_directions,  # noqa: E402
                                       coverage, primary_axis)
from lidar_sim_ros.gnc.tracker import PoseTracker, TargetModel, build_model, pose_matrix  # noqa: E402
from lidar_sim_ros.paths import config_path  # noqa: E402
from test_gnc_tracker import CONFIG, TRUE, box_mesh, box_scan, errors  # noqa: E402

BOX_ACQUISITION = AcquisitionConfig(voxel_m=0.08, model_voxel_m=0.05, axial_step_m=0.3,
                                    coarse_gates_m=[0.4, 0.15], roll_hypotheses=4)
BOX_TURNS = [np.diag([*d, 1.0]) for d in ([1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1])]


def attitude(axis_lidar, roll_deg):
    """The rotation taking the body's long axis (+Z) to ``axis_lidar``, then rolled about it."""
    a = np.asarray(axis_lidar, float) / np.linalg.norm(axis_lidar)
    align, _ = Rotation.align_vectors([a], [[0.0, 0.0, 1.0]])
    return Rotation.from_rotvec(np.radians(roll_deg) * a) * align


@pytest.fixture(scope='module')
def rocket():
    sim = Simulator.from_scenario(load_scenario(config_path('scenario.yaml')))
    return sim, build_model(sim.target.vertices_m, sim.target.faces)


@pytest.fixture(scope='module')
def box_model():
    return build_model(*box_mesh(), CONFIG)


def axis_error_deg(T, rotation):
    est = T[:3, :3] @ [0.0, 0.0, 1.0]
    return np.degrees(np.arccos(np.clip(est @ rotation.apply([0.0, 0.0, 1.0]), -1, 1)))


# At 5 m the 10 m body overflows the 60 x 22 deg field of view: the poses there show an
# end (an oblique view); a patch of the bare tank alone fits end for end and anywhere
# along the tank (docs/gnc.md, bench-gnc counts those apart).
CASES = [(5.0, (-1.0, 1.0, 0.0), 30.0), (8.0, (0.2, 1.0, 0.0), 0.0), (20.0, (1.0, 0.5, 0.5), 10.0),
         (30.0, (-0.9, 0.3, -0.3), 250.0)]


@pytest.mark.parametrize('range_m, axis, roll_deg', CASES)
def test_the_rocket_body_is_acquired_from_one_frame(rocket, range_m, axis, roll_deg):
    sim, model = rocket
    rotation = attitude(axis, roll_deg)
    position = np.array([range_m, 0.0, 0.0])
    frame = sim.simulate_frame(0.0, StaticPose(tuple(position), tuple(rotation.as_quat())), 0)
    acq = acquire(model, frame.truth_xyz_m)
    assert acq.success and acq.hypotheses > 8
    assert np.linalg.norm(acq.pose[:3, 3] - position) < 0.05
    assert axis_error_deg(acq.pose, rotation) < 2.0  # not end for end
    # Roll is what the body of revolution hides: another roll fits as well.
    assert acq.roll_ambiguous
    assert acq.fit > 0.98 and acq.coverage > 0.7
    assert acq.estimate.acceptable(CONFIG.model_copy(update={'min_points': 30}))


def test_the_full_error_model_cloud_is_acquired_within_its_bias(rocket):
    """The model cloud's ranges are 11-14 cm short: the pose sits that much nearer."""
    sim, model = rocket
    rotation = attitude((1.0, 0.5, 0.5), 10.0)
    position = np.array([20.0, 0.0, 0.0])
    frame = sim.simulate_frame(0.0, StaticPose(tuple(position), tuple(rotation.as_quat())), 0)
    acq = acquire(model, frame.xyz_m)
    assert acq.success
    shift = acq.pose[:3, 3] - position
    assert -0.16 < shift[0] < -0.05 and np.linalg.norm(shift[1:]) < 0.05
    assert axis_error_deg(acq.pose, rotation) < 2.0


def test_the_box_is_acquired_modulo_its_turns(box_model):
    acq = acquire(box_model, box_scan(TRUE), BOX_ACQUISITION, CONFIG)
    dt, dr = min(errors(acq.pose @ turn, TRUE) for turn in BOX_TURNS)
    assert acq.success and dt < 2e-3 and dr < 0.1
    assert acq.coverage > 0.9 and acq.fit > 0.99


def test_too_few_points_fail_cleanly(box_model):
    acq = acquire(box_model, np.array([[5.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]), BOX_ACQUISITION, CONFIG)
    assert not acq.success and acq.hypotheses == 0 and not acq.estimate.acceptable(CONFIG)


def test_the_normals_find_the_axis_of_a_cropped_cylinder():
    """A slanted band of a 2 m cylinder (a field of view's window across it at an angle):
    the points spread along the slant, so none of their principal axes is the cylinder's;
    the normals, all perpendicular to the axis, give it exactly."""
    phi, dz = np.meshgrid(np.linspace(-0.75, 0.75, 60), np.linspace(-0.3, 0.3, 12))
    z = 1.5 * phi.ravel() + dz.ravel()
    axis = np.array([0.0, 0.6, 0.8])
    across = np.array([1.0, 0.0, 0.0])
    third = np.cross(axis, across)
    normals = np.cos(phi.ravel())[:, None] * across + np.sin(phi.ravel())[:, None] * third
    points = 2.0 * normals + z[:, None] * axis
    directions = candidate_directions(points, normals, 10.0)
    assert np.abs(directions @ axis).max() > 1 - 1e-9
    assert any(np.allclose(d, -e) for d in directions for e in directions)  # both ends tried
    points_only = candidate_directions(points, np.zeros_like(points), 10.0)  # the normals say nothing
    assert np.abs(points_only @ axis).max() < np.cos(np.radians(10.0))


def test_primary_axis_of_the_rocket_body_is_its_long_axis(rocket):
    assert abs(primary_axis(rocket[1].points_m)[2]) > 0.999


def test_coverage_counts_cells_with_a_return_not_behind_the_surface():
    """A 2 m square plate facing the sensor at 10 m; returns on its left half only, then
    on the right half but 1 m behind it (rays that went through where the plate is)."""
    y, z = np.meshgrid(np.linspace(-1, 1, 201), np.linspace(-1, 1, 201))
    plate = np.column_stack([np.zeros(y.size), y.ravel(), z.ravel()])
    model = TargetModel(plate, np.tile([1.0, 0.0, 0.0], (len(plate), 1)), None, None)
    pose = pose_matrix([10.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    left = plate[plate[:, 1] > 0.05] + [10.0, 0.0, 0.0]
    config = AcquisitionConfig(cell_deg=0.5)
    assert coverage(model, left, pose, config) == pytest.approx(0.5, abs=0.06)
    behind = plate[plate[:, 1] < -0.05] + [11.0, 0.0, 0.0]
    assert coverage(model, np.vstack([left, behind]), pose, config) == pytest.approx(0.5, abs=0.06)
    assert coverage(model, np.vstack([left, behind - [1.0, 0.0, 0.0]]), pose, config) > 0.95
    # Out of the field of view the plate predicts nothing to see.
    far_left = pose_matrix([10.0, 10.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    assert coverage(model, left, far_left, config) == 0.0


def test_the_tracker_acquires_without_a_guess_and_again_after_a_loss(box_model):
    tracker = PoseTracker(box_model, CONFIG, BOX_ACQUISITION)
    est = tracker.update(0.0, box_scan(TRUE))
    assert tracker.tracking and tracker.last_acquisition is not None and tracker.last_acquisition.success
    assert min(errors(est.pose @ turn, TRUE)[0] for turn in BOX_TURNS) < 2e-3
    est = tracker.update(0.1, box_scan(TRUE))
    assert tracker.last_acquisition is None  # tracking, no acquisition
    moved = TRUE.copy()
    moved[:3, 3] += [1.0, 1.5, 0.0]
    est = tracker.update(0.2, box_scan(moved))  # far beyond the tracking gate: lost
    assert not est.acceptable(CONFIG) and not tracker.tracking
    est = tracker.update(0.3, box_scan(moved))  # no guess: acquired where the box now is
    assert tracker.tracking and tracker.last_acquisition is not None
    assert min(errors(est.pose @ turn, moved)[0] for turn in BOX_TURNS) < 2e-3


def test_a_failed_acquisition_is_not_a_track(box_model):
    tracker = PoseTracker(box_model, CONFIG, BOX_ACQUISITION.model_copy(update={'min_fit': 1.0}))
    rng = np.random.default_rng(3)
    scan = box_scan(TRUE)
    est = tracker.update(0.0, scan + rng.normal(0.0, 0.02, size=scan.shape))  # a fit below 1
    assert tracker.last_acquisition is not None and not tracker.last_acquisition.success
    assert est.rejected and not est.acceptable(CONFIG) and not tracker.tracking


def bar_scan(half, T, step_m=0.05):
    """Grid points (lidar frame) on the faces of a box of half extents ``half`` that face
    the sensor at the origin (a convex body hides its back faces)."""
    points = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        uu, vv = np.meshgrid(np.arange(-half[u] + step_m / 2, half[u], step_m),
                             np.arange(-half[v] + step_m / 2, half[v], step_m))
        for sign in (-1.0, 1.0):
            p = np.zeros((uu.size, 3))
            p[:, axis], p[:, u], p[:, v] = sign * half[axis], uu.ravel(), vv.ravel()
            p = p @ T[:3, :3].T + T[:3, 3]
            if (T[:3, :3][:, axis] * sign) @ (-p.mean(axis=0)) > 0:
                points.append(p)
    return np.vstack(points)


def test_coverage_places_a_bar_cut_by_the_edge_of_the_field_of_view():
    """A 4 m bar across the line of sight at 8 m, its centre on the 30 deg edge of the
    field of view: the cloud is its inner half. The fit alone takes any place where that
    half lies on the bar (it may slide up to 2 m inward); the coverage keeps the unseen
    half out of view, which leaves the true place (the bar's turns aside: its centre)."""
    half = np.array([0.3, 0.3, 2.0])
    import trimesh
    bar = trimesh.creation.box(extents=2 * half)
    model = build_model(np.asarray(bar.vertices), np.asarray(bar.faces), CONFIG)
    yaw = np.radians(30.0)
    # Long axis (+Z) along the horizontal direction across the line of sight at 30 deg.
    R = Rotation.from_rotvec([0.0, 0.0, yaw]) * Rotation.from_rotvec([-np.pi / 2, 0.0, 0.0])
    truth = pose_matrix([8 * np.cos(yaw), 8 * np.sin(yaw), 0.0], R.as_quat())
    scan = bar_scan(half, truth)
    seen = scan[np.arctan2(scan[:, 1], scan[:, 0]) <= yaw]
    acq = acquire(model, seen, BOX_ACQUISITION, CONFIG)
    # Along the bar, the place is known to the coverage's cells (0.75 deg: 0.1 m at 8 m).
    assert acq.success and np.linalg.norm(acq.pose[:3, 3] - truth[:3, 3]) < 0.1
    assert acq.coverage > 0.85 and acq.fit > 0.99


def test_far_false_returns_do_not_stop_the_acquisition(rocket):
    """A fifth of the points are false returns spread over 1-250 m (a solar background or a
    range gate's triggers): the crop about the cloud's median drops them, and the target is
    acquired as from its own points (without it: no acceptable fit, and 10-30 s)."""
    sim, model = rocket
    rotation = attitude((1.0, 0.5, 0.5), 10.0)
    position = np.array([20.0, 0.0, 0.0])
    frame = sim.simulate_frame(0.0, StaticPose(tuple(position), tuple(rotation.as_quat())), 0)
    rng = np.random.default_rng(7)
    n = len(frame.truth_xyz_m) // 4
    az, el = rng.uniform(-0.5, 0.5, n), rng.uniform(-0.19, 0.19, n)
    dirs = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    cloud = np.vstack([frame.truth_xyz_m, dirs * rng.uniform(1.0, 250.0, n)[:, None]])
    acq = acquire(model, cloud)
    assert acq.success
    assert np.linalg.norm(acq.pose[:3, 3] - position) < 0.05
    assert axis_error_deg(acq.pose, rotation) < 2.0


def test_a_random_cloud_fails_at_a_bound_before_any_icp(rocket):
    """A 1 MB cloud of random points (62,500, a 40 m box 30 m out) is no target: before the
    bound it took 136 s of ICP over 346 hypotheses; now it fails at the coarse-point bound."""
    _, model = rocket
    xyz = np.random.default_rng(0).uniform(-20, 20, (62_500, 3)) + [30.0, 0.0, 0.0]
    acq = acquire(model, xyz)
    assert not acq.success and acq.hypotheses == 0 and 'max_coarse_points' in acq.reason
    assert acq.seconds < 10.0
    # The hypothesis bound, alone: the same cloud with the coarse bound lifted.
    acq = acquire(model, xyz, AcquisitionConfig(max_coarse_points=100_000, max_hypotheses=50))
    assert not acq.success and 'max_hypotheses' in acq.reason and acq.seconds < 10.0
