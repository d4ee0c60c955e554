"""The distributed engine: Dask distributed runs the campaign, locally or on a cluster.

Without ``address`` a ``LocalCluster`` starts one single-threaded worker process per
core (``workers`` to choose), nothing to set up; with ``address`` the client joins a
running scheduler (``dask scheduler`` + ``dask worker ADDRESS`` on each node, see
docs/campaign.md). A task is (campaign, run id), a few kB: workers sample and
simulate, the client only writes manifest rows as results arrive. Why Dask and not Ray: docs/campaign.md.
"""
from __future__ import annotations

import logging
import os
import signal
import threading
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import dask
from dask.distributed import Client, LocalCluster, as_completed

from lidar_sim_ros.campaign.manifest import Manifest
from lidar_sim_ros.campaign.run import prepare_worker, run_one
from lidar_sim_ros.campaign.sample import run_seed
from lidar_sim_ros.campaign.spec import Campaign


class EngineError(RuntimeError):
    """The engine could not start or reach its cluster."""


@dataclass(frozen=True)
class CampaignReport:
    """What a ``run_campaign`` call did. Times in seconds (wall clock of the client)."""

    manifest_path: Path
    parquet_path: Path | None
    runs: int
    skipped: int
    ran: int
    ok: int
    failed: int
    workers: int
    startup_s: float
    wall_s: float
    compute_s: float


# What a local worker process is started with (Dask's nanny sets these before it
# spawns the worker; None removes one of Dask's own). Dask's MALLOC_TRIM_THRESHOLD_=65536
# (to hand freed memory back to the OS) also fixes glibc's mmap threshold at 128 kB:
# every array of a frame is then mapped afresh and page-faulted in, 16x the page faults
# and 1.5-1.9x the CPU per run measured here. A worker holds ~335 MB steady, so glibc's
# adaptive default suits it. One BLAS / OpenMP thread per worker: there is one worker
# per core (Dask's defaults, restated because they matter here).
WORKER_ENVIRON: dict[str, str | None] = {
    'MALLOC_TRIM_THRESHOLD_': None,
    'OMP_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1',
}
_USER_ENVIRON = {key: os.environ.get(key) for key in WORKER_ENVIRON}  # the user's own win

# Dask's worker profiler samples every worker thread's stack each 10 ms (for the
# dashboard's profile page, which a campaign does not use): walking a frame's deep
# numpy / numba stack costs ~20 % of a run's CPU here (119 -> 145 frames/s on one
# worker, measured on an idle machine). Off on the workers we start.
WORKER_CONFIG = {'distributed.worker.profile.enabled': False}

# Runs submitted ahead per worker thread: enough to keep every worker busy while a result
# travels back, few enough that the client holds a bounded number of futures whatever the
# number of runs (100,000 submitted at once took 45-55 s and 6.3 GB before the first row).
IN_FLIGHT_PER_WORKER = 4


def local_cluster(workers: int) -> LocalCluster:
    """A local Dask cluster of ``workers`` single-threaded worker processes."""
    environ = {f'distributed.nanny.pre-spawn-environ.{k}': v for k, v in WORKER_ENVIRON.items()}
    # The nanny copies its environment into this process's os.environ before spawning,
    # and a worker inherits os.environ: drop what an earlier cluster left there.
    for key, value in WORKER_ENVIRON.items():
        if value is None and _USER_ENVIRON[key] is None:
            os.environ.pop(key, None)
    with dask.config.set({**environ, **WORKER_CONFIG}), _workers_ignore_sigint():
        # One thread per process: the kernels hold the GIL for part of a frame, and one
        # process per core lets each worker keep its own mesh and compiled kernels.
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=None)


@contextmanager
def _workers_ignore_sigint() -> Iterator[None]:
    """Worker processes started in this block ignore SIGINT (an ignored signal stays
    ignored across exec, and Python then installs no KeyboardInterrupt handler): Ctrl-C
    in a terminal reaches the whole process group, and each worker printed a traceback.
    The client alone stops the campaign and closes its cluster."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


@contextmanager
def connect(workers: int | None = None, address: str | None = None) -> Iterator[Client]:
    """A Dask client: of a new local cluster (``workers`` processes, default all cores)
    or of the running scheduler at ``address``."""
    if address:
        try:
            client = Client(address, timeout='20s')
        except (OSError, TimeoutError) as exc:
            raise EngineError(f'cannot reach a Dask scheduler at {address}: {exc}') from None
        with client:
            yield client
        return
    n = workers or os.cpu_count() or 1
    nanny_log = logging.getLogger('distributed.nanny')
    level = nanny_log.level
    try:
        with local_cluster(n) as cluster:
            try:
                with Client(cluster) as client:
                    yield client
            finally:
                # A worker whose interpreter takes > 4 s to tear down (numba, Embree, on a
                # busy machine) is killed by its nanny with a warning: harmless at the end.
                nanny_log.setLevel(logging.ERROR)
    finally:
        nanny_log.setLevel(level)


def run_campaign(campaign: Campaign, out_dir: str | Path, workers: int | None = None,
                 address: str | None = None, retry_failed: bool = False,
                 progress: bool = True) -> CampaignReport:
    """Run every run of ``campaign`` not yet in ``out_dir/manifest.csv``.

    A run that fails (or whose worker dies) is recorded as failed and the others go on;
    ``retry_failed`` runs the failed ones again.
    """
    manifest = Manifest.open(out_dir, campaign)
    runs = campaign.spec.runs
    n_pending = sum(not manifest.is_finished(i, retry_failed) for i in range(runs))
    # Run ids are produced as they are submitted, never listed (memory flat in the runs).
    pending = (i for i in range(runs) if not manifest.is_finished(i, retry_failed))
    t0 = time.perf_counter()
    startup_s = wall_s = 0.0
    n_workers = 0
    tally = {'ok': 0, 'failed': 0, 'compute_s': 0.0}
    bar = _progress_bar(runs, runs - n_pending, progress)
    try:
        if n_pending:
            if bar is not None:
                bar.set_postfix_str('starting workers')
            with connect(workers, address) as client:
                # Mesh and kernels on every worker now, in parallel, so that runs time only runs.
                _check_workers(client.run(prepare_worker, campaign))
                n_workers = sum(client.nthreads().values())
                startup_s = time.perf_counter() - t0
                t1 = time.perf_counter()
                _gather(client, campaign, pending, n_pending, out_dir, manifest, bar, tally,
                        IN_FLIGHT_PER_WORKER * max(n_workers, 1))
                wall_s = time.perf_counter() - t1
    finally:
        if bar is not None:
            bar.close()
    manifest.rewrite()
    parquet = manifest.write_parquet()
    return CampaignReport(manifest.path, parquet, runs, runs - n_pending,
                          tally['ok'] + tally['failed'], tally['ok'], tally['failed'], n_workers,
                          startup_s, wall_s, tally['compute_s'])


def _check_workers(facts: dict[str, dict]) -> None:
    """Warn about workers started with Dask's defaults that cost us CPU (``dask worker``
    on a cluster): a fixed glibc trim threshold (runs cost 1.5-1.9x the CPU,
    ``WORKER_ENVIRON``) or the stack profiler (~1.2x, ``WORKER_CONFIG``)."""
    n = len(facts)
    trimmed = sum(f['MALLOC_TRIM_THRESHOLD_'] is not None for f in facts.values())
    profiled = sum(bool(f['profile']) for f in facts.values())
    if trimmed:
        warnings.warn(f'{trimmed} of {n} Dask workers run with '
                      f'MALLOC_TRIM_THRESHOLD_ set (Dask\'s default): runs cost up to 1.9x the CPU; '
                      f'start them with distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_: '
                      f'null in the Dask config (docs/campaign.md)', stacklevel=3)
    if profiled:
        warnings.warn(f'{profiled} of {n} Dask workers run the stack profiler (Dask\'s default): '
                      f'runs cost ~1.2x the CPU; start them with '
                      f'DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False (docs/campaign.md)',
                      stacklevel=3)


def _gather(client: Client, campaign: Campaign, pending: Iterator[int], n_pending: int,
            out_dir: str | Path, manifest: Manifest, bar, tally: dict, in_flight: int) -> None:
    """Submit the pending runs, at most ``in_flight`` at a time, and record each as it
    finishes (``tally``: ok, failed, summed compute in s). On Ctrl-C the runs in flight
    are cancelled: every finished run is already in the manifest, so the same command
    resumes."""
    # The campaign travels inside each task (~4 kB pickled): tasks without dependencies
    # are queued on the scheduler and handed to whichever worker frees up first, where a
    # scattered campaign made them data-dependent and let one worker take most of them.
    out = str(Path(out_dir).resolve())  # workers may run elsewhere, in another directory
    futures: dict = {}
    queue = as_completed()

    def submit_next() -> None:
        run_id = next(pending, None)
        if run_id is not None:
            future = client.submit(run_one, campaign, run_id, out, pure=False)
            futures[future] = run_id
            queue.add(future)

    for _ in range(in_flight):
        submit_next()
    remaining = n_pending
    if bar is not None:
        bar.set_postfix_str(_counts(manifest, remaining))
    try:
        for future in queue:
            run_id = futures.pop(future)
            try:
                row = future.result()
            except Exception as exc:  # the worker died (KilledWorker) or the task was lost
                row = {'run_id': run_id, 'seed': run_seed(campaign.spec.seed, run_id),
                       'status': 'failed', 'error': f'engine: {type(exc).__name__}: {exc}'}
            future.release()
            submit_next()
            tally['compute_s'] += float(row.get('compute_s') or 0.0)
            tally[row['status']] += 1
            manifest.append(row)
            remaining -= 1
            if bar is not None:
                bar.set_postfix_str(_counts(manifest, remaining), refresh=False)
                bar.update(1)
    except KeyboardInterrupt:
        client.cancel(list(futures), force=True)
        raise


def _counts(manifest: Manifest, remaining: int) -> str:
    return f'done {manifest.count("ok")}, failed {manifest.count("failed")}, remaining {remaining}'


def _progress_bar(total: int, skipped: int, enabled: bool):
    """tqdm over all runs of the campaign, the skipped ones counted in from the start."""
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=total, initial=skipped, unit='run', desc='campaign', dynamic_ncols=True)
