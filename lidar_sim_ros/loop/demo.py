"""``make demo-loop``: the closed GNC loop over DDS, on the truth cloud and on the full error model.

For each cloud, on a private ROS domain, as separate processes: ``loop_dynamics``
(Basilisk, lock-step, the loop's /clock), ``lidar_sim_node`` (the loop config's
scenario: every effect), ``loop_cloud_gate`` (the range gate about the last estimate),
``pose_tracker`` on the gated cloud, and ``loop_controller``. This
process records the truth (/target/pose, /loop/chaser_pose), the estimates, the
commands and the guidance reference until the configured duration is simulated, then
scores both runs with ``metrics.loop_metrics``: ``loop.json`` (per cloud: hold_error_m,
delta_v_mps, min_range_m, est_trans_rms_m, est_axis_rms_deg, acquired_at_s, losses, ...,
and what happened: timing_mode, wall_s, timeouts, late_periods, refused_commands,
clipped_commands, acquisition_compute_s), ``loop.png``, an MCAP rosbag2 of each run
(``<cloud>/loop_bag``: /tf, poses, commands, clouds; ``loop.bag``) and a Foxglove layout
(``loop.foxglove.json``).

    python -m lidar_sim_ros.loop.demo --out demo-output/loop [--duration 150] [--clouds model_cloud]
"""
from __future__ import annotations

import argparse
import json
import random
import re
import struct
import sys
import time
from pathlib import Path

import numpy as np

from lidar_sim_ros.loop.config import load_loop_config
from lidar_sim_ros.paths import config_path

EPOCH_S = 100.0
CLOUD_TOPICS = {'truth_cloud': '/lidar/points_truth', 'model_cloud': '/lidar/points'}
STARTUP_TIMEOUT_S = 120.0
# The dynamics starts once every link of the loop has its subscriber (the poses, the
# attitude, the gated cloud, the estimate; the cloud topic is added per run): a first
# frame lost to discovery cost a 30 s start-up timeout and another run.
WAIT_FOR_SUBSCRIBERS = ['/target/pose', '/chaser/attitude', '/loop/points_gated', '/target/pose_estimate']


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='python -m lidar_sim_ros.loop.demo', description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path('demo-output/loop'))
    parser.add_argument('--config', type=Path, default=config_path('loop.yaml'))
    parser.add_argument('--duration', type=float, default=None, help='simulated seconds (default: the config)')
    parser.add_argument('--clouds', nargs='+', default=list(CLOUD_TOPICS), choices=list(CLOUD_TOPICS))
    parser.add_argument('--domain-id', type=int, default=None,
                        help='ROS_DOMAIN_ID of the run (default: a random one in 1-101, private)')
    parser.add_argument('--timing', choices=['lockstep', 'realtime'], default=None,
                        help="timing mode (default: the config's timing.mode)")
    parser.add_argument('--bag-cloud-every', type=int, default=5,
                        help='keep every N-th gated cloud in the bag (0: none; default 5: 2 Hz)')
    return parser.parse_args(argv)


def run_config(config_file: Path, duration_s: float | None, out: Path) -> Path:
    """The config to run: the given one, with --duration applied (written next to the outputs)."""
    if duration_s is None:
        return config_file
    import yaml
    from lidar_sim_ros.core.config import resolve
    data = yaml.safe_load(config_file.read_text())
    data['duration_s'] = float(duration_s)
    data['scenario'] = str(resolve(data.get('scenario', 'scenario_all_effects.yaml'), config_file.resolve().parent))
    path = out / 'loop_run.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def record(duration_s: float, procs, logs, cloud_every: int = 5) -> dict:
    """Spin a recorder until the clock reaches the end (or a node dies): arrays per topic."""
    import rclpy
    from geometry_msgs.msg import PointStamped, PoseStamped, WrenchStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import Header

    from lidar_sim_ros.demo import spin_until_started
    from lidar_sim_ros.io.pointcloud import stamp_to_ns

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('loop_demo_recorder', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    got = {k: [] for k in ('truth', 'estimate', 'command', 'reference', 'chaser', 'target', 'lost')}
    clouds: list[tuple[int, bytes]] = []
    seen_clouds = [0]
    clock = [0]

    def on_cloud(data: bytes) -> None:
        """Every ``cloud_every``-th gated cloud, its bytes as they came (for the bag)."""
        seen_clouds[0] += 1
        if cloud_every and (seen_clouds[0] - 1) % cloud_every == 0:
            sec, nsec = struct.unpack_from('<iI', data, 4)   # CDR: 4-byte encapsulation, then the header stamp
            clouds.append((sec * 1_000_000_000 + nsec, bytes(data)))

    def pose_row(m):
        p, q = m.pose.position, m.pose.orientation
        return [stamp_to_ns(m.header.stamp), p.x, p.y, p.z, q.x, q.y, q.z, q.w]

    def vec_row(stamp, v):
        return [stamp_to_ns(stamp), v.x, v.y, v.z]

    reliable = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(PoseStamped, '/target/pose', lambda m: got['truth'].append(pose_row(m)), reliable)
    node.create_subscription(PoseStamped, '/target/pose_estimate', lambda m: got['estimate'].append(pose_row(m)),
                             QoSProfile(depth=100))
    node.create_subscription(PoseStamped, '/loop/chaser_pose', lambda m: got['chaser'].append(pose_row(m)),
                             QoSProfile(depth=100))
    node.create_subscription(PoseStamped, '/loop/target_pose', lambda m: got['target'].append(pose_row(m)),
                             QoSProfile(depth=100))
    node.create_subscription(Header, '/target/pose_lost',
                             lambda m: got['lost'].append([stamp_to_ns(m.stamp)]), QoSProfile(depth=100))
    if cloud_every:
        node.create_subscription(PointCloud2, '/loop/points_gated', on_cloud,
                                 QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE), raw=True)
    node.create_subscription(WrenchStamped, '/chaser/force_command',
                             lambda m: got['command'].append(vec_row(m.header.stamp, m.wrench.force)),
                             QoSProfile(depth=100))
    node.create_subscription(PointStamped, '/loop/reference',
                             lambda m: got['reference'].append(vec_row(m.header.stamp, m.point)), QoSProfile(depth=100))
    node.create_subscription(Clock, '/clock', lambda m: clock.__setitem__(0, stamp_to_ns(m.clock)), QoSProfile(depth=10))
    end_ns = round((EPOCH_S + duration_s) * 1e9)
    try:
        spin_until_started(executor, lambda: clock[0] > 0, procs, logs, STARTUP_TIMEOUT_S,
                           lambda: f'no /clock within {STARTUP_TIMEOUT_S:g} s; see the logs in {logs}')
        print('the loop runs ...', flush=True)
        wall0, last_print = time.monotonic(), 0.0
        spin_until_started(executor, lambda: clock[0] >= end_ns, procs, logs, 20 * duration_s + 120,
                           lambda: f'the loop stalled at {clock[0] / 1e9 - EPOCH_S:.1f} s')
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:   # the last period's estimate and command
            executor.spin_once(timeout_sec=0.05)
        print(f'{duration_s:g} s simulated in {time.monotonic() - wall0:.0f} s', flush=True)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    out = {k: np.array(v, dtype=float).reshape(len(v), -1) if v else np.zeros((0, 8)) for k, v in got.items()}
    out['clouds'] = clouds
    return out


def score_recording(config, rec: dict) -> tuple[dict, dict]:
    """(metrics, series) of one DDS run from its recording."""
    from lidar_sim_ros.gnc.evaluate import tracking_errors
    from lidar_sim_ros.loop.metrics import loop_metrics
    period = config.control_period_s
    chaser, truth, est = rec['chaser'], rec['truth'], rec['estimate']
    t = chaser[:, 0] / 1e9 - EPOCH_S
    rho = chaser[:, 1:4]
    # Per period end: the truth range, the command and the reference given for that period.
    truth_t = np.round(truth[:, 0] / 1e9 - EPOCH_S, 6)
    rng = np.interp(t, truth_t, np.linalg.norm(truth[:, 1:4], axis=1))
    force, ref = np.zeros((len(t), 3)), np.full((len(t), 3), np.nan)
    for rows, dest in ((rec['command'], force), (rec['reference'], ref)):
        if len(rows):
            k = np.round((rows[:, 0] / 1e9 - EPOCH_S + 0.5 * period) / period).astype(int) - 1
            ok = (k >= 0) & (k < len(t))
            dest[k[ok]] = rows[ok, 1:4]
    ref = _fill(ref)
    errors = tracking_errors(est[:, 0].astype(np.int64), est[:, 1:4], est[:, 4:8],
                             truth[:, 0].astype(np.int64), truth[:, 1:4], truth[:, 4:8]) if len(est) else None
    est_t = est[:, 0] / 1e9 - EPOCH_S if len(est) else np.zeros(0)
    periods = set(np.round(est_t / period - 0.5).astype(int).tolist())
    lost_periods = [k for k in range(1, len(t)) if (k - 1) in periods and k not in periods]
    losses = len(lost_periods)
    trans = np.linalg.norm(errors.translation_m, axis=1) if errors is not None else np.zeros(0)
    axis = errors.axis_deg if errors is not None else np.zeros(0)
    metrics = loop_metrics(t, rho, ref, rng, force, period, config.chaser.mass_kg, config.guidance.hold_time_s,
                           est_t, trans, axis, losses)
    dv = np.cumsum(np.linalg.norm(force, axis=1)) * period / config.chaser.mass_kg
    series = {'t_s': t, 'rho_true_m': rho, 'ref_m': ref, 'range_m': rng, 'force_lvlh_n': force,
              'delta_v_mps': dv, 'est_t_s': (errors.t_s + truth_t[0]) if errors is not None else est_t,
              'est_trans_err_m': trans, 'est_los_err_m': errors.los_m if errors is not None else np.zeros(0),
              'loss_t_s': np.array([(k + 0.5) * period for k in lost_periods])}
    return metrics, series


def run_statistics(stats_file: Path, tracker_log: Path, period_s: float) -> dict:
    """What happened in a DDS run, for loop.json: the dynamics' counts (``timing.CommandGate``:
    timeouts, late periods, refused and clipped commands by cause, the timing mode run, the
    wall time) and the tracker's acquisitions' compute time (its log)."""
    stats = json.loads(stats_file.read_text()) if stats_file.is_file() else {}
    acquisitions = [float(x) for x in re.findall(r'hypotheses in ([0-9.]+) s', tracker_log.read_text())] \
        if tracker_log.is_file() else []
    periods = max(int(stats.get('periods', 0)), 1)
    late = stats.get('late_period_indices', [])
    return {
        'timing_mode': stats.get('timing_mode'),
        'wall_s': stats.get('wall_s'),
        'timeouts': stats.get('timeouts'),
        'startup_timeouts': stats.get('startup_timeouts'),
        'timeout_t_s': [round((k + 1) * period_s, 6) for k in stats.get('timeout_period_indices', [])],
        'late_periods': stats.get('late_periods'),
        'late_fraction': (len(late) / periods) if stats else None,
        'late_periods_per_10_s': _per_window(late, periods, round(10.0 / period_s)),
        'refused_commands': stats.get('refused_commands'),
        'clipped_commands': stats.get('clipped_commands'),
        'acquisitions': len(acquisitions),
        'acquisition_compute_s': round(sum(acquisitions), 3),
        'acquisition_compute_each_s': acquisitions,
        'statistics': 'loop_dynamics stats_file' if stats else f'missing: {stats_file} was not written',
    }


def _per_window(indices: list[int], periods: int, window: int) -> list[int]:
    """How many of the periods ``indices`` fall in each window of ``window`` periods."""
    counts = [0] * max(1, -(-periods // window))
    for k in indices:
        counts[min(k // window, len(counts) - 1)] += 1
    return counts


def write_bag(run_out: Path, rec: dict, config) -> Path:
    """The run as an MCAP rosbag2 (``loop.bag``: /tf, poses, commands, clouds), replacing
    one left by an earlier run."""
    import shutil
    from lidar_sim_ros.loop.bag import write_loop_bag
    path = run_out / 'loop_bag'
    if path.exists():
        shutil.rmtree(path)
    mount = config.chaser.mount
    write_loop_bag(path, rec, mount.position_m, mount.quat_xyzw)
    return path


def _fill(ref: np.ndarray) -> np.ndarray:
    """Periods without a reference (no estimate yet or that period) keep the previous one."""
    out = ref.copy()
    for i in range(len(out)):
        if np.isnan(out[i]).any():
            out[i] = out[i - 1] if i else np.nan
    first = np.flatnonzero(~np.isnan(out[:, 1]))
    if len(first):
        out[:first[0]] = out[first[0]]
    return out


def plot(series: dict, config, path: Path, stats: dict | None = None) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from lidar_sim_ros.loop.metrics import hold_windows
    fig, ax = plt.subplots(2, 2, figsize=(13, 8.5))
    colours = {'truth_cloud': 'tab:blue', 'model_cloud': 'tab:red'}
    for key, s in series.items():
        c = colours.get(key, 'k')
        ax[0, 0].plot(s['rho_true_m'][:, 1], s['rho_true_m'][:, 0], color=c, label=key)
        ax[0, 1].plot(s['t_s'], s['range_m'], color=c, label=key)
        ax[0, 1].plot(s['t_s'], -s['ref_m'][:, 1], '--', color=c, lw=0.8, label=f'{key} reference (V-bar)')
        marks = {'timeout': ((stats or {}).get(key) or {}).get('timeout_t_s') or [], 'loss': s.get('loss_t_s', [])}
        for what, style in (('timeout', ':'), ('loss', '-.')):
            for i, tm in enumerate(marks[what]):
                for a in (ax[0, 1], ax[1, 1]):
                    a.axvline(tm, color=c, ls=style, lw=0.8, label=f'{key} {what}' if i == 0 and a is ax[0, 1] else None)
        dwell = hold_windows(s['t_s'], s['ref_m'][:, 1], config.guidance.hold_time_s)
        ax[0, 1].fill_between(s['t_s'], 0, 1, where=dwell, color=c, alpha=0.12,
                              transform=ax[0, 1].get_xaxis_transform())
        ax[1, 0].plot(s['est_t_s'], 100 * s['est_trans_err_m'], '.', ms=2, color=c, label=f'{key} |error|')
        ax[1, 0].plot(s['est_t_s'], 100 * s['est_los_err_m'], '-', lw=0.6, color=c, alpha=0.6,
                      label=f'{key} along the line of sight')
        ax[1, 1].plot(s['t_s'], np.abs(s['force_lvlh_n']).max(axis=1), color=c, lw=0.6,
                      label=f'{key} largest axis |F|')
        twin = getattr(ax[1, 1], '_dv_twin', None) or ax[1, 1].twinx()
        ax[1, 1]._dv_twin = twin
        twin.plot(s['t_s'], s['delta_v_mps'], '--', color=c, label=f'{key} delta-v')
        twin.set_ylabel('cumulative delta-v (m/s), dashed')
    for r in config.guidance.hold_ranges_m:
        ax[0, 0].axvline(-r, color='grey', lw=0.5, ls=':')
        ax[0, 1].axhline(r, color='grey', lw=0.5, ls=':')
    ax[1, 1].axhline(config.chaser.thrust_limit_n, color='k', lw=0.8, ls='--', label='thrust limit (per axis)')
    ax[0, 0].set(xlabel='V-bar y (m)', ylabel='R-bar x (m)', title='approach in LVLH (target at origin)')
    ax[0, 1].set(xlabel='t (s)', ylabel='range lidar -> target centre (m)',
                 title='range; dashed: the reference; dotted: holds; shaded: hold dwells')
    ax[1, 0].set(xlabel='t (s)', ylabel='estimate - truth (cm)', title='pose estimate translation error')
    ax[1, 1].set(xlabel='t (s)', ylabel='commanded force, largest axis (N)',
                 title='thrust (limit dashed) and delta-v; timeouts dotted, losses dash-dot')
    for a in ax.flat:
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    from lidar_sim_ros.demo import run_nodes
    args = parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    cfg_file = run_config(args.config, args.duration, out)
    config, scenario = load_loop_config(cfg_file)
    domain = args.domain_id if args.domain_id is not None else random.randint(1, 101)
    results, series, stats = {}, {}, {}
    for key in args.clouds:
        # The tracker acquires from the cloud alone (its pose_topic is '' by default); with
        # acquire_from_cloud off it captures from the truth, as a reference.
        tracker_args = ['-p', 'points_topic:=/loop/points_gated', '-p', f'scenario_file:={scenario}',
                        '-p', 'use_sim_time:=true', '-p', 'points_reliable:=true']
        if not config.acquire_from_cloud:
            tracker_args += ['-p', 'pose_topic:=/target/pose']
        commands = {
            'loop_dynamics': ('lidar_sim_ros.loop.dynamics_node', [
                '-p', f'config_file:={cfg_file}', '-p', f'epoch_s:={EPOCH_S}', '-p', 'clock_delay_s:=0.01',
                '-p', f'stats_file:={(out / key / "dynamics_stats.json").resolve()}',
                '-p', f'timing_mode:={args.timing or config.timing.mode}',
                '-p', "wait_for_publishers:=['/chaser/force_command', '/target/pose_estimate', '/lidar/points']",
                '-p', f"wait_for_subscribers:={WAIT_FOR_SUBSCRIBERS + [CLOUD_TOPICS[key]]}"]),
            'lidar_sim_node': ('lidar_sim_ros.ros.lidar_sim_node', [
                '-p', f'scenario_file:={scenario}', '-p', 'use_sim_time:=true', '-p', 'publish_truth:=true',
                '-p', 'qos_reliability:=reliable', '-p', 'pose_qos_reliability:=reliable']),
            'loop_cloud_gate': ('lidar_sim_ros.loop.cloud_gate_node', [
                '-p', f'input_topic:={CLOUD_TOPICS[key]}', '-p', f'gate_m:={config.cloud_gate_m}',
                '-p', f'capture_gate_m:={config.capture_gate_m if config.acquire_from_cloud else 0.0}',
                '-p', f'period_s:={config.control_period_s}']),
            'pose_tracker': ('lidar_sim_ros.gnc.pose_tracker_node', tracker_args),
            'loop_controller': ('lidar_sim_ros.loop.controller_node', [
                '-p', f'config_file:={cfg_file}', '-p', 'use_sim_time:=true']),
        }
        run_out = out / key
        run_out.mkdir(exist_ok=True)
        (run_out / 'dynamics_stats.json').unlink(missing_ok=True)
        print(f'{key}: ROS_DOMAIN_ID={domain}: starting {", ".join(commands)}', flush=True)
        try:
            rec, codes, logs = run_nodes(commands, run_out, run_out / 'bag', config.duration_s, domain,
                                         lambda bag, seconds, procs, logs: record(seconds, procs, logs,
                                                                                  args.bag_cloud_every))
        except RuntimeError as exc:
            print(f'demo-loop: error: {exc}', file=sys.stderr)
            return 1
        results[key], series[key] = score_recording(config, rec)
        stats[key] = run_statistics(run_out / 'dynamics_stats.json', logs['pose_tracker'], config.control_period_s)
        results[key].update({k: v for k, v in stats[key].items() if k != 'acquisition_compute_each_s'})
        results[key]['bag'] = str(write_bag(run_out, rec, config))
        print(f'{key}: ' + ', '.join(f'{k} {v:.3g}' if isinstance(v, float) else f'{k} {v}'
                                     for k, v in results[key].items()), flush=True)
    modes = sorted({str(v.get('timing_mode')) for v in stats.values()})
    meta = {'config': str(cfg_file), 'scenario': str(scenario), 'duration_s': config.duration_s,
            'timing': modes[0] if len(modes) == 1 else modes,
            'capture': ('pose_tracker acquires from the cloud alone (gnc/acquire.py)'
                        if config.acquire_from_cloud else
                        'pose_tracker captures from /target/pose (truth): acquire_from_cloud is off'),
            'note': 'hold_error_m: RMS along-track (line of sight) error of the true chaser '
                    'position from the hold point over the hold dwells; est_*: estimate minus '
                    'truth at the estimate stamp; see docs/loop.md'}
    (out / 'loop.json').write_text(json.dumps({**results, 'meta': meta}, indent=2))
    plot(series, config, out / 'loop.png', stats)
    from lidar_sim_ros.loop.bag import write_foxglove_layout
    write_foxglove_layout(out / 'loop.foxglove.json')
    print(f'wrote {out / "loop.json"}, {out / "loop.png"}, the bags beside them (MCAP) and '
          f'{out / "loop.foxglove.json"} (a Foxglove layout)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
