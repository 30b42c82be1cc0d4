"""
Measure bag write (and read) throughput for JointState messages of many arms.

Run from the repository root:

    AMENT_PREFIX_PATH=$PWD/.venv PYTHONPATH=$PWD .venv/bin/python bench/bench_bag.py

Prints one row per configuration: messages per second and MB/s of serialised message data
(CDR payload), and the size of the bag on disk. ``serialize only`` is rclpy's
``serialize_message`` alone; ``bytes in`` rows write pre-serialised CDR, so they show the
writer's own cost. Each row is the best of ``--repeat`` runs (the runs of one row come one
after another), which on a shared machine varies far less than a single run.

``--rows zstd`` keeps the rows whose name holds ``zstd`` (what BENCHMARKS.md's
``/tmp/wz.py`` repeated); ``--profile`` prints a cProfile of the writer alone with zstd
(pre-serialised CDR in: what ``/tmp/prof_bag.py`` showed) instead of the table.
"""
import argparse
from pathlib import Path
import shutil
import tempfile
import time

import numpy as np

from pg_node.bag.reader import BagReader
from pg_node.bag.writer import BagWriter
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState


def joint_state(n_arms, joints_per_arm, k, rng):
    """Return a JointState for n_arms arms, all arrays filled with random values."""
    n = n_arms * joints_per_arm
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 10_000_000, 10**9)
    msg.name = [f'arm{a:02d}/joint{j}' for a in range(n_arms) for j in range(joints_per_arm)]
    msg.position = rng.uniform(-3.14, 3.14, n).tolist()
    msg.velocity = rng.normal(0.0, 2.0, n).tolist()
    msg.effort = rng.uniform(-1.0, 1.0, n).tolist()
    return msg


def best_time(repeat, fn):
    """Return the shortest wall time of ``repeat`` calls of ``fn``."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def run(args):
    """Run every configuration and print the table."""
    rng = np.random.default_rng(0)
    # 256 distinct messages, more than a chunk holds, so compression sees no repeats
    msgs = [joint_state(args.arms, args.joints, k, rng) for k in range(256)]
    payload = [serialize_message(m) for m in msgs]
    size = sum(map(len, payload)) / len(payload)
    n = args.messages
    rows = []

    def serialize_all():
        for k in range(n):
            serialize_message(msgs[k % 256])

    def wanted(name):
        return args.rows is None or args.rows in name

    if wanted('serialize only') and not args.profile:
        dt = best_time(args.repeat, serialize_all)
        rows.append(('serialize only', '-', n / dt, n * size / dt / 1e6, '-'))

    tmp = Path(tempfile.mkdtemp(prefix='bench_bag_'))

    def write(bag, compression, raw):
        if bag.exists():
            shutil.rmtree(bag)
        with BagWriter(bag, compression=compression,
                       split_max_bytes=args.split_mb * 10**6) as w:
            w.add_topic('/joint_states', JointState)
            for k in range(n):
                data = payload[k % 256] if raw else msgs[k % 256]
                w.write('/joint_states', data, 1_000_000_000 + k * 10_000_000)

    def read(bag, deserialize):
        count = sum(1 for _ in BagReader(bag).messages(deserialize=deserialize))
        assert count == n

    try:
        if args.profile:
            import cProfile
            import pstats
            prof = cProfile.Profile()
            prof.runcall(write, tmp / 'profile', 'zstd', True)
            pstats.Stats(prof).sort_stats('cumulative').print_stats(25)
            return
        for compression in ('none', 'zstd', 'lz4'):
            for raw in (False, True):
                bag = tmp / f'{compression}_{int(raw)}'
                if not wanted(('bytes in, ' if raw else 'write, ') + compression):
                    continue
                dt = best_time(args.repeat, lambda: write(bag, compression, raw))
                disk = sum(p.stat().st_size for p in bag.glob('*.mcap')) / 1e6
                rows.append((('bytes in, ' if raw else 'write, ') + compression,
                             len(list(bag.glob('*.mcap'))), n / dt, n * size / dt / 1e6,
                             f'{disk:.1f}'))
        for deserialize in (False, True):
            name = 'read zstd' + (' + deserialize' if deserialize else ' raw')
            if not wanted(name):
                continue
            if not (tmp / 'zstd_0').exists():
                write(tmp / 'zstd_0', 'zstd', False)
            dt = best_time(args.repeat, lambda: read(tmp / 'zstd_0', deserialize))
            rows.append((name, '-', n / dt, n * size / dt / 1e6, '-'))
    finally:
        shutil.rmtree(tmp)

    print(f'JointState of {args.arms} arms x {args.joints} joints: {size:.0f} bytes CDR, '
          f'{n} messages, default chunk size, split every {args.split_mb} MB, '
          f'best of {args.repeat}')
    print(f'| {"configuration":<26} | files | {"msg/s":>9} | {"MB/s":>7} | {"bag MB":>7} |')
    print(f'|{"-" * 28}|-------|{"-" * 11}|{"-" * 9}|{"-" * 9}|')
    for name, files, rate, mbs, disk in rows:
        print(f'| {name:<26} | {files!s:>5} | {rate:>9.0f} | {mbs:>7.1f} | {disk:>7} |')


def main():
    """Parse the options and run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--arms', type=int, default=64)
    parser.add_argument('--joints', type=int, default=2, help='joints per arm')
    parser.add_argument('--messages', type=int, default=20000)
    parser.add_argument('--split-mb', type=int, default=64)
    parser.add_argument('--repeat', type=int, default=3, help='runs per row, best kept')
    parser.add_argument('--rows', help='only the rows whose name holds this text (e.g. zstd)')
    parser.add_argument('--profile', action='store_true',
                        help='print a cProfile of the zstd writer (pre-serialised) instead')
    run(parser.parse_args())


if __name__ == '__main__':
    main()
