"""DIR/manifest.csv: one row per finished run, appended as runs finish.

Columns: ``run_id``, ``seed``, ``status`` (ok | failed), ``error``, the dispersed
parameters ``param.<name>``, the statistics ``stat.<name>``, then bookkeeping that is
not a result of the run (``compute_s`` / ``cpu_s``: the run's wall / CPU time on its
worker, ``worker``: host:pid). Floats are written with ``repr`` (shortest round-trip text), so a value
read back equals the one computed, bit for bit.

A row is appended (and flushed) the moment its run finishes, so a campaign killed
mid-way keeps every finished run; a half-written last line is dropped on reopening.
``DIR/campaign.json`` fingerprints the campaign (spec, base scenario, sensor,
materials, mesh bytes; not ``runs``, so a campaign can be extended): resuming into a
directory of a different campaign is refused rather than mixing results.
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import os
from pathlib import Path
from lidar_sim_ros.campaign.sample import param_names
from lidar_sim_ros.campaign.spec import Campaign
from lidar_sim_ros.campaign.statistics import stat_names

MANIFEST = 'manifest.csv'
FINGERPRINT = 'campaign.json'
HEAD = ['run_id', 'seed', 'status', 'error']
TAIL = ['compute_s', 'cpu_s', 'worker']


def columns(campaign: Campaign) -> list[str]:
    """The manifest's columns for ``campaign``."""
    return (HEAD + [f'param.{p}' for p in param_names(campaign)]
            + [f'stat.{s}' for s in stat_names(campaign.scenario.materials.names)] + TAIL)


def format_value(value) -> str:
    """Text of one cell: ints as ints, floats by repr ('nan' for NaN), None as ''."""
    if value is None:
        return ''
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float) or hasattr(value, 'dtype'):
        value = float(value)
        return 'nan' if math.isnan(value) else repr(value)
    return str(value)


def fingerprint(campaign: Campaign) -> str:
    """sha256 over everything that decides a run's result, except the number of runs."""
    h = hashlib.sha256()
    scenario = campaign.scenario
    h.update(campaign.spec.model_dump_json(exclude={'runs'}).encode())
    for model in (scenario.config, scenario.sensor, scenario.materials):
        h.update(model.model_dump_json().encode())
    h.update(Path(scenario.mesh_path).read_bytes())
    return h.hexdigest()


class Manifest:
    """The rows of DIR/manifest.csv by run id; ``append`` writes one through to disk."""

    def __init__(self, out_dir: str | Path, header: list[str]):
        self.dir = Path(out_dir)
        self.path = self.dir / MANIFEST
        self.header = list(header)
        self.rows: dict[int, dict[str, str]] = {}

    @classmethod
    def open(cls, out_dir: str | Path, campaign: Campaign) -> 'Manifest':
        """Open (or create) the manifest of ``campaign`` in ``out_dir``; refuse another campaign's."""
        out = Path(out_dir)
        if out.exists() and not out.is_dir():
            raise NotADirectoryError(f'{out} exists and is not a directory')
        out.mkdir(parents=True, exist_ok=True)
        stamp = {'fingerprint': fingerprint(campaign), 'campaign': str(campaign.source)}
        stamp_path = out / FINGERPRINT
        if stamp_path.is_file():
            old = json.loads(stamp_path.read_text())
            if old.get('fingerprint') != stamp['fingerprint']:
                raise ValueError(
                    f'{out} holds results of a different campaign ({old.get("campaign")}: its spec, '
                    f'scenario, sensor, materials or mesh differ); choose another --out')
        else:
            stamp_path.write_text(json.dumps(stamp, indent=2) + '\n')
        manifest = cls(out, columns(campaign))
        if manifest.path.is_file():
            manifest._load()
        manifest.rewrite()  # drops a half-written last line, restores run order
        return manifest

    def _load(self) -> None:
        with self.path.open(newline='') as fh:
            reader = csv.DictReader(fh)
            if reader.fieldnames != self.header:
                raise ValueError(f'{self.path}: columns differ from this campaign\'s; '
                                 'choose another --out')
            for row in reader:
                if None in row.values() or None in row or row['status'] not in ('ok', 'failed'):
                    continue  # the line a killed campaign was writing
                self.rows[int(row['run_id'])] = row

    def finished(self, retry_failed: bool = False) -> set[int]:
        """Run ids to skip: ok runs, and failed ones unless ``retry_failed``."""
        return {i for i, r in self.rows.items() if r['status'] == 'ok' or not retry_failed}

    def count(self, status: str) -> int:
        return sum(r['status'] == status for r in self.rows.values())

    def text_row(self, row: dict) -> dict[str, str]:
        return {k: format_value(row.get(k)) for k in self.header}

    def append(self, row: dict) -> None:
        """Record a finished run: appended and flushed at once (a later rewrite sorts)."""
        text = self.text_row(row)
        self.rows[int(text['run_id'])] = text
        new = not self.path.is_file()
        with self.path.open('a', newline='') as fh:
            writer = csv.DictWriter(fh, fieldnames=self.header)
            if new:
                writer.writeheader()
            writer.writerow(text)
            fh.flush()

    def rewrite(self) -> None:
        """Write every row, sorted by run id, atomically (temporary file + rename)."""
        tmp = self.path.with_suffix('.csv.tmp')
        with tmp.open('w', newline='') as fh:
            writer = csv.DictWriter(fh, fieldnames=self.header)
            writer.writeheader()
            for run_id in sorted(self.rows):
                writer.writerow(self.rows[run_id])
        os.replace(tmp, self.path)

    def write_parquet(self) -> Path | None:
        """A Parquet copy beside the CSV when pyarrow is installed (it is optional)."""
        try:
            from pyarrow import csv as pa_csv, parquet
        except ImportError:
            return None
        path = self.path.with_suffix('.parquet')
        parquet.write_table(pa_csv.read_csv(self.path), path)
        return path
