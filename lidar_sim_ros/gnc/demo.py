"""``make demo-gnc``: navigation in the loop over real DDS, and what the LiDAR's errors cost it.

Starts, as separate processes on a private random ROS domain: ``target_pose_player``,
``lidar_sim_node`` (publishing the model cloud and the truth cloud) and two
``pose_tracker`` nodes, one on each cloud, each acquiring the target from its cloud
alone (nothing on the GNC side reads ``/target/pose``: only the scoring here does).
The poses and both trackers' estimates are recorded into a rosbag2 with
``ros.recorder.BagRecorder`` for a few seconds; then the estimates are scored against
the true pose: ``gnc.json`` and ``gnc_errors.png``.

    python -m lidar_sim_ros.gnc.demo --out demo-output/gnc [--seconds 10]
"""
from __future__ import annotations

import argparse
import random
import sys
from pathlib import Path

import numpy as np

from lidar_sim_ros.demo import remove_old_bag, run_nodes, spin_for, spin_until_started
from lidar_sim_ros.paths import config_path

STARTUP_TIMEOUT_S = 90.0  # a first start compiles the simulator's kernels (see make venv)
POSE = '/target/pose'
CLOUDS = {'model_cloud': '/lidar/points', 'truth_cloud': '/lidar/points_truth'}
ESTIMATES = {'model_cloud': '/target/pose_estimate', 'truth_cloud': '/target/pose_estimate_truth'}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog='python -m lidar_sim_ros.gnc.demo',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path('demo-output/gnc'), help='output directory')
    parser.add_argument('--seconds', type=float, default=10.0,
                        help='how long to record once both trackers publish (s)')
    parser.add_argument('--params', type=Path, default=config_path('params.yaml'),
                        help='parameters file of the simulator node and the pose player')
    parser.add_argument('--domain-id', type=int, default=None,
                        help='ROS_DOMAIN_ID (default: a random private one)')
    return parser.parse_args(argv)


def tracker_args(key: str) -> list[str]:
    return ['-r', f'__node:=pose_tracker_{key.split("_")[0]}', '-p', f'points_topic:={CLOUDS[key]}',
            '-p', f'estimate_topic:={ESTIMATES[key]}']


def record(bag: Path, seconds: float, procs: dict, logs: dict[str, Path]) -> dict[str, int]:
    """Record the truth and both estimates for ``seconds`` once all flow; count the clouds too."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from lidar_sim_ros.io.bag import BagWriter
    from lidar_sim_ros.ros.recorder import BagRecorder, TopicSpec, header_stamp_ns

    topics = [TopicSpec(t, PoseStamped, 'geometry_msgs/msg/PoseStamped') for t in (POSE, *ESTIMATES.values())]
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('lidar_sim_gnc_demo_recorder', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stamps: dict[str, set[int]] = {topic: set() for topic in CLOUDS.values()}

    def counter(topic):
        def count(raw: bytes) -> None:
            stamps[topic].add(header_stamp_ns(raw))
        return count

    # Seen, not recorded (raw bytes, never deserialised): how many clouds the node
    # published in the window, to tell whether each tracker kept up.
    for topic in CLOUDS.values():
        node.create_subscription(PointCloud2, topic, counter(topic),
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True)
    try:
        with BagWriter(bag) as writer:
            recorder = BagRecorder(node, writer, topics, armed=False)
            spin_until_started(
                executor, lambda: recorder.flowing, procs, logs, STARTUP_TIMEOUT_S,
                lambda: (f'nothing on {[t for t, n in recorder.seen.items() if n == 0]} within '
                         f'{STARTUP_TIMEOUT_S:g} s; see {out_logs(logs)}'))
            since_ns = node.get_clock().now().nanoseconds
            recorder.arm(since_ns)  # by header stamp: a lagging tracker's backlog stays out
            print(f'both trackers publish; recording {seconds:g} s ...', flush=True)
            spin_for(executor, seconds)
            until_ns = node.get_clock().now().nanoseconds
            recorder.close()
            return {**recorder.counts, **{t: published(s, since_ns, until_ns) for t, s in stamps.items()}}
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def published(stamps: set[int], since_ns: int, until_ns: int) -> int:
    """Clouds stamped in [since_ns, until_ns), from the header stamps (ns) of those received.

    The count subscription is best effort, so it may miss clouds; the stamps lie on a
    frame grid (step: the smallest gap between received stamps), so the grid counts
    the missed ones too.
    """
    got = np.array(sorted(stamps), dtype=np.int64)
    if len(got) < 2:
        return int(((got >= since_ns) & (got < until_ns)).sum())
    step = int(np.diff(got).min())
    phase = int(got[0]) % step
    first = -(-(since_ns - phase) // step)  # grid index of the first stamp >= since_ns
    last = -(-(until_ns - phase) // step)  # ... and of the first >= until_ns
    return max(0, last - first)


def out_logs(logs: dict[str, Path]) -> str:
    return ', '.join(str(p) for p in logs.values())


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    bag = out / 'bag'
    try:
        remove_old_bag(bag)
    except FileExistsError as exc:
        print(f'demo-gnc: error: {exc}', file=sys.stderr)
        return 2
    domain = args.domain_id if args.domain_id is not None else random.randint(1, 101)
    params = ['--params-file', str(args.params)]
    commands = {
        'target_pose_player': ('lidar_sim_ros.ros.target_pose_player', params),
        'lidar_sim_node': ('lidar_sim_ros.ros.lidar_sim_node', params + ['-p', 'publish_truth:=true']),
        'pose_tracker_model': ('lidar_sim_ros.gnc.pose_tracker_node', tracker_args('model_cloud')),
        'pose_tracker_truth': ('lidar_sim_ros.gnc.pose_tracker_node', tracker_args('truth_cloud')),
    }
    print(f'ROS_DOMAIN_ID={domain}: starting {", ".join(commands)}', flush=True)
    try:
        counts, codes, logs = run_nodes(commands, out, bag, args.seconds, domain, record)
    except RuntimeError as exc:
        print(f'demo-gnc: error: {exc}', file=sys.stderr)
        return 1
    print('recorded ' + ', '.join(f'{n} on {t}' for t, n in counts.items()))
    if any(codes.values()):
        print(f'demo-gnc: warning: exit codes {codes}', file=sys.stderr)

    from lidar_sim_ros.gnc.report import errors_from_bag, write_report
    errors = errors_from_bag(bag, POSE, ESTIMATES)
    details = {key: {'cloud_topic': CLOUDS[key], 'estimate_topic': ESTIMATES[key],
                     'clouds': counts[CLOUDS[key]]} for key in ESTIMATES}
    meta = {'seconds': args.seconds,
            'note': 'errors are estimate minus truth at the estimate stamp (cloud stamp + half '
                    'the scan); trans_los: along the line of sight, negative = toward the sensor; '
                    'axis: pointing of the body long axis; roll: about it. See docs/gnc.md.'}
    json_path, figure = write_report(errors, out, details, meta)
    for key, e in errors.items():
        s = e.summary()
        print(f'{key}: {s["frames"]} estimates for {counts[CLOUDS[key]]} clouds, translation RMS '
              f'{100 * s["trans_rms_m"]:.1f} cm (mean along the line of sight '
              f'{100 * s["trans_los_mean_m"]:+.1f} cm), rotation RMS {s["rot_rms_deg"]:.2f} deg '
              f'(axis {s["axis_rms_deg"]:.2f} deg, roll {s["roll_rms_deg"]:.2f} deg)')
    print(f'wrote {json_path} and {figure}; bag {bag}; logs {out_logs(logs)}')
    if any(len(e) == 0 for e in errors.values()):
        print('demo-gnc: error: a tracker published no estimate in the recording', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
