"""Attribution: which variable does the range residual depend on, given the others?

Features per matched point: range, incidence, intensity (measured, else the model's),
azimuth, elevation, time, material, edge (distance to a silhouette or depth step),
range_rate (how fast the target surface moves along the ray) and laser (the ring or
channel id, when the recording has more than one: a per-laser calibration residue). The residual is
normalised, z = (measured - expected) / predicted sigma, per-material offsets removed.

Two scores per feature, both in nats per point:

* **marginal** (what the feature explains alone): the points are binned along the
  feature (quantile bins, or categories) and z is summarised per bin by a robust
  centre (median) and spread (MAD); the score is the information the bins carry
  about z under a Gaussian per bin,
  0.5 sum_b w_b (m_b - m)^2 / s^2 + sum_b w_b (log s_b - mean log s)^2
  (conditional-mean plus conditional-spread part), minus the same statistic with the
  feature shuffled (what noise alone gives). It drives the binned profiles and plots.
* **score** (what the feature explains given the others; the ranking): a joint model
  of z's conditional mean and variance on all features (gradient-boosted trees,
  scikit-learn's HistGradientBoostingRegressor: squared error for the mean, gamma
  deviance for the squared deviation), fitted on part of the points and scored on the
  rest by the Gaussian log-likelihood; a feature's score is the held-out log-likelihood
  lost when the joint model is refitted without it (drop-column importance).

Why drop-column and not permutation importance: with correlated features (a short
pass at near-constant range, where intensity is nearly a function of incidence and
material) permuting one feature breaks its link to the others, so every member of a
correlated group looks important; refitting without it asks what the data say
without that feature, which is the conditional dependence the diagnosis needs. When
the residual depends on a group of features that stand in for each other, every
member scores near zero although the joint model gains: the attribution then names
them as confounded (``Attribution.confounded``) instead of ranking one of them first.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import norm
from sklearn.ensemble import HistGradientBoostingRegressor
from threadpoolctl import threadpool_limits

from lidar_sim_ros.compare.model.materials import MAD_TO_SIGMA

FEATURE_NAMES = ('range', 'incidence', 'intensity', 'azimuth', 'elevation', 'time',
                 'material', 'edge', 'range_rate', 'laser')
CATEGORICAL = ('material', 'edge', 'laser')
# Categories the joint model can split on (HistGradientBoosting: below its max_bins).
MAX_TREE_CATEGORIES = 64
UNITS = {'range': 'm', 'incidence': 'deg', 'intensity': 'log10', 'azimuth': 'deg',
         'elevation': 'deg', 'time': 's', 'material': '', 'edge': 'mrad', 'range_rate': 'm/s',
         'laser': ''}
# Axis labels, one per feature the attribution can rank (the report plots any of them).
LABELS = {'range': 'range (m)', 'incidence': 'incidence angle (deg)',
          'intensity': 'log10 intensity', 'azimuth': 'azimuth (deg)',
          'elevation': 'elevation (deg)', 'time': 'time since cloud stamp (s)',
          'material': 'material', 'edge': 'distance to edge (mrad)',
          'range_rate': 'range rate along the ray (m/s)', 'laser': 'laser (ring / channel id)'}
POWER_LABEL = 'log10 measured power (W)'
# ... where the intensity carried the measured range and is read at the model's
# (intensity_range).
POWER_LABEL_MODEL_RANGE = "log10 measured power at the model's range (W)"
MIN_BIN_POINTS = 30
MAX_BINS = 16
N_SHUFFLES = 4
# The joint model: a held-out share of the points, at most this many to fit and score.
TEST_SHARE = 0.4
MAX_FIT_POINTS = 10_000
Z_CLIP = 5.0                  # |z| beyond this is an outlier's business (solar background)
# A feature or the joint model "explains" the residual when its held-out gain is this
# many (block-robust) standard errors above zero, Bonferroni over the features tested
# (one-sided, family error rate 1 %), and ...
FAMILY_ALPHA = 0.01
# ... at least this many nats per point: a dependence that moves the predicted mean by
# ~4 % of sigma RMS (0.5 * 0.045^2) is below what anyone would model.
MIN_FEATURE_GAIN = 0.001
MAX_DROPPED = 5               # drop-column refits for the features with the most marginal


@dataclass(frozen=True)
class FeatureScore:
    """One feature's attribution and its binned residual profile (for plots).

    score: held-out log-likelihood the joint model loses without the feature (nats per
    point, >= 0; what it explains given the others); score_z: that in block-robust
    standard errors; marginal = mean_part + spread_part: what the binned feature
    explains alone (noise-corrected, >= 0); significance: the marginal excess over
    noise in units of the shuffle spread. Bins: edges or category labels, count, robust
    centre and spread of the residual (m) and of z.
    """

    name: str
    score: float
    mean_part: float
    spread_part: float
    significance: float
    labels: list
    centers: np.ndarray
    counts: np.ndarray
    median_m: np.ndarray
    p16_m: np.ndarray
    p84_m: np.ndarray
    z_median: np.ndarray
    z_spread: np.ndarray
    trend: str
    marginal: float = 0.0
    score_z: float = 0.0

    def as_dict(self) -> dict:
        return {'name': self.name, 'score': round(self.score, 6),
                'score_z': round(self.score_z, 2), 'marginal': round(self.marginal, 6),
                'mean_part': round(self.mean_part, 6), 'spread_part': round(self.spread_part, 6),
                'significance': round(self.significance, 2), 'trend': self.trend}


@dataclass(frozen=True)
class Attribution:
    """Features best first by what each explains given the others, and the verdict on
    the residual's structure as a whole.

    structure_gain: held-out nats per point the joint model of all features gains over
    a constant mean and spread (what a perfect catalogue effect could at most explain
    through these features), structure_z its block-robust z. driver: the feature that
    explains most given the others, significantly, with no other adding half as much;
    confounded: when no feature explains the structure given the others, those that
    explain it alone (they stand in for each other in this recording).
    """

    features: list[FeatureScore]
    structure_gain: float
    structure_z: float
    z_crit: float
    driver: str | None
    confounded: list[str]
    per_point_gain: np.ndarray | None = None   # held-out points' gains (joint model)

    @property
    def significant(self) -> bool:
        return self.structure_z >= self.z_crit and self.structure_gain >= MIN_FEATURE_GAIN

    def as_dict(self) -> dict:
        return {'structure_gain': round(self.structure_gain, 6),
                'structure_z': round(self.structure_z, 2), 'significant': self.significant,
                'driver': self.driver, 'confounded': self.confounded}


def feature_values(matching, intensity_model: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per matched point: the feature values (see UNITS); range_rate if the matching has it."""
    m = matching.meas
    sel = matching.matched
    ctx = matching.pred.ctx
    if m.intensity is not None:
        inten = m.intensity[sel]
    else:
        inten = ctx.intensity[sel] if intensity_model is None else intensity_model
    pos = inten[np.isfinite(inten) & (inten > 0)]
    floor = np.min(pos) if len(pos) else 1e-12
    az = np.degrees(np.arctan2(m.directions[sel, 1], m.directions[sel, 0]))
    el = np.degrees(np.arcsin(np.clip(m.directions[sel, 2], -1, 1)))
    time = m.t_frame_s[sel] if m.has_point_time else (m.t_s[sel] - m.t_s.min())
    return {
        'range': np.asarray(ctx.range_m[sel], float),
        'incidence': np.degrees(np.asarray(ctx.incidence_rad[sel], float)),
        'intensity': np.log10(np.maximum(np.nan_to_num(inten, nan=floor), floor)),
        'azimuth': az, 'elevation': el, 'time': time,
        'material': np.asarray(ctx.material[sel], int),
        'edge': np.round(matching.edge_rad[sel] * 1e3, 4),
        **({'range_rate': np.asarray(matching.range_rate_mps[sel], float)}
           if getattr(matching, 'range_rate_mps', None) is not None else {}),
        **({'laser': np.asarray(m.laser[sel], int)} if len(np.unique(m.laser[sel])) > 1
           else {}),
    }


def _bins(x: np.ndarray, categorical: bool, n_bins: int) -> tuple[np.ndarray, list, np.ndarray]:
    """Bin index per point, bin labels and bin centres."""
    if categorical:
        cats, idx = np.unique(x, return_inverse=True)
        return idx, [c.item() if hasattr(c, 'item') else c for c in cats], cats.astype(float)
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    if len(edges) < 3:
        return np.zeros(len(x), int), ['all'], np.array([np.median(x)])
    idx = np.clip(np.searchsorted(edges, x, side='right') - 1, 0, len(edges) - 2)
    centers = np.array([np.median(x[idx == b]) if np.any(idx == b) else np.nan
                        for b in range(len(edges) - 1)])
    labels = [f'{edges[b]:.4g}..{edges[b + 1]:.4g}' for b in range(len(edges) - 1)]
    return idx, labels, centers


def _robust_by_bin(z: np.ndarray, idx: np.ndarray,
                   n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bin: median, MAD sigma and count of z."""
    order = np.argsort(idx, kind='stable')
    zs, ids = z[order], idx[order]
    bounds = np.searchsorted(ids, np.arange(n + 1))
    med = np.full(n, np.nan)
    spr = np.full(n, np.nan)
    cnt = np.diff(bounds)
    for b in range(n):
        part = zs[bounds[b]:bounds[b + 1]]
        if len(part):
            med[b] = np.median(part)
            spr[b] = MAD_TO_SIGMA * np.median(np.abs(part - med[b]))
    return med, spr, cnt


def _information(z: np.ndarray, idx: np.ndarray, n: int) -> tuple[float, float]:
    """(mean part, spread part) of the per-bin Gaussian information, nats/point."""
    med, spr, cnt = _robust_by_bin(z, idx, n)
    ok = (cnt >= MIN_BIN_POINTS) & (spr > 0)
    if ok.sum() < 2:
        return 0.0, 0.0
    w = cnt[ok] / cnt[ok].sum()
    centre = np.median(z)
    total = MAD_TO_SIGMA * np.median(np.abs(z - centre))
    if total <= 0:
        return 0.0, 0.0
    m_bar = np.sum(w * med[ok])
    mean_part = 0.5 * np.sum(w * (med[ok] - m_bar) ** 2) / total ** 2
    log_s = np.log(spr[ok])
    spread_part = np.sum(w * (log_s - np.sum(w * log_s)) ** 2)
    return float(mean_part), float(spread_part)


def varies(x: np.ndarray) -> bool:
    """Whether a feature can explain anything: two distinct finite values at least (a
    column all NaN, as range_rate is on a target closing faster than 5 m/s, whose 5 ms
    step moves every range past ``matching.range_rate_mps``'s 2.5 cm jump cut, or one
    value everywhere, carries no information and stopped the trees' binning)."""
    x = np.asarray(x)
    if x.dtype.kind not in 'fc':
        return len(np.unique(x)) > 1
    finite = x[np.isfinite(x)]
    return finite.size > 1 and bool(np.any(finite != finite[0]))


def score_features(values: dict[str, np.ndarray], residual_m: np.ndarray, z: np.ndarray,
                   seed: int = 0, blocks: np.ndarray | None = None) -> list[FeatureScore]:
    """Every feature's attribution, best first (``attribute(...).features``)."""
    return attribute(values, residual_m, z, seed, blocks).features


def attribute(values: dict[str, np.ndarray], residual_m: np.ndarray, z: np.ndarray,
              seed: int = 0, blocks: np.ndarray | None = None) -> Attribution:
    """Marginal and conditional scores of every feature (module doc), best first by the
    conditional score. ``residual_m`` and ``z`` are over matched points; ``blocks``
    (optional, per point) groups neighbouring points whose residuals may share a misfit,
    for the standard errors (default: every point its own block)."""
    names = [n for n in FEATURE_NAMES if n in values and varies(values[n])]
    marginal = [marginal_score(n, values[n], residual_m, z, seed) for n in names]
    by_name = {f.name: f for f in marginal}
    blocks = np.arange(len(z)) if blocks is None else np.asarray(blocks)
    cond = conditional_scores(values, names, z, blocks, seed, [
        f.name for f in sorted(marginal, key=lambda f: -f.score)[:MAX_DROPPED]
        if f.score > 0])
    z_crit = float(norm.isf(FAMILY_ALPHA / max(len(names), 1)))
    feats = []
    for name in names:
        f = by_name[name]
        unique, unique_z = cond['unique'].get(name, (0.0, 0.0))
        feats.append(replace(f, score=float(max(unique, 0.0)), score_z=float(unique_z),
                             marginal=f.score))
    feats.sort(key=lambda f: (-f.score, -f.marginal))
    gain, gain_z = cond['structure']
    explains = [f for f in feats if f.score_z >= z_crit and f.score >= MIN_FEATURE_GAIN]
    alone = [f.name for f in sorted(feats, key=lambda f: -f.marginal)
             if f.significance > 5 and f.marginal >= MIN_FEATURE_GAIN and f.name != 'material']
    structure = gain_z >= z_crit and gain >= MIN_FEATURE_GAIN
    driver = None
    confounded: list[str] = []
    if structure:
        second = explains[1].score if len(explains) > 1 else 0.0
        if explains and second < 0.5 * explains[0].score:
            # It explains the residual given all the others, and no other feature adds
            # half as much given the rest: the driver.
            driver = explains[0].name
        elif not explains:
            # The structure is there but no feature holds any of it on its own: the
            # features that explain it alone stand in for each other.
            confounded = alone[:4] if len(alone) >= 2 else []
    return Attribution(feats, float(gain), float(gain_z), z_crit, driver, confounded,
                       cond['per_point'])


def marginal_score(name: str, x: np.ndarray, residual_m: np.ndarray, z: np.ndarray,
                   seed: int = 0) -> FeatureScore:
    """The binned, model-free score of one feature (module doc) and its profile."""
    rng = np.random.default_rng([seed, FEATURE_NAMES.index(name) if name in FEATURE_NAMES
                                 else 99])
    n_pts = len(z)
    n_bins = int(np.clip(n_pts // 150, 2, MAX_BINS))
    idx, labels, centers = _bins(x, name in CATEGORICAL, n_bins)
    nb = len(labels)
    mean_part, spread_part = _information(z, idx, nb)
    null = np.array([_information(z[rng.permutation(n_pts)], idx, nb)
                     for _ in range(N_SHUFFLES)])
    null_mean = null.mean(axis=0)
    null_sd = float(np.std(null.sum(axis=1), ddof=1)) if len(null) > 1 else 0.0
    excess_mean = max(mean_part - null_mean[0], 0.0)
    excess_spread = max(spread_part - null_mean[1], 0.0)
    excess = mean_part + spread_part - null_mean.sum()
    # Few shuffles give a rough spread; a chi-square-like statistic over ~2 x bins
    # degrees of freedom has sd ~ 0.25 x its mean, which bounds it from below.
    sig = excess / max(null_sd, 0.25 * null_mean.sum(), 1e-12)
    med_m, p16, p84, zmed, zspr = _profiles(residual_m, z, idx, nb)
    cnt = np.bincount(idx, minlength=nb)
    return FeatureScore(
        name=name, score=float(max(excess, 0.0)), mean_part=float(excess_mean),
        spread_part=float(excess_spread), significance=float(sig), labels=labels,
        centers=np.asarray(centers, float), counts=cnt, median_m=med_m, p16_m=p16,
        p84_m=p84, z_median=zmed, z_spread=zspr,
        trend=_trend(name, centers, med_m, p84 - p16, cnt))


def block_mean_se(d: np.ndarray, blocks: np.ndarray) -> tuple[float, float]:
    """Mean of per-point values and its standard error with points grouped in blocks
    (cluster-robust: blocks are independent, points within a block need not be)."""
    d = np.asarray(d, float)
    n = len(d)
    if n < 2:
        return float(np.mean(d)) if n else 0.0, float('inf')
    mean = float(np.mean(d))
    _, b = np.unique(blocks, return_inverse=True)
    k = int(b.max()) + 1
    if k < 2:
        return mean, float('inf')
    sums = np.bincount(b, weights=d - mean, minlength=k)
    se = float(np.sqrt(k / (k - 1) * np.sum(sums ** 2)) / n)
    return mean, se


def conditional_scores(values: dict[str, np.ndarray], names: list[str], z: np.ndarray,
                       blocks: np.ndarray, seed: int, to_drop: list[str]) -> dict:
    """Held-out gain of the joint model over a constant (``structure``: mean, z) and
    each dropped feature's loss (``unique``: name -> (mean, z)), nats per point."""
    n = len(z)
    out = {'structure': (0.0, 0.0), 'unique': {}, 'per_point': None}
    if n < 200:
        return out
    rng = np.random.default_rng([seed, 41])
    # Whole blocks go to the test side, so a test point's neighbours did not train it.
    _, b = np.unique(blocks, return_inverse=True)
    test_block = rng.random(int(b.max()) + 1) < TEST_SHARE
    test = test_block[b]
    train_idx, test_idx = np.flatnonzero(~test), np.flatnonzero(test)
    if len(train_idx) < 100 or len(test_idx) < 100:
        return out
    if len(train_idx) > MAX_FIT_POINTS:
        train_idx = np.sort(rng.choice(train_idx, MAX_FIT_POINTS, replace=False))
    if len(test_idx) > MAX_FIT_POINTS:
        test_idx = np.sort(rng.choice(test_idx, MAX_FIT_POINTS, replace=False))
    zc = np.clip(np.asarray(z, float), -Z_CLIP, Z_CLIP)
    X = np.column_stack([np.asarray(values[k], float) for k in names])
    if 'laser' in names:
        # Dense category codes; a sensor with more lasers than the trees take splits on
        # the id as a number.
        k = names.index('laser')
        codes = np.unique(X[:, k], return_inverse=True)[1]
        X[:, k] = codes
    cat = [names.index(k) for k in CATEGORICAL if k in names and (
        k == 'material' or (k == 'laser' and X[:, names.index(k)].max() < MAX_TREE_CATEGORIES))]
    X[:, cat] = np.where(np.isfinite(X[:, cat]) & (X[:, cat] >= 0), X[:, cat], np.nan)
    z_tr, z_te = zc[train_idx], zc[test_idx]
    centre = float(np.median(z_tr))
    scale = max(MAD_TO_SIGMA * float(np.median(np.abs(z_tr - centre))), 1e-3)
    base = _gauss_nll(z_te, np.full(len(z_te), centre), np.full(len(z_te), scale ** 2))
    with threadpool_limits(limits=1, user_api='openmp'):
        full = _joint_nll(X, names, cat, train_idx, test_idx, z_tr, z_te, None, seed)
        gain_pp = base - full
        out['per_point'] = gain_pp
        out['structure'] = block_mean_z(gain_pp, blocks[test_idx])
        for name in to_drop:
            drop = _joint_nll(X, names, cat, train_idx, test_idx, z_tr, z_te,
                              names.index(name), seed)
            out['unique'][name] = block_mean_z(drop - full, blocks[test_idx])
    return out


def block_mean_z(d: np.ndarray, blocks: np.ndarray) -> tuple[float, float]:
    """The mean of ``d`` and its z over neighbourhood blocks (``block_mean_se``; z 0
    where the standard error is zero or unknown)."""
    mean, se = block_mean_se(d, blocks)
    return mean, (float(mean / se) if se > 0 and np.isfinite(se) else 0.0)


def _gauss_nll(z: np.ndarray, mean: np.ndarray, var: np.ndarray) -> np.ndarray:
    var = np.maximum(var, 1e-6)
    return 0.5 * (np.log(2 * np.pi * var) + (z - mean) ** 2 / var)


def _joint_nll(X: np.ndarray, names: list[str], cat: list[int], train_idx: np.ndarray,
               test_idx: np.ndarray, z_tr: np.ndarray, z_te: np.ndarray, drop: int | None,
               seed: int) -> np.ndarray:
    """Held-out per-point Gaussian NLL of z under boosted-tree models of its conditional
    mean and variance on the features (without column ``drop``)."""
    cols = [k for k in range(len(names)) if k != drop]
    cat_mask = [k in cat for k in cols]
    Xs = X[:, cols]
    x_tr, x_te = Xs[train_idx], Xs[test_idx]
    mean_model = _booster('squared_error', cat_mask, seed).fit(x_tr, z_tr)
    m_tr, m_te = mean_model.predict(x_tr), mean_model.predict(x_te)
    dev2 = (z_tr - m_tr) ** 2 + 1e-4
    var_model = _booster('gamma', cat_mask, seed).fit(x_tr, dev2)
    return _gauss_nll(z_te, m_te, var_model.predict(x_te))


def _booster(loss: str, categorical: list[bool], seed: int) -> HistGradientBoostingRegressor:
    return HistGradientBoostingRegressor(
        loss=loss, learning_rate=0.1, max_iter=80, max_leaf_nodes=15, min_samples_leaf=60,
        l2_regularization=1.0, max_bins=64,
        categorical_features=categorical if any(categorical) else None,
        early_stopping=True, validation_fraction=0.2, n_iter_no_change=6, random_state=seed)


def _profiles(res: np.ndarray, z: np.ndarray, idx: np.ndarray, nb: int):
    med = np.full(nb, np.nan)
    p16 = np.full(nb, np.nan)
    p84 = np.full(nb, np.nan)
    zmed, zspr, _ = _robust_by_bin(z, idx, nb)
    for b in range(nb):
        part = res[idx == b]
        if len(part):
            med[b], p16[b], p84[b] = np.median(part), *np.percentile(part, [16, 84])
    return med, p16, p84, zmed, zspr


def _trend(name: str, centers: np.ndarray, med: np.ndarray, width: np.ndarray,
           cnt: np.ndarray) -> str:
    """A plain-language description of how the residual moves along the feature."""
    ok = (cnt >= MIN_BIN_POINTS) & np.isfinite(med)
    if ok.sum() < 2:
        return 'no trend'
    c, m, w = centers[ok], med[ok], width[ok]
    if name in CATEGORICAL:
        hi, lo = int(np.argmax(m)), int(np.argmin(m))
        return (f'residual median ranges from {m[lo] * 100:+.1f} cm to {m[hi] * 100:+.1f} cm '
                f'across {name} values; spread from {w.min() * 50:.1f} to {w.max() * 50:.1f} cm')
    slope = np.polyfit(c, m, 1)[0] if np.ptp(c) > 0 else 0.0
    wslope = np.polyfit(c, w, 1)[0] if np.ptp(c) > 0 else 0.0
    unit = UNITS[name]
    parts = []
    dm = slope * np.ptp(c)
    dw = 0.5 * wslope * np.ptp(c)
    if abs(dm) > 1e-4:
        parts.append(f'residual {"grows" if dm > 0 else "falls"} by {abs(dm) * 100:.1f} cm '
                     f'over {name} {c.min():.3g}..{c.max():.3g} {unit}'.rstrip())
    if abs(dw) > 1e-4:
        parts.append(f'spread {"grows" if dw > 0 else "shrinks"} by {abs(dw) * 100:.1f} cm')
    return '; '.join(parts) or 'flat'
