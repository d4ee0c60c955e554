"""The sensor's intensity as received power: a calibration fitted against the model.

A recording's ``intensity`` is the sensor's own measure of each returned pulse, in
its own units: proportional to the received power, log-compressed counts, a
saturating amplifier's counts, or a range-compensated reflectivity. Effects driven
by the received power (range walk, SNR noise: ``Effect.power_driven``) see the
pulse that actually came back, so the comparison fits them against the measured
intensity, converted to received power in the model's units (W) by

    ln P = f(ln I) + c (ln r - mean ln r)

f: a monotone increasing map (isotonic regression of the model's ln P on ln I over
quantile bins, linear between bin centres and out to the extreme points), fitted to the model's own
predicted power on the matched points (robustly: bin medians); c: 0 for an
intensity that grows with the received power, -2 for a range-compensated
reflectivity (proportional to P r^2), whichever explains the model's power better. For a sensor whose intensity is
proportional to power, f(ln I) = ln I - ln G with G the intensity gain. The model's
power differs from the true one only through its reflectance numbers, which shift
ln P per material and incidence and average out in f; the shot-to-shot variation
the sensor saw (speckle, reflectance the mesh does not carry) stays in.

An intensity clipped at the top of its scale (an 8-bit reflectivity, a saturated
amplifier: many points at exactly the largest value) says only that the power was at
least the clip's: those points are left out of the map and given the larger of the
model's power and the clip level's (``IntensityCalibration.power_w``), so a walk read
from the intensity does not go flat where the scale ends.

A sensor that scales its intensity per cloud (an automatic gain control: one gain per
scan, set by the scan's brightest returns) adds one constant per cloud to ln I, the same
for every point of the cloud, which the map of all clouds together cannot take out: read
through it, the gain's spread becomes noise in the power (holdout 10's ``walk_agc``, a
lognormal gain of sd 0.5 in ln: the walk fitted 30 % low). The map is therefore fitted
with a gain per cloud, ln P = f(ln I) + c (...) - g_cloud (``cloud_gains``: the median over
the cloud of what the map reads above the model's power, the map refitted with them,
the clouds' median gain 0). They are used only where they explain the map's residual
held out: each cloud's gain fitted on one half of its points (alternate points) and
tried on the other, against the map without them, must gain CLOUD_GAIN_MIN_NATS of
log-likelihood in all and pass z CLOUD_GAIN_Z (the odds and the one-sided 1 % a
catalogue candidate must reach). The gains come from the intensity against the model's
power only, never from the ranges: they cannot take the walk itself.

An intensity in log counts (a flash sensor's 40 log10 P: intensity = a + b ln P) is
linear in ln P, not in P. The map above can follow it (it is monotone), but the reading
is tested: on the same points (below a clip, no range term, no per-cloud gain) the
model's ln P is fitted as a power law of the intensity, ln P = ln I / s + c (the linear
reading, I = g P^s; s ~ 1 for counts proportional to the power), and as an affine
function of it, ln P = (I - a) / b (the log reading). The one leaving at most
1 - SCALE_MARGIN of the other's unexplained variance is the scale (``scale_test``);
the terminal says which, with b for log counts (counts per e-fold of power: 40 log10 P
has b = 17.4). With log counts the power is read as exp((I - a) / b) when that leaves
at most 1 + SCALE_MARGIN times the map's unexplained variance (the map's freedom buys
little); otherwise, and for the linear reading or no clear margin, through the map, as
before (it is monotone, so it follows log counts as well). b is fitted against the model's
power, so a walk read through it carries the model's scale of ln P (the forced fit on
the model's power shows the same).

The map is fitted against the model's power, so it carries the model's scale of ln P: where
the model's reflectance law spans a narrower range of power than the truth's (another
lab's coatings against our Phong table), the regression of the model's ln P on the
intensity compresses the reading, and a walk fitted on it is over-read by the inverse
(walkscale53: +31 to +34 %). Two corrections, each from what is exact in the model:

* where the layout says what the intensity is (the Cepton drivers' reflectivity, ~ P r^2:
  ``unit_slope``), ln P = ln I - 2 (ln r - mean ln r) + offset, the slope held at 1 and
  only the offset fitted (``unit_slope_map``);
* for log counts, the *range lever* (``range_lever``): b from what is exact in the
  model, the range. Within cells of one material and one quantile bin of the model's
  incidence (one reflectance, whatever the law), ln P moves with the range as -2 ln r, so
  the counts against ln r (the model's range) have slope -2 b, less what still follows
  the incidence within a cell (linearly, per material). One b a material, its standard
  error clustered by cell; their inverse-variance mean, its error widened by their
  spread about it (Birge ratio). Asked where the scale test said 'log', or had no
  margin either way and the range says log: the lever on the counts at most 1 -
  SCALE_MARGIN as inconsistent across materials (Birge ratio) as the same lever on ln I
  (the power law), the materials sitting at different levels of the counts. Where b is
  pinned (relative standard error at most LEVER_MAX_REL_SE) and the b fitted on the
  model's power lies outside it by more than the lever can be trusted to
  (LEVER_B_MARGIN, and LEVER_B_Z standard errors), the power is read as
  exp((I - a) / b) with the range's b (``read_through`` 'range'; a the median of
  I - b ln P_model); otherwise as before, and the verdict says what is left. The
  figures: ``intensity_gain.counts_per_efold``. It assumes the reflectance is one
  function of the incidence per material, and the model's range and incidence right
  (a drifting reference pose moved it 16 % at 3 % standard error). On the foreign drum
  (another lab's law) at 10 m it read 17.09-17.65 for 17.37 (15.7-17.8 with speckle
  0.25), on the Blinn surfaces 17.37-17.41 (docs/compare.md, logwalk54).

The simulator keeps using its own predicted power; see docs/compare.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix, identity
from scipy.sparse.linalg import spsolve
from sklearn.isotonic import IsotonicRegression

MAX_BINS = 48
MIN_BIN_POINTS = 25
MIN_POINTS = 50
# Intensity proportional to the received power (0), or a range-compensated
# reflectivity, proportional to P r^2 (-2 in ln P per ln r): the one that explains the
# model's power best. A fitted exponent would also soak up whatever in the model's
# reflectance happens to correlate with range over the target.
RANGE_EXPONENTS = (0.0, -2.0)
# ... and the range-compensated reading is taken only if it leaves a fifth less of the
# model's ln P unexplained: a few per cent come from whatever in the model's reflectance
# correlates with range over the target, and a wrong compensation would put the
# measured range's noise into the power.
RANGE_TERM_GAIN = 0.2
# Below this share of the model's ln P variance explained, the intensity does not
# measure the received power (or not of these returns): power-driven effects keep the
# model's power.
MIN_EXPLAINED = 0.25
# A clipped scale: the largest value held by at least this share of the points and
# CLIP_SPIKE times as many as the most frequent of the other values at the top of the
# scale (the top CLIP_TOP_SHARE of distinct values): a pile-up, not a value like the others.
CLIP_MIN_SHARE = 0.01
CLIP_SPIKE = 5.0
CLIP_TOP_SHARE = 0.1
# A gain per cloud (module doc): fitted from this many points of a cloud (others keep the
# clouds' median gain, 0), refitted with the map this many rounds, and used only when it
# gains this much held-out log-likelihood of the map's residual (nats in all: odds e^15,
# as a catalogue candidate) at this z (one-sided 1 %).
CLOUD_GAIN_MIN_POINTS = 2 * MIN_POINTS
CLOUD_GAIN_ROUNDS = 4
CLOUD_GAIN_MIN_NATS = 15.0
CLOUD_GAIN_Z = 2.33
# The scale test (module doc): the log reading replaces the map when it leaves at most
# 1 - SCALE_MARGIN of the power law's unexplained variance of the model's ln P (the
# range term's margin), the power law is called linear the other way round; the power
# is read through the log reading when it leaves at most 1 + SCALE_MARGIN times the
# map's (else the map, which follows any monotone scale, stays).
SCALE_MARGIN = 0.2
# The range lever on log counts (module doc): per material, at most LEVER_BINS quantile
# bins of the incidence, LEVER_BIN_POINTS points a bin at least; b is called pinned when
# its relative standard error is at most LEVER_MAX_REL_SE (a walk's k known to 10 %), and
# read instead of the b fitted on the model's power when that one lies outside it by more
# than LEVER_B_MARGIN and LEVER_B_Z standard errors. The margin is the lever's own worst
# systematic seen, not its standard error: a reference pose drifting 0.9 deg within each
# scan (the battery's walk_with_drift, 8-bit counts) moved it 16 % above the counts' true
# slope at 3 % standard error, 33 % away from the model's b; the over-reads it is for are
# 55-110 % (the labs' 675 for 434, the foreign drum's 27-36 for 17.37).
LEVER_BIN_POINTS = 200
LEVER_BINS = 40
LEVER_MAX_REL_SE = 0.1
LEVER_B_MARGIN = 0.4
LEVER_B_Z = 2.0


@dataclass(frozen=True)
class IntensityCalibration:
    """ln P = interp(ln I; knots) + range_exponent (ln r - mean_log_range)."""

    knots_log_i: np.ndarray
    knots_log_p: np.ndarray
    range_exponent: float
    mean_log_range: float
    gain: float                  # median I / model intensity (sensor units per model unit)
    explained: float             # share of the model's ln P variance explained (-)
    log_residual_robust_sigma: float
    log_correlation: float
    points: int
    clip_log_i: float | None = None   # ln of the clipped top value (None: not clipped)
    clipped_share: float = 0.0        # share of the points at it
    # A gain per cloud (module doc): ln of each cloud's gain (cloud index -> ln g), empty
    # when not used; the held-out test that decided it (gain_nats, z, clouds, used).
    cloud_log_gain: dict = field(default_factory=dict)
    cloud_gain_test: dict | None = None
    # The scale test (module doc): 'log' (read as ln P = (I - log_a) / log_b), 'linear'
    # (a power law won: the map), None (no clear margin or not tried: the map).
    scale: str | None = None
    log_a: float = 0.0
    log_b: float = 1.0
    scale_test: dict | None = None
    # Log counts' b from the range (module doc): its figures (None: not tried), and the
    # slope held at 1.
    counts_per_efold: dict | None = None
    unit_slope: bool = False

    @property
    def usable(self) -> bool:
        return self.explained >= MIN_EXPLAINED

    @property
    def reads_log(self) -> bool:
        """The power is read through the log reading (module doc), not the map."""
        return (self.scale == 'log'
                and (self.scale_test or {}).get('read_through') in ('log', 'range'))

    def power_w(self, intensity: np.ndarray, range_m: np.ndarray,
                model_power_w: np.ndarray | None = None,
                cloud: np.ndarray | None = None) -> np.ndarray:
        """Received power (W, model units) per point; NaN where the intensity is not
        positive and finite. On a clipped scale the points at the clip get the larger of
        ``model_power_w`` (the model's power on the same points) and the clip's level.
        ``cloud`` (each point's cloud index): the per-cloud gain taken out, if used."""
        i = np.asarray(intensity, float)
        log_scale = self.reads_log
        ok = (np.isfinite(i) & ((i > 0) | log_scale) & np.isfinite(range_m) & (range_m > 0))
        log_p = np.full(len(i), np.nan)
        log_i = np.log(np.where(ok & (i > 0), i, 1.0))
        if log_scale:
            log_p[ok] = (i[ok] - self.log_a) / self.log_b
        else:
            log_p[ok] = np.interp(log_i[ok], self.knots_log_i, self.knots_log_p,
                                  right=self._clip_log_p())
        log_p[ok] += self.range_exponent * (np.log(range_m[ok]) - self.mean_log_range)
        if self.cloud_log_gain and cloud is not None:
            log_p[ok] -= cloud_lookup(self.cloud_log_gain, np.asarray(cloud)[ok])
        if self.clip_log_i is not None and model_power_w is not None:
            at_clip = ok & (i > 0) & (log_i >= self.clip_log_i)
            model = np.log(np.maximum(np.asarray(model_power_w, float)[at_clip], 1e-300))
            log_p[at_clip] = np.maximum(log_p[at_clip], np.nan_to_num(model, nan=-np.inf))
        return np.exp(log_p)

    def _clip_log_p(self) -> float | None:
        """ln P at the clipped value: the map's end slope continued to it (None: no clip)."""
        if self.clip_log_i is None:
            return None
        x, y = self.knots_log_i, self.knots_log_p
        slope = (y[-1] - y[-2]) / max(x[-1] - x[-2], 1e-12)
        return float(y[-1] + max(slope, 0.0) * max(self.clip_log_i - x[-1], 0.0))

    def as_dict(self) -> dict:
        return {'gain': self.gain, 'log_residual_robust_sigma': self.log_residual_robust_sigma,
                'log_correlation': self.log_correlation,
                'power_explained': round(self.explained, 4),
                'range_exponent': round(self.range_exponent, 4), 'points': self.points,
                'clipped_share': round(self.clipped_share, 4),
                'clipped_value': (None if self.clip_log_i is None
                                  else float(np.exp(self.clip_log_i))),
                'cloud_gain': self.cloud_gain_test,
                'intensity_scale': self.scale, 'scale_test': self.scale_test,
                'unit_slope': self.unit_slope, 'counts_per_efold': self.counts_per_efold,
                'used_for_power_driven_effects': self.usable}


def calibrate_intensity(intensity: np.ndarray, range_m: np.ndarray, model_power_w: np.ndarray,
                        model_intensity: np.ndarray | None = None,
                        range_exponents: tuple[float, ...] = RANGE_EXPONENTS,
                        cloud: np.ndarray | None = None,
                        material: np.ndarray | None = None,
                        unit_slope: bool = False,
                        model_range_m: np.ndarray | None = None,
                        incidence: np.ndarray | None = None,
                        ) -> IntensityCalibration | None:
    """Fit the map from measured intensity to the model's received power (module doc)
    on matched points; None if fewer than MIN_POINTS usable points. ``gain``: median
    measured / ``model_intensity`` (the model's intensity units; default its power).
    ``range_exponents``: the readings to choose from; ``(-2.0,)`` where the layout says
    the intensity is a range-compensated reflectivity (the Cepton drivers'). ``cloud``:
    each point's cloud index, to try a gain per cloud (module doc). ``material``: each
    point's material id in the model, ``incidence`` its incidence angle (rad) and
    ``model_range_m`` its range (m; None: the measured), for the range lever on log counts
    (module doc; either of the first two None: not tried).
    ``unit_slope``: the layout says the intensity is ~ P r^(-c) (module doc): the slope of
    ln I held at 1 (with the one range exponent given), no gain per cloud."""
    i = np.asarray(intensity, float)
    p = np.asarray(model_power_w, float)
    r = np.asarray(range_m, float)
    ok = np.isfinite(i) & (i > 0) & np.isfinite(p) & (p > 0) & np.isfinite(r) & (r > 0)
    if ok.sum() < MIN_POINTS:
        return None
    clip = clipped_value(i[ok])
    n_ok = int(ok.sum())
    clipped_share = 0.0
    if clip is not None:
        at_clip = i[ok] >= clip
        clipped_share = float(np.mean(at_clip))
        if n_ok - at_clip.sum() < MIN_POINTS:
            return None
        ok[np.flatnonzero(ok)[at_clip]] = False    # the map is fitted below the clip
    x, y, lr = np.log(i[ok]), np.log(p[ok]), np.log(r[ok])
    mean_lr = float(np.mean(lr))
    lr = lr - mean_lr
    best = None
    for c in range_exponents:
        knots_x, knots_y = _monotone_map(x, y - c * lr)
        resid = y - np.interp(x, knots_x, knots_y) - c * lr
        spread = float(np.var(resid))
        if best is None or spread < best[0] * (1.0 - RANGE_TERM_GAIN):
            best = (spread, c, knots_x, knots_y)
    spread, c, knots_x, knots_y = best
    if unit_slope:
        knots_x, knots_y = unit_slope_map(x, y - c * lr)
        spread = float(np.var(y - np.interp(x, knots_x, knots_y) - c * lr))
    log_gain, test = {}, None
    if cloud is not None and not unit_slope:
        knots_x, knots_y, log_gain, test = cloud_gains(x, y - c * lr,
                                                       np.asarray(cloud)[ok], knots_x, knots_y)
        if log_gain:
            spread = float(np.var(y - np.interp(x, knots_x, knots_y) - c * lr
                                  + cloud_lookup(log_gain, np.asarray(cloud)[ok])))
    var_y = float(np.var(y))
    scale, log_a, log_b, scale_test = None, 0.0, 1.0, None
    if c == 0.0 and not log_gain and not unit_slope:
        scale, log_a, log_b, scale_test = intensity_scale(np.exp(x), y)
        if scale == 'log':
            log_spread = float(np.var(y - (np.exp(x) - log_a) / log_b))
            # Read through the log reading only where the map's freedom buys little more:
            # a log-like scale of another shape (8-bit counts of u^0.85) keeps the map.
            read = log_spread <= (1.0 + SCALE_MARGIN) * spread
            scale_test['read_through'] = 'log' if read else 'map'
            if read:
                spread = log_spread
            else:
                log_a, log_b = 0.0, 1.0
    explained = 1.0 - spread / var_y if var_y > 0 else 0.0
    if unit_slope:
        # The slope held at 1 is not the model's: how well the reading measures the
        # power is its correlation with the model's (the share a line of any slope
        # explains), not what the unit line leaves.
        explained = line_share(np.interp(x, knots_x, knots_y) + c * lr, y, var_y)
    lever = None
    if (scale_test and scale != 'linear' and scale_test.get('log_b_per_efold')
            and material is not None and incidence is not None):
        # Log counts (or a reading the scale test could not tell from them): b from the
        # range within one material and incidence (module doc).
        lr_lever = (lr if model_range_m is None
                    else np.log(np.maximum(np.asarray(model_range_m, float)[ok], 1e-9)))
        mat_ok, inc_ok = np.asarray(material)[ok], np.asarray(incidence, float)[ok]
        lever = range_lever(np.exp(x), lr_lever, mat_ok, inc_ok)
        if lever is not None:
            # The shape from the range where the scale test had no margin: the materials
            # sit at different levels of the intensity, so only the right reading gives
            # them one slope (the power law's: the same lever on ln I).
            power_law = (None if scale == 'log' else range_lever(x, lr_lever, mat_ok, inc_ok))
            shape = ('scale test' if scale == 'log' else
                     'range' if (power_law is not None and lever['birge_ratio']
                                 <= (1.0 - SCALE_MARGIN) * power_law['birge_ratio'])
                     else None)
            b_model = float(scale_test['log_b_per_efold'])
            b_range = float(lever['per_efold'])
            off = max(LEVER_B_MARGIN, LEVER_B_Z * float(lever['rel_se']))
            used = bool(shape and lever['pinned']
                        and abs(np.log(b_model / b_range)) > np.log1p(off))
            lever = {**lever, 'fitted_on_model': round(b_model, 4), 'log_shape_from': shape,
                     'power_law_birge_ratio': (None if power_law is None
                                               else power_law['birge_ratio']),
                     'used': used}
            if used:
                scale, log_b = 'log', b_range
                log_a = float(np.median(np.exp(x) - log_b * y))
                scale_test['read_through'] = 'range'
                # As with the slope held at 1: the share a line of any slope explains.
                explained = line_share((np.exp(x) - log_a) / log_b, y, var_y)
    d = x - (y if model_intensity is None
             else np.log(np.maximum(np.asarray(model_intensity, float)[ok], 1e-300)))
    return IntensityCalibration(
        knots_log_i=knots_x, knots_log_p=knots_y, range_exponent=c, mean_log_range=mean_lr,
        gain=float(np.exp(np.median(d))),
        explained=float(max(explained, 0.0)),
        log_residual_robust_sigma=float(1.4826 * np.median(np.abs(d - np.median(d)))),
        log_correlation=float(np.corrcoef(x, y)[0, 1]) if np.ptp(x) > 0 else 0.0,
        points=int(ok.sum()),
        clip_log_i=None if clip is None else float(np.log(clip)),
        clipped_share=clipped_share, cloud_log_gain=log_gain, cloud_gain_test=test,
        scale=scale, log_a=log_a, log_b=log_b, scale_test=scale_test,
        counts_per_efold=lever, unit_slope=unit_slope)


def line_share(read: np.ndarray, y: np.ndarray, var_y: float) -> float:
    """The share of the variance of ``y`` (the model's ln P, variance ``var_y``) that a
    line of any slope through ``read`` (the power read from the intensity) explains."""
    return (float(np.corrcoef(read, y)[0, 1]) ** 2
            if np.ptp(read) > 0 and var_y > 0 else 0.0)


def unit_slope_map(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Knots of y = x + offset over the range of x (x = ln I, y = the model's ln P with
    the range term taken out): the slope held at 1, the offset the median of y - x
    (module doc)."""
    offset = float(np.median(y - x))
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi <= lo:
        lo, hi = lo - 1.0, lo + 1.0
    # Far beyond the points' range, so the reading stays a line for every intensity.
    knots_x = np.array([lo - 50.0, hi + 50.0])
    return knots_x, knots_x + offset


def range_lever(reading: np.ndarray, log_r: np.ndarray, material: np.ndarray,
                incidence: np.ndarray) -> dict | None:
    """The reading's slope per e-fold of received power from the range alone (module doc).

    ``reading``: the intensity in its own units (log counts); ``log_r``: ln of the model's
    range (any centre); ``material``: the model's material id; ``incidence``: the model's
    incidence angle (rad). Per material, cells of LEVER_BINS quantile bins of the incidence
    (LEVER_BIN_POINTS each at least); within them, less what still follows the incidence
    (linearly, per material), the reading against ln r has slope -2 b. Each material's b
    with its standard error clustered by cell; the materials' inverse-variance mean, its
    error widened by the spread of the materials about it (the Birge ratio, where above 1).
    None with no material of two cells or no range spread within them."""
    y, z = np.asarray(reading, float), np.asarray(log_r, float)
    mat, inc = np.asarray(material), np.asarray(incidence, float)
    ok = np.isfinite(y) & np.isfinite(z) & np.isfinite(inc)
    y, z, mat, inc = y[ok], z[ok], mat[ok], inc[ok]
    per = []
    for m in np.unique(mat):
        sel = np.flatnonzero(mat == m)
        n_bins = int(min(LEVER_BINS, len(sel) // LEVER_BIN_POINTS))
        if n_bins < 2:
            continue
        edges = np.quantile(inc[sel], np.linspace(0.0, 1.0, n_bins + 1))
        cell = np.clip(np.searchsorted(edges, inc[sel], side='right') - 1, 0, n_bins - 1)
        counts = np.bincount(cell, minlength=n_bins).astype(float)
        counts[counts == 0] = 1.0

        def within(v):
            return v - (np.bincount(cell, v, n_bins) / counts)[cell]

        yc, zc, tc = within(y[sel]), within(z[sel]), within(inc[sel])
        tt = float(np.sum(tc ** 2))
        if tt > 0:
            yc = yc - (np.sum(yc * tc) / tt) * tc
            zc = zc - (np.sum(zc * tc) / tt) * tc
        den = float(np.sum(zc ** 2))
        if not np.isfinite(den) or den <= 1e-12 * len(sel):
            continue
        slope = float(np.sum(yc * zc)) / den
        e = yc - slope * zc
        se = float(np.sqrt(np.sum(np.bincount(cell, e * zc, n_bins) ** 2)) / den)
        if se > 0 and np.isfinite(se):
            per.append((-0.5 * slope, 0.5 * se, len(sel), float(np.std(zc))))
    if not per:
        return None
    b, se, n, sd = (np.array(v, float) for v in zip(*per))
    w = 1.0 / se ** 2
    mean = float(np.sum(w * b) / np.sum(w))
    birge = (float(np.sqrt(np.sum(w * (b - mean) ** 2) / (len(b) - 1))) if len(b) > 1
             else 1.0)
    err = float(np.sqrt(1.0 / np.sum(w))) * max(birge, 1.0)
    rel = err / abs(mean) if mean != 0 else float('inf')
    return {'per_efold': round(mean, 4), 'se': round(err, 4), 'rel_se': round(rel, 4),
            'materials': int(len(b)), 'birge_ratio': round(birge, 3),
            'points': int(n.sum()),
            'range_sd_within_cells': round(float(np.sqrt(np.sum(n * sd ** 2) / n.sum())), 4),
            'pinned': bool(mean > 0 and rel <= LEVER_MAX_REL_SE)}


def intensity_scale(intensity: np.ndarray, log_p: np.ndarray
                    ) -> tuple[str | None, float, float, dict | None]:
    """The scale test (module doc) on positive intensities and the model's ln P (W):
    ('log' | 'linear' | None, a, b, the test's record). Least squares of ln P on ln I (the
    power law) and on I (the log reading, ln P = (I - a) / b); the reading leaving at most
    1 - SCALE_MARGIN of the other's residual variance wins. None when neither does, or
    the intensity does not grow with the power under the log reading (b <= 0)."""
    i, y = np.asarray(intensity, float), np.asarray(log_p, float)
    if len(i) < MIN_POINTS or np.ptp(i) <= 0:
        return None, 0.0, 1.0, None
    var = {}
    coef = {}
    for name, x in (('linear', np.log(i)), ('log', i)):
        slope, icpt = np.polyfit(x, y, 1)
        var[name] = float(np.var(y - (slope * x + icpt)))
        coef[name] = (float(slope), float(icpt))
    slope, icpt = coef['log']
    b = 1.0 / slope if slope > 0 else float('nan')
    a = -icpt * b if slope > 0 else float('nan')
    if var['log'] <= (1.0 - SCALE_MARGIN) * var['linear'] and slope > 0:
        scale = 'log'
    elif var['linear'] <= (1.0 - SCALE_MARGIN) * var['log'] and coef['linear'][0] > 0:
        scale = 'linear'
    else:
        scale = None
    test = {'unexplained_linear': round(var['linear'], 5), 'unexplained_log': round(var['log'], 5),
            'power_law_exponent': round(1.0 / coef['linear'][0], 4) if coef['linear'][0] > 0
            else None, 'log_b_per_efold': round(b, 4) if np.isfinite(b) else None,
            'chosen': scale}
    return scale, (a if scale == 'log' else 0.0), (b if scale == 'log' else 1.0), test


def cloud_gains(x: np.ndarray, y: np.ndarray, cloud: np.ndarray, knots_x: np.ndarray,
                knots_y: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict, dict | None]:
    """A gain per cloud for the map y = f(x) (x = ln I, y = the model's ln P, range term
    taken out), and its held-out test (module doc). Returns the knots of the map refitted
    with the gains, the gains (cloud -> ln g; {} when not used: then the knots given) and
    the test (None with fewer than two clouds of CLOUD_GAIN_MIN_POINTS)."""
    ids, inverse, counts = np.unique(cloud, return_inverse=True, return_counts=True)
    fitted = counts >= CLOUD_GAIN_MIN_POINTS
    if fitted.sum() < 2:
        return knots_x, knots_y, {}, None
    # Alternate points of each cloud: one half fits the gains the other is tried on.
    order = np.argsort(inverse, kind='stable')
    rank = np.empty(len(x), int)
    rank[order] = np.arange(len(x)) - np.repeat(np.cumsum(counts) - counts, counts)
    half = rank % 2
    # Alternating the map and the medians alone creeps: where one bright cloud fills the
    # top of the scale, the map there fits that cloud's own points and its gain barely
    # moves (holdout 10's walk_agc_42: 0.45 in ln short after 4 rounds). The map and the
    # gains fitted together by least squares start them near the answer; the robust
    # rounds (bin medians, cloud medians) then polish.
    gains = _least_squares_gains(x, y, inverse, fitted)
    kx, ky = _monotone_map(x, y + gains[inverse])
    gains = _median_per_cloud(np.interp(x, kx, ky) - y, inverse, fitted)
    for _ in range(CLOUD_GAIN_ROUNDS):
        kx, ky = _monotone_map(x, y + gains[inverse])
        gains = _median_per_cloud(np.interp(x, kx, ky) - y, inverse, fitted)
    # Held out: y - f(x) without gains, and y - f(x) + g with each point's cloud gain g
    # from the other half of the cloud's points.
    base = y - np.interp(x, knots_x, knots_y)
    reads_above = np.interp(x, kx, ky) - y
    crossed = np.empty(len(x))
    for h in (0, 1):
        g = _median_per_cloud(np.where(half == h, reads_above, np.nan), inverse, fitted)
        crossed[half != h] = (g[inverse] - reads_above)[half != h]
    s0, s1 = np.sqrt(np.mean(base ** 2)), np.sqrt(np.mean(crossed ** 2))
    d = (0.5 * (base / s0) ** 2 + np.log(s0)) - (0.5 * (crossed / s1) ** 2 + np.log(s1))
    total = float(np.sum(d))
    z = float(np.mean(d) / (np.std(d) / np.sqrt(len(d)))) if np.std(d) > 0 else 0.0
    used = total >= CLOUD_GAIN_MIN_NATS and z >= CLOUD_GAIN_Z
    test = {'gain_nats': round(total, 1), 'z': round(z, 2), 'clouds': int(fitted.sum()),
            'used': bool(used),
            'log_gain_sd': round(float(np.std(gains[fitted])), 4)}
    if not used:
        return knots_x, knots_y, {}, test
    return kx, ky, {int(c): float(g) for c, g in zip(ids, gains)}, test


def cloud_lookup(log_gain: dict, cloud: np.ndarray) -> np.ndarray:
    """ln g of each point's cloud (0 for clouds without their own gain)."""
    keys = np.fromiter(log_gain.keys(), int, len(log_gain))
    vals = np.fromiter(log_gain.values(), float, len(log_gain))
    order = np.argsort(keys)
    keys, vals = keys[order], vals[order]
    pos = np.clip(np.searchsorted(keys, cloud), 0, len(keys) - 1)
    return np.where(keys[pos] == cloud, vals[pos], 0.0)


def _least_squares_gains(x: np.ndarray, y: np.ndarray, inverse: np.ndarray,
                         fitted: np.ndarray) -> np.ndarray:
    """Per cloud the ln gain g of y + g = f(x), f piecewise linear between MAX_BINS + 1
    quantiles of x, fitted together by least squares on the points of the fitted clouds
    (sparse: two map weights and one gain per point); recentred as _median_per_cloud."""
    use = fitted[inverse]
    xs, ys, cl = x[use], y[use], inverse[use]
    knots = np.unique(np.quantile(xs, np.linspace(0.0, 1.0, MAX_BINS + 1)))
    g = np.zeros(len(fitted))
    if len(knots) < 2:
        return g
    j = np.clip(np.searchsorted(knots, xs, side='right') - 1, 0, len(knots) - 2)
    w = np.clip((xs - knots[j]) / (knots[j + 1] - knots[j]), 0.0, 1.0)
    # Unknowns: the map at the knots, then the gains of the fitted clouds but the first
    # (its gain 0 fixes the common level): y = f(x) - g.
    col = np.cumsum(fitted) - 1
    first = col[cl] == 0
    n, k = len(xs), len(knots)
    rows = np.concatenate([np.arange(n), np.arange(n), np.flatnonzero(~first)])
    cols = np.concatenate([j, j + 1, k - 1 + col[cl][~first]])
    vals = np.concatenate([1.0 - w, w, -np.ones(int((~first).sum()))])
    a = csr_matrix((vals, (rows, cols)), shape=(n, k + int(fitted.sum()) - 1))
    normal = (a.T @ a).tocsc()
    normal = normal + 1e-9 * normal.diagonal().max() * identity(normal.shape[0], format='csc')
    sol = spsolve(normal, a.T @ ys)
    g[np.flatnonzero(fitted)[1:]] = sol[k:]
    g[fitted] -= np.median(g[fitted])
    return g


def _median_per_cloud(v: np.ndarray, inverse: np.ndarray, fitted: np.ndarray) -> np.ndarray:
    """Per cloud the median of v (NaN ignored) less the median over the fitted clouds;
    0 for clouds not fitted."""
    g = np.zeros(len(fitted))
    for j in np.flatnonzero(fitted):
        vals = v[inverse == j]
        vals = vals[np.isfinite(vals)]
        g[j] = np.median(vals) if len(vals) else 0.0
    g[fitted] -= np.median(g[fitted])
    g[~fitted] = 0.0
    return g


def clipped_value(intensity: np.ndarray) -> float | None:
    """The value at which the intensity scale is clipped (module doc), or None: the
    largest value, when it holds CLIP_MIN_SHARE of the points (MIN_BIN_POINTS at least)
    and CLIP_SPIKE times as many as any other value among the top CLIP_TOP_SHARE of
    distinct values."""
    values, counts = np.unique(np.asarray(intensity, float), return_counts=True)
    if len(values) < 2:
        return None
    top = counts[-1]
    if top < max(MIN_BIN_POINTS, CLIP_MIN_SHARE * counts.sum()):
        return None
    others = counts[max(len(values) - 1 - max(int(CLIP_TOP_SHARE * len(values)), 1), 0):-1]
    return float(values[-1]) if top >= CLIP_SPIKE * others.max() else None


def _monotone_map(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Knots of a monotone increasing y(x): bin medians over quantile bins of x (one bin
    per distinct value when there are few, as for integer counts), made monotone by
    isotonic regression weighted by the bin counts."""
    values = np.unique(x)
    if len(values) <= MAX_BINS:
        idx = np.searchsorted(values, x)
        n_bins = len(values)
    else:
        n_bins = int(np.clip(len(x) // MIN_BIN_POINTS, 2, MAX_BINS))
        edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, n_bins + 1)))
        idx = np.clip(np.searchsorted(edges, x, side='right') - 1, 0, len(edges) - 2)
        n_bins = len(edges) - 1
    counts = np.bincount(idx, minlength=n_bins)
    keep = np.flatnonzero(counts > 0)
    order = np.argsort(idx, kind='stable')
    bounds = np.concatenate([[0], np.cumsum(counts)])
    bx = np.array([np.median(x[order[bounds[b]:bounds[b + 1]]]) for b in keep])
    by = np.array([np.median(y[order[bounds[b]:bounds[b + 1]]]) for b in keep])
    if len(bx) == 1:
        return np.array([bx[0] - 1.0, bx[0] + 1.0]), np.array([by[0], by[0]])
    fy = np.asarray(IsotonicRegression(increasing=True).fit_transform(
        bx, by, sample_weight=counts[keep]), float)
    # The outermost points lie beyond the end bins' medians: continue the end slopes
    # out to them (flat beyond).
    lo_slope = (fy[1] - fy[0]) / max(bx[1] - bx[0], 1e-12)
    hi_slope = (fy[-1] - fy[-2]) / max(bx[-1] - bx[-2], 1e-12)
    x_lo, x_hi = float(x.min()), float(x.max())
    if x_lo < bx[0]:
        bx, fy = np.append(x_lo, bx), np.append(fy[0] - lo_slope * (bx[0] - x_lo), fy)
    if x_hi > bx[-1]:
        bx, fy = np.append(bx, x_hi), np.append(fy, fy[-1] + hi_slope * (x_hi - bx[-1]))
    return bx, fy
