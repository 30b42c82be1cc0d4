"""
sim_and_actor: sim_node and actor_node in one process, sharing one executor (composition).

The two nodes, their names, parameters, topics and services are those of
``ros2 run pg_node sim_node`` and ``ros2 run pg_node actor_node``; only the process is
shared, as a ROS 2 component container holds several nodes. Their lock-step exchange (a
transition out, its command back, every control step) then needs no wake-up of another
process: Fast DDS hands a message to a reader of the same process without its transports,
and one executor runs both callbacks in turn (about half the round trip of two processes:
docs/ros_graph.md has the measurement). The critic and the learner share another process
the same way (:mod:`pg_node.ros.critic_and_learner`).

With sim_node's ``in_process_hop`` (the default) the two go further, as rclcpp's
intra-process communication would: the transition and the command are handed from one node
to the other inside the process (:class:`pg_node.ros.local_hop.LocalHop`), with no DDS write,
take or executor wake-up, and published on ``pg_node/transition`` and ``pg_node/commands``
too whenever anyone else subscribes them; ``in_process_hop:=false`` goes over DDS as two
processes do. Either way the training is the same, bit for bit.

``python -m pg_node train`` starts it in place of the two processes (``--separate``: the
two); started by hand it takes the ROS arguments both nodes take (``--ros-args
--params-file ...``, a namespace for several pairs). A ``-p`` given here reaches both
nodes: ``seed`` moves the actor's sampling as well as the simulator's episodes. Ctrl-C or
SIGTERM stops both.
"""
from pg_node.ros.actor_node import ActorNode
from pg_node.ros.local_hop import LocalHop
from pg_node.ros.runtime import make_together, run
from pg_node.ros.sim_node import SimNode


def make_nodes():
    """
    Return ``[SimNode(), ActorNode()]``; the simulator is closed if the actor fails.

    With the simulator's ``in_process_hop``, each node's publisher to the other goes
    through a :class:`pg_node.ros.local_hop.LocalHop`.
    """
    sim, actor = make_together(SimNode, ActorNode)
    if sim.params['in_process_hop']:
        sim.pub_transition = LocalHop(sim.pub_transition, actor.sub_transition)
        actor.pub_cmd = LocalHop(actor.pub_cmd, sim.sub_cmd)
        sim.get_logger().info('transitions and commands handed to actor_node inside the '
                              'process (in_process_hop)')
    return [sim, actor]


def main(args=None):
    """Run both nodes until Ctrl-C or an external shutdown."""
    return run(make_nodes, args, cleanup=lambda nodes: nodes[0].close())


if __name__ == '__main__':
    raise SystemExit(main())
