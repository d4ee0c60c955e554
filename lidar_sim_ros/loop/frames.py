"""The loop's frames: inertial (Earth-centred, Basilisk's N), LVLH, chaser body, lidar, target body.

Conventions (all rotations ``R_AB`` map B components to A components, ``v_A = R_AB v_B``):

- LVLH (Hill) of the target orbit: x radial out (R-bar), y along-track (V-bar: x cross y
  is the orbit normal), z orbit normal. It turns at omega = |r x v| / |r|^2 about z.
- The chaser body B, and the lidar L mounted on it: ``p_B = R_BL p_L + t_B``.
- The target body T (the mesh frame). What the simulator reads on ``/target/pose`` is the
  target body pose in the lidar frame: ``p_L = R_LT p_T + t_L``.

Pure numpy; Basilisk's MRP attitudes convert with ``rotation_from_mrp``.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.loop.config import MountConfig


def unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The cross product of two 3-vectors (np.cross costs ~10x more on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def rotation_from_mrp(sigma_bn: np.ndarray) -> np.ndarray:
    """R_NB (body -> inertial) from Basilisk's MRP sigma_BN (its DCM [BN] is the transpose)."""
    return Rotation.from_mrp(np.asarray(sigma_bn, dtype=float)).as_matrix()


def lvlh_basis(r_m: np.ndarray, v_mps: np.ndarray) -> tuple[np.ndarray, float]:
    """(R_NH (3 x 3, columns: LVLH x, y, z in inertial), frame rate omega (rad/s)) of an orbit
    state (inertial position r (m), velocity v (m/s))."""
    r, v = np.asarray(r_m, float), np.asarray(v_mps, float)
    h = cross(r, v)
    x = unit(r)
    z = unit(h)
    y = cross(z, x)
    return np.column_stack([x, y, z]), float(np.linalg.norm(h) / (r @ r))


def relative_lvlh(r_chaser_m, v_chaser_mps, r_target_m, v_target_mps) -> tuple[np.ndarray, np.ndarray]:
    """The chaser's position (m) and velocity (m/s) relative to the target, in the rotating LVLH."""
    R_NH, omega = lvlh_basis(r_target_m, v_target_mps)
    rho = R_NH.T @ (np.asarray(r_chaser_m, float) - r_target_m)
    w = np.array([0.0, 0.0, omega])
    rho_dot = R_NH.T @ (np.asarray(v_chaser_mps, float) - v_target_mps) - cross(w, rho)
    return rho, rho_dot


def inertial_from_lvlh(r_target_m, v_target_mps, rho_m, rho_dot_mps) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``relative_lvlh``: the chaser's inertial position (m) and velocity (m/s)."""
    R_NH, omega = lvlh_basis(r_target_m, v_target_mps)
    rho, rho_dot = np.asarray(rho_m, float), np.asarray(rho_dot_mps, float)
    w = np.array([0.0, 0.0, omega])
    return (np.asarray(r_target_m, float) + R_NH @ rho,
            np.asarray(v_target_mps, float) + R_NH @ (rho_dot + cross(w, rho)))


def mount_transform(mount: MountConfig) -> tuple[np.ndarray, np.ndarray]:
    """(R_BL, t_B (m)) of the lidar on the chaser: p_B = R_BL p_L + t_B."""
    return Rotation.from_quat(mount.quat_xyzw).as_matrix(), np.asarray(mount.position_m, float)


def frame_from_axes(forward: np.ndarray, up: np.ndarray) -> np.ndarray:
    """A rotation whose x is ``forward`` and whose z is as close to ``up`` as x allows."""
    x = unit(forward)
    z = up - (up @ x) * x
    if np.linalg.norm(z) < 1e-9:  # up along forward: any perpendicular will do
        z = cross(x, [0.0, 0.0, 1.0] if abs(x[2]) < 0.9 else [1.0, 0.0, 0.0])
    z = unit(z)
    return np.column_stack([x, cross(z, x), z])


def attitude_hold_lvlh(R_NH: np.ndarray) -> np.ndarray:
    """R_NB of the LVLH hold: body x along +V-bar, body z radial out (body y = orbit normal)."""
    return frame_from_axes(R_NH[:, 1], R_NH[:, 0])


def attitude_point_at_target(r_chaser_m, r_target_m, R_NH, R_BL, t_B) -> np.ndarray:
    """R_NB that puts the lidar's boresight (lidar +x) on the target centre, lidar z toward
    LVLH +x (radial out) as far as it can. The lidar sits t_B off the chaser's centre, so the
    line of sight depends on the attitude: a fixed point, six passes (each shrinks the
    pointing error by about offset / range, ~0.04 at 20 m: 1e-9 rad after six)."""
    R_NB = attitude_hold_lvlh(R_NH)
    for _ in range(6):
        lidar_n = np.asarray(r_chaser_m, float) + R_NB @ t_B
        R_NL = frame_from_axes(np.asarray(r_target_m, float) - lidar_n, R_NH[:, 0])
        R_NB = R_NL @ R_BL.T
    return R_NB


def lidar_pose(r_chaser_m, R_NB, R_BL, t_B) -> tuple[np.ndarray, np.ndarray]:
    """(lidar origin in inertial (m), R_NL)."""
    return np.asarray(r_chaser_m, float) + R_NB @ t_B, R_NB @ R_BL


def target_in_lidar(r_chaser_m, R_NB, R_BL, t_B, r_target_m, R_NT) -> tuple[np.ndarray, np.ndarray]:
    """(R_LT, t_L (m)): the target body pose in the lidar frame, ``p_L = R_LT p_T + t_L``
    (what ``/target/pose`` carries)."""
    origin, R_NL = lidar_pose(r_chaser_m, R_NB, R_BL, t_B)
    return R_NL.T @ R_NT, R_NL.T @ (np.asarray(r_target_m, float) - origin)


def sun_in_lidar(sun_n: np.ndarray, R_NB, R_BL) -> np.ndarray:
    """The unit direction toward the sun (inertial ``sun_n``) in the lidar frame."""
    return unit((R_NB @ R_BL).T @ unit(sun_n))


def in_earth_shadow(r_m: np.ndarray, sun_n: np.ndarray, earth_radius_m: float = 6378136.6) -> np.ndarray | bool:
    """Cylindrical umbra: behind the Earth (r . s < 0) and within an Earth radius (m) of the
    Earth-sun line. ``r_m``: inertial position(s) (3,) or (K, 3) m; ``sun_n``: the inertial
    direction toward the sun. A bool for one position, (K,) bools for K."""
    s = unit(np.asarray(sun_n, float))
    r = np.asarray(r_m, float)
    along = r @ s
    across = np.linalg.norm(r - along[..., None] * s, axis=-1)
    shadow = (along < 0) & (across < earth_radius_m)
    return bool(shadow) if shadow.ndim == 0 else shadow


def chaser_from_estimate(t_L_m: np.ndarray, R_HB: np.ndarray, R_BL: np.ndarray, t_B: np.ndarray) -> np.ndarray:
    """The chaser's position relative to the target in LVLH (m), from the target position in
    the lidar frame ``t_L`` (the estimate's translation) and the chaser's own attitude in
    LVLH ``R_HB``: rho = -(R_HB (R_BL t_L + t_B)). The target's centre is its body origin."""
    return -(R_HB @ (R_BL @ np.asarray(t_L_m, float) + t_B))


# ----------------------------------------------- the same, for K samples at once
# A control period samples the truth at every dynamics sub-step (11 at 100 Hz and 10 Hz):
# these stack the K samples (leading axis) so that a period costs a few numpy calls, not
# K x ~60 small ones (the per-sample path was ~40 % of ``propagate``, docs/loop.md).
def frame_from_axes_k(forward: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``frame_from_axes`` of K pairs (K, 3): rotations (K, 3, 3)."""
    x = unit(forward)
    z = up - np.einsum('ki,ki->k', up, x)[:, None] * x
    bad = np.linalg.norm(z, axis=1) < 1e-9
    if bad.any():  # up along forward: any perpendicular will do
        other = np.where(np.abs(x[bad, 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
        z[bad] = np.cross(x[bad], other)
    z = unit(z)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def lvlh_basis_k(r_m: np.ndarray, v_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``lvlh_basis`` of K orbit states (K, 3): (R_NH (K, 3, 3), omega (K,) rad/s)."""
    h = np.cross(r_m, v_mps)
    x, z = unit(r_m), unit(h)
    return (np.stack([x, np.cross(z, x), z], axis=-1),
            np.linalg.norm(h, axis=1) / np.einsum('ki,ki->k', r_m, r_m))


def attitude_point_at_target_k(r_chaser_m, r_target_m, R_NH, R_BL, t_B) -> np.ndarray:
    """``attitude_point_at_target`` of K states: R_NB (K, 3, 3)."""
    R_NB = frame_from_axes_k(R_NH[:, :, 1], R_NH[:, :, 0])
    for _ in range(6):
        lidar_n = r_chaser_m + R_NB @ t_B
        R_NB = frame_from_axes_k(r_target_m - lidar_n, R_NH[:, :, 0]) @ R_BL.T
    return R_NB
