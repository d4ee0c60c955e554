"""A surface standoff weighed beside other effects on the same footing as they are.

Two faults made the figures of ``surface_offset`` next to another effect meaningless
(short_incidence@1 and beam_solar_incid@4 of the foreign battery: a standoff fitted on top
of ``incidence_angle`` scored -0.016 nats/point, on top of a footprint and the bias -0.35,
and a footprint on top of a standoff exactly 0):

* the fit returned a standoff worse, on its own objective, than none: the first-order
  columns it selects and steps on do not see the rays a sunken face loses through the
  gaps at its edges (scored as spurious returns). Open (a known failure below): mended
  alone (the iterate with the lowest objective kept, none included), the standoff fitted
  soundly was named in place of a footprint and an incidence bias on the held-out
  beam_solar_incid@6 (0.130 against the footprint's 0.071 nats/point; on main its broken
  fit scores -0.028).
* a standoff beside a footprint undoes the footprint: its rays are checked for a jump
  across a silhouette against the mesh's placement without the footprint, so every edge
  return of the footprint counts as crossed and is put back on the bare mesh. Open (a
  known failure below): mended with the first, the standoff then gains on top of a
  footprint and ``Diagnosis.stands_in_beside`` named it in the footprint's place on the
  battery's beam_divergence_first (docs/compare.md, "A phantom standoff beside incidence
  and a footprint").
"""
from __future__ import annotations

import numpy as np
import pytest

from lidar_sim_ros.compare.model.fit import fit_effect
from lidar_sim_ros.compare.model.likelihood import ROBUST_FLOOR, model_on_rays, objective
from lidar_sim_ros.core.effects import get_effect_class, make_effect

from test_fitting import dataset

SURFACE_OFFSET = get_effect_class('surface_offset')


@pytest.mark.xfail(strict=True, reason='open: the fit keeps its last step on the exact surface '
                   '(module doc)')
def test_a_fitted_standoff_is_never_worse_than_none():
    """A range walk, no standoff: the linearised fit asks for a standoff of -0.46 cm that,
    cast on the exact surface, loses 29 rays through the gaps of the sunken faces
    (objective 300 nats above no standoff). The fit should keep no standoff."""
    data, _ = dataset('range_walk')
    fit = fit_effect(SURFACE_OFFSET, data)
    none = objective(data, [], floor=ROBUST_FLOOR)
    fitted = objective(data, [fit.effect], floor=ROBUST_FLOOR)
    assert fitted <= none + 1e-6
    assert model_on_rays(data, [fit.effect]).placed.all()


@pytest.mark.xfail(strict=True, reason='open: a standoff beside a footprint is told against '
                   'the bare mesh (module doc)')
def test_a_zero_standoff_beside_a_footprint_changes_nothing():
    """The footprint's edge returns move ranges by metres (a sub-ray meets the part in
    front): beside a standoff of zero they were taken as crossed silhouettes and put back
    on the bare mesh (768 nats worse); the footprint's placement should be the reference."""
    data, effects = dataset('beam_divergence')
    footprint = effects[0]
    zero = make_effect('surface_offset', {'standoff_m': 0.0})
    alone = model_on_rays(data, [footprint])
    beside = model_on_rays(data, [footprint, zero])
    np.testing.assert_allclose(beside.expected_range_m, alone.expected_range_m, equal_nan=True)
    assert objective(data, [footprint, zero]) == objective(data, [footprint])
