"""The effect protocol: one class per physical effect, used by simulator and comparison.

An effect changes what the paper's baseline model predicts through a small set of
hooks, each a pure function over per-shot arrays. The simulator calls the forward
hooks; ``lidar-sim compare`` uses the same hooks to predict and ``fit`` to estimate
the parameters from measured-minus-predicted residuals.

Write your own::

    from pydantic import BaseModel
    from lidar_sim_ros.core.effects import Effect

    class DriftInFrame(Effect):
        name = 'drift_in_frame'

        class Params(BaseModel):
            rate_m_per_s: float = 0.0

        def range_bias_m(self, ctx):
            return self.params.rate_m_per_s * ctx.t_s

Every hook has a neutral default, so an effect overrides only what it changes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict


@dataclass(frozen=True)
class ReturnContext:
    """What the model knows about each shot after raycast and reflection.

    range_m: true range (m); incidence_rad; material: id (-1 = miss);
    power_w: received power (W); intensity: power / saturation (-);
    t_s: time since frame start (s); az_rad, el_rad: pointing; laser: id;
    divergence_rad: full beam divergence; hit: bool mask.
    """

    range_m: np.ndarray
    incidence_rad: np.ndarray
    material: np.ndarray
    power_w: np.ndarray
    intensity: np.ndarray
    t_s: np.ndarray
    az_rad: np.ndarray
    el_rad: np.ndarray
    laser: np.ndarray
    divergence_rad: float
    hit: np.ndarray
    threshold_power_w: float = 0.0
    max_range_m: float = 300.0

    def __len__(self) -> int:
        return len(self.range_m)

    def subset(self, mask: np.ndarray) -> 'ReturnContext':
        fields = {k: (v[mask] if isinstance(v, np.ndarray) and v.shape[:1] == self.range_m.shape[:1] else v)
                  for k, v in self.__dict__.items()}
        return ReturnContext(**fields)


class NoParams(BaseModel):
    model_config = ConfigDict(extra='forbid')


class Effect:
    """Base class of all effects. Subclasses set ``name`` and a pydantic ``Params``."""

    name: ClassVar[str] = ''
    Params: ClassVar[type[BaseModel]] = NoParams

    def __init__(self, params: BaseModel | dict[str, Any] | None = None):
        if isinstance(params, BaseModel):
            params = params.model_dump()
        self.params = self.Params.model_validate(params or {})

    def __repr__(self) -> str:
        return f'{type(self).__name__}({self.params.model_dump()})'

    # ---- forward hooks (neutral defaults) -------------------------------------
    def pose_time_s(self, t_s: np.ndarray) -> np.ndarray:
        """Times (s, absolute) at which the target pose is evaluated for each shot."""
        return t_s

    def cast(self, target, directions_lidar: np.ndarray, poses, divergence_rad: float):
        """Replace the single-ray raycast (e.g. sample the beam footprint). None = default."""
        return None

    def power_scale(self, ctx: ReturnContext) -> np.ndarray | float:
        """Multiplier on received power (-)."""
        return 1.0

    def range_bias_m(self, ctx: ReturnContext) -> np.ndarray | float:
        """Extra range bias (m), added to the material bias."""
        return 0.0

    def range_sigma_m(self, ctx: ReturnContext) -> np.ndarray | float:
        """Extra range noise (m, 1 sigma), added in quadrature to the material sigma."""
        return 0.0

    def false_returns(self, ctx: ReturnContext, rng: np.random.Generator):
        """Spurious returns: (mask over shots, range_m) replacing those shots' returns, or None."""
        return None
