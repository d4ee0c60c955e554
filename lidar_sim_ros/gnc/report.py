"""gnc.json and the error figure of ``make demo-gnc``, from a recorded bag."""
from __future__ import annotations

import json
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lidar_sim_ros.gnc.evaluate import TrackingErrors, tracking_errors
from lidar_sim_ros.io.bag import PoseSeries, read_poses

DPI = 150
LABELS = {'truth_cloud': 'truth cloud (no range errors, no dropouts)',
          'model_cloud': 'model cloud (bias, noise, dropouts)'}


def errors_from_bag(bag: str | Path, truth_topic: str, estimate_topics: dict[str, str]) -> dict[str, TrackingErrors]:
    """Errors of each estimate topic (key -> topic) against the truth topic of the bag."""
    truth = read_poses(bag, truth_topic)
    out = {}
    for key, topic in estimate_topics.items():
        est: PoseSeries = read_poses(bag, topic)
        out[key] = tracking_errors(est.stamp_ns, est.position_m, est.quat_xyzw,
                                   truth.stamp_ns, truth.position_m, truth.quat_xyzw)
    return out


def write_report(errors: dict[str, TrackingErrors], out_dir: str | Path,
                 details: dict[str, dict] | None = None, meta: dict | None = None) -> tuple[Path, Path]:
    """Write ``gnc.json`` (per key: the error summary plus ``details[key]``; then ``meta``)
    and ``gnc_errors.png``; return both paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = {key: {**e.summary(), **(details or {}).get(key, {})} for key, e in errors.items()}
    doc.update(meta or {})
    json_path = out / 'gnc.json'
    json_path.write_text(json.dumps(doc, indent=2) + '\n')
    return json_path, error_figure(errors, out / 'gnc_errors.png')


def error_figure(errors: dict[str, TrackingErrors], path: Path) -> Path:
    """Translation and rotation error vs time, one line per cloud."""
    fig = Figure(figsize=(12, 6.5), constrained_layout=True)
    FigureCanvasAgg(fig)
    ax_t, ax_r = fig.subplots(2, 1, sharex=True)
    colours = {'truth_cloud': 'tab:blue', 'model_cloud': 'tab:red'}
    for key, e in errors.items():
        c = colours.get(key)
        s = e.summary()
        name = LABELS.get(key, key)
        ax_t.plot(e.t_s, 100 * (e.translation_m ** 2).sum(axis=1) ** 0.5, color=c,
                  label=f'{name}: |error|, RMS {100 * s["trans_rms_m"]:.1f} cm')
        ax_t.plot(e.t_s, 100 * e.los_m, color=c, ls='--', lw=1,
                  label=f'along the line of sight, mean {100 * s["trans_los_mean_m"]:+.1f} cm')
        ax_r.plot(e.t_s, e.rotation_deg, color=c, label=f'{name}: total, RMS {s["rot_rms_deg"]:.2f} deg')
        ax_r.plot(e.t_s, e.axis_deg, color=c, ls='--', lw=1,
                  label=f'long-axis pointing, RMS {s["axis_rms_deg"]:.2f} deg')
    ax_t.axhline(0, color='0.6', lw=0.8)
    ax_t.set_ylabel('translation error [cm]')
    ax_t.legend(fontsize=8, loc='upper left', bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax_t.set_title('pose_tracker (point-to-plane ICP against the mesh) vs the true pose')
    ax_r.set_ylabel('rotation error [deg]')
    ax_r.set_xlabel('time since the first true pose [s]')
    ax_r.set_yscale('log')
    ax_r.set_ylim(bottom=0.01)
    ax_r.legend(fontsize=8, loc='upper left', bbox_to_anchor=(1.01, 1.0), frameon=False)
    for ax in (ax_t, ax_r):
        ax.grid(alpha=0.3)
    fig.savefig(path, dpi=DPI)
    return path
