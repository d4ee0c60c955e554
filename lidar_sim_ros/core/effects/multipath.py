"""Multipath: the second bounce off a specular surface (MLI's mirror-like lobe).

The paper fits MLI with a sharp Phong lobe (Fig. 10) and blames multipath for lab
points that never occur on orbit (Sec. 1). A shot whose first surface A has a
specular lobe (k_s > 0, finite exponent n) sends most of its light along the mirror
direction; where that meets another surface B, B scatters some of it back along the
same path, A mirrors it to the receiver, and the sensor reports a *ghost* at range

    r_ghost = (|SA| + |AB| + |BA| + |AS|) / 2 = |SA| + |AB|

along the shot's own direction: behind the mirror surface, where the mirror image of
B lies.

Power (paper Eqs. 1-3 chained, Eq. 5 BRDFs; symbols as in ``reflection.py``):

- at A the whole transmitted power P_o tau_t lands on the footprint; A re-radiates it
  with intensity f_A(alpha) P_o tau_t cos(theta_A') (W/sr) toward direction alpha off
  the mirror ray, theta_A' the angle of that direction to A's normal (= theta_A on the
  mirror ray);
- B, at |AB|, receives the irradiance across the beam E_B = f_A P_o tau_t cos(theta_A)
  / |AB|^2 and sends back toward A the radiance L_B = f_B E_B cos(theta_B) (Eq. 1),
  f_B the monostatic BRDF of B (the light returns the way it came: alpha_B = 2 theta_B);
- the receiver looks at A's footprint and sees B reflected in it: the radiance
  L_app = integral over the lobe of f_A L_B cos(theta_A) d omega
        = L_B / f_A * cos(theta_A) * S_A,   S_A = integral of f_A(alpha)^2 d omega (1/sr),
  the specular BRDF entering twice (out and back, same alpha by reciprocity);
- Eq. 3 turns L_app into received power with A's footprint A(r_A) and cos(theta_A).

Altogether P_ghost = P_o tau_t tau_r pi (D/2)^2 Omega_beam S_A cos^2(theta_A)
f_B cos(theta_B) / |AB|^2, with Omega_beam = pi (dtheta/2)^2: independent of |SA|.
For the Phong lobe S_A = k_s^2 (n + 2)^2 / (2 pi (2 n + 1)) (closed form of the
integral of [k_s (n+2)/(2 pi) cos^n alpha]^2 over alpha < pi/2); A's diffuse part is
left out (it scatters over 2 pi sr: k_d^2 / pi, below 1e-3 /sr for MLI's k_d = 0.05,
against S_A = 1.5 /sr).

Which paths are kept, and why (docs/effects.md has the long form):

- S-A-B-A-S only: the path that comes back along the shot's own line of sight, the one
  a monostatic receiver with a footprint-sized field of view sees. Paths S-A-B-S (light
  from B straight to the receiver) land outside the receiver's field of view except when
  B lies on the line of sight itself, i.e. behind A, which the raycast has hidden.
- One ray per shot along the mirror direction, and B taken as the same surface across
  the lobe: S_A integrates the lobe in closed form. The lobe's half-width (~1/sqrt(n):
  13 deg for MLI's n = 20) covers |AB| * 0.22 on B, a few tens of cm at 1-2 m, where the
  ghosts are detectable: edges of B within that patch are not resolved (the ghost keeps
  the mirror ray's answer). Rays over the cone would cost K casts per specular hit; one
  keeps the cost within the benchmark's budget.
- Third and higher bounces: each adds a factor ~ Omega_beam S (1e-6), far below threshold.
- Only shots whose ghost could be detected are followed (pruning that loses no ghost):
  the mirror ray of a face on the target's convex hull meets nothing, and from any face
  it can only meet the mesh within the face's clearance / cos(theta_A)
  (``Target.face_clearance_m``); and with the brightest material of
  the table as B at normal incidence, the ghost falls below the threshold beyond
  d_max = sqrt(P_ghost(|AB| = 1 m) / P_threshold); a shot with d_max < ``min_path_m``
  casts no ray (PIF's broad lobe, n = 1, k_s = 0.02: d_max ~ 2 cm), and hits past d_max
  are dropped. Hits closer than ``min_path_m`` are one pulse with A's echo: no ghost.

``strength`` scales the ghost power (1 = the model above).
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core import reflection
from lidar_sim_ros.core.config import OpticsConfig
from lidar_sim_ros.core.geometry_kernels import rays_to_body
from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ExtraReturns, ReturnContext

# Offset (m) of a mirror ray's origin off surface A along its normal, per metre of range
# plus a floor: clears Embree's float32 rounding so that the ray does not hit A again.
SELF_HIT_OFFSET_PER_M = 2e-5
SELF_HIT_OFFSET_M = 1e-4
# Clearance (m) below which a face counts as on the convex hull (float rounding).
CLEARANCE_TOL_M = 1e-6
MAX_STRENGTH = 1000.0   # ghost power scale; docs/effects.md, "Parameter bounds"
MAX_MIN_PATH_M = 1000.0


def mirror_directions(directions: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit mirror directions r = d - 2 (d . n) n of unit rays d off unit normals n (N, 3)."""
    dn = np.einsum('ij,ij->i', directions, normals)
    return directions - 2.0 * dn[:, None] * normals


def lobe_integral_sr(ks, n):
    """S = integral of the Phong lobe squared [k_s (n+2)/(2 pi) cos^n alpha]^2 over the
    hemisphere alpha < pi/2 (1/sr): k_s^2 (n+2)^2 / (2 pi (2n+1))."""
    ks, n = np.asarray(ks, float), np.asarray(n, float)
    return ks * ks * (n + 2.0) ** 2 / (2.0 * np.pi * (2.0 * n + 1.0))


def ghost_range_m(range_a_m, path_ab_m):
    """Range (m) the ghost appears at along the shot: (|SA| + |AB| + |BA| + |AS|) / 2."""
    return np.asarray(range_a_m) + np.asarray(path_ab_m)


def ghost_power_w(range_a_m, cos_a, lobe_sr, f_b, cos_b, path_ab_m, optics: OpticsConfig):
    """Received power (W) of the S-A-B-A-S path, Eqs. 1-3 chained (module docstring).

    range_a_m: |SA| (m); cos_a: cos of the incidence at A (-, = the mirror ray's angle to
    A's normal); lobe_sr: A's ``lobe_integral_sr`` (1/sr); f_b: B's monostatic BRDF (1/sr);
    cos_b: cos of the mirror ray's incidence at B (-); path_ab_m: |AB| (m).
    """
    cos_a = np.asarray(cos_a, float)
    # Irradiance across the beam at B per unit f_A: A re-radiates all of P_o tau_t.
    e_b = optics.peak_power_w * optics.transmit_efficiency * cos_a / np.asarray(path_ab_m) ** 2
    l_b = reflection.laser_radiance(f_b, e_b, cos_b)                    # Eq. 1 at B
    l_apparent = l_b * np.asarray(lobe_sr) * cos_a                      # B seen in A's lobe
    area = reflection.footprint_area_m2(range_a_m, optics.beam_divergence_rad, cos_a)
    return reflection.received_power_w(l_apparent, optics.receive_efficiency, area, cos_a,
                                       optics.aperture_diameter_m, range_a_m)   # Eq. 3


def max_detectable_path_m(cos_a, lobe_sr, f_b_max, threshold_power_w, optics: OpticsConfig,
                          strength: float = 1.0):
    """|AB| (m) past which no surface B (BRDF <= f_b_max, normal incidence) gives a ghost
    at or above threshold: P_ghost scales as 1 / |AB|^2 and does not depend on |SA|."""
    p_at_1m = strength * ghost_power_w(1.0, cos_a, lobe_sr, f_b_max, 1.0, 1.0, optics)
    return np.sqrt(np.maximum(p_at_1m, 0.0) / threshold_power_w)


@register
class Multipath(Effect):
    """A ghost behind each specular hit whose mirror ray meets another surface."""

    name = 'multipath'
    # The comparison fits ``strength`` (searched on a log scale, ``compare/model/fit.py``); its
    # likelihood reads the ghosts through ``extra_returns`` and ``ghost_scale``, the
    # parameter the ghost power is proportional to (``compare/model/likelihood.py``, ghost term).
    bounds = {'strength': (0.0, 30.0)}
    ghost_scale = 'strength'

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        strength: float = Field(1.0, ge=0.0, le=MAX_STRENGTH, description='scale on the ghost power (-); 1 = Eqs. 1-3')
        min_path_m: float = Field(0.05, ge=0.0, le=MAX_MIN_PATH_M, description=(
            'follow a specular hit only if a ghost could be detected at least this far behind '
            'it (m): closer ghosts merge with the surface echo'))

    def _material_table(self, materials, optics: OpticsConfig, threshold_power_w: float) -> tuple:
        """Per material id: kd, ks, n, the lobe integral (1/sr), and the farthest |AB| (m) at
        which any ghost off it can be detected (at normal incidence, a little over, so that
        float rounding of cos(theta_A) never makes a shot reach farther); and the BRDF of
        the brightest B (1/sr). Computed once per material table (configs are frozen)."""
        values = (threshold_power_w, self.params.strength)
        cached = getattr(self, '_table', None)
        if not (cached and cached[0] is materials and cached[1] is optics and cached[2] == values):
            kd, ks, n = (materials.column(k) for k in ('kd', 'ks', 'n'))
            lobe = lobe_integral_sr(ks, n)
            # The brightest B there is: any material at normal incidence (alpha = 0).
            f_b_max = float(np.max(reflection.phong_brdf_cos(1.0, kd, ks, n)))
            reach_max = 1.001 * max_detectable_path_m(1.0, lobe, f_b_max, threshold_power_w,
                                                      optics, self.params.strength)
            self._table = materials, optics, values, (kd, ks, n, lobe, f_b_max, reach_max)
        return self._table[3]

    def extra_returns(self, ctx: ReturnContext, shots: np.ndarray | None = None) -> ExtraReturns | None:
        scene = ctx.scene
        if self.params.strength <= 0 or scene is None or ctx.normal is None or ctx.direction is None:
            return None
        from lidar_sim_ros.core.geometry import cast_at_poses, coherent_order
        from lidar_sim_ros.core.pose import Poses
        optics = scene.sensor.optics
        # A multi-return receiver merges a ghost closer than min_separation_m to its echo.
        receiver = scene.sensor.detection.returns
        min_path = max(self.params.min_path_m, 0.0 if receiver.single else receiver.min_separation_m)
        least_reach = max(min_path, 1e-9)    # |AB| (m) a followed shot must be able to reach
        kd, ks, n, lobe, f_b_max, reach_max = self._material_table(scene.materials, optics,
                                                                   ctx.threshold_power_w)
        on = np.flatnonzero(ctx.hit) if shots is None else shots[ctx.hit.take(shots)]
        mat_on = ctx.material.take(on)
        # Materials whose ghost fades below the threshold within min_path even at normal
        # incidence (the ghost power grows with cos(theta_A)) are never followed.
        if not np.all(reach_max >= least_reach):
            keep = reach_max.take(mat_on) >= least_reach
            on, mat_on = on[keep], mat_on[keep]
        cos_a = np.abs(np.einsum('ij,ij->i', ctx.direction.take(on, axis=0), ctx.normal.take(on, axis=0)))
        reach = max_detectable_path_m(cos_a, lobe.take(mat_on), f_b_max, ctx.threshold_power_w,
                                      optics, self.params.strength)
        if ctx.face is not None:
            # The mirror ray leaves A at elevation 90 deg - theta_A above A's plane: it can meet
            # the mesh only within clearance / cos(theta_A) (none for a face on the convex hull).
            # The side the ray leaves by: the face's winding normal, or its reverse where the
            # shot came from behind the winding (meshes need not be consistently wound).
            target, face = scene.target, ctx.face.take(on)
            quat, pos = scene.poses.quat_xyzw, scene.poses.position_m.reshape(-1, 3)
            if len(quat) > 1:
                quat, pos = quat.take(on, axis=0), pos.take(on, axis=0)
            _, d_body = rays_to_body(quat, pos, np.zeros((1, 3)), ctx.direction.take(on, axis=0),
                                     np.arange(len(on), dtype=np.int64))
            front = np.einsum('ij,ij->i', target.face_normals.take(face, axis=0), d_body) < 0
            clearance = np.where(front, target.face_clearance_m.take(face),
                                 target.face_clearance_back_m.take(face))
            with np.errstate(divide='ignore', invalid='ignore'):
                reach = np.minimum(reach, np.where(clearance > CLEARANCE_TOL_M, clearance / cos_a, 0.0))
        follow = reach >= least_reach
        shots, cos_a, reach = on[follow], cos_a[follow], reach[follow]
        if len(shots) == 0:
            return None
        d = ctx.direction.take(shots, axis=0)
        normal = ctx.normal.take(shots, axis=0)
        range_a = ctx.range_m.take(shots)
        mirror = mirror_directions(d, normal)
        lift = SELF_HIT_OFFSET_M + SELF_HIT_OFFSET_PER_M * range_a
        origin = d * range_a[:, None] + normal * lift[:, None]
        quat, pos = scene.poses.quat_xyzw, scene.poses.position_m.reshape(-1, 3)
        if len(quat) > 1:
            quat, pos = quat.take(shots, axis=0), pos.take(shots, axis=0)
        # Mirror rays of neighbouring shots point all over: cast them grouped by direction.
        order = coherent_order(np.arctan2(mirror[:, 1], mirror[:, 0]),
                               np.arcsin(np.clip(mirror[:, 2], -1.0, 1.0)))
        hits = cast_at_poses(scene.target, mirror, Poses.from_quat(quat, pos), origin_lidar_m=origin,
                             order=order, length_m=reach)
        # |AB| from A itself: the lifted origin sits lift * cos(theta_A) along the mirror ray.
        # Closer than min_path_m the ghost is one pulse with A's echo (and no ray leaves A
        # for a surface it lies on, such as a blanket's own tank).
        path = hits.range_m + lift * cos_a
        keep = hits.hit & (path >= min_path)
        if not np.any(keep):
            return None
        rows = np.flatnonzero(keep)
        shots, cos_a, range_a, path = shots[rows], cos_a[rows], range_a[rows], path[rows]
        mat_b = hits.material[rows]
        cos_b = hits.cos_incidence[rows]
        f_b = reflection.phong_brdf_cos(reflection.monostatic_cos_alpha(cos_b), kd.take(mat_b),
                                        ks.take(mat_b), n.take(mat_b))
        mat_a = ctx.material.take(shots)
        power = self.params.strength * ghost_power_w(range_a, cos_a, lobe.take(mat_a), f_b, cos_b,
                                                     path, optics)
        return ExtraReturns(shot=shots, range_m=ghost_range_m(range_a, path), power_w=power,
                            material=mat_b, face=hits.face[rows], via_material=mat_a,
                            source=self.name)
