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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_sim_ros.core.effects import make_effect

PLACES = (('start', 0.5), ('end', -0.5))   # place of the stamp, dt_s in frame periods
SCAN_PLACES = (('middle', -0.5), ('end', -1.0))   # the same, times from the scan pattern


@dataclass(frozen=True)
class StampPlace:
    """The stamp's place in the scan that explains a fitted time offset."""

    place: str                 # 'start', 'middle' or 'end'
    dt_s: float                # the convention's offset (s): +-T/2 or -T
    fitted_dt_s: float         # the fitted offset (s)
    period_s: float            # frame period (s), from the cloud stamps
    likelihood_ratio: float    # 2 (NLL(convention) - NLL(fitted)), total nats

    def as_dict(self) -> dict:
        return {'place': self.place, 'dt_s': round(self.dt_s, 6),
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
            best = StampPlace(place, dt, float(fitted_dt_s), period_s, max(float(lr), 0.0))
    return best
