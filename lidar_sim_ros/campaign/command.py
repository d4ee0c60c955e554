"""``lidar-sim campaign``: Monte Carlo campaigns of dispersed runs on Dask distributed.

The engine (Dask) is an optional extra, imported only when a campaign runs, so the
rest of the ``lidar-sim`` command works without it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lidar_sim_ros.cli_types import positive_int, run_id
from lidar_sim_ros.campaign.spec import load_campaign

INSTALL_HINT = "pip install 'lidar_sim_ros[campaign]' (or -r requirements-campaign.txt)"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'campaign', help='run a Monte Carlo campaign of dispersed runs (Dask distributed)',
        description='Run every run of CAMPAIGN.yaml that DIR/manifest.csv does not hold yet, on '
                    'a local Dask cluster (default: one worker per core) or the cluster at '
                    '--address; one manifest row per run. See docs/campaign.md.')
    p.add_argument('campaign', type=Path, help='campaign YAML (e.g. config/campaign_example.yaml)')
    p.add_argument('--out', type=Path, required=True, metavar='DIR',
                   help='output directory: manifest.csv (+ runs/run_NNNNN/bag with save: bags)')
    p.add_argument('--workers', type=positive_int, default=None, metavar='N',
                   help='local worker processes (default: all cores); ignored with --address')
    p.add_argument('--address', default=None, metavar='ADDR',
                   help='join a running Dask scheduler, e.g. tcp://10.0.0.5:8786')
    p.add_argument('--tls-ca-file', type=Path, default=None, metavar='PEM',
                   help='join --address tls://... over TLS: the CA that signed the cluster\'s '
                        'certificates (default: the Dask config\'s distributed.comm.tls.ca-file)')
    p.add_argument('--tls-cert', type=Path, default=None, metavar='PEM',
                   help='this client\'s certificate, signed by that CA (or distributed.comm.tls.client.cert)')
    p.add_argument('--tls-key', type=Path, default=None, metavar='PEM',
                   help='its private key (default: appended to --tls-cert)')
    p.add_argument('--run', type=run_id, default=None, metavar='RUN_ID',
                   help='re-run this one run here (no cluster) and compare with the manifest')
    p.add_argument('--retry-failed', action='store_true',
                   help='run the runs recorded as failed again (default: skip them)')
    p.add_argument('--no-progress', action='store_true', help='no progress bar')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    campaign = load_campaign(args.campaign)
    if args.run is not None:
        return _rerun(campaign, args.out, args.run)
    try:
        from lidar_sim_ros.campaign.engine import EngineError, run_campaign
    except ImportError as exc:
        print(f'lidar-sim campaign: error: the engine is not installed ({exc.name}): {INSTALL_HINT}',
              file=sys.stderr)
        return 2
    try:
        report = run_campaign(campaign, args.out, workers=args.workers, address=args.address,
                              retry_failed=args.retry_failed, progress=not args.no_progress,
                              security=_security(args))
    except EngineError as exc:
        print(f'lidar-sim campaign: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'\nlidar-sim campaign: interrupted; finished runs are in {args.out / "manifest.csv"}, '
              'the same command resumes', file=sys.stderr)
        return 130
    frames = report.ran * campaign.frames_per_run
    print(f'manifest: {report.manifest_path}  ({report.runs} runs: {report.skipped} already '
          f'finished, {report.ok} ok, {report.failed} failed now)')
    if report.ran:
        print(f'engine: {report.workers} Dask workers, first row after {report.startup_s:.1f} s, '
              f'{report.ran} runs ({frames} frames, {report.tasks} tasks) in {report.wall_s:.1f} s '
              f'= {frames / report.wall_s:.1f} frames/s')
    if report.parquet_path:
        print(f'parquet: {report.parquet_path}')
    if campaign.spec.loop is not None:
        _loop_summary(args.out, campaign)
    elif campaign.spec.criteria:
        _frame_summary(args.out, campaign)
    return 1 if report.failed else 0


def _frame_summary(out_dir: Path, campaign):
    """A frame campaign's verdicts (criteria.csv, vs_dispersions.png) and its pass rates."""
    from lidar_sim_ros.campaign.summary import summarize_frames
    summary = summarize_frames(out_dir, campaign)
    print(f'criteria: {summary.runs} ok runs, {summary.failed} failed: {summary.criteria_table}'
          + (f', {summary.figure}' if summary.figure else ''))
    _print_verdicts(summary.verdicts)
    return summary


def _print_verdicts(verdicts) -> None:
    for row in verdicts:
        print(f'  pass {row["passed"]:>6d} of {row["runs"]:<6d} ({100 * (row["pass_rate"] or 0.0):5.1f} %)  '
              f'{row["criterion"]}')


def _security(args: argparse.Namespace):
    """The TLS ``Security`` of ``--tls-*`` (None without them: Dask's config decides)."""
    from lidar_sim_ros.campaign.engine import EngineError, tls_security
    given = {k: getattr(args, k) for k in ('tls_ca_file', 'tls_cert', 'tls_key')}
    if not any(v is not None for v in given.values()):
        return None
    if given['tls_ca_file'] is None or given['tls_cert'] is None:
        raise EngineError('--tls-ca-file and --tls-cert go together (and --tls-key, unless the key '
                          'is appended to the certificate)')
    if not args.address:
        raise EngineError('--tls-* secure the connection to --address tls://HOST:PORT; '
                          'the local cluster listens on 127.0.0.1 only')
    return tls_security(given['tls_ca_file'], given['tls_cert'], given['tls_key'])


def _loop_summary(out_dir: Path, campaign):
    """A closed-loop campaign's tables and figures, its percentiles and pass rates on the
    terminal; returns the ``summary.LoopSummary``."""
    from lidar_sim_ros.campaign.summary import summarize
    summary = summarize(out_dir, campaign)
    print(f'closed loop: {summary.runs} runs: {summary.runs_table}, {summary.summary_table}'
          + (f', {summary.criteria_table}' if summary.criteria_table else '')
          + (f', {len(summary.figures)} figures ({summary.figure.name}, ...)' if summary.figure else ''))
    for row in summary.table:
        if row['runs']:
            print(f'  {row["metric"]:18s} p5 {row["p5"]:9.4g}  p50 {row["p50"]:9.4g}  '
                  f'p95 {row["p95"]:9.4g}  ({row["runs"]} runs, {row["missing"]} without)')
        else:
            print(f'  {row["metric"]:18s} no value in {row["missing"]} runs')
    _print_verdicts(summary.verdicts)
    return summary


def _rerun(campaign, out_dir: Path, run_id: int) -> int:
    from lidar_sim_ros.campaign.manifest import rerun
    if campaign.spec.loop is not None:
        return _rerun_loop(campaign, out_dir, run_id)
    row, old = rerun(campaign, out_dir, run_id)
    stats = {k: v for k, v in row.items() if k.startswith('stat.')}
    print(f'run {run_id}: seed {row["seed"]}, status {row["status"]}'
          + (f': {row["error"]}' if row['error'] else ''))
    for key, value in stats.items():
        print(f'  {key} = {value}')
    if old is None:
        print(f'run {run_id} was not in {out_dir}/manifest.csv; it is now')
        return 0 if row['status'] == 'ok' else 1
    changed = [k for k in stats if old.get(k) != row[k]]
    if old['status'] != row['status'] or changed:
        print(f'run {run_id} differs from the manifest: status {old["status"]} -> {row["status"]}'
              + (f'; {", ".join(changed)}' if changed else ''))
        return 1
    print(f'run {run_id}: statistics identical to the manifest row')
    return 0


def _rerun_loop(campaign, out_dir: Path, run_id: int) -> int:
    """``--run`` of a closed-loop campaign: its metrics (loop.json) compared with the last ones."""
    from lidar_sim_ros.campaign.loop_case import read_result
    from lidar_sim_ros.campaign.manifest import rerun
    old = read_result(out_dir, run_id)
    row, _ = rerun(campaign, out_dir, run_id)
    print(f'run {run_id}: seed {row["seed"]}, status {row["status"]}'
          + (f': {row["error"]}' if row['error'] else ''))
    new = read_result(out_dir, run_id) if row['status'] == 'ok' else None
    for key, value in (new or {}).get('metrics', {}).items():
        print(f'  {key} = {value}')
    if old is None:
        print(f'run {run_id} had no loop.json in {out_dir}; it has now')
        return 0 if row['status'] == 'ok' else 1
    if new is None or new['metrics'] != old['metrics']:
        changed = [k for k in old['metrics'] if new is None or new['metrics'].get(k) != old['metrics'][k]]
        print(f'run {run_id} differs from its last result: {", ".join(changed)}')
        return 1
    print(f'run {run_id}: metrics identical to the last result')
    return 0
