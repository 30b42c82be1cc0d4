"""
The controller manager client against a manager that answers as ros2_control's (jazzy) does.

The ``controller_manager_msgs`` types are built at test time (test/controller_manager_types.py);
the manager is test/fake_controller_manager.py.
"""
import json
import threading
import time

import controller_manager_types
from domains import ros_domain
from fake_controller_manager import FakeControllerManager, NOTHING
from pg_node.control.controller_check import OPT_OUT, refusal
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor

DOMAIN_ID = ros_domain(base=150, spread=20)
JOINTS = ['joint0', 'joint1']
JTC = 'joint_trajectory_controller/JointTrajectoryController'
#: config/controllers/jtc_velocity.yaml's arm_controller, as the controller declares it
SHIPPED = {'joints': JOINTS, 'command_interfaces': ['velocity'],
           'state_interfaces': ['position', 'velocity'], 'cmd_timeout': 0.2,
           'constraints.goal_time': 0.0, 'allow_nonzero_velocity_at_trajectory_end': True,
           'open_loop_control': False,
           **{f'gains.{j}.ff_velocity_scale': 1.0 for j in JOINTS}}
#: the type hashes of ros2_control jazzy 9ffbf97fd's definitions, computed by the venv's
#: rosidl_generator_type_description from the upstream files (2026-12-07): equal hashes, equal
#: types on the wire
UPSTREAM_HASHES = {
    'msg/ControllerState':
        'RIHS01_9a8780ab9814b6032978a07c6c7033cf1a7894ac8d948a6fb72afea07b04cc83',
    'msg/ChainConnection':
        'RIHS01_2daecd1da4b171f48b291c79747657a651eb1ab8821b68e38b1c88c736bba91c',
    'srv/ListControllers':
        'RIHS01_4f8e36bb1fa5afdeba45c2d56ae6a2097b1493a253f961dd6290c085033bd189',
    'srv/SwitchController':
        'RIHS01_d4ad10aa5da7808bc522d55d4123d8ef79de73d049d165639d7663ac37cc9895',
}


@pytest.fixture(scope='module')
def types():
    """Build (or find) the types; return their directory."""
    started = time.monotonic()
    root = controller_manager_types.install()
    assert time.monotonic() - started < 60.0, 'building the types took over a minute'
    return root


class Graph:
    """A context with a fake controller manager spun in a thread, and a client beside it."""

    def __init__(self, controllers, namespace='/'):
        from controller_manager_msgs import msg, srv
        from pg_node.ros.controller_manager import ControllerManagerClient
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.cm = FakeControllerManager(self.context, self.executor, srv, msg, controllers,
                                        namespace=namespace)
        self.running = True
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        self.client = ControllerManagerClient(self.context, 'controller_manager', timeout=5.0,
                                              namespace=namespace)

    def _spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.02)

    def close(self):
        self.running = False
        self.thread.join()
        self.client.close()
        self.cm.destroy()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def graph(types):
    made = []

    def make(controllers, namespace='/'):
        made.append(Graph(controllers, namespace))
        return made[-1]
    yield make
    for g in made:
        g.close()


def test_the_built_types_hash_as_ros2_controls_own(types):
    for name, expected in UPSTREAM_HASHES.items():
        desc = json.loads((types / 'include' / 'controller_manager_msgs' / f'{name}.json')
                          .read_text())
        assert desc['type_hashes'][0]['hash_string'] == expected, name


def test_the_client_reads_type_state_and_parameters(graph):
    g = graph({'arm_controller': (JTC, 'active', SHIPPED),
               'joint_state_broadcaster': ('joint_state_broadcaster/JointStateBroadcaster',
                                           'active', {'use_local_topics': False})})
    ctrl = g.client.controller('arm_controller')
    assert (ctrl.name, ctrl.controller_type, ctrl.state, ctrl.path) == (
        'arm_controller', JTC, 'active', '/arm_controller')
    assert ctrl.params == SHIPPED       # interface_name: not declared by a JTC, so absent
    assert refusal(ctrl, 'velocity', 'trajectory') is None


def test_a_manager_in_a_namespace_is_found_beside_the_node(graph):
    g = graph({'arm_controller': (JTC, 'active', SHIPPED)}, namespace='/left')
    ctrl = g.client.controller('arm_controller')
    assert ctrl.path == '/left/arm_controller' and ctrl.params['cmd_timeout'] == 0.2


@pytest.mark.parametrize('ctype, params, interface, message, named', [
    (JTC, {**SHIPPED, 'cmd_timeout': 0.0}, 'velocity', 'trajectory', 'has cmd_timeout 0:'),
    (JTC, {**SHIPPED, 'command_interfaces': ['position']}, 'velocity', 'trajectory',
     'command_interfaces [position]'),
    (JTC, {**SHIPPED, 'command_interfaces': ['position', 'velocity']}, 'effort', 'trajectory',
     'command_interfaces [position, velocity]'),
    (JTC, {**SHIPPED, 'gains.joint1.ff_velocity_scale': 0.0}, 'velocity', 'trajectory',
     'gains.joint1.ff_velocity_scale 0'),
    (JTC, {**SHIPPED, 'allow_nonzero_velocity_at_trajectory_end': False}, 'velocity',
     'trajectory', 'allow_nonzero_velocity_at_trajectory_end false'),
    ('ur_controllers/ScaledJointTrajectoryController',
     {'joints': JOINTS, 'command_interfaces': ['position'],
      'state_interfaces': ['position', 'velocity'], 'constraints.goal_time': 0.0},
     'position', 'trajectory', 'has cmd_timeout 0:'),
    ('velocity_controllers/JointGroupVelocityController',
     {'joints': JOINTS, 'interface_name': 'velocity'}, 'velocity', 'forward', 'no dead-man'),
])
def test_each_bad_set_up_read_from_the_manager_is_refused_in_one_line(
        graph, ctype, params, interface, message, named):
    g = graph({'arm_controller': (ctype, 'active', params)})
    line = refusal(g.client.controller('arm_controller'), interface, message)
    assert line is not None and named in line and '\n' not in line, line


def test_deactivation_through_switch_controller_takes_effect(graph):
    g = graph({'arm_controller': (JTC, 'active', SHIPPED)})
    assert g.client.deactivate('arm_controller') is None
    assert g.client.state('arm_controller')['state'] == 'inactive'
    request = g.cm.requests[-1]
    assert list(request.deactivate_controllers) == ['arm_controller']
    assert request.strictness == request.BEST_EFFORT and not request.activate_asap
    assert request.timeout.sec == 5
    ctrl = g.client.controller('arm_controller')
    assert 'inactive, not active' in refusal(ctrl, 'velocity', 'trajectory')
    # again: best effort, already inactive is no error (cm.cpp:2157-2182)
    assert g.client.deactivate('arm_controller') is None
    assert g.client.switch(deactivate=['arm_controller']) == (True, NOTHING)
    # strict: the manager refuses, and says why
    ok, message = g.client.switch(deactivate=['arm_controller'], strict=True)
    assert not ok and 'not active' in message
    # the explicit reset
    assert g.client.activate('arm_controller') is None
    assert g.client.state('arm_controller')['state'] == 'active'


def test_an_unknown_controller_or_a_missing_manager_is_one_line_not_a_hang(graph):
    from pg_node.ros.controller_manager import ControllerManagerClient, ControllerManagerError
    g = graph({'arm_controller': (JTC, 'active', SHIPPED)})
    with pytest.raises(ControllerManagerError, match='has no controller left_arm_controller'):
        g.client.controller('left_arm_controller')
    said = g.client.deactivate('left_arm_controller')
    assert 'has no controller left_arm_controller' in said
    ok, message = g.client.switch(deactivate=['left_arm_controller'])
    assert not ok and 'no controller with this name exists' in message
    lost = ControllerManagerClient(g.context, '/nowhere/controller_manager', timeout=0.3)
    try:
        started = time.monotonic()
        with pytest.raises(ControllerManagerError, match='no service '
                           '/nowhere/controller_manager/list_controllers within 0.3 s'):
            lost.controller('arm_controller')
        assert time.monotonic() - started < 3.0
        assert 'no service' in lost.deactivate('arm_controller')
    finally:
        lost.close()


def test_without_controller_manager_msgs_the_client_says_where_it_comes_from(monkeypatch):
    import builtins
    from pg_node.ros import controller_manager
    real = builtins.__import__

    def no_cm(name, *args, **kwargs):
        if name.startswith('controller_manager_msgs'):
            raise ImportError(f'No module named {name!r}')
        return real(name, *args, **kwargs)
    monkeypatch.setattr(builtins, '__import__', no_cm)
    with pytest.raises(controller_manager.ControllerManagerError,
                       match='installed with ros2_control'):
        controller_manager.messages()
    assert OPT_OUT == 'allow_no_dead_man'


def test_the_client_gives_configure_one_line_or_none(graph):
    g = graph({'arm_controller': (JTC, 'active', SHIPPED),
               'fwd': ('effort_controllers/JointGroupEffortController', 'active',
                       {'joints': JOINTS, 'interface_name': 'effort'})})
    assert g.client.refusal('arm_controller', 'velocity', 'trajectory') is None
    assert 'no dead-man' in g.client.refusal('fwd', 'effort', 'forward')
    assert g.client.refusal('fwd', 'effort', 'forward', allow_no_dead_man=True) is None
    line = g.client.refusal('right_arm', 'velocity', 'trajectory')
    assert line.startswith('cannot check controller right_arm through /controller_manager: '
                           '/controller_manager has no controller right_arm'), line


# -- policy_node supervised through the manager (issue 54, items 1 and 2) --------------------

#: a Jazzy JTC on the effort interface with a dead-man (config/controllers/jtc_effort.yaml)
EFFORT_JTC = {'joints': JOINTS, 'command_interfaces': ['effort'],
              'state_interfaces': ['position', 'velocity'], 'cmd_timeout': 0.2,
              'constraints.goal_time': 0.0}


def start_policy_node(tmp_path, types, policy, *params):
    """Start policy_node (autostart) with the built types importable, in this file's domain."""
    import os
    import sys
    from pathlib import Path
    from pg_node.tools import processes
    repo = Path(__file__).resolve().parent.parent
    env = dict(processes.child_env(DOMAIN_ID), PYTHONPATH=os.pathsep.join(
        [str(types / 'python'), str(repo)]))
    cmd = [sys.executable, '-m', 'pg_node.ros.policy_node', '--ros-args', '--params-file',
           str(repo / 'config' / 'policy_node.yaml'), '-p', f'policy:={policy}',
           '-p', 'controller_manager:=controller_manager', '-p', 'autostart:=true',
           '-p', 'configure_timeout:=30.0', '-p', 'controller_timeout:=5.0',
           *[a for p in params for a in ('-p', p)]]
    return processes.start_logged(cmd, tmp_path / f'policy_node_{time.monotonic_ns()}.log', env)


@pytest.fixture(scope='module')
def policy(tmp_path_factory):
    """Return an untrained reacher2 policy exported as ONNX (policy_node loads it in ms)."""
    from test_lifecycle_cli import policy as made
    return made.__wrapped__(tmp_path_factory)


def joint_states(g):
    """Publish reacher2's joint states at rest from the graph's context, as a robot would."""
    from sensor_msgs.msg import JointState
    node = rclpy.create_node('robot_joint_states', context=g.context)
    pub = node.create_publisher(JointState, '/joint_states', 10)
    node.create_timer(0.05, lambda: pub.publish(JointState(
        name=JOINTS, position=[0.0, 0.0], velocity=[0.0, 0.0])))
    g.executor.add_node(node)
    return node


@pytest.mark.e2e
def test_policy_node_refuses_a_forward_controller_in_one_line(graph, types, policy, tmp_path):
    """No dead-man: a forward controller keeps the last torque when policy_node dies."""
    from pg_node.tools import processes
    g = graph({'arm_controller': ('forward_command_controller/ForwardCommandController',
                                  'active', {'joints': JOINTS, 'interface_name': 'effort'})})
    joint_states(g)
    proc = start_policy_node(tmp_path, types, policy, 'command_message:=forward')
    proc.wait(timeout=90)               # autostart: a refused configure ends the node
    code, log = processes.stop_logged(proc)
    assert code == 2, log[-3000:]
    refused = [ln for ln in log.splitlines() if 'no dead-man' in ln]
    assert refused and "parameter 'policy_node.controller_manager': controller " \
        '/arm_controller is a forward command controller' in refused[0], log[-3000:]
    assert 'allow_no_dead_man true' in refused[0]


@pytest.mark.e2e
def test_an_estop_deactivates_the_arm_controller_and_only_a_reset_activates_it(
        graph, types, policy, tmp_path):
    """controller_stop deactivate: the robot's own stop acts; ~/reset_estop brings it back."""
    from lifecycle_msgs.srv import GetState
    from pg_node.tools import processes
    from std_msgs.msg import Bool
    from std_srvs.srv import Trigger
    g = graph({'arm_controller': (JTC, 'active', EFFORT_JTC)})
    node = joint_states(g)
    estop = node.create_publisher(Bool, '/estop', 10)
    get_state = node.create_client(GetState, '/policy_node/get_state')
    proc = start_policy_node(tmp_path, types, policy, 'controller_stop:=deactivate')
    try:
        deadline = time.monotonic() + 90

        def call(client, request):
            assert client.wait_for_service(timeout_sec=30)
            answer = client.call_async(request)
            while not answer.done():
                assert time.monotonic() < deadline and proc.poll() is None, 'no answer'
                time.sleep(0.05)
            return answer.result()
        # autostart configures (reading the controller), then activates
        while call(get_state, GetState.Request()).current_state.label != 'active' \
                or not estop.get_subscription_count():
            time.sleep(0.1)
        estop.publish(Bool(data=True))
        while g.cm.states['arm_controller'] != 'inactive':
            assert time.monotonic() < deadline, 'not deactivated'
            time.sleep(0.1)
        answer = call(node.create_client(Trigger, '/policy_node/reset_estop'), Trigger.Request())
        assert answer.success, answer.message
        assert g.cm.states['arm_controller'] == 'active'
    finally:
        code, log = processes.stop_logged(proc)
    assert code == 0, log[-3000:]
    assert 'e-stop: arm controller arm_controller deactivated' in log, log[-3000:]
    # the shutdown that followed deactivated it again (the stop's default for this set-up)
    assert g.cm.states['arm_controller'] == 'inactive'
