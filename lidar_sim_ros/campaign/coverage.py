"""Target coverage: which share of the mesh area the sensor could see did it sample?

Definition (one frame, evaluated at the frame's mid-time pose):

- a face is **visible** when its centroid lies inside the scan's field of view (the
  azimuth and elevation extents of the frame's shots), the face looks toward the
  sensor (outward normal against the line of sight), and a ray from the sensor to
  the centroid meets that face first (no other part of the target occludes it);
- coverage = (area of the visible faces that hold at least one return) /
  (area of all visible faces), in [0, 1].

It measures the scan pattern's sampling of the visible surface together with the
dropouts (``coverage``: detected returns; ``coverage_hit``: every ray that hit, i.e.
before dropouts). Faces hit although their centroid is hidden or outside the FOV
(grazing edges) do not count in either area. The visibility cast costs about one
frame's raycast on the 49k-face rocket body, hence only a few frames per run.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.core.geometry import Target, coherent_order
from lidar_sim_ros.core.pose import Poses


@dataclass(frozen=True)
class FaceGeometry:
    """Per-face centroid (N, 3) (m, body frame), area (N,) (m^2) and unit normal (N, 3)."""

    centroid_m: np.ndarray
    area_m2: np.ndarray
    normal: np.ndarray

    @classmethod
    def of(cls, target: Target) -> 'FaceGeometry':
        tri = target.vertices_m[target.faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        return cls(tri.mean(axis=1), 0.5 * np.linalg.norm(cross, axis=1), target.face_normals)


def visible_faces(target: Target, faces: FaceGeometry, pose: Poses,
                  az_limits_rad: tuple[float, float], el_limits_rad: tuple[float, float]) -> np.ndarray:
    """Bool mask (N faces,) of the faces visible from the sensor origin at one ``pose``."""
    origin = pose.to_body(np.zeros((1, 3))).reshape(3)
    to_face = faces.centroid_m - origin
    to_face /= np.linalg.norm(to_face, axis=1, keepdims=True)
    facing = np.einsum('ij,ij->i', faces.normal, to_face) < 0.0
    candidates = np.flatnonzero(facing)
    d_lidar = pose.vector_to_lidar(to_face[candidates]).reshape(-1, 3)
    az = np.arctan2(d_lidar[:, 1], d_lidar[:, 0])
    el = np.arctan2(d_lidar[:, 2], np.hypot(d_lidar[:, 0], d_lidar[:, 1]))
    in_fov = ((az >= az_limits_rad[0]) & (az <= az_limits_rad[1])
              & (el >= el_limits_rad[0]) & (el <= el_limits_rad[1]))
    candidates, az, el = candidates[in_fov], az[in_fov], el[in_fov]
    visible = np.zeros(len(faces.area_m2), dtype=bool)
    if len(candidates):
        # Coherent ray order: ~1.7x faster through Embree than face order.
        hits = target.cast(origin.reshape(1, 3), to_face[candidates],
                           order=coherent_order(az, el, np.radians(0.25)))
        visible[candidates[hits.face == candidates]] = True
    return visible


def covered_fraction(area_m2: np.ndarray, visible: np.ndarray, sampled_faces: np.ndarray) -> float:
    """Area share of the visible faces that appear in ``sampled_faces`` (face ids; -1 ignored).

    NaN when nothing is visible.
    """
    total = float(area_m2[visible].sum())
    if total <= 0.0:
        return float('nan')
    sampled = np.zeros(len(area_m2), dtype=bool)
    ids = np.asarray(sampled_faces)
    sampled[ids[ids >= 0]] = True
    return float(area_m2[visible & sampled].sum()) / total
