"""One frame's shots (time, pointing, laser) and the angle <-> direction conversions every
scan pattern shares (``scan.py`` and the rosette's and flash array's own modules)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Shots:
    """One frame's shots, in firing order.

    t_s: time since frame start (s); az_rad, el_rad: pointing (rad); laser: laser id.
    """

    t_s: np.ndarray
    az_rad: np.ndarray
    el_rad: np.ndarray
    laser: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)

    def directions(self) -> np.ndarray:
        """Unit pointing vectors (N, 3) in the lidar frame."""
        return directions_from_angles(self.az_rad, self.el_rad)

    def subset(self, mask: np.ndarray) -> 'Shots':
        return Shots(self.t_s[mask], self.az_rad[mask], self.el_rad[mask], self.laser[mask])


def directions_from_angles(az_rad: np.ndarray, el_rad: np.ndarray) -> np.ndarray:
    """Unit vectors (N, 3) from azimuth/elevation (rad)."""
    cos_el = np.cos(el_rad)
    return np.stack([cos_el * np.cos(az_rad), cos_el * np.sin(az_rad), np.sin(el_rad)], axis=-1)


def angles_from_directions(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad) of vectors (N, 3); they need not be unit length."""
    dirs = np.asarray(dirs, dtype=float)
    az = np.arctan2(dirs[:, 1], dirs[:, 0])
    el = np.arctan2(dirs[:, 2], np.hypot(dirs[:, 0], dirs[:, 1]))
    return az, el
