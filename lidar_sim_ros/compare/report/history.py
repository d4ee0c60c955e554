"""history.json: one entry per ``lidar-sim compare`` run, so the error can be watched fall."""
from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path


def load_history(path: Path) -> list[dict]:
    """The runs recorded so far (an unreadable or foreign file raises, naming it)."""
    path = Path(path)
    if not path.exists():
        return []
    try:
        data = json.loads(path.read_text() or '[]')
    except json.JSONDecodeError as exc:
        raise ValueError(f'history file {path} is not valid JSON ({exc}); '
                         'move it away or pass another --history') from None
    runs = data.get('runs') if isinstance(data, dict) else data
    if not isinstance(runs, list):
        raise ValueError(f'history file {path}: expected a list of runs')
    return runs


def append_run(path: Path, entry: dict) -> list[dict]:
    """Append ``entry`` (timestamped now) to the history file and return all runs."""
    path = Path(path)
    runs = load_history(path)
    entry = {'timestamp': datetime.now(timezone.utc).isoformat(timespec='seconds'), **entry}
    runs.append(entry)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + '.tmp')
    tmp.write_text(json.dumps(runs, indent=2) + '\n')
    tmp.replace(path)
    return runs


def run_entry(summary: dict, effects: list[str], out_dir: Path, bag: Path) -> dict:
    """The history record of one run. Besides the headline figures (materials as
    configured, or refit with --fit: ``materials_refit``) it keeps the calibrated ones
    (each material's offset and sigma scale profiled out in every run): one basis on
    which runs with and without --fit compare."""
    return {'bag': str(bag), 'out': str(out_dir), 'effects': effects,
            'points': summary['points'], 'range_rmse_m': summary['range_rmse_m'],
            'nll_per_point': summary['nll_per_point'],
            'range_rmse_calibrated_m': summary.get('range_rmse_calibrated_m'),
            'nll_calibrated': summary.get('nll_calibrated'),
            'materials_refit': summary.get('materials_refit'),
            'unmatched_fraction': summary['unmatched_fraction'],
            'missing_effect': summary['missing_effect']}
