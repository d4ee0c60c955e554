"""Where the package's config/ and meshes/ live: colcon share dir or the source tree."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

PACKAGE = 'lidar_sim_ros'


@lru_cache(maxsize=1)
def share_dir() -> Path:
    """The directory holding config/, meshes/ and launch/.

    The source tree (editable/pip installs) wins when it has them; otherwise the
    ament share directory of a colcon install.
    """
    src = Path(__file__).resolve().parents[1]
    if (src / 'config').is_dir():
        return src
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory(PACKAGE))
    except Exception:  # noqa: BLE001 - ament index missing or package not installed
        return src


def config_path(name: str) -> Path:
    return share_dir() / 'config' / name


def mesh_path(name: str) -> Path:
    return share_dir() / 'meshes' / name
