"""``python3 -m lidar_sim_ros ...`` is ``lidar-sim ...``: after ``colcon build`` the package
is on PYTHONPATH (``source install/setup.bash``) while its console scripts sit in
``lib/lidar_sim_ros`` (for ``ros2 run``), not on PATH."""
import sys

from lidar_sim_ros.cli import main

sys.exit(main())
