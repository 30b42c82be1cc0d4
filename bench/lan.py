"""
Several "hosts" on one machine: Linux network namespaces on a bridge, for DDS across hosts.

For the multi-host tests (``test/test_multi_host.py``) and benchmark
(``bench/bench_hosts.py``); nothing in training uses it. Needs root (CI runs as root) and
``ip``; :func:`unavailable` says why not otherwise.

Each host is a namespace with its loopback up and one veth to a bridge in the root namespace,
an address in a /24 of 10.213.x.0 of its own (the bridge has none: the hosts reach each other
and nothing else), and a route for multicast, which DDS discovery (``SUBNET``) uses. A
process runs in a host through ``ip netns exec`` (which execs it: the pid is the process's,
in a session of its own). Everything made is removed on exit, the processes stopped first.
Names carry ``pgn<pid>`` so that two test processes do not collide, and what a killed test
process left behind under its pid's names is removed first.

Shared memory does not cross namespaces, but Fast DDS would still use it between two
processes of one host: :func:`dds_env` turns it off (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``) so
that every message crosses the virtual network.
"""
import os
import shutil
import subprocess
from typing import Dict, List, Optional

from pg_node.tools import processes


def unavailable() -> Optional[str]:
    """Return why namespaces cannot be made here (not root, no ``ip``), or None."""
    if shutil.which('ip') is None:
        return 'the ip command (iproute2) is missing'
    if os.geteuid() != 0:
        return 'network namespaces need root'
    return None


def _ip(*args, check=True):
    return subprocess.run(['ip', *args], capture_output=True, text=True, check=check)


def dds_env(base: Dict[str, str], discovery: str = 'SUBNET', static_peers=(),
            shm: bool = False) -> Dict[str, str]:
    """Return ``base`` with the DDS settings of a host: UDP only, the discovery range, peers."""
    env = dict(base, ROS_AUTOMATIC_DISCOVERY_RANGE=discovery)
    if not shm:
        env['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'
    if static_peers:
        env['ROS_STATIC_PEERS'] = ';'.join(static_peers)
    else:
        env.pop('ROS_STATIC_PEERS', None)
    return env


class Host:
    """One namespace: its name, address, and the bridge-side end of its link."""

    def __init__(self, lan: 'Lan', index: int):
        self.lan = lan
        self.name = f'{lan.prefix}h{index}'
        self.address = f'10.213.{lan.subnet}.{index + 1}'
        self.link = f'{lan.prefix}v{index}'       # in the root namespace, on the bridge
        self.inner = f'{lan.prefix}e{index}'      # in the namespace

    def popen(self, argv: List[str], log_path, env: Dict[str, str]) -> subprocess.Popen:
        """Start ``argv`` in this host, in a session of its own, logging to ``log_path``."""
        proc = processes.start_logged(['ip', 'netns', 'exec', self.name, *argv], log_path, env)
        self.lan.procs.append(proc)
        return proc

    def pids(self) -> List[int]:
        """Return the pids of the processes running in this host (``ip netns pids``)."""
        return [int(p) for p in _ip('netns', 'pids', self.name, check=False).stdout.split()]

    def link_down(self):
        """Cut this host off the network (its cable pulled)."""
        _ip('link', 'set', self.link, 'down')

    def link_up(self):
        """Plug this host back in."""
        _ip('link', 'set', self.link, 'up')

    def multicast(self, on: bool):
        """
        Let the bridge flood multicast to this host, or not (a switch that drops multicast).

        The bridge's port flag ``mcast_flood``, with the bridge's IGMP snooping off, is what
        decides; an interface's ``multicast off`` flag does not stop Fast DDS's discovery
        multicast here (measured: SUBNET nodes of two hosts still found each other).
        """
        _ip('link', 'set', 'dev', self.link, 'type', 'bridge_slave',
            'mcast_flood', 'on' if on else 'off')


class Lan:
    """
    ``n`` hosts on one bridge; a context manager that removes all of it on exit.

    ``prefix`` and ``subnet`` default to this process's (``pgn<pid>``); a LAN that outlives
    its process (``scripts/lan_hosts.py``, by hand) names its own and uses :meth:`build`
    and :meth:`remove`.
    """

    def __init__(self, n: int, prefix: Optional[str] = None, subnet: Optional[int] = None):
        self.prefix = prefix or f'pgn{os.getpid() % 100000}'
        self.subnet = subnet if subnet is not None else os.getpid() % 250 + 1
        self.bridge = f'{self.prefix}b'
        self.hosts = [Host(self, i) for i in range(n)]
        self.procs: List[subprocess.Popen] = []

    @classmethod
    def existing(cls, prefix: str, subnet: int) -> 'Lan':
        """Return the LAN of ``prefix`` as the namespaces on this machine are (maybe none)."""
        found = [n for n in _ip('netns', 'list').stdout.split()
                 if n.startswith(f'{prefix}h') and n[len(prefix) + 1:].isdigit()]
        return cls(max((int(n[len(prefix) + 1:]) + 1 for n in found), default=0), prefix,
                   subnet)

    def __enter__(self) -> 'Lan':
        return self.build()

    def build(self) -> 'Lan':
        """Make the bridge and the hosts (what a killed process of this prefix left first)."""
        self.remove()
        try:
            # no IGMP snooping: multicast is flooded to every port whose mcast_flood is on
            _ip('link', 'add', self.bridge, 'type', 'bridge', 'mcast_snooping', '0')
            _ip('link', 'set', self.bridge, 'up')
            for h in self.hosts:
                _ip('netns', 'add', h.name)
                _ip('link', 'add', h.link, 'type', 'veth', 'peer', 'name', h.inner)
                _ip('link', 'set', h.inner, 'netns', h.name)
                _ip('-n', h.name, 'addr', 'add', f'{h.address}/24', 'dev', h.inner)
                _ip('-n', h.name, 'link', 'set', h.inner, 'up')
                _ip('-n', h.name, 'link', 'set', 'lo', 'up')
                _ip('-n', h.name, 'route', 'add', '224.0.0.0/4', 'dev', h.inner)
                _ip('link', 'set', h.link, 'master', self.bridge, 'up')
        except subprocess.CalledProcessError as exc:
            self.remove()
            raise RuntimeError(f'could not build the virtual LAN: {exc.stderr.strip()}') from None
        return self

    def __exit__(self, *exc):
        with processes.shutting_down():
            for proc in self.procs:
                if proc.poll() is None:
                    processes.stop_logged(proc)
        self.remove()

    def remove(self):
        """Delete this LAN's namespaces (their veth ends go with them) and its bridge."""
        for h in self.hosts:
            _ip('netns', 'del', h.name, check=False)
            _ip('link', 'del', h.link, check=False)
        _ip('link', 'del', self.bridge, check=False)

    def leftovers(self) -> List[str]:
        """Return what of this LAN still exists (namespaces, links): empty after exit."""
        names = _ip('netns', 'list').stdout.split() + _ip('-o', 'link').stdout.split()
        return sorted({n.rstrip(':').split('@')[0] for n in names if self.prefix in n})
