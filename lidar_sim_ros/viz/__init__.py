"""Pictures of simulated (or measured) LiDAR frames, like the paper's Figs. 6 and 13-16."""
from lidar_sim_ros.viz.figures import FIGURE_NAMES, render_bag_figures, render_frame_figures

__all__ = ['FIGURE_NAMES', 'render_bag_figures', 'render_frame_figures']
