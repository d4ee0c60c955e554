"""Docs that cannot drift: the command blocks of README.md and docs/*.md marked to run.

A fenced block right after the line ``<!-- doc-test -->`` (``<!-- doc-test: slow -->``
for one that takes more than a few seconds) is a transcript: lines starting with
``$ `` are commands (a trailing backslash continues one), the lines after a command
are what it prints. Each page's marked blocks run in order in one scratch folder that
links ``config/``, ``meshes/`` and ``examples/`` of the repository, with ``lidar-sim``
and the nodes from this checkout. Every quoted output line must appear in the
command's output, in order (other lines may come between); ``...`` inside a line
stands for any text and a line of just ``...`` for lines left out. A command must
exit 0 unless its quoted output has an ``error:`` line.

Slow blocks run where LIDAR_SIM_DOCS_SLOW=1 (.ci/run sets it) and are skipped with
that reason elsewhere. When a test fails, run the command, paste its output into
the page and check the prose around it still says what the output shows.

Every other command block is accounted for: NOT_RUN lists, with the reason, the
blocks a test cannot run (DDS demos of minutes, colcon, pip, clusters, lab data
that is a placeholder), USAGE the synopses, whose options are checked against
``--help``. A new command block in none of these fails
``test_every_command_block_is_run_or_listed``; an entry whose block is gone fails too.
Quoted error messages without their command are in QUOTED_ONLY, with the test that
checks them.
The option tables of the CLI pages and the node's parameter table are checked
against the parser and the node's declared parameters.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]
MARK = re.compile(r'^<!-- doc-test(?:: *(slow))? -->\s*$')
SLOW_ENV = 'LIDAR_SIM_DOCS_SLOW'
TIMEOUT_S = 600


@dataclass
class Step:
    """One documented command and the output lines quoted under it."""

    command: str
    expected: list[str] = field(default_factory=list)
    line: int = 0


@dataclass
class Block:
    page: Path
    line: int
    slow: bool
    steps: list[Step]


def marked_blocks(page: Path) -> list[Block]:
    """The transcripts of ``page``: every fenced block right after a doc-test mark."""
    lines = page.read_text().splitlines()
    blocks, i = [], 0
    while i < len(lines):
        mark = MARK.match(lines[i])
        if mark is None:
            i += 1
            continue
        if i + 1 >= len(lines) or not lines[i + 1].startswith('```'):
            raise ValueError(f'{page.name}:{i + 1}: a doc-test mark must stand right above '
                             'a ``` block')
        end = next(j for j in range(i + 2, len(lines)) if lines[j].startswith('```'))
        blocks.append(Block(page, i + 2, bool(mark.group(1)), parse_steps(lines[i + 2:end], i + 3)))
        i = end + 1
    return blocks


def parse_steps(body: list[str], first_line: int) -> list[Step]:
    steps: list[Step] = []
    continued = False
    for k, text in enumerate(body):
        if continued:
            steps[-1].command += ' ' + text.strip().rstrip('\\').strip()
            continued = text.rstrip().endswith('\\')
        elif text.startswith('$ '):
            steps.append(Step(text[2:].rstrip().rstrip('\\').strip(), [], first_line + k))
            continued = text.rstrip().endswith('\\')
        elif steps:
            steps[-1].expected.append(text)
        elif text.strip():
            raise ValueError(f'line {first_line + k}: output before any "$ " command')
    return steps


def line_pattern(expected: str) -> re.Pattern:
    """A quoted line as a pattern: ``...`` matches any text, the rest literally."""
    parts = [re.escape(p) for p in expected.strip().split('...')]
    return re.compile('^' + '.*'.join(parts) + '$')


def missing_lines(expected: list[str], output: str) -> list[str]:
    """The quoted lines (in order) that ``output`` lacks; '' and '...' lines match anything."""
    got = [line.strip() for line in output.splitlines()]
    pos, missing = 0, []
    for want in expected:
        if want.strip() in ('', '...'):
            continue
        pattern = line_pattern(want)
        hit = next((k for k in range(pos, len(got)) if pattern.match(got[k])), None)
        if hit is None:
            missing.append(want.strip())
        else:
            pos = hit + 1
    return missing


def scratch_folder(tmp: Path) -> Path:
    for name in ('config', 'meshes', 'examples'):
        (tmp / name).symlink_to(ROOT / name)
    return tmp


def run_step(step: Step, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join([str(ROOT), os.environ.get('PYTHONPATH', '')]),
           'PATH': os.pathsep.join([str(Path(sys.executable).parent), os.environ.get('PATH', '')]),
           'ROS_DOMAIN_ID': os.environ.get('ROS_DOMAIN_ID', '0'), 'PYTHONUNBUFFERED': '1',
           # progress bars as wide as on a terminal, whatever runs the tests (no tty under xdist)
           'COLUMNS': '200'}
    # stdout and stderr in one stream, unbuffered: the lines in the order a terminal shows them
    return subprocess.run(['bash', '-c', step.command], cwd=cwd, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=TIMEOUT_S,
                          stdin=subprocess.DEVNULL)


PAGE_BLOCKS = {page: marked_blocks(page) for page in PAGES}


@pytest.mark.parametrize('page', [p for p, b in PAGE_BLOCKS.items() if b],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_documented_commands_print_what_the_page_quotes(page, tmp_path):
    blocks = PAGE_BLOCKS[page]
    if any(b.slow for b in blocks) and os.environ.get(SLOW_ENV) != '1':
        blocks = [b for b in blocks if not b.slow]
        if not blocks:
            pytest.skip(f'slow doc blocks of {page.name} run with {SLOW_ENV}=1 (as in .ci/run)')
    cwd = scratch_folder(tmp_path)
    for block in blocks:
        for step in block.steps:
            proc = run_step(step, cwd)
            output = proc.stdout
            where = f'{page.relative_to(ROOT)}:{step.line}: $ {step.command}'
            expects_error = any('error:' in line for line in step.expected)
            assert proc.returncode == 0 or expects_error, \
                f'{where}\nexit {proc.returncode}:\n{output[-2000:]}'
            missing = missing_lines(step.expected, output)
            assert not missing, (f'{where}\nthe page quotes lines the command no longer prints:\n'
                                 + '\n'.join(missing) + f'\n--- it printed:\n{output[-3000:]}')
    written = [p.name + ('/' if p.is_dir() else '') for p in cwd.iterdir()
               if p.name not in ('config', 'meshes', 'examples')]
    assert not unignored(written), (f'{page.name}: its commands, run from the repository root, '
                                    f'write {unignored(written)}, which .gitignore does not cover')


def unignored(paths: list[str]) -> list[str]:
    """The repository-relative ``paths`` (``dir/`` for a folder) that .gitignore does not cover."""
    return [p for p in paths if subprocess.run(['git', '-C', str(ROOT), 'check-ignore', '-q',
                                                '--no-index', p]).returncode != 0]


def test_every_page_has_a_checked_block():
    """The pages whose commands are cheap to run keep at least one checked transcript."""
    checked = {p.name for p, blocks in PAGE_BLOCKS.items() if blocks}
    assert {'offline.md', 'node.md', 'compare.md', 'calibration.md', 'sunlight.md',
            'real-data.md', 'campaign.md'} <= checked


# Command blocks no test runs, keyed by (page, the block's first line), with the reason.
NOT_RUN = {
    ('compare.md', '$ lidar-sim simulate config/scenario.yaml --frames 3 --out measured_drift'
                   ' --no-figures \\'):
        'the user-effect story (time first, the example DriftInFrame fitted from its file) '
        'runs end to end in test_compare.py::test_effect_outside_catalogue_time_first_and_'
        'user_effect_fixes_it; its two compares here took ~30 s of the suite (the time '
        'budget): the quotes are from a run of 2026-11-30',
    ('compare.md', '$ lidar-sim compare measured_drift/bag --mesh meshes/rocket_body.obj'
                   ' --out drift_runs/drift \\'):
        'the fit of the example effect from its file: test_compare.py::test_effect_outside_'
        'catalogue_time_first_and_user_effect_fixes_it (the suite\'s time budget)',
    ('README.md', 'make demo    # pose player + simulator node over real'
                  ' DDS -> rosbag2 + figures in demo-output/'):
        'make demo is a ~70 s DDS run and make test the whole suite; the demo runs in '
        'test_node_demo.py, its transcript is quoted in node.md',
    ('calibration.md', 'lidar-sim calibrate brdf lab/brdf.csv --out'
                       ' my/materials.yaml --figure my/brdf.png'):
        'lab/ files are placeholders for the user\'s own data; "Try it without lab data" runs '
        'range-errors and scan on simulated bags',
    ('calibration.md', 'lidar-sim simulate my/scenario.yaml --frames 10 --out my/run'):
        'my/ holds the files the placeholder lab calibration above writes',
    ('campaign.md', '# on the scheduler machine (port 8786; the dashboard'
                    ' needs bokeh, --no-dashboard otherwise)'):
        'a Dask cluster over several machines (test_campaign.py joins a local one by its address)',
    ('campaign.md', '# on the scheduler machine'):
        'a TLS cluster over several machines (test_campaign.py starts a TLS scheduler and joins it '
        'with the same options, and makes its certificates with the page\'s openssl commands)',
    ('campaign.md', 'lidar-sim campaign config/campaign_loop.yaml --out loop-campaign --workers 2'):
        'six closed loops of 8 s on Basilisk (~30 s with the cluster start); '
        'test_campaign_loop.py runs the same spec path on shorter cases',
    ('development.md', 'cd ~/ros2_ws/src && git clone <this repository> lidar_sim_ros'):
        'rosdep, pip, colcon and ros2 launch in a ROS workspace: outside the venv the tests use',
    ('gnc.md', 'pip install -e .[gnc]    # small_gicp; make venv installs it (requirements-gnc.txt)'):
        'pip, a DDS demo and a benchmark of minutes',
    ('gnc.md', 'ros2 run lidar_sim_ros pose_tracker --ros-args -p points_topic:=/lidar/points_truth'):
        'ros2 run of a node that runs until stopped (a colcon install)',
    ('loop.md', 'pip install -e .[loop,gnc]   # Basilisk and small_gicp (make venv installs both)'):
        'pip, a DDS demo and a benchmark of minutes',
    ('node.md', '$ make demo'):
        'a ~70 s DDS run (test_node_demo.py runs the demo)',
    ('node.md', 'ros2 launch lidar_sim_ros lidar_sim.launch.py                 # node + pose player'):
        'ros2 launch of nodes that run until stopped (a colcon install)',
    ('node.md', '.venv/bin/lidar_sim_node --ros-args --params-file config/params.yaml'):
        'nodes that run until stopped; test_node_dds.py starts them over DDS',
    ('real-data.md', '$ lidar-sim compare lab/bag --cloud-topic /cepton_pcl2'
                     ' --mesh target.obj --config lab.yaml --out cmp'):
        'lab/bag, target.obj and lab.yaml are placeholders for a real recording',
    ('real-data.md', 'ros2 run lidar_sim_ros lidar_sim_node --ros-args -p point_layout:=cepton \\'):
        'ros2 run of a node that runs until stopped (a colcon install)',
    ('real-data.md', 'ros2 run lidar_sim_ros lidar_sim_node --ros-args -p cepton_udp:=true \\'):
        'ros2 run of a node that runs until stopped; test_node_cepton_udp.py sends its packets live',
    ('real-data.md', 'lidar-sim compare lab/cepton.pcap --poses lab/poses.csv --mesh'
                     ' lab/target.obj --out runs/lab'):
        'lab/ files are placeholders for a real recording; test_cepton_layout.py '
        'compares a simulated pcap with bag and CSV poses',
}

# Synopses: (page, first line) -> the lidar-sim subcommand whose --help must know their options.
USAGE = {
    ('calibration.md', 'lidar-sim calibrate brdf CSV --out YAML [--material NAME] [--materials YAML]'):
        ('calibrate', 'brdf'),
    ('calibration.md', 'lidar-sim calibrate range-errors BAG [BAG ...] --mesh'
                       ' OBJ --out YAML [--config SCENARIO]'):
        ('calibrate', 'range-errors'),
    ('calibration.md', 'lidar-sim calibrate scan BAG --out SENSOR_YAML [--sensor'
                       ' YAML] [--figure PNG] [--cloud-topic T]'):
        ('calibrate', 'scan'),
    ('compare.md', 'lidar-sim compare BAG --mesh OBJ [--config SCENARIO] [--effect'
                   ' NAME_OR_MODULE:CLASS ...] [--fit] --out DIR'):
        ('compare',),
}

# Unmarked blocks that quote error messages without the command: (page, first line) -> where
# a test checks those messages instead.
QUOTED_ONLY = {
    ('compare.md', "lidar-sim compare: error: bag b: all 2 cloud(s) on '/lidar/points' are empty (no "
                   "finite, non-zero points; 0 non-finite, 0 at the origin)"):
        'bags built by a program: test_compare.py::test_bad_bags_name_the_problem',
}

SHELL_FENCES = ('```', '```sh', '```bash', '```console')
COMMAND = re.compile(r'^(\$ )?(lidar-sim|make|ros2|colcon|pip|python|dask|cd|cat|sed|lidar_sim_node'
                     r'|target_pose_player|pose_tracker|\.venv/bin/\S+)( |$)')
OUTPUT = re.compile(r'^([\w-]+( [\w-]+)*: )?(error|warning):')
FLAG = re.compile(r'(?<![\w-])--[a-z][a-z-]*')


def fenced_blocks(page: Path) -> list[tuple[int, str, list[str], bool]]:
    """(line, fence, body, marked) of every fenced block of ``page``."""
    lines = page.read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        if not lines[i].startswith('```'):
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith('```'))
        marked = i > 0 and MARK.match(lines[i - 1]) is not None
        out.append((i + 1, lines[i].strip(), lines[i + 1:end], marked))
        i = end + 1
    return out


def command_blocks(page: Path) -> list[tuple[int, str, bool]]:
    """(line, first line, marked) of the blocks of ``page`` that hold a shell command."""
    found = []
    for line, fence, body, marked in fenced_blocks(page):
        if fence not in SHELL_FENCES:
            continue
        if any(COMMAND.match(b.strip()) and not OUTPUT.match(b.strip()) for b in body):
            found.append((line, body[0], marked))
    return found


def test_command_detection():
    """What counts as a command block: commands yes, error listings and YAML no."""
    assert COMMAND.match('$ lidar-sim simulate x') and COMMAND.match('make demo  # x')
    assert COMMAND.match('.venv/bin/lidar_sim_node --ros-args')
    assert not COMMAND.match('lidar-simulate') and not COMMAND.match('seed: 1')
    assert OUTPUT.match('lidar-sim compare: error: bag b: x')
    assert OUTPUT.match('warning: two.csv: material')


def test_every_command_block_is_run_or_listed():
    """A command block is a doc-test transcript, or NOT_RUN / USAGE say why not; no stale entries."""
    unlisted, seen = [], set()
    for page in PAGES:
        for line, first, marked in command_blocks(page):
            key = (page.name, first)
            if key in NOT_RUN or key in USAGE:
                assert not marked, f'{page.name}:{line}: marked doc-test and listed as not run'
                seen.add(key)
            elif not marked:
                unlisted.append(f'{page.relative_to(ROOT)}:{line}: {first}')
    assert not unlisted, ('command blocks neither marked <!-- doc-test --> nor listed in '
                          'NOT_RUN/USAGE with a reason:\n' + '\n'.join(unlisted))
    stale = (set(NOT_RUN) | set(USAGE)) - seen
    assert not stale, f'NOT_RUN/USAGE entries whose block is gone (or changed): {sorted(stale)}'


def test_quoted_error_messages_are_run_or_listed():
    """An unmarked block quoting ``error:`` lines is in QUOTED_ONLY (and every entry still exists)."""
    found = {}
    for page in PAGES:
        for line, _, body, marked in fenced_blocks(page):
            if not marked and any(re.search(r'(^|: )error:', b) for b in body):
                found[(page.name, body[0])] = line
    unlisted = sorted(set(found) - set(QUOTED_ONLY))
    assert not unlisted, f'error messages quoted without a doc-test or a QUOTED_ONLY reason: {unlisted}'
    assert not set(QUOTED_ONLY) - set(found), 'QUOTED_ONLY entries whose block is gone (or changed)'


@contextlib.contextmanager
def _no_exit():
    try:
        yield
    except SystemExit:
        pass


def cli_help(*words: str) -> str:
    """``lidar-sim WORDS --help`` as the parser prints it (in-process)."""
    from lidar_sim_ros.cli import build_parser
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), _no_exit():
        build_parser().parse_args([*words, '--help'])
    return buf.getvalue()


def cli_flags(*words: str) -> set[str]:
    return set(FLAG.findall(cli_help(*words))) - {'--help'}


def block_text(page_name: str, first: str) -> str:
    page = ROOT / ('README.md' if page_name == 'README.md' else f'docs/{page_name}')
    body = next(b for _, _, b, _ in fenced_blocks(page) if b and b[0] == first)
    return '\n'.join(body)


@pytest.mark.parametrize('key', sorted(USAGE), ids=lambda k: ' '.join(USAGE[k]))
def test_usage_synopses_name_real_options(key):
    documented = set(FLAG.findall(block_text(*key)))
    unknown = documented - cli_flags(*USAGE[key])
    assert not unknown, f'{key[0]}: the synopsis of lidar-sim {" ".join(USAGE[key])} names ' \
                        f'options the command does not have: {sorted(unknown)}'


def option_table(page: Path) -> set[str]:
    """The options in the first column of ``page``'s "| option | ..." table."""
    lines = page.read_text().splitlines()
    start = next(i for i, t in enumerate(lines) if re.match(r'^\| option \|', t))
    flags = set()
    for text in lines[start + 2:]:
        if not text.startswith('|'):
            break
        flags |= set(FLAG.findall(text.split('|')[1]))
    return flags


@pytest.mark.parametrize('page, command', [('offline.md', ('simulate',)), ('compare.md', ('compare',)),
                                           ('campaign.md', ('campaign',))])
def test_option_tables_match_the_help(page, command):
    """Each option of the table exists, and each option of --help is on the page."""
    path = ROOT / 'docs' / page
    table, flags = option_table(path), cli_flags(*command)
    assert table - flags == set(), f'{page}: the option table names unknown options'
    mentioned = set(FLAG.findall(path.read_text()))
    assert flags - {'--debug'} - mentioned == set(), \
        f'{page}: options of lidar-sim {" ".join(command)} --help the page never mentions'


def test_node_parameter_table_matches_the_declared_parameters():
    """docs/node.md's table: the node's parameters, read-only exactly for the start-up ones."""
    from lidar_sim_ros.ros import lidar_sim_node as node
    lines = (ROOT / 'docs' / 'node.md').read_text().splitlines()
    start = lines.index('| parameter | default | read-only | meaning |')
    table, checked_defaults = {}, []
    for text in lines[start + 2:]:
        if not text.startswith('|'):
            break
        cells = [c.strip() for c in text.split('|')[1:-1]]
        names = re.findall(r'`(\w+)`', cells[0])
        for name in names:
            table[name] = cells[2]
        literal = re.fullmatch(r'`([^`]*)`', cells[1])  # a single default value, e.g. `-1`
        if len(names) == 1 and literal and names[0] in node.STARTUP_PARAMETERS | node.DYNAMIC_PARAMETERS:
            declared = {**node.STARTUP_PARAMETERS, **node.DYNAMIC_PARAMETERS}[names[0]][0]
            if not isinstance(declared, (str, int, float, bool, list)):
                declared = []  # declared by type only (Parameter.Type.STRING_ARRAY): empty
            documented = yaml.safe_load(literal.group(1))
            assert documented == declared or str(documented) == declared, \
                f'node.md: {names[0]} defaults to {declared!r}, the table says {literal.group(1)}'
            checked_defaults.append(names[0])
    declared_in_init = {'frame_id': 'no', 'effects': 'no', 'sun_direction': 'no',
                        'material_names': 'yes'}
    expected = {**{n: 'yes' for n in node.STARTUP_PARAMETERS},
                **{n: 'no' for n in node.DYNAMIC_PARAMETERS}, **declared_in_init}
    source = (ROOT / 'lidar_sim_ros' / 'ros' / 'lidar_sim_node.py').read_text()
    assert set(re.findall(r"declare_parameter\(\s*'(\w+)'", source)) == set(declared_in_init)
    assert table == expected
    assert len(checked_defaults) >= 10  # the rows with one literal default were compared


def test_readme_topic_table_names_the_node_topics():
    """README's topic table holds every topic the node subscribes or publishes by default."""
    from lidar_sim_ros.ros import lidar_sim_node as node
    readme = (ROOT / 'README.md').read_text()
    listed = set(re.findall(r'^\| `(/[\w/]+)`', readme, flags=re.M))
    defaults = {v for k, (v, _) in node.STARTUP_PARAMETERS.items() if k.endswith('_topic') and v}
    assert defaults and defaults <= listed, f'README lacks {sorted(defaults - listed)}'


def test_transcript_parsing_and_matching():
    """The checker itself: continuation lines, wildcards, order, left-out lines."""
    steps = parse_steps(['$ lidar-sim simulate a \\', '    --frames 2', 'bag: x  (2 frames, ... points)',
                         '...', 'figure: y', '$ cat z', 'z'], 10)
    assert [s.command for s in steps] == ['lidar-sim simulate a --frames 2', 'cat z']
    assert steps[0].line == 10 and steps[1].line == 15
    out = 'bag: x  (2 frames, 31000 points)\nnoise\nfigure: y\n'
    assert missing_lines(steps[0].expected, out) == []
    assert missing_lines(['figure: y', 'bag: x  (2 frames, ... points)'], out) == [
        'bag: x  (2 frames, ... points)']  # order matters
    assert missing_lines(['bag: x  (3 frames, ... points)'], out) == ['bag: x  (3 frames, ... points)']
    assert line_pattern('a.b (c)').match('a.b (c)') and not line_pattern('a.b').match('axb')
    assert unignored(['demo-output/', 'runs/', 'static_5.yaml']) == ['static_5.yaml']


def test_effect_lists_match_the_catalogue():
    """effects.md's table names every registered effect; quoted catalogue lists are current."""
    from lidar_sim_ros.core.effects import REGISTRY, catalogue
    catalogue()  # loads the catalogue and the by-name-only effects
    text = (ROOT / 'docs' / 'effects.md').read_text().splitlines()
    start = text.index('| name | models | forward model | parameters (default) | fit |')
    table = set()
    for row in text[start + 2:]:
        if not row.startswith('|'):
            break
        table.add(re.match(r'\| `(\w+)`', row).group(1))
    assert table == set(REGISTRY)
    for page in PAGES:
        for quoted in re.findall(r'catalogue: \[([^\]]*)\]', page.read_text()):
            names = re.findall(r"'(\w+)'", quoted)
            full = sorted(REGISTRY)
            assert names == (full[:len(names)] if '...' in quoted else full), \
                f'{page.name}: a quoted catalogue list is not the current one: [{quoted}]'


def test_receiver_table_matches_the_config_defaults():
    """sunlight.md's receiver table: every ReceiverConfig field, with its default."""
    from lidar_sim_ros.core.config import ReceiverConfig
    fields = ReceiverConfig.model_fields
    lines = (ROOT / 'docs' / 'sunlight.md').read_text().splitlines()
    start = lines.index('| key | default | why |')
    named, compared = set(), []
    for text in lines[start + 2:]:
        if not text.startswith('|'):
            break
        cells = [c.strip() for c in text.split('|')[1:-1]]
        names = re.findall(r'`([\w.]+)`', cells[0])
        if any('.' in n for n in names):
            continue  # sun.* rows: the SunConfig's, not the receiver's
        named |= set(names)
        values = [v.strip().strip('`') for v in cells[1].split(',')]
        if names and len(values) == len(names) and all(n in fields for n in names):
            for name, value in zip(names, values):
                default = fields[name].default
                documented = type(default)(value) if not isinstance(default, str) else value
                assert documented == default, \
                    f'sunlight.md: {name} defaults to {default}, the table says {value}'
                compared.append(name)
    assert named == set(fields), \
        f'sunlight.md receiver table vs ReceiverConfig: {sorted(named ^ set(fields))}'
    assert len(compared) >= 10


def _table(page: str, header: str) -> list[list[str]]:
    lines = (ROOT / 'docs' / page).read_text().splitlines()
    start = lines.index(header)
    rows = []
    for text in lines[start + 2:]:
        if not text.startswith('|'):
            break
        rows.append([c.strip() for c in text.split('|')[1:-1]])
    return rows


def test_campaign_tables_match_the_spec_models():
    """campaign.md: the dispersible keys are Dispersions' fields, each law's keys its model's."""
    import typing

    from pydantic import BaseModel

    from lidar_sim_ros.campaign import spec
    keys = {re.match(r'`(\w+)', row[0]).group(1)
            for row in _table('campaign.md', '| key | law | effect on the run |')}
    assert keys == set(spec.Dispersions.model_fields)
    laws = {}
    for obj in vars(spec).values():
        if isinstance(obj, type) and issubclass(obj, BaseModel) and 'dist' in obj.model_fields:
            (name,) = typing.get_args(obj.model_fields['dist'].annotation)
            laws[name] = set(obj.model_fields) - {'dist'}
    documented = {re.fullmatch(r'`(\w+)`', row[0]).group(1): set(re.findall(r'`(\w+)`', row[1]))
                  for row in _table('campaign.md', '| law | keys | draws |')}
    assert documented == laws
