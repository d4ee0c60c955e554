"""The compare report as a reader gets it: its opening, and the page in headless Chromium.

The Chromium tests skip (with the reason) where the Debian package ``chromium`` is not
installed; .ci/run installs it. A screenshot of the page is left in the suite's
artefacts (LIDAR_SIM_TEST_ARTIFACTS, default test-artifacts/ in the repository).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from lidar_sim_ros.cli import main as cli_main
from lidar_sim_ros.paths import config_path, mesh_path

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which('chromium') or shutil.which('chromium-browser')
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason='headless Chromium not installed (Debian: apt-get install chromium)')
ARTIFACTS = Path(os.environ.get('LIDAR_SIM_TEST_ARTIFACTS', ROOT / 'test-artifacts'))

# Injected first into a copy of the page: collects console.error calls, uncaught errors
# and resources that fail to load (capture phase), and writes them into the DOM at load.
PROBE = ('<script>window.__errors=[];const __ce=console.error;'
         'console.error=(...a)=>{__errors.push("console.error: "+a.join(" "));__ce(...a)};'
         'addEventListener("error",ev=>{__errors.push(ev.message?"uncaught: "+ev.message:'
         '"failed to load: "+(ev.target.src||ev.target.href||ev.target.tagName))},true);'
         'addEventListener("load",()=>{document.body.setAttribute("data-errors",'
         'JSON.stringify(__errors))});</script>')


@pytest.fixture(scope='module')
def report(tmp_path_factory) -> Path:
    """A real report: one simulated frame with range walk, compared without candidates."""
    root = tmp_path_factory.mktemp('report')
    assert cli_main(['simulate', str(config_path('scenario.yaml')), '--frames', '1', '--out',
                     str(root / 'flight_03'), '--no-figures', '--effect',
                     'range_walk={k_m: 0.015}']) == 0
    out = root / 'runs' / 'baseline'
    assert cli_main(['compare', str(root / 'flight_03' / 'bag'), '--mesh',
                     str(mesh_path('rocket_body.obj')), '--out', str(out), '--max-points', '3000',
                     '--candidates']) == 0
    return out / 'report.html'


class _Outline(HTMLParser):
    """The page's blocks in order: (tag, class, text) of h1, h2, p and pre."""

    def __init__(self):
        super().__init__()
        self.blocks: list[list[str]] = []
        self._open: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        if tag in ('h1', 'h2', 'p', 'pre', 'title'):
            self._open = [tag, dict(attrs).get('class') or '', '']

    def handle_endtag(self, tag):
        if self._open is not None and tag == self._open[0]:
            self.blocks.append(self._open)
            self._open = None

    def handle_data(self, data):
        if self._open is not None:
            self._open[2] += data


def outline(path: Path) -> list[list[str]]:
    parser = _Outline()
    parser.feed(path.read_text())
    return parser.blocks


def test_report_opens_with_verdict_action_then_evidence(report):
    blocks = outline(report)
    summary = json.loads((report.parent / 'summary.json').read_text())
    title, h1, headline, action = blocks[:4]
    assert title == ['title', '', 'lidar-sim compare: flight_03']  # the recording, not "bag"
    assert h1[:1] == ['h1'] and h1[2] == title[2]
    assert headline[1] == 'headline' and '\n' not in headline[2]
    # No missing effect on this run: the headline is the verdict's first sentence.
    assert summary['missing_effect'] is None
    assert summary['verdict'].startswith(headline[2])
    # ... but the range walk's mean went into the material biases: refit them.
    assert action[0] == 'p' and action[2].startswith('No effect is missing, but the range')
    assert blocks[4][:2] == ['pre', 'command'] and '--fit --out' in blocks[4][2]
    evidence = blocks.index(['h2', '', 'Evidence'])
    assert evidence == 5 and blocks[6][1] == 'verdict'


def chromium(*args: str, timeout_s: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, '--headless', '--no-sandbox', '--disable-gpu',
                           '--hide-scrollbars', '--virtual-time-budget=5000', *args],
                          capture_output=True, text=True, timeout=timeout_s,
                          stdin=subprocess.DEVNULL)


def page_errors(page: Path, scratch: Path) -> list[str]:
    """What went wrong while Chromium loaded ``page``: console errors, uncaught errors,
    resources that failed to load."""
    probed = scratch / f'probed_{page.name}'
    probed.write_text(page.read_text().replace('<head>', '<head>' + PROBE, 1))
    proc = chromium('--dump-dom', probed.as_uri())
    assert proc.returncode == 0, proc.stderr[-2000:]
    start = proc.stdout.find('data-errors="')
    assert start >= 0, 'the page did not finish loading (no load event)'
    end = proc.stdout.index('"', start + len('data-errors="'))
    raw = proc.stdout[start + len('data-errors="'):end]
    return json.loads(raw.replace('&quot;', '"').replace('&amp;', '&'))


@needs_chromium
def test_report_renders_without_console_errors(report, tmp_path):
    assert page_errors(report, tmp_path) == []
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shot = ARTIFACTS / 'compare_report.png'
    proc = chromium('--window-size=1280,2400', f'--screenshot={shot}', report.as_uri())
    assert proc.returncode == 0 and shot.stat().st_size > 50_000


@needs_chromium
def test_the_probe_sees_errors(report, tmp_path):
    """The check itself: a page that logs an error and loads a missing image fails it."""
    broken = tmp_path / 'broken.html'
    broken.write_text(report.read_text().replace(
        '</body>', '<img src="missing.png"><script>console.error("boom")</script></body>'))
    errors = page_errors(broken, tmp_path)
    assert 'console.error: boom' in errors
    assert any(e.startswith('failed to load: ') and 'missing.png' in e for e in errors)
