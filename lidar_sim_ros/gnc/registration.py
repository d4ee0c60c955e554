"""Model-based registration: the target model, the settings and one robust
point-to-plane alignment of a cloud to it (``register``); poses as 4 x 4 matrices.

The mesh is sampled once into model points in the body frame, with normals and a k-d
tree (``build_model``). ``register`` aligns the cloud (lidar frame) to the model from an
initial guess and returns the target body pose in the lidar frame as a 4 x 4 matrix,
``p_lidar = R p_body + t`` (the convention of ``/target/pose``).

The registration is small_gicp's point-to-plane ICP. Its robust kernel is the
truncated quadratic: a point whose nearest model point lies farther than the gate gets
zero weight, so spurious returns and unmodelled structure cannot pull the estimate.
The gates are annealed: a wide one captures from a rough guess, a tight one then
ignores what is not on the target.

Both the acquisition (``gnc.acquire``) and the tracker (``gnc.tracker``) build on this
module; it imports neither (the import graph: registration <- acquire <- tracker).
Pure numpy in and out; small_gicp objects stay inside ``TargetModel``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
import small_gicp
import trimesh
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation


class TrackerConfig(BaseModel):
    """Registration settings (metres, counts). Defaults suit the 4 m x 10 m rocket body at 10 m."""

    model_config = ConfigDict(extra='forbid', frozen=True)

    model_spacing_m: Annotated[float, Field(gt=0)] = Field(
        0.07, description='spacing of the model points sampled on the mesh (m); point-to-plane ICP '
        'needs only the surface\'s planes, and a smaller model keeps the k-d tree in cache (5 cm: '
        '113k points for the rocket body and twice the time per iteration of 7 cm, for the same estimate)')
    normal_neighbors: Annotated[int, Field(ge=5)] = Field(
        10, description='model points per normal estimate')
    scan_voxel_m: Annotated[float, Field(ge=0)] = Field(
        0.15, description='voxel grid applied to each cloud before registration (m); 0 = all points')
    capture_gates_m: list[Annotated[float, Field(gt=0)]] = Field(
        [1.0, 0.3], min_length=1,
        description='correspondence gates (m) used in turn when capturing from a guess, wide to tight')
    tracking_gate_m: Annotated[float, Field(gt=0)] = Field(
        0.3, description='correspondence gate (m) while tracking from the prediction')
    prediction: Literal['translation', 'constant_velocity', 'previous_pose'] = Field(
        'translation', description='where tracking starts each frame: the last pose with its '
        'position extrapolated from the last two (translation), the whole pose extrapolated '
        '(constant_velocity), or the last pose')
    max_iterations: Annotated[int, Field(ge=1)] = Field(
        10, description='ICP iterations per gate (more only slide further along a weakly observed roll)')
    converged_translation_m: Annotated[float, Field(gt=0)] = Field(
        0.001, description='ICP stops once an iteration moves the body centre less than this (m) and '
        'turns the body less than converged_rotation_deg (small_gicp\'s translation_epsilon)')
    converged_rotation_deg: Annotated[float, Field(gt=0)] = Field(
        0.1, description='ICP stops once an iteration turns the body less than this (deg) and moves '
        'its centre less than converged_translation_m (small_gicp\'s rotation_epsilon)')
    min_points: Annotated[int, Field(ge=6)] = Field(
        30, description='fewest cloud points (after the voxel grid) for an estimate')
    min_inlier_fraction: Annotated[float, Field(ge=0, le=1)] = Field(
        0.5, description='share of the cloud points within the gate for the estimate to count')
    num_threads: Annotated[int, Field(ge=1)] = 1
    seed: int = Field(0, description='seed of the model surface sampling')


# ------------------------------------------------------------------ poses
def pose_matrix(position_m: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """4 x 4 homogeneous transform from a position (m) and an xyzw unit quaternion."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.asarray(quat_xyzw, dtype=float)).as_matrix()
    T[:3, 3] = np.asarray(position_m, dtype=float)
    return T


def pose_parts(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,) m, xyzw quaternion (4,) with w >= 0) of a 4 x 4 transform."""
    quat = Rotation.from_matrix(T[:3, :3]).as_quat()
    return T[:3, 3].copy(), quat if quat[3] >= 0 else -quat


def predict_position(p_prev_m: np.ndarray, t_prev_s: float, p_last_m: np.ndarray, t_last_s: float,
                     t_next_s: float) -> np.ndarray:
    """Carry the position (m) from p_prev_m (at t_prev_s) to p_last_m on to t_next_s at the same velocity."""
    dt = t_last_s - t_prev_s
    if dt <= 0:
        return np.array(p_last_m, dtype=float)
    return p_last_m + (t_next_s - t_last_s) / dt * (p_last_m - p_prev_m)


def predict_constant_velocity(T_prev: np.ndarray, t_prev_s: float, T_last: np.ndarray,
                              t_last_s: float, t_next_s: float) -> np.ndarray:
    """Carry the motion from T_prev (at t_prev_s) to T_last on to t_next_s.

    Position moves linearly and the rotation keeps turning about the same lidar-frame
    axis at the same rate: exact for a target drifting at constant velocity while
    tumbling about a fixed axis (the scenario's motion model).
    """
    dt = t_last_s - t_prev_s
    if dt <= 0:
        return T_last.copy()
    scale = (t_next_s - t_last_s) / dt
    R_prev, R_last = T_prev[:3, :3], T_last[:3, :3]
    turn = Rotation.from_matrix(R_last @ R_prev.T).as_rotvec()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(scale * turn).as_matrix() @ R_last
    T[:3, 3] = predict_position(T_prev[:3, 3], t_prev_s, T_last[:3, 3], t_last_s, t_next_s)
    return T


# ------------------------------------------------------------------ model
@dataclass(frozen=True)
class TargetModel:
    """Model points (N, 3) and unit normals (N, 3) in the body frame (m), ready for registration."""

    points_m: np.ndarray
    normals: np.ndarray
    cloud: Any  # small_gicp.PointCloud of points_m, normals estimated
    tree: Any   # small_gicp.KdTree over cloud

    def __len__(self) -> int:
        return len(self.points_m)


def build_model(vertices_m: np.ndarray, faces: np.ndarray,
                config: TrackerConfig = TrackerConfig()) -> TargetModel:
    """Sample the mesh surface evenly every ``model_spacing_m`` and estimate the normals there.

    small_gicp takes no given normals, so they come from the model points' neighbours
    (a plane fit over ``normal_neighbors`` points): the face normal on flat and gently
    curved surfaces, a blend within a spacing or two of sharp edges.
    """
    mesh = trimesh.Trimesh(np.asarray(vertices_m, dtype=float), np.asarray(faces, dtype=np.int64),
                           process=False)
    if len(mesh.faces) == 0 or mesh.area <= 0:
        raise ValueError('the target mesh has no surface to sample')
    spacing = config.model_spacing_m
    # Area-weighted random points, twice as many as a square grid of that spacing would
    # hold: every point lies exactly on the surface (a voxel grid's centroids would not).
    count = max(100, math.ceil(2.0 * mesh.area / spacing ** 2))
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=config.seed)
    cloud = small_gicp.PointCloud(np.asarray(points, dtype=float))
    tree = small_gicp.KdTree(cloud, num_threads=config.num_threads)
    small_gicp.estimate_normals(cloud, tree, num_neighbors=config.normal_neighbors,
                                num_threads=config.num_threads)
    return TargetModel(cloud.points()[:, :3].copy(), cloud.normals()[:, :3].copy(), cloud, tree)


# ------------------------------------------------------------ registration
@dataclass(frozen=True)
class Estimate:
    """One registration: the body pose in the lidar frame and how well the cloud fitted.

    points: cloud points used (after the voxel grid); inliers: those within the last
    gate; iterations: ICP iterations over all gates.
    """

    pose: np.ndarray
    points: int
    inliers: int
    iterations: int
    converged: bool
    rejected: bool = False  # set when an acquisition's score refused the pose

    @property
    def inlier_fraction(self) -> float:
        return self.inliers / self.points if self.points else 0.0

    def acceptable(self, config: TrackerConfig) -> bool:
        """Whether enough of the cloud lies on the model for the pose to be trusted."""
        return (not self.rejected and self.points >= config.min_points
                and self.inlier_fraction >= config.min_inlier_fraction)


def register(model: TargetModel, xyz_m: np.ndarray, guess: np.ndarray, gates_m: list[float],
             config: TrackerConfig = TrackerConfig()) -> Estimate:
    """Align cloud points (N, 3) in the lidar frame to the model, from the pose ``guess`` (4 x 4).

    Runs point-to-plane ICP once per gate in ``gates_m`` (m), each from the last result.
    The cloud is registered about the guessed body centre (its points less the guess's
    position): small_gicp turns each update about the cloud's origin, so from the lidar
    origin a turn of 0.01 deg moves a target 30 m out by 5 mm, and its convergence test
    (``converged_*``) saw that lever arm, not how far the target moved.
    """
    guess = np.asarray(guess, dtype=float)
    xyz = np.asarray(xyz_m, dtype=float).reshape(-1, 3)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    centre = guess[:3, 3]
    source = small_gicp.PointCloud(xyz - centre)
    if config.scan_voxel_m > 0 and len(xyz):
        source = small_gicp.voxelgrid_sampling(source, config.scan_voxel_m, config.num_threads)
    n = source.size()
    if n < config.min_points:
        return Estimate(guess.copy(), n, 0, 0, False)
    # small_gicp solves for T_target_source: the model (body) frame from the centred cloud frame,
    # p_body = T (p_lidar - centre).
    T_body_source = np.linalg.inv(guess)
    T_body_source[:3, 3] += T_body_source[:3, :3] @ centre
    iterations, result = 0, None
    for gate in gates_m:
        result = small_gicp.align(model.cloud, source, model.tree, init_T_target_source=T_body_source,
                                  registration_type='PLANE_ICP', max_correspondence_distance=gate,
                                  max_iterations=config.max_iterations, num_threads=config.num_threads,
                                  translation_epsilon=config.converged_translation_m,
                                  rotation_epsilon=math.radians(config.converged_rotation_deg))
        T_body_source = result.T_target_source
        iterations += result.iterations
    pose = np.linalg.inv(T_body_source)
    pose[:3, 3] += centre
    return Estimate(pose, n, int(result.num_inliers), iterations, bool(result.converged))
