"""A simulated frame as the Cepton SDK3 driver would publish it (``io/cepton.py``).

``point_layout: cepton`` (node and ``lidar-sim simulate``) sends each frame through
``cepton_frame_points``:

* intensity = the sensor's reflectivity estimate, range-compensated: the received
  power times range^2 over the power a 100 % Lambertian plate at normal incidence
  returns at 1 m (``lambertian_power_at_1m_w``, the paper's Eqs. 1-3 with the
  configured optics), so a 30 % Lambertian plate at normal incidence reads 0.30 at
  any range; in the driver's 1 % steps;
* saturated returns (received power at or above the saturation power), which the
  paper's detector omits, are kept with the SATURATED flag, at the range the model
  measured for them (material bias, effects and noise, as for any return) and the
  reflectivity a clipped pulse reads (the saturation power, range-compensated);
* optionally, one NO_RETURN point (x = y = z = 0) per shot that returned nothing;
* time: timestamp_s + timestamp_us = frame start + the shot's time, header stamp =
  frame start.
"""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from lidar_sim_ros.core.config import SensorConfig
from lidar_sim_ros.core.reflection import return_power_w
from lidar_sim_ros.io import cepton

NS_PER_S = 1_000_000_000


def lambertian_power_at_1m_w(sensor: SensorConfig) -> float:
    """Received power (W) from a 100 % Lambertian plate at 1 m, normal incidence (a flash
    array: in the pixel on the boresight)."""
    from lidar_sim_ros.core.scan_flash import pixel_view_sr
    pixel_sr = pixel_view_sr(sensor, np.array([[1.0, 0.0, 0.0]]))
    return float(np.ravel(return_power_w(1.0, 0.0, 1.0, 0.0, 1.0, sensor.optics,
                                         pixel_sr=pixel_sr))[0])


def reflectivity_estimate(power_w: np.ndarray, range_m: np.ndarray,
                          sensor: SensorConfig) -> np.ndarray:
    """Range-compensated reflectivity (fraction): P r^2 / P_lambertian(1 m)."""
    return (np.asarray(power_w, float) * np.asarray(range_m, float) ** 2
            / lambertian_power_at_1m_w(sensor))


def cepton_frame_points(frame, sensor: SensorConfig, stamp_ns: int, no_return: bool = False,
                        polar: bool = False, noise: bool = False) -> np.ndarray:
    """The SDK3 driver's points (``io.cepton.SDK3_DTYPE``) of a simulated ``Frame``
    stamped ``stamp_ns`` (= its start): detected returns, saturated returns flagged,
    and with ``no_return`` a NO_RETURN point per silent shot; in firing order. ``polar``:
    with the driver's optional azimuth, elevation and range fields. ``noise``: false
    returns (no material: sunlight, background) flagged NOISE, as the wire carries them."""
    det = sensor.detection
    sat_w = det.saturation_power_w
    xyz = [np.asarray(frame.xyz_m, float)]
    refl = [reflectivity_estimate(np.asarray(frame.intensity) * sat_w, frame.range_m, sensor)]
    t = [np.asarray(frame.t_s, float)]
    laser = [np.asarray(frame.ring)]
    # The driver flags every return after a shot's first one SECOND_RETURN.
    flags = [np.where(np.asarray(frame.return_number if frame.return_number is not None else 1) > 1, cepton.SECOND_RETURN, 0).astype(np.uint16)]
    if noise:
        from lidar_sim_ros.core.pipeline import NO_MATERIAL
        flags[0] = flags[0] | np.where(np.asarray(frame.material) == NO_MATERIAL,
                                       cepton.NOISE, 0).astype(np.uint16)
    shots = frame.truth_source
    if shots is not None:
        power = np.asarray(shots.intensity, float) * sat_w
        rng = np.asarray(shots.range_m, float)
        measured = (rng if shots.measured_range_m is None
                    else np.asarray(shots.measured_range_m, float))
        # A shot returned when one of the frame's points carries its time (one time per shot).
        returned = np.isin(shots.t_s, frame.t_s)
        with np.errstate(invalid='ignore'):
            sat = (np.asarray(shots.hit, bool) & (power >= sat_w) & (rng >= det.min_range_m)
                   & (rng <= det.max_range_m) & np.isfinite(measured) & (measured > 0)
                   & ~returned)
        idx = np.flatnonzero(sat)
        r_sat = measured[idx]
        xyz.append(shots.directions[idx] * r_sat[:, None])
        refl.append(reflectivity_estimate(np.full(len(idx), sat_w), r_sat, sensor))
        t.append(np.asarray(shots.t_s)[idx])
        laser.append(np.asarray(shots.ring)[idx])
        flags.append(np.full(len(idx), cepton.SATURATED, np.uint16))
        if no_return:
            silent = ~returned & ~sat
            idx = np.flatnonzero(silent)
            xyz.append(np.zeros((len(idx), 3)))
            refl.append(np.zeros(len(idx)))
            t.append(np.asarray(shots.t_s)[idx])
            laser.append(np.asarray(shots.ring)[idx])
            flags.append(np.full(len(idx), cepton.NO_RETURN, np.uint16))
    t_all = np.concatenate(t)
    order = np.argsort(t_all, kind='stable')
    t_ns = np.int64(stamp_ns) + np.rint(t_all[order] * NS_PER_S).astype(np.int64)
    return cepton.cepton_points(np.vstack(xyz)[order], np.concatenate(refl)[order], t_ns,
                                np.concatenate(flags)[order], np.concatenate(laser)[order],
                                polar=polar)


class OutputLayout(BaseModel):
    """How simulated clouds are published: our layout or the Cepton driver's, on which
    topic and in which frame (None: the layout's default)."""

    model_config = ConfigDict(extra='forbid')
    point_layout: Literal['native', 'cepton'] = 'native'
    topic: str | None = None
    frame_id: str | None = None
    no_return_points: bool = False
    polar_fields: bool = False            # cepton: also azimuth, elevation (rad), range (m)

    def cloud_topic(self, native_default: str) -> str:
        """The cloud topic: the configured one, else ``/cepton_pcl2`` or ``native_default``."""
        if self.topic:
            return self.topic
        return '/' + cepton.TOPIC if self.point_layout == 'cepton' else native_default

    def frame(self, native_default: str) -> str:
        """The frame id: the configured one, else ``cepton3`` or ``native_default``."""
        if self.frame_id:
            return self.frame_id
        return cepton.FRAME_ID if self.point_layout == 'cepton' else native_default

    def points(self, frame, sim, stamp_ns: int) -> np.ndarray:
        """The frame's points in this layout (``sim``: the Simulator that made it, for
        its sensor's optics and detection limits)."""
        if self.point_layout == 'cepton':
            return cepton_frame_points(frame, sim.sensor, stamp_ns, self.no_return_points,
                                       self.polar_fields)
        from lidar_sim_ros.io.pointcloud import frame_points
        return frame_points(frame)


def wire_packets(frame, sim, stamp_ns: int, state, no_return: bool = True) -> list:
    """A simulated frame as a Cepton sensor sends it (``io.cepton_wire``): its points in
    firing order, saturated, second-return, noise and (with ``no_return``) NO_RETURN
    points flagged, cut into STDV packets; ``state`` is the stream's ``WireStream``."""
    from lidar_sim_ros.io import cepton_wire
    points = cepton_frame_points(frame, sim.sensor, stamp_ns, no_return, noise=True)
    return cepton_wire.frame_packets(points, state)
