"""Clouds without per-point time: is a fitted time offset just where the stamp sits?

The verdict still names ``time_offset`` (the model needs the offset either way); this
tells the user which stamp convention would produce it, so that a driver's convention
is not chased as a clock error.

Without a time field every point carries its cloud's header stamp. Drivers put that
stamp at the start, the middle or the end of the scan; the model assumes the middle.
A stamp at the start makes every point look measured half a frame early: the data are
then exactly those of a clock offset ``dt_s = +T/2`` (T: frame period), and a stamp at
the end those of ``dt_s = -T/2``. A driver's convention is far more common than a clock
offset of exactly half a frame, so when the fitted offset is consistent with one of
them, the comparison says so (``summary.json`` ``stamp_place``).

Consistent means: the fitted offset is not decisively better than the convention's,
by the rules every candidate must meet (diagnosis module doc): either the likelihood
ratio 2 (NLL(convention) - NLL(fitted)) stays below z_crit^2 (the chi-square with one
degree of freedom at the family's level), or the fitted offset gains less than the
practical margin (nats per point) over the convention's (a scan that does not fill the
frame puts the mean point time a little short of T/2: such a remainder does not
matter). Otherwise the offset is a clock offset (or a stamp convention plus one), and
``time_offset`` stays the verdict.

Clouds whose point times come from the scan pattern (no time field, the directions
matched to the configured shots) are timed from a stamp at the scan's start: a stamp in
the middle then gives ``dt_s = -T/2`` and one at the end ``dt_s = -T`` (``SCAN_PLACES``).

Without point times the stamp's place and a clock offset are the same data: -T/2 fitted
on scan-pattern times is a stamp in the middle with the clocks in step, and just as well
a stamp at the end with the poses stamped T/2 late (a holdout's end-stamped clouds with
a 50 ms pose lag were read as a 'middle' stamp), or at the start with them T/2 early.
So the place is not named: ``StampPlace.readings`` gives every place with the clock
offset it needs, one of them none, and the verdict says that a recording with the
driver's per-point time field (or the driver's documented stamp place) separates them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.core.effects import make_effect

PLACES = (('start', 0.5), ('end', -0.5))   # place of the stamp, dt_s in frame periods
SCAN_PLACES = (('middle', -0.5), ('end', -1.0))   # the same, times from the scan pattern
# Every place, the one the times assume (dt_s 0) among them: the readings of an offset.
ALL_PLACES = {PLACES: (('start', 0.5), ('middle', 0.0), ('end', -0.5)),
              SCAN_PLACES: (('start', 0.0), ('middle', -0.5), ('end', -1.0))}


@dataclass(frozen=True)
class StampPlace:
    """A fitted time offset that a stamp convention explains with the clocks in step:
    one reading of several (``readings``), which the data cannot tell apart."""

    place: str                 # 'start', 'middle' or 'end': the place with clocks in step
    dt_s: float                # the convention's offset (s): +-T/2 or -T
    fitted_dt_s: float         # the fitted offset (s)
    period_s: float            # frame period (s), from the cloud stamps
    likelihood_ratio: float    # 2 (NLL(convention) - NLL(fitted)), total nats
    # (place, clock offset s) of every place: the pose clock's offset (dt_s, poses
    # stamped late when positive) that the place needs to give the same data.
    readings: tuple = ()

    def as_dict(self) -> dict:
        """``place`` is null: the data do not tell it from a clock offset (module doc)."""
        return {'place': None, 'separable_from_clock_offset': False,
                'readings': [{'place': p, 'clock_offset_s': round(c, 6)}
                             for p, c in self.readings],
                'dt_s': round(self.dt_s, 6),
                'fitted_dt_s': round(self.fitted_dt_s, 6), 'period_s': round(self.period_s, 6),
                'likelihood_ratio': round(self.likelihood_ratio, 3)}


def stamp_place(total_nll, fitted_dt_s: float, period_s: float, bound: float,
                n_points: int, margin: float, places=PLACES) -> StampPlace | None:
    """The convention (module doc) that explains ``fitted_dt_s``, or None.

    ``total_nll(effect)``: total NLL (nats) of the ``n_points`` analysed points with
    ``effect`` added; ``bound``: the likelihood ratio below which the two explain the data
    alike; ``margin``: the gain per point (nats) that matters; ``places``: (place, dt in
    frame periods) of the conventions, ``PLACES`` or ``SCAN_PLACES``.
    """
    if not (np.isfinite(fitted_dt_s) and period_s > 0):
        return None
    fitted = total_nll(make_effect('time_offset', {'dt_s': float(fitted_dt_s)}))
    best = None
    for place, share in places:
        dt = share * period_s
        if np.sign(dt) != np.sign(fitted_dt_s):
            continue
        lr = 2.0 * (total_nll(make_effect('time_offset', {'dt_s': dt})) - fitted)
        alike = lr < bound or 0.5 * lr < margin * n_points
        if alike and (best is None or lr < best.likelihood_ratio):
            readings = tuple((p, float(dt - s * period_s))
                             for p, s in ALL_PLACES.get(tuple(places), ()))
            best = StampPlace(place, dt, float(fitted_dt_s), period_s, max(float(lr), 0.0),
                              readings)
    return best
