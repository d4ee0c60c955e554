"""What a campaign's runs add up to: tables, pass/fail verdicts and figures.

A frame campaign with ``criteria`` gets ``criteria.csv`` and ``vs_dispersions.png`` from
its manifest (``summarize_frames``); a closed-loop campaign gets the rest below.

``summarize(out_dir, campaign)`` reads DIR/manifest.csv (which runs are ok, which failed)
and each ok run's runs/run_NNNNN/loop.json, one at a time, and writes into DIR:

- ``loop_runs.csv``: one row per ok run: id, seed, dispersed parameters, metrics, and
  ``pass`` (1/0: every criterion met; empty without criteria);
- ``loop_summary.csv``: per metric, the runs with a value and without, mean, min,
  5th / 50th / 95th percentile, max;
- ``loop_criteria.csv`` (with criteria): per criterion and for all of them together,
  runs, passed, failed, of those missing the metric, and the pass rate. A failed run
  (status ``failed``) counts as a run that passes nothing;
- ``loop_summary.png``: each metric's histogram, and delta-v against the closest approach;
- ``loop_vs_dispersions.png``: each headline metric (rows) against each dispersed
  parameter (columns; quaternion components left out: ``misalignment_deg`` is the
  mount's angle), runs that pass every criterion blue, the others red, each criterion a
  dashed line in its metric's row;
- ``loop_series.png``: the kept runs' time series (``series.py``) against time.

Memory: the metrics and parameters of the ok runs as float arrays (8 bytes each: 2.6 MB
per 10,000 runs of 33 numbers), never the runs' dicts.
"""
from __future__ import annotations

import csv
import math
from array import array
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar_sim_ros.campaign.criteria import Criterion, parse_criterion
from lidar_sim_ros.campaign.loop_case import LOOP_METRICS, read_result
from lidar_sim_ros.campaign.series import SERIES_DIR, read_series
from lidar_sim_ros.campaign.spec import LOOP_METRIC_NAMES, Campaign
from lidar_sim_ros.campaign.statistics import stat_names

RUNS_TABLE = 'loop_runs.csv'
SUMMARY_TABLE = 'loop_summary.csv'
CRITERIA_TABLE = 'loop_criteria.csv'
FIGURE = 'loop_summary.png'
SERIES_FIGURE = 'loop_series.png'
VS_FIGURE = 'loop_vs_dispersions.png'
FRAME_CRITERIA_TABLE = 'criteria.csv'
FRAME_VS_FIGURE = 'vs_dispersions.png'
FRAME_PLOTTED = ('points', 'range_error_mean_m', 'range_error_std_m', 'coverage')
PERCENTILES = (5, 50, 95)
ALL = 'all criteria'


@dataclass(frozen=True)
class LoopSummary:
    runs_table: Path
    summary_table: Path
    figure: Path | None
    runs: int                       # ok runs with a loop.json
    table: list[dict]               # loop_summary.csv's rows
    failed: int = 0                 # runs recorded failed in the manifest
    criteria_table: Path | None = None
    verdicts: tuple = ()            # loop_criteria.csv's rows (the last: all criteria)
    figures: tuple = ()             # every figure written


@dataclass
class _Columns:
    """Float columns grown run by run (NaN: no value)."""

    names: list[str]
    data: dict

    @classmethod
    def of(cls, names: list[str]) -> '_Columns':
        return cls(list(names), {n: array('d') for n in names})

    def add(self, values: dict) -> None:
        for n in self.names:
            self.data[n].append(_float(values.get(n)))

    def __getitem__(self, name: str) -> np.ndarray:
        # A copy: a view would pin the array's buffer, and the next add() would raise.
        return np.array(self.data[name], dtype=float)


def summarize(out_dir: str | Path, campaign: Campaign | None = None, figure: bool = True) -> LoopSummary:
    """Write DIR's tables and figures (module docstring); ``campaign`` gives the criteria."""
    out = Path(out_dir)
    criteria = [parse_criterion(text, LOOP_METRIC_NAMES) for text in campaign.spec.criteria] \
        if campaign is not None else []
    ok_ids, failed = _statuses(out)
    first = next((r for r in map(lambda i: read_result(out, i), ok_ids) if r is not None), None)
    params = list(first['params']) if first else []
    metric_names = list(LOOP_METRICS) + [k for k in (first['metrics'] if first else {})
                                         if k not in LOOP_METRICS]
    metrics, dispersions = _Columns.of(metric_names), _Columns.of(params)
    runs_path = out / RUNS_TABLE
    with runs_path.open('w', newline='') as fh:
        writer = csv.writer(fh)
        writer.writerow(['run_id', 'seed'] + [f'param.{p}' for p in params] + metric_names + ['pass'])
        for run_id in ok_ids:
            r = read_result(out, run_id)
            if r is None:  # ok in the manifest, its loop.json gone: counted as failing below
                continue
            passed = all(bool(c.passes([_float(r['metrics'].get(c.metric))])[0]) for c in criteria)
            writer.writerow([r['run_id'], r['seed']] + [_text(r['params'].get(p)) for p in params]
                            + [_text(r['metrics'].get(m)) for m in metric_names]
                            + [int(passed) if criteria else ''])
            metrics.add(r['metrics'])
            dispersions.add(r['params'])
    n_ok = len(metrics[metric_names[0]]) if metric_names else 0
    table = [metric_row(m, metrics[m]) for m in LOOP_METRICS]
    summary_path = out / SUMMARY_TABLE
    _write_csv(summary_path, table)
    verdicts, passes = verdict_rows(criteria, metrics, n_ok, len(ok_ids) + failed)
    criteria_path = None
    if criteria:
        criteria_path = out / CRITERIA_TABLE
        _write_csv(criteria_path, verdicts)
    figures = []
    if figure and n_ok:
        figures.append(_histograms(out / FIGURE, metrics, n_ok))
        figures.append(_vs_dispersions(out / VS_FIGURE, list(LOOP_METRICS), metrics, dispersions, passes,
                                       criteria))
    kept = sorted((out / SERIES_DIR).glob('run_*.npz')) if figure else []
    kept = [p for p in kept if not p.name.endswith('.tmp.npz')]
    if kept:
        figures.append(_series_figure(out / SERIES_FIGURE, kept))
    return LoopSummary(runs_path, summary_path, figures[0] if figures and n_ok else None, n_ok, table,
                       failed, criteria_path, tuple(verdicts), tuple(figures))


@dataclass(frozen=True)
class FrameSummary:
    criteria_table: Path
    figure: Path | None
    runs: int                       # ok runs
    failed: int
    verdicts: tuple                 # criteria.csv's rows (the last: all criteria)


def summarize_frames(out_dir: str | Path, campaign: Campaign, figure: bool = True) -> FrameSummary:
    """A frame campaign's verdicts (its ``criteria`` over the manifest's ``stat.*``):
    ``criteria.csv`` as ``loop_criteria.csv``, and ``vs_dispersions.png``: the criteria's
    metrics and ``FRAME_PLOTTED`` against each dispersion. Reads the manifest row by row;
    holds the plotted columns as float arrays."""
    out = Path(out_dir)
    names = stat_names(campaign.scenario.materials.names)
    criteria = [parse_criterion(text, names) for text in campaign.spec.criteria]
    plotted = list(dict.fromkeys([c.metric for c in criteria] + list(FRAME_PLOTTED)))
    metrics, dispersions, failed = _Columns.of(plotted), None, 0
    with (out / 'manifest.csv').open(newline='') as fh:
        reader = csv.DictReader(fh)
        params = [k[len('param.'):] for k in reader.fieldnames or [] if k.startswith('param.')]
        dispersions = _Columns.of(params)
        for row in reader:  # one row per run: the engine rewrites the manifest at the end
            if row['status'] != 'ok':
                failed += 1
                continue
            metrics.add({m: _cell(row.get(f'stat.{m}')) for m in plotted})
            dispersions.add({p: _cell(row.get(f'param.{p}')) for p in params})
    n_ok = len(metrics[plotted[0]])
    verdicts, passes = verdict_rows(criteria, metrics, n_ok, n_ok + failed)
    criteria_path = out / FRAME_CRITERIA_TABLE
    _write_csv(criteria_path, verdicts)
    fig = _vs_dispersions(out / FRAME_VS_FIGURE, plotted, metrics, dispersions, passes, criteria) \
        if figure and n_ok else None
    return FrameSummary(criteria_path, fig, n_ok, failed, tuple(verdicts))


def _cell(text: str | None) -> float:
    return math.nan if text in (None, '') else float(text)


def _statuses(out: Path) -> tuple[list[int], int]:
    """The ok run ids (sorted) and the number of failed runs of DIR/manifest.csv (last row wins)."""
    status: dict[int, str] = {}
    with (out / 'manifest.csv').open(newline='') as fh:
        for r in csv.DictReader(fh):
            status[int(r['run_id'])] = r.get('status')
    return sorted(i for i, s in status.items() if s == 'ok'), sum(s == 'failed' for s in status.values())


def verdict_rows(criteria: list[Criterion], metrics: _Columns, n_ok: int,
                 n_runs: int) -> tuple[list[dict], np.ndarray]:
    """Per criterion and for all together: runs, passed, failed, missing, pass_rate; and the
    per-ok-run bool of passing all (all True without criteria). ``n_runs`` counts the failed
    runs and ok runs without a result too: they pass nothing."""
    rows, every = [], np.ones(n_ok, bool)
    for c in criteria:
        values = metrics[c.metric]
        ok = c.passes(values)
        every &= ok
        rows.append(_verdict(str(c), int(ok.sum()), n_runs, int(np.count_nonzero(~np.isfinite(values)))))
    if criteria:
        rows.append(_verdict(ALL, int(every.sum()), n_runs, None))
    return rows, every


def _verdict(name: str, passed: int, runs: int, missing: int | None) -> dict:
    return {'criterion': name, 'runs': runs, 'passed': passed, 'failed': runs - passed,
            'missing': '' if missing is None else missing,
            'pass_rate': passed / runs if runs else None}


def metric_row(name: str, values) -> dict:
    """One line of the percentile table: a value that is None (never acquired) or NaN (no
    hold dwell) is left out of the statistics and counted as ``missing``."""
    x = np.array([np.nan if v is None else float(v) for v in values], float)
    n = len(x)
    x = x[np.isfinite(x)]
    row: dict = {'metric': name, 'runs': int(len(x)), 'missing': int(n - len(x))}
    if len(x):
        row.update(mean=float(x.mean()), min=float(x.min()),
                   **{f'p{p}': float(np.percentile(x, p)) for p in PERCENTILES}, max=float(x.max()))
    else:
        row.update(mean=None, min=None, **{f'p{p}': None for p in PERCENTILES}, max=None)
    return row


def plotted_dispersions(names: list[str]) -> list[str]:
    """The dispersed parameters a metric is plotted against: not quaternion components."""
    return [n for n in names if '_quat_' not in n]


# ------------------------------------------------------------------ helpers
def _float(value) -> float:
    return math.nan if value is None else float(value)


def _text(value) -> str:
    if value is None:
        return ''
    if isinstance(value, float):
        return 'nan' if math.isnan(value) else repr(value)
    return str(value)


def _write_csv(path: Path, rows: list[dict]) -> None:
    with path.open('w', newline='') as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows({k: _text(v) for k, v in row.items()} for row in rows)


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _histograms(path: Path, metrics: _Columns, n: int) -> Path:
    plt = _pyplot()
    fig, axes = plt.subplots(2, 4, figsize=(14, 6.5))
    for ax, name in zip(axes.flat, LOOP_METRICS):
        x = metrics[name]
        ok = x[np.isfinite(x)]
        if len(ok):
            ax.hist(ok, bins=min(30, max(5, len(ok) // 3)), color='tab:blue', alpha=0.8)
            for p, style in zip(PERCENTILES, (':', '-', ':')):
                ax.axvline(np.percentile(ok, p), color='k', ls=style, lw=1)
        ax.set_title(f'{name} ({len(ok)} of {len(x)} runs)', fontsize=9)
        ax.set_ylabel('runs')
    ax = axes.flat[-1]
    ax.scatter(metrics['min_range_m'], metrics['delta_v_mps'], s=10)
    ax.set_xlabel('min_range_m')
    ax.set_ylabel('delta_v_mps')
    ax.set_title('delta-v against closest approach', fontsize=9)
    fig.suptitle(f'closed-loop campaign: {n} runs (lines: 5th, 50th, 95th percentile)')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _vs_dispersions(path: Path, plotted: list[str], metrics: _Columns, dispersions: _Columns,
                    passes: np.ndarray, criteria: list[Criterion]) -> Path:
    """A matrix of panels: row = metric (``plotted``), column = dispersed parameter, one point
    per run (blue: passes every criterion, red: not), each criterion a dashed line in its row.
    Axes shared along rows and columns, and no automatic layout: ~0.1 s a panel less."""
    plt = _pyplot()
    names = plotted_dispersions(dispersions.names)
    rows, cols = len(plotted), max(1, len(names))
    fig, axes = plt.subplots(rows, cols, figsize=(1.5 * cols + 1.2, 1.25 * rows + 1.0), squeeze=False,
                             sharex='col', sharey='row')
    fig.subplots_adjust(left=0.9 / (1.5 * cols + 1.2), right=0.99, bottom=0.75 / (1.25 * rows + 1.0),
                        top=1 - 0.55 / (1.25 * rows + 1.0), wspace=0.08, hspace=0.08)
    for r, metric in enumerate(plotted):
        y = metrics[metric]
        finite = np.isfinite(y)
        for c, name in enumerate(names):
            ax, x = axes[r, c], dispersions[name]
            for mask, color in ((passes, 'tab:blue'), (~passes, 'tab:red')):
                keep = mask & finite
                if keep.any():
                    ax.scatter(x[keep], y[keep], s=4, color=color, alpha=0.7, rasterized=True)
            for crit in criteria:
                if crit.metric == metric:
                    ax.axhline(crit.threshold, color='k', ls='--', lw=0.8)
            ax.locator_params(nbins=3)  # each tick is an object to lay out: most of the time
            ax.tick_params(labelsize=6)
        axes[r, 0].set_ylabel(f'{metric}\n({int(finite.sum())} runs)', fontsize=7)
    for c, name in enumerate(names):
        axes[-1, c].set_xlabel(name, fontsize=7)
    title = f'each metric against each dispersion: {len(passes)} runs'
    if criteria:
        title += (f'; blue: passes every criterion ({int(passes.sum())}), red: not; dashed: '
                  + ', '.join(str(c) for c in criteria))
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, dpi=70)
    plt.close(fig)
    return path


def _series_figure(path: Path, files: list[Path]) -> Path:
    """The kept runs against time: distance from the guidance reference, lidar range,
    estimate error, cumulative delta-v."""
    plt = _pyplot()
    panels = (('distance to reference (m)', lambda s: np.linalg.norm(s['rho_true_m'] - s['ref_m'], axis=1)),
              ('range lidar -> target (m)', lambda s: s['range_m']),
              ('estimate translation error (m)', lambda s: s['est_trans_err_m']),
              ('delta-v (m/s, cumulative)', lambda s: s['delta_v_mps']))
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True)
    for file in files:
        series, meta = read_series(file)
        value = meta['metrics'].get(meta['by']) if meta.get('by') else None
        label = f'run {meta["run_id"]}' + (f': {meta["by"]} {value:.3g}' if value is not None else '') \
            + (' (asked)' if meta.get('asked') else '')
        for ax, (_, f) in zip(axes.flat, panels):
            ax.plot(series['t_s'], f(series), lw=1, label=label)
    for ax, (title, _) in zip(axes.flat, panels):
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel('t (s)')
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f'time series of {len(files)} kept runs (DIR/{SERIES_DIR}/)')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
