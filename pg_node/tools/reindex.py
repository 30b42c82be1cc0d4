"""
``python -m pg_node reindex BAG|RUN ...``: make bags whole, as ``ros2 bag reindex`` does.

A learner killed with SIGKILL (or by the OOM killer) leaves its last MCAP file without its
summary and footer; third-party readers (rosbags, ``ros2 bag info``) refuse such a bag.
Reindexing rewrites each damaged file with everything before the damage (the original is
kept beside it as ``<name>.damaged``), and ``metadata.yaml`` from what the files hold.
Complete files are left as they are; a file that is no MCAP at all is left too, and said to
hold nothing recoverable (exit code 1). A run
directory stands for all its bags (``bag``, ``bag_1``, ...). ``python -m pg_node train``
does this by itself for the bag of a learner that died during the run.
"""
import argparse
from pathlib import Path
import sys


def bags_of(path: Path) -> list:
    """Return the bags ``path`` names: itself (a bag directory) or a run directory's bags."""
    from pg_node.common.run_dir import RunDir
    if (path / 'metadata.yaml').is_file() or any(path.glob('*.mcap')):
        return [path]
    return RunDir(path).bags()


def main(argv=None) -> int:
    """Run ``python -m pg_node reindex``."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node reindex',
        description='Make bags whole after their writer was killed (ros2 bag reindex).')
    parser.add_argument('paths', nargs='+', type=Path, metavar='BAG|RUN',
                        help='a bag directory, or a run directory (all its bags)')
    parser.add_argument('--discard-damaged', action='store_true',
                        help='do not keep each damaged original as <name>.damaged beside its '
                             'repair (kept by default)')
    args = parser.parse_args(argv)
    from pg_node.bag.writer import reindex
    code = 0
    for path in args.paths:
        if not path.is_dir():
            print(f'reindex: {path} is not a directory', file=sys.stderr)
            code = 1
            continue
        bags = bags_of(path)
        if not bags:
            print(f'reindex: no bag in {path} (no .mcap file, no bag/ directory)',
                  file=sys.stderr)
            code = 1
        for bag in bags:
            report = reindex(bag, keep_damaged=not args.discard_damaged)
            for name, damage in report.repaired:
                print(f'{bag}: rewrote {name} up to its damage ({damage.reason}, byte '
                      f'{damage.offset})')
            for name in report.kept:
                print(f'{bag}: the damaged original is kept as {bag / name}')
            for name, damage in report.unrecoverable:
                listed = ', not listed in metadata.yaml' if report.files else ''
                print(f'reindex: {bag / name}: nothing recoverable ({damage.reason}); left as '
                      f'it is{listed}', file=sys.stderr)
                code = 1
            if report.files:
                print(f'{bag}: {len(report.files)} file(s), {report.message_count} messages, '
                      f'{"repaired" if report.repaired else "already whole"}')
    return code
