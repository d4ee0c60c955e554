"""A loop run as a rosbag2 (MCAP) that plays back in 3D, and a Foxglove layout for it.

Written after the run from what ``loop.demo`` recorded, with ``rosbags``' Jazzy typestore
(``io.bag.BagWriter``): no ROS installation is needed, and ``tf2_msgs`` (no pip wheel for
Jazzy) is the typestore's. Topics:

- ``/tf`` (tf2_msgs/msg/TFMessage), once a period: lvlh -> chaser (the true relative
  position and attitude), chaser -> lidar (the mount, ``chaser.mount``), lvlh -> target;
- ``/target/pose`` (PoseStamped, lidar frame): the truth the simulator ran on (100 Hz);
- ``/target/pose_estimate`` (PoseStamped, lidar frame): the tracker's estimates;
- ``/chaser/force_command`` (WrenchStamped, lvlh), ``/loop/reference`` (PointStamped, lvlh);
- the tracker's cloud (PointCloud2, lidar frame), every ``cloud_every``-th frame, the
  bytes as they came over DDS.

The log time of every message is its header stamp.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lidar_sim_ros.io.bag import BagWriter
from lidar_sim_ros.io.pointcloud import ns_to_stamp

TF = 'tf2_msgs/msg/TFMessage'
WRENCH = 'geometry_msgs/msg/WrenchStamped'
POINT = 'geometry_msgs/msg/PointStamped'
CLOUD = 'sensor_msgs/msg/PointCloud2'


def _transform(types, parent: str, child: str, stamp_ns: int, p, q_xyzw):
    return types['geometry_msgs/msg/TransformStamped'](
        header=types['std_msgs/msg/Header'](stamp=ns_to_stamp(int(stamp_ns), types['builtin_interfaces/msg/Time']),
                                            frame_id=parent),
        child_frame_id=child,
        transform=types['geometry_msgs/msg/Transform'](
            translation=types['geometry_msgs/msg/Vector3'](x=float(p[0]), y=float(p[1]), z=float(p[2])),
            rotation=types['geometry_msgs/msg/Quaternion'](x=float(q_xyzw[0]), y=float(q_xyzw[1]),
                                                           z=float(q_xyzw[2]), w=float(q_xyzw[3]))))


def _header(types, stamp_ns: int, frame_id: str):
    return types['std_msgs/msg/Header'](stamp=ns_to_stamp(int(stamp_ns), types['builtin_interfaces/msg/Time']),
                                        frame_id=frame_id)


def _vec(types, v, name='geometry_msgs/msg/Vector3'):
    return types[name](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def write_loop_bag(path: Path, rec: dict, mount_position_m, mount_quat_xyzw, lidar_frame: str = 'lidar',
                   cloud_topic: str = '/loop/points_gated') -> dict:
    """Write the recording ``rec`` (rows per topic, stamps in ns as ``loop.demo.record``
    keeps them: 'chaser', 'target' (LVLH poses), 'truth', 'estimate' (lidar-frame poses),
    'command', 'reference' (vectors), 'clouds' ([(stamp_ns, cdr bytes)])) as an MCAP rosbag2;
    returns the message count per topic."""
    counts: dict[str, int] = {}
    with BagWriter(path, storage='mcap') as bag:
        types = bag.typestore.types

        def put(topic, msgtype, stamp_ns, msg):
            bag.write_raw(topic, msgtype, int(stamp_ns), bag.typestore.serialize_cdr(msg, msgtype))
            counts[topic] = counts.get(topic, 0) + 1

        targets = {int(r[0]): r for r in rec.get('target', [])}
        for row in rec['chaser']:
            stamp = int(row[0])
            tfs = [_transform(types, 'lvlh', 'chaser', stamp, row[1:4], row[4:8]),
                   _transform(types, 'chaser', lidar_frame, stamp, mount_position_m, mount_quat_xyzw)]
            if stamp in targets:
                tfs.append(_transform(types, 'lvlh', 'target', stamp, targets[stamp][1:4], targets[stamp][4:8]))
            put('/tf', TF, stamp, types[TF](transforms=tfs))
        for topic, key in (('/target/pose', 'truth'), ('/target/pose_estimate', 'estimate')):
            for row in rec[key]:
                bag.write_pose(topic, int(row[0]), lidar_frame, row[1:4], np.asarray(row[4:8]) / np.linalg.norm(row[4:8]))
                counts[topic] = counts.get(topic, 0) + 1
        for row in rec['command']:
            put('/chaser/force_command', WRENCH, row[0], types[WRENCH](
                header=_header(types, row[0], 'lvlh'),
                wrench=types['geometry_msgs/msg/Wrench'](force=_vec(types, row[1:4]), torque=_vec(types, [0, 0, 0]))))
        for row in rec['reference']:
            put('/loop/reference', POINT, row[0], types[POINT](
                header=_header(types, row[0], 'lvlh'), point=_vec(types, row[1:4], 'geometry_msgs/msg/Point')))
        for stamp, data in rec.get('clouds', []):
            bag.write_raw(cloud_topic, CLOUD, int(stamp), bytes(data))
            counts[cloud_topic] = counts.get(cloud_topic, 0) + 1
    return counts


def foxglove_layout(cloud_topic: str = '/loop/points_gated', lidar_frame: str = 'lidar') -> dict:
    """A Foxglove layout: the scene in 3D (LVLH fixed, the cloud, the frames and the estimate),
    the commanded force and the range over time."""
    scene = {
        'followMode': 'follow-none', 'followTf': 'lvlh',
        'scene': {'transforms': {'showLabel': True, 'axisScale': 2.0}},
        'cameraState': {'distance': 60, 'perspective': True, 'phi': 55, 'thetaOffset': 45,
                        'target': [0, -15, 0], 'targetOffset': [0, 0, 0], 'targetOrientation': [0, 0, 0, 1],
                        'fovy': 45, 'near': 0.5, 'far': 5000},
        'topics': {cloud_topic: {'visible': True, 'pointSize': 3, 'colorField': 'intensity',
                                 'colorMode': 'colormap', 'colorMap': 'turbo'},
                   '/target/pose_estimate': {'visible': True, 'type': 'axis', 'axisScale': 3},
                   '/target/pose': {'visible': False}},
        'transforms': {'frame:lvlh': {'visible': True}, 'frame:chaser': {'visible': True},
                       f'frame:{lidar_frame}': {'visible': True}, 'frame:target': {'visible': True}},
    }
    force = {'paths': [{'value': f'/chaser/force_command.wrench.force.{a}', 'enabled': True, 'timestampMethod': 'headerStamp'}
                       for a in 'xyz'], 'showLegend': True, 'title': 'commanded force (N, LVLH)'}
    reference = {'paths': [{'value': '/loop/reference.point.y', 'enabled': True, 'timestampMethod': 'headerStamp'},
                           {'value': '/tf.transforms[0].transform.translation.y', 'enabled': True,
                            'timestampMethod': 'receiveTime'}],
                 'showLegend': True, 'title': 'V-bar: reference and true chaser y (m)'}
    return {'configById': {'3D!loop': scene, 'Plot!force': force, 'Plot!vbar': reference},
            'globalVariables': {}, 'userNodes': {}, 'playbackConfig': {'speed': 1},
            'layout': {'first': '3D!loop', 'second': {'first': 'Plot!force', 'second': 'Plot!vbar',
                                                       'direction': 'column'},
                       'direction': 'row', 'splitPercentage': 65}}


def write_foxglove_layout(path: Path, **kwargs) -> None:
    Path(path).write_text(json.dumps(foxglove_layout(**kwargs), indent=2))
