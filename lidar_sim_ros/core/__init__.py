"""The ROS-free simulator core: scan, geometry, reflection, detection, effects, pose."""
