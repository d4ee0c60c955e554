"""BRDF table -> modified Phong parameters (paper Sec. 5, Eq. 5, Figs. 9-10).

A goniometer table ``theta_in, phi_in, theta_out, phi_out, brdf`` (degrees, 1/sr,
optionally a ``material`` column) is reduced to an isotropic table over
(theta_in, theta_out, |phi_out - phi_in|), averaging over the sample's azimuth as
the paper does for its anisotropic metals, and fitted with kd, ks, n twice: by
least squares on the BRDF (follows the specular peak) and on its logarithm
(follows the relative error everywhere). Both fits are reported; one is written.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import optimize, stats

from lidar_sim_ros.calibrate.common import (CalibrationInputError, format_table,
                                            load_materials_document, new_figure, save_figure, sig,
                                            update_materials, write_materials)
from lidar_sim_ros.core.reflection import phong_brdf, specular_alpha
from lidar_sim_ros.paths import config_path

ANGLE_COLUMNS = ('theta_in', 'phi_in', 'theta_out', 'phi_out')
REQUIRED_COLUMNS = ANGLE_COLUMNS + ('brdf',)
MIN_READINGS = 10      # rows per material
MIN_ANGLES = 6         # distinct (theta_in, theta_out, dphi) after azimuth averaging
N_MAX = 1000.0         # upper bound of the specular exponent
FIT_KINDS = ('log', 'linear')
ANISOTROPY_P = 1e-3    # azimuth scatter beyond noise at this significance = anisotropic
_KEY_DECIMALS = 3      # angles equal to 1e-3 deg are the same goniometer setting
_TINY_SR = 1e-12       # floor of the model BRDF inside the log


# ------------------------------------------------------------------- reading
@dataclass(frozen=True)
class BrdfTable:
    """One material's goniometer readings (degrees, 1/sr) and their CSV line numbers."""

    material: str
    source: str
    theta_in_deg: np.ndarray
    phi_in_deg: np.ndarray
    theta_out_deg: np.ndarray
    phi_out_deg: np.ndarray
    brdf_sr: np.ndarray
    line: np.ndarray

    def __len__(self) -> int:
        return len(self.brdf_sr)


def _cell_error(path: Path, row: int, line: int, column: str, value: str, reason: str):
    return CalibrationInputError(f'{path}: row {row} (line {line}), column "{column}": '
                                 f'value {value!r} {reason}')


def read_brdf_csv(path: str | Path, material: str | None = None) -> dict[str, BrdfTable]:
    """Read and validate a BRDF table; one BrdfTable per material.

    Without a ``material`` column all rows belong to ``material`` (required then);
    with one, ``material`` selects a single material. Blank lines and lines
    starting with ``#`` are skipped. Raises CalibrationInputError naming file,
    column and row for missing columns, non-numbers, NaN, angles out of range
    and too few readings.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f'BRDF table not found: {path}')
    with path.open(newline='') as fh:
        numbered = [(i + 1, text) for i, text in enumerate(fh)
                    if text.strip() and not text.lstrip().startswith('#')]
    if not numbered:
        raise CalibrationInputError(f'{path}: no header and no data')
    rows = list(csv.reader(text for _, text in numbered))
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise CalibrationInputError(f'{path}: missing column(s) {missing}; the header (line '
                                    f'{numbered[0][0]}) has {header}; expected '
                                    f'{list(REQUIRED_COLUMNS)} and optionally "material"')
    col = {name: header.index(name) for name in header}
    has_material = 'material' in col
    if not has_material and material is None:
        raise CalibrationInputError(f'{path}: no "material" column; name the material with '
                                    '--material NAME')
    values = {c: [] for c in REQUIRED_COLUMNS}
    names, lines = [], []
    for row_no, ((line, _), cells) in enumerate(zip(numbered[1:], rows[1:]), start=1):
        if len(cells) != len(header):
            raise CalibrationInputError(f'{path}: row {row_no} (line {line}) has {len(cells)} '
                                        f'fields, the header has {len(header)}')
        for c in REQUIRED_COLUMNS:
            text = cells[col[c]].strip()
            try:
                v = float(text)
            except ValueError:
                raise _cell_error(path, row_no, line, c, text,
                                  'is empty' if not text else 'is not a number') from None
            if not np.isfinite(v):
                raise _cell_error(path, row_no, line, c, text, 'is not finite (NaN or inf)')
            values[c].append(v)
        name = cells[col['material']].strip() if has_material else material
        if not name:
            raise _cell_error(path, row_no, line, 'material', '', 'is empty')
        names.append(name)
        lines.append(line)
    arrays = {c: np.asarray(v, dtype=float) for c, v in values.items()}
    lines_arr = np.asarray(lines, dtype=int)
    _check_range(path, arrays, lines_arr)
    names_arr = np.asarray(names, dtype=object)
    found = list(dict.fromkeys(names))
    if has_material and material is not None:
        if material not in found:
            raise CalibrationInputError(f'{path}: material {material!r} not in the "material" '
                                        f'column (found {found})')
        found = [material]
    tables = {}
    for name in found:
        sel = names_arr == name
        if sel.sum() < MIN_READINGS:
            raise CalibrationInputError(
                f'{path}: material {name!r} has {int(sel.sum())} rows, at least {MIN_READINGS} '
                'readings are needed to fit kd, ks and n')
        tables[name] = BrdfTable(name, str(path), *(arrays[c][sel] for c in REQUIRED_COLUMNS),
                                 lines_arr[sel])
    if not tables:
        raise CalibrationInputError(f'{path}: no data rows')
    return tables


def _check_range(path: Path, arrays: dict[str, np.ndarray], lines: np.ndarray) -> None:
    """theta in [0, 90], phi in [0, 360) or [-180, 180]: name the first bad row."""
    limits = {'theta_in': (0.0, 90.0, True), 'theta_out': (0.0, 90.0, True),
              'phi_in': (-180.0, 360.0, False), 'phi_out': (-180.0, 360.0, False)}
    for c, (lo, hi, hi_closed) in limits.items():
        v = arrays[c]
        bad = (v < lo) | ((v > hi) if hi_closed else (v >= hi))
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            allowed = '[0, 90] deg' if hi_closed else '[0, 360) or [-180, 180] deg'
            raise _cell_error(path, i + 1, int(lines[i]), c, f'{v[i]:g}',
                              f'is outside {allowed} ({int(bad.sum())} row(s) out of range)')


# ---------------------------------------------------------- azimuth average
@dataclass(frozen=True)
class IsotropicTable:
    """A BRDF table averaged over the sample azimuth: one row per distinct geometry.

    dphi_deg = |phi_out - phi_in| folded into [0, 180] (0 where a polar angle is 0);
    brdf_sr: mean of all readings (linear fit); brdf_pos_sr: mean of the positive
    readings, NaN where there are none (log fit); n_readings per row.
    Anisotropy: the scatter of ln(brdf) across azimuths at equal geometry,
    ``azimuth_spread`` (RMS, ~relative), tested against the noise ``noise_log``
    (from repeated readings if the table has them, else assumed).
    """

    theta_in_deg: np.ndarray
    theta_out_deg: np.ndarray
    dphi_deg: np.ndarray
    brdf_sr: np.ndarray
    brdf_pos_sr: np.ndarray
    n_readings: np.ndarray
    azimuth_spread: float
    noise_log: float
    noise_source: str
    anisotropy_p: float
    anisotropic: bool

    @property
    def alpha_rad(self) -> np.ndarray:
        return specular_alpha(np.radians(self.theta_in_deg), 0.0,
                              np.radians(self.theta_out_deg), np.radians(self.dphi_deg))

    def __len__(self) -> int:
        return len(self.brdf_sr)


def _group(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row index of each distinct key row and the inverse map."""
    _, first, inverse = np.unique(np.round(keys, _KEY_DECIMALS), axis=0,
                                  return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def _within_ss(y: np.ndarray, group: np.ndarray) -> tuple[float, int]:
    """Sum of squares about the group means and its degrees of freedom."""
    n_groups = group.max() + 1 if len(group) else 0
    count = np.bincount(group, minlength=n_groups)
    mean = np.bincount(group, weights=y, minlength=n_groups) / np.maximum(count, 1)
    return float(np.sum((y - mean[group]) ** 2)), int(len(y) - np.count_nonzero(count))


def average_over_azimuth(table: BrdfTable, noise_rel: float = 0.05) -> IsotropicTable:
    """Collapse the table to isotropic geometry and test whether it was anisotropic.

    An isotropic BRDF depends on theta_in, theta_out and the relative azimuth only
    (symmetric in its sign). Readings that share those but differ in azimuth
    should agree within noise; the chi-square (or, with repeated readings, F) test
    of their scatter in ln(brdf) against the noise decides 'anisotropic'.
    """
    ti, to = table.theta_in_deg, table.theta_out_deg
    dphi = np.mod(table.phi_out_deg - table.phi_in_deg, 360.0)
    dphi = np.minimum(dphi, 360.0 - dphi)
    dphi = np.where((ti == 0) | (to == 0), 0.0, dphi)
    first, geo = _group(np.column_stack([ti, to, dphi]))
    n_geo = len(first)
    count = np.bincount(geo, minlength=n_geo)
    mean = np.bincount(geo, weights=table.brdf_sr, minlength=n_geo) / count
    pos = table.brdf_sr > 0
    count_pos = np.bincount(geo[pos], minlength=n_geo)
    sum_pos = np.bincount(geo[pos], weights=table.brdf_sr[pos], minlength=n_geo)
    mean_pos = np.where(count_pos > 0, sum_pos / np.maximum(count_pos, 1), np.nan)

    # Scatter of ln(brdf) at equal geometry = azimuth dependence + noise; at equal
    # goniometer setting (exact repeats) = noise alone.
    ss_geo = ss_rep = 0.0
    dof_geo = dof_rep = 0
    if pos.any():
        y = np.log(table.brdf_sr[pos])
        _, geo_pos = _group(np.column_stack([ti, to, dphi])[pos])
        _, rep_pos = _group(np.column_stack([ti, table.phi_in_deg, to, table.phi_out_deg])[pos])
        ss_geo, dof_geo = _within_ss(y, geo_pos)
        ss_rep, dof_rep = _within_ss(y, rep_pos)
    ss_az, dof_az = ss_geo - ss_rep, dof_geo - dof_rep
    spread = float(np.sqrt(ss_az / dof_az)) if dof_az > 0 else 0.0
    if dof_rep >= 10:
        noise, source = float(np.sqrt(ss_rep / dof_rep)), f'{dof_rep} repeated readings'
        p = float(stats.f.sf((ss_az / dof_az) / (ss_rep / dof_rep), dof_az, dof_rep)) \
            if dof_az > 0 and ss_rep > 0 else float('nan')
    else:
        noise, source = float(noise_rel), 'assumed (--noise-rel)'
        p = float(stats.chi2.sf(ss_az / noise ** 2, dof_az)) if dof_az > 0 else float('nan')
    anisotropic = bool(dof_az > 0 and p < ANISOTROPY_P)
    return IsotropicTable(ti[first], to[first], dphi[first], mean, mean_pos, count,
                          spread, noise, source, p, anisotropic)


# ---------------------------------------------------------------- Phong fit
@dataclass(frozen=True)
class PhongFit:
    """kd, ks, n of paper Eq. 5 from one least-squares criterion, with both residuals.

    rms_sr: RMS of model - data over all angles (1/sr);
    rms_log: RMS of ln(model / data) over the angles with positive data (~relative).
    """

    kind: str
    kd: float
    ks: float
    n: float
    rms_sr: float
    rms_log: float
    starts: int

    def brdf_sr(self, alpha_rad) -> np.ndarray:
        return phong_brdf(alpha_rad, self.kd, self.ks, self.n)


def _params(x: np.ndarray) -> tuple[float, float, float]:
    """(s, u, m) -> (kd, ks, n): s = kd + ks, u = ks / s, m = ln(1 + n); boxes keep the bounds."""
    s, u, m = x
    return s * (1.0 - u), s * u, float(np.expm1(m))


def _starts(alpha: np.ndarray, brdf: np.ndarray) -> list[np.ndarray]:
    """Starting points over a grid of n: kd, ks by non-negative linear least squares."""
    starts = []
    cos_a = np.clip(np.cos(alpha), 0.0, 1.0)
    for n0 in (0.5, 2.0, 6.0, 20.0, 60.0, 200.0, 700.0):
        a = np.column_stack([np.full_like(alpha, 1.0 / np.pi), (n0 + 2) / (2 * np.pi) * cos_a ** n0])
        (kd0, ks0), _ = optimize.nnls(a, np.maximum(brdf, 0.0))
        s0 = float(np.clip(kd0 + ks0, 0.01, 0.99))
        u0 = float(np.clip(ks0 / max(kd0 + ks0, 1e-12), 0.02, 0.98))
        for u in {u0, 0.5}:
            starts.append(np.array([s0, u, np.log1p(n0)]))
    return starts


def _residuals(kind: str, alpha: np.ndarray, brdf: np.ndarray):
    if kind == 'linear':
        return lambda x: phong_brdf(alpha, *_params(x)) - brdf
    log_data = np.log(brdf)
    return lambda x: np.log(np.maximum(phong_brdf(alpha, *_params(x)), _TINY_SR)) - log_data


def fit_phong(alpha_rad: np.ndarray, brdf_sr: np.ndarray, kind: str,
              brdf_pos_sr: np.ndarray | None = None) -> PhongFit:
    """Least-squares kd, ks, n on the BRDF ('linear') or on ln(BRDF) ('log').

    Bounds: kd, ks in [0, 1] with kd + ks <= 1, n in [0, 1000]; the best of
    several starting points wins. ``brdf_pos_sr`` (NaN = no positive reading) is
    what the log fit and the log residual use; default: brdf_sr where positive.
    """
    if kind not in FIT_KINDS:
        raise ValueError(f'fit kind must be one of {FIT_KINDS}, got {kind!r}')
    alpha = np.asarray(alpha_rad, dtype=float)
    brdf = np.asarray(brdf_sr, dtype=float)
    pos_data = np.where(brdf > 0, brdf, np.nan) if brdf_pos_sr is None else np.asarray(brdf_pos_sr)
    pos = np.isfinite(pos_data) & (pos_data > 0)
    a_fit, b_fit = (alpha, brdf) if kind == 'linear' else (alpha[pos], pos_data[pos])
    if len(b_fit) < 4:
        raise CalibrationInputError(f'{kind} fit needs at least 4 angles with data, got {len(b_fit)}')
    fun = _residuals(kind, a_fit, b_fit)
    lower, upper = [0.0, 0.0, 0.0], [1.0, 1.0, float(np.log1p(N_MAX))]
    starts = _starts(alpha[pos] if pos.any() else alpha, pos_data[pos] if pos.any() else brdf)
    best = None
    for x0 in starts:
        res = optimize.least_squares(fun, x0, bounds=(lower, upper), method='trf',
                                     x_scale=[0.3, 0.3, 1.0], max_nfev=400)
        if best is None or res.cost < best.cost:
            best = res
    kd, ks, n = _params(best.x)
    model = phong_brdf(alpha, kd, ks, n)
    rms_sr = float(np.sqrt(np.mean((model - brdf) ** 2)))
    rms_log = float(np.sqrt(np.mean(np.log(np.maximum(model[pos], _TINY_SR) / pos_data[pos]) ** 2)))
    return PhongFit(kind, float(kd), float(ks), float(n), rms_sr, rms_log, len(starts))


# ------------------------------------------------------------- calibration
@dataclass
class BrdfCalibration:
    """Everything about one material's fit: data, both fits, the choice and why."""

    material: str
    table: BrdfTable
    iso: IsotropicTable
    fits: dict[str, PhongFit]
    used: str
    reason: str
    n_nonpositive: int
    n_nonpositive_angles: int
    warnings: list[str] = field(default_factory=list)

    @property
    def chosen(self) -> PhongFit:
        return self.fits[self.used]


def _reason(used: str, fits: dict[str, PhongFit]) -> str:
    lin, log = fits['linear'], fits['log']
    if used == 'log':
        return (f'log fit used: the simulator needs the BRDF over several decades (dropouts at '
                f'the detection threshold far from the peak, saturation at it), and the log fit '
                f'keeps the relative error small everywhere: RMS ln-ratio {log.rms_log:.3f} vs '
                f'{lin.rms_log:.3f} for the linear fit, which follows the few peak samples '
                f'(RMS {lin.rms_sr:.4g} vs {log.rms_sr:.4g} 1/sr); --fit linear to prefer the peak')
    return (f'linear fit used (--fit linear): it follows the specular peak, where the returns are '
            f'strongest (RMS {lin.rms_sr:.4g} vs {log.rms_sr:.4g} 1/sr for the log fit), at the '
            f'cost of relative error away from it (RMS ln-ratio {lin.rms_log:.3f} vs '
            f'{log.rms_log:.3f})')


def calibrate_material(table: BrdfTable, fit: str = 'log', noise_rel: float = 0.05
                       ) -> BrdfCalibration:
    """Average over azimuth, fit on the BRDF and on its log, choose ``fit``."""
    if fit not in FIT_KINDS:
        raise ValueError(f'--fit must be one of {FIT_KINDS}, got {fit!r}')
    iso = average_over_azimuth(table, noise_rel)
    src = f'{table.source}: material {table.material!r}'
    if len(iso) < MIN_ANGLES:
        raise CalibrationInputError(
            f'{src}: only {len(iso)} distinct (theta_in, theta_out, dphi) geometries after '
            f'averaging over azimuth; at least {MIN_ANGLES} are needed to fit kd, ks and n')
    n_pos_angles = int(np.sum(np.isfinite(iso.brdf_pos_sr)))
    if n_pos_angles < 4:
        raise CalibrationInputError(f'{src}: column "brdf" has only {n_pos_angles} geometries '
                                    'with a positive reading; the log fit needs at least 4')
    warnings = []
    n_bad = int(np.sum(table.brdf_sr <= 0))
    if n_bad:
        lines = ', '.join(str(x) for x in table.line[table.brdf_sr <= 0][:5])
        warnings.append(f'{src}: {n_bad} zero or negative reading(s) (lines {lines}'
                        f'{", ..." if n_bad > 5 else ""}) kept in the linear fit, excluded from '
                        f'the log fit ({len(iso) - n_pos_angles} geometries lost)')
    if iso.anisotropic:
        warnings.append(
            f'{src}: anisotropic: at equal (theta_in, theta_out, dphi) the BRDF varies with the '
            f'sample azimuth by {100 * iso.azimuth_spread:.0f} % RMS vs {100 * iso.noise_log:.0f} % '
            f'noise ({iso.noise_source}; p = {iso.anisotropy_p:.1e}); averaged over azimuth as '
            f'the paper does, the isotropic Phong model cannot follow it')
    fits = {kind: fit_phong(iso.alpha_rad, iso.brdf_sr, kind, iso.brdf_pos_sr) for kind in FIT_KINDS}
    cal = BrdfCalibration(table.material, table, iso, fits, fit, _reason(fit, fits),
                          n_bad, len(iso) - n_pos_angles, warnings)
    misfit = misfit_warning(cal)
    if misfit:
        cal.warnings.append(misfit)
    return cal


MISFIT_RATIO = 1.5  # model/data beyond [1/1.5, 1.5] in an angle bin counts as a misfit


@dataclass(frozen=True)
class AngleBin:
    """Residual in one angle bin: model/data as a geometric mean per fit kind (NaN: no data)."""

    lo_deg: float
    hi_deg: float
    n: int
    data_median_sr: float
    ratio: dict[str, float]


def residual_by_angle(cal: BrdfCalibration, by: str = 'alpha', bin_deg: float = 10.0
                      ) -> list[AngleBin]:
    """Residual of both fits per bin of alpha or theta_out (where the 3 parameters fail)."""
    iso = cal.iso
    angle = np.degrees(iso.alpha_rad) if by == 'alpha' else iso.theta_out_deg
    pos = np.isfinite(iso.brdf_pos_sr)
    log_ratio = {k: np.log(np.maximum(f.brdf_sr(iso.alpha_rad), _TINY_SR)
                           / np.where(pos, iso.brdf_pos_sr, 1.0)) for k, f in cal.fits.items()}
    bins = []
    edges = np.arange(0.0, 180.0 + bin_deg, bin_deg)
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (angle >= lo) & ((angle < hi) | ((hi >= 180) & (angle <= hi)))
        if not sel.any():
            continue
        s = sel & pos
        ratio = {k: float(np.exp(np.mean(v[s]))) if s.any() else float('nan')
                 for k, v in log_ratio.items()}
        bins.append(AngleBin(float(lo), float(hi), int(sel.sum()),
                             float(np.median(iso.brdf_sr[sel])), ratio))
    return bins


def _misfit(ratio: float) -> bool:
    return bool(np.isfinite(ratio) and not 1 / MISFIT_RATIO <= ratio <= MISFIT_RATIO)


def residual_rows(cal: BrdfCalibration, by: str = 'alpha', bin_deg: float = 10.0) -> list[list[str]]:
    """The residual table as text cells; a misfit (off by more than 1.5x) is flagged '!'."""
    rows = []
    for b in residual_by_angle(cal, by, bin_deg):
        cells = [f'{b.lo_deg:.0f}-{b.hi_deg:.0f}', str(b.n), f'{b.data_median_sr:.3g}']
        cells += ['-' if not np.isfinite(b.ratio[k]) else
                  f'{b.ratio[k]:.2f}{" !" if _misfit(b.ratio[k]) else "  "}' for k in FIT_KINDS]
        rows.append(cells)
    return rows


def misfit_warning(cal: BrdfCalibration) -> str | None:
    """Where the written fit is off by more than 1.5x, as one sentence (None if nowhere)."""
    bad = [b for b in residual_by_angle(cal, 'alpha') if _misfit(b.ratio[cal.used])]
    if not bad:
        return None
    ratios = [b.ratio[cal.used] for b in bad]
    where = ', '.join(f'{b.lo_deg:.0f}-{b.hi_deg:.0f}' for b in bad)
    other = 'linear' if cal.used == 'log' else 'log'
    return (f'{cal.table.source}: material {cal.material!r}: the {cal.used} fit is off by more '
            f'than {MISFIT_RATIO}x at alpha {where} deg (model/data {min(ratios):.2g} to '
            f'{max(ratios):.2g}); the 3-parameter model cannot follow this BRDF there (see the '
            f'residual table; --fit {other} trades it differently)')


def format_report(cal: BrdfCalibration) -> str:
    """The fit quality of one material as text: both fits, the choice, residual by angle."""
    iso = cal.iso
    lines = [f'material {cal.material}: {len(cal.table)} readings -> {len(iso)} geometries '
             f'(azimuth spread {100 * iso.azimuth_spread:.1f} %, '
             f'{"ANISOTROPIC" if iso.anisotropic else "isotropic within noise"}), '
             f'{cal.n_nonpositive} zero/negative reading(s) excluded from the log fit']
    rows = [[k, f'{f.kd:.4f}', f'{f.ks:.4f}', f'{f.n:.2f}', f'{f.rms_sr:.4g}', f'{f.rms_log:.3f}',
             '<- used' if k == cal.used else ''] for k, f in cal.fits.items()]
    lines.append(format_table(['fit', 'kd', 'ks', 'n', 'RMS [1/sr]', 'RMS ln(model/data)', ''], rows))
    lines.append(cal.reason)
    for by in ('alpha', 'theta_out'):
        lines.append(f'residual by {by} (model/data, geometric mean; ! = off by more than 1.5x):')
        lines.append(format_table([f'{by} [deg]', 'n', 'data median [1/sr]', 'log fit', 'linear fit'],
                                  residual_rows(cal, by)))
    return '\n'.join(lines)


def plot_brdf(cals: list[BrdfCalibration], path: str | Path) -> Path:
    """Per material: data and both fits vs alpha (log scale); residual vs theta_out."""
    fig, axes = new_figure(2, len(cals), (5.0 * len(cals), 7.5))
    colors = {'linear': 'tab:blue', 'log': 'tab:pink'}
    for j, cal in enumerate(cals):
        iso = cal.iso
        alpha_deg = np.degrees(iso.alpha_rad)
        ax = axes[0, j]
        pos = iso.brdf_sr > 0
        ax.semilogy(alpha_deg[pos], iso.brdf_sr[pos], 'o', mfc='none', color='tab:red', ms=4,
                    label='data (azimuth mean)')
        if (~pos).any():
            floor = np.min(iso.brdf_sr[pos]) / 3 if pos.any() else 1e-6
            ax.semilogy(alpha_deg[~pos], np.full((~pos).sum(), floor), 'x', color='k',
                        label='data <= 0 (plotted at floor)')
        grid = np.linspace(0.0, max(90.0, alpha_deg.max()), 400)
        for kind, f in cal.fits.items():
            ax.semilogy(grid, f.brdf_sr(np.radians(grid)), color=colors[kind],
                        lw=2.5 if kind == cal.used else 1.2,
                        label=f'{kind} fit kd={f.kd:.3f} ks={f.ks:.3f} n={f.n:.1f}'
                              + (' (used)' if kind == cal.used else ''))
        ax.set_xlabel('alpha: angle from the mirror direction [deg]')
        ax.set_ylabel('BRDF [1/sr]')
        ax.set_title(f'{cal.material}: data vs modified Phong')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=7)
        ax = axes[1, j]
        ok = np.isfinite(iso.brdf_pos_sr)
        for kind, f in cal.fits.items():
            r = np.log(np.maximum(f.brdf_sr(iso.alpha_rad[ok]), _TINY_SR) / iso.brdf_pos_sr[ok])
            ax.plot(iso.theta_out_deg[ok] + (0.6 if kind == 'log' else -0.6), r, '.',
                    color=colors[kind], ms=4, label=f'{kind} fit (RMS {f.rms_log:.2f})')
        ax.axhline(0.0, color='k', lw=0.8)
        for lim in (np.log(1.5), -np.log(1.5)):
            ax.axhline(lim, color='gray', lw=0.8, ls='--')
        ax.set_xlabel('theta_out [deg]')
        ax.set_ylabel('ln(model / data)')
        ax.set_title(f'{cal.material}: residual (dashed: 1.5x)')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


@dataclass
class BrdfResult:
    calibrations: list[BrdfCalibration]
    out: Path
    warnings: list[str]
    report: str


def run_brdf(csv_path: str | Path, out: str | Path, materials: str | Path | None = None,
             material: str | None = None, fit: str = 'log', figure: str | Path | None = None,
             noise_rel: float = 0.05, template: str | None = None) -> BrdfResult:
    """``lidar-sim calibrate brdf``: fit every material of the table, write the materials YAML."""
    materials = Path(materials) if materials else config_path('materials.yaml')
    document = load_materials_document(materials)
    tables = read_brdf_csv(csv_path, material)
    cals = [calibrate_material(t, fit, noise_rel) for t in tables.values()]
    updates = {}
    for c in cals:
        kd, ks = sig(c.chosen.kd), sig(c.chosen.ks)
        if kd + ks > 1.0:  # the fit keeps kd + ks <= 1; rounding must not tip it over
            ks = float(f'{1.0 - kd:.12g}')
        updates[c.material] = {'kd': kd, 'ks': ks, 'n': sig(c.chosen.n)}
    doc, warnings = update_materials(document, updates, materials, template)
    header = [f'Materials calibrated by `lidar-sim calibrate brdf {csv_path}`',
              f'from {materials}: kd, ks, n of {", ".join(updates)} fitted ({fit} fit); '
              'everything else copied.']
    out = write_materials(out, doc, header)
    all_warnings = [w for c in cals for w in c.warnings] + warnings
    if figure:
        plot_brdf(cals, figure)
    report = '\n\n'.join(format_report(c) for c in cals)
    return BrdfResult(cals, out, all_warnings, report)
