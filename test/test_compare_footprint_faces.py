"""A footprint read at its nearest sub-ray moves every oblique face, not only its edges.

The diagnosis re-casts a footprint candidate on the rays near an edge only (the others
keep the single ray's answer, ``fit_data.make_fit_data``). For a footprint whose range is
the energy-weighted mean that holds on a plane; for one read at its nearest sub-ray
(``range_mode: first``) it does not: on a face tilted by theta the near side of a spot of
half-angle a is about r a tan(theta) nearer. Re-cast near edges only, a first run's
footprint left those faces to an incidence bias, which then gained four times what it
gains beside the footprint as --fit fits it (battery ``beam_solar_incid``, seed 0: 0.0105
against 0.0024-0.0032 nats/point; docs/compare.md, "The footprint of a first run on every
face").
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_sim_ros.compare.diagnose import fit_data
from lidar_sim_ros.compare.model.matching import (EDGE_FAR, Model, edge_distance_rad,
                                                  predict_rays)
from lidar_sim_ros.compare.recording.measurements import Measurements, padded_pose_track
from lidar_sim_ros.core.effects import make_effect
from lidar_sim_ros.core.scan import directions_from_angles

from conftest import materials, plate_target, sensor

TILT_DEG = 60.0
RANGE_M = 10.0


def tilted_plate_rays(n: int = 41) -> tuple[Model, fit_data.RaySet]:
    """Rays at the middle of a 4 m plate 10 m away, its normal TILT_DEG off the rays
    (about the lidar z axis), static pose; every ray hits, none near an edge."""
    q = (Rotation.from_euler('z', TILT_DEG, degrees=True)
         * Rotation.from_euler('y', -90, degrees=True)).as_quat()    # body +z -> tilted -x
    track = padded_pose_track(np.array([0.0, 1.0]), np.array([[RANGE_M, 0, 0]] * 2),
                              np.array([q, q]), 0.5)
    dirs = directions_from_angles(np.linspace(-0.01, 0.01, n), np.zeros(n))
    meas = Measurements(bag=None, xyz_m=dirs * RANGE_M, range_m=np.full(n, RANGE_M),
                        directions=dirs, intensity=None, t_s=np.full(n, 0.5),
                        t_frame_s=np.zeros(n), cloud=np.zeros(n, int),
                        laser=np.zeros(n, np.uint16), has_point_time=True,
                        cloud_stamps_s=np.zeros(1), epoch_s=0.0, poses=track,
                        material_names=None)
    model = Model(sensor(), materials(), plate_target(4.0))
    pred = predict_rays(model.simulator(), meas)
    assert pred.ctx.hit.all()
    edge = edge_distance_rad(model.target, meas, pred, model.divergence_rad)
    assert np.all(edge == EDGE_FAR * model.divergence_rad)      # far from every edge
    rays = fit_data.RaySet(meas, np.arange(n), np.zeros(0, int), pred=pred, edge_rad=edge)
    return model, rays


def footprint(mode: str, scale: float = 4.0):
    return make_effect('beam_divergence', {'footprint_scale': scale, 'range_mode': mode})


def test_nearest_sub_ray_footprint_shortens_a_tilted_face_away_from_its_edges():
    model, rays = tilted_plate_rays()
    fp = footprint('first')
    assert fp.ranges_off_edges()
    data = fit_data.make_fit_data(model, [], rays)
    base = np.asarray(data.baseline.ctx.range_m, float)
    cast = np.asarray(data.cast([fp]).ctx.range_m, float)
    half = 0.5 * 4.0 * model.divergence_rad
    shortening = base - cast
    # About r a tan(theta) nearer (the outer ring's nearest sub-ray: most of it); the old
    # shortcut kept the single ray's range (0 shorter).
    expected = base * half * np.tan(np.radians(TILT_DEG))
    assert np.all(shortening > 0.5 * expected)
    assert np.all(shortening < 1.2 * expected)
    # ... and it is the footprint's own answer on every ray (no shortcut at all).
    full = fit_data.make_fit_data(model, [], fit_data.RaySet(rays.meas, rays.matched,
                                                             rays.unmatched, pred=rays.pred))
    assert cast == pytest.approx(np.asarray(full.cast([fp]).ctx.range_m, float), abs=1e-6)


def test_energy_weighted_footprint_keeps_the_single_ray_away_from_edges():
    model, rays = tilted_plate_rays()
    fp = footprint('mean')
    assert not fp.ranges_off_edges()
    assert not footprint('first', scale=0.0).ranges_off_edges()
    data = fit_data.make_fit_data(model, [], rays)
    base = np.asarray(data.baseline.ctx.range_m, float)
    cast = np.asarray(data.cast([fp]).ctx.range_m, float)
    assert cast == pytest.approx(base, abs=1e-9)       # the shortcut, as before
    # ... which is what the full re-cast gives to first order (mm at 60 deg).
    full = fit_data.make_fit_data(model, [], fit_data.RaySet(rays.meas, rays.matched,
                                                             rays.unmatched, pred=rays.pred))
    assert np.asarray(full.cast([fp]).ctx.range_m, float) == pytest.approx(base, abs=2e-3)
