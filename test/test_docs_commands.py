"""
The commands of the README and of docs/ run, so that the docs cannot rot.

Every fenced block marked ``bash``, ``sh`` or ``console`` in README.md and docs/*.md is run
here at small sizes, unless the line before it says why not::

    <!-- not run: needs a ROS 2 install (the ros2 CLI) -->

A block that is run: each of its command lines (in a ``console`` block, each line after
``$ ``; the other lines are the output it shows) runs in bash, in one scratch folder where
``bags/`` and ``config/`` are the repository's and ``python`` is this venv's. ``SMALL``
appends options that shrink the command first (argparse keeps an option's last value). It
must exit with 0, or with N after ``<!-- run: exit=N -->``, and print each output line the
block shows. Identical command lines run once. One run is trained, before anything else:
``SHARED_RUN``, the README tour's; every other ``runs/<name>`` the commands name is a link
to it. A fenced block without a language that holds a command fails the check: it would
escape this test. The blocks not run are not test items (nothing is skipped): the check of
every block asks each for its reason.
"""
from dataclasses import dataclass
import os
from pathlib import Path
import re
import shlex
import signal
import subprocess
import sys
from typing import Dict, List, Optional, Tuple

from domains import ros_domain
from pg_node.tools import processes
import pytest

REPO = Path(__file__).resolve().parent.parent
PAGES = [REPO / 'README.md', *sorted((REPO / 'docs').glob('*.md'))]
DOMAIN_ID = ros_domain(base=210, spread=20)

#: the block languages whose commands run
LANGUAGES = ('bash', 'sh', 'console')
#: ``<!-- not run: REASON -->`` or ``<!-- run: exit=N -->`` on the line before a block
MARKER = re.compile(r'<!--\s*(not run|run):(.*?)-->')
FENCE = re.compile(r'\s*```(\S*)')
#: a line that is a command: in a block without a language, it fails the check
COMMAND_LINE = re.compile(r'\s*(\$ |python -m |python3 -m |make |ros2 |colcon |pip |\.venv/)')

#: the one trained run: the README tour's command, trained once (with SMALL's sizes)
SHARED_RUN = 'python -m pg_node train --run-dir runs/reach'
#: options appended to ``python -m pg_node <command>`` so that it runs in seconds
SMALL = {
    'train': ['--total-steps', '2048', '--seed', '0', '--eval-episodes', '2', '--no-progress'],
    'play': ['--episodes', '1'],
    'eval': ['--episodes', '2'],
}
#: repository folders the commands name, linked into the scratch folder
LINKED = ('bags', 'config')
TIMEOUT = {'train': 300}
DEFAULT_TIMEOUT = 120


@dataclass
class Block:
    """A fenced block of a page, and the marker on the line before it."""

    page: str
    line: int                               # the opening fence's line, from 1
    language: str
    text: str
    marker: Optional[Tuple[str, str]]       # ('not run', reason), ('run', options) or None

    @property
    def where(self) -> str:
        return f'{self.page}:{self.line}'

    @property
    def runs(self) -> bool:
        """Whether this test runs the block."""
        return self.language in LANGUAGES and (self.marker or ('',))[0] != 'not run'


def collect(text: str, page: str = '') -> Tuple[List[Block], List[str]]:
    """Return the fenced blocks of ``text``, and its markers that precede no block."""
    lines = text.split('\n')
    found, dangling, i = [], [], 0
    while i < len(lines):
        fence = FENCE.fullmatch(lines[i].rstrip())
        marker = MARKER.fullmatch(lines[i].strip())
        if marker:
            k = i + 1
            while k < len(lines) and not lines[k].strip():
                k += 1
            if k == len(lines) or not FENCE.fullmatch(lines[k].rstrip()):
                dangling.append(f'{page}:{i + 1}: a marker with no fenced block after it')
        if not fence:
            i += 1
            continue
        start, body = i, []
        i += 1
        while i < len(lines) and not FENCE.fullmatch(lines[i].rstrip()):
            body.append(lines[i])
            i += 1
        k = start - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        before = MARKER.fullmatch(lines[k].strip()) if k >= 0 else None
        found.append(Block(page, start + 1, fence.group(1), '\n'.join(body),
                           (before.group(1), before.group(2).strip()) if before else None))
        i += 1
    return found, dangling


def steps(block: Block) -> List[Tuple[str, List[str]]]:
    """Return the block's commands, each with the output lines the block shows for it."""
    if block.language == 'console':
        out = []
        for line in block.text.split('\n'):
            if line.startswith('$ '):
                out.append((line[2:].strip(), []))
            elif out and line.strip():
                out[-1][1].append(line.rstrip())
        return out
    joined = block.text.replace('\\\n', ' ')
    return [(line.strip(), []) for line in joined.split('\n')
            if line.strip() and not line.strip().startswith('#')]


def expected_exit(block: Block) -> int:
    """Return the exit code the block's commands must end with (``run: exit=N``, else 0)."""
    if block.marker and block.marker[0] == 'run':
        return int(re.fullmatch(r'exit=(\d+)', block.marker[1]).group(1))
    return 0


def problems(block: Block) -> List[str]:
    """Return what is wrong with a block's marking (nothing for a good one)."""
    where = f'{block.where}: '
    if block.language not in LANGUAGES:
        commands = [ln for ln in block.text.split('\n') if COMMAND_LINE.match(ln)]
        if commands:
            return [where + f'a command in a block without a language ({commands[0].strip()!r})'
                    ': label it bash or console, so that it is run or says why not']
        return [where + 'a marker on a block that is not bash, sh or console'] \
            if block.marker else []
    if not block.marker:
        return []
    kind, text = block.marker
    if kind == 'not run' and not text:
        return [where + '<!-- not run: REASON -->: the reason is missing']
    if kind == 'run' and not re.fullmatch(r'exit=\d+', text):
        return [where + f'<!-- run: {text} -->: the only option is exit=N']
    if block.runs and not steps(block):
        return [where + 'a block that is run holds no command']
    return []


def sized(command: str) -> str:
    """Return ``python -m pg_node X ...`` without its comment, SMALL's options appended."""
    words = shlex.split(command, comments=True)
    if words[:3] != ['python', '-m', 'pg_node'] or len(words) < 4:
        return command
    assert not {'&&', '||', '|', ';', '&'} & set(words), f'one command per line: {command}'
    return shlex.join(words + SMALL.get(words[3], []))


def all_blocks() -> List[Block]:
    return [b for page in PAGES
            for b in collect(page.read_text(), str(page.relative_to(REPO)))[0]]


def run_names(blocks: List[Block]) -> List[str]:
    """Return the run folders under ``runs/`` that the run blocks' commands name."""
    return sorted({m for b in blocks if b.runs for c, _ in steps(b)
                   for m in re.findall(r'\bruns/(\w+)', c)})


class Scratch:
    """A scratch folder in which the docs' commands run; each command line runs once."""

    def __init__(self, root: Path):
        self.root = root
        self.done: Dict[str, subprocess.CompletedProcess] = {}
        self.wrote: Dict[str, List[str]] = {}      # command -> the files it made, relative
        self.env = dict(os.environ, PYTHONPATH=str(REPO), ROS_DOMAIN_ID=str(DOMAIN_ID),
                        AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix),
                        PATH=f'{Path(sys.executable).parent}{os.pathsep}{os.environ["PATH"]}')
        self.env.pop('MUJOCO_GL', None)

    def run(self, command: str) -> subprocess.CompletedProcess:
        """Run ``command`` (sized) in bash here, once; return what it did."""
        line = sized(command)
        if line not in self.done:
            before = self.files()
            words = shlex.split(line, comments=True)
            timeout = TIMEOUT.get(words[3] if len(words) > 3 else '', DEFAULT_TIMEOUT)
            # a session of its own: a command that times out is stopped with all it started
            proc = subprocess.Popen(['bash', '-c', line], cwd=self.root, env=self.env,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    start_new_session=True)
            try:
                out, err = proc.communicate(timeout=timeout)
                code = proc.returncode
            except subprocess.TimeoutExpired:
                # to its whole session: train and play stop their nodes on SIGINT
                processes.stop(proc, ((signal.SIGINT, 30.0), (signal.SIGKILL, 5.0)))
                out, err = proc.communicate()
                err += f'\n(timed out after {timeout} s)'
                # timeout(1)'s status: a command stopped so may exit 0 (play, train), and a
                # play that waited for ever passed
                code = 124
            self.done[line] = subprocess.CompletedProcess(line, code, out, err)
            self.wrote[line] = sorted(self.files() - before)
        return self.done[line]

    def files(self) -> set:
        """Return the files here, relative (the linked folders and runs not entered)."""
        return {os.path.relpath(os.path.join(folder, name), self.root)
                for folder, _, names in os.walk(self.root) for name in names}


def failure(block: Block, done: subprocess.CompletedProcess, why: str) -> str:
    tail = '\n'.join((done.stdout + done.stderr).strip().splitlines()[-25:])
    return f'{block.where}: {why}\n$ {done.args}\n(exit code {done.returncode})\n{tail}'


# -- the collector and the marks: no command runs -------------------------------------------
def test_the_collector_sees_an_unmarked_block_and_a_missing_reason():
    text = '\n'.join([
        'Train:', '', '```bash', 'python -m pg_node train --run-dir runs/x  # a note', '```',
        '<!-- not run: needs a robot -->', '```bash', 'ros2 run pg_node policy_node', '```',
        '<!-- not run: -->', '', '```sh', 'make train', '```',
        '```', 'python -m pg_node eval runs/x', '```',
        '<!-- run: exit=2 -->', '```console', '$ python -m pg_node train gamma=1.5',
        'configuration error: ...', '```', '<!-- not run: a marker alone -->', ''])
    blocks, dangling = collect(text, 'page.md')
    assert [(b.line, b.runs) for b in blocks] == [(3, True), (7, False), (12, False),
                                                  (15, False), (19, True)]
    assert steps(blocks[0]) == [('python -m pg_node train --run-dir runs/x  # a note', [])]
    assert [p for b in blocks for p in problems(b)] == [
        'page.md:12: <!-- not run: REASON -->: the reason is missing',
        "page.md:15: a command in a block without a language ('python -m pg_node eval runs/x')"
        ': label it bash or console, so that it is run or says why not']
    assert dangling == ['page.md:23: a marker with no fenced block after it']
    assert steps(blocks[4]) == [('python -m pg_node train gamma=1.5',
                                 ['configuration error: ...'])]
    assert expected_exit(blocks[4]) == 2 and expected_exit(blocks[0]) == 0
    assert run_names(blocks) == ['x']


def test_small_sizes_are_appended_to_the_commands_they_shrink():
    assert sized('python -m pg_node train --run-dir runs/x  # a note') == (
        'python -m pg_node train --run-dir runs/x --total-steps 2048 --seed 0 '
        '--eval-episodes 2 --no-progress')
    assert sized("python -m pg_node eval runs/x --perturb 'mass_scale=1.3'") == (
        'python -m pg_node eval runs/x --perturb mass_scale=1.3 --episodes 2')
    assert sized('python -m pg_node export runs/x -o x.onnx   # and x.json') == \
        'python -m pg_node export runs/x -o x.onnx'
    assert sized('ros2 bag info /tmp/bag  # a note') == 'ros2 bag info /tmp/bag  # a note'


def test_every_block_of_the_docs_is_run_or_says_why_not():
    found = [p for page in PAGES for p in collect(page.read_text(),
                                                  str(page.relative_to(REPO)))[1]]
    found += [p for b in all_blocks() for p in problems(b)]
    assert found == []


def test_the_shared_run_is_the_readme_tour_s_training():
    readme = [b for b in all_blocks() if b.page == 'README.md' and b.runs]
    assert SHARED_RUN in [c for b in readme for c, _ in steps(b)]


# -- the commands -----------------------------------------------------------------------------
@pytest.fixture(scope='module')
def scratch(tmp_path_factory):
    """Return the scratch folder, with the shared run trained and lent to every run name."""
    root = tmp_path_factory.mktemp('docs')
    for name in LINKED:
        (root / name).symlink_to(REPO / name)
    shell = Scratch(root)
    done = shell.run(SHARED_RUN)
    assert done.returncode == 0, f'$ {done.args}\n{done.stdout}\n{done.stderr}'
    shared = root / SHARED_RUN.split()[-1]
    for name in run_names(all_blocks()):
        if not (root / 'runs' / name).exists():
            (root / 'runs' / name).symlink_to(shared.resolve())
    return shell


BLOCKS = all_blocks()


@pytest.mark.slow
@pytest.mark.e2e
@pytest.mark.parametrize('block', [b for b in BLOCKS if b.runs], ids=lambda b: b.where)
def test_the_commands_of_a_block_run(block, scratch):
    for command, shown in steps(block):
        done = scratch.run(command)
        assert done.returncode == expected_exit(block), failure(
            block, done, f'exit code {done.returncode}, not {expected_exit(block)}')
        printed = [line.rstrip() for line in (done.stdout + done.stderr).splitlines()]
        missing = [line for line in shown if line not in printed]
        assert missing == [], failure(block, done, f'it did not print {missing[0]!r}')


def ignored_by_git(paths: List[str]) -> List[str]:
    """Return those of ``paths`` (relative to a checkout) that .gitignore covers."""
    done = subprocess.run(['git', 'check-ignore', '--no-index', '--stdin'], cwd=REPO,
                          input='\n'.join(paths), capture_output=True, text=True)
    assert done.returncode in (0, 1), done.stderr       # 1: none of them
    return done.stdout.splitlines()


def test_git_ignore_is_asked_as_a_clone_would_be():
    assert ignored_by_git(['runs/reach/bag/x.mcap', 'runs/reach.gif', 'reach.gif',
                           'bags/mine/metadata.yaml']) == ['runs/reach/bag/x.mcap',
                                                           'runs/reach.gif',
                                                           'bags/mine/metadata.yaml']


@pytest.mark.slow
@pytest.mark.e2e
def test_the_readme_tour_writes_only_where_git_ignores(scratch):
    """A clone stays clean after the tour: its runs, curves, GIFs and ONNX go under runs/."""
    written = []
    for block in BLOCKS:
        if block.page == 'README.md' and block.runs:
            for command, _ in steps(block):
                scratch.run(command)
                written += scratch.wrote[sized(command)]
    assert 'runs/reach/summary.json' in written, written
    assert [p for p in written if p.endswith(('.png', '.gif', '.onnx', '.json'))
            and not p.startswith('runs/reach/')], written       # the tour's own outputs
    ignored = set(ignored_by_git(written))
    assert [path for path in written if path not in ignored] == []
