"""Flash LiDAR scan: a rows x cols focal-plane array, every pixel in one exposure.

The pixels sit behind a pinhole lens: pixel (row r, col c) looks along
(1, u_c, v_r) / |(1, u_c, v_r)| with, in the tangent plane one unit in front,

    u_c = tan(fov_az / 2) (1 - 2 (c + 1/2) / cols)     (col 0 at +y, left)
    v_r = tan(fov_el / 2) (1 - 2 (r + 1/2) / rows)     (row 0 at +z, top)

and covers the rectangle du x dv = 2 tan(fov_az/2)/cols x 2 tan(fov_el/2)/rows there.
Its own field of view is that rectangle's solid angle, exactly (``pixel_solid_angle_sr``):
the pixels at the edge of a wide field see less than those in the middle (about
cos^3 of their angle off the axis). Every pixel of a frame is exposed by the same pulse
at the frame start; a sensor read row by row gives row r the time r x row_readout_s.
The laser id of a pixel is its row.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.core.config import FlashScan, SensorConfig
from lidar_sim_ros.core.shots import Shots, angles_from_directions


def pixel_pitch(cfg: FlashScan) -> tuple[float, float]:
    """(du, dv): a pixel's width and height on the tangent plane one unit ahead (-)."""
    return (2.0 * np.tan(np.radians(cfg.fov_az_deg) / 2.0) / cfg.cols,
            2.0 * np.tan(np.radians(cfg.fov_el_deg) / 2.0) / cfg.rows)


def pixel_tangents(cfg: FlashScan) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of every pixel centre (rows * cols each, row-major: index r * cols + c)."""
    du, dv = pixel_pitch(cfg)
    u = (cfg.cols / 2.0 - (np.arange(cfg.cols) + 0.5)) * du
    v = (cfg.rows / 2.0 - (np.arange(cfg.rows) + 0.5)) * dv
    return np.tile(u, cfg.rows), np.repeat(v, cfg.cols)


def flash_shots(cfg: FlashScan, frame_period_s: float) -> Shots:
    """One frame: every pixel, row-major (row 0 first), at r x row_readout_s."""
    u, v = pixel_tangents(cfg)
    directions = np.stack([np.ones_like(u), u, v], axis=-1)
    az, el = angles_from_directions(directions)
    row = np.repeat(np.arange(cfg.rows), cfg.cols)
    return Shots(row * cfg.row_readout_s, az, el, row.astype(np.uint16))


def rectangle_solid_angle_sr(u0, u1, v0, v1) -> np.ndarray:
    """Solid angle (sr) of the rectangle [u0, u1] x [v0, v1] on the plane x = 1 seen from
    the origin: F(u1, v1) - F(u0, v1) - F(u1, v0) + F(u0, v0), F = atan(u v / sqrt(1 + u^2 + v^2))."""
    def f(u, v):
        return np.arctan(u * v / np.sqrt(1.0 + u * u + v * v))
    return f(u1, v1) - f(u0, v1) - f(u1, v0) + f(u0, v0)


def pixel_solid_angle_sr(cfg: FlashScan, directions: np.ndarray) -> np.ndarray:
    """Each direction's pixel field of view (sr): the pixel rectangle centred on it."""
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    x = np.where(d[:, 0] > 0, d[:, 0], np.nan)      # behind the lens: no pixel
    u, v = d[:, 1] / x, d[:, 2] / x
    du, dv = pixel_pitch(cfg)
    out = rectangle_solid_angle_sr(u - du / 2, u + du / 2, v - dv / 2, v + dv / 2)
    return np.nan_to_num(out, nan=0.0)


def in_field(full_az_deg: float, full_el_deg: float, directions: np.ndarray) -> np.ndarray:
    """Bool per direction: inside the rectangular field of full angles az x el about +x."""
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    x = np.where(d[:, 0] > 0, d[:, 0], np.nan)
    with np.errstate(invalid='ignore'):
        return ((np.abs(d[:, 1] / x) <= np.tan(np.radians(full_az_deg) / 2.0) * (1 + 1e-9))
                & (np.abs(d[:, 2] / x) <= np.tan(np.radians(full_el_deg) / 2.0) * (1 + 1e-9)))


def pixel_view_sr(sensor: SensorConfig, directions: np.ndarray) -> np.ndarray | None:
    """Per direction, the solid angle (sr) of the pixel that sees the flood-lit surface
    there (0 off the flood's field: no laser light), for ``reflection.return_power_w``;
    None for a sensor that fires a beam per shot."""
    if not isinstance(sensor.scan, FlashScan) or sensor.optics.flood is None:
        return None
    flood = sensor.optics.flood
    lit = in_field(flood.field_az_deg, flood.field_el_deg, directions)
    return np.where(lit, pixel_solid_angle_sr(sensor.scan, directions), 0.0)
