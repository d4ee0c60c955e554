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
import re
from array import array
from pathlib import Path
from typing import Iterator

import numpy as np

from lidar_sim_ros.campaign.run import param_names, run_one
from lidar_sim_ros.campaign.series import SeriesKeeper
from lidar_sim_ros.campaign.spec import MAX_RUNS, Campaign
from lidar_sim_ros.campaign.statistics import COUNTS, stat_names

MANIFEST = 'manifest.csv'
FINGERPRINT = 'campaign.json'
HEAD = ['run_id', 'seed', 'status', 'error']
TAIL = ['compute_s', 'cpu_s', 'worker']


def columns(campaign: Campaign) -> list[str]:
    """The manifest's columns for ``campaign``."""
    return (HEAD + [f'param.{p}' for p in param_names(campaign)]
            + [f'stat.{s}' for s in stat_names(campaign.material_names)] + TAIL)


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
    """sha256 over everything that decides a run's result: not the number of runs, nor
    what is made of the results (``criteria``, which runs keep their ``series``)."""
    h = hashlib.sha256()
    scenario = campaign.scenario
    h.update(campaign.spec.model_dump_json(exclude={'runs', 'criteria', 'series'}).encode())
    for model in (scenario.config, scenario.sensor, scenario.materials):
        h.update(model.model_dump_json().encode())
    h.update(Path(scenario.mesh_path).read_bytes())
    for sensor in campaign.sensors or []:           # the choices' contents, not only their names
        h.update(sensor.model_dump_json().encode())
    for target in campaign.targets or []:
        h.update(target.materials.model_dump_json().encode())
        h.update(Path(target.mesh_path).read_bytes())
    return h.hexdigest()


_STATUS = {'ok': 1, 'failed': 2}
_STATUS_NAME = {1: 'ok', 2: 'failed'}
_RUN_ID = re.compile(r'[0-9]{1,8}')  # ASCII digits: str.isdigit() takes '²', which int() refuses


class ManifestError(ValueError):
    """A manifest line that no campaign writes (an edited or foreign file): named with its
    file, line and value, rather than read as something else."""


def parse_run_id(text: str, path: Path, line: int) -> int:
    """The run id of a manifest row: ASCII digits below ``spec.MAX_RUNS``.

    The client keeps one status byte per run id up to the largest one, so an id is bounded
    before it is used (run_id 1e9 took 1.26 GB; 30 digits overflowed the offset index)."""
    if _RUN_ID.fullmatch(text) is None or int(text) >= MAX_RUNS:
        raise ManifestError(f'{path}: line {line}: run_id {text[:40]!r} is not a run id '
                            f'(0..{MAX_RUNS - 1}, ASCII digits); this manifest was not written by '
                            'lidar-sim campaign as it is: fix or remove that line, or choose another --out')
    return int(text)


class Manifest:
    """DIR/manifest.csv: ``append`` writes one row through to disk.

    Memory stays flat in the number of runs: only one status byte per run id is kept
    (the rows live in the file); ``rewrite`` sorts the file by run id through an index
    of byte offsets, and ``row`` reads one row back."""

    def __init__(self, out_dir: str | Path, header: list[str]):
        self.dir = Path(out_dir)
        self.path = self.dir / MANIFEST
        self.header = list(header)
        self._status = bytearray()          # per run id: 0 = no row, 1 = ok, 2 = failed
        self._counts = {'ok': 0, 'failed': 0}

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
        manifest.rewrite()  # drops a half-written last line, restores run order, reads statuses
        return manifest

    # ------------------------------------------------------------- reading
    def _scan(self) -> Iterator[tuple[int, list[str], int, int]]:
        """Every complete row of the file with its run id and byte span [start, end); the
        header is checked. A row cut short (a killed campaign's last line) is skipped; a
        complete row whose run id is not one raises ``ManifestError`` (file, line, value)."""
        if not self.path.is_file():
            return
        with self.path.open('rb') as fh:
            end, newline = [0], [True]

            def lines():
                for raw in fh:
                    end[0] += len(raw)
                    newline[0] = raw.endswith(b'\n')
                    yield raw.decode('utf-8', errors='replace')
            reader = csv.reader(lines())
            header = next(reader, None)
            if header is None:
                return
            if header != self.header:
                raise ValueError(f'{self.path}: columns differ from this campaign\'s; '
                                 'choose another --out')
            start, n, i_status = end[0], len(self.header), self.header.index('status')
            for row in reader:
                stop = end[0]
                if len(row) == n and row[i_status] in _STATUS and newline[0]:
                    yield parse_run_id(row[0], self.path, reader.line_num), row, start, stop
                start = stop

    def row(self, run_id: int) -> dict[str, str] | None:
        """The manifest's row of ``run_id`` as text (the last one written), or None."""
        found = None
        for found_id, row, _, _ in self._scan():
            if found_id == run_id:
                found = dict(zip(self.header, row))
        return found

    def status(self, run_id: int) -> str | None:
        return _STATUS_NAME.get(self._status[run_id]) if run_id < len(self._status) else None

    def is_finished(self, run_id: int, retry_failed: bool = False) -> bool:
        """Skip this run: it is ok, or failed and failures are not retried."""
        status = self.status(run_id)
        return status == 'ok' or (status == 'failed' and not retry_failed)

    def finished(self, retry_failed: bool = False) -> set[int]:
        """Run ids to skip: ok runs, and failed ones unless ``retry_failed``."""
        return {i for i in range(len(self._status)) if self.is_finished(i, retry_failed)}

    def count(self, status: str) -> int:
        return self._counts[status]

    def _set_status(self, run_id: int, status: str) -> None:
        if run_id >= len(self._status):
            self._status.extend(bytes(run_id + 1 - len(self._status)))
        old = _STATUS_NAME.get(self._status[run_id])
        if old:
            self._counts[old] -= 1
        self._status[run_id] = _STATUS[status]
        self._counts[status] += 1

    # ------------------------------------------------------------- writing
    def text_row(self, row: dict) -> dict[str, str]:
        # One physical line per row (an error message may hold newlines): rewrite and
        # resume read the file line by line.
        return {k: ' '.join(format_value(row.get(k)).splitlines()) for k in self.header}

    def append(self, row: dict) -> None:
        """Record a finished run: appended and flushed at once (a later rewrite sorts)."""
        self.append_rows([row])

    def append_rows(self, rows: list[dict]) -> None:
        """Record finished runs (a batch's): appended in one write and flushed at once."""
        texts = [self.text_row(row) for row in rows]
        new = not self.path.is_file()
        with self.path.open('a', newline='') as fh:
            writer = csv.DictWriter(fh, fieldnames=self.header)
            if new:
                writer.writeheader()
            writer.writerows(texts)
            fh.flush()
        for text in texts:
            self._set_status(int(text['run_id']), text['status'])

    def replace(self, row: dict) -> None:
        """Record a run again (``--run``): its new row replaces the old one."""
        self.append(row)
        self.rewrite()

    def rewrite(self) -> None:
        """Sort the rows by run id, the last row of a run id winning, atomically
        (temporary file + rename); reads every status. Holds byte offsets, not rows."""
        ids, starts, stops = array('q'), array('q'), array('q')
        for run_id, _, start, stop in self._scan():
            ids.append(run_id)
            starts.append(start)
            stops.append(stop)
        self._status, self._counts = bytearray(), {'ok': 0, 'failed': 0}
        ids_np = np.frombuffer(ids, np.int64) if len(ids) else np.zeros(0, np.int64)
        # Stable sort by run id; the last of equal ids is the latest row.
        order = np.argsort(ids_np, kind='stable')
        last = np.ones(len(order), bool)
        last[:-1] = ids_np[order][1:] != ids_np[order][:-1]
        keep = order[last]
        tmp = self.path.with_suffix('.csv.tmp')
        with tmp.open('w', newline='') as out:
            csv.writer(out).writerow(self.header)
        if len(keep):
            with self.path.open('rb') as src, tmp.open('ab') as out:
                for k in keep:
                    src.seek(starts[k])
                    line = src.read(stops[k] - starts[k])
                    out.write(line)
        os.replace(tmp, self.path)
        if len(keep):
            i_status = self.header.index('status')
            for run_id, row, _, _ in self._scan():
                self._set_status(run_id, row[i_status])

    def write_parquet(self) -> Path | None:
        """A Parquet copy beside the CSV when pyarrow is installed (it is optional),
        converted block by block (memory flat in the number of runs)."""
        try:
            import pyarrow as pa
            from pyarrow import csv as pa_csv, parquet
        except ImportError:
            return None
        path = self.path.with_suffix('.parquet')
        try:
            with pa_csv.open_csv(self.path, convert_options=pa_csv.ConvertOptions(
                    column_types=self._arrow_types(pa))) as reader:
                with parquet.ParquetWriter(path, reader.schema) as writer:
                    for batch in reader:
                        writer.write_batch(batch)
        except pa.ArrowInvalid:     # a column that is not what its name says: infer it all
            parquet.write_table(pa_csv.read_csv(self.path), path)
        return path

    def _arrow_types(self, pa) -> dict:
        counts = {f'stat.{c}' for c in COUNTS} | {'stat.coverage_frames'}
        types = {}
        for name in self.header:
            if name in ('run_id', 'seed') or name in counts or name.startswith('stat.points.'):
                types[name] = pa.int64()
            elif name in ('status', 'error', 'worker'):
                types[name] = pa.string()
            else:
                types[name] = pa.float64()
        return types


def rerun(campaign: Campaign, out_dir: str | Path, run_id: int) -> tuple[dict, dict | None]:
    """Run one case again in this process; its manifest row is replaced (and a closed-loop
    run's time series kept, as asked for by id).

    Returns the new row and the one the manifest held (None if none), both as manifest
    text, so that equal statistics compare equal character for character.
    """
    if not 0 <= run_id < campaign.spec.runs:
        raise ValueError(f'--run {run_id}: the campaign has runs 0..{campaign.spec.runs - 1}')
    manifest = Manifest.open(out_dir, campaign)
    old = manifest.row(run_id)
    row = run_one(campaign, run_id, out_dir)
    if campaign.spec.loop is not None:  # its series: asked for by id (DIR/series/run_NNNNN.npz)
        SeriesKeeper.open(out_dir, campaign.spec.series).offer(row, asked=True)
    row = manifest.text_row(row)
    manifest.replace(row)
    return row, old
