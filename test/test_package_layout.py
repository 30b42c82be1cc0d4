"""The ament_python layout, checked by building the package with colcon into a temp dir."""
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

from domains import ros_domain
import pytest

REPO = Path(__file__).resolve().parent.parent
EXECUTABLES = ('sim_node', 'actor_node', 'critic_node', 'learner_node', 'replay_node',
               'policy_node', 'sim_and_actor', 'critic_and_learner', 'pg_node')
# bench/ too: a package of the repository that the build sees and must leave out
SOURCES = ('package.xml', 'setup.py', 'setup.cfg', 'resource', 'pg_node', 'config', 'launch',
           'bench')


@pytest.fixture(scope='module')
def install(tmp_path_factory):
    ws = tmp_path_factory.mktemp('ws')
    src = ws / 'src' / 'pg_node'
    src.mkdir(parents=True)
    for name in SOURCES:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns('__pycache__'))
        else:
            shutil.copy2(path, src / name)
    colcon = Path(sys.executable).parent / 'colcon'
    res = subprocess.run([str(colcon), '--log-base', str(ws / 'log'), 'build',
                          '--base-paths', str(ws / 'src'), '--build-base', str(ws / 'build'),
                          '--install-base', str(ws / 'install')],
                         cwd=ws, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    return ws / 'install' / 'pg_node'


def test_executables_in_lib(install):
    for exe in EXECUTABLES:
        path = install / 'lib' / 'pg_node' / exe
        assert path.is_file(), f'{path} missing: ros2 run pg_node {exe} would fail'
        text = path.read_text()
        assert f"'console_scripts', '{exe}'" in text or exe in text


def test_the_benchmarks_and_the_soak_are_not_installed(install):
    """bench/ is a package of the repository (``python -m bench``), not of the install."""
    site = next((install / 'lib').glob('python3*/site-packages'))
    installed = {p.name for p in site.iterdir()}
    assert 'pg_node' in installed and 'bench' not in installed, sorted(installed)
    assert not (site / 'pg_node' / 'tools' / 'soak.py').exists()


def test_share_holds_package_xml_config_launch_models(install):
    share = install / 'share' / 'pg_node'
    assert (share / 'package.xml').is_file()
    assert (share / 'config' / 'pg_node.yaml').is_file()
    for preset in ('a2c', 'ppo'):
        assert (share / 'config' / f'{preset}.yaml').is_file()
    assert (share / 'launch' / 'train.launch.py').is_file()
    # the deployment's launch file and its parameter file (setup.py's globs take them)
    assert (share / 'launch' / 'deploy.launch.py').is_file()
    assert (share / 'config' / 'policy_node.yaml').is_file()
    models = {p.name for p in (share / 'models').glob('*.xml')}
    assert models >= {'reacher2.xml', 'arm5_3d.xml'}
    # the vendor's UR5e with its meshes and licence, in share and beside the module
    site = next((install / 'lib').glob('python3*/site-packages'))
    for urdf in (share / 'models' / 'urdf', site / 'pg_node' / 'sim' / 'models' / 'urdf'):
        assert (urdf / 'ur5e.urdf').is_file() and (urdf / 'LICENSE.ur_description').is_file()
        assert len(list((urdf / 'meshes' / 'ur5e').glob('*.stl'))) == 7
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'pg_node').is_file()


def test_installed_package_finds_its_share_dir_and_runs(install, tmp_path):
    """An installed entry point imports, and its share dir is found through ament_index."""
    site = next((install / 'lib').glob('python3*/site-packages'))
    env = {'PATH': '/usr/bin:/bin', 'PYTHONPATH': str(site),
           'AMENT_PREFIX_PATH': f'{install}:{sys.prefix}',
           'LD_LIBRARY_PATH': ''}
    code = ('import pg_node.common.paths as p; print(p.default_config()); '
            'import pg_node.ros.sim_node, pg_node.ros.actor_node, pg_node.ros.critic_node, '
            'pg_node.ros.learner_node, pg_node.ros.replay_node')
    res = subprocess.run([sys.executable, '-c', code], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == str(install / 'share' / 'pg_node' / 'config' / 'pg_node.yaml')


def test_package_xml_is_format_3_and_declares_dependencies():
    root = ET.parse(REPO / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == 'pg_node'
    deps = {e.text for e in root.iter('exec_depend')}
    # every ROS interface package the code imports (``from x_msgs.msg import ...``) is one
    imported = set()
    for path in (REPO / 'pg_node').rglob('*.py'):
        imported |= set(re.findall(r'^\s*from (\w+_(?:msgs|srvs|interfaces))\.(?:msg|srv) import',
                                   path.read_text(), re.M))
    assert {'trajectory_msgs', 'sensor_msgs', 'std_srvs'} <= imported
    # rclpy.lifecycle (policy_node) needs lifecycle_msgs
    assert imported | {'rclpy', 'lifecycle_msgs'} <= deps, sorted(imported - deps)
    assert root.find('export/build_type').text == 'ament_python'
    assert {'ament_flake8', 'ament_pep257'} <= {e.text for e in root.iter('test_depend')}


def _fake_prefix():
    """Return an install prefix holding an executable ``lib/pg_node/pg_node``."""
    import tempfile
    prefix = Path(tempfile.mkdtemp(prefix='pg_node_prefix_'))
    exe = prefix / 'lib' / 'pg_node' / 'pg_node'
    exe.parent.mkdir(parents=True)
    exe.write_text('#!/bin/sh\n')
    exe.chmod(0o755)
    return prefix


FAKE_PREFIX = _fake_prefix()


def test_pg_node_executable_runs_in_the_python_it_was_installed_with(install, tmp_path):
    """``lib/pg_node/pg_node``, what supervised:=true starts, needs no python on PATH."""
    exe = install / 'lib' / 'pg_node' / 'pg_node'
    first = exe.read_text().splitlines()[0]
    assert first.startswith('#!') and Path(first[2:].split()[0]).resolve() == \
        Path(sys.executable).resolve(), first
    site = next((install / 'lib').glob('python3*/site-packages'))
    env = {'PATH': '/usr/bin:/bin', 'PYTHONPATH': str(site), 'LD_LIBRARY_PATH': '',
           'AMENT_PREFIX_PATH': f'{install}:{sys.prefix}'}
    res = subprocess.run([str(exe), 'train', '--help'], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and 'usage:' in res.stdout, res.stderr


class _Recorded:
    """A stand-in for a launch action or event: it keeps what it was built with."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _fake_launch_modules():
    import types
    mods = {name: types.ModuleType(name) for name in (
        'launch', 'launch.actions', 'launch.event_handlers', 'launch.events', 'launch_ros',
        'launch_ros.actions')}
    for module, names in (('launch', ['LaunchDescription']),
                          ('launch.actions', ['DeclareLaunchArgument', 'EmitEvent',
                                              'ExecuteProcess', 'OpaqueFunction',
                                              'RegisterEventHandler']),
                          ('launch.event_handlers', ['OnProcessExit', 'OnShutdown']),
                          ('launch.events', ['Shutdown']),
                          ('launch_ros.actions', ['Node'])):
        for name in names:
            setattr(mods[module], name, type(name, (_Recorded,), {}))
    return mods


#: the launch's handlers at shutdown (they remove its parameter files), of the test running
_SHUTDOWN = []


@pytest.fixture(autouse=True)
def _launch_shuts_down():
    """Shut each test's launches down as ``ros2 launch`` does: no file of theirs is left."""
    yield
    while _SHUTDOWN:
        _SHUTDOWN.pop().args[0].kwargs['on_shutdown'](None, None)


def _is_shutdown_handler(action):
    return (type(action).__name__ == 'RegisterEventHandler'
            and type(action.args[0]).__name__ == 'OnShutdown')


def _bring_up(monkeypatch, **given):
    """
    Run the launch file's bring-up as ``ros2 launch`` would with ``given`` arguments.

    Returns its actions but the handlers at shutdown, which the test's end runs.
    """
    import ament_index_python.packages
    import runpy
    import types
    for name, module in _fake_launch_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setattr(ament_index_python.packages, 'get_package_share_directory',
                        lambda pkg: str(REPO))
    monkeypatch.setattr(ament_index_python.packages, 'get_package_prefix',
                        lambda pkg: str(FAKE_PREFIX))
    ns = runpy.run_path(str(REPO / 'launch' / 'train.launch.py'))
    desc = ns['generate_launch_description']()
    entities = desc.args[0]
    declared = {e.args[0]: e.kwargs['default_value'] for e in entities
                if type(e).__name__ == 'DeclareLaunchArgument'}
    assert not set(given) - set(declared), 'an argument the launch file does not declare'
    context = types.SimpleNamespace(launch_configurations={**declared, **given})
    bring_up = next(e for e in entities if type(e).__name__ == 'OpaqueFunction')
    actions = bring_up.kwargs['function'](context)
    _SHUTDOWN.extend(a for a in actions if _is_shutdown_handler(a))
    return [a for a in actions if not _is_shutdown_handler(a)]


def _ends_launch_with(handler, action):
    """Check the launch ends when ``action`` exits with 0, and fails when it exits with 1."""
    import types
    on_exit = handler.args[0]
    assert type(on_exit).__name__ == 'OnProcessExit' and on_exit.kwargs['target_action'] is action
    (emit,) = on_exit.kwargs['on_exit'](types.SimpleNamespace(returncode=0), None)
    # launch logs a handler's exception, stops everything and ros2 launch exits 1
    with pytest.raises(RuntimeError, match='with exit code 1$'):
        on_exit.kwargs['on_exit'](types.SimpleNamespace(returncode=1), None)
    return type(emit.kwargs['event']).__name__ == 'Shutdown'


def test_launch_ends_when_the_learner_exits_and_takes_overrides(monkeypatch):
    from pg_node.common.params import params_for
    actions = _bring_up(monkeypatch, compose='false')
    nodes = {a.kwargs['executable']: a for a in actions if type(a).__name__ == 'Node'}
    assert set(nodes) == {'sim_node', 'actor_node', 'critic_node', 'learner_node'}
    handlers = [a for a in actions if type(a).__name__ == 'RegisterEventHandler']
    assert len(handlers) == 1 and _ends_launch_with(handlers[0], nodes['learner_node'])
    assert nodes['learner_node'].kwargs['parameters'][1] == {'run_id': 'latest',
                                                             'run_dir': 'runs/latest'}
    # the run's id, from run_dir's name as train makes it, is every node's namespace
    assert {n.kwargs['namespace'] for n in nodes.values()} == {'/latest'}
    # overrides reach the nodes that read them, typed as the table wants them
    actions = _bring_up(monkeypatch, total_steps='5000', seed='3', num_envs='16', algo='ppo',
                        compose='false')
    nodes = {a.kwargs['executable']: a for a in actions if type(a).__name__ == 'Node'}
    learner = nodes['learner_node'].kwargs['parameters'][1]
    assert learner == {'total_steps': 5000, 'seed': 3, 'num_envs': 16, 'algo': 'ppo',
                       'run_id': 'latest', 'run_dir': 'runs/latest'}
    for key, value in learner.items():
        assert params_for('learner_node')[key].check(key, value) == value
    assert nodes['sim_node'].kwargs['parameters'][1] == {
        'seed': 3, 'num_envs': 16, 'run_id': 'latest'}
    # a simulator/actor pair alone, joining run exp1: no learner to wait for
    actions = _bring_up(monkeypatch, use_learner='false', namespace='arm1', actor_id='1',
                        compose='false', run_id='exp1')
    assert [a.kwargs['executable'] for a in actions] == ['sim_node', 'actor_node']
    assert actions[1].kwargs['parameters'][1] == {'actor_id': 1, 'run_id': 'exp1'}
    assert actions[1].kwargs['namespace'] == '/exp1/arm1'       # under the run's namespace
    with pytest.raises(RuntimeError, match="run_id '1x'"):
        _bring_up(monkeypatch, run_id='1x')


def _sections(node):
    """Return the launch's own parameter file of a composed process, ``{section: values}``."""
    import yaml
    params = node.kwargs['parameters']
    assert len(params) == 2 and isinstance(params[1], str), params
    return {k: v['ros__parameters'] for k, v in yaml.safe_load(Path(params[1]).read_text())
            .items()}


def test_launch_composes_as_train_does_with_each_nodes_own_values(monkeypatch):
    """By default two processes; each node's values in a section of its own name."""
    actions = _bring_up(monkeypatch, total_steps='5000', seed='3', num_envs='16', algo='ppo')
    nodes = {a.kwargs['executable']: a for a in actions if type(a).__name__ == 'Node'}
    assert set(nodes) == {'sim_and_actor', 'critic_and_learner'}
    # a launch name would rename every node of the process
    assert all('name' not in n.kwargs for n in nodes.values())
    handlers = [a for a in actions if type(a).__name__ == 'RegisterEventHandler']
    assert len(handlers) == 1 and _ends_launch_with(handlers[0], nodes['critic_and_learner'])
    run = {'run_id': 'latest'}
    assert _sections(nodes['sim_and_actor']) == {
        '/**/sim_node': {'seed': 3, 'num_envs': 16, **run},
        '/**/actor_node': {'seed': 3, 'num_envs': 16, **run, 'actor_id': 0}}
    assert _sections(nodes['critic_and_learner']) == {
        '/**/critic_node': {'seed': 3, 'num_envs': 16, **run, 'run_dir': 'runs/latest'},
        '/**/learner_node': {'total_steps': 5000, 'seed': 3, 'num_envs': 16, 'algo': 'ppo',
                             **run, 'run_dir': 'runs/latest'}}
    assert {n.kwargs['namespace'] for n in nodes.values()} == {'/latest'}
    actions = _bring_up(monkeypatch, use_learner='false', namespace='/arm1', actor_id='1')
    (pair,) = actions
    assert pair.kwargs['executable'] == 'sim_and_actor' and pair.kwargs['namespace'] == '/arm1'
    assert _sections(pair)['/**/actor_node'] == {'actor_id': 1, **run}


def test_launch_removes_its_parameter_files_at_shutdown(monkeypatch):
    """The composed processes' files exist while the launch runs and are gone after it."""
    nodes = [a for a in _bring_up(monkeypatch) if type(a).__name__ == 'Node']
    files = [n.kwargs['parameters'][1] for n in nodes]
    assert len(files) == 2 and all(Path(f).is_file() for f in files)
    (handler,) = _SHUTDOWN
    _SHUTDOWN.clear()
    handler.args[0].kwargs['on_shutdown'](None, None)
    assert not any(Path(f).exists() for f in files)
    _bring_up(monkeypatch, compose='false')          # dicts: no file of its own, no handler
    assert not _SHUTDOWN


@pytest.mark.e2e
def test_launch_composed_process_gives_each_node_its_own_values(monkeypatch, tmp_path):
    """The files the launch writes, given to the real process: each node takes its values."""
    from pg_node.tools import processes
    (pair,) = _bring_up(monkeypatch, use_learner='false', namespace='/arm1', actor_id='1',
                        seed='7', num_envs='3')
    args = [sys.executable, '-m', 'pg_node.ros.sim_and_actor', '--ros-args',
            '-r', '__ns:=/arm1']
    for path in pair.kwargs['parameters']:
        args += ['--params-file', path]
    env = processes.child_env(ros_domain(base=150, spread=50))
    proc = processes.start_logged(args, tmp_path / 'pair.log', env)
    deadline = time.monotonic() + 60
    while 'waiting for policy weights' not in (tmp_path / 'pair.log').read_text():
        assert proc.poll() is None and time.monotonic() < deadline, \
            (tmp_path / 'pair.log').read_text()
        time.sleep(0.2)
    code, log = processes.stop_logged(proc)
    assert code == 0, log
    assert '[arm1.sim_node]: lock_step: 3 x reacher2' in log and ', seed 7' in log, log
    assert '[arm1.actor_node]: actor 1: 3 arms' in log, log


def test_launch_splits_a_run_over_hosts_as_train_does(monkeypatch):
    """part:=learner: the critic and the learner; part:=workers: the pairs of actors:=."""
    actions = _bring_up(monkeypatch, part='learner', run_id='exp1')
    assert [a.kwargs['executable'] for a in actions if type(a).__name__ == 'Node'] == [
        'critic_and_learner']
    actions = _bring_up(monkeypatch, part='workers', actors='1,2', run_id='exp1', seed='5',
                        num_envs='16')
    assert [(a.kwargs['executable'], a.kwargs['namespace']) for a in actions] == [
        ('sim_and_actor', '/exp1/arm1'), ('sim_and_actor', '/exp1/arm2')]
    sections = _sections(actions[1])
    # each simulator's seed as train seeds it: test_graph_plan.py compares the two
    sim = dict(sections['/**/sim_node'])
    assert sim.pop('seed') is not None and sim == {'num_envs': 16, 'run_id': 'exp1'}
    assert sections['/**/actor_node']['actor_id'] == 2
    train, _ = _bring_up(monkeypatch, supervised='true', part='workers', actors='0,1',
                         run_id='exp1')
    cmd = train.kwargs['cmd']
    assert cmd[cmd.index('--part') + 1] == 'workers' and cmd[cmd.index('--actors') + 1] == '0,1'
    for bad, words in (({'part': 'workers'}, 'needs actors'), ({'part': 'some'}, 'one of')):
        with pytest.raises(RuntimeError, match=words):
            _bring_up(monkeypatch, **bad)


def test_launch_runs_the_supervised_bring_up_on_request(monkeypatch):
    actions = _bring_up(monkeypatch, supervised='true', total_steps='5000', run_dir='/tmp/r')
    train, handler = actions
    cmd = train.kwargs['cmd']
    # the package's executable (its Python is the one pg_node was installed with), not the
    # Python ros2 launch runs in
    assert cmd[:2] == [str(FAKE_PREFIX / 'lib' / 'pg_node' / 'pg_node'), 'train']
    assert 'total_steps=5000' in cmd
    assert cmd[cmd.index('--run-dir') + 1] == '/tmp/r'
    assert cmd[cmd.index('--run-id') + 1] == 'r'
    assert _ends_launch_with(handler, train)


def test_launch_takes_a_preset_by_name_or_its_file(monkeypatch):
    for given in ({'preset': 'ppo'}, {'params_file': str(REPO / 'config' / 'ppo.yaml')}):
        actions = _bring_up(monkeypatch, **given)
        nodes = [a for a in actions if type(a).__name__ == 'Node']
        assert len(nodes) == 2                        # sim_and_actor, critic_and_learner
        for node in nodes:
            assert node.kwargs['parameters'][0] == str(REPO / 'config' / 'ppo.yaml')
    train, _ = _bring_up(monkeypatch, preset='a2c', supervised='true')
    cmd = train.kwargs['cmd']
    assert cmd[cmd.index('--config') + 1] == str(REPO / 'config' / 'a2c.yaml')
    from pg_node.common.paths import presets
    shipped = ', '.join(presets())
    assert {'a2c', 'ppo'} <= set(presets())
    for bad in ('nosuch', '../config/ppo'):
        with pytest.raises(RuntimeError, match=rf'presets: {shipped}\)$'):
            _bring_up(monkeypatch, preset=bad)


def test_launch_preset_argument_lists_every_shipped_preset(monkeypatch):
    import ament_index_python.packages
    import runpy
    from pg_node.common.paths import preset_names
    for name, module in _fake_launch_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setattr(ament_index_python.packages, 'get_package_share_directory',
                        lambda pkg: str(REPO))
    ns = runpy.run_path(str(REPO / 'launch' / 'train.launch.py'))
    (preset,) = [e for e in ns['generate_launch_description']().args[0]
                 if type(e).__name__ == 'DeclareLaunchArgument' and e.args[0] == 'preset']
    assert f'by name: {", ".join(preset_names())} (' in preset.kwargs['description']


@pytest.mark.skipif(sys.prefix == sys.base_prefix, reason='runs in the venv that make creates')
def test_make_installs_the_executables_into_the_venv(tmp_path):
    """``.venv/bin/sim_node`` runs without PYTHONPATH, from any directory (editable install)."""
    bin_dir = Path(sys.prefix) / 'bin'
    for exe in EXECUTABLES:
        assert (bin_dir / exe).is_file(), f'{exe} is not installed in {bin_dir}'
    env = {k: v for k, v in os.environ.items() if k not in ('PYTHONPATH', 'AMENT_PREFIX_PATH')}
    res = subprocess.run([str(bin_dir / 'sim_node'), '--ros-args', '-p', 'num_envs:=0'],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2, res.stderr
    assert "parameter 'sim_node.num_envs': 0 is not allowed" in res.stderr
