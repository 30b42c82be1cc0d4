"""
Benchmark: CPU of every thread of the running pg_node nodes over a window.

Start a training (``python -m pg_node train ...``) and, while it runs::

    python bench/thread_cpu.py 15

Reads ``/proc/<pid>/task/<tid>/stat`` (user + system time) of every process whose command
line names a ``pg_node.ros.<node>`` module, twice, ``SECONDS`` apart, and prints each node's
threads as a share of one core, grouped by thread name (``python main`` is the node's
main thread, ``python`` its other Python threads such as the simulator's stepping thread,
``dds.*`` Fast DDS's own). Linux only. Not a test: nothing is asserted.
"""
import collections
import os
import re
import sys
import time

NODE = re.compile(r'pg_node\.ros\.(\w+)')


def nodes() -> dict:
    """Return ``{pid: node name}`` of the running pg_node nodes."""
    out = {}
    for pid in filter(str.isdigit, os.listdir('/proc')):
        try:
            with open(f'/proc/{pid}/cmdline') as f:
                m = NODE.search(f.read().replace('\0', ' '))
        except OSError:
            continue
        if m:
            out[pid] = m.group(1)
    return out


def cpu_seconds(pids: dict) -> dict:
    """Return ``{(node, thread label): CPU seconds so far}`` summed over like threads."""
    tick = os.sysconf('SC_CLK_TCK')
    out = collections.Counter()
    for pid, node in pids.items():
        try:
            tids = os.listdir(f'/proc/{pid}/task')
        except OSError:
            continue
        for tid in tids:
            try:
                with open(f'/proc/{pid}/task/{tid}/stat') as f:
                    stat = f.read()
                with open(f'/proc/{pid}/task/{tid}/comm') as f:
                    comm = f.read().strip()
            except OSError:
                continue
            fields = stat[stat.rindex(')') + 2:].split()
            label = re.sub(r'\d+', '#', comm) + (' main' if tid == pid else '')
            out[(node, label)] += (int(fields[11]) + int(fields[12])) / tick
    return out


def main(argv=None) -> int:
    """Sample twice and print the shares."""
    argv = sys.argv[1:] if argv is None else argv
    try:
        seconds = float(argv[0]) if argv else 15.0
    except ValueError:
        print(f'usage: python bench/thread_cpu.py [SECONDS], not {argv[0]!r}', file=sys.stderr)
        return 2
    pids = nodes()
    if not pids:
        print('no pg_node node is running: start a training first', file=sys.stderr)
        return 1
    before, t0 = cpu_seconds(pids), time.monotonic()
    time.sleep(seconds)
    after, elapsed = cpu_seconds(pids), time.monotonic() - t0
    print(f'{"node":14s} {"threads":20s} share of one core over {elapsed:.1f} s')
    for key in sorted(after):
        share = (after[key] - before.get(key, 0.0)) / elapsed
        if share >= 0.001:
            print(f'{key[0]:14s} {key[1]:20s} {100 * share:6.1f}%')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
