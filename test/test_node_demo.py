"""`make demo` end to end: two processes over real DDS, a rosbag2, figures."""
import subprocess
import sys

import pytest

from lidar_sim_ros.core.config import load_materials
from lidar_sim_ros.io.bag import read_clouds, read_material_names, read_poses
from lidar_sim_ros.paths import config_path
from conftest import private_domain_id

# Not the demo's random domain (1-101): two workers of pytest -n could draw the same one.
DOMAIN = ['--domain-id', str(private_domain_id(1, 19))]


@pytest.mark.timeout(120)
def test_demo_records_a_bag_and_draws_it(tmp_path):
    out = tmp_path / 'demo'
    result = subprocess.run([sys.executable, '-m', 'lidar_sim_ros.demo', '--out', str(out),
                             '--seconds', '1', *DOMAIN], capture_output=True, text=True, timeout=110)
    assert result.returncode == 0, result.stdout + result.stderr
    clouds = read_clouds(out / 'bag')
    assert len(clouds) >= 5  # 1 s at 10 Hz, give or take the start and stop
    period_ns = 100_000_000
    assert all(c.stamp_ns % period_ns == 0 for c in clouds)  # stamps on the frame grid
    assert len(read_clouds(out / 'bag', '/lidar/points_truth')) >= 5
    assert read_material_names(out / 'bag') == load_materials(config_path('materials.yaml')).names
    assert len(read_poses(out / 'bag').stamp_ns) >= 5 * len(clouds) - 10  # 50 Hz poses
    assert f'bag: {out / "bag"}' in result.stdout
    pngs = sorted(out.glob('*.png'))
    assert pngs and all(str(p) in result.stdout for p in pngs)
    # A second run replaces the bag rather than failing on it.
    again = subprocess.run([sys.executable, '-m', 'lidar_sim_ros.demo', '--out', str(out),
                            '--seconds', '0.5', *DOMAIN], capture_output=True, text=True, timeout=110)
    assert again.returncode == 0, again.stdout + again.stderr
