"""The distributed engine: Dask distributed runs the campaign, locally or on a cluster.

Without ``address`` a ``LocalCluster`` starts one single-threaded worker process per
core (``workers`` to choose), nothing to set up; with ``address`` the client joins a
running scheduler (``dask scheduler`` + ``dask worker ADDRESS`` on each node, see
docs/campaign.md). A task is (campaign, run ids), a few kB: workers sample and
simulate, the client only writes manifest rows as results arrive. Why Dask and not Ray: docs/campaign.md.

Dask, the manifest and the simulator are imported where they are first needed, after
the progress bar is drawn: together they take ~1 s of CPU to import, and the bar is
meant to show at once.
"""
from __future__ import annotations

import importlib.util
import itertools
import logging
import math
import os
import pickle
import signal
import threading
import time
import warnings
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from lidar_sim_ros.campaign.spec import Campaign

if TYPE_CHECKING:
    from dask.distributed import Client, LocalCluster
    from distributed.security import Security

    from lidar_sim_ros.campaign.manifest import Manifest
    from lidar_sim_ros.campaign.series import SeriesKeeper

for _module in ('dask', 'distributed'):  # the extra is missing: say so on import
    if importlib.util.find_spec(_module) is None:
        raise ImportError(f'No module named {_module!r}', name=_module)


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
    tasks: int = 0
    # startup_s: from the call to the first manifest row (manifest, cluster, the first
    # worker's preparation, the first run); wall_s: from the first submission to the last
    # row (the workers prepare on their first task, inside it); compute_s: summed over
    # runs; tasks: Dask tasks submitted (short runs go several to a task).


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

# Local workers are forked from one server process that has imported Dask and the
# simulator (multiprocessing's forkserver, preloaded), not each started afresh: a worker
# then costs ~0.05 s of CPU to start instead of ~1.1 s of imports (measured), which on a
# busy machine is most of the wait for the first rows. The server starts inside
# ``_workers_ignore_sigint``, so it and every worker forked from it ignore SIGINT.
FORKSERVER = {'distributed.worker.multiprocessing-method': 'forkserver'}
FORKSERVER_PRELOAD = ['distributed', 'lidar_sim_ros.campaign.run']

# Runs submitted ahead per worker thread: enough to keep every worker busy while a result
# travels back, few enough that the client holds a bounded number of futures whatever the
# number of runs (100,000 submitted at once took 45-55 s and 6.3 GB before the first row).
IN_FLIGHT_PER_WORKER = 4

# Short runs go several to a task (``BatchSizer``): Dask costs ~5-10 ms per task between
# scheduler, client and worker, more than a one-frame run of a small sensor (~1 ms), and
# runs/s were capped at ~150 on two workers whatever the runs. A task lasts ~TASK_S once
# the first runs are timed; MAX_RUNS_PER_TASK bounds what Ctrl-C or a dead worker costs.
TASK_S = 0.5
MAX_RUNS_PER_TASK = 500


def local_cluster(workers: int) -> LocalCluster:
    """A local Dask cluster of ``workers`` single-threaded worker processes."""
    import dask
    from dask.distributed import LocalCluster
    environ = {f'distributed.nanny.pre-spawn-environ.{k}': v for k, v in WORKER_ENVIRON.items()}
    start_forkserver()
    with dask.config.set({**environ, **WORKER_CONFIG, **FORKSERVER}), _workers_ignore_sigint():
        # One thread per process: the kernels hold the GIL for part of a frame, and one
        # process per core lets each worker keep its own mesh and compiled kernels.
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=None)


def start_forkserver() -> None:
    """Start the server that local workers are forked from (``FORKSERVER``), if it is not
    running: it imports Dask and the simulator in the background, while this process
    reads the manifest and starts the scheduler. Its environment, which every worker
    inherits, is ``WORKER_ENVIRON`` (a value the user exported wins, as in Dask)."""
    import multiprocessing.forkserver

    import dask
    from distributed.utils import get_mp_context
    with dask.config.set(FORKSERVER), _workers_ignore_sigint():
        # Dask sets its own preload list on first use: ours replaces it.
        get_mp_context().set_forkserver_preload(FORKSERVER_PRELOAD)
        saved = dict(os.environ)
        try:
            for key, value in WORKER_ENVIRON.items():
                if _USER_ENVIRON[key] is not None:
                    os.environ[key] = _USER_ENVIRON[key]
                elif value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
            multiprocessing.forkserver.ensure_running()
        finally:
            os.environ.clear()
            os.environ.update(saved)


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


def tls_security(ca_file: str | Path, cert: str | Path, key: str | Path | None = None) -> Security:
    """The client's side of a TLS cluster (docs/campaign.md, "Securing a Dask cluster"): a
    Dask ``Security`` from PEM files, the CA that signed every endpoint's certificate, this
    client's certificate and its key (None: the key is appended to ``cert``); encryption
    required, so that no plain ``tcp://`` connection is made by mistake."""
    from distributed.security import Security
    files = {'--tls-ca-file': ca_file, '--tls-cert': cert, '--tls-key': key}
    for option, path in files.items():
        if path is not None and not Path(path).is_file():
            raise EngineError(f'{option} {path}: no such file')
    extra = {'tls_client_key': str(key)} if key is not None else {}
    return Security(tls_ca_file=str(ca_file), tls_client_cert=str(cert), require_encryption=True,
                    **extra)


def _client_security(address: str, security: Security | None) -> Security | None:
    """``security``, or None for Dask's own (``distributed.comm.tls.*`` of the Dask config,
    read by ``Client``); refuses a pairing that can only fail later, less clearly."""
    tls = address.startswith('tls://')
    if security is not None and not tls:
        raise EngineError(f'--address {address}: with TLS certificates the scheduler\'s address is '
                          'tls://HOST:PORT (dask scheduler --protocol tls)')
    if tls and security is None:
        from distributed.security import Security
        own = Security()  # what Client would build: the Dask config's distributed.comm.tls.*
        if own.tls_ca_file is None or own.tls_client_cert is None:
            raise EngineError(f'--address {address}: a TLS scheduler needs this client\'s certificate: '
                              '--tls-ca-file, --tls-cert (and --tls-key), or distributed.comm.tls.ca-file '
                              'and distributed.comm.tls.client.cert in the Dask config (docs/campaign.md)')
    return security


@contextmanager
def connect(workers: int | None = None, address: str | None = None,
            security: Security | None = None) -> Iterator[Client]:
    """A Dask client: of a new local cluster (``workers`` processes, default all cores)
    or of the running scheduler at ``address``, over TLS with ``security`` (``tls_security``;
    None: the Dask config's ``distributed.comm.tls.*``, as ``dask`` commands read it)."""
    from dask.distributed import Client
    if security is not None and not address:
        raise EngineError('TLS certificates are for joining a scheduler (--address tls://HOST:PORT); '
                          'the local cluster listens on 127.0.0.1 only')
    if address:
        security = _client_security(address, security)
        try:
            client = Client(address, timeout='20s', security=security)
        except (OSError, TimeoutError) as exc:  # ssl.SSLError is an OSError
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
                    client.run(_quiet_worker_close)
                    yield client
            finally:
                # A worker whose interpreter takes > 4 s to tear down (numba, Embree, on a
                # busy machine) is killed by its nanny with a warning: harmless at the end.
                nanny_log.setLevel(logging.ERROR)
    finally:
        nanny_log.setLevel(level)


def _quiet_worker_close() -> None:
    """On a local worker: closing it with a task running (Ctrl-C stops the cluster in
    the middle of a batch) logs a warning per task ("Async instruction ... ended with
    CancelledError"), expected by Dask ("should exclusively happen in Worker.close()")
    and of no use to the user."""
    logging.getLogger('distributed.worker.state_machine').setLevel(logging.ERROR)


def run_campaign(campaign: Campaign, out_dir: str | Path, workers: int | None = None,
                 address: str | None = None, retry_failed: bool = False,
                 progress: bool = True, security: Security | None = None) -> CampaignReport:
    """Run every run of ``campaign`` not yet in ``out_dir/manifest.csv``.

    A run that fails (or whose worker dies) is recorded as failed and the others go on;
    ``retry_failed`` runs the failed ones again. ``security``: joining ``address`` over TLS
    (``tls_security``; None: the Dask config's, see ``connect``).
    """
    t0 = time.perf_counter()
    runs = campaign.spec.runs
    # The bar first, so that something shows while the manifest is read and workers start.
    bar = _progress_bar(runs, progress)
    try:
        if not address:
            start_forkserver()
        from lidar_sim_ros.campaign.manifest import Manifest
        from lidar_sim_ros.campaign.run import keeps_series, worker_facts
        from lidar_sim_ros.campaign.series import SeriesKeeper
        manifest = Manifest.open(out_dir, campaign)
        keeper = SeriesKeeper.open(out_dir, campaign.spec.series) if keeps_series(campaign) else None
        n_pending = sum(not manifest.is_finished(i, retry_failed) for i in range(runs))
        # Run ids are produced as they are submitted, never listed (memory flat in the runs).
        pending = (i for i in range(runs) if not manifest.is_finished(i, retry_failed))
        tally = {'ok': 0, 'failed': 0, 'compute_s': 0.0, 'first_row_s': 0.0, 'tasks': 0}
        n_workers, wall_s = 0, 0.0
        if bar is not None:
            bar.n = bar.initial = runs - n_pending
            bar.set_postfix_str('starting workers' if n_pending else _counts(manifest, 0))
        if n_pending:
            with connect(workers, address, security) as client:
                if address:
                    _check_workers(client.run(worker_facts))
                n_workers = sum(client.nthreads().values()) or 1
                t1 = time.perf_counter()
                # Each worker prepares itself (mesh, BVH, kernels) on its first task, so
                # the first rows come from the first worker ready, not the last one.
                _gather(client, campaign, pending, n_pending, out_dir, manifest, bar, tally,
                        IN_FLIGHT_PER_WORKER * n_workers, t0, keeper)
                wall_s = time.perf_counter() - t1
    finally:
        if bar is not None:
            bar.close()
    manifest.rewrite()
    parquet = manifest.write_parquet()
    ran = tally['ok'] + tally['failed']
    return CampaignReport(manifest.path, parquet, runs, runs - n_pending, ran, tally['ok'],
                          tally['failed'], n_workers, tally['first_row_s'], wall_s,
                          tally['compute_s'], tally['tasks'])


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


class BatchSizer:
    """How many runs the next task takes (``run.run_batch``).

    One until a run has been timed; then enough runs for a task of about ``task_s``
    (mean compute of the runs so far), at most ``max_runs``, and never more than an
    even share of what is left to submit (``remaining // share``), so that the last
    tasks still spread over every worker. Runs of ``task_s`` or longer go one per task.
    """

    def __init__(self, task_s: float = TASK_S, max_runs: int = MAX_RUNS_PER_TASK):
        self.task_s, self.max_runs = task_s, max_runs
        self._timed, self._sum_s = 0, 0.0

    def observe(self, compute_s: float) -> None:
        """One finished run's compute time (s)."""
        if math.isfinite(compute_s):
            self._timed += 1
            self._sum_s += max(compute_s, 0.0)

    def size(self, remaining: int, share: int) -> int:
        if not self._timed:
            return 1
        mean = self._sum_s / self._timed
        wanted = self.max_runs if mean <= 0.0 else int(self.task_s // mean)
        return max(1, min(wanted, self.max_runs, remaining // max(share, 1)))


def _gather(client: Client, campaign: Campaign, pending: Iterator[int], n_pending: int,
            out_dir: str | Path, manifest: Manifest, bar, tally: dict, in_flight: int,
            t0: float, keeper: SeriesKeeper | None = None) -> None:
    """Submit the pending runs in batches (``BatchSizer``), at most ``in_flight`` tasks at
    a time, and record each run as its batch finishes (``tally``: ok, failed, summed
    compute in s, ``first_row_s`` after ``t0``, ``tasks``; ``keeper``: the time series
    a closed-loop campaign keeps).

    A task lost with its worker (``KilledWorker`` after Dask's own retries) may hold
    runs that did nothing wrong: its batch-mates, or a task that only sat queued on the
    worker another run killed. Its runs become suspects, run one at a time with nothing
    else in flight once the tasks in flight have drained: a suspect lost then is the
    one that kills its worker, and only it is recorded as failed.

    On Ctrl-C the tasks in flight are cancelled: every finished run is already in the
    manifest, so the same command resumes."""
    # The campaign travels inside each task (~3.5 kB pickled): tasks without dependencies
    # are queued on the scheduler and handed to whichever worker frees up first, where a
    # scattered campaign made them data-dependent and let one worker take most of them.
    from dask.distributed import as_completed

    from lidar_sim_ros.campaign.run import run_batch
    from lidar_sim_ros.campaign.sample import run_seed
    out = str(Path(out_dir).resolve())  # workers may run elsewhere, in another directory
    payload = pickle.dumps(campaign)  # once; the scheduler keeps less of it (run_batch)
    futures: dict = {}              # future -> (run ids, run alone?)
    queue = as_completed()
    sizer = BatchSizer()
    suspects: deque[int] = deque()  # runs of lost tasks, to be run alone
    unsubmitted = n_pending

    def submit(batch: list[int], isolated: bool) -> None:
        future = client.submit(run_batch, payload, batch, out, pure=False)
        futures[future] = batch, isolated
        queue.add(future)
        tally['tasks'] += 1

    def fill() -> None:
        nonlocal unsubmitted
        while len(futures) < in_flight:
            if suspects:
                if not futures:
                    submit([suspects.popleft()], isolated=True)
                return
            batch = list(itertools.islice(pending, sizer.size(unsubmitted, in_flight)))
            if not batch:
                return
            unsubmitted -= len(batch)
            submit(batch, isolated=False)

    fill()
    remaining = n_pending
    if bar is not None:
        bar.set_postfix_str(_counts(manifest, remaining))
    try:
        for future in queue:
            batch, isolated = futures.pop(future)
            try:
                rows = future.result()
            except Exception as exc:  # the worker died (KilledWorker) or the task was lost
                rows = [] if not isolated else [{
                    'run_id': batch[0], 'seed': run_seed(campaign.spec.seed, batch[0]),
                    'status': 'failed', 'error': f'engine: {type(exc).__name__}: {exc}'}]
                if not isolated:
                    suspects.extend(batch)
            future.release()
            fill()
            for row in rows:
                if keeper is not None:
                    keeper.offer(row)
                compute_s = float(row.get('compute_s') or 0.0)
                sizer.observe(compute_s)
                tally['compute_s'] += compute_s
                tally[row['status']] += 1
            if rows:
                manifest.append_rows(rows)
                if not tally['first_row_s']:
                    tally['first_row_s'] = time.perf_counter() - t0
            remaining -= len(rows)
            if bar is not None and rows:
                bar.set_postfix_str(_counts(manifest, remaining), refresh=False)
                bar.update(len(rows))
    except KeyboardInterrupt:
        client.cancel(list(futures), force=True)
        raise


def _counts(manifest: Manifest, remaining: int) -> str:
    return f'done {manifest.count("ok")}, failed {manifest.count("failed")}, remaining {remaining}'


def _progress_bar(total: int, enabled: bool):
    """tqdm over all runs of the campaign (the caller counts the skipped ones in)."""
    if not enabled:
        return None
    from tqdm import tqdm
    bar = tqdm(total=total, unit='run', desc='campaign', dynamic_ncols=True)
    bar.set_postfix_str('reading the manifest')
    return bar
