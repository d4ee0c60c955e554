"""The per-process cache of a campaign worker: the mesh with its Embree BVH and face
geometry, and the compiled kernels of each effect list, built once and reused by every run
the process gets (frame runs, ``run.py``, and closed-loop runs, ``loop_case.py``); only the
cheap per-run shell (scan directions, material table, effects: a few ms) is rebuilt,
because the dispersed materials and effects differ from run to run.
"""
from __future__ import annotations

import threading
from pathlib import Path

from lidar_sim_ros.campaign.coverage import FaceGeometry
from lidar_sim_ros.core.scenario import Scenario
from lidar_sim_ros.core.geometry import Target, load_target
from lidar_sim_ros.core.pipeline import Simulator

_TARGETS: dict[tuple, tuple[Target, FaceGeometry]] = {}
_WARM: set[tuple[str, ...]] = set()  # effect lists this process has run a frame with
_LOCK = threading.Lock()  # a multi-threaded worker builds each mesh once


def worker_target(scenario: Scenario) -> tuple[Target, FaceGeometry]:
    """The scenario's mesh (BVH built) and face geometry, loaded once per process."""
    path = Path(scenario.mesh_path)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size, tuple(scenario.materials.names),
           repr(scenario.mesh_materials))
    with _LOCK:
        if key not in _TARGETS:
            target = load_target(path, scenario.materials.names,
                                 mesh_materials=scenario.mesh_materials)
            _TARGETS[key] = (target, FaceGeometry.of(target))
        return _TARGETS[key]


def prepare_scenario(scenario: Scenario) -> bool:
    """Load the mesh and compile the kernels of this scenario's effects now, so that no
    run pays for them (once per process and list of effects). True if it had work to do."""
    effects = tuple(e.name for e in scenario.config.effects)
    if effects in _WARM:
        return False
    target, _ = worker_target(scenario)
    with _LOCK:
        if effects not in _WARM:
            Simulator.from_scenario(scenario, target=target).warm_up()
            _WARM.add(effects)
    return True
