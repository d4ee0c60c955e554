"""``lidar-sim calibrate brdf | range-errors | scan``: lab data to config files."""
from __future__ import annotations

import argparse
import sys

from lidar_sim_ros.cli_types import positive_float, positive_int
from lidar_sim_ros.io.bag import CLOUD_TOPIC, POSE_TOPIC


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        'calibrate', help='fit config files to lab data (BRDF table, range errors, scan pattern)',
        description='Calibrate the simulator from lab data; each calibration writes a config '
                    'YAML, prints its fit quality and can save a PNG of data vs fit.')
    sub = parser.add_subparsers(dest='calibration', required=True, metavar='CALIBRATION')

    p = sub.add_parser('brdf', help='goniometer BRDF table -> kd, ks, n (modified Phong)',
                       description='Fit kd, ks, n of the modified Phong BRDF (paper Eq. 5) per '
                                   'material, on the BRDF and on its logarithm, and write a '
                                   'materials YAML.')
    p.add_argument('csv', metavar='CSV', help='columns theta_in, phi_in, theta_out, phi_out '
                   '[deg], brdf [1/sr], optionally material')
    p.add_argument('--out', required=True, metavar='YAML', help='materials YAML to write')
    p.add_argument('--material', metavar='NAME',
                   help='material of a table without a material column, or the one to fit')
    p.add_argument('--materials', metavar='YAML',
                   help='materials YAML to start from (default: the package config/materials.yaml)')
    p.add_argument('--fit', choices=('log', 'linear'), default='log',
                   help='which least-squares fit to write (default: log; both are reported)')
    p.add_argument('--figure', metavar='PNG', help='data vs both fits, residual vs theta_out')
    p.add_argument('--noise-rel', type=positive_float, default=0.05, metavar='FRACTION',
                   help='relative noise of one reading, for the anisotropy test when the table '
                        'has no repeated readings (default 0.05)')
    p.add_argument('--template', metavar='NAME', help='material whose bias_m/sigma_m a new '
                   'material copies (default: the first one)')
    p.set_defaults(func=_brdf)

    p = sub.add_parser('range-errors', help='static-target bag -> bias_m, sigma_m per material',
                       description='Ray-match every point of a static target at known pose, '
                                   'measure bias and sigma per material and distance, test '
                                   'whether they depend on distance, write a materials YAML.')
    p.add_argument('bag', metavar='BAG', nargs='+',
                   help='rosbag2 with point clouds and /target/pose (several: e.g. one per distance), '
                        "or a pcap of a Cepton sensor's packets (with --poses)")
    p.add_argument('--poses', default=None, metavar='BAG_OR_CSV',
                   help='target poses apart from the recordings (required for a pcap): a bag '
                        '(--pose-topic) or a CSV t_s,x_m,y_m,z_m,qx,qy,qz,qw; used for every '
                        'recording given')
    p.add_argument('--mesh', required=True, metavar='OBJ', help='target mesh (usemtl = material)')
    p.add_argument('--config', metavar='SCENARIO',
                   help='scenario YAML naming the materials file (default: config/scenario.yaml)')
    p.add_argument('--materials', metavar='YAML',
                   help='materials YAML to start from (default: the one the scenario names)')
    p.add_argument('--out', required=True, metavar='YAML', help='materials YAML to write')
    p.add_argument('--figure', metavar='PNG', help='bias and sigma per material vs distance')
    p.add_argument('--gate-m', type=positive_float, default=0.5,
                   help='drop points whose error is farther than this from the median (default 0.5)')
    p.add_argument('--bin-m', type=positive_float, default=1.0, help='frames whose target distances '
                   'differ by less than this share a distance bin (default 1.0)')
    p.add_argument('--min-points', type=positive_int, default=30,
                   help='ignore material/distance bins with fewer points (default 30)')
    p.add_argument('--tolerance-m', type=positive_float, default=0.01, help='smallest bias change over '
                   'the distances that counts as a distance dependence (default 0.01)')
    p.add_argument('--sigma-tolerance-m', type=positive_float, default=0.005,
                   help='the same for sigma (default 0.005)')
    p.add_argument('--cloud-topic', default=CLOUD_TOPIC)
    p.add_argument('--pose-topic', default=POSE_TOPIC)
    from lidar_sim_ros.compare.command import add_field_options
    add_field_options(p)
    p.set_defaults(func=_range_errors)

    p = sub.add_parser('scan', help='measured point times and angles -> Lissajous or Risley scan config',
                       description='Fit per-laser Lissajous frequencies, phases, amplitudes and '
                                   'centres (a lissajous_array --sensor) or the two prisms\' rates, '
                                   'deviations and phases (a risley --sensor) to measured points '
                                   '(x, y, z, t and optionally ring) and write a sensor YAML.')
    p.add_argument('bag', metavar='BAG', help='rosbag2 with point clouds')
    p.add_argument('--out', required=True, metavar='SENSOR_YAML', help='sensor YAML to write')
    p.add_argument('--sensor', metavar='YAML', help='sensor YAML to start from (default: the '
                   'package config/cepton_vista_p60.yaml)')
    p.add_argument('--figure', metavar='PNG', help='measured vs fitted pattern')
    p.add_argument('--cloud-topic', default=CLOUD_TOPIC)
    p.add_argument('--time-field', default=None, metavar='NAME[,SUBSECONDS]',
                   help='per-point time since the frame stamp (default: t, ..., or the '
                        'Cepton timestamp_s,timestamp_us)')
    p.add_argument('--laser-field', default=None, metavar='NAME',
                   help='the laser id field (default: ring, channel_id, ...)')
    p.set_defaults(func=_scan)


def _finish(report: str, warnings: list[str], out, figure) -> int:
    print(report)
    for w in warnings:
        print(f'warning: {w}', file=sys.stderr)
    print(f'wrote {out}')
    if figure:
        print(f'wrote {figure}')
    return 0


def _brdf(args: argparse.Namespace) -> int:
    from lidar_sim_ros.calibrate.brdf import run_brdf
    res = run_brdf(args.csv, args.out, args.materials, args.material, args.fit, args.figure,
                   args.noise_rel, args.template)
    return _finish(res.report, res.warnings, res.out, args.figure)


def _range_errors(args: argparse.Namespace) -> int:
    from lidar_sim_ros.calibrate.range_errors import run_range_errors
    cal = run_range_errors(args.bag, args.mesh, args.out, args.config, args.figure, args.gate_m,
                           args.bin_m, args.min_points, args.tolerance_m, args.sigma_tolerance_m,
                           args.cloud_topic, args.pose_topic, args.materials,
                           {'intensity_field': args.intensity_field,
                            'time_field': args.time_field, 'laser_field': args.laser_field},
                           poses_from=args.poses)
    return _finish(cal.report, cal.warnings, cal.out, args.figure)


def _scan(args: argparse.Namespace) -> int:
    from lidar_sim_ros.calibrate.scan_pattern import run_scan
    cal = run_scan(args.bag, args.out, args.sensor, args.figure, args.cloud_topic,
                   {'time_field': args.time_field, 'laser_field': args.laser_field})
    return _finish(cal.report, cal.warnings, cal.out, args.figure)
