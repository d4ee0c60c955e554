"""compare/ reads as its data's way (docs/compare.md, "Code"): the recording in
(``recording``), the model on the measured rays (``model``), the diagnosis
(``diagnose``), the verdict and report (``report``), and the loop that calls them
(``run``, ``command``). Imports flow one way, down that list: a stage imports only the
stages before it (checked on the source, every import, also those inside functions)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

COMPARE = Path(__file__).resolve().parents[1] / 'lidar_sim_ros' / 'compare'
ORDER = ['recording', 'model', 'diagnose', 'report']


def _stage(module: str) -> str | None:
    """The sub-package of a dotted module under lidar_sim_ros.compare (None: elsewhere,
    'top': run/command/the package itself)."""
    prefix = 'lidar_sim_ros.compare'
    if module != prefix and not module.startswith(prefix + '.'):
        return None
    rest = module[len(prefix) + 1:].split('.')[0]
    return rest if rest in ORDER else 'top'


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out |= {f'{node.module}.{a.name}' for a in node.names}
    return out


@pytest.mark.parametrize('stage', ORDER)
def test_each_stage_imports_only_the_stages_before_it(stage: str):
    allowed = set(ORDER[:ORDER.index(stage) + 1])
    files = sorted((COMPARE / stage).glob('*.py'))
    assert files, stage
    bad = []
    for f in files:
        for m in _imports(f):
            s = _stage(m)
            if s is not None and s not in allowed and not (s == 'top' and m in (
                    'lidar_sim_ros.compare', f'lidar_sim_ros.compare.{stage}')):
                bad.append(f'{f.name} imports {m}')
    assert not bad, bad


def test_no_module_left_beside_the_stages():
    loose = sorted(p.name for p in COMPARE.glob('*.py'))
    assert loose == ['__init__.py', 'command.py', 'run.py'], loose
