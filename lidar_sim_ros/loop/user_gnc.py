"""Your own controller and navigation filter in the loop, named in the loop config.

    gnc:
      controller: my_gnc.pd:make_controller      # a module on the path, or
      navigation: filters.py:make_filter         # a file (relative to the loop config)

Each is an entry point ``where:factory``, loaded once when a run starts
(``load_user_gnc``, from ``build_context`` in process and so in every campaign worker, and
from ``loop_controller``'s start-up ``config_file``); it is read from the operator's config
file only: no runtime parameter or message names code. The factory is called with the
``LoopConfig`` and returns:

- controller: ``control(t_s, rho_m, rho_dot_mps, reference, n_rad_s) -> force_lvlh_n``:
  the force (N, LVLH, 3 numbers) for the next period from the navigation state at ``t_s``
  (the period's end), the guidance ``Reference`` (``rho_m``, ``rho_dot_mps``,
  ``rho_ddot_mps2``) and the orbit rate. The loop then clips it to the thrust limit and
  applies the dead band, as for the built-in PD.
- navigation: an object with ``update(t_s, rho_measured_m)`` (the chaser's position
  relative to the target in LVLH from the period's estimate, m; None when the period
  gave no estimate) and ``at(t_s) -> (rho_m, rho_dot_mps) | None`` (the state carried to
  ``t_s``; None: no state yet, the loop then waits with no force).

Keep both deterministic (no unseeded randomness, no wall clock): lock-step runs are then
identical to the bit with them too.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from lidar_sim_ros.user_code import load_source_file


def resolve_spec(spec: str | None, base_dir: Path) -> str | None:
    """A ``file.py:factory`` spec with the file made absolute against ``base_dir`` (the loop
    config's folder); a module spec as it is."""
    if spec is None:
        return None
    where, _, name = spec.rpartition(':')
    if where.endswith('.py') and not Path(where).expanduser().is_absolute():
        where = str((base_dir / Path(where).expanduser()).resolve())
    return f'{where}:{name}'


def load_entry_point(spec: str) -> Callable:
    """The callable named by ``module:name`` or ``path.py:name``; ValueError/ImportError say
    which spec could not be loaded."""
    where, sep, name = spec.rpartition(':')
    if not sep or not where or not name.isidentifier():
        raise ValueError(f"entry point {spec!r} must be 'module:function' or 'file.py:function'")
    if where.endswith('.py'):
        path = Path(where).expanduser().resolve()
        if not path.is_file():
            raise FileNotFoundError(f'entry point {spec!r}: no file {path}')
        module = load_source_file(path, 'user_gnc_')
    else:
        module = importlib.import_module(where)
    factory = getattr(module, name, None)
    if not callable(factory):
        raise ValueError(f'entry point {spec!r}: {name} is not a callable in {where}')
    return factory


@dataclass
class UserGnc:
    """The run's own controller and navigation (None: the built-in PD, alpha-beta filter)."""

    controller: Callable | None = None
    navigation: Any | None = None
    controller_spec: str | None = None

    def force(self, t_s: float, rho_m, rho_dot_mps, reference, n_rad_s: float) -> np.ndarray:
        """The user controller's force (N, LVLH), checked: 3 finite numbers."""
        force = np.asarray(self.controller(t_s, np.array(rho_m), np.array(rho_dot_mps), reference, n_rad_s),
                           dtype=float)
        if force.shape != (3,) or not np.isfinite(force).all():
            raise ValueError(f'controller {self.controller_spec} returned {force.tolist()!r} at t = {t_s:g} s: '
                             'expected 3 finite numbers (N, LVLH)')
        return force


def load_user_gnc(config) -> UserGnc | None:
    """Build the config's ``gnc`` entry points (None when neither is set)."""
    gnc = config.gnc
    if gnc.controller is None and gnc.navigation is None:
        return None
    controller = load_entry_point(gnc.controller)(config) if gnc.controller else None
    navigation = load_entry_point(gnc.navigation)(config) if gnc.navigation else None
    if navigation is not None and not (callable(getattr(navigation, 'update', None))
                                       and callable(getattr(navigation, 'at', None))):
        raise ValueError(f'navigation {gnc.navigation}: its factory must return an object with '
                         'update(t_s, rho_m) and at(t_s)')
    if controller is not None and not callable(controller):
        raise ValueError(f'controller {gnc.controller}: its factory must return a callable')
    return UserGnc(controller, navigation, gnc.controller)
