"""PNG figures of one LiDAR frame, like the paper's Figs. 6 and 13-16.

* ``scan_pattern``: azimuth/elevation of every shot coloured by laser, with the
  tile grid of a tiled (Lissajous array) scanner (paper Fig. 6). Without the
  frame's shots (e.g. from a bag) it shows the returns' angles coloured by ``ring``.
* ``points_3d_range``: the points in 3D coloured by range (Fig. 13).
* ``range_image``: azimuth vs elevation coloured by range, showing the scan
  lattice on the target (Fig. 14).
* ``points_material``: the points by material, legend with the names (Fig. 15).
* ``points_intensity``: the points by intensity on a log colour scale (Fig. 16).

Angular plots are the sensor's view: azimuth grows to the LEFT (REP-103, +y is
left), elevation up, equal degrees on both axes. Figures are drawn with the
object-oriented matplotlib API on the Agg canvas, so importing this module never
changes the pyplot backend of the caller.
"""
from __future__ import annotations

from pathlib import Path
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import MaxNLocator

from lidar_sim_ros.core.scan import Shots, angles_from_directions
from lidar_sim_ros.io.bag import read_material_names
from lidar_sim_ros.viz.run import RunRecord, frame_label, read_run, render_run_figures
from lidar_sim_ros.viz.style import (AZ_LABEL as _AZ_LABEL, DPI, EL_LABEL as _EL_LABEL,
                                     NO_MATERIAL, material_label, new_figure as _new_figure,
                                     palette)

# Scan patterns of more lasers (a flash array's 256 rows) get no per-laser labels, tile
# grid or list of silent lasers: 256 labels and 255 tile edges hid the frame.
MAX_LABELLED_LASERS = 32
FIGURE_NAMES = ('scan_pattern', 'points_3d_range', 'range_image', 'points_material',
                'points_intensity')


@dataclass(frozen=True)
class ScanLayout:
    """The sensor's nominal field of view [deg] and tile array (None: not a tiled scan)."""

    fov_az_deg: float | None = None
    fov_el_deg: float | None = None
    tiles_az: int | None = None
    tiles_el: int | None = None
    field_half_angle_deg: float | None = None   # a circular field (a Risley rosette)

    @classmethod
    def of_sensor(cls, sensor) -> 'ScanLayout':
        """From a SensorConfig: the fields its scan has (a spinning scan has no tiles; a
        rosette's field is the circle of its two prisms' summed deviation)."""
        scan = sensor.scan
        deviation = getattr(scan, 'prism_deviation_deg', None)
        return cls(getattr(scan, 'fov_az_deg', None), getattr(scan, 'fov_el_deg', None),
                   getattr(scan, 'tiles_az', None), getattr(scan, 'tiles_el', None),
                   float(sum(deviation)) if deviation is not None else None)

    def field_circle_deg(self, n: int = 361) -> tuple[np.ndarray, np.ndarray] | None:
        """(az, el) [deg] of the circular field's rim: the cone of half-angle
        field_half_angle_deg about +x (not a circle in az/el far off axis)."""
        if self.field_half_angle_deg is None:
            return None
        rho, phi = np.radians(self.field_half_angle_deg), np.linspace(0, 2 * np.pi, n)
        y, z = np.sin(rho) * np.cos(phi), np.sin(rho) * np.sin(phi)
        return np.degrees(np.arctan2(y, np.cos(rho))), np.degrees(np.arcsin(z))

    def tile_edges_deg(self) -> tuple[np.ndarray, np.ndarray] | None:
        if None in (self.fov_az_deg, self.fov_el_deg, self.tiles_az, self.tiles_el):
            return None
        return (np.linspace(-self.fov_az_deg / 2, self.fov_az_deg / 2, self.tiles_az + 1),
                np.linspace(-self.fov_el_deg / 2, self.fov_el_deg / 2, self.tiles_el + 1))


def render_frame_figures(points_structured: np.ndarray, out_dir: str | Path,
                         material_names: Sequence[str] | None, shots: Shots | None = None,
                         prefix: str = '', *, label: str = '',
                         layout: ScanLayout | None = None) -> list[Path]:
    """Write the five figures of one frame as ``out_dir/<prefix><name>.png``.

    points_structured: a structured array with at least ``x, y, z`` [m, sensor frame]
    (the layout of ``io.pointcloud``; ``ring``, ``material``, ``intensity`` are used
    when present, and a figure whose field is missing is skipped).
    material_names: index -> name for the ``material`` field (None: numbered).
    shots: the frame's shots; given, the scan-pattern figure shows every shot and
    the tile grid, otherwise the returns' angles. label: appended to every title.
    layout: the sensor's field of view and tiles, outlined on the scan pattern.
    Returns the written paths in the order of FIGURE_NAMES.
    """
    pts = _check_points(points_structured)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = list(material_names or [])
    xyz = np.column_stack([pts['x'], pts['y'], pts['z']]).astype(float)
    rng_m = np.linalg.norm(xyz, axis=1)
    az_rad, el_rad = angles_from_directions(xyz) if len(xyz) else (np.zeros(0), np.zeros(0))
    az_deg, el_deg = np.degrees(az_rad), np.degrees(el_rad)
    fields = set(pts.dtype.names)
    suffix = f'\n{label}' if label else ''

    drawers = {
        'scan_pattern': (lambda: _scan_pattern(shots, az_deg, el_deg, pts, suffix, layout))
        if shots is not None or 'ring' in fields else None,
        'points_3d_range': lambda: _points_3d(xyz, rng_m, suffix),
        'range_image': lambda: _range_image(az_deg, el_deg, rng_m, suffix),
        'points_material': (lambda: _materials(az_deg, el_deg, pts['material'], names, suffix))
        if 'material' in fields else None,
        'points_intensity': (lambda: _intensity(az_deg, el_deg, pts['intensity'], suffix))
        if 'intensity' in fields else None,
    }
    paths = []
    for name in FIGURE_NAMES:
        draw = drawers[name]
        if draw is None:
            continue
        fig = draw()
        path = out / f'{prefix}{name}.png'
        fig.savefig(path, dpi=DPI)
        paths.append(path)
    return paths


def render_bag_figures(bag_path: str | Path, out_dir: str | Path,
                       material_names: Sequence[str] | None = None,
                       frames: str | int | Sequence[int] = 'last', *, shots: Shots | None = None,
                       layout: ScanLayout | None = None, run_figures: bool = True) -> list[Path]:
    """Read a recording (``/lidar/points``, ``/lidar/points_truth``, ``/target/pose``,
    ``/sun/direction``, ``/lidar/material_names``) and render its figures.

    frames: 'last' (files named ``<figure>.png``), or 'first', 'all', a frame index
    or a list of indices (files named ``frame_NNNN_<figure>.png``); negative indices
    count from the end. material_names: overrides the names stored in the bag.
    shots, layout: the sensor's shots and field of view for the scan pattern.
    run_figures: also the whole-run figures of ``viz.run`` (run, range_error, dropouts).
    Titles give the time since the run started and the scenario (range, attitude,
    tumble rate, sun) at that frame.
    """
    bag_path = Path(bag_path)
    if material_names is None:
        material_names = read_material_names(bag_path)
    return render_run(read_run(bag_path), out_dir, material_names, frames, shots=shots,
                      layout=layout, run_figures=run_figures)


def render_run(run: RunRecord, out_dir: str | Path, material_names: Sequence[str] | None,
               frames: str | int | Sequence[int] = 'last', *, shots: Shots | None = None,
               layout: ScanLayout | None = None, run_figures: bool = True) -> list[Path]:
    """``render_bag_figures`` on a recording already read (``viz.run.read_run``)."""
    selected, prefixed = _select_frames(frames, len(run.clouds))
    paths: list[Path] = []
    for i in selected:
        prefix = f'frame_{i:04d}_' if prefixed else ''
        paths += render_frame_figures(run.clouds[i].points, out_dir, material_names, shots, prefix,
                                      label=frame_label(run, i), layout=layout)
    if run_figures:
        paths += render_run_figures(run, out_dir, material_names)
    return paths


# ------------------------------------------------------------------ helpers
def _check_points(points: np.ndarray) -> np.ndarray:
    names = getattr(getattr(points, 'dtype', None), 'names', None)
    if not names or not {'x', 'y', 'z'} <= set(names):
        raise ValueError(f'points must be a structured array with fields x, y, z, got dtype '
                         f'{getattr(points, "dtype", type(points).__name__)}')
    return np.asarray(points).reshape(-1)


def _select_frames(frames: str | int | Sequence[int], n: int) -> tuple[list[int], bool]:
    """Frame indices to draw and whether file names carry the frame index."""
    if isinstance(frames, str):
        choice = {'last': ([n - 1], False), 'first': ([0], True), 'all': (list(range(n)), True)}
        if frames not in choice:
            raise ValueError(f"frames must be 'last', 'first', 'all', an index or a list of "
                             f'indices, got {frames!r}')
        return choice[frames]
    wanted = [frames] if isinstance(frames, (int, np.integer)) else list(frames)
    out = []
    for i in wanted:
        if not isinstance(i, (int, np.integer)) or not -n <= i < n:
            raise ValueError(f'frames: index {i!r} outside the bag\'s {n} frames')
        out.append(int(i) % n)
    return out, True


def _angular_axes(fig: Figure, title: str):
    ax = fig.add_subplot()
    ax.set_title(title)
    ax.set_xlabel(_AZ_LABEL)
    ax.set_ylabel(_EL_LABEL)
    ax.set_aspect('equal', adjustable='box')
    ax.grid(True, linewidth=0.3, alpha=0.5)
    return ax


def _finish_angular(ax, az_deg: np.ndarray, el_deg: np.ndarray) -> None:
    """Axis limits around the data (with a margin) and azimuth increasing to the left."""
    if len(az_deg):
        pad = 1.0
        ax.set_xlim(az_deg.max() + pad, az_deg.min() - pad)
        ax.set_ylim(el_deg.min() - pad, el_deg.max() + pad)
    else:
        ax.invert_xaxis()
        ax.text(0.5, 0.5, 'no returns in this frame', transform=ax.transAxes,
                ha='center', va='center')


def _laser_colours(laser: np.ndarray, n_lasers: int) -> np.ndarray:
    return np.asarray(palette(n_lasers))[np.asarray(laser, dtype=np.int64) % max(n_lasers, 1)]


def _scan_pattern(shots: Shots | None, az_deg: np.ndarray, el_deg: np.ndarray,
                  pts: np.ndarray, suffix: str, layout: ScanLayout | None = None) -> Figure:
    """Shots (faint) and returns (full colour) per laser, the FOV outline and the tiles."""
    fig = _new_figure((10.0, 5.5))
    rings = np.asarray(pts['ring']) if 'ring' in pts.dtype.names else None
    if shots is not None:
        s_az, s_el = np.degrees(shots.az_rad), np.degrees(shots.el_rad)
        laser = np.asarray(shots.laser)
        lasers = np.unique(laser)
        title = (f'Scan pattern of one frame (cf. paper Fig. 6): {len(s_az)} shots, '
                 f'{len(lasers)} lasers')
    else:
        s_az, s_el, laser = az_deg, el_deg, rings
        lasers = np.unique(laser)
        title = f'Scan pattern seen in the returns: {len(s_az)} points'
    labelled = len(lasers) <= MAX_LABELLED_LASERS
    n_colours = int(lasers.max()) + 1 if len(lasers) else 1
    if rings is not None:
        n_colours = max(n_colours, int(rings.max()) + 1 if len(rings) else 0)
        present = np.unique(rings)
        title += f'; returns in {len(present)} rings'
        if shots is not None:
            absent = np.setdiff1d(lasers, present)
            if not labelled and len(absent):    # a flash array's 256 rows: a count, not a list
                title += f', none from {len(absent)} of {len(lasers)}'
            else:
                title += (', none from ' + ('ring ' if len(absent) == 1 else 'rings ')
                          + ', '.join(str(int(a)) for a in absent) if len(absent) else ', every laser')
    ax = _angular_axes(fig, title + suffix)
    if shots is not None and len(s_az):
        ax.scatter(s_az, s_el, c=_laser_colours(laser, n_colours), s=0.6, linewidths=0,
                   alpha=0.25, rasterized=True)
    if rings is not None and len(az_deg):
        ax.scatter(az_deg, el_deg, c=_laser_colours(rings, n_colours), s=1.2, linewidths=0,
                   rasterized=True)
    grid = layout.tile_edges_deg() if layout is not None else None
    if grid is None and shots is not None and labelled:    # a flash array's rows are no tiles
        grid = _tile_grid(s_az, s_el, laser)
    if grid is not None:
        az_edges, el_edges = grid
        for a in az_edges[1:-1]:
            ax.plot([a, a], [el_edges[0], el_edges[-1]], color='k', linewidth=0.6, alpha=0.7)
        for e in el_edges[1:-1]:
            ax.plot([az_edges[0], az_edges[-1]], [e, e], color='k', linewidth=0.6, alpha=0.7)
    fov = (layout.fov_az_deg, layout.fov_el_deg) if layout is not None else (None, None)
    if None not in fov:
        ax.add_patch(Rectangle((-fov[0] / 2, -fov[1] / 2), fov[0], fov[1], fill=False,
                               edgecolor='k', linewidth=1.6))
    elif grid is not None:
        ax.add_patch(Rectangle((grid[0][0], grid[1][0]), grid[0][-1] - grid[0][0],
                               grid[1][-1] - grid[1][0], fill=False, edgecolor='k',
                               linewidth=1.6))
    for lid in (lasers if labelled else ()):
        sel = laser == lid
        # labels at the laser's own centre: tile centre for shots, median of its returns otherwise
        ca = 0.5 * (s_az[sel].min() + s_az[sel].max()) if shots is not None else np.median(s_az[sel])
        ce = 0.5 * (s_el[sel].min() + s_el[sel].max()) if shots is not None else np.median(s_el[sel])
        ax.text(ca, ce, str(int(lid)), ha='center', va='center', fontsize=7,
                bbox=dict(boxstyle='round,pad=0.15', fc='white', ec='none', alpha=0.7))
    if None not in fov:
        ax_az = np.concatenate([s_az, [-fov[0] / 2, fov[0] / 2]])
        ax_el = np.concatenate([s_el, [-fov[1] / 2, fov[1] / 2]])
        _finish_angular(ax, ax_az, ax_el)
        ax.text(fov[0] / 2, fov[1] / 2, f'field of view {fov[0]:g} x {fov[1]:g} deg',
                ha='left', va='bottom', fontsize=8)
    elif layout is not None and layout.field_circle_deg() is not None:
        c_az, c_el = layout.field_circle_deg()
        ax.plot(c_az, c_el, color='k', linewidth=1.6)
        _finish_angular(ax, np.concatenate([s_az, c_az]), np.concatenate([s_el, c_el]))
        ax.text(0.0, c_el.max(), f'field of view {2 * layout.field_half_angle_deg:g} deg circle',
                ha='center', va='bottom', fontsize=8)
    else:
        _finish_angular(ax, s_az, s_el)
    key = 'colour and label' if labelled else 'colour'
    what = (f'{key} = laser id; faint: every shot, full colour: returns'
            if shots is not None else f'{key} = ring')
    ax.set_xlabel(_AZ_LABEL + '; ' + what)
    return fig


def _tile_grid(az_deg: np.ndarray, el_deg: np.ndarray,
               laser: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Tile edges (deg) when the lasers' own extents tile a regular grid, else None.

    A laser's tile centre is the middle of its angular extent; edges sit midway
    between neighbouring centres (outer edges half a spacing out). Patterns whose
    lasers have no 2D extent (a spinning multi-beam sensor) get no grid.
    """
    ids = np.unique(laser)
    if len(ids) < 2:
        return None
    centres = []
    for lid in ids:
        sel = laser == lid
        a0, a1, e0, e1 = (az_deg[sel].min(), az_deg[sel].max(),
                              el_deg[sel].min(), el_deg[sel].max())
        if a1 - a0 < 1e-6 or e1 - e0 < 1e-6:
            return None
        centres.append(((a0 + a1) / 2, (e0 + e1) / 2))
    centres = np.round(np.asarray(centres), 3)
    az_c, el_c = np.unique(centres[:, 0]), np.unique(centres[:, 1])
    if len(az_c) * len(el_c) != len(ids) or len(np.unique(centres, axis=0)) != len(ids):
        return None

    def edges(c: np.ndarray, lo: float, hi: float) -> np.ndarray:
        if len(c) == 1:
            return np.array([lo, hi])
        mid = (c[1:] + c[:-1]) / 2
        return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])

    return (edges(az_c, az_deg.min(), az_deg.max()), edges(el_c, el_deg.min(), el_deg.max()))


def _points_3d(xyz: np.ndarray, rng_m: np.ndarray, suffix: str) -> Figure:
    fig = _new_figure((9.0, 7.0))
    ax = fig.add_subplot(projection='3d')
    ax.set_title(f'Simulated points coloured by range (cf. paper Fig. 13): {len(xyz)} points'
                 + suffix)
    norm = _range_norm(rng_m)
    sc = ax.scatter(xyz[:, 0], xyz[:, 1], xyz[:, 2], c=rng_m, cmap='viridis', norm=norm,
                    s=0.6, linewidths=0, depthshade=False, rasterized=True)
    if len(xyz):
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
        ax.set_box_aspect(np.maximum(hi - lo, 1e-3))  # equal metres on every axis
    else:
        ax.text2D(0.5, 0.5, 'no returns in this frame', transform=ax.transAxes, ha='center')
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(5))
    ax.set_xlabel('x [m] (forward)', labelpad=8)
    ax.set_ylabel('y [m] (left)', labelpad=8)
    # Unrotated: mplot3d otherwise turns the z label upside down at this view.
    ax.zaxis.set_rotate_label(False)
    ax.set_zlabel('z [m]\n(up)', labelpad=8, rotation=0)
    # Camera behind and above the sensor, looking along +x: the side the LiDAR sees.
    ax.view_init(elev=20.0, azim=-150.0)
    fig.colorbar(sc, ax=ax, shrink=0.6, pad=0.1, label='range [m]')
    return fig


def _range_norm(rng_m: np.ndarray) -> Normalize:
    if len(rng_m) == 0:
        return Normalize(0.0, 1.0)
    lo, hi = np.percentile(rng_m, [0.5, 99.5])
    return Normalize(lo, max(hi, lo + 1e-3))


def _range_image(az_deg: np.ndarray, el_deg: np.ndarray, rng_m: np.ndarray,
                 suffix: str) -> Figure:
    fig = _new_figure((10.0, 5.0))
    ax = _angular_axes(fig, 'Range image: the scan lattice on the target (cf. paper Fig. 14)'
                       + suffix)
    sc = ax.scatter(az_deg, el_deg, c=rng_m, cmap='viridis', norm=_range_norm(rng_m),
                    s=1.5, linewidths=0, rasterized=True)
    _finish_angular(ax, az_deg, el_deg)
    fig.colorbar(sc, ax=ax, shrink=0.9, label='range [m]')
    return fig


def _materials(az_deg: np.ndarray, el_deg: np.ndarray, material: np.ndarray,
               names: list[str], suffix: str) -> Figure:
    fig = _new_figure((10.0, 5.0))
    ax = _angular_axes(fig, 'Points by surface material (cf. paper Fig. 15)' + suffix)
    material = np.asarray(material, dtype=np.int64)
    ids, counts = np.unique(material, return_counts=True)
    colours = palette(max(len(names), int(ids[ids != NO_MATERIAL].max(initial=-1)) + 1))
    # Large classes first, small ones on top with larger dots: a 5-point nozzle stays visible.
    for mid, count in sorted(zip(ids, counts), key=lambda ic: -ic[1]):
        sel = material == mid
        colour = (0.5, 0.5, 0.5) if mid == NO_MATERIAL else colours[mid]
        small = count < 0.02 * len(material)
        ax.scatter(az_deg[sel], el_deg[sel], color=colour, s=8.0 if small else 1.5,
                   linewidths=0, label=f'{material_label(int(mid), names)} ({int(count)})',
                   rasterized=True, zorder=3 if small else 2)
    for mid in sorted(set(range(len(names))) - set(int(i) for i in ids)):
        ax.scatter([], [], color=colours[mid], s=1.5, label=f'{material_label(mid, names)} (0)')
    _finish_angular(ax, az_deg, el_deg)
    if len(material):
        # Legend in material order (the order of the materials file), not drawing order.
        handles, labels = ax.get_legend_handles_labels()
        order = sorted(range(len(labels)), key=lambda k: _legend_key(labels[k], names))
        ax.legend([handles[k] for k in order], [labels[k] for k in order],
                  title='material (points)', loc='center left', bbox_to_anchor=(1.01, 0.5),
                  markerscale=4, fontsize=8, frameon=False)
    return fig


def _legend_key(label: str, names: list[str]) -> int:
    name = label.split(':')[0].split(' (')[0]
    return names.index(name) if name in names else len(names) + 1


def _intensity(az_deg: np.ndarray, el_deg: np.ndarray, intensity: np.ndarray,
               suffix: str) -> Figure:
    fig = _new_figure((10.0, 5.0))
    ax = _angular_axes(fig, 'Points by signal intensity (cf. paper Fig. 16)' + suffix)
    intensity = np.asarray(intensity, dtype=float)
    positive = intensity[intensity > 0]
    lo = positive.min() if len(positive) else 1e-6
    hi = max(positive.max(), lo * 10) if len(positive) else 1.0
    # Non-positive intensities (possible in measured data) sit at the bottom of the scale.
    sc = ax.scatter(az_deg, el_deg, c=np.clip(intensity, lo, None), cmap='plasma',
                    norm=LogNorm(lo, hi), s=1.5, linewidths=0, rasterized=True)
    _finish_angular(ax, az_deg, el_deg)
    fig.colorbar(sc, ax=ax, shrink=0.9,
                 label='intensity = received / saturation power [-] (log scale)')
    return fig


def render_sunlight_figure(az_deg: np.ndarray, el_deg: np.ndarray, hit: np.ndarray,
                           background_w: np.ndarray, sunlit: np.ndarray,
                           false_probability: np.ndarray, false_az_deg: np.ndarray,
                           false_el_deg: np.ndarray, out_path: str | Path,
                           label: str = '', dpi: int = DPI) -> Path:
    """Sunlight on the target, one frame (docs/sunlight.md): two panels over the sensor's view.

    Top: background power (W) of every shot that sees the target, log colour where the
    surface is sunlit, grey where it lies in shadow. Bottom: each shot's probability of a
    false return (log colour), with the frame's actual false returns (material 255) as red
    crosses. Arrays are per shot (az_deg, el_deg, hit, background_w, sunlit,
    false_probability) and per false return (false_az_deg, false_el_deg).
    """
    az_deg, el_deg = np.asarray(az_deg, float), np.asarray(el_deg, float)
    hit, sunlit = np.asarray(hit, bool), np.asarray(sunlit, bool)
    fig = _new_figure((10.0, 9.0))
    suffix = f'\n{label}' if label else ''
    top, bottom = fig.subplots(2, 1)
    shadowed = hit & ~sunlit
    for ax in (top, bottom):
        ax.set_xlabel(_AZ_LABEL)
        ax.set_ylabel(_EL_LABEL)
        ax.set_aspect('equal', adjustable='box')
        ax.grid(True, linewidth=0.3, alpha=0.5)
    top.set_title(f'Solar background on the target: {int(sunlit.sum())} shots see sunlit surfaces, '
                  f'{int(shadowed.sum())} shadowed' + suffix)
    top.scatter(az_deg[shadowed], el_deg[shadowed], color=(0.7, 0.7, 0.7), s=1.5, linewidths=0,
                rasterized=True, label='in shadow')
    lit_bg = np.asarray(background_w, float)[sunlit]
    if len(lit_bg) and lit_bg.max() > 0:
        lo = max(np.percentile(lit_bg[lit_bg > 0], 1), 1e-15) if np.any(lit_bg > 0) else 1e-12
        sc = top.scatter(az_deg[sunlit], el_deg[sunlit], c=np.clip(lit_bg, lo, None) * 1e9,
                         cmap='inferno', norm=LogNorm(lo * 1e9, max(lit_bg.max(), lo * 10) * 1e9),
                         s=1.5, linewidths=0, rasterized=True)
        fig.colorbar(sc, ax=top, shrink=0.9, label='background power [nW] (log)')
    top.legend(loc='upper right', markerscale=6, fontsize=8)
    _finish_angular(top, az_deg[hit], el_deg[hit])
    p = np.clip(np.asarray(false_probability, float), 1e-9, 1.0)
    sc = bottom.scatter(az_deg, el_deg, c=p, cmap='viridis', norm=LogNorm(1e-7, 1.0), s=1.5,
                        linewidths=0, rasterized=True)
    bottom.scatter(false_az_deg, false_el_deg, marker='x', color='red', s=14, linewidths=0.8,
                   label=f'false returns ({len(false_az_deg)})')
    bottom.set_title('False returns: probability per shot (threshold crossings before the echo)')
    bottom.legend(loc='upper right', fontsize=8)
    _finish_angular(bottom, az_deg, el_deg)
    fig.colorbar(sc, ax=bottom, shrink=0.9, label='P(false return) per shot [-] (log)')
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=dpi)
    return out_path


__all__ = ['DPI', 'FIGURE_NAMES', 'ScanLayout', 'render_bag_figures', 'render_frame_figures',
           'render_run', 'render_sunlight_figure']
