"""CAMPAIGN.yaml: a base scenario, dispersions, a number of runs and a duration.

Every distribution is a mapping with a ``dist`` key; a quantity that is not listed
under ``dispersions`` keeps the base scenario's value. A bad spec raises
:class:`~lidar_sim_ros.core.config.ConfigError` naming the file, the key path and the
value (``campaign.yaml: key "dispersions.tumble_rate_dps.sigma" = -1.0: ...``).
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_serializer, model_validator

from lidar_sim_ros.campaign.criteria import MAX_CRITERIA, parse_criterion
from lidar_sim_ros.campaign.statistics import stat_names
from lidar_sim_ros.core.config import (ConfigError, MaterialsConfig, MeshMaterials, SensorConfig,
                                       check_file_kind, load_materials, load_sensor, parse,
                                       read_yaml, resolve)
from lidar_sim_ros.core.geometry import MeshFileError, MeshMaterialError, read_target_mesh
from lidar_sim_ros.core.scenario import Scenario, load_scenario


class _Model(BaseModel):
    model_config = ConfigDict(extra='forbid', frozen=True, allow_inf_nan=False)


# -------------------------------------------------------------- scalar laws
class Uniform(_Model):
    """Uniform on [low, high]."""

    dist: Literal['uniform']
    low: float
    high: float

    @model_validator(mode='after')
    def _order(self):
        if not self.high > self.low:
            raise ValueError(f'high ({self.high:g}) must exceed low ({self.low:g})')
        return self

    def support(self) -> tuple[float, float]:
        return self.low, self.high

    def sample(self, rng: np.random.Generator) -> float:
        return float(rng.uniform(self.low, self.high))


class Normal(_Model):
    """Gaussian N(mean, sigma^2), truncated to [low, high] when either bound is given."""

    dist: Literal['normal']
    mean: float
    sigma: Annotated[float, Field(gt=0.0)]
    low: float | None = None
    high: float | None = None

    @model_validator(mode='after')
    def _order(self):
        lo, hi = self.support()
        if not hi > lo:
            raise ValueError(f'high ({hi:g}) must exceed low ({lo:g})')
        if not lo <= self.mean <= hi:
            raise ValueError(f'mean {self.mean:g} lies outside [low, high] = [{lo:g}, {hi:g}]')
        return self

    def support(self) -> tuple[float, float]:
        return (-math.inf if self.low is None else self.low,
                math.inf if self.high is None else self.high)

    def sample(self, rng: np.random.Generator) -> float:
        if self.low is None and self.high is None:
            return float(rng.normal(self.mean, self.sigma))
        from scipy.stats import truncnorm
        lo, hi = self.support()
        a, b = (lo - self.mean) / self.sigma, (hi - self.mean) / self.sigma
        return float(truncnorm.rvs(a, b, loc=self.mean, scale=self.sigma, random_state=rng))


class Choice(_Model):
    """One of ``values``, each equally likely."""

    dist: Literal['choice']
    values: list[float] = Field(min_length=1)

    def support(self) -> tuple[float, float]:
        return min(self.values), max(self.values)

    def sample(self, rng: np.random.Generator) -> float:
        return float(self.values[int(rng.integers(len(self.values)))])


Scalar = Annotated[Union[Uniform, Normal, Choice], Field(discriminator='dist')]


# ------------------------------------------------------------ attitude laws
class UniformAttitude(_Model):
    """Any attitude, uniformly distributed over the rotation group (Haar measure)."""

    dist: Literal['uniform_attitude']

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """A unit quaternion (x, y, z, w)."""
        from scipy.spatial.transform import Rotation
        return Rotation.random(random_state=rng).as_quat()


class SmallRotation(_Model):
    """A rotation vector with independent N(0, sigma_deg^2) components (lidar frame)."""

    dist: Literal['small_rotation']
    sigma_deg: Annotated[float, Field(gt=0.0, le=45.0)]

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        from scipy.spatial.transform import Rotation
        return Rotation.from_rotvec(rng.normal(0.0, np.radians(self.sigma_deg), 3)).as_quat()


Attitude = Annotated[Union[UniformAttitude, SmallRotation], Field(discriminator='dist')]


# ----------------------------------------------------------- direction laws
class UniformSphere(_Model):
    """A direction uniformly distributed on the unit sphere."""

    dist: Literal['uniform_sphere']

    def sample(self, rng: np.random.Generator, nominal: np.ndarray) -> np.ndarray:
        v = rng.standard_normal(3)
        return v / np.linalg.norm(v)


class Cone(_Model):
    """A direction uniform on the spherical cap of ``half_angle_deg`` around ``axis``
    (default: the base scenario's direction)."""

    dist: Literal['cone']
    half_angle_deg: Annotated[float, Field(gt=0.0, le=180.0)]
    axis: tuple[float, float, float] | None = None

    @model_validator(mode='after')
    def _nonzero(self):
        if self.axis is not None and float(np.linalg.norm(self.axis)) == 0.0:
            raise ValueError('axis must be non-zero')
        return self

    def sample(self, rng: np.random.Generator, nominal: np.ndarray) -> np.ndarray:
        from scipy.spatial.transform import Rotation
        axis = np.asarray(self.axis if self.axis is not None else nominal, dtype=float)
        axis = axis / np.linalg.norm(axis)
        # Uniform on the cap: cos(theta) uniform in [cos(half angle), 1].
        cos_t = rng.uniform(math.cos(math.radians(self.half_angle_deg)), 1.0)
        phi = rng.uniform(0.0, 2.0 * math.pi)
        sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
        local = np.array([sin_t * math.cos(phi), sin_t * math.sin(phi), cos_t])
        to_axis, _ = Rotation.align_vectors(axis[None], np.array([[0.0, 0.0, 1.0]]))
        return to_axis.apply(local)


Direction = Annotated[Union[UniformSphere, Cone], Field(discriminator='dist')]


# --------------------------------------------------------------- the spec
class LoopCase(_Model):
    """Closed-loop runs (campaign/loop_case.py): each run is ``loop.step.run_loop`` on the
    loop config, its lidar the (dispersed) base scenario; see docs/campaign.md."""

    config: str = Field(description='loop YAML (config/loop.yaml), relative to the campaign file')
    cloud: Literal['model', 'truth'] = Field('model', description='the cloud the tracker gets')
    config_sha256: str = Field('', description='filled at load (the loop file\'s bytes, so that '
                                               'resuming checks them); leave out')


class MaterialDispersion(_Model):
    """Per-material range error (paper Table 2): bias (m) and 1-sigma noise (m)."""

    bias_m: Scalar | None = None
    sigma_m: Scalar | None = None


class TargetChoice(_Model):
    """A target a run may observe instead of the base scenario's: its mesh, its materials
    file and the map from the mesh's names to them (paths relative to the campaign file)."""

    mesh: str
    materials: str
    mesh_materials: MeshMaterials = None


class Dispersions(_Model):
    """What varies from run to run; omitted keys keep the base scenario's values."""

    sensor: list[str] | None = Field(
        None, min_length=1, description='sensor YAML files, one drawn per run (equally likely; '
                                        'the manifest column param.sensor_choice is its index)')
    target: list[TargetChoice] | None = Field(
        None, min_length=1, description='targets, one drawn per run (equally likely; '
                                        'param.target_choice is its index)')

    initial_distance_m: Scalar | None = Field(
        None, description='distance to the target at t = 0 along the base line of sight (m)')
    initial_attitude: Attitude | None = Field(
        None, description='uniform_attitude replaces the base attitude; small_rotation '
                          'perturbs it (applied in the lidar frame)')
    tumble_axis: Direction | None = None
    tumble_rate_dps: Scalar | None = None
    approach_speed_mps: Scalar | None = None
    mounting_misalignment: Attitude | None = Field(
        None, description='rotation M of the sensor mount: the pose in the lidar frame '
                          'becomes p_lidar = M (R p_body + t)')
    materials: dict[str, MaterialDispersion] = Field(default_factory=dict)
    effects: dict[str, dict[str, Scalar]] = Field(
        default_factory=dict, description='effect name -> parameter -> law; an effect that '
                                          'the base scenario lacks is added')

    @model_serializer(mode='wrap')
    def _without_no_choice(self, handler):
        # Without sensor or target choices a spec dumps as before they existed: the
        # fingerprints of campaigns written then stay the same, and they resume.
        data = handler(self)
        if isinstance(data, dict):
            for key in ('sensor', 'target'):
                if data.get(key) is None:
                    data.pop(key, None)
        return data


MAX_SERIES = 1000
"""Runs whose time series a campaign keeps (``series.worst`` and ``series.runs`` each)."""

# What a closed-loop run measures (runs/run_NNNNN/loop.json "metrics": ``loop.metrics.loop_metrics``
# and ``loop.step.score``'s additions), the names criteria and ``series.by`` may use;
# test_campaign_loop checks that a run has each.
LOOP_METRIC_NAMES = ('hold_error_m', 'delta_v_mps', 'min_range_m', 'est_trans_rms_m',
                     'est_axis_rms_deg', 'acquired_at_s', 'losses', 'hold_samples', 'final_error_m',
                     'estimates', 'periods', 'truth_captures', 'holds_reached')


class SeriesSpec(_Model):
    """Which closed-loop runs keep their time series (DIR/series/run_NNNNN.npz): the
    ``worst`` runs by the metric ``by`` (its highest values, or its lowest with
    ``worst_is: low``), and the ``runs`` named by id, whatever their metrics."""

    worst: Annotated[int, Field(ge=0, le=MAX_SERIES)] = 0
    by: str = Field('', description='a metric (LOOP_METRIC_NAMES); required with worst > 0')
    worst_is: Literal['high', 'low'] = 'high'
    runs: list[Annotated[int, Field(ge=0)]] = Field(default_factory=list, max_length=MAX_SERIES)


MAX_RUNS = 10_000_000
"""Runs in one campaign (the client keeps one byte per run id, and a bounded few in flight)."""
MAX_DURATION_S = 86_400.0
"""Simulated time per run (s): a day of frames."""


class CampaignSpec(_Model):
    """CAMPAIGN.yaml."""

    scenario: str = Field(description='base scenario YAML, relative to the campaign file')
    seed: Annotated[int, Field(ge=0)]
    runs: Annotated[int, Field(ge=1, le=MAX_RUNS)]
    duration_s: Annotated[float, Field(gt=0.0, le=MAX_DURATION_S)] = Field(
        description='simulated time per run (s)')
    save: Literal['stats', 'bags'] = 'stats'
    storage: Literal['mcap', 'sqlite3'] = 'mcap'
    coverage_frames: Annotated[int, Field(ge=0, le=1000)] = Field(
        3, description='frames per run on which target coverage is evaluated (evenly spaced)')
    dispersions: Dispersions = Dispersions()
    loop: LoopCase | None = Field(None, description='closed-loop runs instead of frame statistics')
    criteria: list[str] = Field(default_factory=list, max_length=MAX_CRITERIA,
                                description='pass/fail per run: "METRIC OP THRESHOLD" (criteria.py)')
    series: SeriesSpec | None = Field(None, description='closed-loop runs whose time series are kept')

    @model_serializer(mode='wrap')
    def _without_unset_additions(self, handler):
        # A spec that uses none of ``loop``, ``criteria``, ``series`` dumps as before they
        # existed: the manifest's fingerprint of campaigns written then stays the same,
        # and they resume.
        data = handler(self)
        if isinstance(data, dict):
            for key in ('loop', 'series'):
                if data.get(key) is None:
                    data.pop(key, None)
            if data.get('criteria') == []:
                data.pop('criteria')
        return data


@dataclass(frozen=True)
class LoadedTarget:
    """A target choice, loaded: mesh path, its materials (as the file has them, before a
    sensor's own range error) and the mesh's names map."""

    mesh_path: Path
    materials: MaterialsConfig
    mesh_materials: str | dict[str, str] | None


class Campaign:
    """A loaded campaign: its spec, the base scenario and the file it came from; with
    sensor or target choices, the choices loaded (``sensors``, ``targets``)."""

    def __init__(self, spec: CampaignSpec, scenario: Scenario, source: Path,
                 sensors: list[SensorConfig] | None = None,
                 targets: list[LoadedTarget] | None = None,
                 base_materials: MaterialsConfig | None = None):
        self.spec, self.scenario, self.source = spec, scenario, source
        self.sensors, self.targets = sensors, targets
        # The base scenario's materials as its file has them (before the sensor's range error).
        self.base_materials = base_materials or scenario.materials

    @property
    def frames_per_run(self) -> int:
        """Frames simulated per run: duration times frame rate, at least one."""
        return self.frames_for(self.scenario.sensor)

    def frames_for(self, sensor: SensorConfig) -> int:
        """Frames of one run with ``sensor``: duration times its frame rate, at least one."""
        return max(1, int(round(self.spec.duration_s * sensor.frame_rate_hz)))

    @property
    def material_names(self) -> list[str]:
        """Every material a run may report, the base scenario's first (manifest columns)."""
        names = list(self.scenario.materials.names)
        for target in self.targets or []:
            names += [n for n in target.materials.names if n not in names]
        return names


def load_campaign(path: str | Path) -> Campaign:
    """Load CAMPAIGN.yaml and its base scenario; check every dispersion against it."""
    path = Path(path)
    data = read_yaml(path, mapping=True)
    check_file_kind(data, 'campaign spec', path)
    try:
        spec = parse(CampaignSpec, data, path)
    except ConfigError as exc:
        raise ConfigError(exc.file, _without_tags(data, exc.key), exc.value, exc.reason) from None
    scenario_path = Path(spec.scenario).expanduser()
    if not scenario_path.is_absolute():
        scenario_path = path.resolve().parent / scenario_path
    if not scenario_path.is_file():
        raise ConfigError(path, 'scenario', spec.scenario, f'file not found at {scenario_path}')
    scenario = load_scenario(scenario_path)
    _check_supports(spec.dispersions, path)
    sensors, targets = _load_choices(spec.dispersions, path)
    _check_materials(spec.dispersions, scenario, path, targets)
    _check_effects(spec.dispersions, path)
    if spec.loop is not None:
        if sensors or targets:
            raise ConfigError(path, 'dispersions.sensor' if sensors else 'dispersions.target',
                              None, 'a closed-loop campaign takes its sensor and target from '
                                    'the loop config; drop the choice')
        spec = check_loop_spec(spec, path)
    _check_outcomes(spec, scenario, path)
    base_materials = None
    if sensors or targets:
        base_materials = load_materials(resolve(scenario.config.materials, scenario_path.resolve().parent))
    return Campaign(spec, scenario, path.resolve(), sensors, targets, base_materials)


def _load_choices(disp: Dispersions, path: Path) -> tuple[list | None, list | None]:
    """The sensor and target choices loaded; a missing file or a bad map names its key."""
    base = path.resolve().parent
    sensors = None
    if disp.sensor:
        sensors = []
        for i, name in enumerate(disp.sensor):
            file = resolve(name, base)
            if not file.is_file():
                raise ConfigError(path, f'dispersions.sensor.{i}', name, f'file not found at {file}')
            sensors.append(load_sensor(file))
    targets = None
    if disp.target:
        targets = []
        for i, choice in enumerate(disp.target):
            mesh, materials_file = resolve(choice.mesh, base), resolve(choice.materials, base)
            for key, file, given in (('mesh', mesh, choice.mesh),
                                     ('materials', materials_file, choice.materials)):
                if not file.is_file():
                    raise ConfigError(path, f'dispersions.target.{i}.{key}', given,
                                      f'file not found at {file}')
            materials = load_materials(materials_file)
            mapping = choice.mesh_materials
            values = [mapping] if isinstance(mapping, str) else list((mapping or {}).values())
            for value in values:
                if value not in materials.names:
                    raise ConfigError(path, f'dispersions.target.{i}.mesh_materials', value,
                                      f'not a material of {choice.materials} (known: {materials.names})')
            try:    # read now: a bad mesh failed every run that drew it, hours in
                read_target_mesh(mesh, materials.names, mapping)
            except (MeshFileError, MeshMaterialError) as exc:
                raise ConfigError(path, f'dispersions.target.{i}.mesh', choice.mesh, str(exc)) from None
            targets.append(LoadedTarget(mesh, materials, mapping))
    return sensors, targets


def metric_names(spec: CampaignSpec, scenario: Scenario) -> tuple[str, ...]:
    """The metrics a run of this campaign has, which criteria and ``series.by`` may name:
    a closed-loop run's (loop.json), or a frame run's statistics (manifest ``stat.*``)."""
    if spec.loop is not None:
        return LOOP_METRIC_NAMES
    return tuple(stat_names(scenario.materials.names))


def _check_outcomes(spec: CampaignSpec, scenario: Scenario, path: Path) -> None:
    """Criteria and kept series name real metrics and runs (ConfigError: file, key, value)."""
    if spec.loop is None and spec.series is not None:
        raise ConfigError(path, 'series', spec.series.model_dump(), 'time series are kept for '
                          'closed-loop campaigns (a loop: section); a frame campaign keeps its '
                          'frames with save: bags')
    names = metric_names(spec, scenario)
    for i, text in enumerate(spec.criteria):
        try:
            parse_criterion(text, names)
        except ValueError as exc:
            raise ConfigError(path, f'criteria.{i}', text, str(exc)) from None
    series = spec.series
    if series is None:
        return
    if (series.worst or series.by) and series.by not in names:
        raise ConfigError(path, 'series.by', series.by, f'worst: {series.worst} ranks runs by a metric: '
                          f'one of {", ".join(names)}')
    for i, run in enumerate(series.runs):
        if run >= spec.runs:
            raise ConfigError(path, f'series.runs.{i}', run, f'not a run of this campaign '
                              f'(runs 0..{spec.runs - 1})')


# ---------------------------------------------------------- closed loop
# Dispersions of the frame-statistics scenario that mean nothing in the loop.
_NOT_IN_LOOP = {'approach_speed_mps': 'the approach is the guidance\'s (loop config guidance.*)'}


def loop_config_path(campaign_file: Path, spec: CampaignSpec) -> Path:
    return resolve(spec.loop.config, Path(campaign_file).resolve().parent)


def check_loop_spec(spec: CampaignSpec, path: Path) -> CampaignSpec:
    """The spec with its loop file checked (ConfigError naming the file, key and value) and
    its bytes' sha256 filled in, so that the manifest's fingerprint covers the loop."""
    from lidar_sim_ros.loop.config import load_loop_config
    if spec.loop.config_sha256:
        raise ConfigError(path, 'loop.config_sha256', spec.loop.config_sha256,
                          'is filled when the campaign loads; leave it out')
    for key, why in _NOT_IN_LOOP.items():
        if getattr(spec.dispersions, key) is not None:
            raise ConfigError(path, f'dispersions.{key}', getattr(spec.dispersions, key).model_dump(
                exclude_none=True), f'not used by a closed-loop campaign: {why}')
    if spec.save != 'stats':
        raise ConfigError(path, 'save', spec.save, 'a closed-loop campaign writes runs/run_NNNNN/loop.json, '
                          'not bags: leave save out (or stats)')
    loop_path = loop_config_path(path, spec)
    if not loop_path.is_file():
        raise ConfigError(path, 'loop.config', spec.loop.config, f'file not found at {loop_path}')
    config, _ = load_loop_config(loop_path)
    period = config.control_period_s
    if abs(spec.duration_s / period - round(spec.duration_s / period)) > 1e-9:
        raise ConfigError(path, 'duration_s', spec.duration_s,
                          f'must be a whole number of control periods ({period:g} s, {loop_path.name})')
    digest = hashlib.sha256(loop_path.read_bytes()).hexdigest()
    return spec.model_copy(update={'loop': spec.loop.model_copy(update={'config_sha256': digest})})


def _check_supports(disp: Dispersions, path: Path) -> None:
    """Laws that can draw impossible values fail at load, not in run 4711."""
    distance = disp.initial_distance_m
    if distance is not None and distance.support()[0] <= 0.0:
        raise ConfigError(path, 'dispersions.initial_distance_m', distance.model_dump(exclude_none=True),
                          'can draw a distance <= 0 m; bound it above zero (uniform low, normal low)')
    for name, mat in disp.materials.items():
        if mat.sigma_m is not None and mat.sigma_m.support()[0] < 0.0:
            raise ConfigError(path, f'dispersions.materials.{name}.sigma_m',
                              mat.sigma_m.model_dump(exclude_none=True),
                              'can draw a negative sigma; bound it at or above zero')


def _check_materials(disp: Dispersions, scenario: Scenario, path: Path,
                     targets: list[LoadedTarget] | None = None) -> None:
    """A dispersed material must be one of the base scenario's, or of every target choice's."""
    pools = [t.materials.names for t in targets] if targets else [scenario.materials.names]
    for name in disp.materials:
        missing = [names for names in pools if name not in names]
        if missing:
            where = 'the base scenario' if not targets else 'every target choice'
            raise ConfigError(path, f'dispersions.materials.{name}', name,
                              f'not a material of {where} (known: {missing[0]})')


def _check_effects(disp: Dispersions, path: Path) -> None:
    """Each effect must resolve, each parameter exist and accept both ends of its law."""
    from lidar_sim_ros.core.effects import get_effect_class
    for name, laws in disp.effects.items():
        try:
            cls = get_effect_class(name)
        except (KeyError, ImportError, FileNotFoundError, TypeError, AttributeError) as exc:
            raise ConfigError(path, f'dispersions.effects.{name}', name,
                              exc.args[0] if exc.args else str(exc)) from None
        for param, law in laws.items():
            key = f'dispersions.effects.{name}.{param}'
            if param not in cls.Params.model_fields:
                raise ConfigError(path, key, law.model_dump(exclude_none=True),
                                  f'effect {name!r} has no parameter {param!r} '
                                  f'(it has {sorted(cls.Params.model_fields)})')
            for end in law.support():
                if not math.isfinite(end):
                    continue
                try:
                    cls({param: end})
                except ValidationError as exc:
                    raise ConfigError(path, key, end, f'reachable value rejected by effect '
                                      f'{name!r}: {exc.errors()[0]["msg"]}') from None


def _without_tags(data, key: str) -> str:
    """Drop the ``dist`` tags pydantic puts in error paths (``x.normal.sigma`` -> ``x.sigma``):
    a segment that is not a key of the YAML mapping but is its ``dist`` value."""
    kept = []
    for part in key.split('.'):
        if isinstance(data, dict) and part not in data and data.get('dist') == part:
            continue
        kept.append(part)
        data = data.get(part) if isinstance(data, dict) else None
    return '.'.join(kept)
