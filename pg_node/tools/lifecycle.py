"""
``python -m pg_node lifecycle NODE get|configure|activate|deactivate|cleanup``.

For users without the ``ros2`` command line: ``ros2 lifecycle get NODE`` and ``ros2
lifecycle set NODE TRANSITION`` over the services every managed node offers
(``lifecycle_msgs``): ``<NODE>/get_state`` (``GetState``) and ``<NODE>/change_state``
(``ChangeState``). ``NODE`` is a full node name (``/policy_node``, ``/left/policy_node``);
a name without a leading ``/`` gets one, as ros2cli gives it (ros2cli jazzy de6cd272
ros2node/ros2node/api/__init__.py:37-42).

It prints what ros2cli prints (ros2cli jazzy de6cd272 ros2lifecycle/ros2lifecycle/verb):

* ``get``: the state as ``<label> [<id>]``, e.g. ``active [3]`` (get.py:76); exit 0;
* a transition: ``Transitioning successful`` (set.py:86-87); exit 0. One the node refuses:
  one line on stderr starting ``Transitioning failed`` (set.py:88-89) that names the state
  the node is in and, when the transition does not start from there, the ones that do, or
  else the reason: the error the node logged on ``/rosout`` meanwhile (ros2cli prints no
  reason; the log holds it); exit 1 (ros2cli prints the line and exits 0; a script here
  learns of the failure).

A node that offers no ``get_state`` within ``--timeout`` s: one line starting ``Node not
found`` (get.py:50) that names the lifecycle nodes seen; exit 1. Bad arguments: argparse's
usage and one line; exit 2. The transition is asked for by label as well as id: a managed
node looks a label up among the transitions from its current state and answers
``success: false`` when there is none, rather than failing inside (rclpy jazzy
lifecycle/node.py ``__on_change_state``; rclcpp_lifecycle does the same).
"""
import argparse
import sys
import time

from pg_node.tools.args import positive_float

#: the transitions this command asks for, with their lifecycle_msgs/msg/Transition ids
TRANSITIONS = {'configure': 1, 'cleanup': 2, 'activate': 3, 'deactivate': 4}
#: the service type ``ros2 lifecycle nodes`` looks for (ros2cli jazzy de6cd272
#: ros2lifecycle/ros2lifecycle/api/__init__.py:36-43)
GET_STATE_TYPE = 'lifecycle_msgs/srv/GetState'


def absolute_node_name(text: str) -> str:
    """
    Return ``text`` as a full node name, with a leading ``/``; refuse an invalid one.

    >>> absolute_node_name('policy_node'), absolute_node_name('/left/policy_node')
    ('/policy_node', '/left/policy_node')
    """
    from rclpy.exceptions import InvalidServiceNameException
    from rclpy.validate_full_topic_name import validate_full_topic_name
    name = '/' + text.strip('/')
    try:
        validate_full_topic_name(name + '/get_state', is_service=True)
    except InvalidServiceNameException as exc:
        # "Invalid service name: topic name must not ...": the rule, said of the node name
        rule = str(exc).splitlines()[0].split(': ', 1)[-1].replace('topic name', 'it')
        raise argparse.ArgumentTypeError(f'{text!r} is not a node name: {rule}') from None
    return name


def parse_args(argv):
    """Parse ``NODE COMMAND [--timeout S]``."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node lifecycle',
        description="Get or change a managed node's lifecycle state (ros2 lifecycle get/set "
                    'without the ros2 CLI).')
    parser.add_argument('node', type=absolute_node_name,
                        help='full node name, e.g. /policy_node or /left/policy_node')
    parser.add_argument('command', choices=('get', *TRANSITIONS),
                        help='get: print the state; else: ask for that transition')
    parser.add_argument('--timeout', type=positive_float, default=5.0,
                        help='seconds to wait for the node to be found (default 5)')
    return parser.parse_args(argv)


def state_text(state) -> str:
    """Return a ``lifecycle_msgs/msg/State`` as ros2 lifecycle prints it: ``active [3]``."""
    return f'{state.label} [{state.id}]'


class LifecycleClient:
    """The services of one managed node, called from a node of this process."""

    def __init__(self, node, name: str):
        """Make the clients of node ``name``'s lifecycle services."""
        from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
        from rclpy.executors import SingleThreadedExecutor
        self.node, self.name = node, name
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self.get = node.create_client(GetState, f'{name}/get_state')
        self.change = node.create_client(ChangeState, f'{name}/change_state')
        self.available = node.create_client(GetAvailableTransitions,
                                            f'{name}/get_available_transitions')
        # what the node logs at ERROR and above on /rosout (a refused transition's reason);
        # transient local as rcl's rosout publisher, so a line logged before this command's
        # subscription was matched still comes (rcl jazzy include/rcl/logging_rosout.h
        # rcl_qos_profile_rosout_default: reliable, transient local, depth 1000)
        from rcl_interfaces.msg import Log
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        self.logger_name = name.strip('/').replace('/', '.')
        self.errors = []
        node.create_subscription(
            Log, '/rosout', self._on_log,
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.asked_at = None

    def _on_log(self, msg):
        """Keep the node's ERROR and FATAL lines (its logger's name is its full name)."""
        if msg.name == self.logger_name and msg.level >= msg.ERROR:
            self.errors.append((msg.stamp.sec + msg.stamp.nanosec * 1e-9, msg.msg))

    def reason(self, wait: float = 2.0):
        """
        Return the node's newest error line since the transition was asked for, or None.

        Waits up to ``wait`` s for it: /rosout and the service answer are separate topics.
        """
        deadline = time.monotonic() + wait
        while True:
            # the node's clock is the wall clock here (a stamp in simulated time never
            # passes this and leaves the line to the node's log)
            since = [text for stamp, text in self.errors if stamp >= self.asked_at - 1.0]
            if since or time.monotonic() > deadline:
                return since[-1] if since else None
            self.executor.spin_once(timeout_sec=0.05)

    def call(self, client, request):
        """Call ``client`` and wait for the answer (as ros2cli does, without a limit)."""
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future)
        if future.exception() is not None:
            raise future.exception()
        return future.result()

    def state(self):
        """Return the node's ``lifecycle_msgs/msg/State``."""
        return self.call(self.get, self.get.srv_type.Request()).current_state

    def transition(self, label: str) -> bool:
        """Ask for transition ``label``; return whether the node made it."""
        request = self.change.srv_type.Request()
        request.transition.id, request.transition.label = TRANSITIONS[label], label
        self.asked_at = time.time()
        return self.call(self.change, request).success

    def transitions_from_here(self) -> list:
        """Return the labels of the transitions the node offers from its current state."""
        answer = self.call(self.available, self.available.srv_type.Request())
        return list(dict.fromkeys(t.transition.label for t in answer.available_transitions))


def full_names(node) -> dict:
    """Return ``{full name: (name, namespace)}`` of the nodes in the graph."""
    return {ns.rstrip('/') + '/' + n: (n, ns) for n, ns in node.get_node_names_and_namespaces()}


def lifecycle_nodes(node) -> list:
    """
    Return the managed nodes seen, sorted: those that serve ``<name>/get_state``.

    Asked node by node (``get_service_names_and_types_by_node`` lists a node's servers):
    the graph's list of service names holds clients' too, this command's own among them.
    """
    from rclpy.impl.implementation_singleton import rclpy_implementation
    gone = rclpy_implementation.NodeNameNonExistentError

    def serves_get_state(full, name, namespace):
        try:
            servers = node.get_service_names_and_types_by_node(name, namespace)
        except gone:                    # it left the graph since it was listed
            return False
        return any(s == f'{full}/get_state' and GET_STATE_TYPE in types for s, types in servers)

    return sorted(full for full, (n, ns) in full_names(node).items()
                  if serves_get_state(full, n, ns))


def not_found(node, name: str, timeout: float) -> str:
    """Return the line for a node that offered no ``get_state`` within ``timeout`` s."""
    seen = lifecycle_nodes(node)
    why = (f'{name} runs but is not a managed (lifecycle) node' if name in full_names(node)
           else f'no lifecycle node {name} answered within {timeout:g} s')
    return (f'Node not found: {why}; lifecycle nodes seen on ROS_DOMAIN_ID '
            f'{node.context.get_domain_id()}: {", ".join(seen) or "none"} (ros2 lifecycle '
            'nodes lists them)')


def refusal(client: LifecycleClient, label: str) -> str:
    """Return the line for a transition the node refused: where it is, what it offers."""
    state = client.state()
    offered = client.transitions_from_here()
    if label not in offered:
        return (f'Transitioning failed: {client.name} is {state_text(state)}, from which '
                f'there is no {label} (from there: {", ".join(offered) or "none"})')
    why = client.reason()
    return (f'Transitioning failed: {client.name} refused {label} and is '
            f'{state_text(state)}' + (f': {why}' if why else ' (its log says why)'))


def run(args) -> int:
    """Find the node, then print its state or ask for the transition; return the exit code."""
    import rclpy
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    # a hidden name (leading _), as ros2cli's own nodes: not in ros2 node list
    node = rclpy.create_node(f'_pg_node_lifecycle_{time.monotonic_ns() % 10**9}',
                             context=context, start_parameter_services=False)
    try:
        client = LifecycleClient(node, args.node)
        if not client.get.wait_for_service(timeout_sec=args.timeout):
            print(not_found(node, args.node, args.timeout), file=sys.stderr)
            return 1
        if args.command == 'get':
            print(state_text(client.state()))
            return 0
        if not client.change.wait_for_service(timeout_sec=args.timeout):
            print(not_found(node, args.node, args.timeout), file=sys.stderr)
            return 1
        if client.transition(args.command):
            print('Transitioning successful')
            return 0
        print(refusal(client, args.command), file=sys.stderr)
        return 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def main(argv=None) -> int:
    """Run ``python -m pg_node lifecycle``."""
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        return run(args)
    except KeyboardInterrupt:
        print(f'interrupted: no answer from {args.node} yet', file=sys.stderr)
        return 130
