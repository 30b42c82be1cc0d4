"""
The deployment files: ``config/policy_node.yaml`` and ``launch/deploy.launch.py``.

The parameter file is generated from :data:`pg_node.common.params.POLICY_PARAMS` (by
:mod:`pg_node.tools.param_docs`) with the command written in its header, and must equal what
that command writes today. The launch file runs against the recording stand-ins of
``launch``/``launch_ros`` that test_package_layout.py's train.launch.py tests use (``launch``
is not on PyPI), with ``LifecycleNode`` added; test_lifecycle_cli.py starts a real policy_node
from the file.
"""
from pathlib import Path
import re
import shlex
import subprocess
import sys
import types

import pytest
from test_package_layout import _fake_launch_modules, _Recorded
import yaml

REPO = Path(__file__).resolve().parent.parent
SHIPPED = REPO / 'config' / 'policy_node.yaml'


def test_shipped_policy_node_yaml_is_what_its_command_writes():
    """One source: the file equals the renderer's output and the header's command makes it."""
    from pg_node.tools.param_docs import POLICY_FILE_COMMAND, policy_node_file
    text = SHIPPED.read_text()
    assert text == policy_node_file(), f'regenerate it: {POLICY_FILE_COMMAND}'
    assert f'#   {POLICY_FILE_COMMAND}\n' in text
    command, _, target = POLICY_FILE_COMMAND.partition(' > ')
    assert REPO / target == SHIPPED
    done = subprocess.run([sys.executable if w == 'python' else w for w in shlex.split(command)],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stderr == '', done.stderr
    assert done.stdout == text


def test_policy_node_yaml_holds_every_parameter_at_its_default_explained():
    """Every POLICY_PARAMS entry, in order, at its default, valid, under its meaning."""
    from pg_node.common.config_files import read_sections
    from pg_node.common.params import POLICY_PARAMS
    from pg_node.tools.param_docs import POLICY_FILE_NOTES
    raw = yaml.safe_load(SHIPPED.read_text())
    # /**/policy_node: the section reaches policy_node in any namespace (a plain
    # policy_node: key reaches /policy_node only)
    assert list(raw) == ['/**/policy_node']
    values = raw['/**/policy_node']['ros__parameters']
    assert list(values) == list(POLICY_PARAMS)
    assert values == {k: p.default for k, p in POLICY_PARAMS.items()}
    assert read_sections(SHIPPED) == {'policy_node': values}
    for key, param in POLICY_PARAMS.items():
        assert param.check(key, values[key]) == param.default
    comments = ' '.join(line.strip()[2:] for line in SHIPPED.read_text().splitlines()
                        if line.strip().startswith('# '))
    for key, param in POLICY_PARAMS.items():
        assert ' '.join(param.description.split()) in comments, key
        assert param.allowed() in comments, key
    # the policy has no default: the file says what to put there
    assert 'policy' in POLICY_FILE_NOTES and POLICY_FILE_NOTES['policy'] in comments
    assert values['policy'] == ''


def test_the_modules_worked_examples_hold():
    import doctest
    from pg_node.common import config_files, param_schema
    from pg_node.tools import lifecycle, param_docs
    for module in (param_schema, config_files, param_docs, lifecycle):
        failures, tried = doctest.testmod(module)
        assert tried > 0 and failures == 0, module.__name__


def test_the_deployment_file_is_no_training_preset():
    """config/policy_node.yaml is in config/, but train --config and preset:= do not list it."""
    from pg_node.common.paths import DEPLOY_CONFIG, preset_names, presets
    assert SHIPPED.stem == DEPLOY_CONFIG
    assert DEPLOY_CONFIG not in presets() and DEPLOY_CONFIG not in preset_names()


class _Given(dict):
    """The parameters dict of the launch, ``policy`` read out of its ParameterValue."""

    def pop(self, key):
        value = super().pop(key)
        assert type(value).__name__ == 'ParameterValue' and value.kwargs == {'value_type': str}
        return value.args[0]


def _launch(monkeypatch, **given):
    """Run deploy.launch.py's bring-up as ``ros2 launch`` would; return (actions, declared)."""
    import ament_index_python.packages
    import runpy
    modules = _fake_launch_modules()
    modules['launch_ros.actions'].LifecycleNode = type('LifecycleNode', (_Recorded,), {})
    modules['launch_ros.parameter_descriptions'] = types.ModuleType(
        'launch_ros.parameter_descriptions')
    modules['launch_ros.parameter_descriptions'].ParameterValue = type(
        'ParameterValue', (_Recorded,), {})
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setattr(ament_index_python.packages, 'get_package_share_directory',
                        lambda pkg: str(REPO))
    ns = runpy.run_path(str(REPO / 'launch' / 'deploy.launch.py'))
    entities = ns['generate_launch_description']().args[0]
    declared = {e.args[0]: e.kwargs for e in entities
                if type(e).__name__ == 'DeclareLaunchArgument'}
    assert not set(given) - set(declared), 'an argument the launch file does not declare'
    context = types.SimpleNamespace(launch_configurations={
        **{k: v['default_value'] for k, v in declared.items()}, **given})
    bring_up = next(e for e in entities if type(e).__name__ == 'OpaqueFunction')
    actions = bring_up.kwargs['function'](context)
    for action in actions:
        action.kwargs['parameters'][1] = _Given(action.kwargs['parameters'][1])
    return actions, declared


def test_deploy_launch_starts_a_lifecycle_policy_node_with_the_shipped_file(monkeypatch):
    (node,), declared = _launch(monkeypatch, policy='/p/reach.onnx')
    assert type(node).__name__ == 'LifecycleNode'
    kw = node.kwargs
    assert (kw['package'], kw['executable'], kw['name'], kw['namespace']) == (
        'pg_node', 'policy_node', 'policy_node', '')
    path, given = kw['parameters']
    assert path == str(SHIPPED) and given.pop('policy') == '/p/reach.onnx'
    assert given == {'autostart': False, 'use_sim_time': False}
    # by default each topic keeps the node's own name
    assert kw['remappings'] == [('arm_controller/commands', 'arm_controller/commands'),
                                ('arm_controller/joint_trajectory',
                                 'arm_controller/joint_trajectory'),
                                ('joint_states', 'joint_states')]
    (end,) = kw['on_exit']
    assert type(end).__name__ == 'EmitEvent'
    assert type(end.kwargs['event']).__name__ == 'Shutdown'
    # every argument is described on the page a robot team reads
    page = (REPO / 'docs' / 'deploy.md').read_text()
    for name, arg in declared.items():
        assert arg['description'] and f'`{name}' in page, name


def test_deploy_launch_remaps_to_the_robots_controllers(monkeypatch):
    """A UR5e on its scaled JTC, in a namespace, started at once: the docs' line."""
    (node,), _ = _launch(
        monkeypatch, policy='2024', command_interface='position',
        command_message='trajectory', namespace='/ur',
        controller_name='/scaled_joint_trajectory_controller',
        trajectory_topic='/scaled_joint_trajectory_controller/joint_trajectory',
        commands_topic='/forward_position_controller/commands', autostart='true')
    kw = node.kwargs
    assert kw['namespace'] == '/ur'
    given = kw['parameters'][1]
    assert given.pop('policy') == '2024'        # a name of digits stays a string
    assert given == {'command_interface': 'position', 'command_message': 'trajectory',
                     'controller_name': '/scaled_joint_trajectory_controller',
                     'autostart': True, 'use_sim_time': False}
    assert dict(kw['remappings']) == {
        'arm_controller/commands': '/forward_position_controller/commands',
        'arm_controller/joint_trajectory': '/scaled_joint_trajectory_controller/joint_trajectory',
        'joint_states': 'joint_states'}


def test_deploy_launch_remaps_topics_policy_node_has():
    """The names the launch remaps are policy_node's own (a renamed topic breaks this)."""
    from pg_node.common.run import CONTROLLER_COMMANDS, CONTROLLER_TRAJECTORY
    source = (REPO / 'pg_node' / 'ros' / 'policy_node.py').read_text()
    text = (REPO / 'launch' / 'deploy.launch.py').read_text()
    remapped = re.search(r'REMAPS = \{(.*?)\}', text, re.S).group(1)
    topics = re.findall(r":\s*'([^']+)'", remapped)
    # the controller topics policy_node publishes on (pg_node.common.run), the states it takes
    assert 'create_publisher(Float64MultiArray, CONTROLLER_COMMANDS' in source
    assert 'create_publisher(JointTrajectory, CONTROLLER_TRAJECTORY' in source
    assert "'joint_states'" in source
    assert sorted(topics) == sorted([CONTROLLER_COMMANDS, CONTROLLER_TRAJECTORY, 'joint_states'])


def test_deploy_launch_takes_the_policy_from_the_file_or_stops(monkeypatch, tmp_path):
    with pytest.raises(RuntimeError, match=r'^policy:= is required .* gives none$'):
        _launch(monkeypatch)
    own = tmp_path / 'mine.yaml'
    own.write_text(SHIPPED.read_text().replace("policy: ''", 'policy: /robot/reach.onnx'))
    (node,), _ = _launch(monkeypatch, params_file=str(own))
    assert node.kwargs['parameters'] == [str(own), {'autostart': False, 'use_sim_time': False}]
    for bad, words in (({'params_file': str(tmp_path / 'none.yaml')}, 'No such file'),
                       ({'policy': 'p.onnx', 'autostart': 'yes'}, 'autostart:=yes: true or '
                                                                  'false')):
        with pytest.raises(RuntimeError, match=words):
            _launch(monkeypatch, **bad)
