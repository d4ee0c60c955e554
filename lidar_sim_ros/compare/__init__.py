"""Measured point clouds against the model: ``lidar-sim compare``.

Sub-packages along the data's way, imports flowing one way down this list:

* ``recording``: the recording in (``measurements``: bag or pcap -> measured rays;
  ``fields``: the point fields; ``intensity``: the measured intensity as power;
  ``shots``: the shots fired);
* ``model``: the model on the measured rays (``matching``: the prediction on each ray
  and the edge probe; ``likelihood`` with each material profiled; ``fit``;
  ``materials``; ``neighbours``; ``point_times``: the spread of unknown times);
* ``diagnose``: the diagnosis (``features``: where the residual depends;
  ``diagnosis``: the candidates and the one naming rule; ``pose_error``: the reference
  pose; ``scan_clock``: the time within the scan for one rate of the pose; ``plan``: the
  recording that separates a tie; ``stamp_place``; ``sunlight``);
* ``report``: the verdict and the report (``verdict``, ``page``: report.html,
  ``opening``, ``history``).

``run.run_compare`` reads the whole loop top to bottom, one function per stage;
``command`` is the CLI.
"""
