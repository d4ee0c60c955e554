"""``lidar-sim simulate``: the core pipeline straight into a rosbag2 and the paper's figures.

No ROS graph is involved: the scenario's closed-form trajectory drives
``Simulator.simulate_frame`` frame after frame and every message goes into the
bag through ``io.bag.BagWriter``.

Time: scenario time ``t`` [s] is written as ROS time ``epoch_s + t`` (default
epoch 1.7e9 s, 2023-11-14T22:13:20Z), because a stamp of zero confuses tools that
treat it as "unset". Cloud and pose stamps use the same clock, so a consumer of
the bag needs nothing but the stamps: cloud stamp = frame start, point ``t`` =
seconds since that stamp, pose stamps = the times the poses hold.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from lidar_sim_ros.core.scenario import Scenario, load_scenario
from lidar_sim_ros.core.driver_layout import OutputLayout
from lidar_sim_ros.core.effects import effect_from_spec
from lidar_sim_ros.core.pipeline import Frame, Simulator
from lidar_sim_ros.core.pose import PoseSource, ScenarioTrajectory
from lidar_sim_ros.core.scan import varies_by_frame
from lidar_sim_ros.io.bag import CLOUD_TOPIC, MATERIAL_NAMES_TOPIC, POSE_TOPIC, SUN_TOPIC, BagWriter
from lidar_sim_ros.cli_types import epoch_seconds, finite_seconds, float_in, positive_int
from lidar_sim_ros.io import cepton
from lidar_sim_ros.io.pointcloud import POINT_DTYPE, frame_points

TRUTH_TOPIC = '/lidar/points_truth'
DEFAULT_EPOCH_S = 1_700_000_000.0
POSES_PER_FRAME = 10
NS_PER_S = 1_000_000_000
MAX_OUTPUT_GB = 20.0
"""``lidar-sim simulate`` refuses a run whose bag may exceed this (GB, 1e9 bytes) unless
``--max-output-gb`` raises it: ``--frames 1000000000`` started writing ~200 TB."""
ANNOUNCE_BYTES = 1e9       # a run that may write this much says its estimate before it starts
_MESSAGE_BYTES = 256     # header, field list, CDR and storage framing of one message, at most


@dataclass(frozen=True)
class OfflineResult:
    """What ``simulate_to_bag`` wrote: the bag, the figures and per-frame statistics."""

    bag_path: Path
    figure_paths: list[Path]
    frame_stamps_ns: list[int]
    frame_stats: list[dict] = field(default_factory=list)


def to_stamp_ns(t_s: float | np.ndarray, epoch_s: float = DEFAULT_EPOCH_S) -> np.ndarray:
    """Scenario time [s] -> ROS stamp [ns] (int64): epoch plus t, rounded to the nanosecond."""
    return np.int64(round(epoch_s * NS_PER_S)) + np.rint(
        np.asarray(t_s, dtype=float) * NS_PER_S).astype(np.int64)


def _check_stamp_range(first_s: float, last_s: float) -> None:
    """Every stamp must fit builtin_interfaces/Time (int32 seconds, not negative here);
    a frame rate of 1e-9 Hz ended in a struct.error from the bag writer."""
    if not (0.0 <= first_s and last_s < 2**31):
        raise ValueError(f'frames would be stamped from {first_s:.6g} s to {last_s:.6g} s ROS time: '
                         'stamps must lie in [0, 2**31) s (check --epoch-s, --start-s, --frames and '
                         'the frame rate)')


def _first_frame_index(start_s: float, period_s: float, own_shots_per_frame: bool) -> int:
    """The index k of the frame starting at ``start_s``: round(start_s / period). A scan
    whose frames each have their own shots (a rosette) draws frame k's from the prisms at
    k x period + t, so its run must start on that grid: a start off it (0.05 s at 10 Hz)
    would have put every shot a fixed prism rotation away from the rosette at its own time."""
    k = int(round(start_s / period_s))
    if own_shots_per_frame and abs(start_s - k * period_s) > 1e-9 + 4 * np.spacing(abs(start_s)):
        raise ValueError(f'--start-s {start_s:g}: not a whole number of frame periods ({period_s:g} s): '
                         "this sensor's shots turn with its prisms on the frame clock (frame k "
                         f'from k x the period); start on it, e.g. --start-s {k * period_s:g}')
    return k


def simulate_to_bag(scenario: Scenario | str | Path, out_dir: str | Path, frames: int,
                    start_s: float = 0.0, storage: str = 'mcap', effects: Sequence[str] = (),
                    figures: bool = True, epoch_s: float = DEFAULT_EPOCH_S,
                    poses_per_frame: int = POSES_PER_FRAME, simulator: Simulator | None = None,
                    pose_source: PoseSource | None = None,
                    on_frame: Callable[[Frame], None] | None = None,
                    layout: OutputLayout | None = None,
                    pcap: str | Path | None = None, threads: int = 1) -> OfflineResult:
    """Simulate ``frames`` frames from scenario time ``start_s`` into ``out_dir/bag``.

    Topics: /lidar/points (detected returns), /lidar/points_truth (every hit, no
    noise or dropouts), /target/pose (target body pose in the lidar frame,
    ``poses_per_frame`` evenly spaced samples per frame plus one at the end of the
    last frame), /lidar/material_names (JSON list, once), and with a sun in the scenario
    /sun/direction (Vector3Stamped toward the sun, lidar frame, one per frame start).
    Figures of the last frame and of the whole run go to ``out_dir/figures`` (plus
    ``sunlight.png`` with a sun), drawn from the bag. Raises FileExistsError if the bag already exists.
    ``simulator`` / ``pose_source`` replace the scenario's own (campaigns reuse a
    worker's mesh and move the sensor mount); ``on_frame`` sees every simulated frame.
    ``layout`` (``core/driver_layout.py``): the Cepton driver's point layout, topic
    (``/cepton_pcl2``) and frame (``cepton3``) instead of ours; the truth stays ours.
    ``pcap``: also write the frames as a Cepton sensor sends them (STDV packets over
    UDP to port 8808, ``io/cepton_wire.py``) into this pcap file, capture time = packet
    time (the bag's clock); it must not exist yet.
    ``threads``: threads each frame's raycast is split over (the frames do not depend on it).
    """
    layout = layout or OutputLayout()
    if frames < 1:
        raise ValueError(f'frames must be >= 1, got {frames}')
    if poses_per_frame < 1:
        raise ValueError(f'poses_per_frame must be >= 1, got {poses_per_frame}')
    out = Path(out_dir)
    bag_path = out / 'bag'
    if bag_path.exists():
        raise FileExistsError(f'{bag_path} already exists; choose another --out or remove it')
    if pcap is not None and Path(pcap).exists():
        raise FileExistsError(f'{pcap} already exists; choose another --pcap or remove it')
    if pcap is not None and bag_path.resolve() in (Path(pcap).resolve(), *Path(pcap).resolve().parents):
        raise ValueError(f'--pcap {pcap} is the bag folder {bag_path} or inside it; write it '
                         'beside the bag (e.g. DIR/cepton.pcap)')
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    sim = simulator if simulator is not None else Simulator.from_scenario(
        scenario, extra_effects=[effect_from_spec(e) for e in effects], threads=threads)
    trajectory = pose_source if pose_source is not None else ScenarioTrajectory.from_config(
        scenario.config)
    frame_id = layout.frame(scenario.config.frame_id)
    cloud_topic = layout.cloud_topic(CLOUD_TOPIC)
    period = sim.frame_period_s
    _check_stamp_range(epoch_s + start_s, epoch_s + start_s + frames * period)
    first_index = _first_frame_index(start_s, period, varies_by_frame(sim.sensor))

    out.mkdir(parents=True, exist_ok=True)
    stamps, stats, last = [], [], None
    # The pcap first: a path that cannot be written stops before the bag exists (which
    # would refuse the corrected command as 'already exists').
    with _WireOut(pcap) as wire, BagWriter(bag_path, storage=storage) as bag:
        bag.write_material_names(MATERIAL_NAMES_TOPIC, int(to_stamp_ns(start_s, epoch_s)),
                                 scenario.materials.names)
        for i in range(frames):
            frame_start = start_s + i * period
            # Poses first: a live consumer would need them before it could use the cloud.
            last_frame = i == frames - 1
            k = np.arange(poses_per_frame + (1 if last_frame else 0))
            _write_poses(bag, trajectory, frame_start + k * (period / poses_per_frame),
                         frame_id, epoch_s)
            last = sim.simulate_frame(frame_start, trajectory, first_index + i)
            if on_frame is not None:
                on_frame(last)
            stamp = int(to_stamp_ns(frame_start, epoch_s))
            if sim.sun is not None:
                bag.write_vector3(SUN_TOPIC, stamp, frame_id,
                                  sim.sun.at(np.array([frame_start])).sun_direction[0])
            bag.write_cloud(cloud_topic, layout.points(last, sim, stamp), stamp, frame_id)
            bag.write_cloud(TRUTH_TOPIC, frame_points(last, truth=True), stamp, frame_id)
            wire.write(last, sim, stamp)
            stamps.append(stamp)
            stats.append(last.stats)

    figure_paths: list[Path] = []
    if figures:
        # Drawn from the bag just written, as `make demo` draws from its recording.
        from lidar_sim_ros.viz.figures import ScanLayout, render_run
        from lidar_sim_ros.viz.run import frame_label, read_run
        run = read_run(bag_path)
        figure_paths = render_run(run, out / 'figures', scenario.materials.names,
                                  shots=sim.shots_of_frame(last.index),
                                  layout=ScanLayout.of_sensor(sim.sensor))
        if sim.sun is not None:
            label = frame_label(run, len(run.clouds) - 1)
            figure_paths.append(_sunlight_figure(sim, last, trajectory, out / 'figures', label))
    return OfflineResult(bag_path, figure_paths, stamps, stats)


class _WireOut:
    """The optional pcap of ``simulate --pcap``: each frame's STDV packets, in order."""

    def __init__(self, path: str | Path | None):
        self.writer, self.path = None, path
        if path is not None:
            from lidar_sim_ros.io.cepton_wire import WireStream
            from lidar_sim_ros.io.pcap import PcapWriter
            self.writer, self.state = PcapWriter(path), WireStream()

    def __enter__(self) -> '_WireOut':
        """Opens the pcap (and its folder); ValueError naming it when that fails (a
        PermissionError was a traceback)."""
        if self.writer is not None:
            try:
                Path(self.path).parent.mkdir(parents=True, exist_ok=True)
                self.writer.__enter__()
            except OSError as exc:
                raise ValueError(f'--pcap {self.path}: cannot write it '
                                 f'({exc.strerror or exc}: {exc.filename or self.path})') from None
        return self

    def write(self, frame: Frame, sim: Simulator, stamp_ns: int) -> None:
        if self.writer is not None:
            from lidar_sim_ros.core.driver_layout import wire_packets
            for pkt in wire_packets(frame, sim, stamp_ns, self.state):
                self.writer.write(pkt.t_us, pkt.payload)

    def __exit__(self, *exc) -> None:
        if self.writer is not None:
            self.writer.__exit__(*exc)


def _sunlight_figure(sim: Simulator, frame, trajectory, out_dir: Path, label: str) -> Path:
    """Background power and false returns of ``frame`` painted on the target (sunlight.png)."""
    from lidar_sim_ros.core.effects.sunlight import Sunlight, background_of
    from lidar_sim_ros.core.pipeline import NO_MATERIAL
    from lidar_sim_ros.viz.figures import render_sunlight_figure
    shots = sim.shots
    pred = sim.predict(frame.stamp_s + shots.t_s, sim.directions, trajectory, shots.t_s)
    scale = next((e.params.background_scale for e in sim.effects if isinstance(e, Sunlight)), 1.0)
    bg = background_of(pred.ctx, scale)
    false = frame.material == NO_MATERIAL
    az, el = np.degrees(shots.az_rad), np.degrees(shots.el_rad)
    f_az = np.degrees(np.arctan2(frame.xyz_m[false, 1], frame.xyz_m[false, 0]))
    f_el = np.degrees(np.arcsin(np.clip(frame.xyz_m[false, 2] / frame.range_m[false], -1, 1)))
    p_false = np.where(bg.blinded, 1.0, bg.false_return_probability)
    return render_sunlight_figure(az, el, pred.ctx.hit, bg.power_w, bg.sunlit, p_false, f_az, f_el,
                                  out_dir / 'sunlight.png', label)


def output_bound_bytes(sim: Simulator, layout: OutputLayout, frames: int,
                       poses_per_frame: int = POSES_PER_FRAME) -> int:
    """An upper bound (bytes) of the bag ``simulate_to_bag`` writes: every shot a point
    (``max_returns`` of them on the cloud topic in the layout's point size, one on the
    truth topic), plus the poses, the sun direction and each message's framing. (For a
    receiver in mode ``all``, 8 returns a shot: an estimate, not a bound.)"""
    point_b = POINT_DTYPE.itemsize
    if layout.point_layout == 'cepton':
        point_b = (cepton.SDK3_POLAR_DTYPE if layout.polar_fields else cepton.SDK3_DTYPE).itemsize
    shots = len(sim.shots)
    receiver = sim.sensor.detection.returns
    # mode 'all' reports every return a shot makes; 8 a shot (the most max_returns allows)
    # stands in for them: the bound of that receiver is an estimate.
    returns = receiver.max_returns if receiver.mode != 'all' else max(receiver.max_returns, 8)
    per_frame = (shots * (returns * point_b + POINT_DTYPE.itemsize)
                 + (poses_per_frame + 4) * _MESSAGE_BYTES)
    return int(frames) * per_frame + _MESSAGE_BYTES


def _size(n_bytes: float) -> str:
    """'1.35 MB', '205 TB': decimal units."""
    for unit, scale in (('PB', 1e15), ('TB', 1e12), ('GB', 1e9), ('MB', 1e6), ('kB', 1e3)):
        if n_bytes >= scale:
            return f'{n_bytes / scale:.3g} {unit}'
    return f'{int(n_bytes)} B'


def check_output_size(sim: Simulator, layout: OutputLayout, frames: int, out_dir: Path,
                      max_output_gb: float) -> str:
    """The terminal's estimate line; ValueError when the bound exceeds ``max_output_gb``
    (named with the frames, the size a frame and the option that raises the limit)."""
    bound = output_bound_bytes(sim, layout, frames)
    per_frame = _size(bound / frames)
    if bound > max_output_gb * 1e9:
        raise ValueError(f'--frames {frames}: the bag may reach {_size(bound)} ({per_frame} a '
                         f'frame, {len(sim.shots)} shots each a point), above --max-output-gb '
                         f'{max_output_gb:g}; write fewer frames or raise the limit')
    line = f'estimate: the bag takes at most {_size(bound)} ({per_frame} a frame, every shot a point)'
    where = next((p for p in (Path(out_dir).resolve(), *Path(out_dir).resolve().parents)
                  if p.exists()), None)
    free = shutil.disk_usage(where).free if where is not None else None
    if free is not None and bound > free:
        line += f'; only {_size(free)} free on {where}'
    return line


def _write_poses(bag: BagWriter, trajectory: PoseSource, t_s: np.ndarray,
                 frame_id: str, epoch_s: float) -> None:
    poses = trajectory.at(t_s)
    quat = poses.rotation.as_quat()
    for stamp, pos, q in zip(to_stamp_ns(t_s, epoch_s), poses.position_m, quat):
        bag.write_pose(POSE_TOPIC, int(stamp), frame_id, pos, q)


# ----------------------------------------------------------------------- CLI
def register(subparsers) -> None:
    p = subparsers.add_parser(
        'simulate', help='simulate a scenario into a rosbag2 and figures',
        description='Run the simulator on a scenario and write DIR/bag (rosbag2) with '
                    f'{CLOUD_TOPIC}, {TRUTH_TOPIC}, {POSE_TOPIC} and {MATERIAL_NAMES_TOPIC}, '
                    'plus PNG figures of the last frame in DIR/figures.')
    p.add_argument('scenario', type=Path, help='scenario YAML (e.g. config/scenario.yaml)')
    p.add_argument('--frames', type=positive_int, required=True, help='number of frames')
    p.add_argument('--max-output-gb', type=float_in(0.0, 1e6, 'a size in GB', open_low=True),
                   default=MAX_OUTPUT_GB, metavar='GB',
                   help='refuse a run whose bag may exceed this many GB (default %(default)g; '
                        'the estimate assumes every shot a point)')
    p.add_argument('--out', type=Path, required=True, metavar='DIR',
                   help='output directory; DIR/bag must not exist yet')
    p.add_argument('--start-s', type=finite_seconds, default=0.0, metavar='S',
                   help='scenario time of the first frame start [s] (default 0)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage plugin (default mcap)')
    p.add_argument('--epoch-s', type=epoch_seconds, default=DEFAULT_EPOCH_S, metavar='S',
                   help='ROS time of scenario time 0 [s] (default %(default).0f)')
    p.add_argument('--no-figures', action='store_true', help='write the bag only')
    p.add_argument('--effect', action='append', default=[], metavar='NAME[=PARAMS]',
                   help='add an effect to the scenario\'s list, e.g. --effect range_walk or '
                        '--effect "range_walk={k_m: 0.02}"; repeatable')
    p.add_argument('--point-layout', choices=('native', 'cepton'), default='native',
                   help='native: our layout on /lidar/points; cepton: the Cepton SDK3 '
                        "driver's layout (docs/real-data.md) on /cepton_pcl2, frame cepton3")
    p.add_argument('--cloud-topic', default=None, metavar='TOPIC',
                   help='cloud topic (default: the layout\'s)')
    p.add_argument('--frame-id', default=None, metavar='FRAME',
                   help='frame of clouds and poses (default: the layout\'s; native: the '
                        'scenario\'s frame_id)')
    p.add_argument('--no-return-points', action='store_true',
                   help='cepton layout: one NO_RETURN point per shot that returned nothing')
    p.add_argument('--polar-fields', action='store_true',
                   help="cepton layout: the driver's optional azimuth, elevation, range fields")
    p.add_argument('--pcap', type=Path, default=None, metavar='FILE',
                   help='also write the frames as a Cepton sensor sends them (STDV packets, '
                        'UDP port 8808) into this pcap file (docs/real-data.md)')
    p.add_argument('--threads', type=positive_int, default=None, metavar='N',
                   help='threads a frame\'s raycast is split over (default: the CPUs this '
                        'process may use; frames are the same for any N)')
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    layout = OutputLayout(point_layout=args.point_layout, topic=args.cloud_topic,
                          frame_id=args.frame_id, no_return_points=args.no_return_points,
                          polar_fields=args.polar_fields)
    scenario = load_scenario(args.scenario)
    sim = Simulator.from_scenario(scenario, extra_effects=[effect_from_spec(e) for e in args.effect],
                                  threads=args.threads or len(os.sched_getaffinity(0)))
    estimate = check_output_size(sim, layout, args.frames, args.out, args.max_output_gb)
    if output_bound_bytes(sim, layout, args.frames) >= ANNOUNCE_BYTES:
        print(estimate, file=sys.stderr, flush=True)
    result = simulate_to_bag(scenario, args.out, args.frames, start_s=args.start_s,
                             storage=args.storage, simulator=sim,
                             figures=not args.no_figures, epoch_s=args.epoch_s, layout=layout,
                             pcap=args.pcap)
    points = sum(s.get('detected', 0) for s in result.frame_stats)
    print(f'bag: {result.bag_path}  ({len(result.frame_stamps_ns)} frames, {points} points)')
    summary = multipath_summary(result.frame_stats)
    if summary:
        print(summary)
    if args.pcap is not None:
        print(f'pcap: {args.pcap}  (Cepton STDV packets, UDP port 8808)')
    for path in result.figure_paths:
        print(f'figure: {path}')
    return 0


def multipath_summary(frame_stats: list[dict]) -> str | None:
    """One line on the multipath ghosts of a run (frames' ``multipath*`` stats): their count
    and share of the points, the mirror materials they came from, and how far behind their
    mirror surface they lie (|AB|, m). None when multipath was off."""
    if not any('multipath' in s for s in frame_stats):
        return None
    ghosts = sum(s.get('multipath', 0) for s in frame_stats)
    points = sum(s.get('detected', 0) for s in frame_stats)
    seconds = sum(s.get('second_returns', 0) for s in frame_stats)
    by: dict[str, int] = {}
    paths: list[float] = []
    for s in frame_stats:
        for name, count in s.get('multipath_by_mirror', {}).items():
            by[name] = by.get(name, 0) + count
        paths += s.get('multipath_path_m', [])
    line = (f'multipath: {ghosts} ghost points ({100.0 * ghosts / max(points, 1):.3g} % of {points}), '
            f'{seconds} second-or-later returns')
    if ghosts:
        mirrors = ', '.join(f'{k} {100.0 * v / ghosts:.0f} %' for k, v in sorted(by.items(), key=lambda kv: -kv[1]))
        lo, mid, hi = np.percentile(paths, [0, 50, 100])
        line += f'; mirror surfaces: {mirrors}; behind the mirror by {lo:.2f} / {mid:.2f} / {hi:.2f} m (min / median / max)'
    return line
