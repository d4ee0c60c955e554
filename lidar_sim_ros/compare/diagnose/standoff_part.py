"""A surface standoff beside an incidence-shaped rival: named only by its per-material part.

The foreign incidence bias -g (1 / cos(theta) - 1) and a standoff s common to every
surface (a range change of -s / cos(theta)) differ only by a constant, which each
material's profiled range offset takes: at one distance a common standoff IS an
incidence-shaped bias, and a footprint's edge bias (growing as 1 / cos(theta) too) is
within its reach. What a standoff does that they cannot is differ between materials (an
MLI blanket proud, bare metal not). So where ``surface_offset`` competes with such a
rival (``INCIDENCE_SHAPED``, one that may be named itself), its per-material part must
pass the rule alone: its held-out gain over the same standoff fitted common to every
material (``CommonStandoff``, cross-fitted on the diagnosis's folds as the score). A
standoff whose part does not pass is set aside (``Diagnosis.standoff_part_veto``): the
rival is named if it passes, or a tie stays among the others.
"""
from __future__ import annotations

import numpy as np

from lidar_sim_ros.core.effects.surface_offset import SurfaceOffset

STANDOFF = 'surface_offset'
# Rivals whose range change grows as 1 / cos(incidence): an incidence bias, a footprint.
INCIDENCE_SHAPED = ('incidence_angle', 'beam_divergence')


class CommonStandoff(SurfaceOffset):
    """``surface_offset`` fitted with no standoff of a material's own (the scale and the
    common standoff only): the part an incidence-shaped bias shares. Not registered: the
    comparison's variant, written out as ``surface_offset``."""

    common_only = True


def common_part_of(effect_cls) -> type | None:
    """The common-standoff variant of a ``surface_offset`` class, or None for any other
    effect (or one that is that variant)."""
    if (isinstance(effect_cls, type) and issubclass(effect_cls, SurfaceOffset)
            and not getattr(effect_cls, 'common_only', False)):
        return CommonStandoff
    return None


def rival_of(cand, cands, nameable) -> object | None:
    """The first incidence-shaped candidate among ``cands`` that may be named
    (``nameable``), or None: where ``cand`` (a standoff) competes with one."""
    if cand.name != STANDOFF:
        return None
    return next((c for c in cands if c.name in INCIDENCE_SHAPED and c is not cand
                 and nameable(c)), None)


def part_gain(full_nll: np.ndarray, common_nll: np.ndarray, blocks: np.ndarray,
              n_total: int, block_mean_se) -> tuple[float, float]:
    """The per-material part's held-out gain (nats per analysed point, matched points
    only) and its block-robust z: per point, the common standoff's held-out NLL less the
    full standoff's (both in ``cross_fit`` order)."""
    d = np.asarray(common_nll, float) - np.asarray(full_nll, float)
    ok = np.isfinite(d)
    if ok.sum() < 2:
        return 0.0, 0.0
    mean, se = block_mean_se(d[ok], blocks[ok])
    total = float(np.sum(d[ok]))
    z = total / (se * ok.sum()) if se > 0 and np.isfinite(se) else 0.0
    return total / max(n_total, 1), float(z)
