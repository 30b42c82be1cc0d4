"""
Several "hosts" on this machine, by hand: try docs/many_runs.md's commands as the test does.

``test/test_multi_host.py`` runs a learner host and worker hosts in Linux network
namespaces on a bridge (``bench/lan.py``), with Fast DDS's shared memory off so that every
message crosses the virtual network. This script makes the same hosts and leaves them up,
so that each command can be typed in a terminal of its own. Run it as root (``sudo -s``),
from the repository root::

    python scripts/lan_hosts.py up [--hosts 3]         # hosts 0, 1, 2: 10.213.251.1, .2, .3
    python scripts/lan_hosts.py run 0 -- python -m pg_node train --part learner ...
    python scripts/lan_hosts.py status                 # the hosts, and what runs in each
    python scripts/lan_hosts.py down                   # stop what runs in them, remove all

``run HOST -- CMD`` runs CMD in host HOST (its number or its namespace's name) with the
DDS settings of the test: UDP only (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``) and discovery by
multicast (``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``), or with ``--static-peers`` the other
hosts' addresses in ``ROS_STATIC_PEERS`` (``LOCALHOST``), as on a network without
multicast; the rest of the environment (``ROS_DOMAIN_ID``, ``PYTHONPATH``) is passed on.
``--prefix`` names the namespaces and links (default ``pgl``: ``pglh0``, ``pglv0``, the
bridge ``pglb``), ``--subnet X`` their addresses (``10.213.X.0/24``): give the same to every
subcommand. Exit codes: 0, 1 when something failed (the line says what), 2 for bad usage.
"""
import argparse
import os
from pathlib import Path
import shlex
import signal
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))   # bench/, pg_node/

from bench.lan import dds_env, Lan, unavailable  # noqa: E402 - after the path
from pg_node.tools.processes import proc_stat  # noqa: E402

#: seconds a process in a host has to end after SIGINT, then after SIGTERM, at ``down``
GRACE = 10.0


def find_host(lan: Lan, text: str):
    """Return the host ``text`` names (its number or namespace name), or None."""
    for i, host in enumerate(lan.hosts):
        if text in (str(i), host.name):
            return host
    return None


def up(args) -> int:
    """Make ``--hosts`` hosts (removing an earlier LAN of the prefix first); list them."""
    Lan.existing(args.prefix, args.subnet).remove()
    lan = Lan(args.hosts, args.prefix, args.subnet)
    try:
        lan.build()
    except RuntimeError as exc:
        print(f'lan_hosts: {exc}', file=sys.stderr)
        return 1
    for i, host in enumerate(lan.hosts):
        print(f'host {i}: namespace {host.name}, address {host.address}')
    print(f'run a command in host i: python {sys.argv[0]} run i -- COMMAND; '
          f'remove them all: python {sys.argv[0]} down')
    return 0


def run(args, lan: Lan) -> int:
    """Replace this process with ``args.command`` in the host named, DDS as the test sets it."""
    host = find_host(lan, args.host)
    if host is None:
        hosts = ', '.join(f'{i} ({h.name})' for i, h in enumerate(lan.hosts)) or 'none: run up'
        print(f'lan_hosts: no host {args.host!r}; hosts: {hosts}', file=sys.stderr)
        return 1
    command = list(args.command)
    while command[:1] == ['--static-peers']:      # after HOST: REMAINDER took it
        args.static_peers = command.pop(0)
    command = command[1:] if command[:1] == ['--'] else command
    if not command:
        print('lan_hosts: run HOST -- COMMAND: the command is missing', file=sys.stderr)
        return 2
    peers = [h.address for h in lan.hosts if h is not host] if args.static_peers else ()
    env = dds_env(dict(os.environ), discovery='LOCALHOST' if args.static_peers else 'SUBNET',
                  static_peers=peers)
    print(f'lan_hosts: in {host.name} ({host.address}): {shlex.join(command)}',
          file=sys.stderr, flush=True)
    os.execvpe('ip', ['ip', 'netns', 'exec', host.name, *command], env)


def stop(pids):
    """SIGINT ``pids``, then SIGTERM, then SIGKILL what is left; return those that ended."""
    left = set(pids)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        for pid in left:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        end = time.monotonic() + GRACE
        while left and time.monotonic() < end:
            left = {p for p in left if (proc_stat(p) or ['Z'])[0] != 'Z'}   # gone or ended
            time.sleep(0.1)
        if not left:
            break
    return [p for p in pids if p not in left]


def down(lan: Lan) -> int:
    """Stop the processes in the hosts, then remove the namespaces, links and bridge."""
    for host in lan.hosts:
        pids = host.pids()
        if pids:
            print(f'{host.name}: stopping {", ".join(map(str, pids))}', flush=True)
            stop(pids)
    lan.remove()
    left = lan.leftovers()
    if left:
        print(f'lan_hosts: could not remove {", ".join(left)}', file=sys.stderr)
        return 1
    print(f'removed {len(lan.hosts)} host(s) and the bridge {lan.bridge}')
    return 0


def status(lan: Lan) -> int:
    """Print each host, its address and the processes running in it."""
    if not lan.hosts:
        print(f'no hosts of prefix {lan.prefix!r} (python {sys.argv[0]} up makes them)')
        return 0
    for i, host in enumerate(lan.hosts):
        pids = host.pids()
        procs = []
        for pid in pids:
            try:
                cmd = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
                procs.append(f'{pid} {shlex.join(c.decode() for c in cmd if c)}')
            except OSError:
                pass
        print(f'host {i}: namespace {host.name}, address {host.address}, '
              f'{len(pids)} process(es)' + ''.join(f'\n  {p}' for p in procs))
    return 0


def parser() -> argparse.ArgumentParser:
    """Return the command line of the script."""
    p = argparse.ArgumentParser(
        prog='lan_hosts.py',
        description='Linux network namespaces on a bridge as hosts, to try docs/many_runs.md '
                    'by hand (root only).')
    p.add_argument('--prefix', default='pgl',
                   help='names of the namespaces and links (default pgl: pglh0, pglv0, ...)')
    p.add_argument('--subnet', type=int, default=251, choices=range(1, 255), metavar='1..254',
                   help='hosts are 10.213.SUBNET.1, .2, ... (default 251)')
    sub = p.add_subparsers(dest='action', required=True)
    make = sub.add_parser('up', help='make the hosts')
    make.add_argument('--hosts', type=int, default=3, choices=range(1, 65), metavar='N',
                      help='how many (default 3: a learner host and two worker hosts)')
    one = sub.add_parser('run', help='run a command in a host: run HOST -- COMMAND ...')
    one.add_argument('host', help='its number (0, 1, ...) or its namespace name')
    one.add_argument('--static-peers', action='store_true',
                     help='discover by ROS_STATIC_PEERS (the other hosts), not multicast')
    one.add_argument('command', nargs=argparse.REMAINDER)
    sub.add_parser('status', help='list the hosts and what runs in them')
    sub.add_parser('down', help='stop what runs in the hosts and remove them')
    return p


def main(argv=None) -> int:
    """Run the subcommand; return the exit status."""
    args = parser().parse_args(argv)
    if len(args.prefix) > 8 or not args.prefix.isalnum():
        print(f'lan_hosts: --prefix {args.prefix!r}: at most 8 letters and digits (a link '
              'name has 15 characters at most)', file=sys.stderr)
        return 2
    why = unavailable()
    if why is not None:
        print(f'lan_hosts: {why} (run it as root: sudo -s)', file=sys.stderr)
        return 1
    if args.action == 'up':
        return up(args)
    lan = Lan.existing(args.prefix, args.subnet)
    if args.action == 'run':
        return run(args, lan)
    return status(lan) if args.action == 'status' else down(lan)


if __name__ == '__main__':
    sys.exit(main())
