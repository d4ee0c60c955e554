"""Measured point clouds against the model: ``lidar-sim compare``.

measurements (bag -> rays) -> matching (prediction on each ray, edge probe) ->
materials (per-material bias/sigma) -> features (where the residual depends) ->
diagnosis (which catalogue effect is missing) -> report + history. ``run.run_compare``
reads the whole loop top to bottom.
"""
