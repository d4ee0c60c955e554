"""Whether a recorded intensity carries the measured range, and the intensity without it.

A range-compensated reflectivity computed with the sensor's *measured* range,
I = P r_meas^2 (/ cos^q), moves with the range's own error: at a fixed geometry
d ln I = 2 dr / r, about r / 2 metres of residual per neper of intensity (5 m at 10 m,
hundreds of times a range walk's slope). Read as a feature beside the model's range and
incidence, such an intensity hands the residual back to the joint feature model (the
attribution's ``structure_gain``): the range noise itself looks like structure no
catalogue effect explains, a phantom "outside the catalogue" on a null recording.

The test: neighbouring points (same cloud and material, nearest direction in the
sample) differ in their geometry smoothly but in their range noise independently, so
the slope of the difference in ln I on the difference in ln(r_meas / r_model), with the
differences of the model's ln P and ln r held, is about 2 for an intensity computed
with the measured range and about 0 for one that is not (a raw or counted power, even
where a reference-pose error moves the measured range off the model's: that part is
smooth between neighbours). A walk on a raw power gives a negative slope (weak returns
read long). Where the slope is nearer 2 than 0 and 4 standard errors above 0, the
attribution reads the intensity moved to the model's range, I (r_model / r_meas)^2:
the measured range's noise taken out, nothing else. Where the slope is nearer 0 than 2
and 4 standard errors below 2 (``free_of_measured_range``), a compensation for range in
the intensity's reading (I ~ P r^2) is undone with the model's range, not the measured
one: I / r_meas^2 would put the measured range's noise into the power. A raw-power
intensity is never re-expressed (the mend that did so everywhere made phantom structure
from pose errors).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# The slope of d ln I on d ln(r_meas / r_model): 2 for a compensation with the measured
# range, 0 without; taken as the measured range's when nearer 2 than 0 or 4 ...
SLOPE_LOW, SLOPE_HIGH = 1.0, 3.0
# ... and this many standard errors above 0.
SLOPE_Z = 4.0
# Neighbour pairs: at most this far apart (rad) and this far apart in the model's range
# (m: not across a depth step); differences of ln(r_meas / r_model) beyond this many
# robust sigmas are outliers' (a false return, a stray surface).
MAX_PAIR_RAD = 0.01
MAX_PAIR_DR_M = 0.1
OUTLIER_SIGMAS = 5.0
MIN_PAIRS = 100


@dataclass(frozen=True)
class RangeInIntensity:
    """The neighbour-difference slope of ln I on ln(r_meas / r_model) (-), its standard
    error, the pairs it rests on, and whether the intensity is read on the model's range."""

    slope: float
    se: float
    pairs: int
    re_expressed: bool

    @property
    def free(self) -> bool:
        """The intensity is shown not to carry the measured range (``free_of_measured_range``):
        a compensation for range in its reading is undone with the model's range, not the
        measured one (which would put the range's noise into the power)."""
        return not self.re_expressed and free_of_measured_range(self.slope, self.se)

    def as_dict(self) -> dict:
        return {'slope': round(self.slope, 3), 'se': round(self.se, 3), 'pairs': self.pairs,
                're_expressed': self.re_expressed, 'free': self.free,
                'why': ('the intensity carries the measured range (I ~ r_meas^2): the '
                        "attribution reads it at the model's range, I (r_model / r_meas)^2, "
                        "so the range's own noise is not read back as structure"
                        if self.re_expressed else
                        'the intensity does not carry the measured range: read as recorded '
                        "(a compensation for range in its reading, if any, undone with the "
                        "model's range: the measured one would put the range's noise into "
                        'the power)'
                        if self.free else
                        'the intensity does not carry the measured range: read as recorded')}


def neighbour_pairs(directions: np.ndarray, cloud: np.ndarray, material: np.ndarray,
                    range_model_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j): each point and its nearest direction in its cloud and material,
    within MAX_PAIR_RAD and MAX_PAIR_DR_M of the model's range; each pair once."""
    d = np.asarray(directions, float)
    key = np.asarray(cloud, np.int64) * 100_003 + np.asarray(material, np.int64)
    first, second = [], []
    for k in np.unique(key):
        idx = np.flatnonzero(key == k)
        if len(idx) < 2:
            continue
        dist, nn = cKDTree(d[idx]).query(d[idx], k=2)
        i, j = idx, idx[nn[:, 1]]
        ok = (dist[:, 1] <= MAX_PAIR_RAD) & (i < j)
        # A mutual pair is found from both ends; i < j keeps it once, and a one-way pair
        # (j's nearest is another) from its own end.
        one_way = (dist[:, 1] <= MAX_PAIR_RAD) & (i > j) & (idx[nn[nn[:, 1], 1]] != i)
        first += [i[ok], i[one_way]]
        second += [j[ok], j[one_way]]
    if not first:
        return np.zeros(0, int), np.zeros(0, int)
    i, j = np.concatenate(first), np.concatenate(second)
    keep = np.abs(range_model_m[i] - range_model_m[j]) <= MAX_PAIR_DR_M
    return i[keep], j[keep]


def measured_range_slope(intensity: np.ndarray, range_meas_m: np.ndarray,
                         range_model_m: np.ndarray, power_model_w: np.ndarray,
                         directions: np.ndarray, cloud: np.ndarray,
                         material: np.ndarray) -> tuple[float, float, int]:
    """(slope, standard error, pairs) of d ln I on d ln(r_meas / r_model) between
    neighbours, the differences of the model's ln P and ln r held (module doc); slope
    NaN with fewer than MIN_PAIRS usable pairs."""
    i_w = np.asarray(intensity, float)
    rm, rp, pw = (np.asarray(a, float) for a in (range_meas_m, range_model_m, power_model_w))
    ok = np.isfinite(i_w) & (i_w > 0) & (rm > 0) & (rp > 0) & np.isfinite(pw) & (pw > 0)
    idx = np.flatnonzero(ok)
    if len(idx) < 2 * MIN_PAIRS:
        return float('nan'), float('nan'), 0
    a, b = neighbour_pairs(np.asarray(directions)[idx], np.asarray(cloud)[idx],
                           np.asarray(material)[idx], rp[idx])
    if len(a) < MIN_PAIRS:      # neighbours too sparse (a spinning sensor's few rows)
        return float('nan'), float('nan'), int(len(a))
    a, b = idx[a], idx[b]
    x = np.log(rm[a] / rp[a]) - np.log(rm[b] / rp[b])
    y = np.log(i_w[a]) - np.log(i_w[b])
    controls = np.column_stack([np.log(pw[a] / pw[b]), np.log(rp[a] / rp[b])])
    # Outliers in either difference (a false return's range, a glint's or a saturated
    # count's intensity) are dropped before the fit, and the fit's own outliers after it:
    # one glint in a hundred pairs turned a slope of 2.0 into -2 +- 2.5 by least squares.
    keep = _within(x, np.ones_like(x, bool)) & _within(y, np.ones_like(y, bool))
    coef = None
    for _ in range(2):
        if keep.sum() < MIN_PAIRS:
            return float('nan'), float('nan'), int(keep.sum())
        X = np.column_stack([x[keep], controls[keep]])
        coef, *_ = np.linalg.lstsq(X, y[keep], rcond=None)
        full = y - np.column_stack([x, controls]) @ coef
        keep = keep & _within(full, keep)
    X = np.column_stack([x[keep], controls[keep]])
    coef, *_ = np.linalg.lstsq(X, y[keep], rcond=None)
    resid = y[keep] - X @ coef
    dof = max(int(keep.sum()) - X.shape[1], 1)
    cov = np.linalg.pinv(X.T @ X) * float(resid @ resid) / dof
    return float(coef[0]), float(np.sqrt(max(cov[0, 0], 0.0))), int(keep.sum())


def _within(v: np.ndarray, among: np.ndarray) -> np.ndarray:
    """Whether each value lies within OUTLIER_SIGMAS robust sigmas (1.4826 MAD) of the
    median of ``v[among]``."""
    ref = v[among]
    mid = np.median(ref)
    sigma = 1.4826 * np.median(np.abs(ref - mid))
    return np.abs(v - mid) <= OUTLIER_SIGMAS * max(sigma, 1e-12)


def carries_measured_range(slope: float, se: float) -> bool:
    """Whether the slope is a compensation with the measured range's (module doc)."""
    return (bool(np.isfinite(slope) and np.isfinite(se)) and SLOPE_LOW <= slope <= SLOPE_HIGH
            and slope >= SLOPE_Z * se)


def free_of_measured_range(slope: float, se: float) -> bool:
    """Whether the slope shows an intensity that does not carry the measured range: nearer
    0 than 2 and SLOPE_Z standard errors below 2 (``carries_measured_range`` mirrored). A
    reflectivity compensated with a range the sensor knew otherwise (an independent lab's
    true range; boxnull53) is one: its power is I / r^2 at the model's range, the best
    estimate of that range; read at the measured range, P (r / r_meas)^2 carries the
    range's own noise, 2 dr / r in ln P, and on flat faces of one power each the
    attribution's trees read the residual back from it (a phantom "outside the catalogue",
    0.07 nats/point on a null)."""
    return (bool(np.isfinite(slope) and np.isfinite(se)) and slope < SLOPE_LOW
            and slope <= 2.0 - SLOPE_Z * se)


def on_model_range(intensity: np.ndarray, range_meas_m: np.ndarray,
                   range_model_m: np.ndarray) -> np.ndarray:
    """The intensity moved from the measured range to the model's: I (r_model / r_meas)^2."""
    rm = np.asarray(range_meas_m, float)
    rp = np.asarray(range_model_m, float)
    ratio = np.where((rm > 0) & (rp > 0), rp / np.where(rm > 0, rm, 1.0), 1.0)
    return np.asarray(intensity, float) * ratio ** 2


def range_in_intensity(intensity, range_meas_m, range_model_m, power_model_w, directions,
                       cloud, material) -> RangeInIntensity:
    """The test on one sample's matched points (``measured_range_slope``)."""
    slope, se, pairs = measured_range_slope(intensity, range_meas_m, range_model_m,
                                            power_model_w, directions, cloud, material)
    return RangeInIntensity(slope, se, pairs, carries_measured_range(slope, se))
