"""Compile every cached numba kernel once, so that no node compiles at its first start.

``make venv`` runs ``python -m lidar_sim_ros.warm_up`` after installing. numba writes
the compiled kernels next to their sources (``__pycache__``, or ``NUMBA_CACHE_DIR``)
and later processes load them in a fraction of a second instead of compiling for
~10 s. The run exercises what the nodes run (a frame with interpolated and
extrapolated poses, the pose player's trajectory), then checks that every cached
kernel of the package has been compiled, so a new kernel the warm-up misses is
reported rather than compiled at a node's first start.

    python -m lidar_sim_ros.warm_up
"""
from __future__ import annotations

import importlib
import pkgutil
import sys
import time

import numpy as np

import lidar_sim_ros
from lidar_sim_ros.core.scenario import load_scenario
from lidar_sim_ros.core.pipeline import Simulator
from lidar_sim_ros.core.pose import ScenarioTrajectory
from lidar_sim_ros.paths import config_path

# Packages whose modules may hold kernels; the optional ones (ros, gnc) need extras.
KERNEL_PACKAGES = ('lidar_sim_ros.core',)


def cached_kernels() -> dict[str, object]:
    """Every ``@njit(cache=True)`` dispatcher in KERNEL_PACKAGES, by qualified name.

    Kernels inlined into their callers (``inline='always'``) are compiled with them and
    left out.
    """
    from numba.core.caching import FunctionCache
    from numba.core.registry import CPUDispatcher

    found = {}
    for pkg_name in KERNEL_PACKAGES:
        pkg = importlib.import_module(pkg_name)
        names = [pkg_name] + [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg_name + '.')]
        for name in names:
            module = importlib.import_module(name)
            for attr, obj in vars(module).items():
                # numba keeps cache=True only as the dispatcher's cache object.
                if (isinstance(obj, CPUDispatcher) and obj.__module__ == name
                        and isinstance(obj._cache, FunctionCache)
                        and obj.targetoptions.get('inline') != 'always'):
                    found[f'{name}.{attr}'] = obj
    return found


def warm_up() -> list[str]:
    """Run the kernels the nodes run; return the cached kernels still not compiled."""
    scenario = load_scenario(config_path('scenario.yaml'))
    Simulator.from_scenario(scenario).warm_up()
    ScenarioTrajectory.from_config(scenario.config).at(np.zeros(1))
    # Every catalogue effect on (beam footprint, sunlight, ...): frames of the real
    # trajectory, so that silhouettes, shadows and both thread paths are met.
    every = load_scenario(config_path('scenario_all_effects.yaml'))
    trajectory = ScenarioTrajectory.from_config(every.config)
    for threads in (1, 2):
        sim = Simulator.from_scenario(every, threads=threads)
        sim.warm_up()
        sim.simulate_frame(0.0, trajectory, 0)
    kernels = cached_kernels()
    ready = {name for name, kernel in kernels.items() if _ready(kernel)}
    # A kernel called only from other kernels is compiled into them (their cache holds
    # its code), so it is ready when a ready kernel calls it.
    while True:
        called = {name for name, kernel in kernels.items() if name not in ready
                  and any(_calls(kernels[r], kernel) for r in ready)}
        if not called:
            break
        ready |= called
    return sorted(set(kernels) - ready)


def _ready(kernel) -> bool:
    """Compiled in this process, or its own cache is on disk."""
    return bool(kernel.signatures) or bool(kernel._cache._cache_file._load_index())


def _calls(caller, callee) -> bool:
    """Whether ``caller``'s Python source names ``callee`` (a global of its module)."""
    code = caller.py_func.__code__
    names = set(code.co_names)
    for const in code.co_consts:            # nested functions and generator bodies
        if hasattr(const, 'co_names'):
            names |= set(const.co_names)
    return any(caller.py_func.__globals__.get(n) is callee for n in names)


def main() -> int:
    t0 = time.perf_counter()
    missing = warm_up()
    kernels = cached_kernels()
    if missing:
        print(f'warm-up: error: kernels not compiled by the warm-up: {missing}; add a call that '
              f'runs them to {__name__}.warm_up', file=sys.stderr)
        return 1
    print(f'warm-up: {len(kernels)} numba kernels of {lidar_sim_ros.__name__} compiled or loaded '
          f'from the cache in {time.perf_counter() - t0:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
