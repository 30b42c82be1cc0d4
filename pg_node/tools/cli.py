"""
``python -m pg_node <command>``: one entry point for the tools that need no ``ros2`` CLI.

Each command lives in its own module with a ``main(argv) -> int``; it is imported only when
asked for, so ``python -m pg_node variance`` never loads rclpy and a command whose module is
missing says so instead of failing at start-up.
"""
import importlib
import importlib.util
import os
import sys

#: command -> (module, one-line help)
#: the exit status of a command whose reader closed the pipe (SIGPIPE's, as coreutils')
EXIT_BROKEN_PIPE = 128 + 13

COMMANDS = {
    'train': ('pg_node.tools.train', 'start the training graph (sim, actor, critic, learner)'),
    'eval': ('pg_node.tools.evaluate', 'evaluate a saved policy checkpoint'),
    'robustness': ('pg_node.tools.robustness', 'compare trained policies on arms that are not '
                                               'their model (mass, strength, latency, noise)'),
    'variance': ('pg_node.tools.variance', 'bias and variance of every gradient estimator'),
    'replay': ('pg_node.ros.replay_node', 'play a rosbag2 MCAP bag back onto its topics'),
    'monitor': ('pg_node.tools.monitor', 'live terminal view of a running training'),
    'topics': ('pg_node.tools.topics', "list the graph's topics, types, endpoints and rates"),
    'plot': ('pg_node.tools.plot', 'learning-curve PNG from a bag or run directory'),
    'render': ('pg_node.tools.render', 'animation of a recorded episode'),
    'reindex': ('pg_node.tools.reindex', 'make bags whole after a killed writer (ros2 bag '
                                         'reindex)'),
    'export': ('pg_node.tools.export', 'a trained policy as ONNX with its card (runs without '
                                       'torch)'),
    'play': ('pg_node.tools.play', 'watch a trained policy act: real-time sim_node + policy_node'),
    'view': ('pg_node.tools.view', "the arm in the Foxglove app: live, or from a run's bag"),
    'arm': ('pg_node.tools.arm', "import a robot's URDF as an arm model (arm import)"),
    'lifecycle': ('pg_node.tools.lifecycle', "get or change a managed node's lifecycle state "
                                             '(ros2 lifecycle get/set)'),
}
#: commands that left the installed package for the repository's ``bench`` package: what to
#: type instead, from a checkout of the repository
MOVED = {
    'bench': 'python -m bench',
    'soak': 'python -m bench.soak',
}
#: third-party modules every command imports: looked for before a command's module is loaded
NEEDED = ('numpy', 'yaml')


def missing_dependency(name: str) -> str:
    """Return the one line that says a dependency is not in this Python, and what to do."""
    return (f'pg_node: this Python ({sys.executable}) has no {name!r}, which pg_node needs: '
            'run `source .venv/bin/activate` in the checkout first (`make train` and '
            '`make test` create it), or the Python pg_node was installed into')


def usage() -> str:
    """Return the command list shown by ``python -m pg_node --help``."""
    lines = ['usage: python -m pg_node <command> [options]', '', 'commands:']
    for name, (module, text) in COMMANDS.items():
        available = importlib.util.find_spec(module) is not None
        lines.append(f'  {name:<10} {text}' + ('' if available else '  (not built yet)'))
    lines.append('')
    lines.append("`python -m pg_node <command> --help` describes a command's options.")
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Dispatch to the command's module; a reader that leaves early ends it quietly."""
    try:
        code = dispatch(argv)
        sys.stdout.flush()          # here, not at exit, where a closed pipe would be reported
        return code
    except BrokenPipeError:
        # the reader left (``... --list | head``, ``--help | head``): stop quietly, as
        # coreutils do when SIGPIPE ends them (status 128 + 13); the recipe of Python's signal
        # docs: stdout goes to devnull so that nothing is written to the closed pipe at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


def dispatch(argv=None) -> int:
    """Run the command ``argv`` names; return its exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ('-h', '--help'):
        print(usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name in MOVED:
        print(f'pg_node: {name!r} is not part of the installed package any more: from a '
              f'checkout of the repository, run `{MOVED[name]}` (docs/benchmarks.md)',
              file=sys.stderr)
        return 2
    if name not in COMMANDS:
        print(f'pg_node: unknown command {name!r}\n\n{usage()}', file=sys.stderr)
        return 2
    module_name = COMMANDS[name][0]
    if importlib.util.find_spec(module_name) is None:
        print(f'pg_node: command {name!r} is not available in this version '
              f'(module {module_name} is missing)', file=sys.stderr)
        return 2
    absent = [m for m in NEEDED if importlib.util.find_spec(m) is None]
    if absent:
        print(missing_dependency(absent[0]), file=sys.stderr)
        return 2
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        # a dependency of this command alone (mcap, torch, rclpy...): before anything ran
        if not exc.name or exc.name.split('.')[0] == 'pg_node':
            raise
        print(missing_dependency(exc.name.split('.')[0]), file=sys.stderr)
        return 2
    return int(module.main(rest) or 0)
