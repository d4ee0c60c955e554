"""Counts of returns left out before anything is fitted (occlusion, crosstalk ghosts)."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LeftOut:
    """Returns left out of the analysed points: how many, and in how many clouds."""

    points: int                  # returns left out
    analysed: int                # points analysed before they were left out
    clouds: int                  # clouds with at least one
    clouds_total: int

    @property
    def fraction(self) -> float:
        return self.points / max(self.analysed, 1)

    def counts(self) -> dict:
        """The counts for summary.json (the share rounded to 1e-5)."""
        return {'points': self.points, 'fraction': round(self.fraction, 5),
                'clouds': self.clouds, 'clouds_total': self.clouds_total}
