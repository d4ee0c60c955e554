"""The time within the scan, one base for a whole recording (``ScanClock``), and the part
of it that the direction does not fix (``beyond_direction``): what one rate of the
reference pose for the recording is fitted and tested on (``pose_error.fit_reference_pose``
with ``constant=True``, ``rate=True``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SCAN_CLOCK_QUANTILE = 0.001   # a few stray point times do not stretch the scan's time base
SAMPLE_EDGE_SHARE = 1e-3      # a pose sample this share of a frame before a scan is its first


@dataclass(frozen=True)
class ScanClock:
    """One time base within the scan for the whole recording: tau = (t - stamp_c -
    centre_s) / half_s, t a time and stamp_c the stamp of the cloud whose frame holds
    it: the frame period ``period_s`` about each scan's centre (stamp + ``centre_s``),
    half-open, so frames tile the time axis. The same rate of a drifting reference pose
    in every cloud is a correction ``a tau`` with one set of parameters; fixed once for
    the recording so that a correction composed over re-casts (``PoseCorrection``) means
    the same at every pass.

    The drift belongs to the reference pose's samples (``sample_s``: their times, s):
    the model interpolates the pose between them, so a pose that drifts within each
    scan and is reset at its start (a tracking pose sampled once a cloud and held) shows
    at a point's time as the samples' errors interpolated there, not as tau at the
    point's own time. Between the last sample of one cloud and the first of the next
    the interpolated error runs back to the start: at 100 Hz, a drift of 4 cm over each
    0.1 s scan fitted on tau at the point times came out as 2.9 cm. So ``tau(t)`` is
    tau at the samples, interpolated to t (tau at t itself without samples). A sample
    at a scan's start (up to SAMPLE_EDGE_SHARE of a frame before its frame, far less
    than any tracking system's sample interval, which the edge's rounding would
    otherwise decide) is that scan's first: a pose sampled at the cloud's stamp."""

    stamps_s: np.ndarray      # (K,) each cloud's stamp, sorted (s, recording clock)
    centre_s: float           # tau = 0: this long after the stamp (s)
    half_s: float             # tau = +-1: this far from the centre (s)
    period_s: float           # the frame period (s)
    sample_s: np.ndarray | None = None   # (S,) the reference pose's sample times (s), sorted

    @classmethod
    def of(cls, cloud: np.ndarray, t_s: np.ndarray, stamps_s: np.ndarray | None = None,
           sample_s: np.ndarray | None = None) -> 'ScanClock | None':
        """The time base of points ``cloud`` (cloud index each) at times ``t_s`` (s);
        ``stamps_s``: the stamp of each cloud index (None: each cloud's first point
        time); ``sample_s``: the reference pose's sample times (None: none known). The
        centre and half-span are the middle and half the width of the points' times
        since their stamps (quantiles SCAN_CLOCK_QUANTILE), the frame period the median
        step between stamps (one cloud: the span). None when the points span no time
        within their clouds (no point times)."""
        t = np.asarray(t_s, float)
        clouds, row = np.unique(np.asarray(cloud), return_inverse=True)
        ok = np.isfinite(t)
        if not len(clouds) or not ok.any():
            return None
        if stamps_s is None:
            stamp = np.full(len(clouds), np.inf)
            np.minimum.at(stamp, row[ok], t[ok])
        else:
            stamp = np.asarray(stamps_s, float)[np.asarray(clouds, int)]
        keep = np.isfinite(stamp)
        since = (t - stamp[row])[ok & keep[row]]
        if not len(since):
            return None
        lo, hi = np.quantile(since, [SCAN_CLOCK_QUANTILE, 1 - SCAN_CLOCK_QUANTILE])
        if not hi - lo > 1e-9:
            return None
        stamps = np.sort(stamp[keep])
        steps = np.diff(stamps)
        steps = steps[steps > 0]
        period = float(np.median(steps)) if len(steps) else float(hi - lo)
        samples = None
        if sample_s is not None:
            samples = np.unique(np.asarray(sample_s, float))
            samples = samples[np.isfinite(samples)]
            samples = samples if len(samples) >= 2 else None
        return cls(stamps, float(0.5 * (lo + hi)), float(0.5 * (hi - lo)),
                   max(period, float(hi - lo)), samples)

    def tau_at(self, t_s: np.ndarray, edge_s: float = 0.0) -> np.ndarray:
        """(N,) tau of each time itself within its frame's scan; ``edge_s``: a time this
        much before a frame counts in it. A time before the first frame or after the
        last (a pose sample outside the recording) is read at that frame's edge."""
        t = np.asarray(t_s, float)
        start = self.stamps_s + self.centre_s - 0.5 * self.period_s - edge_s
        k = np.clip(np.searchsorted(start, t, side='right') - 1, 0, len(start) - 1)
        edge = (0.5 * self.period_s + edge_s) / self.half_s
        return np.clip((t - self.stamps_s[k] - self.centre_s) / self.half_s, -edge, edge)

    def tau(self, t_s: np.ndarray) -> np.ndarray:
        """(N,) tau of the reference pose at each time: interpolated from its samples'
        (class doc), else ``tau_at``."""
        if self.sample_s is None:
            return self.tau_at(t_s)
        return np.interp(np.asarray(t_s, float), self.sample_s,
                         self.tau_at(self.sample_s, SAMPLE_EDGE_SHARE * self.period_s))

    def as_dict(self) -> dict:
        return {'centre_after_stamp_s': round(self.centre_s, 6),
                'scan_s': round(2 * self.half_s, 6), 'frame_s': round(self.period_s, 6),
                'from_pose_samples': self.sample_s is not None}


DIRECTION_CELL_DEG = 0.25   # a sensor's pattern over its field of view is smooth over this


def beyond_direction(tau: np.ndarray, direction: np.ndarray, use: np.ndarray) -> np.ndarray:
    """(N,) ``tau`` less its mean over the ``use`` points of each direction cell
    (DIRECTION_CELL_DEG in azimuth and elevation, lidar frame; zero where a cell holds
    one point): the time within the scan that the direction does not fix. A scan that
    repeats every cloud ties each shot's time to its direction, so one rate for the
    recording, ``a tau``, is a fixed pattern over the field of view as well, which a
    sensor's own pattern passes for: on a raster, whose time follows its rows, a range
    bias periodic in azimuth (an encoder error, the battery's ``azimuth_bias``) passed
    as a drift of 2.6 cm and 3.4 deg per 0.1 s (z 6.8). A drift of the pose shows where
    the scan meets one direction at different times (a Lissajous's or a rosette's
    crossing passes), which no pattern over the directions can take."""
    u = np.asarray(direction, float)
    az = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    el = np.degrees(np.arcsin(np.clip(u[:, 2], -1.0, 1.0)))
    ok = use & np.isfinite(az) & np.isfinite(el)
    key = np.stack([np.floor(np.where(ok, az, 0.0) / DIRECTION_CELL_DEG),
                    np.floor(np.where(ok, el, 0.0) / DIRECTION_CELL_DEG)], axis=1)
    _, cell = np.unique(key.astype(np.int64), axis=0, return_inverse=True)
    cell = cell.ravel()
    t = np.where(ok, np.asarray(tau, float), 0.0)
    n = np.bincount(cell, weights=ok.astype(float))
    mean = np.bincount(cell, weights=t) / np.maximum(n, 1.0)
    return np.where(ok & (n[cell] > 1), t - mean[cell], 0.0)
