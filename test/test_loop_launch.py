"""launch/loop.launch.py and docs/loop.md's parameter tables against the loop nodes' code
(no `launch` package in the venv: the launch file is compiled and read as Python)."""
import ast
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
LOOP_NODES = {'loop_dynamics': 'dynamics_node.py', 'loop_controller': 'controller_node.py',
              'loop_cloud_gate': 'cloud_gate_node.py'}


def declared(node_file: str) -> dict:
    """name -> default of the start-up parameters a loop node declares (``p('name', default, ...)``)."""
    tree = ast.parse((ROOT / 'lidar_sim_ros' / 'loop' / node_file).read_text())
    out, names = {}, {}
    for node in ast.walk(tree):   # breadth first: a default naming an earlier parameter (its variable) resolves
        call = node.value if isinstance(node, ast.Assign) else node
        if isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id == 'p':
            value = eval(compile(ast.Expression(call.args[1]), node_file, 'eval'), {}, dict(names))
            out[ast.literal_eval(call.args[0])] = value
            if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
                names[node.targets[0].id] = value
    return out


def node_parameters(executable: str) -> set:
    if executable in LOOP_NODES:
        return set(declared(LOOP_NODES[executable])) | {'use_sim_time'}
    if executable == 'lidar_sim_node':
        from lidar_sim_ros.ros import lidar_sim_node as node
        return set(node.STARTUP_PARAMETERS) | set(node.DYNAMIC_PARAMETERS) | {'use_sim_time'}
    from lidar_sim_ros.gnc import pose_tracker_node as tracker
    from lidar_sim_ros.gnc.tracker import TrackerConfig
    return set(tracker.PARAMETERS) | set(TrackerConfig.model_fields) | {'use_sim_time'}


def test_the_launch_file_starts_the_five_nodes_with_parameters_they_declare():
    source = (ROOT / 'launch' / 'loop.launch.py').read_text()
    tree = ast.parse(source)
    compile(tree, 'loop.launch.py', 'exec')
    scripts = set(re.findall(r"'(\w+) = lidar_sim_ros", (ROOT / 'setup.py').read_text()))
    nodes = {}
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, 'id', None) == 'Node':
            kw = {k.arg: k.value for k in call.keywords}
            executable = ast.literal_eval(kw['executable'])
            assert ast.literal_eval(kw['name']) == executable and executable in scripts
            params = kw['parameters'].elts[0]
            nodes[executable] = {ast.literal_eval(k) for k in params.keys}
    assert set(nodes) == {'loop_dynamics', 'lidar_sim_node', 'loop_cloud_gate', 'pose_tracker', 'loop_controller'}
    for executable, params in nodes.items():
        assert params <= node_parameters(executable), (executable, params - node_parameters(executable))
    # The demo starts the same nodes.
    demo = (ROOT / 'lidar_sim_ros' / 'loop' / 'demo.py').read_text()
    for module in ('loop.dynamics_node', 'ros.lidar_sim_node', 'loop.cloud_gate_node', 'gnc.pose_tracker_node',
                   'loop.controller_node'):
        assert f'lidar_sim_ros.{module}' in demo


def test_docs_tables_list_each_loop_node_s_parameters_and_defaults():
    lines = (ROOT / 'docs' / 'loop.md').read_text().splitlines()
    for node, node_file in LOOP_NODES.items():
        start = next(i for i, line in enumerate(lines) if line.startswith(f'`{node}`') and line.endswith(':'))
        assert lines[start + 2] == '| parameter | default | meaning |'
        table = {}
        for text in lines[start + 4:]:
            if not text.startswith('|'):
                break
            cells = [c.strip() for c in text.split('|')[1:-1]]
            table[cells[0].strip('`')] = yaml.safe_load(cells[1].strip('`'))
        code = declared(node_file)
        assert set(table) == set(code), (node, set(table) ^ set(code))
        for name, default in code.items():
            assert table[name] == default or (default == '' and table[name] == "''"), (node, name, default)
