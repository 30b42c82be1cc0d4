"""
``python -m pg_node lifecycle``: ros2 lifecycle get/set for users without the ros2 CLI.

End to end: policy_node starts (unconfigured, from the shipped ``config/policy_node.yaml``
with an untrained reacher2 policy exported to ONNX) and the command, run as a process,
reads its state and drives its transitions over ``lifecycle_msgs``' services. What it
prints is ros2cli's (ros2cli jazzy de6cd272 ros2lifecycle/ros2lifecycle/verb/get.py:76 and
set.py:86-89): ``unconfigured [1]``, ``Transitioning successful``, ``Transitioning failed``.
"""
import contextlib
from pathlib import Path
import subprocess
import sys
import types

from domains import ros_domain
import pytest
from repeating import repeating

REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID = ros_domain(base=100, spread=10)


@pytest.fixture(scope='module')
def policy(tmp_path_factory):
    """Return an untrained reacher2 policy exported as ONNX (policy_node loads it in ms)."""
    from pg_node.common.config_files import load_config
    from pg_node.common.paths import default_config
    from pg_node.rl.learner import Learner
    from pg_node.rl.onnx_export import export_policy
    from pg_node.rl.trained_policy import find_checkpoint, TorchPolicy
    root = tmp_path_factory.mktemp('lifecycle_run')
    sections = load_config(default_config(), [f'run_dir={root}'])
    Learner(10, 2, {k: v for s in sections.values() for k, v in s.items()}).save(
        root / 'checkpoints')
    torch_policy = TorchPolicy(*find_checkpoint(root))
    export_policy(torch_policy.policy, torch_policy.card, root / 'policy.onnx')
    return root / 'policy.onnx'


def lifecycle(*args, timeout=60):
    """Run ``python -m pg_node lifecycle ARGS`` in the test's domain."""
    from pg_node.tools import processes
    return subprocess.run([sys.executable, '-m', 'pg_node', 'lifecycle', *args],
                          env=processes.child_env(DOMAIN_ID), capture_output=True, text=True,
                          timeout=timeout)


@contextlib.contextmanager
def joint_states_published(names=('joint0', 'joint1'), rate=20.0):
    """Publish reacher2's joint states at rest in the test's domain (configure waits for one)."""
    import rclpy
    from rclpy.context import Context
    from sensor_msgs.msg import JointState
    context = Context()
    rclpy.init(context=context, domain_id=int(DOMAIN_ID))
    node = rclpy.create_node('lifecycle_test_joint_states', context=context)
    pub = node.create_publisher(JointState, '/joint_states', 10)
    rest = JointState(name=list(names), position=[0.0] * len(names),
                      velocity=[0.0] * len(names))
    try:
        with repeating(lambda: pub.publish(rest), rate):
            yield
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def one_line(done, code, *words):
    """Assert exit ``code`` and one line on stderr holding ``words``, nothing on stdout."""
    assert done.returncode == code, (done.returncode, done.stdout, done.stderr)
    assert done.stdout == '' and len(done.stderr.strip().splitlines()) == 1, done.stderr
    for word in words:
        assert word in done.stderr, (word, done.stderr)


@pytest.mark.e2e
def test_lifecycle_command_drives_policy_node(tmp_path, policy):
    """
    get, a refused activate, configure, activate, deactivate, cleanup; an unknown node.

    A second policy_node, in a namespace, fails its configure: the refusal names its state.
    """
    from pg_node.tools import processes

    def start(name, *args):
        # no controller serves its joints here: the check is off (controller_timeout 0)
        return processes.start_logged(
            [sys.executable, '-m', 'pg_node.ros.policy_node', '--ros-args', '--params-file',
             str(REPO / 'config' / 'policy_node.yaml'), '-p', f'policy:={policy}',
             '-p', 'controller_timeout:=0.0', *args],
            tmp_path / f'{name}.log', processes.child_env(DOMAIN_ID))

    with joint_states_published():
        node = start('policy_node')
        # in a namespace, with a record it cannot write: its configure callback fails
        bad = start('bad', '-r', '__ns:=/bad', '-r', 'joint_states:=/joint_states',
                    '-p', 'record:=/proc/no_bags_here/bag')
        try:
            # the reason the node logged, on the console
            one_line(lifecycle('/bad/policy_node', 'configure', '--timeout', '30'), 1,
                     'Transitioning failed: /bad/policy_node refused configure and is '
                     "unconfigured [1]: configure failed: parameter 'policy_node.record'")
            # a bare name: /policy_node
            first = lifecycle('policy_node', 'get', '--timeout', '30')
            assert (first.returncode, first.stdout) == (0, 'unconfigured [1]\n'), first.stderr
            # activate does not start from unconfigured: the node answers success false
            one_line(lifecycle('/policy_node', 'activate'), 1,
                     'Transitioning failed: /policy_node is unconfigured [1], from which '
                     'there is no activate (from there: configure, shutdown)')
            for command, state in (('configure', 'inactive [2]'),
                                   ('activate', 'active [3]'),
                                   ('deactivate', 'inactive [2]'),
                                   ('cleanup', 'unconfigured [1]')):
                done = lifecycle('/policy_node', command)
                assert (done.returncode, done.stdout) == (0, 'Transitioning successful\n'), \
                    (command, done.stderr)
                done = lifecycle('/policy_node', 'get')
                assert (done.returncode, done.stdout) == (0, state + '\n'), \
                    (command, done.stderr)
            # 8 s: time enough for the command to discover both nodes' services on a loaded
            # machine (3 s was not, once, in CI)
            one_line(lifecycle('/no_such_node', 'get', '--timeout', '8'), 1,
                     'Node not found: no lifecycle node /no_such_node answered within 8 s',
                     f'lifecycle nodes seen on ROS_DOMAIN_ID {DOMAIN_ID}: /bad/policy_node, '
                     '/policy_node (ros2 lifecycle nodes lists them)')
        finally:
            code, log = processes.stop_logged(node)
            bad_code, bad_log = processes.stop_logged(bad)
    assert code == 0, log[-3000:]
    assert bad_code == 0 and "configure failed: parameter 'policy_node.record'" in bad_log, \
        bad_log[-3000:]
    assert 'active: commanding' in log and 'cleaned up' in log, log[-3000:]


@pytest.mark.parametrize('args, words', [
    (['/policy_node', 'explode'], "invalid choice: 'explode'"),
    (['a b', 'get'], "'a b' is not a node name: it must not contain characters"),
    (['/policy_node', 'get', '--timeout', '0'], 'must be > 0'),
    (['/policy_node'], 'the following arguments are required: command'),
])
def test_bad_arguments_are_argparse_usage_and_exit_2(args, words):
    done = lifecycle(*args)
    assert done.returncode == 2 and words in done.stderr, done.stderr
    assert 'Traceback' not in done.stderr and done.stderr.strip().splitlines()[-1].startswith(
        'python -m pg_node lifecycle: error: ')


class FakeClient:
    """A managed node's answers, for the refusal line."""

    name = '/left/policy_node'

    def __init__(self, label, state_id, offered, reason=None):
        """Be in state ``label`` [``state_id``], offering ``offered``; ``reason``: logged."""
        self._state = types.SimpleNamespace(label=label, id=state_id)
        self._offered, self._reason = offered, reason

    def state(self):
        return self._state

    def transitions_from_here(self):
        return self._offered

    def reason(self):
        return self._reason


def test_refusal_names_the_state_and_what_starts_there():
    from pg_node.tools.lifecycle import refusal
    # a callback that returned FAILURE (configure failed): back where it was
    assert refusal(FakeClient('unconfigured', 1, ['configure', 'shutdown']), 'configure') == (
        'Transitioning failed: /left/policy_node refused configure and is unconfigured [1] '
        '(its log says why)')
    # the error the node logged meanwhile is the reason
    assert refusal(FakeClient('unconfigured', 1, ['configure'], 'configure failed: no policy'),
                   'configure') == ('Transitioning failed: /left/policy_node refused '
                                    'configure and is unconfigured [1]: configure failed: '
                                    'no policy')
    assert refusal(FakeClient('active', 3, ['deactivate', 'shutdown']), 'cleanup') == (
        'Transitioning failed: /left/policy_node is active [3], from which there is no '
        'cleanup (from there: deactivate, shutdown)')


class FakeGraph:
    """A node's view of the graph: node names and service names."""

    context = types.SimpleNamespace(get_domain_id=lambda: 7)

    def get_node_names_and_namespaces(self):
        return [('sim_node', '/'), ('policy_node', '/left')]

    def get_service_names_and_types(self):
        # the graph's list holds clients' service names too: this command's own client of
        # /sim_node/get_state among them
        return [('/left/policy_node/get_state', ['lifecycle_msgs/srv/GetState']),
                ('/sim_node/get_state', ['lifecycle_msgs/srv/GetState'])]

    def get_service_names_and_types_by_node(self, name, namespace):
        return {'/left/policy_node': [
            ('/left/policy_node/get_state', ['lifecycle_msgs/srv/GetState']),
            ('/left/policy_node/change_state', ['lifecycle_msgs/srv/ChangeState'])],
            '/sim_node': [('/sim_node/reset_world', ['std_srvs/srv/Trigger'])]}[
                namespace.rstrip('/') + '/' + name]


def test_not_found_says_why_and_lists_the_managed_nodes():
    from pg_node.tools.lifecycle import not_found
    assert not_found(FakeGraph(), '/sim_node', 2.0) == (
        'Node not found: /sim_node runs but is not a managed (lifecycle) node; lifecycle '
        'nodes seen on ROS_DOMAIN_ID 7: /left/policy_node (ros2 lifecycle nodes lists them)')
    assert not_found(FakeGraph(), '/policy_node', 2.0).startswith(
        'Node not found: no lifecycle node /policy_node answered within 2 s; lifecycle nodes '
        'seen on ROS_DOMAIN_ID 7: /left/policy_node')
