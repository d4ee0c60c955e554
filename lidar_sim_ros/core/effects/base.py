"""The effect protocol: one class per physical effect, used by simulator and comparison.

An effect changes what the paper's baseline model predicts through a small set of
hooks, each a pure function over per-shot arrays. The simulator calls the forward
hooks; ``lidar-sim compare`` uses the same hooks to predict, and estimates the
parameters by maximum likelihood from the measured ranges (``compare/model/fit.py``). An
effect never imports that machinery: it declares what a fit needs (``bounds``,
``initial``, ``linear_bias``, ``fit_options``, ``power_driven``) and the fit reads it.

Write your own (``examples/drift_effect.py``)::

    from pydantic import BaseModel
    from lidar_sim_ros.core.effects import Effect

    class DriftInFrame(Effect):
        name = 'drift_in_frame'
        bounds = {'rate_m_per_s': (-5.0, 5.0)}   # free parameters and their search box
        initial = {'rate_m_per_s': 0.0}

        class Params(BaseModel):
            rate_m_per_s: float = 0.0

        def range_bias_m(self, ctx):
            return self.params.rate_m_per_s * ctx.t_s

Every hook has a neutral default, so an effect overrides only what it changes; a
class that declares ``bounds`` is fitted by the generic bounded maximum-likelihood
fit with no extra code.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, ClassVar, Sequence

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

if TYPE_CHECKING:
    from lidar_sim_ros.core.config import MaterialsConfig, SensorConfig
    from lidar_sim_ros.core.geometry import Target
    from lidar_sim_ros.core.pose import Poses
    from lidar_sim_ros.core.sun import Illumination


@dataclass(frozen=True)
class Scene:
    """The world around a set of shots, for effects that follow light beyond the laser's
    own ray (shadows, background light): the target at each shot's pose, the material
    table, the sensor, and the illumination at each shot's time (None = no sun)."""

    target: 'Target'
    poses: 'Poses'
    materials: 'MaterialsConfig'
    sensor: 'SensorConfig'
    illumination: 'Illumination | None' = None

    def occluded(self, origins_lidar_m: np.ndarray, directions_lidar: np.ndarray,
                 shots: np.ndarray) -> np.ndarray:
        """Shadow rays from lidar-frame origins along unit directions, each against the
        target at the pose of shot ``shots[i]``: True where the ray meets the target."""
        from lidar_sim_ros.core.geometry import occluded_at_poses
        from lidar_sim_ros.core.pose import Poses
        quat, pos = self.poses.quat_xyzw, self.poses.position_m.reshape(-1, 3)
        if len(quat) > 1:
            quat, pos = quat.take(shots, axis=0), pos.take(shots, axis=0)
        return occluded_at_poses(self.target, origins_lidar_m, directions_lidar,
                                 Poses.from_quat(quat, pos))

    def subset(self, mask: np.ndarray) -> 'Scene':
        from lidar_sim_ros.core.pose import Poses
        quat, pos = self.poses.quat_xyzw, self.poses.position_m.reshape(-1, 3)
        if len(quat) > 1:
            quat, pos = quat[mask], pos[mask]
        return replace(self, poses=Poses.from_quat(quat, pos),
                       illumination=None if self.illumination is None else self.illumination.subset(mask))


@dataclass(frozen=True)
class ReturnContext:
    """What the model knows about each shot after raycast and reflection.

    range_m: true range (m); incidence_rad; material: id (-1 = miss);
    power_w: received power (W); intensity: power / saturation (-);
    t_s: time since frame start (s); az_rad, el_rad: pointing; laser: id;
    divergence_rad: full beam divergence; hit: bool mask;
    threshold_power_w: detection threshold (W); min_range_m, max_range_m: range gate;
    direction (N, 3): unit ray directions and normal (N, 3): surface normals toward the
    sensor (zeros on a miss), both in the lidar frame; face: the target triangle hit (-1 on
    a miss); scene: the target, poses, materials, sensor and light (``Scene``). The last
    four are None where the caller has no geometry; time_s: each shot's absolute time
    (s, the recording's or simulation's clock; None where the caller has no clock).
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
    min_range_m: float = 0.0
    direction: np.ndarray | None = None
    normal: np.ndarray | None = None
    face: np.ndarray | None = None
    scene: Scene | None = None
    time_s: np.ndarray | None = None   # absolute time of each shot (s, the recording's clock)

    def __len__(self) -> int:
        return len(self.range_m)

    def subset(self, mask: np.ndarray) -> 'ReturnContext':
        fields = {k: (v[mask] if isinstance(v, np.ndarray) and v.shape[:1] == self.range_m.shape[:1] else v)
                  for k, v in self.__dict__.items()}
        if self.scene is not None:
            fields['scene'] = self.scene.subset(mask)
        return ReturnContext(**fields)


@dataclass(frozen=True)
class ExtraReturns:
    """Returns a shot makes besides its own echo (e.g. a multipath ghost), one row each.

    shot: index of the shot in the context (int); range_m: true range along the shot
    (m); power_w: received power (W); material, face: the surface the light came from
    (its id and triangle); via_material: the surface that redirected it (-1: none);
    source: the effect's name; replaces_echo: these rows are the shot's echo, split (its
    own echo is dropped). The receiver (``core/returns.py``) decides which of a
    shot's returns it reports; the pipeline adds range bias and noise of ``material``.
    """

    shot: np.ndarray
    range_m: np.ndarray
    power_w: np.ndarray
    material: np.ndarray
    face: np.ndarray
    via_material: np.ndarray
    source: str = ''
    replaces_echo: bool = False      # the rows stand for their shots' echo (a split footprint)

    def __len__(self) -> int:
        return len(self.shot)


class NoParams(BaseModel):
    model_config = ConfigDict(extra='forbid')


class Effect:
    """Base class of all effects. Subclasses set ``name`` and a pydantic ``Params``.

    What a fit needs, declared (``lidar_sim_ros.compare.model.fit`` reads it; nothing here
    imports it): ``bounds`` maps each free parameter to its (low, high) search box and
    ``initial`` gives the starting value (default: the Params default); parameters
    not in ``bounds`` stay at their Params values. ``entry_bounds`` maps a parameter
    that holds several values (a dict by name) to the box an effect's own fit searches
    each entry in (the generic fit does not free it; ``fit.at_bounds`` reads it to say
    an entry ended at the box's edge). ``linear_bias`` names free
    parameters the range bias is linear in (estimated in closed form).
    ``fit_options`` tunes the generic 1-D searches (``n_grid``, ``prefer_low``,
    ``smooth``). ``needs_repredict`` marks effects that change the pose time or the
    raycast (``pose_time_s``, ``seen_target``, ``beam_directions``, ``cast``), which the fit must re-run the prediction for. ``power_driven`` marks
    effects whose hooks read the received power (``ctx.power_w``): the comparison
    fits them against the power measured by the sensor (its intensity, calibrated)
    when the recording has intensity; the simulator uses its own power.
    """

    name: ClassVar[str] = ''
    Params: ClassVar[type[BaseModel]] = NoParams
    bounds: ClassVar[dict[str, tuple[float, float]]] = {}
    entry_bounds: ClassVar[dict[str, tuple[float, float]]] = {}
    initial: ClassVar[dict[str, float]] = {}
    linear_bias: ClassVar[tuple[str, ...]] = ()
    fit_options: ClassVar[dict[str, Any]] = {}
    needs_repredict: ClassVar[bool] = False
    power_driven: ClassVar[bool] = False
    # How to load the class again (``module:Class`` / ``file.py:Class``); set by the
    # registry when it loads a user effect, used by ``to_yaml_snippet``.
    load_spec: ClassVar[str | None] = None

    def __init__(self, params: BaseModel | dict[str, Any] | None = None):
        if isinstance(params, BaseModel):
            params = params.model_dump()
        # Finite first: a NaN then says "finite", not "less than or equal to" a bound.
        _check_finite(params or {}, self.Params.__name__)
        self.params = _finite_params(self.Params.model_validate(params or {}))

    def __repr__(self) -> str:
        return f'{type(self).__name__}({self.params.model_dump()})'

    # ---- forward hooks (neutral defaults) -------------------------------------
    def pose_time_s(self, t_s: np.ndarray) -> np.ndarray:
        """Times (s, absolute) at which the target pose is evaluated for each shot."""
        return t_s

    def seen_target(self, target: 'Target') -> 'Target | None':
        """The surface the sensor sees in place of ``target`` (the mesh), e.g. the mesh
        with its faces standing proud; None = the mesh. Every raycast (and ``cast``)
        meets it."""
        return None

    def beam_directions(self, directions_lidar: np.ndarray, laser: np.ndarray) -> np.ndarray | None:
        """The unit directions (N, 3, lidar frame) the beams really leave along, for shots
        configured along ``directions_lidar`` by lasers ``laser`` (a laser's pointing
        error); the raycast follows them, the points stay on the configured directions.
        None = as configured."""
        return None

    def cast(self, target, directions_lidar: np.ndarray, poses, divergence_rad: float):
        """Replace the single-ray raycast (e.g. sample the beam footprint). None = default."""
        return None

    def cast_reach_rad(self, divergence_rad: float) -> float | None:
        """How far (rad) from its axis a ``cast`` override looks: rays farther than this
        from any silhouette or depth step return as with the single-ray cast. None =
        any ray may change (the default; the comparison then re-casts every ray)."""
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
        """Spurious returns: (mask over shots, range_m) replacing those shots' returns, or None.

        A NaN range under the mask removes the shot's return (e.g. a blinded detector)."""
        return None

    def extra_returns(self, ctx: ReturnContext, shots: np.ndarray | None = None) -> ExtraReturns | None:
        """Further returns of some shots behind their echo (``ExtraReturns``), deterministic;
        None = none. ``shots``: indices of the shots whose returns behind the echo the receiver
        can still report (a first-return receiver: those whose echo went undetected); None =
        every shot. Changes frames only where the effect is on."""
        return None

    def outlier_fraction(self, ctx: ReturnContext) -> np.ndarray | float:
        """Probability (-) that a shot's return is a spurious point at a uniform range.

        The likelihood of a measured range r becomes
        (1 - w) N(r; expected, sigma) + w / (range window width).
        """
        return 0.0

    # ---- export -------------------------------------------------------------------
    @classmethod
    def spec(cls) -> str:
        """The name that ``make_effect`` / a scenario's ``effects:`` entry loads this class by."""
        from lidar_sim_ros.core.effects import REGISTRY
        in_catalogue = cls.__module__.startswith('lidar_sim_ros.core.effects.')
        if in_catalogue and REGISTRY.get(cls.name) is cls:
            return cls.name
        if cls.__dict__.get('load_spec'):
            return cls.__dict__['load_spec']
        return f'{cls.__module__}:{cls.__qualname__}'

    def to_yaml_snippet(self) -> str:
        """The scenario ``effects:`` entry for this effect, e.g.
        ``- {name: range_walk, params: {k_m: 0.0213}}``."""
        values = self.params.model_dump()
        defaults = type(self)().params.model_dump()
        # The free parameters always; the others only where they differ from the default.
        params = {k: _round(v) for k, v in values.items()
                  if k in self.bounds or v != defaults.get(k)}
        entry = {'name': self.spec(), 'params': params}
        return '- ' + yaml.safe_dump(entry, default_flow_style=True, sort_keys=False,
                                     width=1000).strip()


def apply_effects(ctx: ReturnContext, effects: Sequence['Effect'], bias_m: np.ndarray,
                  var_m2: np.ndarray) -> tuple[ReturnContext, np.ndarray, np.ndarray]:
    """The effects' power scale, then their extra bias (m) and variance (m^2) on top of
    ``bias_m`` / ``var_m2``: the one place the simulator and the fits combine effects."""
    # Hooks left at their neutral scalar defaults cost no pass over the shots.
    scale = 1.0
    for eff in effects:
        factor = eff.power_scale(ctx)
        if not (np.isscalar(factor) and factor == 1.0):
            scale = scale * np.asarray(factor, float)
    if np.any(scale != 1.0):
        # intensity is power / saturation power: it scales with the power.
        ctx = replace(ctx, power_w=ctx.power_w * scale, intensity=ctx.intensity * scale)
    bias = np.asarray(bias_m, float)
    var = np.asarray(var_m2, float)
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):  # misses carry NaN range
        for eff in effects:
            extra_bias = eff.range_bias_m(ctx)
            if not (np.isscalar(extra_bias) and extra_bias == 0.0):
                bias = bias + extra_bias
            extra_sigma = eff.range_sigma_m(ctx)
            if not (np.isscalar(extra_sigma) and extra_sigma == 0.0):
                var = var + np.asarray(extra_sigma, float) ** 2
    n = len(ctx)
    # broadcast_to only where a scalar stands in for the shots (it costs ~10 us a call).
    return (ctx, bias if bias.shape == (n,) else np.broadcast_to(bias, (n,)),
            var if var.shape == (n,) else np.broadcast_to(var, (n,)))


def _finite_params(params: BaseModel) -> BaseModel:
    """Every number among an effect's parameters must be finite (``range_walk k_m: .nan``
    gave 0 points and rc 0): refused as a pydantic error naming the key and value, which
    the config loaders turn into one line."""
    _check_finite(params.model_dump(), type(params).__name__)
    return params


def _check_finite(values: Any, title: str) -> None:
    """The ValidationError of ``_finite_params`` for the first non-finite number in
    ``values`` (nested dicts and lists), if any."""
    bad = [(key, value) for key, value in _numbers(values) if not np.isfinite(value)]
    if bad:
        key, value = bad[0]
        raise ValidationError.from_exception_data(title, [
            {'type': 'finite_number', 'loc': key, 'input': value}])


def _numbers(value: Any, key: tuple = ()) -> Any:
    """(key path, number) for every float or int inside nested dicts, lists and tuples."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _numbers(v, key + (str(k),))
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            yield from _numbers(v, key + (i,))
    elif isinstance(value, float) or (isinstance(value, np.floating)):
        yield key, float(value)


def _round(value: Any) -> Any:
    """Six significant digits for floats: readable snippets, no false precision."""
    if isinstance(value, float) and np.isfinite(value):
        return float(f'{value:.6g}')
    return value
