"""``lidar-sim compare``: measured bag vs model; where it fails and which effect is missing."""
from __future__ import annotations

import argparse
from pathlib import Path

from lidar_sim_ros.cli_types import positive_int
from lidar_sim_ros.io.bag import CLOUD_TOPIC, POSE_TOPIC, SUN_TOPIC


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'compare', help='compare measured point clouds with the model',
        description=(
            'Ray-matched comparison of a measured rosbag2 (PointCloud2 + target PoseStamped) '
            'with the model: writes DIR/summary.json, DIR/report.html, DIR/materials.yaml, '
            'DIR/effects.yaml (with --fit) and appends to DIR/../history.json.'))
    p.add_argument('bag', type=Path, metavar='BAG', help='recording: a rosbag2 directory (MCAP or sqlite3), a bare .mcap or .db3, a ROS 1 .bag, or a pcap of a Cepton sensor\'s packets (with --poses)')
    p.add_argument('--poses', type=Path, default=None, metavar='BAG_OR_CSV',
                   help='target poses apart from the recording (required for a pcap): a bag '
                        '(--pose-topic; its material names and sun too) or a CSV '
                        't_s,x_m,y_m,z_m,qx,qy,qz,qw (docs/real-data.md)')
    p.add_argument('--mesh', type=Path, required=True, metavar='OBJ',
                   help='target OBJ (+MTL) with one usemtl group per material')
    p.add_argument('--config', type=Path, default=None, metavar='SCENARIO',
                   help='scenario YAML giving sensor, materials and effects '
                        '(default: the package scenario)')
    p.add_argument('--effect', action='append', default=[], metavar='NAME_OR_MODULE:CLASS',
                   help='add an effect to the model: catalogue name, module:Class or '
                        'file.py:Class, optionally NAME={param: value}; repeatable')
    p.add_argument('--fit', action='store_true',
                   help='estimate the --effect parameters by maximum likelihood, print them '
                        'and write DIR/effects.yaml; refit each material\'s bias/sigma too')
    p.add_argument('--out', type=Path, required=True, metavar='DIR', help='output directory')
    p.add_argument('--cloud-topic', default=CLOUD_TOPIC, metavar='TOPIC',
                   help=f'PointCloud2 topic (default {CLOUD_TOPIC})')
    p.add_argument('--pose-topic', default=POSE_TOPIC, metavar='TOPIC',
                   help=f'PoseStamped topic of the target body pose (default {POSE_TOPIC})')
    p.add_argument('--sun-topic', default=None, metavar='TOPIC',
                   help=f'Vector3Stamped topic of the sun direction in the lidar frame (default '
                        f'{SUN_TOPIC} if the bag has it): fits the sunlight receiver factor '
                        'from false returns on sunlit vs shadowed surfaces')
    p.add_argument('--history', type=Path, default=None, metavar='FILE',
                   help='history file to append to (default DIR/../history.json)')
    p.add_argument('--max-points', type=positive_int, default=None, metavar='N',
                   help='analyse a random subset of at most this many points '
                        '(default 300000)')
    p.add_argument('--candidates', nargs='*', default=None, metavar='EFFECT',
                   help='effects to diagnose (default: the whole catalogue)')
    add_field_options(p)
    p.add_argument('--no-report', action='store_true', help='skip report.html')
    p.add_argument('--no-plan', action='store_true',
                   help='on a tie, skip simulating which recording would separate it '
                        '(plan.yaml)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar_sim_ros.compare.run import DEFAULT_MAX_POINTS, CompareOptions, run_compare
    if args.max_points is not None and args.max_points < 100:
        raise ValueError(f'--max-points must be at least 100, got {args.max_points}')
    result = run_compare(CompareOptions(
        bag=args.bag, mesh=args.mesh, out=args.out, config=args.config, effects=args.effect,
        fit=args.fit, cloud_topic=args.cloud_topic, pose_topic=args.pose_topic,
        sun_topic=args.sun_topic, history=args.history,
        max_points=args.max_points or DEFAULT_MAX_POINTS,
        candidates=args.candidates, report=not args.no_report, plan=not args.no_plan,
        intensity_field=args.intensity_field, time_field=args.time_field,
        laser_field=args.laser_field, poses=args.poses))
    print('\n'.join(field_lines(result.summary) + result.lines))
    dropped = dropped_line(result.summary.get('dropped') or {})
    if dropped:
        print(dropped)
    return 0


def add_field_options(p) -> None:
    """--intensity-field, --time-field, --laser-field (compare and calibrate)."""
    p.add_argument('--intensity-field', default=None, metavar='NAME',
                   help='the intensity field (default: intensity, else reflectivity)')
    p.add_argument('--time-field', default=None, metavar='NAME[,SUBSECONDS]',
                   help='per-point time: one field, or a seconds + sub-seconds pair of '
                        'integer fields, or none (default: timestamp_s,timestamp_us of the '
                        'Cepton driver, else t, time, timestamp, offset_time, ...)')
    p.add_argument('--laser-field', default=None, metavar='NAME',
                   help='the laser id field (default: ring, channel_id, channel, laser, ...)')


def field_lines(summary: dict) -> list[str]:
    """What every field of the recording was read as, and what the flags said."""
    from lidar_sim_ros.compare.recording.fields import saturation_line
    lines = list(summary.get('point_fields', {}).get('lines', []))
    flags = summary.get('point_flags') or {}
    sat = saturation_line(flags.get('saturation'))
    return lines + ([sat] if sat else [])


# Input the loader dropped as unusable (not the "no return" markers or the subsample):
# said on the terminal, not only in summary.json, so a cleaned-up answer is not mistaken
# for the bag's own.
_DROPPED = {'beyond_range': 'points beyond 10 km', 'bad_time': 'points with a non-finite time',
            'bad_poses': 'poses with a non-finite position or a non-unit quaternion'}


def dropped_line(dropped: dict) -> str | None:
    """'dropped as unusable: 3 poses with ...' or None when nothing was dropped."""
    parts = [f'{dropped[k]} {what}' for k, what in _DROPPED.items() if dropped.get(k)]
    return f'dropped as unusable: {", ".join(parts)} (see notes in summary.json)' if parts else None
