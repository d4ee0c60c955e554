"""Scan pattern from measured data: per-laser Lissajous parameters (paper Sec. 3, Figs. 5-6).

The model (``core/scan.py``): laser i points at
``az = c_az + A_az sin(2 pi f_az t + phi_az)``, ``el`` likewise, with t the time
since frame start; the lasers fire round-robin, shot k of a frame at
t = k T / N by laser k mod n_lasers. Each laser's azimuth and elevation are
fitted separately: frequency from the periodogram (FFT) of angle vs time (the
points of all frames pooled on the frame clock; missing shots are fine), then
centre, amplitude, frequency and phase by nonlinear least squares started from
the highest periodogram peaks. Points without a
``ring`` field are first assigned to lasers: by tile of the tiles_az x tiles_el
grid, then by which fitted curve passes nearest at the point's time.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import optimize

from lidar_sim_ros.calibrate.common import (AngularErrorSummary, CalibrationInputError,
                                            check_fit_rms, format_table, new_figure, save_figure,
                                            sig, write_sensor)
from lidar_sim_ros.calibrate.scan_samples import ScanSamples, read_scan_samples
from lidar_sim_ros.core.config import LissajousArrayScan, RisleyScan, load_sensor, read_yaml
from lidar_sim_ros.core.scan import (LissajousLaser, directions_from_angles, frame_shots,
                                     lissajous_angles, lissajous_lasers)
from lidar_sim_ros.io.bag import CLOUD_TOPIC
from lidar_sim_ros.paths import config_path

MIN_POINTS_PER_LASER = 40
_OUTLIER_SIGMAS = 6.0
_ASSIGN_ITERATIONS = 10


# ---------------------------------------------------------------- one sine
@dataclass(frozen=True)
class SineFit:
    """y = center + amp sin(2 pi freq_hz t + phase_rad); rms of the residual (units of y)."""

    center: float
    amp: float
    freq_hz: float
    phase_rad: float
    rms: float
    n_used: int
    n_outliers: int

    def __call__(self, t_s: np.ndarray) -> np.ndarray:
        return self.center + self.amp * np.sin(2 * np.pi * self.freq_hz * t_s + self.phase_rad)


def _linear_sine(t, y, f):
    """Centre and (sin, cos) amplitudes at fixed frequency by linear least squares."""
    w = 2 * np.pi * f * t
    a = np.column_stack([np.ones_like(t), np.sin(w), np.cos(w)])
    (c, s, k), *_ = np.linalg.lstsq(a, y, rcond=None)
    return c, float(np.hypot(s, k)), float(np.arctan2(k, s))


def _local_maxima(freqs: np.ndarray, power: np.ndarray, f_min_hz: float, f_max_hz: float,
                  count: int) -> np.ndarray:
    peak = np.zeros(len(power), dtype=bool)
    peak[1:-1] = (power[1:-1] >= power[:-2]) & (power[1:-1] > power[2:])
    peak &= (freqs >= f_min_hz) & (freqs <= f_max_hz)
    if not peak.any():
        return np.array([float(f_min_hz)])
    cand = np.flatnonzero(peak)
    return freqs[cand[np.argsort(power[cand])[::-1][:count]]]


def _sine_fit_power(t: np.ndarray, y: np.ndarray, freqs: np.ndarray) -> np.ndarray:
    """Fraction of the variance a sine of each frequency (with free offset) explains."""
    y = y - y.mean()
    n, yy = len(t), float(y @ y)
    w = 2 * np.pi * freqs[:, None] * t[None, :]
    s, c = np.sin(w), np.cos(w)
    a = np.empty((len(freqs), 3, 3))
    a[:, 0, 0] = n
    a[:, 0, 1] = a[:, 1, 0] = s.sum(1)
    a[:, 0, 2] = a[:, 2, 0] = c.sum(1)
    a[:, 1, 1] = (s * s).sum(1)
    a[:, 2, 2] = n - a[:, 1, 1]
    a[:, 1, 2] = a[:, 2, 1] = (s * c).sum(1)
    b = np.stack([np.zeros(len(freqs)), s @ y, c @ y], axis=1)
    x = np.linalg.solve(a + 1e-9 * np.eye(3), b[..., None])[..., 0]
    return np.einsum('ij,ij->i', b, x) / max(yy, 1e-300)


def periodogram_peaks_hz(t_s: np.ndarray, y: np.ndarray, f_min_hz: float, f_max_hz: float,
                         count: int = 6) -> np.ndarray:
    """The ``count`` highest periodogram peaks in [f_min_hz, f_max_hz], highest first.

    Samples at identical times (the same shot in several frames) are averaged.
    Densely sampled data (most shots present on the shot-spacing grid): FFT of
    the gridded samples, zero-padded to 1/8 of the resolution. Sparse data (a
    laser's points gated to part of its tile): the least-squares sine fit at
    each frequency (generalised Lomb-Scargle), which gaps do not fool. Several
    peaks, not one: with gaps the harmonics can outgrow the fundamental.
    """
    tu, inv = np.unique(np.round(t_s, 9), return_inverse=True)
    yu = np.bincount(inv, weights=y) / np.bincount(inv)
    span = max(float(tu[-1] - tu[0]), 1e-9)
    dt = float(np.median(np.diff(tu))) if len(tu) > 1 else 1.0
    idx = np.round((tu - tu[0]) / dt).astype(int)
    if len(tu) >= 0.5 * (idx[-1] + 1):
        grid = np.zeros(idx[-1] + 1)
        grid[idx] = yu - yu.mean()
        nfft = 1 << int(np.ceil(np.log2(8 * len(grid))))
        power = np.abs(np.fft.rfft(grid, nfft)) ** 2
        return _local_maxima(np.fft.rfftfreq(nfft, dt), power, f_min_hz, f_max_hz, count)
    freqs = np.arange(f_min_hz, f_max_hz, 1.0 / (8 * span))
    power = np.concatenate([_sine_fit_power(tu, yu, chunk)
                            for chunk in np.array_split(freqs, max(1, len(freqs) * len(tu) // 500_000))])
    return _local_maxima(freqs, power, f_min_hz, f_max_hz, count)


def fit_sine(t_s: np.ndarray, y: np.ndarray, f_min_hz: float, f_max_hz: float,
             start_hz: float | None = None) -> SineFit:
    """Least squares of (centre, amplitude, frequency, phase) from the periodogram peaks.

    Each of the highest periodogram peaks (or ``start_hz`` alone, when refining a
    known fit) is a starting point; the lowest cost wins. Gross outliers (beyond
    6 robust sigmas) are dropped once and the fit repeated from the winner.
    """
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y, dtype=float)
    span = max(float(t.max() - t.min()), 1e-9)
    starts = [start_hz] if start_hz else list(periodogram_peaks_hz(t, y, f_min_hz, f_max_hz))
    keep = np.ones(len(t), dtype=bool)
    best = None
    for _ in range(2):
        tt, yy = t[keep], y[keep]

        def resid(x, tt=tt, yy=yy):
            return x[0] + x[1] * np.sin(2 * np.pi * x[2] * tt + x[3]) - yy

        best = None
        for f in starts:
            c, amp, ph = _linear_sine(tt, yy, f)
            scale = max(amp, 1e-6)
            res = optimize.least_squares(resid, [c, amp, f, ph], method='lm',
                                         x_scale=[scale, scale, 1.0 / span, 1.0])
            if best is None or res.cost < best.cost:
                best = res
        r = resid(best.x, t, y)
        sigma = 1.4826 * np.median(np.abs(r[keep] - np.median(r[keep])))
        outliers = np.abs(r) > _OUTLIER_SIGMAS * sigma + 1e-12
        if not outliers.any() or np.array_equal(~outliers, keep):
            break
        keep = ~outliers
        starts = [best.x[2]]
    c, amp, f, ph = best.x
    if amp < 0:
        amp, ph = -amp, ph + np.pi
    r = resid(best.x, t[keep], y[keep])
    return SineFit(float(c), float(amp), float(f), float(np.mod(ph, 2 * np.pi)),
                   float(np.sqrt(np.mean(r ** 2))), int(keep.sum()), int((~keep).sum()))


# --------------------------------------------------------------- all lasers
def _stack(fits_az: list[SineFit], fits_el: list[SineFit]) -> LissajousLaser:
    g = lambda fits, k: np.array([getattr(f, k) for f in fits])  # noqa: E731
    return LissajousLaser(g(fits_az, 'center'), g(fits_el, 'center'), g(fits_az, 'amp'),
                          g(fits_el, 'amp'), g(fits_az, 'freq_hz'), g(fits_el, 'freq_hz'),
                          g(fits_az, 'phase_rad'), g(fits_el, 'phase_rad'))


def _freq_range(t_s: np.ndarray) -> tuple[float, float]:
    """From half a cycle per frame up to the Nyquist frequency of one laser's shot rate."""
    span = max(float(t_s.max() - t_s.min()), 1e-9)
    n_unique = len(np.unique(np.round(t_s, 9)))
    return 0.5 / span, max(0.45 * n_unique / span, 2.0 / span)


def fit_lasers(samples: ScanSamples, laser: np.ndarray, n_lasers: int,
               mask: np.ndarray | None = None, previous: LissajousLaser | None = None,
               fallback: LissajousLaser | None = None
               ) -> tuple[LissajousLaser, list[SineFit], list[SineFit]]:
    """Fit every laser's az and el sines on its points (``mask`` selects a subset).

    ``previous`` fits, if given, start the least squares instead of the periodogram.
    A laser with too few points takes its ``fallback`` parameters (its SineFits
    then have ``n_used = 0``); without a fallback that is an error naming the laser.
    """
    fits_az, fits_el = [], []
    use = np.ones(len(samples), dtype=bool) if mask is None else mask
    for i in range(n_lasers):
        sel = use & (laser == i)
        if sel.sum() < MIN_POINTS_PER_LASER:
            if fallback is None:
                raise CalibrationInputError(
                    f'{samples.source}: laser {i} has {int(sel.sum())} points; at least '
                    f'{MIN_POINTS_PER_LASER} are needed to fit its Lissajous curve (record more '
                    'frames of a target that fills the field of view)')
            fb = fallback
            fits_az.append(SineFit(fb.center_az_rad[i], fb.amp_az_rad[i], fb.freq_az_hz[i],
                                   fb.phase_az_rad[i], float('nan'), 0, 0))
            fits_el.append(SineFit(fb.center_el_rad[i], fb.amp_el_rad[i], fb.freq_el_hz[i],
                                   fb.phase_el_rad[i], float('nan'), 0, 0))
            continue
        t = samples.t_s[sel]
        f_min, f_max = _freq_range(t)
        f_az = None if previous is None else previous.freq_az_hz[i]
        f_el = None if previous is None else previous.freq_el_hz[i]
        fits_az.append(fit_sine(t, samples.az_rad[sel], f_min, f_max, f_az))
        fits_el.append(fit_sine(t, samples.el_rad[sel], f_min, f_max, f_el))
    return _stack(fits_az, fits_el), fits_az, fits_el


def nearest_laser(samples: ScanSamples, lasers: LissajousLaser) -> np.ndarray:
    """For each point, the laser whose curve at the point's time points closest to it."""
    n = len(lasers.center_az_rad)
    best = np.zeros(len(samples), dtype=int)
    best_d = np.full(len(samples), np.inf)
    cos_el = np.cos(samples.el_rad)
    for i in range(n):
        az, el = lissajous_angles(lasers, np.full(len(samples), i), samples.t_s)
        d = ((az - samples.az_rad) * cos_el) ** 2 + (el - samples.el_rad) ** 2
        better = d < best_d
        best[better], best_d[better] = i, d[better]
    return best


def assign_lasers(samples: ScanSamples, tiles_az: int, tiles_el: int,
                  overlap: float = 0.0) -> np.ndarray:
    """Laser ids (row * tiles_az + col, row 0 at the top, col 0 at the most negative azimuth).

    First the tile grid: the data's extent less the curves' overrun at the outer
    edges (``overlap`` of a tile half-width, from the sensor config) split into
    tiles; points in the central 80 % of a tile, clear of the neighbours'
    overrun, seed a fit per laser. Then every point goes to the curve nearest to
    it at its time, and fit and assignment alternate until the assignment settles.
    """
    az_lo, az_hi = samples.az_rad.min(), samples.az_rad.max()
    el_lo, el_hi = samples.el_rad.min(), samples.el_rad.max()
    # extent = tiles * w + 2 * overlap * w / 2 = (tiles + overlap) * w
    w_az = (az_hi - az_lo) / (tiles_az + overlap)
    w_el = (el_hi - el_lo) / (tiles_el + overlap)
    u = (samples.az_rad - az_lo - overlap * w_az / 2) / max(w_az, 1e-12)
    v = (el_hi - overlap * w_el / 2 - samples.el_rad) / max(w_el, 1e-12)
    col = np.clip(np.floor(u), 0, tiles_az - 1).astype(int)
    row = np.clip(np.floor(v), 0, tiles_el - 1).astype(int)
    laser = row * tiles_az + col
    inner = (np.abs(u - col - 0.5) < 0.25) & (np.abs(v - row - 0.5) < 0.25)
    lasers, _, _ = fit_lasers(samples, laser, tiles_az * tiles_el, inner)
    for _ in range(_ASSIGN_ITERATIONS):
        new = nearest_laser(samples, lasers)
        if np.array_equal(new, laser):
            break
        laser = new
        lasers, _, _ = fit_lasers(samples, laser, tiles_az * tiles_el, previous=lasers)
    return laser


def angular_error_deg(samples: ScanSamples, laser: np.ndarray, lasers: LissajousLaser) -> np.ndarray:
    """Angle (deg) between each measured direction and the model's at the same laser and time."""
    az, el = lissajous_angles(lasers, laser, samples.t_s)
    chord = np.linalg.norm(directions_from_angles(az, el) - samples.direction, axis=1)
    return np.degrees(2 * np.arcsin(np.clip(chord / 2, 0.0, 1.0)))


def infer_tiling(lasers: LissajousLaser) -> tuple[int, int] | None:
    """tiles_az x tiles_el from the fitted centres (rows split where el centres jump), or None."""
    el = np.sort(lasers.center_el_rad)
    jump = np.median(lasers.amp_el_rad)
    rows = 1 + int(np.sum(np.diff(el) > jump))
    n = len(el)
    if n % rows:
        return None
    return n // rows, rows


# ------------------------------------------------------------------ output
@dataclass
class ScanCalibration(AngularErrorSummary):
    """The fitted pattern, its error per shot, and the sensor YAML written."""

    samples: ScanSamples
    laser: np.ndarray
    lasers: LissajousLaser
    fits_az: list[SineFit]
    fits_el: list[SineFit]
    tiles: tuple[int, int]
    frame_period_s: float
    shots_per_laser: int
    error_deg: np.ndarray
    prior_error_deg: np.ndarray | None
    sensor_doc: dict
    warnings: list[str] = field(default_factory=list)
    out: Path | None = None
    report: str = ''


def _shots_per_laser(samples: ScanSamples, laser: np.ndarray, period_s: float) -> int | None:
    """Shots per laser per frame: the frame period over one laser's own shot spacing (s),
    median over the lasers (the densest frame of each); None if too sparse to tell.

    Per laser, so the count does not depend on how the lasers share the time line: fired
    round-robin (one laser at a time) or together (every laser at the same instants)."""
    estimates = []
    for i in np.unique(laser):
        sel = laser == i
        frames, counts = np.unique(samples.frame[sel], return_counts=True)
        t = np.unique(np.round(samples.t_s[sel & (samples.frame == frames[np.argmax(counts)])], 9))
        d = np.diff(t)
        if len(d) < 10:
            continue
        dt = float(np.median(d))
        if dt > 0 and np.mean(np.abs(d - dt) < 0.1 * dt) >= 0.5:
            estimates.append(period_s / dt)
    if not estimates:
        return None
    return max(1, int(round(float(np.median(estimates)))))


def _scan_doc(scan: dict, lasers: LissajousLaser, tiles: tuple[int, int], shots: int) -> dict:
    tiles_az, tiles_el = tiles
    c_az, c_el = np.degrees(lasers.center_az_rad), np.degrees(lasers.center_el_rad)
    a_az, a_el = np.degrees(lasers.amp_az_rad), np.degrees(lasers.amp_el_rad)
    # Tile defaults are not used (every laser is overridden) but must describe the array.
    fov_az = (np.ptp(c_az) * tiles_az / (tiles_az - 1)) if tiles_az > 1 else 2 * np.median(a_az)
    fov_el = (np.ptp(c_el) * tiles_el / (tiles_el - 1)) if tiles_el > 1 else 2 * np.median(a_el)
    overlap = max(0.0, float(np.median(a_az / (fov_az / tiles_az / 2))) - 1.0)
    out = dict(scan)
    out.update(type='lissajous_array', fov_az_deg=sig(fov_az), fov_el_deg=sig(fov_el),
               tiles_az=int(tiles_az), tiles_el=int(tiles_el), shots_per_laser=int(shots),
               overlap=sig(overlap, 4), freq_az_hz=sig(np.median(lasers.freq_az_hz), 9),
               freq_el_hz=sig(np.median(lasers.freq_el_hz), 9), phase_az_rad=0.0,
               phase_el_rad=0.0, phase_step_rad=0.0)
    out['lasers'] = [
        {'center_az_deg': sig(c_az[i], 9), 'center_el_deg': sig(c_el[i], 9),
         'amp_az_deg': sig(a_az[i], 9), 'amp_el_deg': sig(a_el[i], 9),
         'freq_az_hz': sig(lasers.freq_az_hz[i], 10), 'freq_el_hz': sig(lasers.freq_el_hz[i], 10),
         'phase_az_rad': sig(lasers.phase_az_rad[i], 9),
         'phase_el_rad': sig(lasers.phase_el_rad[i], 9)}
        for i in range(len(c_az))]
    return out


def calibrate_scan(samples: ScanSamples, sensor_path: str | Path) -> ScanCalibration:
    """Fit the pattern of ``samples``; the sensor config supplies tiling (no ring) and defaults."""
    sensor_path = Path(sensor_path)
    sensor = load_sensor(sensor_path)
    if not isinstance(sensor.scan, LissajousArrayScan):
        raise CalibrationInputError(f'{sensor_path}: scan.type is {sensor.scan.type!r}; '
                                    'calibrate scan fits lissajous_array and risley sensors')
    warnings = []
    period = sensor.frame_period_s
    if samples.frame_period_s is not None:
        if abs(samples.frame_period_s - period) > 0.01 * period:
            warnings.append(f'frame period from the bag stamps {samples.frame_period_s:.6g} s differs '
                            f'from {sensor_path} ({period:.6g} s); using the bag\'s')
            period = samples.frame_period_s
    if samples.t_s.min() < 0 or samples.t_s.max() >= 1.01 * period:
        warnings.append(f'point times span [{samples.t_s.min():.4g}, {samples.t_s.max():.4g}] s, '
                        f'not [0, {period:.4g}) s: the simulator counts time from the frame start, '
                        'so the fitted phases assume the header stamp marks it')
    cfg_tiles = (sensor.scan.tiles_az, sensor.scan.tiles_el)
    n_cfg = cfg_tiles[0] * cfg_tiles[1]
    prior_lasers = lissajous_lasers(sensor.scan)
    if samples.laser is None:
        tiles = cfg_tiles
        laser = assign_lasers(samples, *tiles, sensor.scan.overlap)
        lasers, fits_az, fits_el = fit_lasers(samples, laser, n_cfg)
    elif int(samples.laser.max()) < n_cfg:
        # The config's lasers: those the target did not cover keep the config's curve.
        tiles, laser = cfg_tiles, samples.laser
        lasers, fits_az, fits_el = fit_lasers(samples, laser, n_cfg, fallback=prior_lasers)
        kept = [i for i, f in enumerate(fits_az) if f.n_used == 0]
        if len(kept) == n_cfg:
            raise CalibrationInputError(f'{samples.source}: no laser has {MIN_POINTS_PER_LASER} '
                                        'points; record more frames of a target that fills the '
                                        'field of view')
        if kept:
            warnings.append(f'laser(s) {kept} have fewer than {MIN_POINTS_PER_LASER} points: their '
                            f'curves are kept from {sensor_path}; record a target that fills the '
                            'field of view to fit them')
    else:
        # More lasers than the config knows: all must be there, the tiling comes from the data.
        laser = samples.laser
        n = int(laser.max()) + 1
        lasers, fits_az, fits_el = fit_lasers(samples, laser, n)
        tiles = infer_tiling(lasers)
        if tiles is None:
            tiles = (n, 1)
            warnings.append(f'{n} lasers do not form a grid of rows; written as {n} x 1 tiles')
        else:
            warnings.append(f'the bag has {n} lasers: tiling {tiles[0]} x {tiles[1]} inferred from '
                            f'their centres (the sensor config has {cfg_tiles[0]} x {cfg_tiles[1]})')
    n_lasers = tiles[0] * tiles[1]
    shots = _shots_per_laser(samples, laser, period)
    if shots is None:
        shots = sensor.scan.shots_per_laser
        warnings.append('too few shots detected per frame to measure the shot spacing; '
                        f'shots_per_laser {shots} kept from {sensor_path}')
    error = angular_error_deg(samples, laser, lasers)
    check_fit_rms(error, samples.source, f'the best Lissajous curves found ({n_lasers} lasers)',
                  'the points are not that pattern (is the recording from this sensor, its ring '
                  'field the laser ids, and the tiling right?)')
    prior = None
    if int(laser.max()) < n_cfg:
        prior = angular_error_deg(samples, laser, prior_lasers)
    doc = read_yaml(sensor_path)
    doc['frame_rate_hz'] = sig(1.0 / period, 9)
    doc['scan'] = _scan_doc(doc['scan'], lasers, tiles, shots)
    return ScanCalibration(samples, laser, lasers, fits_az, fits_el, tiles, period, shots,
                           error, prior, doc, warnings)


def format_report(cal: ScanCalibration) -> str:
    las = cal.lasers
    rows = []
    for i in range(len(las.center_az_rad)):
        sel = cal.laser == i
        rows.append([str(i), str(int(sel.sum())),
                     f'{np.degrees(las.center_az_rad[i]):+.3f}', f'{np.degrees(las.center_el_rad[i]):+.3f}',
                     f'{np.degrees(las.amp_az_rad[i]):.3f}', f'{np.degrees(las.amp_el_rad[i]):.3f}',
                     f'{las.freq_az_hz[i]:.4f}', f'{las.freq_el_hz[i]:.4f}',
                     f'{las.phase_az_rad[i]:.4f}', f'{las.phase_el_rad[i]:.4f}',
                     f'{np.sqrt(np.mean(cal.error_deg[sel] ** 2)):.3g}'
                     if cal.fits_az[i].n_used else 'kept from config'])
    lines = [f'{len(cal.samples)} points in {len(np.unique(cal.samples.frame))} frames; '
             f'frame period {cal.frame_period_s:.6g} s; {cal.tiles[0]} x {cal.tiles[1]} tiles; '
             f'{cal.shots_per_laser} shots per laser per frame; lasers '
             + ('from the ring field' if cal.samples.laser is not None else
                'assigned by clustering (no ring field)'),
             format_table(['laser', 'points', 'c_az', 'c_el', 'A_az', 'A_el', 'f_az [Hz]',
                           'f_el [Hz]', 'ph_az', 'ph_el', 'RMS [deg]'], rows)]
    return '\n'.join(lines + cal.error_lines('shot', 'fitted pattern', ''))


def plot_scan(cal: ScanCalibration, sensor_out: Path, path: str | Path) -> Path:
    """Measured vs fitted pattern (paper Figs. 5-6), a zoom on one tile, error histogram."""
    fig, axes = new_figure(2, 2, (13.0, 8.5))
    s = cal.samples
    first = s.frame == s.frame.min()
    ax = axes[0, 0]
    ax.plot(np.degrees(s.az_rad[first]), np.degrees(s.el_rad[first]), ',', color='k')
    ax.set_title(f'measured pattern (one frame, {int(first.sum())} points)')
    shots = frame_shots(load_sensor(sensor_out))
    ax = axes[0, 1]
    ax.plot(np.degrees(shots.az_rad), np.degrees(shots.el_rad), ',', color='tab:blue')
    ax.set_title(f'fitted pattern: frame_shots of the written config ({len(shots)} shots)')
    for ax in axes[0]:
        ax.set_xlabel('azimuth [deg]')
        ax.set_ylabel('elevation [deg]')
        ax.invert_xaxis()  # +az is to the left, as seen from behind the sensor
        ax.set_aspect('equal')
    ax = axes[1, 0]
    i = int(np.argmin(np.hypot(cal.lasers.center_az_rad, cal.lasers.center_el_rad)))
    sel = cal.laser == i
    t = np.linspace(0.0, cal.frame_period_s, 4000)
    az, el = lissajous_angles(cal.lasers, np.full(len(t), i), t)
    ax.plot(np.degrees(az), np.degrees(el), '-', color='tab:blue', lw=0.6, label='fitted curve')
    ax.plot(np.degrees(s.az_rad[sel]), np.degrees(s.el_rad[sel]), '.', color='tab:red', ms=2,
            label='measured')
    ax.set_title(f'laser {i}: measured vs fitted curve')
    ax.set_xlabel('azimuth [deg]')
    ax.set_ylabel('elevation [deg]')
    ax.invert_xaxis()
    ax.legend(fontsize=8, loc='upper right')
    ax = axes[1, 1]
    bins = np.linspace(0.0, max(np.percentile(cal.error_deg, 99.5), 1e-6), 60)
    ax.hist(np.clip(cal.error_deg, 0, bins[-1]), bins, color='tab:blue', alpha=0.8, label='fitted')
    ax.axvline(cal.rms_deg, color='k', ls='--', label=f'RMS {cal.rms_deg:.3g} deg')
    ax.axvline(cal.p95_deg, color='k', ls=':', label=f'p95 {cal.p95_deg:.3g} deg')
    ax.set_xlabel('angular error per shot [deg]')
    ax.set_ylabel('shots')
    ax.set_title('measured vs fitted direction, same laser and time\n(last bin: above the 99.5th percentile)',
                 fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def run_scan(bag: str | Path, out: str | Path, sensor: str | Path | None = None,
             figure: str | Path | None = None, topic: str = CLOUD_TOPIC,
             fields: dict | None = None) -> ScanCalibration:
    """``lidar-sim calibrate scan``: fit, write the sensor YAML, check it reloads, plot."""
    sensor = Path(sensor) if sensor else config_path('cepton_vista_p60.yaml')
    if isinstance(load_sensor(sensor).scan, RisleyScan):  # a wrong --sensor fails before the bag
        from lidar_sim_ros.calibrate.scan_risley import run_risley
        return run_risley(bag, out, sensor, figure, topic, fields)
    samples = read_scan_samples(bag, topic, fields)
    cal = calibrate_scan(samples, sensor)
    header = [f'Sensor calibrated by `lidar-sim calibrate scan {bag}` from {sensor}:',
              'per-laser Lissajous parameters (scan.lasers), frame rate and shots per laser fitted;',
              f'angular error per shot RMS {cal.rms_deg:.3g} deg, p95 {cal.p95_deg:.3g} deg.']
    cal.out = write_sensor(out, cal.sensor_doc, header)
    # What the simulator will use: the written (rounded) file, reloaded.
    written = lissajous_lasers(load_sensor(cal.out).scan)
    cal.error_deg = angular_error_deg(samples, cal.laser, written)
    if figure:
        plot_scan(cal, cal.out, figure)
    cal.report = format_report(cal)
    return cal
