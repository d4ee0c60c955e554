"""A user-defined effect: a range bias that drifts linearly with time within each frame.

The smallest class that works both in the simulator and in ``lidar-sim compare``:

* in a scenario:  ``effects: [{name: 'examples/drift_effect.py:DriftInFrame',
  params: {rate_m_per_s: 0.4}}]``
* in the comparison:  ``lidar-sim compare BAG --mesh OBJ
  --effect examples/drift_effect.py:DriftInFrame --fit --out DIR``

Physics (a made-up but plausible one): the time-of-flight counter's reference
oscillator warms up after every frame sync, so the range scale drifts through
the frame; over 0.1 s that is a linear drift of the bias with the shot time
t since frame start:

    bias = rate_m_per_s * t_s

Nothing else is needed: ``Params`` holds the parameter with a neutral default,
``range_bias_m`` is the forward model (vectorised over shots via
``ctx.t_s``), and ``bounds`` makes the generic bounded maximum-likelihood fit
estimate ``rate_m_per_s`` with no fitting code. The per-material bias offsets
that every fit re-estimates absorb the drift's mean, so only its slope counts.
"""
from __future__ import annotations

from pydantic import BaseModel

from lidar_sim_ros.core.effects import Effect


class DriftInFrame(Effect):
    """Range bias rate_m_per_s * (time since frame start)."""

    name = 'drift_in_frame'
    bounds = {'rate_m_per_s': (-5.0, 5.0)}     # the fit searches this box (m/s)

    class Params(BaseModel):
        rate_m_per_s: float = 0.0              # bias drift rate (m/s); 0 = no effect

    def range_bias_m(self, ctx):
        return self.params.rate_m_per_s * ctx.t_s
