# Copyright 2026 toc_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
The commands of README.md and docs/*.md run as written; their links resolve.

The rule: every ```bash / ```sh and ```python code block of README.md and docs/*.md is run
as written, in a scratch directory that sees the repository's config/, docs/ and launch/,
with the package's executables (toc-solve, ...) on the PATH: a bash block as one
`bash -e` script, a python block by this interpreter.  A block that cannot run here (the
set-up and whole-suite commands, the demo, nodes and launches that run until stopped,
commands that need a recording) carries the marker comment

    <!-- doc-test: skip: <reason> -->

on the line before its opening fence; the reason is required and shows in the test report.
Other blocks (yaml, plain output) are not commands and are not run.
"""

import os
from pathlib import Path
import re
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / 'README.md'] + sorted((ROOT / 'docs').glob('*.md'))
SHELL = ('bash', 'sh')
PYTHON = ('python',)
SKIP = re.compile(r'^<!--\s*doc-test:\s*skip:\s*(?P<reason>\S.*?)\s*-->$')
FENCE = re.compile(r'^```(?P<lang>[\w+-]*)\s*$')
LINK = re.compile(r'!?\[[^\]]*\]\((?P<target>[^)\s]+)\)')
# The first run compiles the numba kernels (minutes on a loaded 2-core machine).
TIMEOUT_S = 900
README_MAX_LINES = 150


def code_blocks(path):
    """Yield (language, line number, text, skip reason or None) of the fenced code blocks."""
    lines = path.read_text().split('\n')
    k = 0
    while k < len(lines):
        opening = FENCE.match(lines[k])
        if not opening:
            k += 1
            continue
        before = next((lines[j].strip() for j in range(k - 1, -1, -1) if lines[j].strip()), '')
        marker = SKIP.match(before)
        end = next((j for j in range(k + 1, len(lines)) if lines[j].startswith('```')), None)
        assert end is not None, f'{path.name}:{k + 1}: code block is not closed'
        yield (opening.group('lang').lower(), k + 1, '\n'.join(lines[k + 1:end]),
               marker.group('reason') if marker else None)
        k = end + 1


def _prose(path):
    """Return the text of a document without its code blocks (links live in the prose)."""
    text, inside = [], False
    for line in path.read_text().split('\n'):
        if line.startswith('```'):
            inside = not inside
            continue
        if not inside:
            text.append(line)
    return '\n'.join(text)


def _slug(heading):
    """Return the anchor GitHub gives a heading: lower case, no punctuation, hyphens."""
    text = re.sub(r'[^\w\- ]', '', heading.strip().lower())
    return text.replace(' ', '-')


def _anchors(path):
    return {_slug(line.lstrip('#')) for line in _prose(path).split('\n')
            if line.startswith('#')}


def _commands():
    for path in DOCUMENTS:
        for lang, line, text, reason in code_blocks(path):
            if lang in SHELL + PYTHON:
                yield pytest.param(path, lang, text, reason,
                                   id=f'{path.relative_to(ROOT)}:{line}')


@pytest.fixture
def workdir(tmp_path):
    """Return a scratch directory where the docs' relative paths resolve."""
    for name in ('config', 'docs', 'launch'):
        (tmp_path / name).symlink_to(ROOT / name)
    return tmp_path


def _env():
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(ROOT), env.get('PYTHONPATH')]))
    # The package's executables beside this interpreter (the venv's bin) come first.
    env['PATH'] = os.pathsep.join([os.path.dirname(sys.executable), env.get('PATH', '')])
    return env


@pytest.mark.slow
@pytest.mark.parametrize('path,lang,text,reason', list(_commands()))
def test_documented_command_runs_as_written(path, lang, text, reason, workdir):
    if reason is not None:
        pytest.skip(f'marked in {path.name}: {reason}')
    if lang in SHELL:
        argv = ['bash', '-e', '-o', 'pipefail', '-c', text]
    else:
        argv = [sys.executable, '-c', text]
    result = subprocess.run(argv, cwd=workdir, env=_env(), capture_output=True, text=True,
                            timeout=TIMEOUT_S)
    assert result.returncode == 0, (
        f'exit {result.returncode}\n--- block\n{text}\n--- stdout\n{result.stdout[-3000:]}'
        f'\n--- stderr\n{result.stderr[-3000:]}')


def test_every_command_block_runs_or_says_why_not():
    runnable = {path: [] for path in DOCUMENTS}
    for path in DOCUMENTS:
        for lang, line, _text, reason in code_blocks(path):
            assert not (reason is not None and lang not in SHELL + PYTHON), (
                f'{path.name}:{line}: a skip marker on a block that is not run ({lang!r})')
            if lang in SHELL + PYTHON and reason is None:
                runnable[path].append(line)
    # The documents that teach commands must have some that the test runs.
    for name in ('README.md', 'docs/cli.md', 'docs/solver.md'):
        assert runnable[ROOT / name], f'{name} has no command block that is run'


def test_readme_starts_with_the_product_and_runs_its_python_example():
    readme = ROOT / 'README.md'
    lines = readme.read_text().split('\n')
    assert len(lines) <= README_MAX_LINES, f'README.md has {len(lines)} lines'
    python = [(text, reason) for lang, _line, text, reason in code_blocks(readme)
              if lang in PYTHON]
    assert python, 'README.md has no Python example'
    text, reason = python[0]
    assert reason is None, 'the README Python example must be run by the test'
    assert 'from toc_ros.core import' in text and 'solve(' in text and 'Problem(' in text
    # The set-up commands that .ci/run and .ci/test depend on, verbatim.
    setup = next(text for lang, _line, text, _reason in code_blocks(readme) if lang in SHELL)
    assert setup.split('\n')[0].startswith('bash .ci/setup && .venv/bin/toc-demo')
    assert setup.split('\n')[1].startswith('bash .ci/test ')


@pytest.mark.parametrize('path', DOCUMENTS + [ROOT / 'CHANGELOG.md'],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_links_resolve(path):
    broken = []
    for match in LINK.finditer(_prose(path)):
        target = match.group('target')
        if re.match(r'^[a-z][a-z0-9+.-]*:', target):      # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition('#')
        resolved = (path.parent / file_part).resolve() if file_part else path
        if not resolved.exists():
            broken.append(f'{target} (no {resolved})')
        elif anchor and resolved.suffix == '.md' and anchor not in _anchors(resolved):
            broken.append(f'{target} (no heading #{anchor} in {resolved.name})')
    assert not broken, f'{path.name}: broken links: {broken}'


def test_docs_link_every_page():
    readme = ROOT / 'README.md'
    linked = {(readme.parent / m.group('target').partition('#')[0]).resolve()
              for m in LINK.finditer(_prose(readme))}
    missing = [p.name for p in DOCUMENTS[1:] if p.resolve() not in linked]
    assert not missing, f'docs pages not linked from README.md: {missing}'


def test_parameter_table_is_current():
    from toc_ros import docs_tables
    current = Path(docs_tables.DOC).read_text()
    assert docs_tables.render(current) == current, (
        'docs/ros_interface.md parameter table is out of date: '
        'python -m toc_ros.docs_tables --write')


def test_parameter_table_lists_every_node_parameter_once():
    from toc_ros import docs_tables
    from toc_ros.config import SCENARIO_TABLE
    from toc_ros.core.settings import parameter_table
    from toc_ros.arm_config import ArmSettings
    from toc_ros.nodes.parameters import PlantSettings, SolverNodeSettings
    # The names from the dataclass declarations themselves (not the nodes' name lists).
    declared = {p.name for p in SCENARIO_TABLE}
    declared |= {p.name for p in parameter_table(ArmSettings)}
    declared |= {p.name for p in parameter_table(SolverNodeSettings)}
    declared |= {p.name for p in parameter_table(PlantSettings)}
    table = Path(docs_tables.DOC).read_text().partition(docs_tables.BEGIN)[2].partition(
        docs_tables.END)[0]
    rows = re.findall(r'^\| `([^`]+)` \|', table, flags=re.M)
    assert len(rows) == len(set(rows))
    assert set(rows) == declared


def test_parameter_table_render_replaces_a_stale_table_and_needs_the_markers():
    from toc_ros import docs_tables
    stale = f'intro\n{docs_tables.BEGIN}\n| old | table |\n{docs_tables.END}\noutro\n'
    fresh = docs_tables.render(stale)
    assert fresh != stale and '| old | table |' not in fresh
    assert fresh.startswith('intro\n') and fresh.endswith('\noutro\n')
    assert docs_tables.render(fresh) == fresh
    with pytest.raises(ValueError):
        docs_tables.render('no markers here\n')
