"""A surface standoff beside an incidence-shaped rival is named only by the part of it
that differs between materials (``Diagnosis.standoff_part_veto``, ``standoff_part``): a
standoff common to every surface moves ranges as 1 / cos(incidence), which the materials'
offsets turn into an incidence-shaped bias (the battery's short_incidence@1: a tie
[surface_offset, incidence_angle] on an incidence bias alone)."""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.compare.diagnose import diagnosis as dg
from lidar_sim_ros.compare.diagnose import standoff_part
from lidar_sim_ros.compare.model.fit import fit_effect
from lidar_sim_ros.core.effects import get_effect_class, make_effect

from test_fitting import MATERIALS, fit_data_from_rays, model_sim, scene

N = 6000
SURFACE_OFFSET = get_effect_class('surface_offset')


class Held(dg.Diagnosis):
    """A diagnosis whose held-out NLLs are given: ``common`` is the common standoff's
    (``cross_fit`` of ``CommonStandoff``), per point in fold order."""

    def __init__(self, common):
        self.common, self.asked = common, 0
        self.blocks = np.arange(N) // 20
        self.n_total = N
        self._z_crit = 3.0

    def cross_fit(self, variant, on_top, first=None):
        assert variant is standoff_part.CommonStandoff and not on_top
        self.asked += 1
        return self.common, 0.0

    def nameable(self, cand):
        return cand.vetoed is None and cand.error is None


def _standoff(nll):
    c = dg.Candidate('surface_offset', score=0.0066, heldout_nll=nll)
    c.effect, c.variant = make_effect('surface_offset', {'standoff_m': 0.0126}), SURFACE_OFFSET
    return c


def _incidence():
    c = dg.Candidate('incidence_angle', score=0.0054)
    c.effect = make_effect('incidence_angle', {'bias_gain': -0.4})
    return c


def test_a_standoff_common_to_every_material_is_set_aside_beside_incidence():
    """No part of its own (the full standoff holds out as the common one, to noise):
    set aside beside a nameable incidence_angle, with its figures; alone, or beside an
    incidence_angle that may not be named, it is not asked."""
    rng = np.random.default_rng(1)
    common = rng.normal(-1.8, 1.0, N)
    diag = Held(common)
    cand = _standoff(common - rng.normal(0.0, 0.002, N))
    why = diag.standoff_part_veto(cand, [cand, _incidence()])
    assert why is not None and 'differs between materials' in why
    assert cand.standoff_part['passes'] is False
    assert cand.standoff_part['beside'] == 'incidence_angle'
    alone = _standoff(common)
    assert diag.standoff_part_veto(alone, [alone]) is None and alone.standoff_part is None
    vetoed = _incidence()
    vetoed.vetoed = 'its shape is another'
    assert diag.standoff_part_veto(alone, [alone, vetoed]) is None
    assert diag.asked == 1


def test_a_standoff_of_one_material_passes_beside_incidence():
    """Its part of its own gains 0.02 nats/point over the common standoff on a third of
    the points (a blanket proud): it stays nameable."""
    rng = np.random.default_rng(2)
    common = rng.normal(-1.8, 1.0, N)
    own = np.where(np.arange(N) % 3 == 0, 0.06, 0.0) + rng.normal(0.0, 0.01, N)
    cand = _standoff(common - own)
    assert Held(common).standoff_part_veto(cand, [cand, _incidence()]) is None
    assert cand.standoff_part['passes'] is True and cand.standoff_part['score'] > 0.015


def test_the_common_standoff_is_fitted_without_a_material_of_its_own():
    """One material (FOIL, the caps) 3 cm proud: the standoff's fit frees FOIL's own
    standoff; its common variant fits the scale and the common standoff only."""
    effect = make_effect('surface_offset', {'material_standoff_m': {'FOIL': 0.03}})
    truth = model_sim([effect], MATERIALS, 5)
    traj = scene()[2]
    fr = truth.simulate_frame(3 * truth.frame_period_s, traj, 3)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    clean = model_sim()
    data = fit_data_from_rays(clean, fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s,
                              laser=fr.ring, n_shots=len(clean.shots))
    full = fit_effect(SURFACE_OFFSET, data).effect
    common = fit_effect(standoff_part.CommonStandoff, data).effect
    assert full.params.material_standoff_m.get('FOIL', 0.0) > 0.015
    assert common.params.material_standoff_m == {}
    assert standoff_part.common_part_of(SURFACE_OFFSET) is standoff_part.CommonStandoff
    assert standoff_part.common_part_of(standoff_part.CommonStandoff) is None
