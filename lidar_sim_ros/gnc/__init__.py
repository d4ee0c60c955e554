"""Navigation in the loop: model-based pose tracking of the target from the simulated clouds.

Needs the optional extra ``pip install lidar_sim_ros[gnc]`` (small_gicp); the core does not.
"""
