"""Measured intensity as received power (compare/recording/intensity.py), and power-driven effects
fitted against it (compare/model/likelihood.py: Effect.power_driven)."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import ahead_fit_data

from lidar_sim_ros.compare.model.fit import fit_effect
from lidar_sim_ros.compare.recording.intensity import calibrate_intensity
from lidar_sim_ros.compare.model.likelihood import FitData
from lidar_sim_ros.core.effects import get_effect_class

P_TH = 1e-7


def _powers(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return 10 ** rng.uniform(-6.5, -3.5, n), rng.uniform(8.0, 14.0, n)


def test_intensity_proportional_to_power_gives_the_gain_and_the_power():
    p, r = _powers(5000)
    cal = calibrate_intensity(3.0e6 * p, r, p)
    assert cal.gain == pytest.approx(3.0e6, rel=1e-6)
    assert cal.range_exponent == 0.0 and cal.explained > 0.999
    assert cal.power_w(3.0e6 * p, r) == pytest.approx(p, rel=0.05)


def test_range_compensated_reflectivity_is_recognised():
    p, r = _powers(5000, 1)
    cal = calibrate_intensity(p * r ** 2, r, p)
    assert cal.range_exponent == -2.0
    assert cal.power_w(p * r ** 2, r) == pytest.approx(p, rel=0.05)


def test_log_compressed_counts_map_back_to_power_within_a_count():
    p, r = _powers(20000, 2)
    u = np.log(p / P_TH) / np.log(1e-3 / P_TH)
    counts = np.clip(np.round(1 + 254 * u ** 0.85), 1, 255)
    back = calibrate_intensity(counts, r, p).power_w(counts, r)
    # One count spans d ln P = ln(1e-3 / P_th) / (254 * 0.85 u^-0.15): about 0.05 here.
    assert np.median(np.abs(np.log(back / p))) < 0.05


def test_unrelated_intensity_is_not_used():
    p, r = _powers(5000, 3)
    noise = np.random.default_rng(9).uniform(1, 100, 5000)
    assert not calibrate_intensity(noise, r, p).usable


def _fit_data(material: np.ndarray, p_model: np.ndarray, measured: np.ndarray,
              sigma: float) -> FitData:
    """Matched points at 10 m along +x with the model's power ``p_model`` (W) and the
    measured ranges ``measured`` (m), range noise ``sigma`` (m)."""
    return ahead_fit_data(material, p_model, measured, sigma, P_TH)


def _walk_data(k_m: float, seed: int = 4) -> tuple[FitData, np.ndarray]:
    """Points whose bias is -k ln(P_true / P_th); the model's power is off by a factor
    per material (wrong reflectance numbers), the sensor measured the true power."""
    rng = np.random.default_rng(seed)
    n = 6000
    material = rng.integers(0, 2, n)
    p_true = 10 ** rng.uniform(-6.5, -4.0, n)
    p_model = p_true * np.where(material == 0, 4.0, 0.25) * 10 ** rng.normal(0, 0.3, n)
    sigma = 0.02
    rng_m = np.full(n, 10.0)
    measured = rng_m - k_m * np.log(p_true / P_TH) + sigma * rng.standard_normal(n)
    return _fit_data(material, p_model, measured, sigma), p_true


def test_range_walk_is_fitted_against_the_measured_power():
    from dataclasses import replace
    data, p_true = _walk_data(0.02)
    walk = get_effect_class('range_walk')
    measured = fit_effect(walk, replace(data, measured_power_w=p_true))
    modelled = fit_effect(walk, data)
    assert measured.params['k_m'] == pytest.approx(0.02, abs=0.001)
    # Against the model's own power the slope is diluted by its reflectance errors
    # (errors-in-variables: var ln P / (var ln P + var error) = 1.66^2 / (1.66^2 + 0.69^2)).
    assert modelled.params['k_m'] == pytest.approx(0.02 * 0.85, abs=0.001)
    assert measured.nll_per_point < modelled.nll_per_point - 0.05


def test_a_clipped_scale_is_found_and_its_points_take_the_models_power():
    """An intensity clipped at the top of its scale (holdout 10's 8-bit reflectivity, most
    points at 255) says only that the power reached the clip: the map is fitted below it
    and the clipped points take the larger of the model's power and the clip's level."""
    p, r = _powers(8000, 5)
    cap = np.quantile(3.0e6 * p, 0.6)
    counts = np.minimum(3.0e6 * p, cap)
    cal = calibrate_intensity(counts, r, p)
    assert cal.clip_log_i == pytest.approx(np.log(cap))
    assert cal.clipped_share == pytest.approx(0.4, abs=0.01)
    back = cal.power_w(counts, r, p)
    assert back == pytest.approx(p, rel=0.05)
    # Without the model's power the clipped points sit at the clip's level (the old
    # reading: every clipped point alike).
    flat = cal.power_w(counts, r)
    assert np.ptp(np.log(flat[counts >= cap])) < 0.05


@pytest.mark.parametrize('seed', [2, 6])
def test_a_scale_that_is_not_clipped_has_no_clip(seed):
    """Counts that reach the top of the scale as often as any value near it (a log scale
    over the whole range of powers), and float intensities: no clip."""
    p, r = _powers(20000, seed)
    u = np.log(p / p.min()) / np.log(p.max() / p.min())
    counts = np.clip(np.round(1 + 254 * u), 1, 255)
    assert calibrate_intensity(counts, r, p).clip_log_i is None
    assert calibrate_intensity(3.0e6 * p, r, p).clip_log_i is None


def test_range_walk_read_through_a_clipped_scale_keeps_its_slope():
    """The walk fitted on the power read from a clipped intensity: the clipped points at
    the model's power keep the slope (diluted as the model's power dilutes it: 0.016 here,
    as in the test above); all at the clip's level steepen it to fit the unclipped half
    alone (0.026)."""
    from dataclasses import replace
    data, p_true = _walk_data(0.02)
    counts = np.minimum(1e7 * p_true, np.quantile(1e7 * p_true, 0.5))
    p_model = data.baseline.ctx.power_w
    cal = calibrate_intensity(counts, data.baseline.ctx.range_m, p_model)
    walk = get_effect_class('range_walk')
    kept = fit_effect(walk, replace(data, measured_power_w=cal.power_w(
        counts, data.baseline.ctx.range_m, p_model)))
    flat = fit_effect(walk, replace(data, measured_power_w=cal.power_w(
        counts, data.baseline.ctx.range_m)))
    assert abs(kept.params['k_m'] - 0.02) < abs(flat.params['k_m'] - 0.02)
    assert kept.nll_per_point < flat.nll_per_point


def _agc(p: np.ndarray, sd_ln: float, clouds: int = 12, seed: int = 7):
    """Intensity proportional to power times a lognormal gain per cloud (a gain control)."""
    rng = np.random.default_rng(seed)
    cloud = np.sort(rng.integers(0, clouds, len(p)))
    log_g = rng.normal(0.0, sd_ln, clouds)
    return 3.0e6 * p * np.exp(log_g[cloud]), cloud, log_g


def test_a_gain_per_cloud_is_found_and_taken_out():
    """Holdout 10's walk_agc: the intensity scaled per cloud by a lognormal gain (sd 0.5
    in ln). One map for all clouds leaves the gain's spread in the power (0.5 in ln);
    with a gain per cloud the power comes back within the map's own error, and the gains
    are the true ones up to their common level."""
    p, r = _powers(12000, 8)
    counts, cloud, log_g = _agc(p, 0.5)
    one_map = calibrate_intensity(counts, r, p)
    per_cloud = calibrate_intensity(counts, r, p, cloud=cloud)
    assert np.std(np.log(one_map.power_w(counts, r) / p)) > 0.3
    assert per_cloud.cloud_gain_test['used']
    back = per_cloud.power_w(counts, r, cloud=cloud)
    assert np.std(np.log(back / p)) < 0.05
    fitted = np.array([per_cloud.cloud_log_gain[c] for c in range(12)])
    assert np.std((fitted - fitted.mean()) - (log_g - log_g.mean())) < 0.02
    assert per_cloud.as_dict()['cloud_gain']['used']


def test_no_gain_per_cloud_where_the_clouds_read_alike():
    """Without a gain per cloud the halves' gains are noise: they lose held out, are not
    used, and the power is read as before."""
    p, r = _powers(12000, 9)
    rng = np.random.default_rng(3)
    counts = 3.0e6 * p * np.exp(rng.normal(0.0, 0.3, len(p)))   # speckle, no per-cloud part
    cloud = np.sort(rng.integers(0, 12, len(p)))
    cal = calibrate_intensity(counts, r, p, cloud=cloud)
    assert not cal.cloud_gain_test['used'] and cal.cloud_log_gain == {}
    assert cal.cloud_gain_test['gain_nats'] < 15.0
    plain = calibrate_intensity(counts, r, p)
    assert np.array_equal(cal.power_w(counts, r, cloud=cloud), plain.power_w(counts, r))


def _banded_walk_data(k_m: float, seed: int = 4) -> tuple[FitData, np.ndarray]:
    """Points whose bias is -k ln(P_true / P_th) plus an offset per material, with the
    materials' powers in separate bands (a bright and a dark one, one decade each, as a
    target's materials are): the walk is measured within each material. The model's
    power is the true one within 0.1 decade."""
    rng = np.random.default_rng(seed)
    n = 6000
    material = rng.integers(0, 2, n)
    p_true = 10 ** np.where(material == 0, rng.uniform(-5.0, -4.0, n),
                            rng.uniform(-6.5, -5.5, n))
    p_model = p_true * 10 ** rng.normal(0, 0.1, n)
    sigma = 0.02
    rng_m = np.full(n, 10.0)
    measured = (rng_m - k_m * np.log(p_true / P_TH) + np.where(material == 0, 0.01, -0.02)
                + sigma * rng.standard_normal(n))
    return _fit_data(material, p_model, measured, sigma), p_true


def test_range_walk_read_through_a_gain_per_cloud_keeps_its_slope():
    """The walk fitted on the power read from an intensity with a gain per cloud (sd 0.5
    in ln): one map for all clouds leaves the gain as noise in ln P that the ranges do
    not follow, which dilutes the slope within each material (0.0188 for 0.02 here) and
    costs likelihood; the gain per cloud taken out restores both (0.0199)."""
    from dataclasses import replace
    data, p_true = _banded_walk_data(0.02)
    counts, cloud, _ = _agc(p_true, 0.5, seed=11)
    p_model = data.baseline.ctx.power_w
    r = data.baseline.ctx.range_m
    walk = get_effect_class('range_walk')
    one = calibrate_intensity(counts, r, p_model)
    per = calibrate_intensity(counts, r, p_model, cloud=cloud)
    diluted = fit_effect(walk, replace(data, measured_power_w=one.power_w(counts, r)))
    kept = fit_effect(walk, replace(data, measured_power_w=per.power_w(counts, r, cloud=cloud)))
    assert kept.params['k_m'] == pytest.approx(0.02, abs=0.0005)
    assert diluted.params['k_m'] < 0.02 - 0.001
    assert kept.nll_per_point < diluted.nll_per_point - 0.03


def test_a_bright_cloud_at_the_top_of_the_scale_gets_its_whole_gain():
    """Holdout 10's walk_agc_42: a few clouds with gains of e^0.6-e^1.1 fill the top of
    the intensity scale on their own (the target's powers span less than a decade, the
    model's power is off the true one by 0.2 in ln point to point), where a map refitted
    in turn with the clouds' medians fits those clouds' own points and their gains creep
    (0.24 in ln short here, 0.45 on the holdout). Fitted together with the map, each gain
    is the true one within the model's noise."""
    rng = np.random.default_rng(10)
    p = 10 ** rng.uniform(-5.5, -4.8, 12000)
    r = rng.uniform(8.0, 14.0, 12000)
    cloud = np.sort(rng.integers(0, 12, len(p)))
    log_g = np.array([0.8, 1.0, 0.0, -0.35, -0.5, 0.0, 1.1, -0.4, 0.65, -0.95, 0.0, 0.95])
    counts = 3.0e6 * p * np.exp(log_g[cloud])
    p_model = p * np.exp(rng.normal(0.0, 0.2, len(p)))
    cal = calibrate_intensity(counts, r, p_model, cloud=cloud)
    fitted = np.array([cal.cloud_log_gain[c] for c in range(12)])
    assert np.max(np.abs((fitted - np.median(fitted)) - (log_g - np.median(log_g)))) < 0.06


def test_log_counts_are_read_as_log_counts_and_give_back_the_power():
    # A flash sensor's 40 log10 P (P in nW): linear in ln P, not in P. The scale test
    # chooses the log reading, its b is 40 / ln 10 per e-fold, the power comes back.
    p, r = _powers(5000, 5)
    counts = 40.0 * np.log10(p / 1e-9)
    cal = calibrate_intensity(counts, r, p)
    assert cal.scale == 'log'
    assert cal.scale_test['log_b_per_efold'] == pytest.approx(40.0 / np.log(10.0), rel=1e-3)
    assert cal.power_w(counts, r) == pytest.approx(p, rel=1e-3)


def test_counts_proportional_to_power_are_not_read_as_log_counts():
    p, r = _powers(5000, 6)
    cal = calibrate_intensity(2.0e6 * p * np.random.default_rng(1).lognormal(0, 0.2, 5000),
                              r, p)
    assert cal.scale == 'linear'
    assert cal.scale_test['power_law_exponent'] == pytest.approx(1.0, abs=0.1)


def test_log_counts_at_or_below_zero_still_give_a_power():
    # 40 log10 of a power below the unit is negative: a log reading keeps those points.
    p, r = _powers(5000, 7)
    counts = 40.0 * np.log10(p / 1e-5)        # P from 3e-7 to 3e-4 W: about half below 0
    cal = calibrate_intensity(counts, r, p)
    assert cal.scale == 'log'
    assert np.all(np.isfinite(cal.power_w(counts, r)))


def test_the_terminal_says_log_counts_and_b():
    from lidar_sim_ros.compare.recording import fields
    p, r = _powers(5000, 8)
    cal = calibrate_intensity(40.0 * np.log10(p / 1e-9), r, p)
    line = fields.intensity_reading(cal.as_dict(), 'intensity')
    assert 'log counts' in line and 'b 17.4 per e-fold' in line


def test_log_like_counts_of_another_shape_keep_the_map():
    # 8-bit counts of u^0.85 (u ~ ln P) look like log counts but are not affine in ln P:
    # the scale is called log, the power still read through the map.
    p, r = _powers(20000, 2)
    u = np.log(p / P_TH) / np.log(1e-3 / P_TH)
    counts = np.clip(np.round(1 + 254 * u ** 0.85), 1, 255)
    cal = calibrate_intensity(counts, r, p)
    assert cal.scale == 'log' and cal.scale_test['read_through'] == 'map'
    assert not cal.reads_log


def test_the_foreign_sensor_writes_log_counts_of_its_power():
    import foreign_sim as fs
    p = np.array([1e-8, 1e-6, 1e-4])
    out = fs.intensity_units(p, np.full(3, 10.0), 'log', fs.Sensor())
    assert out == pytest.approx(40.0 * np.log10(np.maximum(p, fs.Sensor().threshold_power_w)
                                                / 1e-9), rel=1e-6)


def _wide_truth(n: int, seed: int, r_lo: float = 6.0, r_hi: float = 25.0,
                with_incidence: bool = False):
    """A target whose true reflectance term spans 1.7x the model's in ln (per material
    and incidence u), ranges r_lo..r_hi: (true ln P, model ln P, range, material), and
    the incidence (rad, 0-1.2 with u) when asked."""
    rng = np.random.default_rng(seed)
    mat = rng.integers(0, 4, n)
    u = rng.uniform(0.0, 1.0, n)
    model_term = -12.0 + 0.5 * mat + 2.0 * u        # the model's ln(reflectance x cos)
    true_term = -12.0 + 1.7 * (model_term + 12.0)   # the truth's: 1.7x as wide
    r = rng.uniform(r_lo, r_hi, n)
    out = true_term - 2 * np.log(r), model_term - 2 * np.log(r), r, mat
    return out + (1.2 * u,) if with_incidence else out


def _slope(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.polyfit(b, a, 1)[0])


def test_cepton_reflectivity_keeps_the_slope_of_ln_i_at_one():
    """walkscale53: a reflectivity ~ P r^2 read through a map fitted on a model whose
    powers are narrower than the truth's came out compressed (a walk over-read by the
    inverse). With the layout's word (unit_slope) the reading is the true ln P + const."""
    log_pt, log_pm, r, _ = _wide_truth(20000, 3)
    refl = np.exp(log_pt) * r ** 2
    cal = calibrate_intensity(refl, r, np.exp(log_pm), range_exponents=(-2.0,),
                              unit_slope=True)
    read = np.log(cal.power_w(refl, r))
    assert _slope(read, log_pt) == pytest.approx(1.0, abs=1e-6)
    assert cal.usable and cal.unit_slope and cal.as_dict()['unit_slope'] is True
    # without it, the map carries the model's scale (the over-read's cause)
    old = calibrate_intensity(refl, r, np.exp(log_pm), range_exponents=(-2.0,))
    assert _slope(np.log(old.power_w(refl, r)), log_pt) < 0.8


B_LOG = 40.0 / np.log(10.0)    # 40 log10 P: counts per e-fold


def _walk_k(range_error: np.ndarray, log_p: np.ndarray, mat: np.ndarray) -> float:
    """Least squares k of range_error = -k ln P + a per material."""
    x = log_p - np.array([log_p[mat == m].mean() for m in range(mat.max() + 1)])[mat]
    y = range_error - np.array([range_error[mat == m].mean()
                                for m in range(mat.max() + 1)])[mat]
    return float(-np.sum(x * y) / np.sum(x * x))


def test_range_lever_reads_log_counts_at_the_truths_b_where_the_model_is_narrow():
    """logwalk54: log counts a + b ln P (b 17.37) fitted on the model's narrower ln P read
    b too large, and a walk over-read by the same ratio; the range within one material and
    incidence gives b, and the power is read with it: the walk's k comes back."""
    log_pt, log_pm, r, mat, inc = _wide_truth(40000, 4, with_incidence=True)
    log_pt = log_pt + np.random.default_rng(5).normal(0, 0.2, len(r))   # speckle
    counts = B_LOG * (log_pt + 20.72)
    walk = -0.03 * log_pt + np.random.default_rng(6).normal(0, 0.005, len(r))
    old = calibrate_intensity(counts, r, np.exp(log_pm))
    assert old.scale == 'log' and old.log_b > 1.2 * B_LOG and old.counts_per_efold is None
    k_old = _walk_k(walk, np.log(old.power_w(counts, r)), mat)
    assert k_old > 1.2 * 0.03                              # the over-read
    cal = calibrate_intensity(counts, r, np.exp(log_pm), material=mat, model_range_m=r,
                              incidence=inc)
    lever = cal.as_dict()['counts_per_efold']
    assert lever['pinned'] and lever['used'] and lever['rel_se'] < 0.02
    assert lever['per_efold'] == pytest.approx(B_LOG, rel=0.02)
    assert lever['fitted_on_model'] == pytest.approx(old.log_b, rel=1e-3)
    assert cal.reads_log and cal.scale_test['read_through'] == 'range'
    assert cal.log_b == pytest.approx(B_LOG, rel=0.02)
    assert _walk_k(walk, np.log(cal.power_w(counts, r)), mat) == pytest.approx(0.03, rel=0.03)


def test_range_lever_leaves_the_reading_where_the_model_has_the_truths_scale():
    """The model's power is the truth (our own simulator's recordings): the range's b is
    the fitted one, so the reading stays as the scale test left it."""
    _, log_pm, r, mat, inc = _wide_truth(40000, 6, with_incidence=True)
    counts = B_LOG * (log_pm + 20.72) + np.random.default_rng(7).normal(0, 1.0, len(r))
    old = calibrate_intensity(counts, r, np.exp(log_pm))
    cal = calibrate_intensity(counts, r, np.exp(log_pm), material=mat, model_range_m=r,
                              incidence=inc)
    lever = cal.counts_per_efold
    assert lever['pinned'] and not lever['used']
    assert lever['per_efold'] == pytest.approx(B_LOG, rel=0.02)
    assert cal.log_b == old.log_b and cal.scale_test['read_through'] != 'range'
    assert cal.power_w(counts, r) == pytest.approx(old.power_w(counts, r), rel=1e-9)


def test_range_lever_is_not_pinned_without_range_spread():
    """Every point at nearly one range: nothing within a cell moves with the range; the
    reading is the model's fit, and the verdict beside a walk says the range was too
    loose to read b."""
    from lidar_sim_ros.compare.report.verdict import walk_scale_words
    log_pt, log_pm, r, mat, inc = _wide_truth(20000, 8, 9.99, 10.01, with_incidence=True)
    counts = B_LOG * (log_pt + 20.72) + np.random.default_rng(9).normal(0, 3.0, len(r))
    cal = calibrate_intensity(counts, r, np.exp(log_pm), material=mat, model_range_m=r,
                              incidence=inc)
    lever = cal.counts_per_efold
    assert not lever['pinned'] and not lever['used']
    assert cal.scale_test['read_through'] != 'range'
    words = walk_scale_words(cal.as_dict(), {'k_m': 0.04, 'power': 'measured'})
    assert 'too loose to read' in words and 'over-read' in words


def test_range_lever_holds_where_the_nearer_part_of_a_surface_faces_the_sensor_more():
    """Within an incidence bin the incidence still follows the range (the nearer part of a
    surface faces the sensor more): the lever takes that out, and reads the truth's b."""
    from lidar_sim_ros.compare.recording.intensity import range_lever
    rng = np.random.default_rng(8)
    n = 20000
    mat = rng.integers(0, 3, n)
    r = rng.uniform(9.5, 10.5, n)
    inc = np.clip(0.6 - 0.5 * (r - 10.0) + rng.normal(0, 0.15, n), 0.0, 1.4)
    log_pt = -12.0 + 0.5 * mat - 3.0 * inc ** 2 - 2 * np.log(r)
    out = range_lever(B_LOG * (log_pt + 20.72), np.log(r), mat, inc)
    assert out['pinned'] and out['per_efold'] == pytest.approx(B_LOG, rel=0.02)


def test_range_lever_is_not_asked_off_log_counts():
    """A reading proportional to the power (and a Cepton reflectivity): no lever, the
    calibration as before."""
    log_pt, log_pm, r, mat, inc = _wide_truth(20000, 10, with_incidence=True)
    i = 3.0e6 * np.exp(log_pt)
    cal = calibrate_intensity(i, r, np.exp(log_pm), material=mat, model_range_m=r,
                              incidence=inc)
    assert cal.scale != 'log' and cal.counts_per_efold is None
    refl = np.exp(log_pt) * r ** 2
    cep = calibrate_intensity(refl, r, np.exp(log_pm), range_exponents=(-2.0,),
                              unit_slope=True, material=mat, model_range_m=r, incidence=inc)
    assert cep.counts_per_efold is None and cep.as_dict()['counts_per_efold'] is None


def test_the_cepton_layouts_hold_the_slope():
    from lidar_sim_ros.compare.recording.fields import slope_known
    assert slope_known({'layout': 'cepton sdk3 driver'})
    assert not slope_known({'layout': 'generic'}) and not slope_known(None)


def test_the_verdict_says_what_the_scale_leaves_open_of_a_walk():
    from lidar_sim_ros.compare.report.verdict import walk_scale_words
    gain = {'used_for_power_driven_effects': True, 'range_exponent': 0.0}
    # not log counts: nothing checks the scale
    assert 'does not check' in walk_scale_words(gain, {'k_m': 0.05, 'power': 'measured'})
    assert walk_scale_words(gain, {'k_m': 0.03, 'power': 'model'}) == ''
    assert walk_scale_words({'used_for_power_driven_effects': True, 'unit_slope': True},
                            {'k_m': 0.03}) == ''
    pinned = {**gain, 'counts_per_efold': {'per_efold': 17.4, 'se': 0.2, 'rel_se': 0.01,
                                           'pinned': True, 'used': True,
                                           'fitted_on_model': 29.0,
                                           'range_sd_within_cells': 0.03}}
    assert walk_scale_words(pinned, {'k_m': 0.03, 'power': 'measured'}) == ''
    # pinned, short of the margin: the ratio the model's fit may leave in k
    short = {**gain, 'counts_per_efold': {**pinned['counts_per_efold'], 'used': False,
                                          'fitted_on_model': 15.0,
                                          'log_shape_from': 'scale test'}}
    words = walk_scale_words(short, {'k_m': 0.027, 'power': 'measured'})
    assert '-14 %' in words and '17.4' in words
    # the same within its error: the model's scale confirmed
    same = {**gain, 'counts_per_efold': {**short['counts_per_efold'], 'fitted_on_model': 17.5}}
    assert walk_scale_words(same, {'k_m': 0.03, 'power': 'measured'}) == ''


def test_the_terminal_line_says_whence_b():
    """The intensity line: b from the range where read with it; quoted beside the model's
    fit where short of the margin; none where not log counts."""
    from lidar_sim_ros.compare.recording.fields import intensity_reading
    lever = {'per_efold': 17.4, 'se': 0.1, 'rel_se': 0.006, 'pinned': True,
             'fitted_on_model': 29.1, 'log_shape_from': 'scale test', 'used': True}
    base = {'intensity_scale': 'log', 'power_explained': 0.9,
            'used_for_power_driven_effects': True}
    used = intensity_reading({**base, 'counts_per_efold': lever,
                              'scale_test': {'log_b_per_efold': 29.1, 'read_through': 'range'}},
                             'intensity')
    assert 'b 17.4 +- 0.1 per e-fold of power from the range' in used and '29.1 fitted' in used
    short = intensity_reading({**base, 'counts_per_efold': {**lever, 'used': False,
                                                            'fitted_on_model': 15.0},
                               'scale_test': {'log_b_per_efold': 15.0, 'read_through': 'map'}},
                              'intensity')
    assert '-14 % from it, short of the margin' in short
    plain = intensity_reading({**base, 'intensity_scale': 'linear', 'scale_test': {}},
                              'intensity')
    assert 'range within one material' not in plain
