"""Start a pg_node node as a process of its own, as the end-to-end tests do."""
import sys
import time

from pg_node.tools import processes


def start_node(domain: int, tmp_path, module: str, *params, remap=()):
    """Start ``python -m <module> --ros-args -p ... -r ...`` in ``domain``, logged in tmp_path."""
    args = [sys.executable, '-m', module, '--ros-args']
    for param in params:
        args += ['-p', param]
    for rule in remap:
        args += ['-r', rule]
    log = tmp_path / f'{module.rsplit(".", 1)[-1]}_{time.monotonic_ns()}.log'
    return processes.start_logged(args, log, processes.child_env(domain))
