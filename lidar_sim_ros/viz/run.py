"""Figures of a whole recorded run, the ones a GNC engineer opens first.

* ``run``: points per frame, range to the target and its attitude against the time
  since the run started.
* ``range_error``: measured minus true range per material (detected points matched
  to the noise-free ``/lidar/points_truth`` by shot: same ring, same time in frame).
* ``dropouts``: the last frame's shots that hit the target on the scan lattice,
  coloured detected / below threshold / saturated, false returns marked.

Everything is read from the bag (``/lidar/points``, ``/lidar/points_truth``,
``/target/pose``, ``/sun/direction``), so ``make demo`` and ``lidar-sim simulate``
draw the same pictures. ``scenario_caption`` states the scenario (range, attitude,
tumble rate, sun) in one line that every figure of the run carries.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from lidar_sim_ros.core.scan import angles_from_directions
from lidar_sim_ros.io.bag import (CLOUD_TOPIC, BagContentError, CloudFrame, PoseSeries,
                                  VectorSeries, read_clouds, read_poses, read_vectors,
                                  recording_name)
from lidar_sim_ros.viz.style import (AZ_LABEL, EL_LABEL, NO_MATERIAL, material_label,
                                     new_figure, palette)

TRUTH_TOPIC = '/lidar/points_truth'
RUN_FIGURE_NAMES = ('run', 'range_error', 'dropouts')
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class RunRecord:
    """What a recording holds for the run figures.

    start_ns: the run's time zero (the earliest cloud or pose stamp) [ns].
    clouds / truth: the detected and noise-free clouds (truth empty if not recorded).
    poses: target pose in the sensor frame (None if not recorded); sun: direction toward
    the sun in the sensor frame (None without a sun).
    """

    source: str
    start_ns: int
    clouds: list[CloudFrame]
    truth: list[CloudFrame]
    poses: PoseSeries | None
    sun: VectorSeries | None

    def t_rel_s(self, stamp_ns: int | np.ndarray) -> np.ndarray | float:
        """Seconds since the run started."""
        return (np.asarray(stamp_ns, dtype=np.int64) - self.start_ns) / NS_PER_S


def read_run(bag_path: str | Path) -> RunRecord:
    """Read the topics the run figures need; BagContentError without clouds."""
    bag_path = Path(bag_path)
    clouds = read_clouds(bag_path)
    if not clouds:
        raise BagContentError(f'bag {bag_path} has no messages on {CLOUD_TOPIC}')
    truth = _optional(lambda: read_clouds(bag_path, TRUTH_TOPIC)) or []
    poses = _optional(lambda: read_poses(bag_path))
    sun = _optional(lambda: read_vectors(bag_path))
    if poses is not None and len(poses.stamp_ns) == 0:
        poses = None
    stamps = [c.stamp_ns for c in clouds] + ([int(poses.stamp_ns[0])] if poses is not None else [])
    return RunRecord(recording_name(bag_path), int(min(stamps)), clouds, truth, poses, sun)


def _optional(read):
    try:
        return read()
    except BagContentError:
        return None


# ------------------------------------------------------------ scenario line
def tumble_rate_dps(poses: PoseSeries) -> float | None:
    """Median angular rate of the target [deg/s] between consecutive poses (None if < 2)."""
    if poses is None or len(poses.stamp_ns) < 2:
        return None
    rot = Rotation.from_quat(poses.quat_xyzw)
    dt_s = np.diff(poses.stamp_ns) / NS_PER_S
    ok = dt_s > 0
    if not ok.any():
        return None
    angle_rad = (rot[1:] * rot[:-1].inv()).magnitude()
    return float(np.degrees(np.median(angle_rad[ok] / dt_s[ok])))


def scenario_caption(run: RunRecord, stamp_ns: int) -> str:
    """One line: range, attitude (roll, pitch, yaw of the target in the sensor frame),
    tumble rate and sun direction at ``stamp_ns`` (the nearest recorded pose/sun sample)."""
    parts = []
    if run.poses is not None:
        i = int(np.argmin(np.abs(run.poses.stamp_ns - stamp_ns)))
        pos = run.poses.position_m[i]
        rpy = Rotation.from_quat(run.poses.quat_xyzw[i]).as_euler('xyz', degrees=True)
        parts.append(f'range {np.linalg.norm(pos):.2f} m')
        parts.append('attitude r/p/y ' + '/'.join(f'{round(a) + 0:.0f}' for a in rpy) + ' deg')
        rate = tumble_rate_dps(run.poses)
        if rate is not None:
            parts.append(f'tumble {rate:.1f} deg/s')
    else:
        parts.append('no target pose recorded')
    if run.sun is not None and len(run.sun.stamp_ns):
        j = int(np.argmin(np.abs(run.sun.stamp_ns - stamp_ns)))
        v = run.sun.vector[j] / max(np.linalg.norm(run.sun.vector[j]), 1e-12)
        az, el = np.degrees(np.arctan2(v[1], v[0])), np.degrees(np.arcsin(np.clip(v[2], -1, 1)))
        parts.append(f'sun at az {az:.0f}, el {el:.0f} deg')
    else:
        parts.append('no sun')
    return ', '.join(parts)


def frame_label(run: RunRecord, index: int) -> str:
    """Title suffix of one frame: recording, frame, time into the run, scenario line."""
    cloud = run.clouds[index]
    return (f'{run.source}: frame {index + 1} of {len(run.clouds)}, '
            f't = {run.t_rel_s(cloud.stamp_ns):.2f} s into the run\n'
            + scenario_caption(run, cloud.stamp_ns))


# ------------------------------------------------------------- matching
def _shot_key(points: np.ndarray) -> np.ndarray:
    """One int64 per shot: its ring and its time in frame (float32 bits)."""
    t = np.ascontiguousarray(points['t'], dtype='<f4').view('<u4').astype(np.int64)
    return (points['ring'].astype(np.int64) << 32) | t


def match_truth(points: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Index into ``truth`` of each detected point's shot (-1 where none): a shot is its
    ring and its time in frame, which the detected and the truth cloud share."""
    tk, pk = _shot_key(truth), _shot_key(points)
    if len(tk) == 0:
        return np.full(len(pk), -1, dtype=np.int64)
    order = np.argsort(tk, kind='stable')
    sorted_keys = tk[order]
    pos = np.minimum(np.searchsorted(sorted_keys, pk), len(tk) - 1)
    return np.where(sorted_keys[pos] == pk, order[pos], -1)


def range_errors_by_material(run: RunRecord) -> dict[int, np.ndarray]:
    """Measured minus true range [m] of every detected on-target point, per material id,
    over the frames whose truth cloud was recorded (matched by stamp)."""
    truth_by_stamp = {c.stamp_ns: c.points for c in run.truth}
    errors: dict[int, list[np.ndarray]] = {}
    for cloud in run.clouds:
        truth = truth_by_stamp.get(cloud.stamp_ns)
        if truth is None or not len(cloud.points):
            continue
        pts = cloud.points[cloud.points['material'] != NO_MATERIAL]
        idx = match_truth(pts, truth)
        ok = idx >= 0
        meas = _norm(pts[ok])
        true = _norm(truth[idx[ok]])
        mat = pts['material'][ok].astype(np.int64)
        for m in np.unique(mat):
            errors.setdefault(int(m), []).append((meas - true)[mat == m])
    return {m: np.concatenate(v) for m, v in sorted(errors.items())}


def _norm(points: np.ndarray) -> np.ndarray:
    return np.sqrt(points['x'].astype(float) ** 2 + points['y'].astype(float) ** 2
                   + points['z'].astype(float) ** 2)


DROPOUT_CLASSES = ('detected', 'below threshold', 'saturated')


def classify_shots(points: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per truth point (a shot that hit the target): 0 detected (a return was reported,
    possibly a false one), 1 below threshold, 2 saturated. The truth cloud's intensity is
    received / saturation power, so a dropped shot at >= 1 saturated the receiver."""
    idx = match_truth(points, truth)
    cls = np.where(np.asarray(truth['intensity']) >= 1.0, 2, 1).astype(np.int8)
    cls[idx[idx >= 0]] = 0
    return cls


# -------------------------------------------------------------- figures
def render_run_figures(run: RunRecord, out_dir: str | Path,
                       material_names: Sequence[str] | None = None) -> list[Path]:
    """Write ``run.png``, ``range_error.png`` (needs the truth cloud) and ``dropouts.png``
    (needs the truth cloud) into ``out_dir``; returns the written paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = list(material_names or [])
    figs = {'run': _run_figure(run)}
    if run.truth:
        figs['range_error'] = _range_error_figure(run, names)
        figs['dropouts'] = _dropout_figure(run)
    paths = []
    for name in RUN_FIGURE_NAMES:
        if name in figs:
            path = out / f'{name}.png'
            figs[name].savefig(path, dpi=150)
            paths.append(path)
    return paths


def _run_figure(run: RunRecord):
    fig = new_figure((10.0, 8.0))
    ax_n, ax_r, ax_a = fig.subplots(3, 1, sharex=True)
    t_c = run.t_rel_s([c.stamp_ns for c in run.clouds])
    n_pts = np.array([len(c.points) for c in run.clouds])
    fig.suptitle(f'The whole run: {run.source}, {len(run.clouds)} frames over '
                 f'{t_c[-1] - t_c[0]:.1f} s\n{scenario_caption(run, run.clouds[0].stamp_ns)} '
                 '(at the start)')
    ax_n.plot(t_c, n_pts, 'o-', ms=3, label='detected points')
    if run.truth:
        ax_n.plot(run.t_rel_s([c.stamp_ns for c in run.truth]), [len(c.points) for c in run.truth],
                  's--', ms=3, label='shots on the target\n(truth cloud)')
    ax_n.set_ylabel('points per frame')
    ax_n.set_ylim(bottom=0)
    ax_n.legend(loc='center left', bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    med = [np.median(_norm(c.points)) if len(c.points) else np.nan for c in run.clouds]
    ax_r.plot(t_c, med, 'o', ms=3, label='median measured\nrange of the frame')
    if run.poses is not None:
        t_p = run.t_rel_s(run.poses.stamp_ns)
        ax_r.plot(t_p, np.linalg.norm(run.poses.position_m, axis=1), '-',
                  label='range to the target\norigin (pose)')
        rpy = np.unwrap(Rotation.from_quat(run.poses.quat_xyzw).as_euler('xyz'), axis=0)
        for k, name in enumerate(('roll (about x)', 'pitch (about y)', 'yaw (about z)')):
            ax_a.plot(t_p, np.degrees(rpy[:, k]), label=name)
        ax_a.legend(loc='center left', bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    else:
        ax_a.text(0.5, 0.5, 'no /target/pose in the recording', transform=ax_a.transAxes,
                  ha='center')
    ax_r.set_ylabel('range [m]')
    ax_r.legend(loc='center left', bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    ax_a.set_ylabel('target attitude in\nthe sensor frame [deg]')
    ax_a.set_xlabel('time since the run started [s]')
    for ax in (ax_n, ax_r, ax_a):
        ax.grid(True, linewidth=0.3, alpha=0.5)
    return fig


def _range_error_figure(run: RunRecord, names: list[str]):
    errors = range_errors_by_material(run)
    fig = new_figure((10.0, 5.5))
    ax = fig.add_subplot()
    last = run.clouds[-1].stamp_ns
    ax.set_title('Measured minus true range per material, all frames\n'
                 f'{run.source}: {len(run.clouds)} frames; {scenario_caption(run, last)} (at the end)')
    if not errors:
        ax.text(0.5, 0.5, 'no detected point matched a truth point', transform=ax.transAxes,
                ha='center')
        return fig
    mats = list(errors)
    data = [errors[m] * 100.0 for m in mats]
    colours = palette(max(mats) + 1)
    parts = ax.boxplot(data, orientation='horizontal', whis=(1, 99), showfliers=False, patch_artist=True,
                       widths=0.6)
    for box, m in zip(parts['boxes'], mats):
        box.set_facecolor(colours[m])
        box.set_alpha(0.6)
    ax.set_yticks(range(1, len(mats) + 1),
                  [material_label(m, names) for m in mats], fontsize=8)
    ax.invert_yaxis()
    for k, d in enumerate(data, start=1):
        ax.annotate(f'mean {d.mean():+.1f} cm, sd {d.std():.1f} cm, n = {len(d)}', (1.0, k),
                    xycoords=('axes fraction', 'data'), xytext=(4, 0),
                    textcoords='offset points', va='center', fontsize=8)
    ax.axvline(0.0, color='k', linewidth=0.8)
    ax.set_xlabel('measured minus true range [cm] (box: quartiles, whiskers: 1st-99th percentile)')
    ax.grid(True, axis='x', linewidth=0.3, alpha=0.5)
    return fig


def _dropout_figure(run: RunRecord):
    truth_by_stamp = {c.stamp_ns: c.points for c in run.truth}
    cloud = next((c for c in reversed(run.clouds) if c.stamp_ns in truth_by_stamp), run.clouds[-1])
    index = run.clouds.index(cloud)
    truth = truth_by_stamp.get(cloud.stamp_ns, cloud.points[:0])
    cls = classify_shots(cloud.points, truth)
    fig = new_figure((10.0, 5.5))
    ax = fig.add_subplot()
    ax.set_title('Dropouts on the scan lattice: the shots that hit the target\n'
                 + frame_label(run, index))
    az, el = _angles_deg(truth)
    styles = {0: dict(color=(0.75, 0.75, 0.75), s=1.5),
              1: dict(color='tab:blue', s=6), 2: dict(color='tab:red', s=6)}
    for k in (0, 1, 2):
        sel = cls == k
        ax.scatter(az[sel], el[sel], linewidths=0, rasterized=True, **styles[k],
                   label=f'{DROPOUT_CLASSES[k]} ({int(sel.sum())})')
    false = cloud.points[cloud.points['material'] == NO_MATERIAL]
    if len(false):
        f_az, f_el = _angles_deg(false)
        ax.scatter(f_az, f_el, marker='x', color='k', s=14, linewidths=0.8,
                   label=f'false returns ({len(false)})')
    ax.set_xlabel(AZ_LABEL)
    ax.set_ylabel(EL_LABEL)
    ax.set_aspect('equal', adjustable='box')
    ax.grid(True, linewidth=0.3, alpha=0.5)
    if len(az):
        ax.set_xlim(az.max() + 1, az.min() - 1)
        ax.set_ylim(el.min() - 1, el.max() + 1)
    else:
        ax.invert_xaxis()
    ax.legend(loc='center left', bbox_to_anchor=(1.01, 0.5), markerscale=3, fontsize=8,
              frameon=False, title='shot')
    return fig


def _angles_deg(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xyz = np.column_stack([points['x'], points['y'], points['z']]).astype(float)
    if not len(xyz):
        return np.zeros(0), np.zeros(0)
    az, el = angles_from_directions(xyz)
    return np.degrees(az), np.degrees(el)


__all__ = ['DROPOUT_CLASSES', 'RUN_FIGURE_NAMES', 'RunRecord', 'classify_shots', 'frame_label',
           'match_truth', 'range_errors_by_material', 'read_run', 'render_run_figures',
           'scenario_caption', 'tumble_rate_dps']
