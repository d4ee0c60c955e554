"""A material too small for its own range offset (fewer than MIN_MATERIAL_POINTS points)
under an effect with a constant part (``likelihood.unprofiled_offset``): every material's
offset was calibrated with the model's own effects, so an added effect's constant shift is
taken back on a small material's points as the profiled offset takes it on a large one's
(walk_graze s7 step 1: a material of 12 points per fold lost 15 nats a point to the walk's
-18 cm, its held-out z 2.1 instead of 11.0, and incidence_angle was named for it)."""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.compare.model import likelihood as lk
from lidar_sim_ros.compare.model.fit import fit_data_from_rays
from lidar_sim_ros.core.effects import make_effect

from test_fitting import model_sim, scene


def _data(keep_small: int):
    """Clean points of the test scene, the FOIL caps cut to ``keep_small`` points."""
    truth = model_sim()
    traj = scene()[2]
    fr = truth.simulate_frame(3 * truth.frame_period_s, traj, 3)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    foil = np.flatnonzero(fr.material == 1)
    keep = np.ones(len(fr.range_m), bool)
    keep[foil[keep_small:]] = False
    return fit_data_from_rays(model_sim(), (fr.stamp_s + fr.t_s)[keep], dirs[keep],
                              fr.range_m[keep], traj, fr.t_s[keep])


def test_a_constant_shift_costs_nothing_on_a_small_material():
    data = _data(12)
    mat = np.asarray(data.baseline.ctx.material)
    small = mat == 1
    assert 0 < small.sum() < lk.MIN_MATERIAL_POINTS
    assert (mat == 0).sum() >= lk.MIN_MATERIAL_POINTS
    walk = make_effect('range_walk', {'k_m': 0.03, 'power': 'model'})   # about -0.2 m here
    base = lk.point_nll(data, lk.model_on_rays(data, []))[0]
    with_walk = lk.point_nll(data, lk.model_on_rays(data, [walk]))[0]
    shift = lk.model_on_rays(data, [walk]).expected_range_m - data.base_expected_m
    assert np.median(shift[small]) < -0.1            # a constant part of a decimetre and more
    # Before: the small material's offset stayed at 0 and each point lost ~10 nats or more.
    assert np.mean(with_walk[small] - base[small]) < 1.0
    # The large material's offset is profiled as it was: its loss is the walk's spread only.
    assert abs(np.mean(with_walk[mat == 0] - base[mat == 0])) < 1.0
    # No effect: no shift, the offset of the small material stays 0.
    use = np.isfinite(base)
    assert not np.any(lk.unprofiled_offset(data, data.base_expected_m, use))
