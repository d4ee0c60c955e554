"""Start lidar_sim_node and target_pose_player with config/params.yaml.

    ros2 launch lidar_sim_ros lidar_sim.launch.py
    ros2 launch lidar_sim_ros lidar_sim.launch.py params_file:=/path/to/params.yaml \
        use_sim_time:=true player:=false

Without launch (e.g. a pip install), the same two processes are:

    lidar_sim_node --ros-args --params-file config/params.yaml
    target_pose_player --ros-args --params-file config/params.yaml
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory('lidar_sim_ros'), 'config', 'params.yaml')
    params_file = LaunchConfiguration('params_file')
    use_sim_time = LaunchConfiguration('use_sim_time')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='parameters of both nodes'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='follow /clock instead of the wall clock'),
        DeclareLaunchArgument('player', default_value='true',
                              description='also start target_pose_player (false: poses come from your GNC)'),
        Node(package='lidar_sim_ros', executable='lidar_sim_node', name='lidar_sim_node',
             output='screen', emulate_tty=True,
             parameters=[params_file, {'use_sim_time': use_sim_time}]),
        Node(package='lidar_sim_ros', executable='target_pose_player', name='target_pose_player',
             output='screen', emulate_tty=True, condition=IfCondition(LaunchConfiguration('player')),
             parameters=[params_file, {'use_sim_time': use_sim_time}]),
    ])
