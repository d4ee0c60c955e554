"""Monte Carlo campaigns: a base scenario plus dispersions, many runs on Dask distributed.

Modules, each importing only those above it (``test_campaign`` checks it):
``statistics.py`` and ``coverage.py`` (what a frame run measures), ``criteria.py``
(pass/fail criteria), ``spec.py`` (CAMPAIGN.yaml, the loop file of a closed-loop campaign
included), ``sample.py`` (seeds and dispersed parameters), ``worker.py`` (a worker
process's mesh and kernels), ``series.py`` (the time series kept: the worst runs, the
runs asked for), ``loop_case.py`` (a closed-loop run), ``run.py`` (a frame run; the
engine's task, either kind), ``manifest.py`` (DIR/manifest.csv, ``--run``),
``summary.py`` (a closed-loop campaign's tables, verdicts and figures), ``engine.py``
(Dask; the only module that imports it), ``command.py`` (``lidar-sim campaign``).
See docs/campaign.md.
"""
