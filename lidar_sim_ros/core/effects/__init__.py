"""Physical effects beyond the paper's baseline model: a registry by name.

``get_effect_class('range_walk')`` finds a catalogue effect; ``'pkg.module:Class'``
or ``'path/to/file.py:Class'`` loads a user-defined one. Fitting effects to
measurements lives above the pipeline, in ``lidar_sim_ros.compare.model.fit``.
"""
from __future__ import annotations

import importlib
from pathlib import Path

from lidar_sim_ros.core.effects.base import Effect, ExtraReturns, NoParams, ReturnContext
from lidar_sim_ros.user_code import load_source_file

REGISTRY: dict[str, type[Effect]] = {}

# Catalogue modules register themselves on import. ``catalogue()`` lists the effects the
# comparison diagnoses on any recording; those that need more than the recording's points
# and poses (``sunlight`` needs its sun direction, see compare/diagnose/sunlight.py) load by name only.
_CATALOGUE = ('range_walk', 'incidence_angle', 'snr_noise', 'solar_background',
              'beam_divergence', 'time_offset', 'laser_bias', 'multipath', 'laser_pointing')
# range_scale is a test a user asks for (--effect range_scale): a bias linear in range also
# fits smooth spatial patterns on a target whose range follows its azimuth or elevation
# (docs/compare.md, "Range scale"), so it is no default candidate. range_scale and
# range_drift are weighed against a named effect (compare: Diagnosis.weigh_rivals: on an
# approach a walk in ln P follows the range as a scale does) and against the reference
# pose when its per-cloud correction passes (Diagnosis.weigh_pose_rivals): a range error
# of the sensor moves clouds along the line of sight as a pose error does.
# surface_offset (the target's surfaces off its mesh: a scale slip, blankets standing
# proud) is no sensor effect; it is weighed against a named effect the same way
# (Diagnosis.weigh_rivals): a surface moved along its normal reads as incidence.
_BY_NAME_ONLY = ('sunlight', 'range_scale', 'range_drift', 'surface_offset')


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available by its ``name``."""
    if not cls.name:
        raise ValueError(f'{cls.__name__} has no name')
    REGISTRY[cls.name] = cls
    return cls


def _load_catalogue() -> None:
    for mod in _CATALOGUE + _BY_NAME_ONLY:
        try:
            importlib.import_module(f'lidar_sim_ros.core.effects.{mod}')
        except ModuleNotFoundError as exc:
            if exc.name != f'lidar_sim_ros.core.effects.{mod}':
                raise


def builtin_names() -> tuple[str, ...]:
    """The names of the effects this package ships: the catalogue and those by name only."""
    return _CATALOGUE + _BY_NAME_ONLY


def builtin_classes() -> dict[str, type[Effect]]:
    """The package's own effects by name (nothing outside ``builtin_names`` is resolved)."""
    _load_catalogue()
    return {name: REGISTRY[name] for name in builtin_names() if name in REGISTRY}


def is_plugin_spec(spec: str) -> bool:
    """True for anything but the name of an effect this package ships: resolving it may run
    user code (``module:Class``, ``path/a=b/file.py:Class``, any unknown string). An
    allow-list, not a pattern: no spelling of a path passes for a catalogue name."""
    return spec not in builtin_names()


def get_effect_class(spec: str) -> type[Effect]:
    """Resolve a catalogue name, ``module:Class`` or ``file.py:Class`` to an Effect class."""
    _load_catalogue()
    if spec in REGISTRY:
        return REGISTRY[spec]
    if ':' not in spec:
        raise KeyError(f'unknown effect {spec!r}; catalogue: {sorted(REGISTRY)}; '
                       'or give module:Class / path.py:Class')
    where, cls_name = spec.rsplit(':', 1)
    if where.endswith('.py') or Path(where).is_file():
        path = Path(where).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f'effect file not found: {path}')
        if path.suffix != '.py':
            # spec_from_file_location has no loader for other files ('NoneType' object...).
            raise TypeError(f'{spec}: an effect file is Python source ending in .py, '
                            f'not {path.name!r}')
        path = path.resolve()
        module = load_source_file(path, 'user_effect_')
        load_spec = f'{path}:{cls_name}'
    else:
        module = importlib.import_module(where)
        load_spec = spec
    cls = getattr(module, cls_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise TypeError(f'{spec}: {cls_name} is not an Effect subclass')
    if not cls.__module__.startswith(__name__ + '.'):
        cls.load_spec = load_spec
    return cls


def parse_effect_spec(spec: str) -> tuple[str, dict]:
    """``NAME`` / ``module:Class`` / ``file.py:Class``, optionally ``=`` a YAML mapping.

    ``'range_walk={k_m: 0.02}'`` -> ``('range_walk', {'k_m': 0.02})``.
    """
    import yaml
    name, sep, text = spec.partition('=')
    if not sep:
        return spec, {}
    try:
        params = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f'--effect {spec!r}: parameters are not valid YAML: {exc}') from None
    if not isinstance(params, dict):
        raise ValueError(f'--effect {spec!r}: parameters must be a mapping, e.g. '
                         f'{name}={{k_m: 0.02}}')
    return name, params


def effect_from_spec(spec: str) -> Effect:
    """An effect from a command-line ``--effect`` spec; errors name the spec, key and value."""
    from pydantic import ValidationError

    from lidar_sim_ros.core.config import ConfigError
    name, params = parse_effect_spec(spec)
    try:
        cls = get_effect_class(name)
    except (KeyError, TypeError, ImportError, AttributeError) as exc:
        raise ConfigError('--effect', spec, name, exc.args[0] if exc.args else str(exc)) from None
    try:
        return cls(params)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = '.'.join(str(p) for p in err['loc'])
        raise ConfigError('--effect', f'{name}.{key}', err.get('input'),
                          f'{err["msg"]} (effect {name!r})') from None


def make_effect(spec: str, params: dict | None = None) -> Effect:
    """An effect instance from a catalogue name / ``module:Class`` / ``file.py:Class``."""
    return get_effect_class(spec)(params)


def catalogue() -> dict[str, type[Effect]]:
    _load_catalogue()
    return {k: REGISTRY[k] for k in _CATALOGUE if k in REGISTRY}


__all__ = ['Effect', 'ExtraReturns', 'NoParams', 'ReturnContext', 'REGISTRY', 'register', 'get_effect_class',
           'builtin_classes', 'builtin_names', 'is_plugin_spec',
           'make_effect', 'parse_effect_spec', 'effect_from_spec', 'catalogue']
