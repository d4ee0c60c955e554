"""Calibration from lab data: the config files the simulator reads, fitted to measurements.

- ``brdf``: goniometer BRDF table -> kd, ks, n of the modified Phong model (paper Sec. 5)
- ``range_errors``: static-target bag -> range bias and sigma per material (paper Sec. 6)
- ``scan_pattern``: measured point times and angles -> per-laser Lissajous scan (paper Sec. 3)

Each has a ``run_*`` function behind ``lidar-sim calibrate ...`` (``command.py``).
"""
