"""A surface standoff's re-cast across a silhouette is no evidence (likelihood.crossed_silhouette).

A lab may read a blanket proud along each ray and leave its silhouette where the mesh has
it (an independent lab's MLI 2.5 cm proud recording): there, rays just past a limb still
meet the part behind. A standoff fitted on the blanket's faces re-casts those rays onto
the proud limb, metres nearer, and before this their outlier score outweighed the whole
gain of the blanket's faces (surface_offset -0.0006 nats/point held out for a true 2.5 cm).
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.compare.model.fit import fit_data_from_rays
from lidar_sim_ros.compare.model.likelihood import (crossed_silhouette, material_standoffs_m,
                                                    model_on_rays, point_nll)
from lidar_sim_ros.core.effects import make_effect
from lidar_sim_ros.core.pipeline import Simulator

from test_fitting import MATERIALS, scene

PAINT, FOIL, PANEL = 0, 1, 2


def limb_data(seed: int = 5):
    """Rays of the mesh scene (cylinder in PAINT, a PANEL plate 2.5 m behind it) as the
    recording: the silhouette is the mesh's."""
    sensor, target, traj = scene()
    sim = Simulator(sensor, MATERIALS, target, seed=seed, effects=[])
    fr = sim.simulate_frame(0.0, traj, 0)
    dirs = fr.xyz_m / np.linalg.norm(fr.xyz_m, axis=1, keepdims=True)
    return fit_data_from_rays(sim, fr.stamp_s + fr.t_s, dirs, fr.range_m, traj, fr.t_s)


def proud_paint(standoff_m: float):
    return make_effect('surface_offset', {'material_standoff_m': {'PAINT': standoff_m}})


def test_rays_past_a_proud_limb_keep_the_mesh_placement():
    """With the cylinder's PAINT 8 cm proud, rays that met the PANEL just past its limb
    now meet the cylinder, 2-4 m nearer: they keep the mesh's placement and score as
    without the standoff (before: expected on the proud limb, scored as outliers). The
    standoff still moves the PAINT rays that stay on the PAINT."""
    data = limb_data()
    effect = proud_paint(0.08)
    recast = data.cast([effect])
    crossed = crossed_silhouette(data.baseline, recast)
    base_mat = np.asarray(data.baseline.ctx.material)
    past_limb = crossed & (base_mat == PANEL)
    assert past_limb.sum() >= 5
    jump = recast.expected_range_m[past_limb] - data.baseline.expected_range_m[past_limb]
    assert np.all(jump < -1.0)
    before = model_on_rays(data, [])
    after = model_on_rays(data, [effect])
    np.testing.assert_allclose(after.expected_range_m[crossed],
                               before.expected_range_m[crossed])
    nll_before = point_nll(data, before)[0]
    nll_after = point_nll(data, after)[0]
    assert np.max(np.abs(nll_after[past_limb] - nll_before[past_limb])) < 0.05
    on_paint = (base_mat == PAINT) & ~crossed
    shift = after.expected_range_m[on_paint] - before.expected_range_m[on_paint]
    assert np.median(shift) < -0.07


def test_only_rays_at_an_edge_are_crossed():
    """A standoff of 1 mm crosses at most a ray or two of 4004 (a limb's), 1 cm a few
    dozen, 8 cm a few per cent: only rays within the standoff's reach of an edge."""
    data = limb_data()
    counts = [int(crossed_silhouette(data.baseline, data.cast([proud_paint(s)])).sum())
              for s in (0.001, 0.01, 0.08)]
    assert counts[0] <= 2 < counts[1] < counts[2] < 0.06 * len(data.measured_range_m)


def test_a_blankets_rim_over_bare_faces_keeps_the_mesh_placement_a_proud_seam_counts():
    """PAINT alone 3 cm proud (the FOIL caps bare): rays moved over the side's rim between
    the caps and the side are crossed and placed on their own face of the mesh, moved
    (before: re-cast onto the ramp or the rim). The same cylinder proud all over (one standoff): a ray over the
    same seam moves with both faces and still counts (only limb jumps are crossed)."""
    data = limb_data()
    base_mat = np.asarray(data.baseline.ctx.material)
    one = proud_paint(0.03)
    recast = data.cast([one])
    table = material_standoffs_m(recast, [one])
    assert table is not None and table[PAINT] == 0.03 and table[FOIL] == 0.0
    crossed = crossed_silhouette(data.baseline, recast, table)
    jump = np.abs(recast.expected_range_m - data.baseline.expected_range_m)
    rim = crossed & (jump < 0.5)
    assert rim.sum() >= 3
    assert np.all(base_mat[rim] != np.asarray(recast.ctx.material)[rim])
    before, after = model_on_rays(data, []), model_on_rays(data, [one])
    shift = after.expected_range_m - before.expected_range_m
    bare_side, proud_side = rim & (base_mat == FOIL), rim & (base_mat == PAINT)
    assert bare_side.sum() + proud_side.sum() == rim.sum()
    # On its own face of the mesh, that face moved: a bare cap's ray stays, a side's
    # moves by its standoff along the ray (-s / cos(theta)), whatever the rim does.
    np.testing.assert_allclose(shift[bare_side], 0.0, atol=1e-9)
    own = one.first_order_shift_m(data.baseline.ctx, MATERIALS.names)
    np.testing.assert_allclose(shift[proud_side], own[proud_side], atol=1e-6)
    assert np.all(own[proud_side] <= -0.0299)
    every = make_effect('surface_offset', {'standoff_m': 0.03})
    recast_all = data.cast([every])
    crossed_all = crossed_silhouette(data.baseline, recast_all,
                                     material_standoffs_m(recast_all, [every]))
    jump_all = np.abs(recast_all.expected_range_m - data.baseline.expected_range_m)
    assert np.all(jump_all[crossed_all] > 0.5)
