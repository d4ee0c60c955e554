"""ros/sun_input.py and core/vectors.py: any finite direction is normalised after scaling."""
import numpy as np
import pytest

from lidar_sim_ros.core.config import SunConfig
from lidar_sim_ros.core.vectors import unit_vector
from lidar_sim_ros.ros.sun_input import check_sun_direction


@pytest.mark.parametrize('vector, expected', [
    ((1e300, 1e300, 0.0), (2 ** -0.5, 2 ** -0.5, 0.0)),     # norm overflows to inf unscaled
    ((-1.7e308, 0.0, 1.7e308), (-2 ** -0.5, 0.0, 2 ** -0.5)),
    ((3e-8, 4e-8, 0.0), (0.6, 0.8, 0.0)),                   # small but not nearly zero
    ((0.0, 0.0, 2.0), (0.0, 0.0, 1.0)),
])
def test_finite_vectors_of_any_size_give_their_direction(vector, expected):
    np.testing.assert_allclose(unit_vector(vector), expected, rtol=0, atol=1e-15)
    unit, rejection = check_sun_direction(vector)
    assert rejection is None
    np.testing.assert_allclose(unit, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(SunConfig(direction=vector).direction, expected, atol=1e-15)


@pytest.mark.parametrize('vector, kind, words', [
    ((1e-300, 0.0, 0.0), 'sun_zero', 'nearly zero'),       # once underflowed to "sun hidden"
    ((1e-10, -1e-10, 0.0), 'sun_zero', 'nearly zero'),
    ((0.0, 0.0, 0.0), 'sun_zero', 'is zero'),
    ((np.inf, 0.0, 0.0), 'sun_finite', 'not finite'),
    ((np.nan, 1.0, 0.0), 'sun_finite', 'not finite'),
    ((1.0, 0.0), 'sun_shape', '3 components'),
])
def test_bad_vectors_are_refused_with_the_reason(vector, kind, words):
    unit, rejection = check_sun_direction(vector)
    assert unit is None and rejection.kind == kind and words in rejection.reason
    with pytest.raises(ValueError, match=words):
        unit_vector(vector)


def test_only_an_exact_zero_hides_the_sun():
    assert check_sun_direction((0.0, -0.0, 0.0), zero_is_dark=True) == (None, None)
    unit, rejection = check_sun_direction((1e-300, 0.0, 0.0), zero_is_dark=True)
    assert unit is None and rejection.kind == 'sun_zero'
