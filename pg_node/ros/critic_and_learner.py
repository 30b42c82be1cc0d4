"""
critic_and_learner: critic_node and learner_node in one process, sharing one executor.

The composition of :mod:`pg_node.ros.sim_and_actor` for the training side: the two nodes,
their names, parameters, topics and services are those of ``ros2 run pg_node critic_node``
and ``ros2 run pg_node learner_node``; only the process is shared. The batch goes from the
critic to the learner without leaving the process, and one process holding torch is
loaded instead of two. V's regression step, which the critic queues after sending the
batch, runs once the learner has sent the new weights, so it stays off the hand-over's
path as it is with two processes.

Started by hand it takes the ROS arguments both nodes take (``--ros-args --params-file
...``); a ``-p`` given here reaches both nodes. It exits when the learner does (its
``total_steps`` learned with ``exit_when_done``), Ctrl-C or SIGTERM; both nodes save their
checkpoints first.
"""
from pg_node.ros.critic_node import CriticNode
from pg_node.ros.learner_node import LearnerNode
from pg_node.ros.runtime import make_together, run


def make_nodes():
    """Return ``[CriticNode(), LearnerNode()]``; the critic is destroyed if the learner fails."""
    return make_together(CriticNode, LearnerNode)


def cleanup(nodes):
    """Save V and close the learner's checkpoint, bag and logs."""
    critic, learner = nodes
    critic.save()
    learner.close()


def main(args=None):
    """Run both nodes until the learner is done, Ctrl-C or an external shutdown."""
    return run(make_nodes, args, cleanup=cleanup)


if __name__ == '__main__':
    raise SystemExit(main())
