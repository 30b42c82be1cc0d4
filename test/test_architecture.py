"""
The package's layers, as docs/architecture.md draws them.

Each subpackage of ``pg_node`` is a layer with a rank; a module may import its own layer and
the layers of lower rank, never a layer of the same rank or above (every import counts, also
one inside a function). No module imports itself back through others. The math (``rl``), the
labs, the simulator, the robot-facing layer (``control``) and the base layer import with
``rclpy`` made unimportable; the robot-facing layer and the base layer also without MuJoCo,
torch, onnxruntime or PyBullet.
"""
import ast
from pathlib import Path
import subprocess
import sys

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / 'pg_node'

#: layer -> rank; a module may import layers of lower rank and its own
LAYERS = {'common': 0, 'control': 1, 'sim': 2, 'rl': 3, 'bag': 3, 'lab': 4, 'ros': 4,
          'tools': 5}
#: modules at the package's top, above every layer
TOP = {'pg_node', 'pg_node.__main__'}
#: layers that must work without ROS 2 installed
ROS_FREE = ('common', 'control', 'sim', 'rl', 'lab')


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def imports_of(path: Path):
    """
    Return the pg_node modules that ``path`` imports, at any depth.

    ``from pg_node.x import y`` counts ``pg_node.x.y`` when that is a module, else ``pg_node.x``.
    """
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split('.')[0] == 'pg_node')
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f'{path}: relative import; pg_node imports absolutely'
            if node.module and node.module.split('.')[0] == 'pg_node':
                for alias in node.names:
                    sub = f'{node.module}.{alias.name}'
                    found.add(sub if sub in MODULES else node.module)
    return found


MODULES = {module_name(p): p for p in PACKAGE.rglob('*.py')}


def layer(module: str):
    parts = module.split('.')
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def test_every_module_sits_in_a_layer():
    loose = sorted(m for m in MODULES if m not in TOP and layer(m) is None)
    assert not loose, f'modules outside the layer subpackages: {loose}'
    assert set(LAYERS) <= {layer(m) for m in MODULES}


def test_imports_point_down_the_layers():
    wrong = []
    for mod, path in MODULES.items():
        if mod in TOP:
            continue
        here = layer(mod)
        for dep in imports_of(path):
            there = layer(dep)
            if dep in TOP or (there != here and LAYERS.get(there, 99) >= LAYERS[here]):
                wrong.append(f'{mod} -> {dep}')
    assert not wrong, 'imports that do not point down the layers:\n' + '\n'.join(wrong)


def find_cycles(graph):
    """Return the cycles that a depth-first walk of ``graph`` (module -> imports) meets."""
    state, cycles = {}, []

    def visit(m, stack):
        state[m] = 'open'
        for d in sorted(graph[m]):
            if state.get(d) == 'open':
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 'done'

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return cycles


def test_no_import_cycles():
    graph = {m: {d for d in imports_of(p) if d in MODULES and d != m}
             for m, p in MODULES.items()}
    cycles = find_cycles(graph)
    assert not cycles, 'import cycles: ' + '; '.join(' -> '.join(c) for c in cycles)


def test_the_checks_can_fail(tmp_path):
    """A cycle is found, and a lazy import inside a function counts as an import."""
    assert find_cycles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': set()}) == [['a', 'b', 'c', 'a']]
    (tmp_path / 'm.py').write_text('def f():\n    from pg_node.rl import gae\n'
                                   '    from pg_node.ros.sim_node import main\n')
    assert imports_of(tmp_path / 'm.py') == {'pg_node.rl.gae', 'pg_node.ros.sim_node'}


#: packages the ROS-free layers must not need
ROS_PACKAGES = ('rclpy', 'rosbags', 'rosidl_runtime_py')
#: packages the robot-facing layer must not need either: it runs beside any engine or none
ENGINE_PACKAGES = ROS_PACKAGES + ('mujoco', 'torch', 'onnxruntime', 'pybullet')

BLOCKER = """
import importlib, importlib.abc, pkgutil, sys

BLOCKED = tuple(sys.argv[1].split(','))

class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in BLOCKED:
            raise ImportError(f'{name} is not importable in this test')

sys.meta_path.insert(0, Blocker())
import pg_node
for layer in sys.argv[2:]:
    pkg = importlib.import_module('pg_node.' + layer)
    for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):
        importlib.import_module(info.name)
        print(info.name)
"""


def blocked_import(blocked, layers):
    """Import every module of ``layers`` with the ``blocked`` packages made unimportable."""
    return subprocess.run([sys.executable, '-c', BLOCKER, ','.join(blocked), *layers],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize('blocked, layers', [(ROS_PACKAGES, ROS_FREE),
                                             (ENGINE_PACKAGES, ('common', 'control'))])
def test_layers_import_without_what_they_must_not_need(blocked, layers):
    res = blocked_import(blocked, layers)
    assert res.returncode == 0, res.stderr[-3000:]
    imported = set(res.stdout.split())
    expected = {m for m in MODULES if layer(m) in layers and m.count('.') == 2}
    assert imported == expected


def test_the_ros_blocker_blocks():
    """A module that needs rclpy fails under the same blocker, so the test above can fail."""
    res = blocked_import(ROS_PACKAGES, ['ros'])
    assert res.returncode != 0 and 'not importable in this test' in res.stderr


#: what the repository's root holds: the package's files and the folders the docs name
ROOT_FILES = {'.gitignore', 'Makefile', 'README.md', 'package.xml', 'pytest.ini',
              'requirements.in', 'requirements.lock', 'setup.cfg', 'setup.py'}
ROOT_DIRS = {'.ci', 'bags', 'bench', 'config', 'docs', 'launch', 'pg_node', 'resource',
             'scripts', 'test'}


def stray_at_root(tracked):
    """Return the tracked paths whose first component is neither a root file nor a folder."""
    return sorted(p for p in tracked
                  if (p.split('/')[0] not in ROOT_DIRS if '/' in p else p not in ROOT_FILES))


def test_nothing_stray_is_tracked_at_the_root():
    # a shell redirect once committed a file named after a table cell, and a test's
    # MUJOCO_LOG.TXT was committed: the root holds what a package's root holds
    root = PACKAGE.parent
    listed = subprocess.run(['git', 'ls-files'], cwd=root, capture_output=True, text=True)
    if listed.returncode != 0:
        pytest.skip('not a git checkout')
    assert stray_at_root(listed.stdout.splitlines()) == []
    assert stray_at_root(['MUJOCO_LOG.TXT', 'hat | x', 'pg_node/a.py', 'tmp/x']) == [
        'MUJOCO_LOG.TXT', 'hat | x', 'tmp/x']


#: the decisions issue 53 moved to one place each: (what, the pattern that writes it, the one
#: module allowed to) — a second writer found anywhere in the package, bench/ or launch/ fails
SINGLE_SOURCES = [
    ("a run's file names", r"""['"](progress\.csv|summary\.json|params\.yaml)['"]""",
     'pg_node/common/run_dir.py'),
    ('the checkpoints folder', r"""= ['"]checkpoints['"]""", 'pg_node/common/run_dir.py'),
    ("a simulator's seed from its pair", r'seed \+ i \* ', 'pg_node/common/graph_plan.py'),
    ("each update's settings", r"""^\s*(SETTINGS|ALGO_SETTINGS)\b.*=""",
     'pg_node/rl/update_settings.py'),
    ('the largest value on the wire', r'^MAX_ABS = ', 'pg_node/common/bounds.py'),
]


@pytest.mark.parametrize('what, pattern, home', SINGLE_SOURCES,
                         ids=[w for w, _, _ in SINGLE_SOURCES])
def test_each_decision_is_written_in_one_module(what, pattern, home):
    import re
    root = PACKAGE.parent
    found = sorted(str(path.relative_to(root))
                   for folder in ('pg_node', 'bench', 'launch')
                   for path in (root / folder).rglob('*.py')
                   if any(re.search(pattern, line) for line in path.read_text().splitlines()
                          if not line.lstrip().startswith('#')))
    assert found == [home], (what, found)
