"""
Launch policy_node against a robot's controllers: ``ros2 launch pg_node deploy.launch.py``.

One ``policy_node`` (a managed node: launch_ros's ``LifecycleNode``) with a parameter file
(``params_file``, default the package's ``config/policy_node.yaml``: every parameter at its
default, explained) and the topic remaps that wire it to the robot. Arguments:

- ``policy``: the policy to run (a run directory, a ``ckpt_*.pt`` file or an exported
  ``.onnx`` with its card); empty (the default): the parameter file's. The launch stops
  with one line when neither gives one;
- ``params_file``: a copy of ``config/policy_node.yaml`` with your values;
- ``command_interface`` (``effort``, ``position``, ``velocity``), ``command_message``
  (``forward``, ``trajectory``) and ``controller_name`` (the controller whose ``joints`` configure
  checks): empty (the default): the parameter file's values;
- ``commands_topic``, ``trajectory_topic``, ``joint_states_topic``: where the robot's
  controller takes commands and where its joint states are; the node's own names
  (``arm_controller/commands``, ``arm_controller/joint_trajectory``, ``joint_states``)
  are remapped to them. A name without a leading ``/`` is taken in ``namespace``; a robot's
  controller manager usually runs in ``/`` (give ``/forward_velocity_controller/commands``);
- ``namespace``: the node's namespace (one policy_node per robot: ``/left``, ``/right``);
- ``autostart`` (default ``false``): policy_node's own ``autostart`` parameter: configure
  and activate at start, with its checks; a failure is one line and exit code 2. With
  ``false`` the node waits, unconfigured, for its transitions (``ros2 lifecycle set``, or
  ``python -m pg_node lifecycle /policy_node configure`` without the ros2 CLI);
- ``use_sim_time`` (default ``false``): ``true`` against a simulator that publishes
  ``/clock`` (``sim_node``, Gazebo).

The launch ends when policy_node exits. docs/deploy.md gives the lines for a UR5e and a
Franka. Jazzy's ``LifecycleNode`` takes no ``autostart`` of its own (launch_ros jazzy
62c56e5 launch_ros/launch_ros/actions/lifecycle_node.py:41-75), hence the parameter.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction
from launch.events import Shutdown
from launch_ros.actions import LifecycleNode
from launch_ros.parameter_descriptions import ParameterValue
import yaml

#: launch argument -> the policy_node topic it remaps
REMAPS = {'commands_topic': 'arm_controller/commands',
          'trajectory_topic': 'arm_controller/joint_trajectory',
          'joint_states_topic': 'joint_states'}
#: launch arguments that override the parameter file's value when given
OVERRIDES = ('command_interface', 'command_message', 'controller_name', 'controller_manager')
#: launch arguments always given to the node as parameters (booleans)
SWITCHES = ('autostart', 'use_sim_time')


def _value(context, name):
    return context.launch_configurations.get(name, '')


def _file_policy(path):
    """Return the ``policy`` a policy_node parameter file gives (any of its key forms)."""
    try:
        with open(path) as f:
            raw = yaml.safe_load(f) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise RuntimeError(f'params_file {path}: {exc}') from None
    for key in ('/**/policy_node', '/policy_node', 'policy_node', '/**'):
        section = raw.get(key) if isinstance(raw, dict) else None
        if isinstance(section, dict) and (section.get('ros__parameters') or {}).get('policy'):
            return section['ros__parameters']['policy']
    return ''


def _bring_up(context):
    params_file = _value(context, 'params_file')
    # a path as it is: launch_ros reads a plain string as YAML (a name of digits, an int)
    given = ({'policy': ParameterValue(_value(context, 'policy'), value_type=str)}
             if _value(context, 'policy') else {})
    if not given and not _file_policy(params_file):
        raise RuntimeError(f'policy:= is required (a run directory, a ckpt_*.pt file or an '
                           f'exported .onnx file): {params_file} gives none')
    given.update({k: _value(context, k) for k in OVERRIDES if _value(context, k)})
    for name in SWITCHES:
        text = _value(context, name).lower()
        if text not in ('true', 'false'):
            raise RuntimeError(f'{name}:={_value(context, name)}: true or false')
        given[name] = text == 'true'
    remaps = [(topic, _value(context, arg)) for arg, topic in REMAPS.items()]
    node = LifecycleNode(package='pg_node', executable='policy_node', name='policy_node',
                         namespace=_value(context, 'namespace'),
                         parameters=[params_file, given], remappings=remaps,
                         output='screen',
                         on_exit=[EmitEvent(event=Shutdown(reason='policy_node exited'))])
    return [node]


def generate_launch_description():
    """Describe the arguments and the node."""
    default_params = os.path.join(get_package_share_directory('pg_node'), 'config',
                                  'policy_node.yaml')
    args = [
        ('policy', '', 'the policy: a run directory, a ckpt_*.pt file or an exported .onnx '
                       'file (empty: from params_file)'),
        ('params_file', default_params, "policy_node's parameter file"),
        ('command_interface', '', 'effort (N m), position (rad) or velocity (rad/s) (empty: '
                                  'from params_file)'),
        ('command_message', '', 'forward (Float64MultiArray) or trajectory (JointTrajectory) '
                                '(empty: from params_file)'),
        ('controller_name', '', 'the controller whose joints parameter configure checks, '
                                'e.g. /scaled_joint_trajectory_controller (empty: from '
                                'params_file)'),
        ('controller_manager', '', "ros2_control's controller manager, e.g. "
                                   'controller_manager: configure checks the arm controller '
                                   'through it and the stops can deactivate it (empty: from '
                                   'params_file, none)'),
        ('commands_topic', REMAPS['commands_topic'],
         "the forward command controller's commands topic, e.g. "
         '/forward_position_controller/commands'),
        ('trajectory_topic', REMAPS['trajectory_topic'],
         "the joint trajectory controller's topic, e.g. "
         '/scaled_joint_trajectory_controller/joint_trajectory'),
        ('joint_states_topic', REMAPS['joint_states_topic'],
         "the robot's joint states, e.g. /franka/joint_states"),
        ('namespace', '', "policy_node's namespace (one per robot)"),
        ('autostart', 'false', 'configure and activate at start (policy_node checks first); '
                               'false: wait for the lifecycle transitions'),
        ('use_sim_time', 'false', 'true against a simulator that publishes /clock'),
    ]
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in args] + [OpaqueFunction(function=_bring_up)])
