"""
sim_node with lock-step round-trip timing, for the benchmarks.

``python -m pg_node.tools.latency_probe OUT.npy --ros-args -p num_envs:=64`` runs the real
:class:`~pg_node.ros.sim_node.SimNode` (same parameters, topics, code path, and executor
loop: :func:`pg_node.ros.node_utils.run`) and measures, in its own process and clock, the
time from just before it publishes a transition to the moment the command answering it
arrives in ``on_command``: serialisation, DDS both ways, the client's work and the
executor's dispatch. On shutdown (Ctrl-C / SIGINT) it writes the
round trips in nanoseconds to ``OUT.npy``. A transition re-sent after a lock-step timeout
restarts the clock, so a lost message shows up as one long round trip, not as a gap.
"""
import sys
import time

import numpy as np
from pg_node.common.paths import default_config
from pg_node.ros.node_utils import run
from pg_node.ros.sim_node import SimNode


class _TimedPublisher:
    """Forwards to a publisher, noting the time of every ``publish`` on the node first."""

    def __init__(self, node, pub):
        self._node, self._pub = node, pub

    def publish(self, msg):
        """Note the time, then publish."""
        self._node.sent_ns = time.perf_counter_ns()
        self._pub.publish(msg)

    def __getattr__(self, name):
        return getattr(self._pub, name)


class TimedSimNode(SimNode):
    """A SimNode that records the lock-step round trip of every transition it publishes."""

    def __init__(self):
        self.round_trips = []
        self.sent_ns = None
        super().__init__()
        self.pub_transition = _TimedPublisher(self, self.pub_transition)

    def on_command(self, msg):
        """Record the round trip of the transition this command answers, then handle it."""
        if self.sent_ns is not None:
            self.round_trips.append(time.perf_counter_ns() - self.sent_ns)
            self.sent_ns = None
        super().on_command(msg)


def main(argv=None) -> int:
    """Run the timed simulator until SIGINT, then write the round trips."""
    argv = list(sys.argv if argv is None else argv)
    if len(argv) < 2 or argv[1].startswith('-'):
        print('usage: python -m pg_node.tools.latency_probe OUT.npy [--ros-args ...]',
              file=sys.stderr)
        return 2
    out, ros_args = argv[1], [argv[0]] + argv[2:]
    config = default_config()
    if '--params-file' not in ros_args and config.is_file():
        if '--ros-args' not in ros_args:
            ros_args.append('--ros-args')
        at = ros_args.index('--ros-args') + 1
        ros_args[at:at] = ['--params-file', str(config)]

    def save(node):
        np.save(out, np.asarray(node.round_trips, dtype=np.int64))
        node.task.close()

    # sim_node's own loop and executor (node_utils.run), so the round trip is training's
    return run(TimedSimNode, ros_args, cleanup=save)


if __name__ == '__main__':
    sys.exit(main())
