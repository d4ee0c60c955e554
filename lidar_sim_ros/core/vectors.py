"""Directions and rotations from user input: vectors scaled before they are normalised, so
any finite vector works; the tolerance a quaternion's norm is held to.

``np.linalg.norm`` of ``[1e300, 1e300, 0]`` overflows to inf (and that of ``[1e-300, 0, 0]``
underflows to 0): a direction divided by it is zero or NaN. Dividing by the largest
component first keeps every finite vector in range; only the direction matters.
"""
from __future__ import annotations

import numpy as np

# A vector whose largest component is below this is refused as "nearly zero": its direction
# is as likely rounding noise as intent (an exact zero may mean something to the caller).
MIN_COMPONENT = 1e-9

QUAT_NORM_TOL = 0.01
"""A quaternion whose norm is within this of 1 is normalised; further off it is refused
(config) or dropped and counted (recorded poses, pose topics): (1, 1, 0, 0) is no rotation
anyone meant."""


def unit_vector(vector) -> np.ndarray:
    """The unit vector along ``vector`` (3 finite components, not nearly zero).

    Raises ValueError naming what is wrong (shape, non-finite, zero or nearly zero).
    """
    v = np.asarray(vector, dtype=float)
    if v.shape != (3,):
        raise ValueError(f'needs 3 components, got {v.size}')
    if not np.isfinite(v).all():
        raise ValueError(f'{v.tolist()} is not finite')
    largest = float(np.abs(v).max())
    if largest == 0.0:
        raise ValueError('is zero')
    if largest < MIN_COMPONENT:
        raise ValueError(f'{v.tolist()} is nearly zero (every component below {MIN_COMPONENT:g})')
    scaled = v / largest                      # largest component +-1: the norm is in [1, sqrt 3]
    return scaled / np.linalg.norm(scaled)
