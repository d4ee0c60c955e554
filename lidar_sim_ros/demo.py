"""``make demo``: the pose player and the node over real DDS, recorded, then drawn.

Starts ``target_pose_player`` and ``lidar_sim_node`` as two processes on a private
random ROS domain, records what they publish into a rosbag2 (MCAP) with
``ros.recorder.BagRecorder`` for a few seconds, stops them with SIGINT, and renders
the figures of the last recorded frame from the bag.

    python -m lidar_sim_ros.demo --out demo-output [--seconds 3]
"""
from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

from lidar_sim_ros.paths import config_path

STARTUP_TIMEOUT_S = 30.0
TOPICS_TIMEOUT_S = 10.0  # after the first cloud, how long to wait for the other topics to flow


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog='python -m lidar_sim_ros.demo', description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path('demo-output'), help='output directory')
    parser.add_argument('--seconds', type=float, default=3.0,
                        help='how long to record after the first cloud (s)')
    parser.add_argument('--params', type=Path, default=config_path('params.yaml'),
                        help='parameters file for both nodes')
    parser.add_argument('--domain-id', type=int, default=None,
                        help='ROS_DOMAIN_ID (default: a random private one)')
    return parser.parse_args(argv)


def start(module: str, ros_args: list[str], env: dict, log: Path) -> subprocess.Popen:
    with open(log, 'wb') as fh:
        return subprocess.Popen([sys.executable, '-m', module, '--ros-args', *ros_args],
                                env=env, stdout=fh, stderr=subprocess.STDOUT)


def stop(proc: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGINT (clean rclpy shutdown), then SIGKILL if it does not exit."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def remove_old_bag(bag: Path) -> None:
    """Replace the previous demo's bag, but never a directory that is not a bag."""
    if not bag.exists():
        return
    if not (bag / 'metadata.yaml').is_file() or any(
            p.suffix not in ('.mcap', '.yaml', '.db3') for p in bag.iterdir()):
        raise FileExistsError(f'{bag} exists and does not look like a previous demo bag; '
                              'remove it or choose another --out')
    shutil.rmtree(bag)


def record(bag: Path, seconds: float, procs: dict[str, subprocess.Popen], logs: dict[str, Path]) -> dict:
    """Record the node's topics until `seconds` after the first cloud; return counts per topic."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from lidar_sim_ros.io.bag import BagWriter
    from lidar_sim_ros.ros.recorder import BagRecorder

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('lidar_sim_demo_recorder', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        with BagWriter(bag) as writer:
            recorder = BagRecorder(node, writer, armed=False)
            spin_until_started(executor, lambda: recorder.seen['/lidar/points'] > 0, procs, logs,
                               STARTUP_TIMEOUT_S,
                               lambda: (f'no cloud on /lidar/points within {STARTUP_TIMEOUT_S:g} s; '
                                        f'see {logs["lidar_sim_node"]}'))
            # Discovery of the other topics may lag the first cloud: the bag starts once
            # every topic flows, so that no stretch of clouds lacks its poses.
            settle = time.monotonic() + TOPICS_TIMEOUT_S
            while not recorder.flowing and time.monotonic() < settle:
                executor.spin_once(timeout_sec=0.05)
            missing = [t for t, n in recorder.seen.items() if n == 0]
            if missing:
                print(f'demo: warning: nothing on {missing} yet; recording anyway', file=sys.stderr)
            # From now on by header stamp: clouds a lagging node publishes late belong
            # to a time before the poses in the bag.
            recorder.arm(since_ns=node.get_clock().now().nanoseconds)
            print(f'first cloud received; recording {seconds:g} s ...', flush=True)
            spin_for(executor, seconds)
            recorder.close()
            return dict(recorder.counts)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def spin_until_started(executor, started: Callable[[], bool], procs: dict[str, subprocess.Popen],
                       logs: dict[str, Path], timeout_s: float, timed_out: Callable[[], str]) -> None:
    """Spin ``executor`` until ``started()``. RuntimeError with the node's log if a node
    exits meanwhile, or with ``timed_out()`` after ``timeout_s`` (s)."""
    deadline = time.monotonic() + timeout_s
    while not started():
        executor.spin_once(timeout_sec=0.1)
        for name, proc in procs.items():
            if proc.poll() is not None:
                raise RuntimeError(f'{name} exited with {proc.returncode}:\n{logs[name].read_text()}')
        if time.monotonic() > deadline:
            raise RuntimeError(timed_out())


def spin_for(executor, seconds: float) -> None:
    """Spin ``executor`` for ``seconds`` (s) of wall time."""
    stop_at = time.monotonic() + seconds
    while time.monotonic() < stop_at:
        executor.spin_once(timeout_sec=0.05)


def run_nodes(commands: dict[str, tuple[str, list[str]]], out: Path, bag: Path, seconds: float,
              domain: int, recorder: Callable | None = None) -> tuple[dict, dict, dict[str, Path]]:
    """Start each node (module, ROS arguments) on the private ROS domain ``domain`` (this
    process joins it to record), its output in ``out/NAME.log``; record ``bag`` for
    ``seconds`` with ``recorder`` (default: ``record``); stop them all.

    Returns (counts per topic, exit codes, logs); a RuntimeError of the recording passes
    through after the nodes are stopped.
    """
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    env = {**os.environ, 'PYTHONUNBUFFERED': '1'}
    logs = {name: out / f'{name}.log' for name in commands}
    procs = {name: start(module, ros_args, env, logs[name])
             for name, (module, ros_args) in commands.items()}
    try:
        counts = (recorder or record)(bag, seconds, procs, logs)
    finally:
        codes = {name: stop(proc) for name, proc in procs.items()}
    return counts, codes, logs


def sensor_scan(params: Path):
    """The node's sensor shots and field of view, for the scan-pattern figure: from the
    ``sensor_file`` / ``scenario_file`` parameters in ``params`` ('' = package defaults).
    (None, None) if they cannot be loaded: the figure then shows the returns alone."""
    from lidar_sim_ros.core.config import ConfigError, load_sensor, read_yaml
    from lidar_sim_ros.core.scenario import load_scenario
    from lidar_sim_ros.core.scan import frame_shots
    from lidar_sim_ros.viz.figures import ScanLayout
    try:
        node = (read_yaml(params) or {}).get('lidar_sim_node', {}).get('ros__parameters', {})
        if node.get('sensor_file'):
            sensor_path = Path(node['sensor_file'])
            sensor = load_sensor(sensor_path)
        else:
            scenario = load_scenario(node.get('scenario_file') or config_path('scenario.yaml'))
            sensor, sensor_path = scenario.sensor, scenario.source
        return frame_shots(sensor, Path(sensor_path).resolve().parent), ScanLayout.of_sensor(sensor)
    except (ConfigError, OSError, AttributeError) as exc:
        print(f'demo: note: scan pattern without the sensor\'s shots ({exc})', file=sys.stderr)
        return None, None


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    bag = out / 'bag'
    try:
        remove_old_bag(bag)
    except FileExistsError as exc:
        print(f'demo: error: {exc}', file=sys.stderr)
        return 2
    domain = args.domain_id if args.domain_id is not None else random.randint(1, 101)
    names = ('lidar_sim_node', 'target_pose_player')
    print(f'ROS_DOMAIN_ID={domain}: starting {" and ".join(names)} with {args.params}', flush=True)
    # Reliable clouds so that the recording is lossless (best effort drops whole clouds
    # when two 350 kB messages a frame overrun the shared-memory transport).
    params = ['--params-file', str(args.params)]
    commands = {'lidar_sim_node': ('lidar_sim_ros.ros.lidar_sim_node',
                                   params + ['-p', 'qos_reliability:=reliable']),
                'target_pose_player': ('lidar_sim_ros.ros.target_pose_player', params)}
    try:
        counts, codes, logs = run_nodes(commands, out, bag, args.seconds, domain)
    except RuntimeError as exc:
        print(f'demo: error: {exc}', file=sys.stderr)
        return 1
    print('recorded ' + ', '.join(f'{n} on {t}' for t, n in counts.items()))
    print(f'bag: {bag}')
    print(f'logs: {logs["lidar_sim_node"]}, {logs["target_pose_player"]}')
    if any(codes.values()):
        print(f'demo: warning: exit codes {codes}', file=sys.stderr)
    if counts.get('/lidar/points', 0) == 0:
        print('demo: error: no cloud was recorded', file=sys.stderr)
        return 1
    try:
        from lidar_sim_ros.viz.figures import render_bag_figures
    except ImportError as exc:
        print(f'note: figures skipped, lidar_sim_ros.viz.figures is not available ({exc})')
        return 0
    shots, layout = sensor_scan(args.params)
    figures = render_bag_figures(bag, out, shots=shots, layout=layout)
    print('figures:')
    for path in figures:
        print(f'  {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
