"""Per-material range error: measured versus modelled bias and sigma, refit as nuisance.

The paper models range error as a constant bias and sigma per material (Table 2).
A mismatch there is a calibration matter, not a missing physical effect, so the
comparison measures both per material with robust statistics (median, MAD), reports
them, and refits them before any candidate effect is scored.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.core.config import MaterialConfig, MaterialsConfig
from lidar_sim_ros.core.pipeline import Prediction

MAD_TO_SIGMA = 1.4826
CHI2_1_MEDIAN = 0.454936423   # median of z^2 for z ~ N(0, 1)
MIN_POINTS = 20          # fewer points leave a material's bias/sigma as configured
MISMATCH_Z = 5.0         # significance of a bias or sigma mismatch (standard errors)
MISMATCH_MIN_FRACTION = 0.1   # ... and at least this fraction of the modelled sigma
# Every material's range offset alike (at least this many materials, each within this
# share of the largest, the same sign, their mean at least this many metres): a range
# offset of the sensor or the reference pose along the line of sight, not the materials.
COMMON_OFFSET_MATERIALS = 3
COMMON_OFFSET_SPREAD = 0.5
COMMON_OFFSET_MIN_M = 0.01


def robust_sigma(x: np.ndarray) -> float:
    """MAD-based standard deviation (outlier tolerant)."""
    x = np.asarray(x, float)
    if len(x) == 0:
        return float('nan')
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


@dataclass(frozen=True)
class MaterialStats:
    """One material: modelled vs measured bias and sigma (m), from matched points."""

    name: str
    points: int
    model_bias_m: float
    model_sigma_m: float
    measured_bias_m: float
    measured_sigma_m: float
    bias_mismatch: bool
    sigma_mismatch: bool

    def as_dict(self) -> dict:
        return {'points': self.points,
                'model_bias_m': self.model_bias_m, 'measured_bias_m': self.measured_bias_m,
                'model_sigma_m': self.model_sigma_m, 'measured_sigma_m': self.measured_sigma_m,
                'bias_mismatch': self.bias_mismatch, 'sigma_mismatch': self.sigma_mismatch}


def material_stats(materials: MaterialsConfig, pred: Prediction, residual_m: np.ndarray,
                   matched: np.ndarray, far_m: np.ndarray | None = None
                   ) -> list[MaterialStats]:
    """Measured bias = modelled bias + median residual; measured sigma = robust spread of
    the residual, less the noise the enabled effects already add (in quadrature).
    ``far_m`` (per point, m): points whose |residual| exceeds it are no range of the
    material (a false return, a wrapped range, clutter within the target's depth) and
    are left out: a material seen only through them is not measured (the eleventh
    holdout's wrapped NOZZLE, 29 points 10.6 m short, was refit to a -10.57 m bias)."""
    out = []
    mat = np.where(matched, pred.ctx.material, -1)
    if far_m is not None:
        with np.errstate(invalid='ignore'):
            mat = np.where(np.abs(residual_m) <= far_m, mat, -1)
    for m_id, cfg in enumerate(materials.materials):
        sel = mat == m_id
        n = int(sel.sum())
        if n == 0:
            continue
        res = residual_m[sel]
        extra_var = np.maximum(pred.sigma_m[sel] ** 2 - cfg.sigma_m ** 2, 0.0)
        spread = robust_sigma(res)
        d_bias = float(np.median(res))
        meas_sigma = material_sigma_m(res - d_bias, extra_var)
        se_bias = 1.2533 * max(spread, 1e-6) / np.sqrt(n)
        se_sigma = 1.65 * max(spread, 1e-6) / np.sqrt(2 * n)    # MAD is ~37 % efficient
        floor = MISMATCH_MIN_FRACTION * max(cfg.sigma_m, 1e-3)
        out.append(MaterialStats(
            name=cfg.name, points=n, model_bias_m=cfg.bias_m, model_sigma_m=cfg.sigma_m,
            measured_bias_m=cfg.bias_m + d_bias, measured_sigma_m=meas_sigma,
            bias_mismatch=bool(n >= MIN_POINTS and abs(d_bias) > max(MISMATCH_Z * se_bias, floor)),
            sigma_mismatch=bool(n >= MIN_POINTS and abs(meas_sigma - cfg.sigma_m)
                                > max(MISMATCH_Z * se_sigma, floor))))
    return out


def material_sigma_m(residual_m: np.ndarray, extra_var_m2: np.ndarray) -> float:
    """Robust ML-like material sigma s (m) when each point's noise is s^2 + extra_var
    (the enabled effects' noise, in quadrature): the s at which the median of
    residual^2 / (s^2 + extra_var) is the median of chi2(1).

    Subtracting the mean extra variance from a robust spread instead would be biased
    low when the extra noise varies from point to point (the MAD of a scale mixture is
    below its RMS), and a too small material sigma lends any noise effect a false gain.
    """
    r2 = np.asarray(residual_m, float) ** 2
    e2 = np.broadcast_to(np.asarray(extra_var_m2, float), r2.shape)
    if len(r2) == 0:
        return float('nan')

    def excess(s: float) -> float:
        return float(np.median(r2 / np.maximum(s * s + e2, 1e-18))) - CHI2_1_MEDIAN

    if excess(0.0) <= 0:
        return 0.0
    lo, hi = 0.0, 4.0 * float(np.sqrt(np.median(r2) / CHI2_1_MEDIAN)) + 1e-6
    while excess(hi) > 0:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


def refit_materials(materials: MaterialsConfig, stats: list[MaterialStats]) -> MaterialsConfig:
    """The materials with bias/sigma replaced by the measured ones (enough points only)."""
    by_name = {s.name: s for s in stats if s.points >= MIN_POINTS}
    rows = []
    for cfg in materials.materials:
        s = by_name.get(cfg.name)
        if s is None:
            rows.append(cfg)
            continue
        sigma = max(s.measured_sigma_m, 0.05 * cfg.sigma_m, 1e-4)
        rows.append(MaterialConfig(**{**cfg.model_dump(), 'bias_m': s.measured_bias_m,
                                      'sigma_m': sigma}))
    return MaterialsConfig(materials=rows)


def materials_yaml(materials: MaterialsConfig, stats: list[MaterialStats]) -> str:
    """The refit bias/sigma as materials.yaml rows (only materials seen in the data)."""
    seen = {s.name for s in stats if s.points >= MIN_POINTS}
    lines = ['# per-material range error refit by lidar-sim compare (paste into materials.yaml)',
             'materials:']
    for m in materials.materials:
        mark = '' if m.name in seen else '   # not seen: unchanged'
        lines.append(f'  - {{name: {m.name}, kd: {m.kd:g}, ks: {m.ks:g}, n: {m.n:g}, '
                     f'bias_m: {m.bias_m:.5f}, sigma_m: {m.sigma_m:.5f}}}{mark}')
    return '\n'.join(lines) + '\n'


def common_offset_m(offsets_m) -> float | None:
    """The mean of the materials' range offsets from their configuration (m) when every
    material is off alike (COMMON_OFFSET_*), else None."""
    d = np.asarray(list(offsets_m), float)
    d = d[np.isfinite(d)]
    if (len(d) < COMMON_OFFSET_MATERIALS or not (np.all(d > 0) or np.all(d < 0))
            or np.min(np.abs(d)) < COMMON_OFFSET_SPREAD * np.max(np.abs(d))
            or abs(float(np.mean(d))) < COMMON_OFFSET_MIN_M):
        return None
    return float(np.mean(d))
