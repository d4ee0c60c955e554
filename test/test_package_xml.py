"""package.xml, requirements*.txt and setup.py against what the code imports (as rosdep would).

Every third-party module imported anywhere in lidar_sim_ros/ or launch/ (at the top of a
module or inside a function) must resolve: to a rosdep key that package.xml declares as
an <exec_depend>, or, for modules without a usable rosdep key on Ubuntu 24.04 (Jazzy), to
a pip requirement in requirements*.txt and setup.py that package.xml's comment names.
Imports guarded by ``except ImportError`` are optional and need neither. A new import
fails here until it is declared; a declared key that nothing imports fails too.
"""
from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]

# import name -> (rosdep key or None, pip requirement name or None). Keys as in rosdistro's
# rosdep/base.yaml and python.yaml; None: no key that resolves on Ubuntu noble (python3-numba
# resolves only on bionic/focal), so pip installs it (docs/development.md).
RESOLVE: dict[str, tuple[str | None, str | None]] = {
    'numpy': ('python3-numpy', 'numpy'),
    'scipy': ('python3-scipy', 'scipy'),
    'matplotlib': ('python3-matplotlib', 'matplotlib'),
    'pydantic': ('python3-pydantic', 'pydantic'),
    'yaml': ('python3-yaml', 'PyYAML'),
    'sklearn': ('python3-sklearn', 'scikit-learn'),
    'tqdm': ('python3-tqdm', 'tqdm'),
    'trimesh': ('python3-trimesh-pip', 'trimesh'),
    'threadpoolctl': (None, 'threadpoolctl'),
    'embreex': (None, 'embreex'),
    'numba': (None, 'numba'),
    'rosbags': (None, 'rosbags'),
    'dask': (None, 'distributed'),  # dask comes with distributed
    'distributed': (None, 'distributed'),
    'small_gicp': (None, 'small_gicp'),
    'Basilisk': (None, 'bsk'),
    # ROS 2 packages: the key is the package name (pip users: requirements-ros.txt).
    **{name: (name, None) for name in (
        'rclpy', 'sensor_msgs', 'geometry_msgs', 'nav_msgs', 'std_msgs', 'rosgraph_msgs',
        'builtin_interfaces', 'rcl_interfaces', 'tf2_msgs', 'ament_index_python', 'launch',
        'launch_ros')},
}


def _is_import_error_guard(node: ast.Try) -> bool:
    for handler in node.handlers:
        names = ([handler.type] if not isinstance(handler.type, ast.Tuple)
                 else handler.type.elts) if handler.type is not None else []
        if any(isinstance(n, ast.Name) and n.id in ('ImportError', 'ModuleNotFoundError')
               for n in names):
            return True
    return False


def imports_of(path: Path) -> tuple[set[str], set[str]]:
    """(required, optional) top-level module names a Python file imports."""
    tree = ast.parse(path.read_text(), str(path))
    guarded: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and _is_import_error_guard(node):
            guarded |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    required, optional = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        (optional if id(node) in guarded else required).update(n.split('.')[0] for n in names)
    return required, optional


def third_party_imports() -> dict[str, list[str]]:
    """Required third-party module -> the files that import it."""
    found: dict[str, list[str]] = {}
    files = sorted((ROOT / 'lidar_sim_ros').rglob('*.py')) + sorted((ROOT / 'launch').glob('*.py'))
    for path in files:
        required, _ = imports_of(path)
        for name in required - set(sys.stdlib_module_names) - {'lidar_sim_ros'}:
            found.setdefault(name, []).append(str(path.relative_to(ROOT)))
    return found


def package_xml() -> tuple[set[str], str]:
    """(exec_depend keys, comment text) of package.xml."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.parse(ROOT / 'package.xml', parser).getroot()
    keys = {e.text.strip() for e in root.iter('exec_depend')}
    comments = ' '.join(e.text for e in root.iter() if e.tag is ET.Comment)
    return keys, comments


def pip_requirements() -> set[str]:
    names = set()
    for path in ROOT.glob('requirements*.txt'):
        for line in path.read_text().splitlines():
            line = line.split('#')[0].strip()
            if line:
                names.add(_canonical(Requirement(line).name))
    return names


def _canonical(name: str) -> str:
    return re.sub(r'[-_.]+', '-', name).lower()


def test_every_import_resolves_to_a_declared_dependency():
    imports = third_party_imports()
    keys, comments = package_xml()
    pip_names = pip_requirements()
    setup_text = (ROOT / 'setup.py').read_text()
    problems = []
    for name, files in sorted(imports.items()):
        if name not in RESOLVE:
            problems.append(f'{name} (imported by {files[0]}) has no rosdep key or pip name in '
                            'test_package_xml.RESOLVE: declare it in package.xml and here')
            continue
        key, pip_name = RESOLVE[name]
        if key is not None and key not in keys:
            problems.append(f'{name} (imported by {files[0]}): package.xml lacks '
                            f'<exec_depend>{key}</exec_depend>')
        if key is None:
            if pip_name not in comments:
                problems.append(f'{name}: no rosdep key, so package.xml\'s comment must name '
                                f'the pip requirement {pip_name!r}')
            if f"'{pip_name}" not in setup_text:
                problems.append(f'{name}: setup.py does not require {pip_name!r}')
        if pip_name is not None and _canonical(pip_name) not in pip_names:
            problems.append(f'{name}: no requirements*.txt lists {pip_name!r}')
    assert not problems, '\n'.join(problems)


def test_every_declared_key_is_imported():
    """A key no module imports is a stale dependency (or this map lacks its import name)."""
    used = {RESOLVE[name][0] for name in third_party_imports() if name in RESOLVE}
    keys, _ = package_xml()
    assert keys - used == set()


def test_the_scan_sees_lazy_imports_and_skips_optional_ones(tmp_path):
    """The checker itself: an import inside a function counts, one under
    ``except ImportError`` does not."""
    src = tmp_path / 'm.py'
    src.write_text('import os\n'
                   'def f():\n    from sklearn.linear_model import HuberRegressor\n'
                   'try:\n    import pyarrow.csv\nexcept ImportError:\n    pass\n')
    assert imports_of(src) == ({'os', 'sklearn'}, {'pyarrow'})
