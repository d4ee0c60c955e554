"""lidar_sim_ros: LiDAR measurement simulator for rendezvous with space debris."""
__version__ = '0.1.0'
