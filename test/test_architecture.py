"""
The package's layers, as docs/architecture.md draws them.

Each subpackage of ``pg_node`` is a layer with a rank; a module may import its own layer and
the layers of lower rank, never a layer of the same rank or above (every import counts, also
one inside a function). No module imports itself back through others. The math (``rl``), the
labs, the simulator and the base layer import with ``rclpy`` made unimportable.
"""
import ast
from pathlib import Path
import subprocess
import sys

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / 'pg_node'

#: layer -> rank; a module may import layers of lower rank and its own
LAYERS = {'common': 0, 'sim': 1, 'rl': 2, 'bag': 2, 'lab': 3, 'ros': 3, 'tools': 4}
#: modules at the package's top, above every layer
TOP = {'pg_node', 'pg_node.__main__'}
#: layers that must work without ROS 2 installed
ROS_FREE = ('common', 'sim', 'rl', 'lab')


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


ROS_BLOCKER = """
import importlib, importlib.abc, pkgutil, sys

class NoRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('rclpy', 'rosbags', 'rosidl_runtime_py'):
            raise ImportError(f'{name} is not importable in this test')

sys.meta_path.insert(0, NoRos())
import pg_node
for layer in sys.argv[1:]:
    pkg = importlib.import_module('pg_node.' + layer)
    for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):
        importlib.import_module(info.name)
        print(info.name)
"""


@pytest.mark.parametrize('layers', [ROS_FREE])
def test_math_and_simulator_import_without_ros(layers):
    res = subprocess.run([sys.executable, '-c', ROS_BLOCKER, *layers], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    imported = set(res.stdout.split())
    expected = {m for m in MODULES if layer(m) in layers and m.count('.') == 2}
    assert imported == expected


def test_the_ros_blocker_blocks():
    """A module that needs rclpy fails under the same blocker, so the test above can fail."""
    res = subprocess.run([sys.executable, '-c', ROS_BLOCKER, 'ros'], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode != 0 and 'not importable in this test' in res.stderr
