"""Scan model (paper Sec. 3): when and where every shot of one frame points.

Angles follow REP-103 in the lidar frame (x forward, y left, z up): azimuth is
measured from +x toward +y, elevation from the x-y plane toward +z.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar_sim_ros.core.config import (MAX_LASERS, MAX_SHOTS_PER_FRAME, ConfigError, FileScan,
                                       FlashScan, LissajousArrayScan, RisleyScan, RotatingScan,
                                       SensorConfig)
from lidar_sim_ros.core.shots import Shots, angles_from_directions, directions_from_angles


@dataclass(frozen=True)
class LissajousLaser:
    """Per-laser Lissajous parameters (rad, Hz) resolved from a LissajousArrayScan."""

    center_az_rad: np.ndarray
    center_el_rad: np.ndarray
    amp_az_rad: np.ndarray
    amp_el_rad: np.ndarray
    freq_az_hz: np.ndarray
    freq_el_hz: np.ndarray
    phase_az_rad: np.ndarray
    phase_el_rad: np.ndarray


def lissajous_lasers(cfg: LissajousArrayScan) -> LissajousLaser:
    """Resolve the tiles_az x tiles_el array (laser = row * tiles_az + col, row 0 at the top)."""
    n = cfg.tiles_az * cfg.tiles_el
    tile_w = cfg.fov_az_deg / cfg.tiles_az
    tile_h = cfg.fov_el_deg / cfg.tiles_el
    col = np.arange(n) % cfg.tiles_az
    row = np.arange(n) // cfg.tiles_az
    base = {
        # column 0 on the right (most negative azimuth) like a raster seen from behind
        'center_az_deg': -cfg.fov_az_deg / 2 + (col + 0.5) * tile_w,
        'center_el_deg': cfg.fov_el_deg / 2 - (row + 0.5) * tile_h,
        'amp_az_deg': np.full(n, tile_w / 2 * (1.0 + cfg.overlap)),
        'amp_el_deg': np.full(n, tile_h / 2 * (1.0 + cfg.overlap)),
        'freq_az_hz': np.full(n, cfg.freq_az_hz),
        'freq_el_hz': np.full(n, cfg.freq_el_hz),
        'phase_az_rad': cfg.phase_az_rad + cfg.phase_step_rad * np.arange(n),
        'phase_el_rad': np.full(n, cfg.phase_el_rad),
    }
    base = {k: np.asarray(v, dtype=float).copy() for k, v in base.items()}
    for i, override in enumerate(cfg.lasers or []):
        for key, value in override.model_dump(exclude_none=True).items():
            base[key][i] = value
    return LissajousLaser(
        center_az_rad=np.radians(base['center_az_deg']),
        center_el_rad=np.radians(base['center_el_deg']),
        amp_az_rad=np.radians(base['amp_az_deg']),
        amp_el_rad=np.radians(base['amp_el_deg']),
        freq_az_hz=base['freq_az_hz'], freq_el_hz=base['freq_el_hz'],
        phase_az_rad=base['phase_az_rad'], phase_el_rad=base['phase_el_rad'])


def lissajous_angles(lasers: LissajousLaser, laser: np.ndarray,
                     t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pointing (rad) of ``laser`` at time ``t_s`` since frame start."""
    az = lasers.center_az_rad[laser] + lasers.amp_az_rad[laser] * np.sin(
        2 * np.pi * lasers.freq_az_hz[laser] * t_s + lasers.phase_az_rad[laser])
    el = lasers.center_el_rad[laser] + lasers.amp_el_rad[laser] * np.sin(
        2 * np.pi * lasers.freq_el_hz[laser] * t_s + lasers.phase_el_rad[laser])
    return az, el


def lissajous_array_shots(cfg: LissajousArrayScan, frame_period_s: float) -> Shots:
    """Shots of a tiled Lissajous scanner; lasers fire round-robin at a uniform rate."""
    lasers = lissajous_lasers(cfg)
    n_lasers = cfg.tiles_az * cfg.tiles_el
    n = cfg.shots_per_laser * n_lasers
    k = np.arange(n)
    t = k * (frame_period_s / n)
    laser = (k % n_lasers).astype(np.uint16)
    az, el = lissajous_angles(lasers, laser, t)
    return Shots(t, az, el, laser)


def rotating_shots(cfg: RotatingScan, frame_period_s: float) -> Shots:
    """Shots of a spinning multi-beam sensor: all beams fire together at each azimuth step."""
    n_beams = len(cfg.elevations_deg)
    step = np.arange(cfg.shots_per_beam)
    t_step = step * (frame_period_s / cfg.shots_per_beam)
    az_step = np.radians(cfg.az_min_deg + (cfg.az_max_deg - cfg.az_min_deg) * step / cfg.shots_per_beam)
    t = np.repeat(t_step, n_beams)
    az = np.repeat(az_step, n_beams)
    el = np.tile(np.radians(cfg.elevations_deg), cfg.shots_per_beam)
    laser = np.tile(np.arange(n_beams, dtype=np.uint16), cfg.shots_per_beam)
    return Shots(t, az, el, laser)


def file_shots(cfg: FileScan, frame_period_s: float, base: Path | None = None) -> Shots:
    """Shots read from CSV (header t_s,az_deg,el_deg,laser) or .npy with those columns."""
    path = Path(cfg.path)
    if not path.is_absolute() and base is not None:
        path = base / path
    if not path.is_file():
        raise ConfigError(path, 'scan.path', cfg.path, 'scan pattern file not found')
    if path.suffix == '.npy':
        try:   # memory-mapped: the shape is checked before anything is read
            data = np.load(path, mmap_mode='r', allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise ConfigError(path, 'scan.path', cfg.path, f'not a readable .npy file: {exc}') from None
        if data.ndim and len(data) > MAX_SHOTS_PER_FRAME:
            raise ConfigError(path, 'shape', list(data.shape),
                              f'more shots than the limit of {MAX_SHOTS_PER_FRAME}')
        if data.dtype.names:
            missing = {'t_s', 'az_deg', 'el_deg', 'laser'} - set(data.dtype.names)
            if missing or data.ndim != 1:
                raise ConfigError(path, 'columns', data.dtype.names,
                                  f'a 1-D record array with t_s, az_deg, el_deg, laser '
                                  f'(missing {sorted(missing)}, shape {data.shape})')
            cols = {name: data[name] for name in data.dtype.names}
        elif data.ndim != 2 or data.shape[1] < 4 or data.dtype.kind not in 'iuf':
            raise ConfigError(path, 'shape', list(data.shape),
                              f'a scan .npy holds an (N, 4) number array (t_s, az_deg, el_deg, '
                              f'laser columns) or a record array; this is {data.ndim}-D '
                              f'{data.dtype}')
        else:
            cols = {name: data[:, i] for i, name in enumerate(('t_s', 'az_deg', 'el_deg', 'laser'))}
    else:
        data = np.genfromtxt(path, delimiter=',', names=True)
        missing = {'t_s', 'az_deg', 'el_deg', 'laser'} - set(data.dtype.names or ())
        if missing:
            raise ConfigError(path, 'columns', data.dtype.names, f'missing columns {sorted(missing)}')
        cols = {name: np.atleast_1d(data[name]) for name in data.dtype.names}
    t = np.asarray(cols['t_s'], dtype=float)
    if np.any(~np.isfinite(t)) or np.any(t < 0) or np.any(t >= frame_period_s):
        raise ConfigError(path, 't_s', float(np.nanmax(t)),
                          f'shot times must lie in [0, frame period {frame_period_s:g} s)')
    if len(t) > MAX_SHOTS_PER_FRAME:
        raise ConfigError(path, 't_s', len(t), f'more shots than the limit of {MAX_SHOTS_PER_FRAME}')
    az, el = (np.asarray(cols[c], dtype=float) for c in ('az_deg', 'el_deg'))
    for name, v in (('az_deg', az), ('el_deg', el)):
        bad = ~np.isfinite(v)
        if bad.any():
            raise ConfigError(path, name, float(v[bad][0]), 'angles must be finite (deg)')
    laser = np.asarray(cols['laser'], dtype=float)
    bad = ~np.isfinite(laser) | (laser != np.round(laser)) | (laser < 0) | (laser >= MAX_LASERS)
    if bad.any():
        raise ConfigError(path, 'laser', float(laser[bad][0]),
                          f'laser ids must be whole numbers in [0, {MAX_LASERS}) '
                          f'({int(bad.sum())} row(s))')
    order = np.argsort(t, kind='stable')
    return Shots(t[order], np.radians(az)[order], np.radians(el)[order],
                 laser.astype(np.uint16)[order])


def frame_shots(sensor: SensorConfig, base: Path | None = None, frame_index: int = 0) -> Shots:
    """All shots of one frame for the configured scan pattern; ``frame_index`` matters only
    to a pattern that does not repeat every frame (``varies_by_frame``: the Risley rosette)."""
    scan = sensor.scan
    if isinstance(scan, LissajousArrayScan):
        return lissajous_array_shots(scan, sensor.frame_period_s)
    if isinstance(scan, RotatingScan):
        return rotating_shots(scan, sensor.frame_period_s)
    if isinstance(scan, RisleyScan):
        from lidar_sim_ros.core.scan_risley import risley_shots
        return risley_shots(scan, sensor.frame_period_s, frame_index)
    if isinstance(scan, FlashScan):
        from lidar_sim_ros.core.scan_flash import flash_shots
        return flash_shots(scan, sensor.frame_period_s)
    return file_shots(scan, sensor.frame_period_s, base)


def frame_shots_and_directions(sensor: SensorConfig, base: Path | None = None,
                               frame_index: int = 0) -> tuple[Shots, np.ndarray]:
    """``frame_shots`` and their unit directions (N, 3); a rosette computes its directions
    first, so a frame's shots cost one trigonometric pass, not two."""
    if isinstance(sensor.scan, RisleyScan):
        from lidar_sim_ros.core.scan_risley import risley_frame
        return risley_frame(sensor.scan, sensor.frame_period_s, frame_index)
    shots = frame_shots(sensor, base, frame_index)
    return shots, shots.directions()


def varies_by_frame(sensor: SensorConfig) -> bool:
    """Whether each frame has its own shots (a non-repeating rosette) rather than one
    pattern every frame."""
    return isinstance(sensor.scan, RisleyScan)
