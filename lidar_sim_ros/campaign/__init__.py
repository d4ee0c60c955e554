"""Monte Carlo campaigns: a base scenario plus dispersions, many runs on Dask distributed.

``spec.py`` (CAMPAIGN.yaml), ``sample.py`` (seeds and dispersed parameters),
``run.py`` (one run -> statistics), ``coverage.py`` and ``statistics.py`` (what a run
measures), ``manifest.py`` (DIR/manifest.csv), ``engine.py`` (Dask; the only module
that imports it), ``command.py`` (``lidar-sim campaign``). See docs/campaign.md.
"""
