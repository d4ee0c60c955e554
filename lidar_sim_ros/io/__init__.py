"""Message and file formats: the PointCloud2 layout and rosbag2 reading/writing."""
