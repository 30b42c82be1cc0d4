"""
Launch the pg_node training graph on a full ROS 2 install: ``ros2 launch pg_node train.launch.py``.

The same bring-up as ``python -m pg_node train`` without its supervision, evaluation and
summary: the four nodes with the package's ``config/pg_node.yaml`` (or ``params_file:=...``).
Arguments: ``params_file``, ``run_dir``, ``namespace`` (of the simulator/actor pair) and
``use_learner:=false`` to start only a simulator/actor pair that joins a critic and learner
running elsewhere on the same ``ROS_DOMAIN_ID`` (give it its own ``namespace`` and
``actor_id``, and set ``num_actors`` on the critic/learner side).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    """Describe the four nodes and their arguments."""
    default_params = os.path.join(get_package_share_directory('pg_node'), 'config',
                                  'pg_node.yaml')
    params = LaunchConfiguration('params_file')
    run_dir = LaunchConfiguration('run_dir')
    namespace = LaunchConfiguration('namespace')
    actor_id = LaunchConfiguration('actor_id')
    use_learner = LaunchConfiguration('use_learner')
    overrides = {'run_dir': run_dir}
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS 2 parameter file of all pg_node nodes'),
        DeclareLaunchArgument('run_dir', default_value='runs/latest',
                              description='where checkpoints, the bag and progress go'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the simulator/actor pair'),
        DeclareLaunchArgument('actor_id', default_value='0',
                              description='id of this pair when several feed one learner'),
        DeclareLaunchArgument('use_learner', default_value='true',
                              description='also start the critic and the learner'),
        Node(package='pg_node', executable='sim_node', name='sim_node', namespace=namespace,
             parameters=[params], output='screen'),
        Node(package='pg_node', executable='actor_node', name='actor_node',
             namespace=namespace, parameters=[params, {'actor_id': actor_id}],
             output='screen'),
        Node(package='pg_node', executable='critic_node', name='critic_node',
             parameters=[params, overrides], output='screen', condition=IfCondition(use_learner)),
        Node(package='pg_node', executable='learner_node', name='learner_node',
             parameters=[params, overrides], output='screen',
             condition=IfCondition(use_learner)),
    ])
