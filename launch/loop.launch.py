"""The closed GNC loop over DDS (docs/loop.md): five nodes, lock-step on loop_dynamics' /clock.

    ros2 launch lidar_sim_ros loop.launch.py
    ros2 launch lidar_sim_ros loop.launch.py loop_config:=/path/to/loop.yaml \
        scenario_file:=/path/to/scenario.yaml cloud_topic:=/lidar/points_truth controller:=false

controller:=false leaves loop_controller out: your own GNC then subscribes to
/target/pose_estimate and /chaser/attitude and publishes /chaser/force_command (see
docs/loop.md, "Your own GNC in the loop"). Set ROS_DOMAIN_ID first (a private domain).
Without launch (a pip install), ``python -m lidar_sim_ros.loop.demo`` starts the same nodes
with the same parameters and records the run.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory('lidar_sim_ros')
    loop_config = LaunchConfiguration('loop_config')
    scenario = LaunchConfiguration('scenario_file')
    cloud_topic = LaunchConfiguration('cloud_topic')
    epoch = LaunchConfiguration('epoch_s')
    return LaunchDescription([
        DeclareLaunchArgument('loop_config', default_value=os.path.join(share, 'config', 'loop.yaml'),
                              description='the loop config (dynamics, guidance, timing, gnc entry points)'),
        DeclareLaunchArgument('scenario_file',
                              default_value=os.path.join(share, 'config', 'scenario_all_effects.yaml'),
                              description="the simulator's scenario (the loop config's scenario)"),
        DeclareLaunchArgument('cloud_topic', default_value='/lidar/points',
                              description='/lidar/points (the full error model) or /lidar/points_truth'),
        DeclareLaunchArgument('epoch_s', default_value='100.0', description='clock time of loop time zero (s)'),
        DeclareLaunchArgument('controller', default_value='true',
                              description='start loop_controller (false: your own GNC commands)'),
        Node(package='lidar_sim_ros', executable='loop_dynamics', name='loop_dynamics',
             output='screen', emulate_tty=True,
             parameters=[{'config_file': loop_config, 'epoch_s': epoch, 'clock_delay_s': 0.01,
                          'wait_for_publishers': ['/chaser/force_command', '/target/pose_estimate',
                                                  '/lidar/points'],
                          'wait_for_subscribers': ['/target/pose', '/chaser/attitude', '/loop/points_gated',
                                                   '/target/pose_estimate']}]),
        Node(package='lidar_sim_ros', executable='lidar_sim_node', name='lidar_sim_node',
             output='screen', emulate_tty=True,
             parameters=[{'scenario_file': scenario, 'use_sim_time': True, 'publish_truth': True,
                          'qos_reliability': 'reliable', 'pose_qos_reliability': 'reliable'}]),
        Node(package='lidar_sim_ros', executable='loop_cloud_gate', name='loop_cloud_gate',
             output='screen', emulate_tty=True,
             parameters=[{'input_topic': cloud_topic, 'gate_m': 8.0, 'capture_gate_m': 12.0,
                          'period_s': 0.1}]),
        Node(package='lidar_sim_ros', executable='pose_tracker', name='pose_tracker',
             output='screen', emulate_tty=True,
             parameters=[{'points_topic': '/loop/points_gated', 'scenario_file': scenario,
                          'use_sim_time': True, 'points_reliable': True}]),
        Node(package='lidar_sim_ros', executable='loop_controller', name='loop_controller',
             output='screen', emulate_tty=True, condition=IfCondition(LaunchConfiguration('controller')),
             parameters=[{'config_file': loop_config, 'use_sim_time': True}]),
    ])
