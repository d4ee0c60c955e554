"""ament_python package: builds with colcon on ROS 2 Jazzy and installs with pip on bare Python 3.11."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'lidar_sim_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/meshes', sorted(glob('meshes/*.obj') + glob('meshes/*.mtl') + glob('meshes/*.glb')
                                               + glob('meshes/*.gltf') + glob('meshes/*.stl') + glob('meshes/*.ply'))),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    # ROS client libraries are deliberately absent: colcon users get them from
    # their distro, pip users from requirements-ros.txt.
    install_requires=[
        'setuptools',
        'numpy>=1.26',
        'scipy>=1.11',
        'trimesh>=4.0',
        'embreex>=2.17',
        'numba>=0.59',
        'rosbags>=0.10',
        'matplotlib>=3.8',
        'scikit-learn>=1.4',
        'threadpoolctl>=3.1',
        'pydantic>=2.6',
        'PyYAML>=6.0',
    ],
    # Optional subsystems with heavy dependencies: pip install lidar_sim_ros[gnc]
    extras_require={
        'gnc': ['small_gicp>=1.0'],
        # lidar-sim campaign: the distributed engine and its progress bar (requirements-campaign.txt).
        'campaign': ['distributed>=2024.1', 'tqdm>=4.60'],
        # The closed GNC loop's dynamics (lidar_sim_ros.loop): Basilisk (requirements-loop.txt).
        'loop': ['bsk>=2.12,<2.13'],
        # Cepton's decoders, for the wire tests only (requirements-cepton.txt): proprietary,
        # installed by the user from PyPI, never imported by the package.
        'cepton': ['cepton-sdk2==2.1.4', 'cepton-sdk3==3.0.17.14.post1'],
    },
    zip_safe=True,
    maintainer='lidar_sim_ros developers',
    maintainer_email='lidar-sim@example.com',
    description='LiDAR simulator for rendezvous with space debris (Cepton Vista P-60 model).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'lidar-sim = lidar_sim_ros.cli:main',
            'lidar_sim_node = lidar_sim_ros.ros.lidar_sim_node:main',
            'target_pose_player = lidar_sim_ros.ros.target_pose_player:main',
            'pose_tracker = lidar_sim_ros.gnc.pose_tracker_node:main',
            'loop_dynamics = lidar_sim_ros.loop.dynamics_node:main',
            'loop_controller = lidar_sim_ros.loop.controller_node:main',
            'loop_cloud_gate = lidar_sim_ros.loop.cloud_gate_node:main',
        ],
    },
)
