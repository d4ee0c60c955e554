"""Sunlight as physics: shadows, background power, false returns, added noise, blinding.

The paper ends with "modeling solar light as a disturbance would be ideal"; this is that
model (docs/sunlight.md has the equations, assumptions and numbers). For each shot:

1. What its receiver field of view sees, and how bright it is at the laser wavelength:
   * a surface point (the shot hits the target): lit by the sun if it faces the sun and
     a shadow ray toward the sun leaves the target; its radiance toward the sensor is
     L = E_sun dlambda f(sun -> sensor) cos(theta_sun) with the material's modified Phong
     BRDF (paper Eq. 5) in the bistatic geometry; plus the Earth's diffuse light if the
     scenario has an Earth (no shadow ray for this extended source);
   * empty space (a miss): the Earth's radiance if the ray points inside its disk, else
     the deep-space radiance; the sun itself where its disk overlaps the field of view;
   * stray light: sunlight scattered inside the receiver optics when the sun is near the
     shot's axis (power-law point-source transmittance), unless the target shades the
     aperture.
   P_bg = L A_rx Omega_IFOV tau_r (``radiometry.py``), times ``background_scale`` (the
   receiver factor: band-pass, field of view and filter transmission are not public).
2. What the background does:
   * false returns: background shot noise crosses the detection threshold at the Rice
     rate (linear APD) or photons arrive at the Poisson rate (photon counting); the
     first crossing before the target echo (or anywhere in the listening window if no
     echo is detected) is reported instead, at its range, with material 255;
   * range noise of true returns grows as the signal-to-background-noise ratio falls
     (timing jitter = rise time / SNR, in quadrature with the material sigma, which
     already holds the lab's dark and signal noise);
   * blinding: a background at or above ``receiver.blinding_power_w`` (the sun in or near
     the field of view, a specular glint of the sun off MLI) saturates the front end:
     the shot returns nothing.

Without a sun (``ctx.scene.illumination`` None) the effect does nothing and draws nothing.
Likelihood (``lidar-sim compare``): a shot returns a false point with probability
1 - exp(-nu T) (``outlier_fraction``); ``background_scale`` is the free parameter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field

from lidar_sim_ros.core import detection, radiometry as rad
from lidar_sim_ros.core.config import ReceiverConfig, SensorConfig
from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect, ReturnContext, Scene
from lidar_sim_ros.core.geometry_kernels import _rotate

# Shadow rays start this far off the surface along its normal, so they do not hit the
# face they leave (Embree works in float32: ~1e-6 relative at the target's size).
SHADOW_RAY_OFFSET_M = 2e-3
# Stray light weaker than this share of the receiver's own noise floor is ignored, which
# spares the aperture-shadow rays where they cannot matter.
NEGLIGIBLE_NOISE_SHARE = 0.01
# A blinded shot's likelihood of a matched point is not zero (the model may be wrong).
MAX_OUTLIER_FRACTION = 0.999
MAX_BACKGROUND_SCALE = 1e4   # receiver factor; docs/effects.md, "Parameter bounds"


@dataclass(frozen=True)
class Background:
    """Per-shot background light and what it does to the receiver.

    power_w: total background power collected (W); surface_power_w: the part from sunlit
    (and Earth-lit) target surfaces (W); sunlit: the shot sees a target point in direct
    sunlight; shadowed: it sees a target point in shadow (or facing away from the sun);
    noise_sigma_w: receiver noise as an optical power (W); dark_sigma_w: the same without
    background (W); rate_hz: false-return (threshold-crossing) rate (Hz); listen_s: time the
    detector listens before the echo, or the whole window without one (s); blinded: the
    background saturates the receiver.
    """

    power_w: np.ndarray
    surface_power_w: np.ndarray
    sunlit: np.ndarray
    shadowed: np.ndarray
    noise_sigma_w: np.ndarray
    dark_sigma_w: float
    rate_hz: np.ndarray
    listen_s: np.ndarray
    blinded: np.ndarray

    @property
    def false_return_probability(self) -> np.ndarray:
        """P(a threshold crossing before the echo / in the window) per shot (-)."""
        return rad.crossing_probability(self.rate_hz, self.listen_s)


def noise_sigma_w(background_w, rx: ReceiverConfig) -> np.ndarray:
    """Linear-mode receiver noise (W, optical equivalent) with ``background_w`` on the detector."""
    return rad.apd_noise_sigma_w(background_w, rx.responsivity_a_per_w, rx.apd_gain,
                                 rx.excess_noise_factor, rx.bandwidth_hz,
                                 rx.amplifier_noise_a_per_rthz, rx.dark_current_a)


def crossing_rate_hz(background_w, sensor: SensorConfig) -> tuple[np.ndarray, np.ndarray]:
    """False-return rate (Hz) and noise sigma (W; NaN for photon counting) per shot."""
    rx = sensor.receiver
    if rx.detector == 'photon_counting':
        lam = rad.photon_rate_hz(background_w, rx.photon_detection_efficiency, rx.wavelength_nm)
        rate = rad.coincidence_rate_hz(lam + rx.dark_count_rate_hz, rx.coincidence_photons,
                                       rx.coincidence_window_s)
        return rate, np.full(np.shape(background_w), np.nan)
    sigma = noise_sigma_w(background_w, rx)
    return rad.rice_rate_hz(sensor.detection.threshold_power_w, sigma, rx.bandwidth_hz), sigma


def negligible_background_w(sensor: SensorConfig) -> float:
    """Background power (W) that changes the receiver's dark noise by 1 %: the noise
    variance (linear APD) or the count rate (photon counting)."""
    rx = sensor.receiver
    if rx.detector == 'photon_counting':
        return float(NEGLIGIBLE_NOISE_SHARE * max(rx.dark_count_rate_hz, 1.0)
                     / rad.photon_rate_hz(1.0, rx.photon_detection_efficiency, rx.wavelength_nm))
    var_per_w = (2.0 * rad.ELEMENTARY_CHARGE_C * rx.excess_noise_factor * rx.bandwidth_hz
                 / rx.responsivity_a_per_w)
    return float(NEGLIGIBLE_NOISE_SHARE * noise_sigma_w(0.0, rx) ** 2 / var_per_w)


def background_of(ctx: ReturnContext, scale: float = 1.0) -> Background | None:
    """The background light of every shot in ``ctx`` and its effect on the receiver
    (None without a scene or a sun). ``scale`` multiplies every background power."""
    scene: Scene | None = ctx.scene
    if scene is None or scene.illumination is None or ctx.direction is None:
        return None
    light, sensor = scene.illumination, scene.sensor
    rx, optics, det = sensor.receiver, sensor.optics, sensor.detection
    n = len(ctx)
    d = np.asarray(ctx.direction, float)
    s = light.sun_direction
    e_sun = light.sun_irradiance_w_m2_nm * rx.bandpass_nm            # W m^-2 in the band
    area = rad.aperture_area_m2(optics.aperture_diameter_m)
    tau = optics.receive_efficiency
    to_power = area * rx.ifov_sr * tau * scale                       # W per W m^-2 sr^-1
    surface_power = np.zeros(n)
    sunlit = shadowed = np.zeros(n, bool)

    on = np.flatnonzero(ctx.hit)
    if len(on):
        kd, ks, n_exp = (scene.materials.column(k) for k in ('kd', 'ks', 'n'))
        # Which hits face the sun, their power if lit, and the shadow rays still needed.
        target = scene.target
        if ctx.face is not None:
            face, clearance = ctx.face, target.face_clearance_m
        else:   # no face ids: every ray unbounded
            face, clearance = np.zeros(n, np.int64), np.full(1, np.inf)
        sunlit, surface_power, shots, o_body, d_body, length = sunward_surfaces(
            on, d, ctx.range_m, ctx.normal, ctx.material, s, e_sun * to_power, kd, ks, n_exp,
            SHADOW_RAY_OFFSET_M, scene.poses.quat_xyzw, scene.poses.position_m.reshape(-1, 3),
            face, clearance, target.face_normals)
        if len(shots):
            shade = shots[target.occluded(o_body, d_body, length)]
            surface_power[shade], sunlit[shade] = 0.0, False
        shadowed = ctx.hit & ~sunlit
        if light.earth_direction is not None:
            normal, mat = ctx.normal.take(on, axis=0), ctx.material.take(on)
            e = light.earth_direction
            e_earth = (light.earth_radiance_w_m2_sr_nm.take(on) * rx.bandpass_nm
                       * rad.disk_irradiance_factor(light.earth_angular_radius_rad))
            f_earth = rad.bistatic_phong_brdf(normal, e, -d.take(on, axis=0), kd.take(mat),
                                              ks.take(mat), n_exp.take(mat))
            surface_power[on] += rad.reflected_radiance_w_m2_sr(e_earth, f_earth, normal @ e) * to_power

    power = surface_power.copy()
    off = np.flatnonzero(~ctx.hit)
    if len(off) and (light.deep_space_radiance_w_m2_sr_nm > 0 or light.earth_direction is not None):
        sky = np.full(len(off), light.deep_space_radiance_w_m2_sr_nm * rx.bandpass_nm)
        if light.earth_direction is not None:
            cos_rho = np.cos(light.earth_angular_radius_rad)
            behind_earth = d.take(off, axis=0) @ light.earth_direction > cos_rho
            sky = np.where(behind_earth, light.earth_radiance_w_m2_sr_nm.take(off) * rx.bandpass_nm,
                           sky)
        power[off] += sky * to_power
    # The sun itself: the share of its disk inside the field of view (misses only: a hit
    # means the target stands in front of it), and stray light from near the axis. Only
    # shots close enough to the sun for either to matter are looked at.
    into_aperture = e_sun * area * tau * scale                        # W entering the aperture
    negligible_w = negligible_background_w(sensor)
    field_rad = rad.field_radius_rad(rx.ifov_sr)
    reach_rad = max(rad.SUN_ANGULAR_RADIUS_RAD + field_rad, rad.stray_light_reach_rad(
        rx.stray_light_pst_at_1deg, float(np.max(into_aperture, initial=0.0)), negligible_w))
    cos_off = rad.row_dot(d, s)
    near = np.flatnonzero(cos_off > np.cos(min(reach_rad, np.pi / 2)))
    if len(near):
        off_axis = np.arccos(np.clip(cos_off.take(near), -1.0, 1.0))
        into = into_aperture.take(near)
        direct = rad.disk_overlap_fraction(off_axis, rad.SUN_ANGULAR_RADIUS_RAD, field_rad) * into
        stray = rad.stray_light_pst(off_axis, rx.stray_light_pst_at_1deg) * into
        seen = np.flatnonzero(stray > negligible_w)
        if len(seen):
            # The aperture may lie in the target's shadow (the sun behind the target).
            shaded = scene.occluded(np.zeros((len(seen), 3)), s.take(near[seen], axis=0), near[seen])
            stray[seen[shaded]] = 0.0
        power[near] += np.where(ctx.hit.take(near), 0.0, direct) + np.where(stray > negligible_w, stray, 0.0)

    if rx.detector == 'linear':
        sigma, rate, listen = apd_response(
            power, ctx.hit, ctx.power_w, ctx.range_m, det.threshold_power_w, det.saturation_power_w,
            det.min_range_m, det.max_range_m, rx.responsivity_a_per_w, rx.apd_gain,
            rx.excess_noise_factor, rx.bandwidth_hz, rx.amplifier_noise_a_per_rthz, rx.dark_current_a)
        dark = float(noise_sigma_w(0.0, rx))
    else:
        rate, sigma = crossing_rate_hz(power, sensor)
        echo = ctx.hit & detection.detected_mask(ctx.power_w, ctx.range_m, det)
        c_half = 0.5 * rad.SPEED_OF_LIGHT_M_S
        window_s = (det.max_range_m - det.min_range_m) / c_half
        listen = np.where(echo, np.clip((np.nan_to_num(ctx.range_m) - det.min_range_m) / c_half,
                                        0.0, window_s), window_s)
        dark = float('nan')
    return Background(power, surface_power, sunlit, shadowed, sigma, dark, rate,
                      listen, power >= rx.blinding_power_w)


@njit(cache=True)
def apd_response(power_w, hit, signal_w, range_m, threshold_w, saturation_w, min_range_m,
                 max_range_m, responsivity, gain, excess_noise, bandwidth_hz, amplifier_noise,
                 dark_current_a):
    """Per shot, for a linear-mode APD receiver: noise sigma (W, optical equivalent), Rice
    crossing rate (Hz), and how long the detector listens (s): until the echo if the
    detector reports it (threshold <= signal < saturation inside the range gate), else the
    whole gate. One pass; the numpy reference the tests check it against is
    ``radiometry.apd_noise_sigma_w``, ``radiometry.rice_rate_hz`` and
    ``detection.detected_mask``."""
    n = power_w.shape[0]
    sigma = np.empty(n)
    rate = np.empty(n)
    listen = np.empty(n)
    c_half = 0.5 * rad.SPEED_OF_LIGHT_M_S
    window = (max_range_m - min_range_m) / c_half
    shot = 2.0 * rad.ELEMENTARY_CHARGE_C * gain * gain * excess_noise * bandwidth_hz
    amp = amplifier_noise * amplifier_noise * bandwidth_hz
    prefactor = bandwidth_hz / math.sqrt(3.0)
    dark_sigma = math.sqrt(shot * dark_current_a + amp) / (gain * responsivity)
    dark_rate = prefactor * math.exp(-0.5 * (threshold_w / dark_sigma) ** 2)
    for i in range(n):
        if power_w[i] > 0.0:
            s = math.sqrt(shot * (responsivity * power_w[i] + dark_current_a) + amp) / (gain * responsivity)
            z = threshold_w / s
            sigma[i] = s
            rate[i] = prefactor * math.exp(-0.5 * z * z)
        else:   # most shots see no light: the dark values
            sigma[i] = dark_sigma
            rate[i] = dark_rate
        r = range_m[i]
        p = signal_w[i]
        if hit[i] and p >= threshold_w and p < saturation_w and r >= min_range_m and r <= max_range_m:
            listen[i] = min(max((r - min_range_m) / c_half, 0.0), window)
        else:
            listen[i] = window
    return sigma, rate, listen


@njit(cache=True)
def sunward_surfaces(on, direction, range_m, normal, material, sun_direction, band_irradiance,
                     kd, ks, n_exp, offset_m, quat_xyzw, position_m, face, clearance_m, face_normals):
    """The surface terms of the hits ``on`` (indices into the shots), one pass per hit.

    direction, normal, sun_direction (N, 3): unit vectors in the lidar frame (normals
    toward the sensor); band_irradiance (N,): solar irradiance in the band (W m^-2), or
    that times A_rx Omega_IFOV tau_r to get collected power (W) instead of radiance;
    kd, ks, n_exp per material id; quat_xyzw (N|1, 4), position_m (N|1, 3): the target
    pose of each shot (``p_lidar = R p_body + t``); face (N,): triangle hit; clearance_m,
    face_normals: ``Target.face_clearance_m`` and the body-frame face normals.
    Returns ``facing`` (N,): the hit faces the sun; ``radiance`` (N,):
    what those would send toward the sensor if lit, L = E f(sun -> sensor) cos(theta_sun)
    (W m^-2 sr^-1, or W with the scaled irradiance; ``radiometry.reflected_radiance_w_m2_sr`` of
    ``radiometry.bistatic_phong_brdf``, the numpy reference the tests check this against);
    and the shadow rays still needed: ``shots`` (M,) and the rays in the body frame as
    Embree takes them (float32 origins: hit point + offset_m along the normal; directions:
    toward the sun; lengths). Seen from the outside of a face, a ray can only meet the mesh
    while it is within the face's clearance of its plane: its length is
    (clearance - offset) / cos(theta_sun) plus 1 mm, and a face whose clearance is below
    the offset (on the convex hull) needs no ray at all. Seen from the inside, the length
    is unbounded. One loop instead of a dozen temporary arrays and three gathers.
    """
    n_on = on.shape[0]
    radiance = np.zeros(direction.shape[0])
    facing = np.zeros(direction.shape[0], np.bool_)
    shots = np.empty(n_on, np.int64)
    o_body = np.empty((n_on, 3), np.float32)
    d_body = np.empty((n_on, 3), np.float32)
    length = np.empty(n_on, np.float32)
    one_q, one_p = quat_xyzw.shape[0] == 1, position_m.shape[0] == 1
    m = 0
    for k in range(n_on):
        i = on[k]
        nx, ny, nz = normal[i, 0], normal[i, 1], normal[i, 2]
        sx, sy, sz = sun_direction[i, 0], sun_direction[i, 1], sun_direction[i, 2]
        cos_sun = nx * sx + ny * sy + nz * sz
        if cos_sun <= 0.0 or band_irradiance[i] <= 0.0:
            continue
        dx, dy, dz = direction[i, 0], direction[i, 1], direction[i, 2]
        # Toward the sensor v = -d; cos(alpha) = 2 (n.s)(n.v) - s.v (radiometry.mirror_cos_alpha).
        cos_a = -2.0 * cos_sun * (nx * dx + ny * dy + nz * dz) + (sx * dx + sy * dy + sz * dz)
        cos_a = min(max(cos_a, 0.0), 1.0)
        mat = material[i]
        f = kd[mat] / math.pi + ks[mat] * (n_exp[mat] + 2.0) / (2.0 * math.pi) * cos_a ** n_exp[mat]
        radiance[i] = f * band_irradiance[i] * cos_sun
        facing[i] = True
        iq, ip = (0 if one_q else i), (0 if one_p else i)
        # The sun into the body frame with the inverse (conjugate) rotation.
        qx, qy, qz, qw = -quat_xyzw[iq, 0], -quat_xyzw[iq, 1], -quat_xyzw[iq, 2], quat_xyzw[iq, 3]
        bx, by, bz = _rotate(qx, qy, qz, qw, sx, sy, sz)
        # Seen from its outer side, the sensor-facing normal is the outward one, so the sun
        # (n.s > 0) is on the outward side too: n_face . s_body > 0.
        fc = face[i]
        reach = math.inf
        if face_normals[fc, 0] * bx + face_normals[fc, 1] * by + face_normals[fc, 2] * bz > 0.0:
            if clearance_m[fc] <= offset_m:
                continue                      # nothing in front of the face: lit
            reach = (clearance_m[fc] - offset_m + 1e-3) / cos_sun
        r = range_m[i]
        ox, oy, oz = _rotate(qx, qy, qz, qw,
                             dx * r + offset_m * nx - position_m[ip, 0],
                             dy * r + offset_m * ny - position_m[ip, 1],
                             dz * r + offset_m * nz - position_m[ip, 2])
        o_body[m, 0], o_body[m, 1], o_body[m, 2] = ox, oy, oz
        d_body[m, 0], d_body[m, 1], d_body[m, 2] = bx, by, bz
        length[m] = reach
        shots[m] = i
        m += 1
    return facing, radiance, shots[:m], o_body[:m], d_body[:m], length[:m]


def first_crossings(rate_hz: np.ndarray, listen_s: np.ndarray,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The shots whose noise crosses the threshold while the detector listens, and the delay
    (s) of each one's first crossing after the gate opens.

    Each shot's crossings are a Poisson process of rate nu_i over [0, T_i): one crossing or
    more with probability 1 - exp(-nu_i T_i), the first at an exponential delay. Drawn
    exactly, but without a draw per shot (false returns are rare): the expected counts
    h_i = nu_i T_i are laid end to end, the arrivals of one unit-rate Poisson process on
    [0, sum h) fall into shot i's segment independently with mean h_i, and the first
    arrival's offset x in the segment is the delay x / nu_i. Shots with h_i > 1 (near the
    sun) draw their own exponential delay instead, which keeps the arrivals few.
    """
    hazard = rate_hz * listen_s                                   # expected crossings per shot
    busy = np.flatnonzero(hazard > 1.0)
    quiet_hazard = hazard.copy()
    quiet_hazard[busy] = 0.0
    cum = np.cumsum(quiet_hazard)
    total = float(cum[-1]) if len(cum) else 0.0
    x = np.sort(rng.uniform(0.0, total, rng.poisson(total)))
    shot = np.minimum(np.searchsorted(cum, x, side='right'), len(cum) - 1)
    shot, first = np.unique(shot, return_index=True)               # x sorted: first arrivals
    delay = (x[first] - (cum[shot] - quiet_hazard[shot])) / rate_hz[shot]
    busy_delay = rng.standard_exponential(len(busy)) / rate_hz[busy]
    crossed = busy_delay < listen_s[busy]
    return (np.concatenate([shot, busy[crossed]]), np.concatenate([delay, busy_delay[crossed]]))


@register
class Sunlight(Effect):
    """Sunlight on the target and in the receiver: false returns, extra noise, blinding."""

    name = 'sunlight'
    bounds = {'background_scale': (0.0, 30.0)}
    initial = {'background_scale': 1.0}

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        background_scale: float = Field(
            1.0, ge=0.0, le=MAX_BACKGROUND_SCALE, description='receiver factor multiplying every background power (-); '
                                     'band-pass x field of view x transmission relative to the '
                                     "sensor's receiver section")

    def __init__(self, params=None):
        super().__init__(params)
        self._cached: tuple[ReturnContext, Background | None] | None = None

    def background(self, ctx: ReturnContext) -> Background | None:
        """``background_of(ctx)`` with this effect's scale, computed once per context."""
        if self._cached is None or self._cached[0] is not ctx:
            self._cached = (ctx, background_of(ctx, self.params.background_scale))
        return self._cached[1]

    def range_sigma_m(self, ctx: ReturnContext) -> np.ndarray | float:
        bg = self.background(ctx)
        if bg is None or ctx.scene.sensor.receiver.detector != 'linear':
            return 0.0
        # Only the noise the background adds (Table 2's sigma already holds the dark noise),
        # so only hits with some background get any.
        lit = np.flatnonzero(ctx.hit & (bg.power_w > 0))
        extra = np.sqrt(np.clip(bg.noise_sigma_w.take(lit) ** 2 - bg.dark_sigma_w ** 2, 0.0, None))
        jitter = np.zeros(len(ctx))
        jitter[lit] = rad.timing_jitter_range_m(extra, ctx.power_w.take(lit),
                                                ctx.scene.sensor.receiver.bandwidth_hz)
        return jitter

    def false_returns(self, ctx: ReturnContext, rng: np.random.Generator):
        bg = self.background(ctx)
        if bg is None:
            return None
        det = ctx.scene.sensor.detection
        shots, delay_s = first_crossings(bg.rate_hz, np.where(bg.blinded, 0.0, bg.listen_s), rng)
        mask = bg.blinded.copy()
        mask[shots] = True
        range_m = np.full(len(ctx), np.nan)      # NaN under the mask: blinded, no return
        range_m[shots] = det.min_range_m + 0.5 * rad.SPEED_OF_LIGHT_M_S * delay_s
        return mask, range_m

    def outlier_fraction(self, ctx: ReturnContext) -> np.ndarray | float:
        bg = self.background(ctx)
        if bg is None:
            return 0.0
        p = np.where(bg.blinded, 1.0, bg.false_return_probability)
        return np.minimum(p, MAX_OUTLIER_FRACTION)
