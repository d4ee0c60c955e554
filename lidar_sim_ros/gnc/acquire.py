"""Acquisition: the first pose of the target from one cloud alone, no guess.

Principal axes give the hypotheses, ICP refines them, a score picks one:

1. **Directions.** The cloud (on a coarse voxel grid) gives candidate directions for
   the model's primary axis (the principal axis of the model points whose variance
   stands apart from the other two: the long axis of the rocket body): the three
   principal axes of the points and the three of the surface normals (a cylinder's
   normals are all perpendicular to its axis, so the normals find the axis even when
   the field of view crops the body to a patch). Both signs of each: the front/back
   ambiguity of the long axis is a hypothesis like any other.
2. **Roll** about that axis: ``roll_hypotheses`` angles evenly over the turn.
3. **Position.** The body centre is placed so that the model's surface seen from the
   sensor (an orthographic z-buffer of the model along the line of sight) has the
   cloud's centroid across the axis; along the axis, the cloud's extent is matched to
   the visible model's at both ends and at steps of ``axial_step_m`` between (a body
   larger than the field of view is seen as a patch whose place along it is unknown).
4. **Refinement.** Every hypothesis is aligned by point-to-plane ICP through the widest
   of ``coarse_gates_m`` (the ``coarse_keep`` best fits on through the others), on the
   coarse cloud and a coarse copy of the model (``model_voxel_m``: a wrong hypothesis
   puts points far from the surface, where a k-d tree query walks much of the tree, and
   a small tree keeps that cheap). The survivors are ranked by the score (below), and
   the best ``refine_best`` distinct ones are refined again on the tracker's model,
   cloud and capture gates (``tracker.register``).
5. **Score** (0-1, higher is better): the fit (one minus the mean truncated quadratic
   point-to-plane cost at ``score_gate_m``) times the coverage (the share of the
   angular cells where the pose puts visible model surface in the field of view that
   hold a return not farther than ``coverage_tolerance_m`` behind that surface). The
   fit alone cannot tell one patch of a cylinder from another, nor the body from its
   mirror image end for end; the coverage says where the rest of the body would have
   been seen, and was not.

Roll on a near body of revolution: hypotheses that differ only in roll fit almost
equally. The best one is taken (the tracker tracks from it), and ``roll_ambiguous``
says whether a hypothesis rolled from it scored within ``ambiguity_margin``. What the
cloud cannot show stays ambiguous: a patch of the tank cylinder at 5 m, with neither
end in view, fits as well end for end or shifted along the axis (``runner_up_score``
close to ``score`` says so).

Pure numpy in and out, like ``tracker.register``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Annotated

import numpy as np
import small_gicp
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.transform import Rotation

from lidar_sim_ros.gnc.registration import Estimate, TargetModel, TrackerConfig, register

Vec3 = tuple[float, float, float]


class AcquisitionConfig(BaseModel):
    """Acquisition settings (metres, degrees, counts). Defaults suit the rocket body at 5-30 m
    seen by the Cepton Vista P-60 (60 x 22 deg field of view)."""

    model_config = ConfigDict(extra='forbid', frozen=True)

    voxel_m: Annotated[float, Field(gt=0)] = Field(
        0.3, description='voxel grid of the cloud for the hypotheses and their coarse ICP (m)')
    model_voxel_m: Annotated[float, Field(gt=0)] = Field(
        0.2, description='voxel grid of the model copy the hypotheses are searched on (m)')
    normal_neighbors: Annotated[int, Field(ge=5)] = Field(
        10, description='cloud points per normal estimate (for the normals\' principal axes)')
    primary_axis_body: Vec3 | None = Field(
        None, description='the model axis the hypotheses align (body frame); None = the principal '
                          'axis of the model points whose variance stands apart from the other two')
    roll_hypotheses: Annotated[int, Field(ge=1)] = Field(
        4, description='roll angles about the primary axis tried per direction, evenly over 360 deg')
    axial_step_m: Annotated[float, Field(gt=0)] = Field(
        2.0, description='spacing of the positions tried along the axis when the cloud is shorter '
                         'than the visible model (m)')
    direction_merge_deg: Annotated[float, Field(gt=0, lt=90)] = Field(
        10.0, description='candidate directions closer than this are tried once (deg)')
    coarse_gates_m: list[Annotated[float, Field(gt=0)]] = Field(
        [1.5, 0.5], min_length=1, description='ICP gates of the coarse stage, wide to tight (m)')
    coarse_iterations: Annotated[int, Field(ge=1)] = Field(
        8, description='ICP iterations per gate in the coarse stage')
    coarse_keep: Annotated[int, Field(ge=1)] = Field(
        24, description='hypotheses (best fits after the widest gate) taken on through the other gates')
    refine_best: Annotated[int, Field(ge=1)] = Field(
        6, description='distinct coarse results refined on the tracker\'s cloud and gates')
    score_gate_m: Annotated[float, Field(gt=0)] = Field(
        0.3, description='truncation of the fit cost: farther points count as misses (m)')
    cell_deg: Annotated[float, Field(gt=0)] = Field(
        0.75, description='angular cell of the coverage check (deg); coarser than the scan lattice')
    coverage_tolerance_m: Annotated[float, Field(gt=0)] = Field(
        0.5, description='a return no farther than this behind the predicted surface covers its cell (m)')
    fov_az_deg: Annotated[float, Field(gt=0, le=360)] = Field(
        60.0, description='sensor field of view in azimuth (deg), centred on +x')
    fov_el_deg: Annotated[float, Field(gt=0, le=180)] = Field(
        22.0, description='sensor field of view in elevation (deg), centred on +x')
    min_fit: Annotated[float, Field(ge=0, le=1)] = Field(
        0.9, description='lowest fit of an accepted acquisition')
    min_coverage: Annotated[float, Field(ge=0, le=1)] = Field(
        0.5, description='lowest coverage of an accepted acquisition')
    ambiguity_margin: Annotated[float, Field(ge=0, le=1)] = Field(
        0.02, description='a hypothesis of another roll within this of the best score makes the roll '
                          'ambiguous')
    max_coarse_points: Annotated[int, Field(ge=10)] = Field(
        3000, description='more coarse (voxel_m) points than this about the median and the cloud is '
        'not a target (the rocket body fills ~450 voxels of 0.3 m at 5 m): the acquisition fails at '
        'once (a 1 MB random cloud took 136 s of ICP over 346 hypotheses)')
    max_hypotheses: Annotated[int, Field(ge=1)] = Field(
        400, description='more hypotheses than this and the acquisition fails at once (76-128 on the '
        "loop's clouds with every effect); bounds its time whatever the cloud")


@dataclass(frozen=True)
class Acquisition:
    """The result of ``acquire``.

    pose: 4 x 4 body -> lidar (``p_lidar = R p_body + t``); success: the fit, the coverage
    and the tracker's own test (``Estimate.acceptable``) pass; score (0-1) = fit x coverage
    of the best; estimate: its last registration (the tracker's cloud and gates);
    hypotheses: poses tried;
    seconds: wall time; roll_ambiguous: a hypothesis rolled > 10 deg about the primary
    axis from the best scored within the margin; runner_up_score: the best score of a
    refined hypothesis with the axis > 5 deg or the centre > 0.3 m away from the best's
    (end for end, or along the axis), nan if none: close to ``score``, the cloud does
    not tell them apart.
    """

    pose: np.ndarray
    success: bool
    score: float
    fit: float
    coverage: float
    estimate: Estimate
    hypotheses: int
    seconds: float
    roll_ambiguous: bool
    runner_up_score: float
    reason: str = ''   # why it failed before the ICP (a bound), '' otherwise


# ------------------------------------------------------------ the model's shape
def primary_axis(points_m: np.ndarray) -> np.ndarray:
    """The principal axis (unit, body frame) whose variance stands apart from the other two.

    For a body of revolution it is the symmetry axis (the two others are equal); for a
    long body, the long axis.
    """
    centred = points_m - points_m.mean(axis=0)
    values, vectors = np.linalg.eigh(centred.T @ centred / len(points_m))  # ascending
    gaps = [values[1] - values[0], values[2] - values[1]]
    return vectors[:, 0] if gaps[0] > gaps[1] else vectors[:, 2]


def visible_orthographic(points_m: np.ndarray, view_dir: np.ndarray, cell_m: float) -> np.ndarray:
    """Indices of the points seen looking along ``view_dir`` (unit): the nearest in each
    ``cell_m`` square of the plane across it (an orthographic z-buffer)."""
    u = view_dir / np.linalg.norm(view_dir)
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    cells = np.floor(np.column_stack([points_m @ e1, points_m @ e2]) / cell_m).astype(np.int64)
    key = (cells[:, 0] - cells[:, 0].min()) * (cells[:, 1].max() - cells[:, 1].min() + 1) + \
        (cells[:, 1] - cells[:, 1].min())
    order = np.lexsort((points_m @ u, key))  # by cell, nearest first
    first = np.ones(len(order), dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    return order[first]


# ------------------------------------------------------------- hypotheses
def candidate_directions(xyz_m: np.ndarray, normals: np.ndarray, merge_deg: float) -> np.ndarray:
    """Unit directions (K, 3) the primary axis may take in the lidar frame, both signs.

    The principal axes of the points (a long body's extent) and of the normals (the
    axis of a cylinder is the direction its normals avoid), merged within ``merge_deg``.
    """
    lines = []
    for data in (xyz_m - xyz_m.mean(axis=0), normals):
        _, vectors = np.linalg.eigh(data.T @ data)
        lines.extend(vectors.T)
    kept: list[np.ndarray] = []
    cos_merge = math.cos(math.radians(merge_deg))
    for line in lines:
        if all(abs(line @ k) < cos_merge for k in kept):
            kept.append(line)
    return np.array([s * k for k in kept for s in (1.0, -1.0)])


def hypotheses(model_points_m: np.ndarray, axis_body: np.ndarray, xyz_m: np.ndarray,
               directions: np.ndarray, config: AcquisitionConfig) -> list[np.ndarray]:
    """Initial poses (4 x 4 body -> lidar): each direction x roll x position along the axis."""
    centroid = xyz_m.mean(axis=0)
    view = centroid / np.linalg.norm(centroid)  # line of sight to the cloud
    poses = []
    for direction in directions:
        align, _ = Rotation.align_vectors([direction], [axis_body])
        s_cloud = xyz_m @ direction
        for roll in np.arange(config.roll_hypotheses) * 2 * np.pi / config.roll_hypotheses:
            R = (Rotation.from_rotvec(roll * direction) * align).as_matrix()
            seen = model_points_m[visible_orthographic(model_points_m, R.T @ view, config.voxel_m)]
            seen_lidar = seen @ R.T  # the visible model, rotated, centred on the body origin
            # Across the axis: the visible model's centroid on the cloud's.
            across = centroid - seen_lidar.mean(axis=0)
            across -= (across @ direction) * direction
            s_model = seen_lidar @ direction
            low, high = s_cloud.min() - s_model.min(), s_cloud.max() - s_model.max()
            count = 1 + math.ceil(abs(high - low) / config.axial_step_m - 1e-9)
            for along in np.linspace(low, high, count) if count > 1 else [0.5 * (low + high)]:
                T = np.eye(4)
                T[:3, :3] = R
                T[:3, 3] = across + along * direction
                poses.append(T)
    return poses


# ------------------------------------------------------------------ score
def fit_score(model: TargetModel, xyz_m: np.ndarray, pose: np.ndarray, gate_m: float) -> float:
    """One minus the mean truncated quadratic point-to-plane cost (gate ``gate_m``) of the
    cloud at ``pose``: 1 for a perfect fit, 0 when no point is within the gate."""
    body = (xyz_m - pose[:3, 3]) @ pose[:3, :3]
    index, sq = model.tree.batch_nearest_neighbor_search(body)
    index, sq = np.asarray(index).ravel(), np.asarray(sq).ravel()
    plane = np.einsum('ij,ij->i', body - model.points_m[index], model.normals[index])
    # Within the gate the plane distance is at most the point distance, so below the gate.
    d2 = np.where(sq <= gate_m ** 2, plane ** 2, gate_m ** 2)
    return float(1.0 - np.mean(d2) / gate_m ** 2)


def _cells(xyz_m: np.ndarray, cell_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(azimuth, elevation (rad), range (m)) and the angular cell of each point."""
    r = np.linalg.norm(xyz_m, axis=1)
    az = np.arctan2(xyz_m[:, 1], xyz_m[:, 0])
    el = np.arcsin(np.clip(xyz_m[:, 2] / np.maximum(r, 1e-12), -1, 1))
    cell = np.floor(az / cell_rad).astype(np.int64) * 1_000_003 + np.floor(el / cell_rad).astype(np.int64)
    return np.column_stack([az, el]), r, cell


def coverage(model: TargetModel, xyz_m: np.ndarray, pose: np.ndarray, config: AcquisitionConfig) -> float:
    """Share of the angular cells where ``pose`` puts visible model surface in the field of
    view that hold a return not farther than ``coverage_tolerance_m`` behind that surface."""
    cell_rad = math.radians(config.cell_deg)
    model_lidar = model.points_m[::2] @ pose[:3, :3].T + pose[:3, 3]
    angles, r_model, cell_model = _cells(model_lidar, cell_rad)
    in_view = (np.abs(angles[:, 0]) <= math.radians(config.fov_az_deg) / 2) & \
        (np.abs(angles[:, 1]) <= math.radians(config.fov_el_deg) / 2)
    if not in_view.any():
        return 0.0
    cell_model, r_model = cell_model[in_view], r_model[in_view]
    # z-buffer: the nearest model range in each cell is what the sensor would see there.
    order = np.lexsort((r_model, cell_model))
    first = np.ones(len(order), dtype=bool)
    first[1:] = cell_model[order][1:] != cell_model[order][:-1]
    cells, r_seen = cell_model[order][first], r_model[order][first]
    _, r_cloud, cell_cloud = _cells(xyz_m, cell_rad)
    # A cell is covered when a return in it is not behind the surface (beyond the tolerance):
    # a ray that passed through the predicted surface contradicts it, a nearer return does
    # not (the cell's model sample may lie on a hidden far side where the model is sparse).
    where = np.searchsorted(cells, cell_cloud)
    where = np.minimum(where, len(cells) - 1)
    match = (cells[where] == cell_cloud) & (r_cloud <= r_seen[where] + config.coverage_tolerance_m)
    return float(len(np.unique(where[match])) / len(cells))


# ---------------------------------------------------------------- the search
def coarse_model(model: TargetModel, config: AcquisitionConfig) -> TargetModel:
    """The model on the ``model_voxel_m`` grid, with its own normals and k-d tree."""
    cloud = _voxel_cloud(model.points_m, config.model_voxel_m, config.normal_neighbors)
    return TargetModel(cloud.points()[:, :3].copy(), cloud.normals()[:, :3].copy(), cloud,
                       small_gicp.KdTree(cloud))


def _voxel_cloud(xyz_m: np.ndarray, voxel_m: float, neighbors: int):
    cloud = small_gicp.voxelgrid_sampling(small_gicp.PointCloud(xyz_m), voxel_m)
    if cloud.size() >= neighbors:
        tree = small_gicp.KdTree(cloud)
        small_gicp.estimate_normals(cloud, tree, num_neighbors=neighbors)
    return cloud


def _differs(a: np.ndarray, b: np.ndarray, distance_m: float = 0.3, angle_deg: float = 10.0) -> bool:
    angle = Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).magnitude()
    return bool(np.linalg.norm(a[:3, 3] - b[:3, 3]) > distance_m or math.degrees(angle) > angle_deg)


def target_crop(xyz_m: np.ndarray, model: TargetModel) -> np.ndarray:
    """The points (N, 3, m) within the target's diameter of the cloud's per-axis median.

    False returns (solar background, a range gate's triggers) spread over the whole
    range, the target's returns bunch: while the target gives most of the points the
    median lies on it, within its radius of its centre, so a ball of one diameter about
    the median keeps the whole target and drops the far triggers that would otherwise
    tilt the principal axes and multiply the hypotheses (10-30 s per acquisition, and
    none accepted, on clouds with every effect)."""
    if not len(xyz_m):
        return xyz_m
    centre = model.points_m.mean(axis=0)
    diameter = 2.0 * float(np.sqrt(np.max(np.sum((model.points_m - centre) ** 2, axis=1))))
    d = xyz_m - np.median(xyz_m, axis=0)
    return xyz_m[np.einsum('ij,ij->i', d, d) <= diameter * diameter]


def acquire(model: TargetModel, xyz_m: np.ndarray, config: AcquisitionConfig = AcquisitionConfig(),
            tracker: TrackerConfig = TrackerConfig()) -> Acquisition:
    """The target body pose in the lidar frame from cloud points (N, 3, lidar frame, m) alone.

    ``tracker`` supplies the final refinement (its voxel grid, capture gates and
    iterations) and the least number of points (``min_points``).
    """
    t0 = time.perf_counter()
    xyz = np.asarray(xyz_m, dtype=float).reshape(-1, 3)
    xyz = xyz[np.isfinite(xyz).all(axis=1) & (np.linalg.norm(xyz, axis=1) > 0)]
    xyz = target_crop(xyz, model)
    coarse = _voxel_cloud(xyz, config.voxel_m, config.normal_neighbors) if len(xyz) else None
    if coarse is None or coarse.size() < max(tracker.min_points // 4, config.normal_neighbors):
        failed = Estimate(np.eye(4), 0 if coarse is None else coarse.size(), 0, 0, False)
        return Acquisition(np.eye(4), False, 0.0, 0.0, 0.0, failed, 0, time.perf_counter() - t0, False, math.nan)
    if coarse.size() > config.max_coarse_points:
        return _refused(t0, coarse.size(), f'{coarse.size()} coarse points > max_coarse_points '
                                            f'{config.max_coarse_points}: not a target')
    coarse_xyz = coarse.points()[:, :3]
    axis_body = (np.asarray(config.primary_axis_body, dtype=float) if config.primary_axis_body is not None
                 else primary_axis(model.points_m))
    axis_body = axis_body / np.linalg.norm(axis_body)
    directions = candidate_directions(coarse_xyz, coarse.normals()[:, :3], config.direction_merge_deg)
    rough = coarse_model(model, config)
    starts = hypotheses(rough.points_m, axis_body, coarse_xyz, directions, config)
    if len(starts) > config.max_hypotheses:
        return _refused(t0, coarse.size(), f'{len(starts)} hypotheses > max_hypotheses {config.max_hypotheses}')
    candidates = coarse_stage(rough, coarse_xyz, xyz, starts, config, tracker)
    results = fine_stage(model, coarse_xyz, xyz, candidates, config, tracker)
    score, fit, cov, best = results[0]
    roll_ambiguous, runner_up = ambiguities(results, axis_body, config.ambiguity_margin)
    success = bool(best.acceptable(tracker) and fit >= config.min_fit and cov >= config.min_coverage)
    return Acquisition(best.pose, success, score, fit, cov, best, len(starts), time.perf_counter() - t0,
                       roll_ambiguous, runner_up)


def _refused(t0: float, points: int, reason: str) -> Acquisition:
    """A failed acquisition that stopped at a bound before any ICP."""
    failed = Estimate(np.eye(4), points, 0, 0, False)
    return Acquisition(np.eye(4), False, 0.0, 0.0, 0.0, failed, 0, time.perf_counter() - t0, False,
                       math.nan, reason)


def coarse_stage(rough: TargetModel, coarse_xyz: np.ndarray, xyz_m: np.ndarray, starts: list[np.ndarray],
                 config: AcquisitionConfig, tracker: TrackerConfig) -> list[np.ndarray]:
    """ICP of every start on the coarse cloud and model through the widest gate, of the
    ``coarse_keep`` best fits through the others; the ``refine_best`` distinct best by score."""
    icp = tracker.model_copy(update={'scan_voxel_m': 0.0, 'max_iterations': config.coarse_iterations,
                                     'min_points': 6})
    poses = starts
    for gate in config.coarse_gates_m:
        poses = [register(rough, coarse_xyz, T, [gate], icp).pose for T in poses]
        fits = [fit_score(rough, coarse_xyz, T, config.score_gate_m) for T in poses]
        poses = [poses[i] for i in np.argsort(fits, kind='stable')[::-1][:config.coarse_keep]]
    # Ranked by the whole score: among equal fits (a patch that may slide along the body)
    # the coverage prefers the places that hide nothing the sensor saw through.
    scores = [fit_score(rough, coarse_xyz, T, config.score_gate_m) * coverage(rough, xyz_m, T, config)
              for T in poses]
    distinct: list[np.ndarray] = []
    for i in np.argsort(scores, kind='stable')[::-1]:
        if all(_differs(poses[i], other) for other in distinct):
            distinct.append(poses[i])
        if len(distinct) == config.refine_best:
            break
    return distinct


def fine_stage(model: TargetModel, coarse_xyz: np.ndarray, xyz_m: np.ndarray, candidates: list[np.ndarray],
               config: AcquisitionConfig, tracker: TrackerConfig) -> list[tuple[float, float, float, Estimate]]:
    """Each candidate registered on the tracker's model, cloud and capture gates;
    (score, fit, coverage, estimate) best first."""
    results = []
    for pose in candidates:
        estimate = register(model, xyz_m, pose, list(tracker.capture_gates_m), tracker)
        fit = fit_score(model, coarse_xyz, estimate.pose, config.score_gate_m)
        cov = coverage(model, xyz_m, estimate.pose, config)
        results.append((fit * cov, fit, cov, estimate))
    return sorted(results, key=lambda item: -item[0])


def ambiguities(results: list[tuple[float, float, float, Estimate]], axis_body: np.ndarray,
                margin: float) -> tuple[bool, float]:
    """(whether a pose rolled from the best scored within ``margin`` of it, the best score
    of a pose elsewhere: the axis > 5 deg or the centre > 0.3 m away; nan if none)."""
    score, best = results[0][0], results[0][3].pose
    axis_best = best[:3, :3] @ axis_body
    rolled, elsewhere = [], []
    for item in results[1:]:
        pose = item[3].pose
        if not _differs(pose, best):
            continue
        same_place = (float(axis_best @ (pose[:3, :3] @ axis_body)) > math.cos(math.radians(5.0))
                      and np.linalg.norm(pose[:3, 3] - best[:3, 3]) < 0.3)
        (rolled if same_place else elsewhere).append(item[0])
    return bool(rolled) and rolled[0] >= score - margin, float(elsewhere[0]) if elsewhere else math.nan
