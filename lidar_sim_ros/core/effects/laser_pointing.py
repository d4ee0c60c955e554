"""Laser pointing: each laser's beam leaves a little off its configured direction.

A multi-laser sensor (the P-60 fires 24 lasers, one per Lissajous tile) steers every
laser through its own emitter and optics; what the factory calibration leaves of their
alignment is a fixed angular offset per laser. The sensor does not know it: it reports
each point along the NOMINAL (configured) direction, at the range measured along the
TRUE beam:

    true direction = direction(az + az_offsets_deg[laser], el + el_offsets_deg[laser])
    point          = nominal direction * range measured along the true direction

(0 for a laser beyond the lists; azimuth and elevation as ``core/shots.py`` defines them,
in degrees). The range a shot measures is then the range of a neighbouring spot of the
surface: on a plane at range r and incidence theta, to first order

    range error = r tan(theta) * (offset along the surface's slope direction, rad)

so it grows at grazing incidence and with range, changes sign with the laser, and is
zero head-on. ``lidar-sim calibrate scan`` cannot see it (the point directions are the
nominal ones). The offsets are two free parameters per laser; ``compare/model/fit.py``
fits them through the range gradient across the surface (linear in the offsets).
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from lidar_sim_ros.core.config import MAX_LASERS
from lidar_sim_ros.core.effects import register
from lidar_sim_ros.core.effects.base import Effect
from lidar_sim_ros.core.shots import angles_from_directions, directions_from_angles

# Physical limit (docs/effects.md, "Parameter bounds"): a beam 5 deg off its direction
# lies in another laser's tile; no calibration leaves that.
MAX_OFFSET_DEG = 5.0
FIT_OFFSET_DEG = 1.0      # the search box a fit keeps to


def per_shot_deg(offsets_deg: list[float], laser: np.ndarray) -> np.ndarray:
    """``offsets_deg[laser]`` per shot (deg), 0 for a laser beyond the list."""
    off = np.asarray(offsets_deg, float)
    laser = np.asarray(laser, np.int64)
    if not len(off) or not len(laser):
        return np.zeros(len(laser))
    inside = (laser >= 0) & (laser < len(off))
    return np.where(inside, off[np.clip(laser, 0, len(off) - 1)], 0.0)


def offset_directions(directions: np.ndarray, laser: np.ndarray, az_offsets_deg: list[float],
                      el_offsets_deg: list[float]) -> np.ndarray:
    """Unit directions (N, 3) of ``directions`` (lidar frame) turned by each shot's laser's
    azimuth and elevation offsets (deg): the directions the beams really leave along."""
    az, el = angles_from_directions(directions)
    return directions_from_angles(az + np.radians(per_shot_deg(az_offsets_deg, laser)),
                                  el + np.radians(per_shot_deg(el_offsets_deg, laser)))


def _bounded(v: list[float]) -> list[float]:
    bad = [x for x in v if not np.isfinite(x) or abs(x) > MAX_OFFSET_DEG]
    if bad:
        raise ValueError(f'offsets must be finite and within +-{MAX_OFFSET_DEG} deg, got {bad[:3]}')
    return v


@register
class LaserPointing(Effect):
    """Each laser's beam off its configured direction by (az_offsets_deg[laser],
    el_offsets_deg[laser]) deg; points are reported along the configured direction."""

    name = 'laser_pointing'
    # One bound per element (the generic fit never runs: compare/model/fit.py registers
    # its own; the comparison reads ``bounds`` to know which parameters are fitted).
    bounds = {'az_offsets_deg': (-FIT_OFFSET_DEG, FIT_OFFSET_DEG),
              'el_offsets_deg': (-FIT_OFFSET_DEG, FIT_OFFSET_DEG)}
    needs_repredict = True     # it moves the rays: the comparison casts them again

    class Params(BaseModel):
        model_config = ConfigDict(extra='forbid')
        az_offsets_deg: list[float] = Field(
            default_factory=list, max_length=MAX_LASERS,
            description='azimuth offset (deg) of laser i\'s beam, i = list index')
        el_offsets_deg: list[float] = Field(
            default_factory=list, max_length=MAX_LASERS,
            description='elevation offset (deg) of laser i\'s beam, i = list index')

        @field_validator('az_offsets_deg', 'el_offsets_deg')
        @classmethod
        def _finite_and_bounded(cls, v: list[float]) -> list[float]:
            return _bounded(v)

        @model_validator(mode='after')
        def _same_length(self) -> 'LaserPointing.Params':
            a, e = len(self.az_offsets_deg), len(self.el_offsets_deg)
            if a and e and a != e:
                raise ValueError(f'az_offsets_deg has {a} values, el_offsets_deg {e}: one pair '
                                 'per laser')
            return self

    def beam_directions(self, directions_lidar: np.ndarray, laser: np.ndarray) -> np.ndarray | None:
        p = self.params
        if not any(p.az_offsets_deg) and not any(p.el_offsets_deg):
            return None
        return offset_directions(directions_lidar, laser, p.az_offsets_deg, p.el_offsets_deg)

    def rms_offset_deg(self) -> float:
        """RMS over the lasers of the beam's angle off its configured direction (deg),
        sqrt(mean(az^2 cos^2 el + el^2)) with el ~ 0: sqrt(mean(az^2 + el^2))."""
        a = np.asarray(self.params.az_offsets_deg, float)
        e = np.asarray(self.params.el_offsets_deg, float)
        n = max(len(a), len(e))
        if n == 0:
            return 0.0
        a, e = np.pad(a, (0, n - len(a))), np.pad(e, (0, n - len(e)))
        return float(np.sqrt(np.mean(a ** 2 + e ** 2)))
