"""
sim_and_actor: sim_node and actor_node in one process, sharing one executor (composition).

The two nodes, their names, parameters, topics and services are those of
``ros2 run pg_node sim_node`` and ``ros2 run pg_node actor_node``; only the process is
shared, as a ROS 2 component container holds several nodes. Their lock-step exchange (a
transition out, its command back, every control step) then needs no wake-up of another
process: Fast DDS hands a message to a reader of the same process without its transports,
and one executor runs both callbacks in turn. Measured on 2 cores (BENCHMARKS.md, the ROS
tax, two invocations of 5 paired runs): the round trip within a rollout 0.33-0.34 ms at the
median and 0.91-0.92 ms at p99, against 0.68-0.82 and 2.3-2.9 ms with two processes, and
training faster in each of the ten pairs (graph / in-process 0.765 and 0.639 against 0.559
and 0.543). The critic and the learner share another process the same way
(:mod:`pg_node.ros.critic_and_learner`).

``python -m pg_node train`` starts it in place of the two processes (``--separate``: the
two); started by hand it takes the ROS arguments both nodes take (``--ros-args
--params-file ...``, a namespace for several pairs). A ``-p`` given here reaches both
nodes: ``seed`` moves the actor's sampling as well as the simulator's episodes. Ctrl-C or
SIGTERM stops both.
"""
from pg_node.ros.actor_node import ActorNode
from pg_node.ros.runtime import make_together, run
from pg_node.ros.sim_node import SimNode


def make_nodes():
    """Return ``[SimNode(), ActorNode()]``; the simulator is closed if the actor fails."""
    return make_together(SimNode, ActorNode)


def main(args=None):
    """Run both nodes until Ctrl-C or an external shutdown."""
    return run(make_nodes, args, cleanup=lambda nodes: nodes[0].close())


if __name__ == '__main__':
    raise SystemExit(main())
