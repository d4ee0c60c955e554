"""The opening of the compare report: the verdict in one line, the action as a command to
copy, and why the named effect beat the other candidates. Pure functions of the run's
``summary.json`` dict, so the page and the tests read the same facts.
"""
from __future__ import annotations

import re
import shlex
from pathlib import Path

from lidar_sim_ros.io.bag import recording_name
from lidar_sim_ros.paths import config_path


def _candidate(summary: dict, name: str | None) -> dict | None:
    return next((c for c in summary.get('candidates') or [] if c.get('name') == name), None)


def _first_sentence(text: str) -> str:
    match = re.match(r'(.+?[.!?])(\s|$)', text.strip())
    return match.group(1) if match else text.strip()


def title(summary: dict) -> str:
    """``lidar-sim compare: measured``: named for the recording, not its ``bag`` folder."""
    return f'lidar-sim compare: {recording_name(summary["bag"])}'


def headline(summary: dict) -> str:
    """The verdict in one line; a scan pattern that is off first (clouds without point
    times whose directions mostly miss the configured pattern: verdict.scan_pattern_off)."""
    share = summary.get('scan_pattern_match')
    if summary.get('point_times') == 'stamp' and share is not None and share < 0.5:
        return (f'Scan pattern off: only {100 * share:.0f} % of the directions match the '
                'configured pattern (fix it with lidar-sim calibrate scan). '
                + _headline(summary))
    return _headline(summary)


def _headline(summary: dict) -> str:
    missing = summary.get('missing_effect')
    cand = _candidate(summary, missing)
    if missing and cand is not None:
        before = (summary.get('candidates_basis') or {}).get('range_rmse_calibrated_m',
                                                              summary.get('range_rmse_calibrated_m'))
        after = cand.get('range_rmse_after_m')
        cut = (f' cuts the range RMSE from {before:.4f} m to {after:.4f} m'
               if before is not None and after is not None else ' improves the fit')
        return (f'Missing effect: {missing}. Adding it{cut} (held-out gain '
                f'{cand["score"]:.4f} nats/point, z = {cand.get("z", 0.0):.1f}).')
    return _first_sentence(summary.get('verdict', '')) or 'No verdict.'


def next_command(summary: dict, out_dir: str | Path) -> tuple[str, str] | None:
    """(what it does, the shell command) to run next, or None when nothing is left to do.

    A missing effect: the same comparison again with it added and fitted, into a folder
    beside this run's. Effects fitted and nothing missing: show the scenario snippet.
    """
    out_dir = Path(out_dir)
    missing = summary.get('missing_effect')
    cmd = ['lidar-sim', 'compare', summary['bag'], '--mesh', summary['mesh']]
    config = summary.get('config')
    if config and Path(config).resolve() != config_path('scenario.yaml').resolve():
        cmd += ['--config', config]
    for effect in summary.get('effects') or []:
        cmd += ['--effect', effect['name']]
    if missing:
        cmd += ['--effect', missing, '--fit', '--out', str(out_dir.parent / missing)]
        return f'Add {missing}, fitted, and compare again:', shlex.join(cmd)
    if summary.get('fitted_effects'):
        return ('Nothing is missing. Paste the fitted effects under "effects:" in the scenario '
                '(and materials.yaml over the materials file):',
                shlex.join(['cat', str(out_dir / 'effects.yaml')]))
    mismatched = [name for name, m in (summary.get('materials') or {}).items()
                  if m.get('bias_mismatch') or m.get('sigma_mismatch')]
    if mismatched:
        cmd += ['--fit', '--out', str(out_dir.parent / 'materials_fit')]
        return (f'No effect is missing, but the range bias/sigma of {", ".join(mismatched)} '
                'differ from the configuration: refit them (then use materials.yaml):',
                shlex.join(cmd))
    return None


def candidate_reasons(summary: dict) -> dict[str, str]:
    """Per candidate, why it is (or is not) the missing effect, against the named one."""
    missing = summary.get('missing_effect')
    best = _candidate(summary, missing)
    reasons = {}
    for c in summary.get('candidates') or []:
        name = c.get('name')
        share = c.get('structure_share')
        share_text = f'{100 * share:.0f} % of the residual\'s structure' if share is not None else ''
        if c.get('error'):
            reasons[name] = f'failed: {c["error"]}'
        elif best is not None and name == missing:
            reasons[name] = ('named: the largest held-out gain'
                             + (f', explains {share_text}' if share_text else ''))
        elif c.get('vetoed'):
            reasons[name] = f'vetoed: {c["vetoed"]}'
        elif not c.get('significant'):
            reasons[name] = f'not significant (z = {c.get("z", 0.0):.1f})'
        elif best is not None:
            parts = [f'gain {c["score"]:.4f} < {best["score"]:.4f} nats/point']
            best_share = best.get('structure_share')
            if share is not None and best_share is not None:
                parts.append(f'explains {100 * share:.0f} % of the residual\'s structure, '
                             f'{missing} {100 * best_share:.0f} %')
            after, best_after = c.get('range_rmse_after_m'), best.get('range_rmse_after_m')
            if after is not None and best_after is not None:
                parts.append(f'RMSE after {after:.4f} m vs {best_after:.4f} m')
            reasons[name] = f'significant, but {missing} explains more: ' + '; '.join(parts)
        elif not c.get('practical', True):
            reasons[name] = 'significant, but too small a gain to matter'
        else:
            reasons[name] = 'significant'
    return reasons
