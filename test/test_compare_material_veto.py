"""A range error of the sensor is the same on every material (``Diagnosis.material_veto``):
one material given its own range scale and the rest theirs must not do better, held out,
than one scale for all. The fits here are an independent closed form (least squares of
the residual on the range, one intercept per material; a Gaussian held-out NLL), not the
comparison's likelihood."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lidar_sim_ros.compare.diagnose import diagnosis as dg

from test_compare_laser_tiles import Splits

SIGMA = 0.02
NAMES = ['PIF', 'MLI']


def _recording(case: str, seed: int):
    """Two materials, 3000 points each at 7-10 m, noise 2 cm. ``scale``: every range 1 %
    long (a clock). ``part``: the PIF points nearer than 8.5 m (a part of the target of a
    material the configuration does not list) read 4.8 cm long, the rest true. ``narrow``:
    ``scale`` with the MLI seen as 300 points over 0.3 m of range only (a small part seen
    face on), where a scale fitted on its own points is poor."""
    rng = np.random.default_rng(seed)
    material = np.repeat([0, 1], 3000)
    r = rng.uniform(7.0, 10.0, len(material))
    if case == 'narrow':
        material = np.repeat([0, 1], [3000, 300])
        r = np.concatenate([rng.uniform(7.0, 10.0, 3000), rng.uniform(9.0, 9.3, 300)])
    if case in ('scale', 'narrow'):
        truth = 0.01 * r
    else:
        truth = np.where((material == 0) & (r < 8.5), 0.048, 0.0)
    return material, r, truth + rng.normal(0.0, SIGMA, len(r))


def _centred(v, material, sel):
    out = v.astype(float).copy()
    for m in (0, 1):
        s = sel & (material == m)
        if s.any():
            out[material == m] -= v[s].mean()
    return out


def _nll(residual, material, r, train, test):
    """Held-out Gaussian NLL on ``test`` of a range scale (slope on r, one intercept per
    material) fitted on ``train``; a material absent from ``train`` takes its test mean."""
    x, y = _centred(r, material, train), _centred(residual, material, train)
    slope = float(np.sum(x[train] * y[train]) / np.sum(x[train] ** 2))
    e = residual - slope * r
    for m in (0, 1):
        src = train & (material == m)
        src = src if src.any() else test & (material == m)
        e[material == m] -= e[src].mean()
    return 0.5 * (e[test] / SIGMA) ** 2 + np.log(SIGMA * np.sqrt(2 * np.pi))


class Materials(Splits):
    """A diagnosis of one recording's residuals, fitted in closed form."""

    def __init__(self, material, r, residual, seed=0):
        super().__init__(residual, seed)
        self.full = SimpleNamespace(baseline=SimpleNamespace(ctx=SimpleNamespace(
            material=material, scene=SimpleNamespace(target=SimpleNamespace(
                material_names=NAMES)))))
        self.material, self.r = material, r

    def split_nll(self, variant, group, on_top=()):
        """One scale for the points of ``group`` and another for the rest, each fitted on
        one random fold and scored on the other."""
        out = np.full(self.n_total, np.nan)
        for fold in (0, 1):
            for side in (True, False):
                train = (self.random_fold == fold) & (group == side)
                test = (self.random_fold != fold) & (group == side)
                out[test] = _nll(self.residual, self.material, self.r, train, test)
        return out

    def transfer_nll(self, variant, halves, on_top=()):
        """The old form of the veto (``Diagnosis.worst_transfer``): fitted on one half,
        scored on the other."""
        out = np.full(self.n_total, np.nan)
        for h in halves:
            test = np.zeros(self.n_total, bool)
            test[h.matched] = True
            out[test] = _nll(self.residual, self.material, self.r, ~test, test)
        return out

    def scale_candidate(self, name='range_scale'):
        c = dg.Candidate(name, n_params=1)
        c.effect, c.variant = object(), object
        one = self.random_fold == 1
        c.heldout_nll = np.concatenate([
            _nll(self.residual, self.material, self.r, ~one, one),
            _nll(self.residual, self.material, self.r, one, ~one)])
        return c


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_range_scale_holds_on_every_material(seed):
    d = Materials(*_recording('scale', seed), seed)
    assert d.material_veto(d.scale_candidate()) is None


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_material_seen_over_a_short_stretch_of_range_keeps_the_scale(seed):
    """Holdout 10's range drift: the PAF seen in 9 of 16 clouds over a few seconds fits a
    drift of its own poorly (9.1e-4 m/s for 6.7e-4, within its error), and that fit carried
    to the other materials lost against a random half: the drift was set aside as 'part of
    the target reads off'. An imprecise fit costs the split only on its own points."""
    d = Materials(*_recording('narrow', seed), seed)
    assert d.material_veto(d.scale_candidate()) is None


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_a_part_of_one_material_reading_off_is_no_range_scale(seed):
    """Holdout 9's newmat: half the PIF faces of a material the configuration lacks,
    4.8 cm long; they lie nearer, so a range scale fits them (-0.9 %) and was named.
    Given a scale of their own, the PIF points and the MLI ones do better held out than
    with one scale: a part of the target, outside the catalogue."""
    d = Materials(*_recording('part', seed), seed)
    why = d.material_veto(d.scale_candidate())
    assert why is not None and 'outside the catalogue' in why
    assert 'PIF points' in why or 'MLI points' in why
    # Only the sensor's range errors kept out of the defaults are asked.
    assert d.material_veto(d.scale_candidate('range_walk')) is None


def _drift_recording(seed: int):
    """A range drift of 6.7e-4 m/s over 60 s (4 cm), noise 4 cm: PIF seen all the
    time (3000 points), the BULKHEAD only from 32 to 52 s (600 points), as the ninth
    holdout's turning rocket shows it. The regressor is the time."""
    rng = np.random.default_rng(seed)
    material = np.repeat([0, 1], [3000, 600])
    t = np.concatenate([rng.uniform(0.0, 60.0, 3000), rng.uniform(32.0, 52.0, 600)])
    return material, t, 6.7e-4 * t + rng.normal(0.0, 0.04, len(t))


@pytest.mark.parametrize('seed', [0, 9, 25])
def test_a_drift_seen_briefly_on_one_material_holds_within_its_noise(seed):
    """The ninth holdout's drift_101 (a range drift alone) was set aside: fitted on the
    BULKHEAD's points (seen for 20 s of 60) and scored on the others, the drift lost
    0.0286 nats/point (z 11.8). A rate fitted on 20 s is known to about 40 % here, and its
    error alone costs every other point: the transfer passes the rule on these seeds
    (asserted), while the BULKHEAD given its own rate gains nothing held out. A rate of the
    BULKHEAD's own (ten times the drift there: 12 cm over its 20 s) is told apart."""
    material, t, residual = _drift_recording(seed)
    d = Materials(material, t, residual, seed)
    global SIGMA
    saved, SIGMA = SIGMA, 0.04
    try:
        c = d.scale_candidate('range_drift')
        at_random = d.in_matched_order(c.heldout_nll)
        assert d.worst_transfer(c, {1: material == 1}, at_random) is not None  # the old form
        assert d.material_veto(c) is None
        off = residual + np.where(material == 1, 9 * 6.7e-4 * t, 0.0)
        d2 = Materials(material, t, off, seed)
        assert d2.material_veto(d2.scale_candidate('range_drift')) is not None
    finally:
        SIGMA = saved
