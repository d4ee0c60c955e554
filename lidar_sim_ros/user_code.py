"""Python files the operator names in a config (effect plugins, a loop's controller and
navigation filter), run once per process: loading one is running it, so only start-up
code paths call this, never a runtime parameter or a message."""
from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

_FILE_MODULES: dict[Path, ModuleType] = {}


def load_source_file(path: Path, prefix: str) -> ModuleType:
    """The module of the Python file ``path`` (resolved), executed at its first load and
    cached by path after that (loading twice gives the same classes). ``prefix`` names the
    module (``user_effect_``, ``user_gnc_``). TypeError for a file not ending in .py."""
    path = Path(path).expanduser().resolve()
    if path.suffix != '.py':
        # spec_from_file_location has no loader for other files ('NoneType' object...).
        raise TypeError(f'{path}: a plugin file is Python source ending in .py, '
                        f'not {path.name!r}')
    module = _FILE_MODULES.get(path)
    if module is None:
        spec = importlib.util.spec_from_file_location(f'{prefix}{path.stem}', path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _FILE_MODULES[path] = module
    return module
