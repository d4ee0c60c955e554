"""A loaded scenario: the scenario file's config with the sensor, materials and mesh it
names, its effects checked against the registry at load (fail at load, not mid-run).

Above ``config`` (the file formats) and ``effects`` (the registry): config imports neither,
so the core's imports flow one way.
"""
from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError

from lidar_sim_ros.core.config import (ConfigError, MaterialsConfig, ScenarioConfig, SensorConfig,
                                       check_file_kind, load_materials, load_sensor,
                                       mesh_materials_from_text, parse, read_yaml, resolve,
                                       with_sensor_range_error)
from lidar_sim_ros.core.effects import get_effect_class


class Scenario:
    """A loaded scenario: its config plus the sensor and materials it names."""

    def __init__(self, config: ScenarioConfig, sensor: SensorConfig,
                 materials: MaterialsConfig, mesh_path: Path, source: Path | None = None):
        self.config, self.sensor, self.materials = config, sensor, materials
        self.mesh_path, self.source = mesh_path, source

    @property
    def seed(self) -> int:
        return self.config.seed

    @property
    def mesh_materials(self) -> str | dict[str, str] | None:
        """The scenario's map from mesh names to config materials (``load_target``)."""
        return self.config.mesh_materials


def load_scenario(path: str | Path, sensor_file: str | Path | None = None,
                  materials_file: str | Path | None = None,
                  mesh_file: str | Path | None = None,
                  mesh_materials: str | None = None) -> Scenario:
    """Load scenario YAML and the sensor/materials/mesh files it references, or the files
    given instead (the node's sensor_file, materials_file and mesh_file parameters, a
    missing one named as key '<parameters>' mesh_file), and the node's mesh_materials
    parameter (YAML text) instead of the scenario's map: a mesh_file of another target
    needs its own. The materials get the sensor's own range error once both are known:
    swapping the sensor after the load (as the node did) simulated a Mid-40 with the P-60's
    Table 2 errors, or the P-60 with the Mid-40's."""
    path = Path(path)
    data = read_yaml(path, mapping=True)
    check_file_kind(data, 'scenario', path)
    cfg = parse(ScenarioConfig, data, path)
    base = path.resolve().parent
    sensor_path = Path(sensor_file).expanduser() if sensor_file else resolve(cfg.sensor, base)
    materials_path = Path(materials_file).expanduser() if materials_file else resolve(cfg.materials, base)
    if mesh_file:
        mesh_path = Path(mesh_file).expanduser()
        if not mesh_path.is_file():
            raise ConfigError('<parameters>', 'mesh_file', str(mesh_file), 'mesh file not found')
    else:
        mesh_path = resolve(cfg.mesh, base)
        if not mesh_path.is_file():
            raise ConfigError(path, 'mesh', cfg.mesh, f'mesh file not found at {mesh_path}')
    _check_effects(cfg, path)
    mapped_in = path
    if mesh_materials:
        mapped_in = '<parameters>'
        cfg = cfg.model_copy(update={'mesh_materials': mesh_materials_from_text(mesh_materials,
                                                                                mapped_in)})
    materials = load_materials(materials_path)
    _check_mesh_materials(cfg, materials, mapped_in, materials_path)
    sensor = load_sensor(sensor_path)
    return Scenario(cfg, sensor, with_sensor_range_error(materials, sensor), mesh_path, path)


def _check_mesh_materials(cfg: ScenarioConfig, materials: MaterialsConfig, source: str | Path,
                          materials_path: Path) -> None:
    """Every material the mesh_materials map (of the scenario file or the node's parameter:
    ``source``) names must be in the materials file."""
    mapping = cfg.mesh_materials
    items = [('mesh_materials', mapping)] if isinstance(mapping, str) else \
        [(f'mesh_materials.{k}', v) for k, v in (mapping or {}).items()]
    for key, value in items:
        if value not in materials.names:
            raise ConfigError(source, key, value, f'not a material of {materials_path.name} '
                                                  f'(known: {materials.names})')


def scenario_effect_spec(spec: str, base: Path | None) -> str:
    """A scenario's ``file.py:Class`` effect resolved against the scenario's folder
    ``base``, and only there: a plugin missing beside the scenario is not looked for in
    the current directory (which would run whatever file of that name sits there).
    Catalogue names, ``module:Class`` and absolute paths are returned as given."""
    where, _, cls_name = spec.rpartition(':')
    if base is None or not where.endswith('.py'):
        return spec
    file = Path(where).expanduser()
    return spec if file.is_absolute() else f'{base / file}:{cls_name}'


def _check_effects(cfg: ScenarioConfig, path: Path) -> None:
    """Every listed effect must resolve and accept its params: fail at load, not mid-run."""
    base = path.resolve().parent
    for i, eff in enumerate(cfg.effects):
        spec = scenario_effect_spec(eff.name, base)
        try:
            cls = get_effect_class(spec)
        except (KeyError, ImportError, FileNotFoundError, TypeError, AttributeError) as exc:
            raise ConfigError(path, f'effects.{i}.name', eff.name,
                              exc.args[0] if exc.args else str(exc)) from None
        try:
            cls(eff.params)
        except ValidationError as exc:
            err = exc.errors()[0]
            key = '.'.join(str(p) for p in err['loc'])
            raise ConfigError(path, f'effects.{i}.params.{key}', err.get('input'),
                              f'{err["msg"]} (effect {eff.name!r})') from None
