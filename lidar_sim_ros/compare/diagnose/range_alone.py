"""Whether a named range term stands in for a bias that follows range alone.

A range walk follows the received power: at one range the power still varies with the
incidence angle and the material, and so does a walk's bias. A range scale follows range
linearly (a clock). A range error outside the catalogue (a near-range bias of the
receiver's recovery, say 6 cm (8 / r)^2) follows range alone, in its own shape. On an
approach the power falls as 1 / r^2, so a walk or a scale fitted to such a bias gains
enough to be named, though neither is the cause.

The test asks the residual (measured minus the model without the named term, per-material
offsets as nuisance) which it follows, held out: a smooth function of range alone
(``range_columns``) against the same smooth function of the named term's own variable
(``DRIVER``: the walk's log power) or, for a term that is already a function of range,
against its own form (the scale's linear range). Each is linear least squares in z units
(the residual over the predicted sigma; points beyond Z_CLIP robust sigmas of the first
fit left out of the second), fitted on one half of the neighbourhood blocks
and scored on the other (two-fold), both with one intercept per material. When range
alone is decisively better, by the same rule a candidate is named by (its paired
held-out gain per point at least ``MIN_PRACTICAL_GAIN``, at z above the diagnosis's
bound), the named term stands in for a range-dependent bias outside the catalogue, and
the verdict says so. A real walk (power varying at one range), or a real scale (linear
in range), is not beaten by range alone: where the data cannot tell them apart nothing
is said.

A range scale has one more mark: its bias is zero at zero range. Over the narrow span of
ranges of a short approach a bias of range alone is close to linear, and range alone
does not beat the scale's own form; but the scale fitted to it is its local slope, and
the offset of the bias at the recording's ranges is left to the materials: with the
scale, every material's range is then off its configuration alike (``materials.
common_offset_m``, the rule by which the verdict says a sensor's range offset). A scale
and a common range offset together are two effects where a bias of range alone is one:
the scale then stands in too (``offset_m``, the common offset it leaves).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.compare.diagnose.features import Z_CLIP, block_mean_z
from lidar_sim_ros.compare.model.materials import MAD_TO_SIGMA, common_offset_m
from lidar_sim_ros.compare.model.materials import MIN_POINTS as MATERIAL_POINTS

# The named term -> what its bias follows: 'log_power' (a smooth function of the log of
# the power it is fitted on) or 'range_linear' (its own form, linear in range).
DRIVER = {'range_walk': 'log_power', 'range_scale': 'range_linear'}
# Terms whose bias is zero at zero range: with them, no common offset of the materials.
ZERO_AT_NO_RANGE = ('range_scale',)
KNOT_QUANTILES = (0.25, 0.5, 0.75)    # a piecewise-linear function of the variable
MIN_POINTS = 200                      # fewer matched points: not asked


@dataclass(frozen=True)
class RangeAlone:
    """The test's outcome: ``gain`` (nats per matched point, held out) of a function of
    range alone over the named term's ``against``, its block-robust ``z``, and whether
    it passes the rule (``stands_in``)."""

    name: str
    against: str
    gain: float
    z: float
    stands_in: bool
    # The materials' common range offset (m) the named term, zero at zero range, leaves
    # (``ZERO_AT_NO_RANGE``; None: none, or not asked).
    offset_m: float | None = None

    @property
    def range_alone_passes(self) -> bool:
        return self.stands_in and self.offset_m is None

    def as_dict(self) -> dict:
        return {'named': self.name, 'range_alone_against': self.against,
                'gain_per_matched_point': round(self.gain, 6), 'z': round(self.z, 2),
                'common_offset_left_m': (None if self.offset_m is None
                                         else round(self.offset_m, 4)),
                'stands_in_for_a_range_bias_outside_the_catalogue': self.stands_in}


def hinge_columns(x: np.ndarray) -> np.ndarray:
    """A piecewise-linear function's columns in ``x``: x and (x - k)+ at the knots
    (``KNOT_QUANTILES`` of x itself, never of the residual)."""
    x = np.asarray(x, float)
    knots = np.quantile(x, KNOT_QUANTILES)
    return np.column_stack([x, *[np.maximum(x - k, 0.0) for k in knots]])


def range_columns(range_m: np.ndarray) -> np.ndarray:
    """Range alone, as smooth as the walk's alternative: ``hinge_columns`` of r (m)."""
    return hinge_columns(range_m)


def driver_columns(driver: str, range_m: np.ndarray, power_w: np.ndarray) -> np.ndarray:
    """What the named term's bias follows (``DRIVER``), as columns."""
    if driver == 'log_power':
        return hinge_columns(np.log(power_w))
    if driver == 'range_linear':
        return np.asarray(range_m, float)[:, None]
    raise ValueError(f'unknown driver {driver!r}')


def heldout_nll(cols: np.ndarray, material: np.ndarray, z: np.ndarray, w: np.ndarray,
                test: np.ndarray) -> np.ndarray:
    """Per test point Gaussian NLL (nats) of z under least squares on ``cols`` (each
    column divided by the point's sigma: ``w`` = 1 / sigma) and one intercept per
    material, fitted on the points not in ``test``: once, then again without the points
    beyond Z_CLIP robust sigmas (false returns, a heavy tail); a test point's residual
    counts up to Z_CLIP of the fit's sigma (an outlier costs both sides alike)."""
    mats = np.unique(material)
    inter = (material[:, None] == mats[None, :]).astype(float)
    x = np.column_stack([inter, cols]) * w[:, None]
    x = x / np.maximum(np.sqrt(np.mean(x ** 2, axis=0)), 1e-12)
    train = np.flatnonzero(~test)
    coef, *_ = np.linalg.lstsq(x[train], z[train], rcond=None)
    res = z[train] - x[train] @ coef
    spread = MAD_TO_SIGMA * float(np.median(np.abs(res - np.median(res))))
    kept = train[np.abs(res) <= Z_CLIP * max(spread, 1e-6)]
    if len(kept) > x.shape[1]:
        coef, *_ = np.linalg.lstsq(x[kept], z[kept], rcond=None)
        train = kept
    var = max(float(np.mean((z[train] - x[train] @ coef) ** 2)), 1e-6)
    r = np.clip(z[test] - x[test] @ coef, -Z_CLIP * np.sqrt(var), Z_CLIP * np.sqrt(var))
    return 0.5 * (np.log(2 * np.pi * var) + r ** 2 / var)


def common_offset_left_m(residual_m: np.ndarray, named_bias_m: np.ndarray,
                         material: np.ndarray) -> float | None:
    """The materials' common range offset from their configuration (m) once the named
    term's bias is taken off (each material's median, those with MATERIAL_POINTS points
    at least; ``materials.common_offset_m``), or None."""
    left = residual_m - named_bias_m
    ids, counts = np.unique(material, return_counts=True)
    return common_offset_m([float(np.median(left[material == m]))
                            for m, k in zip(ids, counts) if m >= 0 and k >= MATERIAL_POINTS])


def weigh_range_alone(name: str, residual_m: np.ndarray, sigma_m: np.ndarray,
                     range_m: np.ndarray, power_w: np.ndarray, material: np.ndarray,
                     blocks: np.ndarray, z_crit: float, min_gain: float,
                     seed: int = 0, named_bias_m: np.ndarray | None = None
                     ) -> RangeAlone | None:
    """Whether the named term ``name`` stands in for a bias that follows range alone
    (module doc); None where it is not a range term of ``DRIVER`` or too few points
    have finite figures. Inputs per matched point: the residual without the named term
    (m) against the configured materials, its predicted sigma (m), the model's range (m),
    the power the term is fitted on (W), the material id, the neighbourhood block, and
    (for a term zero at zero range) the named term's bias as fitted (m)."""
    driver = DRIVER.get(name)
    if driver is None:
        return None
    asked = name in ZERO_AT_NO_RANGE and named_bias_m is not None
    if named_bias_m is None:
        named_bias_m = np.zeros(len(residual_m))
    residual_m, sigma_m, range_m, power_w, material, blocks, named_bias_m = (
        np.asarray(a) for a in (residual_m, sigma_m, range_m, power_w, material, blocks,
                                named_bias_m))
    ok = (np.isfinite(residual_m) & np.isfinite(sigma_m) & (sigma_m > 0)
          & np.isfinite(range_m) & (range_m > 0) & np.isfinite(power_w) & (power_w > 0))
    if ok.sum() < MIN_POINTS:
        return None
    w = 1.0 / sigma_m[ok]
    z = residual_m[ok] * w
    r, p, mat, blk = range_m[ok], power_w[ok], material[ok], blocks[ok]
    # Whole blocks on either side: a test point's neighbours did not fit it.
    _, b = np.unique(blk, return_inverse=True)
    half = np.random.default_rng([seed, 59]).random(int(b.max()) + 1) < 0.5
    side = half[b]
    if side.all() or not side.any():
        return None
    alone, other = range_columns(r), driver_columns(driver, r, p)
    d = np.empty(len(z))
    for test in (side, ~side):
        d[test] = (heldout_nll(other, mat, z, w, test) - heldout_nll(alone, mat, z, w, test))
    gain, zz = block_mean_z(d, blk)
    against = ('a function of the received power' if driver == 'log_power'
               else 'its own form, linear in range')
    offset = (common_offset_left_m(residual_m[ok], named_bias_m[ok], mat)
              if asked else None)
    return RangeAlone(name, against, float(gain), float(zz),
                      bool((gain >= min_gain and zz >= z_crit) or offset is not None), offset)


# --------------------------------------------- a per-cloud pose against range alone
# A range error of the sensor outside the catalogue that follows range (a cyclic error
# of the receiver, 5 cm cos(2 pi r / 3 m)) has no catalogue term to stand in for it; on
# an approach each cloud sits at another range, so a per-cloud pose correction takes
# it, and a pose was claimed on exact poses (the twelfth holdout's out_cyclic). Before
# a per-cloud pose is claimed it is weighed against a smooth function of range alone
# on the pose test's own footing (``pose_error.fit_reference_pose``: the same residual,
# sigmas, points and held-out halves): a piecewise-linear function of the model's range
# on a uniform grid of knots, as fine as the training half supports (``range_fit``: the
# knots chosen among ``knot_ladder`` by a held-out split of the training points alone).
RANGE_KNOTS_PER_CLOUD = 6        # the pose's parameters a cloud: the coarsest grid
KNOT_SPACINGS_M = (1.0, 0.5, 0.25, 0.125)   # and grids this fine (m)
MIN_KNOTS = 4
POINTS_PER_KNOT = 50             # fewer usable points a knot: fewer knots
RANGE_RIDGE = 1e-6               # relative ridge, as the pose test's (TEST_RIDGE)


@dataclass(frozen=True)
class RangeDesign:
    """A piecewise-linear function of range (hat functions on ``n_knots`` knots evenly
    over the usable points' range: point i weighs knot ``k[i]`` by 1 - ``f[i]`` and the
    next by ``f[i]``; the hats sum to one) and one intercept per material (``m``: each
    point's material row of ``n_mat``). Its normal equations are sums over the points
    (``np.bincount``): two hats a point, never an (N, K) matrix."""

    k: np.ndarray
    f: np.ndarray
    m: np.ndarray
    n_knots: int
    n_mat: int

    @property
    def size(self) -> int:
        return self.n_knots + self.n_mat

    def _parts(self, at: np.ndarray):
        """(index, weight) pairs of the rows ``at``: the two hats and the intercept."""
        k, f = self.k[at], self.f[at]
        hats = ((k, 1.0 - f), (k + 1, f))
        return hats + ((self.n_knots + self.m[at], np.ones(len(at))),) if self.n_mat else hats

    def gram(self, at: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(K, K) B' W^2 B over the rows ``at`` (``w``: their weights)."""
        n = self.size
        out = np.zeros(n * n)
        parts = self._parts(at)
        for i, (ci, vi) in enumerate(parts):
            for cj, vj in parts[i:]:
                v = np.bincount(ci * n + cj, weights=w ** 2 * vi * vj, minlength=n * n)
                out += v
                if cj is not ci:
                    out += v.reshape(n, n).T.ravel()
        return out.reshape(n, n)

    def cross(self, at: np.ndarray, w: np.ndarray, y: np.ndarray) -> np.ndarray:
        """B' W^2 y over the rows ``at``: (K,) for y (len(at),), (K, P) for y (len(at), P)."""
        y = np.asarray(y, float)
        flat = y.reshape(len(at), -1)
        out = np.zeros((self.size, flat.shape[1]))
        for c, v in self._parts(at):
            for j in range(flat.shape[1]):
                out[:, j] += np.bincount(c, weights=w ** 2 * v * flat[:, j],
                                         minlength=self.size)
        return out[:, 0] if y.ndim == 1 else out

    def predict(self, coef: np.ndarray) -> np.ndarray:
        """(N,) the function and intercepts at every point."""
        all_ = np.arange(len(self.k))
        return sum(coef[c] * v for c, v in self._parts(all_))


def range_design(range_m: np.ndarray, use: np.ndarray, n_knots: int,
                 material: np.ndarray | None = None) -> RangeDesign:
    """The hats of range (m) on ``n_knots`` knots spread evenly over the ``use`` points'
    range (one knot pair spanning nothing where the range spans nothing) and one
    intercept per ``material`` id (none where None): the materials' offsets refitted
    with the function of range, as each material's median taken out before does not
    leave a function of range where the materials sit at different ranges (the nozzle
    at the far end)."""
    r = np.asarray(range_m, float)
    lo, hi = (float(np.min(r[use])), float(np.max(r[use]))) if np.any(use) else (0.0, 0.0)
    n_knots = max(int(n_knots), 2)
    step = (hi - lo) / (n_knots - 1) if hi > lo else 1.0
    x = np.clip((np.where(np.isfinite(r), r, lo) - lo) / step, 0.0, n_knots - 1.0)
    k = np.minimum(np.floor(x).astype(int), n_knots - 2)
    if material is None:
        return RangeDesign(k, x - k, np.zeros(len(r), int), n_knots, 0)
    ids, m = np.unique(np.asarray(material), return_inverse=True)
    return RangeDesign(k, x - k, m, n_knots, len(ids))


def knot_ladder(n_clouds: int, span_m: float, n_use: int) -> list[int]:
    """Knot counts to choose among: the pose's parameters (RANGE_KNOTS_PER_CLOUD a cloud)
    and grids KNOT_SPACINGS_M apart over the range span (m), each at most one knot per
    POINTS_PER_KNOT usable points and at least MIN_KNOTS."""
    cap = max(MIN_KNOTS, n_use // POINTS_PER_KNOT)
    wanted = [RANGE_KNOTS_PER_CLOUD * n_clouds,
              *[int(np.ceil(span_m / h)) + 1 for h in KNOT_SPACINGS_M]]
    return sorted({int(min(max(MIN_KNOTS, k), cap)) for k in wanted})


def range_fit(range_m: np.ndarray, residual_m: np.ndarray, sigma_m: np.ndarray,
              use: np.ndarray, train: np.ndarray, n_clouds: int, seed: int = 0,
              material: np.ndarray | None = None) -> RangeDesign:
    """The function of range alone for one held-out fold (with one intercept per
    ``material``): the knot count of ``knot_ladder`` that, fitted on one half of the
    ``train`` points, scores best on the other (Gaussian NLL in sigma units); the test
    points are never seen."""
    r = np.where(np.isfinite(range_m), range_m, 0.0)
    span = float(np.ptp(r[use])) if np.any(use) else 0.0
    ladder = knot_ladder(n_clouds, span, int(use.sum()))
    idx = np.flatnonzero(train)
    inner = np.random.default_rng([seed, 67]).integers(0, 2, len(idx)).astype(bool)
    fit_on, score_on = np.zeros(len(r), bool), np.zeros(len(r), bool)
    fit_on[idx[inner]], score_on[idx[~inner]] = True, True
    best, best_design = np.inf, None
    for k in ladder:
        design = range_design(r, use, k, material)
        c = fit_range_function(design, residual_m, sigma_m, fit_on)
        nll = float(np.sum(((residual_m - c)[score_on] / sigma_m[score_on]) ** 2))
        if nll < best:
            best, best_design = nll, design
    return best_design


def solve_ridged(gram: np.ndarray, rhs: np.ndarray, ridge: float) -> np.ndarray:
    """``gram`` x = ``rhs`` with a relative ridge (``ridge`` x its mean diagonal)."""
    n = len(gram)
    return solve_or_lstsq(gram + np.diag(np.full(n, ridge * max(np.trace(gram), 1e-12) / n)),
                          rhs)


def solve_or_lstsq(ata: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``ata`` x = ``rhs``; least squares where ``ata`` is singular (a block of columns
    that carries nothing, e.g. one pose rate for the recording on a single cloud, whose
    times the directions fix: ``scan_clock.beyond_direction``)."""
    try:
        return np.linalg.solve(ata, rhs)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(np.nan_to_num(ata), np.nan_to_num(rhs), rcond=None)[0]


def fit_range_function(design: RangeDesign, residual_m: np.ndarray, sigma_m: np.ndarray,
                       train: np.ndarray) -> np.ndarray:
    """(N,) the range correction (m) of a function of range alone (``design``) fitted
    by weighted least squares on the ``train`` points (light relative ridge), at every
    point."""
    at = np.flatnonzero(train)
    w = 1.0 / np.asarray(sigma_m, float)[at]
    coef = solve_ridged(design.gram(at, w),
                        design.cross(at, w, np.asarray(residual_m, float)[at]), RANGE_RIDGE)
    return design.predict(coef)


@dataclass(frozen=True)
class PoseAgainstRange:
    """A pose correction against a function of range alone, held out on the pose
    test's halves: range alone's gain over nothing (nats per matched point, z); the
    pose's gain beyond it, nested (the pose fitted on top of range alone, jointly, over
    range alone; paired per point, z); and the pose's gain over range alone's as
    alternatives (``pose_margin``: negative where range alone explains more)."""

    knots: int
    range_gain: float
    range_z: float
    pose_beyond_gain: float
    pose_beyond_z: float
    pose_margin: float = 0.0

    def range_passes(self, z_crit: float, min_gain: float) -> bool:
        return self.range_z >= z_crit and self.range_gain >= min_gain

    def pose_passes(self, z_crit: float, min_gain: float) -> bool:
        """The pose beats range alone by the rule a candidate is named by."""
        return self.pose_beyond_z >= z_crit and self.pose_beyond_gain >= min_gain

    def outcome(self, z_crit: float, min_gain: float) -> str:
        """'pose': range alone does not pass the rule (no rival: as every name in a tie,
        a range error is weighed only where its own test passes), or the pose gains
        beyond range alone by the rule (a range error of the sensor may be there too;
        the pose is); 'range': range alone explains the residual at least as well as
        the pose (a range error of the sensor that follows range); 'tie': the data
        cannot tell the two."""
        if not self.range_passes(z_crit, min_gain) or self.pose_passes(z_crit, min_gain):
            return 'pose'
        if self.pose_margin <= 0.0:
            return 'range'
        return 'tie'

    def as_dict(self) -> dict:
        return {'knots': self.knots, 'gain_per_matched_point': round(self.range_gain, 6),
                'z': round(self.range_z, 3),
                'pose_gain_beyond': round(self.pose_beyond_gain, 6),
                'pose_z_beyond': round(self.pose_beyond_z, 3),
                'pose_margin_over_range': round(self.pose_margin, 6)}
