"""A Risley scan's prism rates from measured data (``lidar-sim calibrate scan`` on a
sensor whose ``scan.type`` is ``risley``; the model in ``core/scan_risley.py``).

Each measured direction gives the beam's deviation as one complex number
z = theta exp(i psi) (theta off the boresight, psi about it from +y toward +z), and the
first-order model says z(t) = a_1 exp(2 pi i f_1 t) + a_2 exp(2 pi i f_2 t), with
|a_j| the prisms' deviations and arg a_j their angles at t = 0: a sum of two complex
exponentials of signed frequency. The points of all clouds are put on one clock (each
cloud's stamp plus the point's time since it; t = 0 at the first cloud), the strongest
frequency is taken from the periodogram of z, its term is fitted and removed, the
second frequency is taken from the remainder's periodogram (so the first's sidelobes,
which the target's gaps make strong, cannot pass for it), and both rates with both
complex amplitudes are refined by least squares (the amplitudes are linear given the
rates). The phases are written for frame 0 = the recording's first cloud.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import optimize

from lidar_sim_ros.calibrate.common import (AngularErrorSummary, CalibrationInputError,
                                            check_fit_rms, new_figure, save_figure, sig,
                                            write_sensor)
from lidar_sim_ros.calibrate.scan_samples import ScanSamples, read_scan_samples
from lidar_sim_ros.core.config import RisleyScan, load_sensor, read_yaml
from lidar_sim_ros.core.scan import frame_shots
from lidar_sim_ros.core.scan_risley import (directions_from_deviation, petals_per_period,
                                           rosette_period_s)
from lidar_sim_ros.io.bag import CLOUD_TOPIC

MIN_POINTS = 200
PERIODOGRAM_POINTS = 4000       # points the periodogram sums over (a random, seeded subset)
MAX_RATE_HZ = 1000.0            # largest prism rate searched (rev/s)
_GRID_OVERSAMPLE = 8            # frequency steps per 1 / (time span)
CANDIDATE_PEAKS = 4             # periodogram peaks tried for each rate
MAX_FIT_SPAN_S = 30.0
"""Longest stretch of recording fitted (s, from the first cloud): the periodogram's grid has
16 MAX_RATE_HZ x 8 steps a second (two clouds 10^4 s apart asked for 32 GiB; 100 s apart
took 949 MB). 30 s of a Mid-40 is 3 million points, more than the rates need."""


@dataclass
class RisleyCalibration(AngularErrorSummary):
    """The fitted prisms, the error per point, and the sensor YAML written."""

    samples: ScanSamples
    rates_hz: tuple[float, float]
    deviation_deg: tuple[float, float]
    phase_rad: tuple[float, float]
    shot_rate_hz: float
    frame_period_s: float
    error_deg: np.ndarray
    prior_error_deg: np.ndarray | None
    sensor_doc: dict
    warnings: list[str] = field(default_factory=list)
    out: Path | None = None
    report: str = ''


def deviation_of(direction: np.ndarray) -> np.ndarray:
    """z = theta exp(i psi) (rad) of unit directions (N, 3): the inverse of
    ``core.scan_risley.directions_from_deviation``."""
    d = np.asarray(direction, float)
    theta = np.arccos(np.clip(d[:, 0], -1.0, 1.0))
    return theta * np.exp(1j * np.arctan2(d[:, 2], d[:, 1]))


def periodogram(t_s: np.ndarray, z: np.ndarray, freqs_hz: np.ndarray) -> np.ndarray:
    """|sum z exp(-2 pi i f t)|^2 / N for each signed frequency (Hz)."""
    out = np.empty(len(freqs_hz))
    for lo in range(0, len(freqs_hz), 256):
        f = freqs_hz[lo:lo + 256]
        out[lo:lo + 256] = np.abs(np.exp(-2j * np.pi * np.outer(f, t_s)) @ z) ** 2
    return out / max(len(t_s), 1)


def gridded_periodogram(t_s: np.ndarray, z: np.ndarray, span_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The periodogram on |f| <= MAX_RATE_HZ in steps of 1 / (8 span), by FFT of z summed
    into time bins of 1 / (16 MAX_RATE_HZ) s (a bin moves a term's phase by at most
    pi/16 at the largest rate: good enough to find peaks, which are then refined on the
    exact sum)."""
    dt = 1.0 / (16.0 * MAX_RATE_HZ)
    index = np.round((t_s - t_s.min()) / dt).astype(np.int64)
    grid = np.bincount(index, weights=z.real) + 1j * np.bincount(index, weights=z.imag)
    n = int(2 ** np.ceil(np.log2(max(len(grid), 1) * _GRID_OVERSAMPLE)))
    spectrum = np.fft.fftshift(np.fft.fft(grid, n))
    freqs = np.fft.fftshift(np.fft.fftfreq(n, dt))
    keep = np.abs(freqs) <= MAX_RATE_HZ
    # A shift of the time origin changes only the phases, not the power.
    return freqs[keep], np.abs(spectrum[keep]) ** 2 / max(len(t_s), 1)


def amplitudes(t_s: np.ndarray, z: np.ndarray, rates_hz) -> np.ndarray:
    """Least-squares complex amplitudes a_j of z(t) = sum a_j exp(2 pi i f_j t)."""
    basis = np.exp(2j * np.pi * np.outer(t_s, np.atleast_1d(rates_hz)))
    return np.linalg.lstsq(basis, z, rcond=None)[0]


def _model(t_s, rates_hz, a) -> np.ndarray:
    return np.exp(2j * np.pi * np.outer(t_s, rates_hz)) @ a


def _peaks(t_s: np.ndarray, z: np.ndarray, span_s: float, k: int) -> list[float]:
    """The ``k`` highest local maxima of the periodogram (Hz), at least 2 / span apart,
    each refined on the continuous periodogram around its grid point."""
    freqs, power = gridded_periodogram(t_s, z, span_s)
    df = float(freqs[1] - freqs[0])
    local = np.flatnonzero((power[1:-1] >= power[:-2]) & (power[1:-1] >= power[2:])) + 1
    chosen: list[float] = []
    for i in local[np.argsort(-power[local])]:
        if all(abs(freqs[i] - c) > 2.0 / span_s for c in chosen):
            chosen.append(float(freqs[i]))
        if len(chosen) == k:
            break
    out = []
    for f0 in chosen:
        res = optimize.minimize_scalar(lambda f: -periodogram(t_s, z, np.array([f]))[0],
                                       bounds=(f0 - df, f0 + df), method='bounded',
                                       options={'xatol': 1e-9})
        out.append(float(res.x))
    return out


def _misfit(t_s: np.ndarray, z: np.ndarray, rates) -> float:
    r = z - _model(t_s, rates, amplitudes(t_s, z, rates))
    return float(np.mean(np.abs(r) ** 2))


def fit_prisms(t_s: np.ndarray, z: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Signed rates (rev/s) and complex amplitudes (rad) of the two prisms.

    The target's gaps sample the rosette only where it crosses the target, which smears
    the rates' peaks and raises sidelobes beside them. So: each of the periodogram's
    highest peaks is tried as the first rate; its term is fitted and removed, and each of
    the remainder's highest peaks is tried as the second; every pair is refined by least
    squares on a subset and the pair that fits best (the true pair fits to the noise, an
    alias does not) is refined on every point."""
    span = float(np.ptp(t_s))
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(t_s), min(len(t_s), PERIODOGRAM_POINTS), replace=False)
    ts, zs = t_s[pick], z[pick]
    pairs = []
    for f1 in _peaks(ts, zs, span, CANDIDATE_PEAKS):
        rest = zs - _model(ts, [f1], amplitudes(ts, zs, [f1]))
        pairs += [(f1, f2) for f2 in _peaks(ts, rest, span, CANDIDATE_PEAKS)
                  if abs(f2 - f1) > 2.0 / span]
    if not pairs:
        raise CalibrationInputError('the periodogram of the points has fewer than two peaks: '
                                    'no prism pair to fit')
    refined = [_refine(ts, zs, p, span, 1e-8, 30) for p in pairs]
    best = min(refined, key=lambda p: _misfit(ts, zs, p))
    rates = _refine(t_s, z, best, span, 1e-14, None)
    return rates, amplitudes(t_s, z, rates)


def _refine(t_s: np.ndarray, z: np.ndarray, rates, span_s: float, tol: float,
            max_nfev: int | None) -> np.ndarray:
    """Both rates by least squares, the amplitudes solved for at each step."""
    def residual(f):
        r = z - _model(t_s, f, amplitudes(t_s, z, f))
        return np.concatenate([r.real, r.imag])
    return optimize.least_squares(residual, list(rates), x_scale=1.0 / span_s, xtol=tol,
                                  ftol=tol, max_nfev=max_nfev).x


def angular_error_deg(direction: np.ndarray, t_s: np.ndarray, rates_hz, a) -> np.ndarray:
    """Angle (deg) between each measured direction and the model's at its time."""
    zm = _model(t_s, np.asarray(rates_hz, float), np.asarray(a))
    model = directions_from_deviation(zm.real, zm.imag)
    return np.degrees(np.arccos(np.clip(np.sum(model * direction, axis=1), -1.0, 1.0)))


def _shot_rate_hz(samples: ScanSamples) -> float | None:
    """1 / the median spacing of point times in the densest cloud; None if too sparse."""
    frames, counts = np.unique(samples.frame, return_counts=True)
    t = np.unique(np.round(samples.t_s[samples.frame == frames[np.argmax(counts)]], 9))
    d = np.diff(t)
    if len(d) < 10:
        return None
    d = d[d > 0]
    if len(d) < 10:
        return None
    # Neighbouring shots: the spacings within half a step of the smallest; then the slope of
    # time over shot number (float32 times are ~1e-8 s coarse: one spacing is not enough).
    dt = float(np.median(d[d < 1.5 * d.min()]))
    for steps in (100, 1000, 10000, None):      # longer baselines as the step gets better
        near = slice(None) if steps is None else (t - t[0]) < steps * dt
        n = np.round((t[near] - t[0]) / dt)
        if len(np.unique(n)) > 2:
            dt = float(np.polyfit(n, t[near] - t[0], 1)[0])
    return 1.0 / dt if dt > 0 else None


def calibrate_risley(samples: ScanSamples, sensor_path: str | Path) -> RisleyCalibration:
    """Fit the prisms of ``samples``; the sensor config gives the frame rate and the rest."""
    sensor_path = Path(sensor_path)
    sensor = load_sensor(sensor_path)
    warnings = []
    period = sensor.frame_period_s
    if samples.frame_period_s is not None and abs(samples.frame_period_s - period) > 0.01 * period:
        warnings.append(f'frame period from the bag stamps {samples.frame_period_s:.6g} s differs '
                        f'from {sensor_path} ({period:.6g} s); using the bag\'s')
        period = samples.frame_period_s
    starts = samples.frame_start_s if samples.frame_start_s is not None else np.zeros(1)
    t_abs = starts[samples.frame] + samples.t_s
    early = t_abs - t_abs.min() <= MAX_FIT_SPAN_S
    if not early.all():
        warnings.append(f'the clouds span {np.ptp(t_abs):.6g} s; the prisms are fitted on the '
                        f'first {MAX_FIT_SPAN_S:g} s ({int(early.sum())} of {len(t_abs)} points)')
        samples = dataclasses.replace(samples, **{k: getattr(samples, k)[early] for k in (
            't_s', 'az_rad', 'el_rad', 'direction', 'frame')}, laser=None if samples.laser is None
            else samples.laser[early])
        t_abs = t_abs[early]
    if len(samples) < MIN_POINTS:
        raise CalibrationInputError(f'{samples.source}: {len(samples)} points; the prism fit needs '
                                    f'at least {MIN_POINTS} (record more frames)')
    if np.ptp(t_abs) <= 0:
        raise CalibrationInputError(f'{samples.source}: every point has the same time; the prism '
                                    'fit needs per-point times')
    z = deviation_of(samples.direction)
    rates, a = fit_prisms(t_abs, z)
    order = np.argsort(-np.abs(a))          # the stronger prism first
    rates, a = rates[order], a[order]
    error = angular_error_deg(samples.direction, t_abs, rates, a)
    check_fit_rms(error, samples.source, f'the best prism pair found ({rates[0]:.6g} and '
                  f'{rates[1]:.6g} rev/s)', f'the points are not that rosette (rates beyond '
                  f'+-{MAX_RATE_HZ:g} rev/s are not searched; is the recording from a Risley sensor?)')
    prior = None
    scan = sensor.scan
    if isinstance(scan, RisleyScan):
        prior_a = np.radians(scan.prism_deviation_deg) * np.exp(1j * np.asarray(scan.prism_phase_rad))
        prior = angular_error_deg(samples.direction, t_abs, scan.prism_rates_hz, prior_a)
    shot_rate = _shot_rate_hz(samples)
    if shot_rate is None:
        shot_rate = scan.shot_rate_hz
        warnings.append(f'too few points a cloud to measure the shot spacing; shot_rate_hz '
                        f'{shot_rate:g} kept from {sensor_path}')
    doc = read_yaml(sensor_path)
    doc['frame_rate_hz'] = sig(1.0 / period, 9)
    doc['scan'] = {'type': 'risley',
                   'prism_rates_hz': [sig(f, 10) for f in rates],
                   'prism_deviation_deg': [sig(np.degrees(abs(x)), 8) for x in a],
                   'prism_phase_rad': [sig(float(np.angle(x)), 9) for x in a],
                   'shot_rate_hz': sig(shot_rate, 8)}
    return RisleyCalibration(samples, tuple(float(f) for f in rates),
                             tuple(float(np.degrees(abs(x))) for x in a),
                             tuple(float(np.angle(x)) for x in a), float(shot_rate), period, error,
                             prior, doc, warnings)


def format_report(cal: RisleyCalibration) -> str:
    f1, f2 = cal.rates_hz
    lines = [f'{len(cal.samples)} points in {len(np.unique(cal.samples.frame))} frames; frame '
             f'period {cal.frame_period_s:.6g} s; shot rate {cal.shot_rate_hz:.6g} Hz',
             f'prism 1: {f1:+.6f} rev/s ({60 * f1:+.2f} rpm), deviation {cal.deviation_deg[0]:.4f} deg, '
             f'phase {cal.phase_rad[0]:+.4f} rad',
             f'prism 2: {f2:+.6f} rev/s ({60 * f2:+.2f} rpm), deviation {cal.deviation_deg[1]:.4f} deg, '
             f'phase {cal.phase_rad[1]:+.4f} rad',
             f'field half-angle {sum(cal.deviation_deg):.4f} deg; {abs(f1 - f2):.4f} petal tips a second']
    fitted, *prior = cal.error_lines('point', 'fitted',
                                     ' (its phases taken at the first cloud)')
    lines.append(fitted)
    period = rosette_period_s(cal.rates_hz)
    if period < 100.0:
        lines.append(f'the rosette closes after {period:.6g} s ({petals_per_period(cal.rates_hz)} petals)')
    return '\n'.join(lines + prior)


def plot_risley(cal: RisleyCalibration, sensor_out: Path, path: str | Path) -> Path:
    """Measured points of the first frame over the fitted frame's rosette, and the errors."""
    fig, axes = new_figure(1, 2, (12.0, 5.5))
    s = cal.samples
    first = s.frame == s.frame.min()
    shots = frame_shots(load_sensor(sensor_out), frame_index=0)
    ax = axes[0, 0]
    ax.plot(np.degrees(shots.az_rad), np.degrees(shots.el_rad), '-', color='tab:blue', lw=0.4,
            label='fitted rosette, frame 0')
    ax.plot(np.degrees(s.az_rad[first]), np.degrees(s.el_rad[first]), '.', color='tab:red', ms=2,
            label='measured, first frame')
    ax.set_xlabel('azimuth [deg]')
    ax.set_ylabel('elevation [deg]')
    ax.invert_xaxis()
    ax.set_aspect('equal')
    ax.legend(fontsize=8, loc='upper right')
    ax = axes[0, 1]
    bins = np.linspace(0.0, max(np.percentile(cal.error_deg, 99.5), 1e-6), 60)
    ax.hist(np.clip(cal.error_deg, 0, bins[-1]), bins, color='tab:blue', alpha=0.8)
    ax.axvline(cal.rms_deg, color='k', ls='--', label=f'RMS {cal.rms_deg:.3g} deg')
    ax.set_xlabel('angular error per point [deg]')
    ax.set_ylabel('points')
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def run_risley(bag: str | Path, out: str | Path, sensor: Path, figure: str | Path | None = None,
               topic: str = CLOUD_TOPIC, fields: dict | None = None) -> RisleyCalibration:
    """``lidar-sim calibrate scan`` for a risley sensor: fit, write, reload, plot."""
    samples = read_scan_samples(bag, topic, fields)
    cal = calibrate_risley(samples, sensor)
    header = [f'Sensor calibrated by `lidar-sim calibrate scan {bag}` from {sensor}:',
              'Risley prism rates, deviations and phases (frame 0 = the recording\'s first cloud)',
              f'and the shot rate fitted; angular error per point RMS {cal.rms_deg:.3g} deg, '
              f'p95 {cal.p95_deg:.3g} deg.']
    cal.out = write_sensor(out, cal.sensor_doc, header)
    written = load_sensor(cal.out).scan
    samples = cal.samples                   # the points fitted (the first MAX_FIT_SPAN_S)
    starts = samples.frame_start_s if samples.frame_start_s is not None else np.zeros(1)
    t_abs = starts[samples.frame] + samples.t_s
    a = np.radians(written.prism_deviation_deg) * np.exp(1j * np.asarray(written.prism_phase_rad))
    cal.error_deg = angular_error_deg(samples.direction, t_abs, written.prism_rates_hz, a)
    if figure:
        plot_risley(cal, cal.out, figure)
    cal.report = format_report(cal)
    return cal
