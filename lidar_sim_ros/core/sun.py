"""Where the light comes from at each shot's time: the sun, the Earth, empty space.

A *sun source* answers ``at(t_abs_s) -> Illumination`` (like a pose source answers
``at(t) -> Poses``): the scenario's sun turning at an orbit rate (offline runs), a fixed
direction (the node, from a parameter or a topic), or a recorded track (a bag's
``/sun/direction``). All directions are unit vectors in the lidar frame.

The Earth (optional) is a Lambertian disk of angular radius rho_E in direction e. Its
spectral radiance is that of the sub-sensor point,

    L_E = albedo E_sun cos(z) / pi,  cos(z) = -e . s     (z: solar zenith angle there)

(an approximation: the whole visible disk takes the sub-point's illumination). The sun is
eclipsed while it lies behind the Earth disk: s . e > cos(rho_E) (umbra only, no penumbra).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.config import SunConfig
from lidar_sim_ros.core.radiometry import unit


@dataclass(frozen=True)
class Illumination:
    """The light sources for N shots (lidar frame).

    sun_direction (N, 3): unit vectors toward the sun; sun_irradiance_w_m2_nm (N,):
    solar spectral irradiance reaching the scene (0 in eclipse); earth_direction (3,) or
    None; earth_angular_radius_rad; earth_radiance_w_m2_sr_nm (N,): the Earth's spectral
    radiance (0 without an Earth); deep_space_radiance_w_m2_sr_nm: empty sky.
    """

    sun_direction: np.ndarray
    sun_irradiance_w_m2_nm: np.ndarray
    earth_direction: np.ndarray | None = None
    earth_angular_radius_rad: float = 0.0
    earth_radiance_w_m2_sr_nm: np.ndarray | None = None
    deep_space_radiance_w_m2_sr_nm: float = 0.0

    def __len__(self) -> int:
        return len(self.sun_direction)

    def subset(self, mask: np.ndarray) -> 'Illumination':
        return Illumination(self.sun_direction[mask], self.sun_irradiance_w_m2_nm[mask],
                            self.earth_direction, self.earth_angular_radius_rad,
                            None if self.earth_radiance_w_m2_sr_nm is None
                            else self.earth_radiance_w_m2_sr_nm[mask],
                            self.deep_space_radiance_w_m2_sr_nm)


class SunSource(Protocol):
    """Anything that gives the illumination at absolute times (s)."""

    config: SunConfig

    def at(self, t_s: np.ndarray) -> Illumination: ...


def illumination(config: SunConfig, sun_direction: np.ndarray) -> Illumination:
    """The scene's light for per-shot unit sun directions (N, 3): eclipse and the Earth's radiance."""
    s = np.atleast_2d(sun_direction)
    e_sun = np.full(len(s), config.spectral_irradiance_w_m2_nm)
    earth = config.earth
    if earth is None:
        return Illumination(s, e_sun, deep_space_radiance_w_m2_sr_nm=config.deep_space_radiance_w_m2_sr_nm)
    e = np.asarray(earth.direction, float)
    rho = np.radians(earth.angular_radius_deg)
    cos_se = s @ e
    eclipsed = cos_se > np.cos(rho)
    radiance = earth.albedo * config.spectral_irradiance_w_m2_nm * np.clip(-cos_se, 0.0, None) / np.pi
    return Illumination(s, np.where(eclipsed, 0.0, e_sun), e, float(rho), radiance,
                        config.deep_space_radiance_w_m2_sr_nm)


@dataclass(frozen=True)
class ScenarioSun:
    """The scenario's sun: ``direction`` at time ``epoch_s``, turning about ``orbit_axis``
    at ``orbit_rate_dps`` (the apparent motion of the sun seen from an orbiting chaser whose
    frame follows the local vertical)."""

    config: SunConfig
    epoch_s: float = 0.0

    def direction_at(self, t_s: np.ndarray) -> np.ndarray:
        """Unit vectors (N, 3) toward the sun at absolute times t_s (s)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        d0 = np.asarray(self.config.direction, float)
        rate = np.radians(self.config.orbit_rate_dps)
        if rate == 0.0:
            return np.broadcast_to(d0, (len(t), 3))  # read-only view: no copy per frame
        rot = Rotation.from_rotvec(np.outer(rate * (t - self.epoch_s), self.config.orbit_axis))
        return rot.apply(d0)

    def at(self, t_s: np.ndarray) -> Illumination:
        return illumination(self.config, self.direction_at(t_s))

    def with_direction(self, direction) -> 'ScenarioSun':
        """The same sun, fixed at a new direction (lidar frame; normalised)."""
        cfg = self.config.model_validate({**self.config.model_dump(), 'direction': tuple(direction),
                                          'orbit_rate_dps': 0.0})
        return ScenarioSun(cfg, self.epoch_s)


@dataclass(frozen=True)
class SunTrack:
    """Sun directions sampled at times (e.g. a recording's ``/sun/direction``), interpolated
    linearly and renormalised; held constant outside the samples."""

    config: SunConfig
    t_s: np.ndarray
    directions: np.ndarray

    def __post_init__(self):
        if len(self.t_s) == 0 or len(self.t_s) != len(self.directions):
            raise ValueError('a sun track needs as many directions as times, at least one')
        if np.any(np.diff(self.t_s) < 0):
            raise ValueError('sun track times must be sorted')

    def at(self, t_s: np.ndarray) -> Illumination:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        d = np.column_stack([np.interp(t, self.t_s, self.directions[:, k]) for k in range(3)])
        return illumination(self.config, unit(d))
