"""Hostile inputs, second round (issue 29): effect parameters bounded where they enter,
the range gate holding after every effect, and scenario / command-line inputs refused
with one line naming file, key and value."""
import numpy as np
import pytest
from pydantic import ValidationError

from lidar_sim_ros.core.effects import REGISTRY, Effect, catalogue, get_effect_class
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import StaticPose
from conftest import materials, plate_target, sensor

FACING = (0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5))    # plate normal (body +z) toward the sensor


def _numeric_fields(cls):
    """(name, lower, upper) of every float/int parameter of an effect's Params, its
    pydantic bounds read from the field metadata (None: unbounded)."""
    out = []
    for name, info in cls.Params.model_fields.items():
        ann = str(info.annotation)
        if not any(t in ann for t in ('float', 'int')) or 'list' in ann:
            continue
        lo = hi = None
        for m in info.metadata:
            lo = getattr(m, 'ge', None) if getattr(m, 'ge', None) is not None else (
                getattr(m, 'gt', None) if getattr(m, 'gt', None) is not None else lo)
            hi = getattr(m, 'le', None) if getattr(m, 'le', None) is not None else (
                getattr(m, 'lt', None) if getattr(m, 'lt', None) is not None else hi)
        out.append((name, lo, hi))
    return out


def _all_effects():
    catalogue()
    get_effect_class('sunlight')
    get_effect_class('range_scale')
    return sorted(REGISTRY.items())


@pytest.mark.parametrize('name, cls', _all_effects())
def test_every_effect_parameter_is_bounded(name, cls):
    """Issue 29: range_walk k_m = -1e6 was accepted. Every numeric parameter of every
    catalogue effect has a lower and an upper bound, refuses +-1e6, and the fit's search
    box lies inside them (a fit never proposes a value the Params refuse)."""
    fields = _numeric_fields(cls)
    assert fields or name == 'laser_bias'
    for field, lo, hi in fields:
        assert lo is not None and hi is not None, (name, field)
        assert hi < 1e6 and lo > -1e6, (name, field, lo, hi)
        for bad in (1e6, -1e6):
            with pytest.raises(ValidationError):
                cls({field: bad})
    for field, (lo, hi) in cls.bounds.items():
        if field == 'offsets_m':
            cls({field: [lo, hi]})
        else:
            cls({field: lo}), cls({field: hi})


def test_laser_bias_offsets_are_limited_in_number():
    from lidar_sim_ros.core.config import MAX_LASERS
    cls = get_effect_class('laser_bias')
    cls({'offsets_m': [0.0] * MAX_LASERS})
    with pytest.raises(ValidationError, match='at most 1024'):
        cls({'offsets_m': [0.0] * (MAX_LASERS + 1)})


def test_range_walk_bound_is_named_on_the_command_line():
    from lidar_sim_ros.core.config import ConfigError
    from lidar_sim_ros.core.effects import effect_from_spec
    with pytest.raises(ConfigError, match=r'range_walk.k_m" = .-1e6.: Input should be greater '
                                          r'than or equal to -2'):
        effect_from_spec('range_walk={k_m: -1e6}')


class _FarBias(Effect):
    """A user effect with no bounds of its own: shifts every range by ``shift_m``."""

    name = 'far_bias_test'

    def __init__(self, shift_m):
        super().__init__()
        self.shift_m = shift_m

    def range_bias_m(self, ctx):
        return np.full(len(ctx), self.shift_m)


@pytest.mark.parametrize('returns', [{}, {'returns': {'max_returns': 2, 'mode': 'all'}}])
def test_no_published_range_lies_outside_the_gate_whatever_the_effects(returns):
    """The detector gates the true range; the gate now holds for the published (measured)
    range too, after bias, noise and every effect, for the single- and multi-return
    receiver. A plate at 20 m, gate [5, 50] m: +40 m and -17 m publish nothing, +10 m all."""
    s = sensor(min_range_m=5.0, max_range_m=50.0, **returns)
    pose = StaticPose((20.0, 0.0, 0.0), FACING)
    counts = {}
    for shift in (0.0, 10.0, 40.0, -17.0):
        frame = Simulator(s, materials(), plate_target(6.0), seed=1,
                          effects=[_FarBias(shift)]).simulate_frame(0.0, pose, 0)
        counts[shift] = len(frame.range_m)
        if len(frame.range_m):
            assert frame.range_m.min() >= 5.0 and frame.range_m.max() <= 50.0
            assert np.allclose(frame.range_m, np.linalg.norm(frame.xyz_m, axis=1))
    assert counts[0.0] == counts[10.0] == 8 and counts[40.0] == counts[-17.0] == 0
