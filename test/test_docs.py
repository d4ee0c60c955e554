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
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

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
           'ROS_DOMAIN_ID': os.environ.get('ROS_DOMAIN_ID', '0')}
    return subprocess.run(['bash', '-c', step.command], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL)


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
            output = proc.stdout + proc.stderr
            where = f'{page.relative_to(ROOT)}:{step.line}: $ {step.command}'
            expects_error = any('error:' in line for line in step.expected)
            assert proc.returncode == 0 or expects_error, \
                f'{where}\nexit {proc.returncode}:\n{output[-2000:]}'
            missing = missing_lines(step.expected, output)
            assert not missing, (f'{where}\nthe page quotes lines the command no longer prints:\n'
                                 + '\n'.join(missing) + f'\n--- it printed:\n{output[-3000:]}')


def test_every_page_has_a_checked_block():
    """The pages whose commands are cheap to run keep at least one checked transcript."""
    checked = {p.name for p, blocks in PAGE_BLOCKS.items() if blocks}
    assert {'offline.md', 'node.md', 'compare.md'} <= checked


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
