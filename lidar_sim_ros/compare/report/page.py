"""report.html: one self-contained page (PNG figures embedded as base64) per comparison.

Sections: the verdict in plain words, the headline numbers, the ranked candidate
effects with their fitted parameters and what each brings, the residual against the
top features (binned median and 16-84 % band), per-material residual histograms, the
residual painted on the target (body frame, two views), the unmatched points and
the history of runs (RMSE and NLL falling as effects are added).
"""
from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lidar_sim_ros.compare.diagnose.plan import MOTION_RIVALS
from lidar_sim_ros.compare.report import opening
from lidar_sim_ros.compare.report.verdict import pose_size_words
from lidar_sim_ros.compare.diagnose.features import CATEGORICAL, LABELS  # noqa: E402
from lidar_sim_ros.compare.model.materials import robust_sigma  # noqa: E402

MAX_SCATTER = 4000
MAX_TARGET_POINTS = 8000


def _png(fig) -> bytes:
    buf = io.BytesIO()
    # Layouts are set by tight_layout / constrained layout: a 'tight' bounding box would
    # draw every figure twice.
    fig.savefig(buf, format='png', dpi=80)
    plt.close(fig)
    return buf.getvalue()


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode('ascii')
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def features_figure(feats, values: dict, residual_m: np.ndarray, material_names: list[str],
                    top: int = 4, labels: dict | None = None) -> bytes:
    """Residual (cm) against the top features: points, binned median and 16-84 % band.

    ``values``: the feature values the attribution ranked (the same points as
    ``residual_m``), so that the scatter and the binned curve share one axis.
    """
    labels = {**LABELS, **(labels or {})}
    chosen = feats[:top]
    fig, axes = plt.subplots(1, len(chosen), figsize=(4.2 * len(chosen), 3.6), squeeze=False)
    rng = np.random.default_rng(0)
    pick = rng.choice(len(residual_m), min(MAX_SCATTER, len(residual_m)), replace=False)
    lim = 4 * max(robust_sigma(residual_m), 1e-4) * 100
    for ax, f in zip(axes[0], chosen):
        x = values[f.name]
        if f.name in CATEGORICAL:
            pos = {c: i for i, c in enumerate(f.labels)}
            xs = np.array([pos.get(v.item() if hasattr(v, 'item') else v, -1) for v in x[pick]])
            jitter = rng.uniform(-0.3, 0.3, len(pick))
            ax.plot(xs + jitter, residual_m[pick] * 100, '.', ms=2, alpha=0.25, color='0.4')
            centers = np.arange(len(f.labels))
            names = ([material_names[int(c)] if 0 <= int(c) < len(material_names) else str(c)
                      for c in f.labels] if f.name == 'material'
                     else [f'{c:g}' for c in f.labels])
            ax.set_xticks(centers, names, rotation=45 if f.name == 'material' else 0,
                          fontsize=8)
        else:
            ax.plot(x[pick], residual_m[pick] * 100, '.', ms=2, alpha=0.25, color='0.4')
            centers = f.centers
        ok = f.counts > 0
        ax.fill_between(np.asarray(centers)[ok], f.p16_m[ok] * 100, f.p84_m[ok] * 100,
                        color='tab:orange', alpha=0.3, label='16-84 %')
        ax.plot(np.asarray(centers)[ok], f.median_m[ok] * 100, 'o-', color='tab:red', ms=4,
                label='binned median')
        ax.axhline(0, color='k', lw=0.8)
        ax.set_ylim(-lim, lim)
        ax.set_xlabel(labels[f.name])
        ax.set_title(f'{f.name}: score {f.score:.4f}', fontsize=10)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel('range residual, measured - model (cm)')
    axes[0][0].legend(fontsize=8, loc='upper right')
    fig.tight_layout()
    return _png(fig)


def target_figure(matching, residual_m: np.ndarray) -> bytes:
    """The residual painted on the target: matched points at their model hit in the body
    frame, seen along the two shorter body axes (the longest body axis runs across)."""
    meas, sel = matching.meas, matching.matched
    poses = meas.poses.at(meas.t_s)
    pts = meas.directions * np.where(sel, matching.pred.ctx.range_m, meas.range_m)[:, None]
    body = poses.to_body(pts)
    hit = body[sel]
    residual_m = np.asarray(residual_m)
    if len(hit) > MAX_TARGET_POINTS:      # a scatter of more points shows nothing more
        pick = np.sort(np.random.default_rng(1).choice(len(hit), MAX_TARGET_POINTS, False))
        hit, residual_m = hit[pick], residual_m[pick]
    extent = np.ptp(hit, axis=0) if len(hit) else np.ones(3)
    long_axis = int(np.argmax(extent))
    others = [i for i in range(3) if i != long_axis]
    lim = 3 * max(robust_sigma(residual_m), 1e-4) * 100
    axis_name = 'xyz'
    ratio = extent[others].max() / max(extent[long_axis], 1e-6)
    fig, axes = plt.subplots(2, 1, figsize=(10, 2 * (1.2 + 4.5 * min(max(ratio, 0.3), 1.0))),
                             layout='constrained')
    for ax, j, k in zip(axes, others, others[::-1]):
        order = np.argsort(hit[:, k])       # nearest-to-viewer last
        sc = ax.scatter(hit[order, long_axis], hit[order, j], c=(residual_m * 100)[order],
                        s=4, cmap='coolwarm', vmin=-lim, vmax=lim)
        # Unmatched points close to the target (clutter far away has its own figure).
        lo, hi = hit.min(axis=0) - 0.5, hit.max(axis=0) + 0.5
        close = ~sel & np.all((body >= lo) & (body <= hi), axis=1)
        if np.any(close):
            ax.plot(body[close, long_axis], body[close, j], 'kx', ms=3,
                    label='unmatched (measured point)')
            ax.legend(fontsize=8, loc='upper right')
        ax.set_xlabel(f'body {axis_name[long_axis]} (m)')
        ax.set_ylabel(f'body {axis_name[j]} (m)')
        ax.set_title(f'seen along body {axis_name[k]}', fontsize=10)
        ax.set_aspect('equal')
        ax.grid(alpha=0.3)
    fig.colorbar(sc, ax=list(axes), label='range residual (cm)', shrink=0.9)
    return _png(fig)


def candidates_figure(cands) -> bytes:
    ok = [c for c in cands if c.error is None]
    fig, ax = plt.subplots(figsize=(7, 0.45 * max(len(ok), 1) + 1.2))
    names = [c.name for c in ok][::-1]
    scores = [c.score for c in ok][::-1]
    colors = ['tab:red' if c.significant else 'tab:gray' for c in ok][::-1]
    ax.barh(names, scores, color=colors)
    ax.axvline(0, color='k', lw=0.8)
    ax.set_xlabel('held-out log-likelihood gain (nats per point); red = significant')
    ax.grid(alpha=0.3, axis='x')
    fig.tight_layout()
    return _png(fig)


def history_figure(runs: list[dict]) -> bytes:
    """RMSE and NLL of every recorded run on one basis: each material's offset and sigma
    scale refit in every run (``history.run_entry``), so a run with materials as
    configured and a --fit run with materials refit compare. Runs recorded without the
    calibrated figures show their headline figures as open markers (another basis)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    k = np.arange(1, len(runs) + 1)
    labels = [f'{i}\n' + ('+'.join(r.get('effects') or []) or 'baseline').replace('+', '+\n')
              for i, r in zip(k, runs)]
    series = (('range_rmse_calibrated_m', 'range_rmse_m', 100.0, 'range RMSE (cm)', 'tab:blue'),
              ('nll_calibrated', 'nll_per_point', 1.0, 'NLL per point', 'tab:red'))

    def column(key: str) -> np.ndarray:
        return np.array([r.get(key) if r.get(key) is not None else np.nan for r in runs],
                        float)
    for ax, (key, headline, scale, label, color) in zip(axes, series):
        y, y_head = column(key), column(headline)
        ax.plot(k, y * scale, 'o-', color=color,
                label='per-material offsets and sigmas refit (every run)')
        other = np.isnan(y) & np.isfinite(y_head)
        if other.any():
            ax.plot(k[other], y_head[other] * scale, 'o', mfc='none', color=color,
                    label='headline: materials as each run had them (another basis)')
        ax.set_ylabel(label)
        ax.set_xticks(k, labels, fontsize=7)
        ax.set_xlabel('run')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return _png(fig)


def pose_figure(pose: dict) -> bytes:
    """The per-cloud correction of the reference pose (summary.json's
    ``reference_pose``): translation (cm) and rotation (deg) per axis against time."""
    clouds = pose['clouds']
    t = np.array([c['t_s'] for c in clouds])
    d = np.array([c['translation_m'] for c in clouds]) * 100.0
    w = np.array([c['rotation_deg'] for c in clouds])
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4))
    for ax, v, label in ((axes[0], d, 'translation (cm)'), (axes[1], w, 'rotation (deg)')):
        for j, axis in enumerate('xyz'):
            ax.plot(t - t.min(), v[:, j], 'o-', ms=3, label=axis)
        ax.axhline(0, color='k', lw=0.8)
        ax.set_xlabel('time since the first cloud (s)')
        ax.set_ylabel(f'{label}, lidar frame')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return _png(fig)


def unmatched_figure(matching, divergence_rad: float) -> bytes:
    un = ~matching.matched
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    r = matching.meas.range_m
    bins = np.linspace(r.min(), r.max(), 50) if np.ptp(r) > 0 else 10
    axes[0].hist(r[matching.matched], bins=bins, alpha=0.5, density=True, label='matched')
    axes[0].hist(r[un], bins=bins, alpha=0.6, density=True, label='unmatched')
    axes[0].set_xlabel('measured range (m)')
    axes[0].legend(fontsize=8)
    d = matching.edge_rad[un] / divergence_rad
    levels, counts = np.unique(np.round(d, 3), return_counts=True)
    axes[1].bar([f'{x:g}' for x in levels], counts, color='tab:purple')
    axes[1].set_xlabel('angular distance to the silhouette (beam divergences; 16 = far)')
    axes[1].set_ylabel('unmatched points')
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return _png(fig)


def scene_figure(matching, divergence_rad: float, isolated: np.ndarray | None) -> bytes:
    """Azimuth/elevation view of the analysed points: target points grey, unmatched points
    painted by class (near the silhouette, clutter surface, isolated)."""
    d = matching.meas.directions
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    el = np.degrees(np.arcsin(np.clip(d[:, 2], -1, 1)))
    on = matching.matched
    near = ~on & (matching.edge_rad <= 2.0 * divergence_rad + 1e-12)
    alone = ~on & ~near & (isolated if isolated is not None else np.zeros(len(on), bool))
    clutter = ~on & ~near & ~alone
    fig, ax = plt.subplots(figsize=(10, 4.2))
    rng = np.random.default_rng(0)
    show = np.flatnonzero(on)
    show = show if len(show) <= MAX_SCATTER else rng.choice(show, MAX_SCATTER, False)
    ax.plot(az[show], el[show], '.', ms=1.5, color='0.7', label='on the target model')
    for mask, color, label in ((near, 'tab:blue', 'unmatched, near the silhouette'),
                               (clutter, 'tab:orange', 'unmatched, clutter surface'),
                               (alone, 'tab:red', 'unmatched, isolated')):
        if mask.any():
            ax.plot(az[mask], el[mask], '.', ms=3, color=color,
                    label=f'{label} ({int(mask.sum())})')
    ax.invert_xaxis()        # azimuth grows to the left (REP-103): as seen from the sensor
    ax.set_xlabel('azimuth (deg)')
    ax.set_ylabel('elevation (deg)')
    ax.set_aspect('equal')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc='upper right', markerscale=3)
    fig.tight_layout()
    return _png(fig)


def _table(rows: list[list], header: list[str]) -> str:
    head = ''.join(f'<th>{html.escape(str(h))}</th>' for h in header)
    body = ''.join('<tr>' + ''.join(f'<td>{html.escape(_fmt(c))}</td>' for c in row) + '</tr>'
                   for row in rows)
    return f'<table><tr>{head}</tr>{body}</table>'


def plan_table(rows: list[dict]) -> str:
    """The separation plan (summary.json's ``separation_plan``) as a table."""
    def way(w: dict) -> str:
        if w.get('skipped'):
            return 'not flown (the other way fails)'
        return ('n/a' if w['margin'] is None or w['z'] is None
                else f'{w["margin"]:.4f} (z {w["z"]:.1f})')
    names = list(rows[0]['ways'])
    body = [[r['recording'], f'{r["distance_m"]:.1f}', r['frames'], r['points'],
             *(way(r['ways'][n]) for n in names),
             'n/a' if r['margin'] is None else f'{r["margin"]:.4f}',
             'n/a' if r['z'] is None else f'{r["z"]:.1f}',
             'not simulated' if r.get('simulated') is False
             else ('yes' if r['separates'] else 'no')]
            for r in rows]
    return _table(body, ['recording', 'distance (m)', 'frames', 'points',
                         *(f'{n} data: margin (z)' for n in names), 'margin', 'z', 'separates'])


def _fmt(v) -> str:
    if isinstance(v, float):
        return 'n/a' if not np.isfinite(v) else f'{v:.5g}'
    if isinstance(v, dict):
        return ', '.join(f'{k} = {_fmt(x)}' for k, x in v.items())
    return '' if v is None else str(v)


CSS = """body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;
font-size:13px;text-align:left}th{background:#eee}.verdict{background:#fff6e0;padding:1em;
border-left:4px solid #e0a000}img{max-width:100%}code{background:#f3f3f3}
.headline{font-size:1.25em;font-weight:bold}pre.command{background:#f3f3f3;padding:0.8em;
white-space:pre-wrap;word-break:break-all;border-left:4px solid #2a7ae2}"""


def _plan_words(rows: list[dict]) -> str:
    """What the separation plan's rows are: the recordings a tie of the reference pose
    with a clock offset or with a range error would need (not simulated), or both
    confounded candidates flown by the simulator."""
    rival = next((n for n in rows[0].get('ways', {}) if n in MOTION_RIVALS), None)
    if rows[0].get('simulated') is False and rival is not None:
        what, how = MOTION_RIVALS[rival]
        return (f'The reference pose against {what}: not simulated (a reference pose error '
                'is no sensor effect the simulator flies). The target tumbling faster '
                f'({how}), and held still on a surveyed pose. The first is written as '
                'plan.yaml.')
    if rows[0].get('simulated') is False:
        return ('The reference pose against a range error of the sensor: not simulated (a '
                'reference pose error is no sensor effect the simulator flies). The target '
                'held still on a surveyed pose, near (seen across a wide angle: a pose error '
                'changes the range differently across the view, a range offset does not) '
                'and far (a range scale grows with the distance, a pose error does not). '
                'The near one is written as plan.yaml.')
    return ('Both confounded candidates as fitted (materials refit with each) flown '
            'by the simulator on each recording, and each simulated recording diagnosed '
            'as compare would: the held-out margin of the true hypothesis over the other '
            '(nats per point, the weaker of the two ways) and its z with the points '
            'compare would diagnose. It separates them when both ways clear the rule '
            '(margin at least 0.005 nats/point and z above the bound). The best is '
            'written as plan.yaml.')


def write_report(out: Path, summary: dict, matching, configured, residual_m: np.ndarray,
                 stats, feats, cands, runs: list[dict], model, values: dict,
                 isolated: np.ndarray | None = None, labels: dict | None = None) -> list[Path]:
    """Write DIR/report.html (figures embedded); return the written paths.

    ``matching``: the model's prediction on the analysed sample of rays; ``configured``:
    on every ray, materials as configured (for the per-material histograms);
    ``residual_m``: the sample's matched residuals, per-material offsets removed;
    ``values``: the feature values the attribution ranked, per matched sample point
    (``labels`` overrides their axis labels, e.g. intensity read as measured power);
    ``isolated``: per sample point, no neighbouring ray at the same range.
    """
    names = list(model.materials.names)
    s = summary
    figs = {
        'features': features_figure(feats, values, residual_m, names, labels=labels),
        'materials': materials_figure(configured, stats, names),
        'target': target_figure(matching, residual_m),
        'history': history_figure(runs),
    }
    if any(c.error is None for c in cands):
        figs['candidates'] = candidates_figure(cands)
    pose = s.get('pose_correction') or (s.get('reference_pose') if s.get('reference_pose_off')
                                        else None)
    if pose and pose.get('clouds'):
        figs['pose'] = pose_figure(pose)
    if s['unmatched_points']:
        figs['unmatched'] = unmatched_figure(matching, model.divergence_rad)
        figs['scene'] = scene_figure(matching, model.divergence_rad, isolated)
    why = opening.candidate_reasons(s)
    cand_rows = [[c.name, c.score, c.params, c.range_rmse_after_m, c.nll_after,
                  c.range_robust_sigma_after_m, c.unmatched_explained, c.z,
                  'vetoed' if c.vetoed else 'yes' if c.significant else 'no',
                  why.get(c.name, ''), c.yaml or c.error or ''] for c in cands]
    feat_rows = [[f.name, f.score, f.score_z, f.marginal, f.mean_part, f.spread_part,
                  f.significance, f.trend] for f in feats]
    mat_rows = [[n, m['points'], m['model_bias_m'], m['measured_bias_m'], m['model_sigma_m'],
                 m['measured_sigma_m'],
                 'yes' if (m['bias_mismatch'] or m['sigma_mismatch']) else 'no']
                for n, m in s['materials'].items()]
    unmatched = f'{s["unmatched_points"]} ({100 * s["unmatched_fraction"]:.2f} %)'
    head = [['points', s['points']],
            ['matched / unmatched', f'{s["matched_points"]} / {unmatched}'],
            ['range RMSE (m)', s['range_rmse_m']], ['NLL per point', s['nll_per_point']],
            ['range RMSE, per-material offsets refit (m)', s['range_rmse_calibrated_m']],
            ['NLL, per-material offsets and sigmas refit', s['nll_calibrated']],
            ['robust (MAD) sigma of the residual, per-material offsets refit (m)',
             s['range_robust_sigma_calibrated_m']],
            ['effects in the model', ', '.join(e['name'] for e in s['effects']) or 'none'],
            ['missing effect', s['missing_effect'] or 'none (null)'],
            ['intensity gain (measured / model)',
             s['intensity_gain']['gain'] if s['intensity_gain'] else 'no intensity']]
    # The opening: verdict in one line, the next command to copy, then the evidence.
    title = html.escape(opening.title(s))
    action = opening.next_command(s, out)
    parts = [
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">',
        f'<title>{title}</title>',
        f'<style>{CSS}</style></head><body>',
        f'<h1>{title}</h1>',
        f'<p class="headline">{html.escape(opening.headline(s))}</p>',
        (f'<p>{html.escape(action[0])}</p><pre class="command"><code>{html.escape(action[1])}'
         '</code></pre>') if action else '<p>Nothing to do: no effect to add.</p>',
        '<h2>Evidence</h2>',
        f'<p class="verdict">{html.escape(s["verdict"])}</p>',
        _table(head, ['quantity', 'value']),
        '<h2>Candidate effects (fitted by maximum likelihood, best first)</h2>',
        '<p>Score: held-out log-likelihood gain in nats per measured point (fitted on one '
        'half of the points, scored on the other) with per-material offsets and sigmas refit. '
        'RMSE, NLL and robust spread after: the model with the effect added, per-material '
        'offsets and sigmas refit (what --effect NAME --fit gives); compare them with the '
        'per-material-refit rows above, not with the headline RMSE/NLL.</p>',
        _table(cand_rows, ['effect', 'score', 'fitted params', 'RMSE after (m)', 'NLL after',
                           'robust sigma after (m)', 'unmatched explained', 'z', 'significant',
                           'why (or why not) the missing effect', 'scenario snippet']),
        _img(figs['candidates'], 'candidates') if 'candidates' in figs else
        '<p>No candidate effects were diagnosed in this run.</p>',
        '<h2>Where the model fails: residual against each feature</h2>',
        '<p>Score: held-out log-likelihood (nats per point) a joint model of the residual on '
        'all features loses without this one: what it explains given the others. Marginal: '
        'what it explains alone (binned). Features that explain the residual alone but not '
        'given the others stand in for each other: '
        f'{html.escape(", ".join(s["residual_structure"]["confounded"]) or "none")}.</p>',
        _table(feat_rows, ['feature', 'score', 'score z', 'marginal', 'mean part',
                           'spread part', 'significance', 'trend']),
        _img(figs['features'], 'residual vs top features'),
        '<h2>Per-material range error</h2>',
        _table(mat_rows, ['material', 'points', 'model bias (m)', 'measured bias (m)',
                          'model sigma (m)', 'measured sigma (m)', 'mismatch']),
        _img(figs['materials'], 'per-material residual histograms'),
        '<h2>Residual on the target</h2>',
        '<p>Matched points at their model hit position in the target body frame, coloured '
        'by the range residual (per-material offsets removed); crosses: unmatched points.</p>',
        _img(figs['target'], 'residual painted on the target'),
    ]
    if 'unmatched' in figs:
        u = s['unmatched']
        parts += ['<h2>Unmatched points (rays that miss the target model)</h2>',
                  f'<p>{u["points"]} points; {100 * u["near_silhouette_fraction"]:.0f} % within '
                  f'2 beam divergences of the silhouette; '
                  f'{100 * u["within_target_ranges_fraction"]:.0f} % at target ranges: '
                  f'{html.escape(u["interpretation"])}.</p>',
                  _img(figs['unmatched'], 'unmatched points'),
                  '<p>The view from the sensor: points on the target model in grey, the '
                  'unmatched ones coloured by what they look like: near the silhouette (beam '
                  'edge, pose), on a surface that is not the target (lab clutter: walls, '
                  'jigs, cables) or isolated (random ranges: false returns).</p>',
                  _img(figs['scene'], 'unmatched points in the view, clutter painted')]
    if 'pose' in figs:
        what = ('applied by --effect pose_error' if s.get('pose_correction')
                else 'that would explain the residual')
        parts += ['<h2>Reference pose: the correction per cloud</h2>',
                  f'<p>The rigid correction of the target pose {what}: RMS '
                  f'{pose_size_words(pose)} '
                  f'(held-out gain {pose["gain_per_matched_point"]:.4f} nats/point, '
                  f'z = {pose["z"]:.1f}). A reference error (tracking system, extrinsic '
                  'calibration), not a sensor effect.</p>',
                  _img(figs['pose'], 'reference pose correction per cloud')]
    if s.get('separation_plan'):
        parts += ['<h2>Which recording would separate the tie</h2>',
                  f'<p>{_plan_words(s["separation_plan"])}</p>',
                  plan_table(s['separation_plan'])]
    parts += ['<h2>History: the error across runs</h2>',
              f'<p>From {html.escape(s.get("history", ""))}. RMSE and NLL with each '
              'material\'s offset and sigma refit in every run (one basis for runs with and '
              'without --fit).</p>',
              _img(figs['history'], 'history'),
              _table([[i + 1, r.get('timestamp'), '+'.join(r.get('effects') or []) or 'baseline',
                       r.get('range_rmse_m'), r.get('nll_per_point'),
                       r.get('unmatched_fraction'), r.get('missing_effect')]
                      for i, r in enumerate(runs)],
                     ['run', 'time', 'effects', 'RMSE (m)', 'NLL', 'unmatched', 'missing effect'])]
    if s['notes']:
        parts += (['<h2>Notes</h2><ul>'] + [f'<li>{html.escape(n)}</li>' for n in s['notes']]
                  + ['</ul>'])
    parts.append('</body></html>')
    path = Path(out) / 'report.html'
    path.write_text('\n'.join(parts))
    return [path]


def materials_figure(matching, stats, names: list[str]) -> bytes:
    """Per-material histograms of measured minus modelled range (materials as configured)."""
    mat = np.asarray(matching.pred.ctx.material)
    shown = [s for s in stats if s.points >= 5]
    n = max(len(shown), 1)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.9 * rows), squeeze=False)
    for ax in axes.ravel()[len(shown):]:
        ax.axis('off')
    for ax, s in zip(axes.ravel(), shown):
        sel = matching.matched & (mat == names.index(s.name))
        r = matching.residual_m[sel] * 100
        d = (s.measured_bias_m - s.model_bias_m) * 100
        half = 5 * max(s.model_sigma_m, s.measured_sigma_m, 1e-3) * 100
        lo, hi = min(0.0, d) - half, max(0.0, d) + half
        bins = np.linspace(lo, hi, 41)
        ax.hist(np.clip(r, lo, hi), bins=bins, density=True, color='tab:blue', alpha=0.6,
                label='measured')
        xs = np.linspace(lo, hi, 200)
        sig = max(s.model_sigma_m * 100, 1e-3)
        ax.plot(xs, np.exp(-0.5 * (xs / sig) ** 2) / (sig * np.sqrt(2 * np.pi)), 'k-', lw=1.2,
                label='model')
        ax.axvline(d, color='tab:red', lw=1.2,
                   label='bias difference')
        ax.set_title(f'{s.name} ({s.points} pts)', fontsize=10)
        ax.set_xlabel('measured - model range (cm)')
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return _png(fig)
