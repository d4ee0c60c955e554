"""Shared pieces of the calibrations: input errors, config YAML read/update/write, figures."""
from __future__ import annotations

import copy
import datetime
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import yaml

from lidar_sim_ros.core.config import MaterialsConfig, SensorConfig, parse, read_yaml


class CalibrationInputError(ValueError):
    """Lab data that cannot be calibrated from: names the file and what is wrong where."""


def rms_p95_deg(error_deg: np.ndarray) -> tuple[float, float]:
    """RMS and 95th percentile of per-shot angular errors (deg)."""
    return float(np.sqrt(np.mean(error_deg ** 2))), float(np.percentile(error_deg, 95))


MAX_FIT_RMS_DEG = 2.0
"""Largest RMS angular error (deg) of a scan fit that is written, for every scan type: a
fit of the right pattern leaves the sensor's noise and the model's own error (the risley
first-order model's on a real Mid-40 below ~1 deg; a Lissajous fit of a P-60 recording
~0.01 deg); prisms beyond the risley search fitted aliases at 9.6 deg, and a Lissajous
recording whose points are not the pattern (shuffled directions) 18.5 deg."""


def check_fit_rms(error_deg: np.ndarray, source: str, fitted: str, hint: str) -> None:
    """Stop (CalibrationInputError naming ``source``, what was ``fitted`` and the error)
    when a scan fit leaves more than MAX_FIT_RMS_DEG RMS: its sensor file is not written."""
    rms = rms_p95_deg(error_deg)[0]
    if not rms <= MAX_FIT_RMS_DEG:
        raise CalibrationInputError(
            f'{source}: {fitted} leaves an angular error of RMS {rms:.3g} deg, more than '
            f'{MAX_FIT_RMS_DEG:g} deg: {hint}; no sensor file written')


class AngularErrorSummary:
    """A scan fit's per-shot angular error (``error_deg``, deg) summed up: RMS and p95;
    ``prior_error_deg`` (deg or None): the same with the input sensor config."""

    error_deg: np.ndarray
    prior_error_deg: np.ndarray | None

    @property
    def rms_deg(self) -> float:
        return rms_p95_deg(self.error_deg)[0]

    @property
    def p95_deg(self) -> float:
        return rms_p95_deg(self.error_deg)[1]

    def error_lines(self, per: str, fitted: str, prior: str) -> list[str]:
        """The summary's lines on the error per ``per`` (shot, point): the fitted one
        (``fitted`` in brackets) and, with a prior, the input config's (``prior`` after it)."""
        lines = [f'angular error per {per} ({fitted}): RMS {self.rms_deg:.3g} deg, '
                 f'p95 {self.p95_deg:.3g} deg, max {self.error_deg.max():.3g} deg']
        if self.prior_error_deg is not None:
            rms, p95 = rms_p95_deg(self.prior_error_deg)
            lines.append(f'angular error per {per} with the input sensor config{prior}: RMS '
                         f'{rms:.3g} deg, p95 {p95:.3g} deg')
        return lines


class _Flow(dict):
    """A mapping written on one line (``{name: PIF, kd: 0.45, ...}``), like the shipped configs."""


class _Dumper(yaml.SafeDumper):
    pass


_Dumper.add_representer(_Flow, lambda dumper, data: dumper.represent_mapping(
    'tag:yaml.org,2002:map', data.items(), flow_style=True))


def sig(value: float, digits: int = 6) -> float:
    """A float rounded to ``digits`` significant digits, so the YAML stays readable."""
    return float(f'{float(value):.{digits}g}')


def write_config_yaml(path: str | Path, data: dict[str, Any], header: Iterable[str]) -> Path:
    """Write a config dict with a provenance comment; list entries of mappings go one per line."""
    path = Path(path)
    body = copy.deepcopy(data)
    for key, value in body.items():
        if isinstance(value, list) and all(isinstance(v, dict) for v in value):
            body[key] = [_Flow(v) for v in value]
    if isinstance(body.get('scan'), dict) and isinstance(body['scan'].get('lasers'), list):
        body['scan']['lasers'] = [_Flow(v) for v in body['scan']['lasers']]
    stamp = datetime.datetime.now().astimezone().strftime('%Y-%m-%d %H:%M %Z')
    lines = [f'# {line}' if line else '#' for line in header]
    lines.append(f'# written {stamp}')
    text = '\n'.join(lines) + '\n' + yaml.dump(body, Dumper=_Dumper, sort_keys=False,
                                                  width=200, default_flow_style=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def load_materials_document(path: str | Path) -> dict[str, Any]:
    """The materials YAML as a plain dict, validated against the config model."""
    data = read_yaml(path)
    parse(MaterialsConfig, data, path)
    return data


def update_materials(document: dict[str, Any], updates: dict[str, dict[str, float]],
                     source: str | Path, template: str | None = None
                     ) -> tuple[dict[str, Any], list[str]]:
    """Copy of a materials document with ``updates[name][field] = value`` applied.

    Unknown material names are appended; the fields not being calibrated are taken
    from ``template`` (default: the first material) and a warning says so. Values
    are written as given: round them (``sig``) before.
    Returns the new document and the warnings.
    """
    doc = copy.deepcopy(document)
    entries = doc['materials']
    by_name = {m['name']: m for m in entries}
    if template is None:
        template = entries[0]['name']
    if template not in by_name:
        raise CalibrationInputError(f'{source}: template material {template!r} not found '
                                    f'(known: {sorted(by_name)})')
    warnings = []
    for name, fields in updates.items():
        if name not in by_name:
            entry = {k: v for k, v in by_name[template].items()}
            entry['name'] = name
            kept = sorted(set(entry) - set(fields) - {'name'})
            warnings.append(f'material {name!r} is new in {source}: added with {", ".join(kept)} '
                            f'copied from template {template!r}; calibrate those too')
            entries.append(entry)
            by_name[name] = entry
        by_name[name].update({k: float(v) for k, v in fields.items()})
    return doc, warnings


def write_materials(path: str | Path, document: dict[str, Any], header: Iterable[str]) -> Path:
    """Validate and write a materials YAML (the config/materials.yaml format)."""
    parse(MaterialsConfig, document, path)
    return write_config_yaml(path, document, header)


def write_sensor(path: str | Path, document: dict[str, Any], header: Iterable[str]) -> Path:
    """Validate and write a sensor YAML (the config/cepton_vista_p60.yaml format)."""
    parse(SensorConfig, document, path)
    return write_config_yaml(path, document, header)


def new_figure(nrows: int, ncols: int, size_in: tuple[float, float]):
    """A matplotlib figure on the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(nrows, ncols, figsize=size_in, squeeze=False)
    return fig, axes


def save_figure(fig, path: str | Path) -> Path:
    import matplotlib.pyplot as plt
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def format_table(header: list[str], rows: list[list[str]]) -> str:
    """A plain fixed-width text table."""
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
    fmt = '  '.join(f'{{:>{w}}}' for w in widths)
    return '\n'.join([fmt.format(*header), fmt.format(*('-' * w for w in widths))]
                     + [fmt.format(*map(str, r)) for r in rows])
