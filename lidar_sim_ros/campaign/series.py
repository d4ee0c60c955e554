"""The time series a closed-loop campaign keeps: DIR/series/run_NNNNN.npz.

Which runs (CAMPAIGN.yaml ``series``): the ``worst`` runs by one metric, and the runs
asked for by id (``series.runs``, and any run re-run with ``--run``). Every run's series
comes back to the client with its row; ``SeriesKeeper`` keeps a file for a run only
while it ranks among the worst K seen so far (or was asked for) and deletes the one it
displaces, so the client holds K ranks and the folder K + asked files, whatever the
number of runs. The kept set depends on the runs only, not on the order their results
arrive in (ties broken by run id). A run without a value of the metric (never held, so
no ``hold_error_m``) ranks worst of all.

A file holds the run's series (``loop.step.LoopResult.series``: arrays, one row per
control period) and ``meta``, a JSON text: run id, seed, why it is kept, its metrics.
Resuming rebuilds the ranking from the files (a ``worst`` raised later applies to the
runs from then on).
"""
from __future__ import annotations

import heapq
import json
import math
import os
from pathlib import Path

import numpy as np

from lidar_sim_ros.campaign.spec import SeriesSpec

SERIES_DIR = 'series'


def series_path(out_dir: str | Path, run_id: int) -> Path:
    return Path(out_dir) / SERIES_DIR / f'run_{run_id:05d}.npz'


def write_series(path: Path, series: dict, meta: dict) -> None:
    """One run's series and ``meta`` (JSON), atomically (temporary file + rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {k: np.asarray(v) for k, v in series.items()}
    arrays['meta'] = np.array(json.dumps(meta))
    tmp = path.with_name(path.stem + '.tmp.npz')
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


class SeriesFileError(ValueError):
    """A file in DIR/series that is not a series this campaign wrote: names it."""


def read_series(path: str | Path, arrays: bool = True) -> tuple[dict[str, np.ndarray], dict]:
    """(series, meta) of one file (series empty unless ``arrays``: resuming reads the meta
    only); no pickled objects are loaded. SeriesFileError naming the file when it cannot
    be read, or its meta is not a run id and metrics."""
    try:
        with np.load(path, allow_pickle=False) as data:
            series = {k: data[k] for k in data.files if k != 'meta'} if arrays else {}
            meta = json.loads(str(data['meta']))
    except Exception as exc:  # noqa: BLE001 - numpy, zipfile and json raise many kinds
        raise SeriesFileError(f'{path}: not a series file ({type(exc).__name__}: '
                              f'{str(exc)[:120]}); remove it to resume') from None
    run_id = meta.get('run_id') if isinstance(meta, dict) else None
    if (not isinstance(run_id, int) or isinstance(run_id, bool) or run_id < 0
            or not isinstance(meta.get('metrics'), dict)):
        raise SeriesFileError(f'{path}: its meta is not a run id and metrics: '
                              f'{str(meta)[:120]!r}; remove it to resume')
    return series, meta


class SeriesKeeper:
    """Decides, run by run, which series are kept (``offer``); see the module docstring."""

    def __init__(self, out_dir: str | Path, spec: SeriesSpec | None):
        self.out_dir = Path(out_dir)
        self.spec = spec or SeriesSpec()
        self.asked = set(self.spec.runs)
        self._worst: list[tuple[tuple, int]] = []   # min-heap of (rank, run id): the K worst
        self._ranked: set[int] = set()              # the run ids in _worst
        self._files: set[int] = set()               # run ids kept for an ask (never deleted)

    @classmethod
    def open(cls, out_dir: str | Path, spec: SeriesSpec | None) -> 'SeriesKeeper':
        """The keeper of ``out_dir``, its ranking rebuilt from the files already there."""
        keeper = cls(out_dir, spec)
        folder = keeper.out_dir / SERIES_DIR
        if folder.is_dir():
            for path in sorted(folder.glob('run_*.npz')):
                if path.name.endswith('.tmp.npz'):
                    path.unlink()  # left by a client killed while writing
                    continue
                _, meta = read_series(path, arrays=False)
                run_id = int(meta['run_id'])
                # Ranked, not pruned: a lower ``worst`` deletes the surplus as runs come.
                keeper._place(run_id, meta['metrics'], bool(meta['asked']) or run_id in keeper.asked,
                              prune=False)
        return keeper

    @property
    def kept(self) -> list[int]:
        """Run ids whose series are kept, in order."""
        return sorted(self._files | self._ranked)

    def rank(self, metrics: dict) -> tuple:
        """Larger is worse: (missing?, value, or its negative with ``worst_is: low``)."""
        value = metrics.get(self.spec.by)
        if value is None or not math.isfinite(float(value)):
            return (1, 0.0)
        return (0, float(value) if self.spec.worst_is == 'high' else -float(value))

    def offer(self, row: dict, asked: bool = False) -> bool:
        """A finished run's row (its ``series`` and ``metrics``, which are taken out of
        it): keep its series if it is asked for or ranks among the worst. True if kept."""
        series, metrics = row.pop('series', None), row.pop('metrics', None)
        if series is None or metrics is None or row.get('status') != 'ok':
            return False
        run_id = int(row['run_id'])
        asked = asked or run_id in self.asked
        keep, dropped = self._place(run_id, metrics, asked)
        if keep:
            meta = {'run_id': run_id, 'seed': row.get('seed'), 'asked': asked,
                    'by': self.spec.by, 'worst_is': self.spec.worst_is, 'metrics': _json_safe(metrics)}
            write_series(series_path(self.out_dir, run_id), series, meta)
        for run in dropped:
            series_path(self.out_dir, run).unlink(missing_ok=True)
        return keep

    def _place(self, run_id: int, metrics: dict, asked: bool, prune: bool = True) -> tuple[bool, list[int]]:
        """Rank ``run_id`` in; (whether its series is kept, run ids whose files go: only
        runs that had one, so that a run ranked out at once costs no file system call)."""
        had = run_id in self._ranked or run_id in self._files
        if run_id in self._ranked:  # the same run again (--run, --retry-failed): its new rank
            self._worst = [(r, i) for r, i in self._worst if i != run_id]
            heapq.heapify(self._worst)
            self._ranked.discard(run_id)
        if asked:
            self._files.add(run_id)
        if self.spec.worst and self.spec.by:
            heapq.heappush(self._worst, (self.rank(metrics), run_id))
            self._ranked.add(run_id)
        dropped = []
        while prune and len(self._worst) > self.spec.worst:
            _, run = heapq.heappop(self._worst)
            self._ranked.discard(run)
            dropped.append(run)
        kept = run_id in self._files or run_id in self._ranked
        return kept, [run for run in dropped if run not in self._files and (run != run_id or had)]


def _json_safe(metrics: dict) -> dict:
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()}
