"""
Launch the pg_node training graph on a full ROS 2 install: ``ros2 launch pg_node train.launch.py``.

The four nodes with the package's ``config/pg_node.yaml`` (or ``params_file:=...``). The launch
ends by itself when the learner exits (it has learned ``total_steps``): every other node is
then stopped, as Ctrl-C does. Arguments:

- ``params_file``, ``run_dir``;
- ``preset``: the name of a parameter file in the package's ``config/`` (``preset:=ppo`` is
  ``config/ppo.yaml``, ``preset:=a2c`` the design's A2C); when given it replaces
  ``params_file``. A preset names only its algorithm's values; the nodes' defaults fill in the
  rest. An unknown name stops the launch with one line that lists the presets;
- ``total_steps``, ``seed``, ``num_envs``, ``algo``: override the parameter file's values
  (empty, the default: the file's value);
- ``run_id``: the run's name on the ROS network (letters, digits, ``_``): every node runs
  in the namespace ``/<run_id>`` and its topics are ``/<run_id>/pg_node/...``; nodes drop
  messages of another run, so several launches (and ``python -m pg_node train`` runs) share
  one ``ROS_DOMAIN_ID`` without mixing. Empty (the default): made from ``run_dir``'s name,
  as ``train`` makes it, so give two runs two run dirs or two run ids;
- ``namespace`` (of the simulator/actor pair: relative to ``/<run_id>``, e.g. ``arm1``),
  ``actor_id`` and ``use_learner:=false`` to start only a simulator/actor pair that joins a
  critic and learner running elsewhere on the same ``ROS_DOMAIN_ID`` with the same
  ``run_id`` (set ``num_actors`` on the critic/learner side);
- ``part`` and ``actors``, as ``train --part``: one run on many hosts. ``part:=learner``
  starts the critic and the learner only; ``part:=workers actors:=2,3`` the pairs of those
  actor ids only, each in ``/<run_id>/arm<i>`` and seeded as ``train`` seeds it; the same
  ``run_id``, parameter file and ``num_actors`` on every host. With ``supervised:=true``
  the choice goes to ``train``, which checks the hosts' configurations against each other;
- ``compose`` (default ``true``, as ``python -m pg_node train``): the simulator and the actor
  run in one process (``sim_and_actor``), the critic and the learner in another
  (``critic_and_learner``): the same four nodes, names, topics and parameters, with fewer
  processes to wake each control step; ``compose:=false`` starts a process per node;
- ``supervised:=true``: instead of the four nodes, run ``pg_node train`` (the package's
  ``lib/pg_node/pg_node``, in the Python pg_node was installed with) with the same file and
  overrides: it restarts a node that dies, evaluates the final policy and writes
  ``summary.json`` and the learning-curve plot; the launch ends with it.

The processes, their namespaces, seeds and actor ids are those of the graph plan
(``pg_node.common.graph_plan``), which ``python -m pg_node train`` starts too.

A learner (or supervised training) that exits with an error fails the launch: every
process is stopped and ``ros2 launch`` exits 1.
"""
import os

from ament_index_python.packages import get_package_prefix
from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, EmitEvent, ExecuteProcess, OpaqueFunction,
                            RegisterEventHandler)
from launch.event_handlers import OnProcessExit, OnShutdown
from launch.events import Shutdown
from launch_ros.actions import Node
# stdlib-only modules of pg_node: ros2 launch may run another Python than the one pg_node's
# dependencies were installed into
from pg_node.common.graph_plan import graph_plan, LEARNER, part_plan, PARTS, placed_pair
from pg_node.common.paths import default_config, preset_names, presets, share_dir
from pg_node.common.run import check_run_id, run_id_for_dir
import yaml

#: launch arguments that override one parameter of every node that reads it
OVERRIDES = ('total_steps', 'seed', 'num_envs', 'algo')


def _value(context, name):
    return context.launch_configurations.get(name, '')


def _end_with(action, reason):
    """
    Return the handler that shuts the launch down when ``action``'s process exits.

    A non-zero exit fails the launch: the handler raises, launch logs the line, stops every
    process and ``ros2 launch`` exits 1 (LaunchService.run's code for a caught exception),
    so a script or CI that runs the launch sees that training failed.
    """
    def on_exit(event, context):
        if event.returncode != 0:
            raise RuntimeError(f'{reason} with exit code {event.returncode}')
        return [EmitEvent(event=Shutdown(reason=reason))]
    return RegisterEventHandler(OnProcessExit(target_action=action, on_exit=on_exit))


def _removed_at_shutdown(paths):
    """
    Return the handler that removes the launch's own parameter ``paths`` when it shuts down.

    The processes read them once, at start (rcl's arguments); launch_ros leaves the files it
    writes for a dict of parameters in the temporary folder for good, one per node and launch.
    """
    def remove(event, context):
        for path in paths:
            try:
                os.remove(path)
            except FileNotFoundError:
                pass
    return RegisterEventHandler(OnShutdown(on_shutdown=remove))


def _executable(name):
    """Return the path of the package's executable ``name`` (``lib/pg_node/<name>``)."""
    path = os.path.join(get_package_prefix('pg_node'), 'lib', 'pg_node', name)
    if not os.access(path, os.X_OK):
        raise RuntimeError(f'{path} is missing: build and install pg_node again '
                           '(colcon build), then source the install')
    return path


def _preset_file(name):
    """Return the path of preset ``name`` (``config/<name>.yaml``), or say which exist."""
    config = share_dir() / 'config'
    if name not in presets():
        raise RuntimeError(f'preset {name!r} is not in {config} '
                           f'(presets: {", ".join(presets())})')
    return str(config / f'{name}.yaml')


def _run_id(context):
    """Return the ``run_id`` argument, or one made from the run dir's name as train does."""
    given = _value(context, 'run_id')
    if not given:
        return run_id_for_dir(_value(context, 'run_dir'))
    try:
        return check_run_id(given)
    except ValueError as exc:
        raise RuntimeError(f'run_id {given!r}: {exc}') from None


def _plan(context, params, given, run_id, part, actors, compose):
    """Return the graph plan (:mod:`pg_node.common.graph_plan`) of the arguments."""
    run_dir = _value(context, 'run_dir')
    if part == 'all':
        pair = placed_pair(run_id, _value(context, 'namespace'),
                           int(_value(context, 'actor_id')), given.get('seed'))
        return graph_plan(run_id, run_dir, [pair], compose,
                          learner=_value(context, 'use_learner').lower() == 'true')
    seed = arms = None
    if part == 'workers':
        # pair i in /<run>/arm<i>, seeded as train seeds it; the file's values when not given
        seed, arms = (given.get(k, _file_value(params, k)) for k in ('seed', 'num_envs'))
    try:
        # num_actors None: the pairs are some of several (the file's count is not checked)
        return part_plan(run_id, run_dir, seed, arms, None, compose, part,
                         [int(a) for a in actors.split(',')] if actors else None)
    except ValueError as exc:
        raise RuntimeError(f'actors:={actors}: {exc}') from None


def _bring_up(context):
    params = _value(context, 'params_file')
    if _value(context, 'preset'):
        params = _preset_file(_value(context, 'preset'))
    run_dir = _value(context, 'run_dir')
    given = {k: yaml.safe_load(_value(context, k)) for k in OVERRIDES if _value(context, k)}
    run_id = _run_id(context)
    part, actors = _value(context, 'part') or 'all', _value(context, 'actors')
    if part not in PARTS:
        raise RuntimeError(f'part {part!r}: one of {", ".join(PARTS)}')
    if part == 'workers' and not actors:
        raise RuntimeError('part:=workers needs actors:=IDS (e.g. actors:=2,3)')
    if _value(context, 'supervised').lower() == 'true':
        # pg_node's own executable, whose first line names the Python it was installed
        # with (as ros2 run's executables do): ros2 launch may run in another Python
        train = ExecuteProcess(
            cmd=[_executable('pg_node'), 'train', '--config', params,
                 '--run-dir', run_dir, '--run-id', run_id, '--no-progress', '--part', part,
                 *(['--actors', actors] if actors else []),
                 *[f'{k}={v}' for k, v in given.items()]],
            output='screen', sigterm_timeout='30')
        return [train, _end_with(train, 'supervised training ended')]
    compose = _value(context, 'compose').lower() == 'true'
    # the overrides: the learner reads them all, every other node the shared ones
    shared = {k: v for k, v in given.items() if k in ('seed', 'num_envs')}
    actions, files = [], []
    for proc in _plan(context, params, given, run_id, part, actors, compose):
        values = {node: {**(given if node == LEARNER else shared), **own}
                  for node, own in proc.values.items()}
        if compose:
            # no name=: it would rename every node of the process; each node's own values go
            # in a section of its name, as a parameters dict would reach both nodes
            files.append(_sections_file(values))
            named = {'parameters': [params, files[-1]]}
        else:
            (name, own), = values.items()
            named = {'name': name, 'parameters': [params, own]}
        actions.append(Node(package='pg_node', executable=proc.executable,
                            namespace=proc.namespace, output='screen', **named))
        if LEARNER in proc.values:
            actions.append(_end_with(actions[-1], 'the learner ended'))
    return actions + [_removed_at_shutdown(files)] if files else actions


def _file_value(params, key):
    """Return a shared value of a parameter file, or of the shipped pg_node.yaml."""
    for path in (params, default_config()):
        with open(path) as f:
            value = ((yaml.safe_load(f) or {}).get('/**', {}).get('ros__parameters', {})
                     .get(key))
        if value is not None:
            return value
    raise RuntimeError(f'{key} is in neither {params} nor the shipped pg_node.yaml')


def _sections_file(values_by_node):
    """Write ``{node name: parameters}`` as a parameter file of ``/**/<name>`` sections."""
    import tempfile
    with tempfile.NamedTemporaryFile('w', prefix='pg_node_launch_', suffix='.yaml',
                                     delete=False) as f:
        yaml.safe_dump({f'/**/{name}': {'ros__parameters': values}
                        for name, values in values_by_node.items()}, f, sort_keys=False)
    return f.name


def generate_launch_description():
    """Describe the arguments and the bring-up."""
    default_params = str(default_config())
    args = [
        ('params_file', default_params, 'ROS 2 parameter file of all pg_node nodes'),
        ('preset', '', "a parameter file of the package's config/ by name: "
                       f'{", ".join(preset_names())} '
                       '(replaces params_file)'),
        ('run_dir', 'runs/latest', 'where checkpoints, the bag and progress go'),
        ('total_steps', '', 'environment steps to learn (empty: from params_file)'),
        ('seed', '', 'seed of simulator, policy and sampling (empty: from params_file)'),
        ('num_envs', '', 'arms per simulator (empty: from params_file)'),
        ('algo', '', 'a2c, ppo, npg or trpo (empty: from params_file)'),
        ('run_id', '', "the run's name on the ROS network: nodes in /<run_id>, topics "
                       "/<run_id>/pg_node/... (empty: from run_dir's name)"),
        ('namespace', '', 'namespace of the simulator/actor pair, under /<run_id> unless it '
                          'starts with /'),
        ('actor_id', '0', 'id of this pair when several feed one learner'),
        ('use_learner', 'true', 'also start the critic and the learner'),
        ('part', 'all', 'one run on many hosts: learner (the critic and the learner only) or '
                        'workers (the simulator/actor pairs of actors:=) on this host; the '
                        'same run_id and parameters on every host'),
        ('actors', '', 'with part:=workers: the actor ids of this host, e.g. 2,3'),
        ('compose', 'true', 'the simulator and the actor in one process (sim_and_actor), '
                            'the critic and the learner in another (critic_and_learner); '
                            'false: a process each'),
        ('supervised', 'false', 'run python -m pg_node train (restarts, evaluation, summary)'),
    ]
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in args] + [OpaqueFunction(function=_bring_up)])
