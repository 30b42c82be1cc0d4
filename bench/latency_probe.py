"""
sim_node with every lock-step round trip written to a file, for the benchmarks.

``python -m bench.latency_probe OUT.npy --ros-args -p num_envs:=64`` runs sim_node
(:mod:`pg_node.ros.sim_node`: its parameters, topics, code path and executor loop) with
``round_trip_log:=OUT.npy``: in its own process and clock, the node times each transition
from just before it is published to the arrival of the command that answers it
(serialisation, DDS both ways, the client's work and the executor's dispatch) and, on
shutdown (Ctrl-C / SIGINT), writes the round trips in nanoseconds to ``OUT.npy``. A
transition re-sent after a lock-step timeout restarts the clock, so a lost message shows up
as one long round trip, not as a gap.
"""
import sys

from pg_node.ros import sim_node


def main(argv=None) -> int:
    """Run sim_node with ``round_trip_log`` until SIGINT."""
    argv = list(sys.argv if argv is None else argv)
    if len(argv) < 2 or argv[1].startswith('-'):
        print('usage: python -m bench.latency_probe OUT.npy [--ros-args ...]',
              file=sys.stderr)
        return 2
    out, ros_args = argv[1], [argv[0]] + argv[2:]
    if '--ros-args' not in ros_args:
        ros_args.append('--ros-args')
    # (a --params-file with a sim_node section that sets round_trip_log would win over this)
    return sim_node.main(ros_args + ['-p', f'round_trip_log:={out}'])


if __name__ == '__main__':
    sys.exit(main())
