"""
The graph plan (pg_node.common.graph_plan), and train and the launch file starting the same graph.

``python -m pg_node train`` turns the plan into commands and parameter files, the launch file
into launch_ros ``Node`` actions; here both are read back into what each node ends up with
(its process, namespace, seed, actor id, run id and run dir) and compared, for one pair and
for several, composed or not, whole or in parts.
"""
import ast
from pathlib import Path
import subprocess
import sys

from pg_node.common.graph_plan import (graph_plan, part_plan, placed_pair, run_pairs,
                                       sim_seed)
import pytest
from test_package_layout import _bring_up, _launch_shuts_down  # noqa: F401 (a fixture)
import yaml

REPO = Path(__file__).resolve().parent.parent
#: the nodes of each executable, as the ros/ modules hold them
NODES = {'sim_and_actor': ('sim_node', 'actor_node'),
         'critic_and_learner': ('critic_node', 'learner_node')}
#: what the comparison reads of each node (only the critic and the learner read run_dir)
KEYS = ('seed', 'actor_id', 'run_id', 'run_dir')


def test_pairs_of_a_run_are_placed_and_seeded_apart():
    (lone,) = run_pairs('exp1', 5, 16, 1)
    assert lone == (0, '/exp1', 5, '')
    pairs = run_pairs('exp1', 5, 16, 3)
    assert [(p.actor_id, p.namespace, p.seed, p.tag) for p in pairs] == [
        (0, '/exp1/arm0', 5, '_0'), (1, '/exp1/arm1', 21, '_1'), (2, '/exp1/arm2', 37, '_2')]
    assert [p.seed for p in pairs] == [sim_seed(5, 16, i) for i in range(3)]
    assert run_pairs('exp1', 5, 16, 3, [2]) == pairs[2:]
    # the launch file's worker host, which does not know the run's count
    assert run_pairs('exp1', 0, 64, None, [1]) == [(1, '/exp1/arm1', 64, '_1')]
    for actors in ([3], [-1]):
        with pytest.raises(ValueError, match='not of a run of num_actors 3'):
            run_pairs('exp1', 5, 16, 3, actors)
    assert pairs[1].values() == {'sim_node': {'seed': 21}, 'actor_node': {'actor_id': 1}}
    placed = placed_pair('exp1', 'arm1', 1, None)
    assert placed == (1, '/exp1/arm1', None, '')
    assert placed.values() == {'sim_node': {}, 'actor_node': {'actor_id': 1}}


def test_plan_lists_processes_nodes_and_their_values():
    pairs = run_pairs('exp1', 5, 16, 2)
    plan = graph_plan('exp1', 'runs/a', pairs, compose=True)
    assert [(p.name, p.executable, p.module, p.namespace) for p in plan] == [
        ('critic_and_learner', 'critic_and_learner', 'pg_node.ros.critic_and_learner', '/exp1'),
        ('sim_and_actor_0', 'sim_and_actor', 'pg_node.ros.sim_and_actor', '/exp1/arm0'),
        ('sim_and_actor_1', 'sim_and_actor', 'pg_node.ros.sim_and_actor', '/exp1/arm1')]
    run = {'run_id': 'exp1'}
    assert plan[0].values == {'critic_node': {**run, 'run_dir': 'runs/a'},
                              'learner_node': {**run, 'run_dir': 'runs/a'}}
    assert plan[2].values == {'sim_node': {**run, 'seed': 21},
                              'actor_node': {**run, 'actor_id': 1}}
    assert plan[0].pair is None and plan[2].pair == pairs[1]
    apart = graph_plan('exp1', 'runs/a', pairs, compose=False, learner=False)
    assert [(p.name, list(p.values)) for p in apart] == [
        ('sim_node_0', ['sim_node']), ('actor_node_0', ['actor_node']),
        ('sim_node_1', ['sim_node']), ('actor_node_1', ['actor_node'])]
    assert [p.name for p in part_plan('exp1', 'r', None, None, None, True, 'learner')] == [
        'critic_and_learner']
    assert [p.name for p in part_plan('exp1', 'r', 5, 16, 3, False, 'workers', [1])] == [
        'sim_node_1', 'actor_node_1']
    with pytest.raises(ValueError, match="part 'some'"):
        part_plan('exp1', 'r', 5, 16, 3, True, 'some')


def test_the_launch_files_pg_node_imports_need_the_standard_library_only():
    """ros2 launch may run a Python without numpy, torch, rclpy or Gymnasium."""
    launch = REPO / 'launch' / 'train.launch.py'
    modules = sorted(n.module for n in ast.walk(ast.parse(launch.read_text()))
                     if isinstance(n, ast.ImportFrom) and n.module.split('.')[0] == 'pg_node')
    assert 'pg_node.common.graph_plan' in modules
    script = f"""
import importlib, sys


class OnlyTheStandardLibrary:
    def find_spec(self, name, path=None, target=None):
        top = name.split('.')[0]
        if top not in sys.stdlib_module_names and top != 'pg_node':
            raise ImportError(f'{{name}} is not of the standard library')


before = set(sys.modules)
sys.meta_path.insert(0, OnlyTheStandardLibrary())
for name in {modules!r}:
    importlib.import_module(name)
print(sorted(m for m in set(sys.modules) - before
             if m.split('.')[0] not in sys.stdlib_module_names))
"""
    # -S: none of site-packages' start-up hooks either
    done = subprocess.run([sys.executable, '-S', '-c', script], cwd=REPO, capture_output=True,
                          text=True, timeout=60, env={'PYTHONPATH': str(REPO)})
    assert done.returncode == 0, done.stderr
    loaded = ast.literal_eval(done.stdout.strip())
    assert set(modules) <= set(loaded) and all(m.startswith('pg_node') for m in loaded), loaded


def _effective(files, namespace, node):
    """Return what ``node`` in ``namespace`` reads of :data:`KEYS` from ``files``, in order."""
    values = {}
    for given in files:
        if isinstance(given, dict):             # launch_ros: a dict is the named node's
            values.update(given)
            continue
        sections = yaml.safe_load(Path(given).read_text())
        for key in ('/**', f'/**/{node}', f'{namespace}/{node}'):
            values.update(sections.get(key, {}).get('ros__parameters', {}))
    return {k: values.get(k) for k in KEYS
            if k != 'run_dir' or node in NODES['critic_and_learner']}


def _train_graph(tmp_path, settings, overrides, compose, part, actors):
    """Return ``{(executable, namespace): {node: values}}`` of what train starts."""
    from pg_node.common.config_files import load_config
    from pg_node.tools.train import node_commands, sim_seeds, write_params
    cfg = load_config(settings, overrides + ['run_id=exp1', 'run_dir=runs/x'])
    params = tmp_path / 'params.yaml'
    write_params(cfg, params)
    graph, seeds = {}, sim_seeds(cfg, compose)
    for name, cmd in node_commands(params, cfg, compose, part, actors).items():
        assert cmd[:2] == [sys.executable, '-m'] and cmd[2].startswith('pg_node.ros.')
        executable = cmd[2][len('pg_node.ros.'):]
        args = list(zip(cmd, cmd[1:]))
        (namespace,) = [v[len('__ns:='):] for k, v in args if k == '-r']
        files = [v for k, v in args if k == '--params-file']
        nodes = {node: _effective(files, namespace, node)
                 for node in NODES.get(executable, (executable,))}
        if 'sim_node' in nodes:     # a restarted simulator moves on from its first seed
            assert seeds[name] == nodes['sim_node']['seed'], (name, seeds, nodes)
        graph[(executable, namespace)] = nodes
    return graph


def _launch_graph(monkeypatch, settings, **given):
    """Return ``{(executable, namespace): {node: values}}`` of what the launch file starts."""
    graph = {}
    for action in _bring_up(monkeypatch, params_file=str(settings), run_id='exp1',
                            run_dir='runs/x', **given):
        if type(action).__name__ != 'Node':
            continue
        kw = action.kwargs
        nodes = NODES.get(kw['executable'], (kw['executable'],))
        assert kw.get('name', nodes[0]) == nodes[0]
        graph[(kw['executable'], kw['namespace'])] = {
            node: _effective(kw['parameters'], kw['namespace'], node) for node in nodes}
    return graph


@pytest.mark.parametrize('compose', [True, False])
@pytest.mark.parametrize('seed', [None, 7])
@pytest.mark.parametrize('case', ['one pair', 'learner', 'workers 1,2', 'workers 0'])
def test_train_and_the_launch_file_start_the_same_graph(monkeypatch, tmp_path, compose, seed,
                                                        case):
    """The same processes, namespaces, seeds, actor ids, run id and dir on both sides."""
    num_actors = 1 if case == 'one pair' else 3
    settings = tmp_path / 'settings.yaml'
    settings.write_text(yaml.safe_dump({'/**': {'ros__parameters': {
        'seed': 5, 'num_envs': 16, 'num_actors': num_actors}}}))
    overrides = [] if seed is None else [f'seed={seed}']
    given = {'compose': str(compose).lower(), **({} if seed is None else {'seed': str(seed)})}
    part, _, ids = case.partition(' ')
    if case == 'one pair':
        train = _train_graph(tmp_path, settings, overrides, compose, 'all', None)
    else:
        actors = [int(i) for i in ids.split(',')] if ids else None
        train = _train_graph(tmp_path, settings, overrides, compose, part, actors)
        given.update(part=part, **({'actors': ids} if ids else {}))
    launch = _launch_graph(monkeypatch, settings, **given)
    assert launch == train
    # what the launch tests pinned: simulator i seeded from seed + i * num_envs, a pair's
    # actor with its id and the run's seed, the critic and the learner in the run's namespace
    first = 5 if seed is None else seed
    nodes = {(ns, node): vals for (_, ns), by_node in train.items()
             for node, vals in by_node.items()}
    run, learning = {'run_id': 'exp1'}, {'run_id': 'exp1', 'run_dir': 'runs/x'}
    expected = {} if part == 'workers' else {
        ('/exp1', 'critic_node'): {'seed': first, 'actor_id': None, **learning},
        ('/exp1', 'learner_node'): {'seed': first, 'actor_id': None, **learning}}
    pairs = {'one pair': {'/exp1': 0}, 'learner': {},
             'workers 1,2': {'/exp1/arm1': 1, '/exp1/arm2': 2}, 'workers 0': {'/exp1/arm0': 0}}
    for ns, i in pairs[case].items():
        expected[(ns, 'sim_node')] = {'seed': first + i * 16, 'actor_id': None, **run}
        expected[(ns, 'actor_node')] = {'seed': first, 'actor_id': i, **run}
    assert nodes == expected


def test_train_and_the_launch_file_seed_from_the_shipped_file(monkeypatch, tmp_path):
    """Seeds not given: the parameter file's (the shipped one's: seed 0, 64 arms)."""
    from pg_node.common.paths import default_config
    train = _train_graph(tmp_path, default_config(), ['num_actors=2'], True, 'workers', [1])
    launch = _launch_graph(monkeypatch, default_config(), part='workers', actors='1')
    assert launch == train
    assert launch[('sim_and_actor', '/exp1/arm1')]['sim_node']['seed'] == 64
