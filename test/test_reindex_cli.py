"""``python -m pg_node reindex``: a run's bags made whole from the command line."""
from pathlib import Path
import subprocess
import sys

from pg_node.bag.writer import BagWriter
import pytest
from rosbags.rosbag2 import Reader
from std_msgs.msg import Float64MultiArray

REPO = Path(__file__).resolve().parent.parent


def write_bag(directory, n=400):
    """Write ``n`` messages in small chunks; return the bag's directory."""
    with BagWriter(directory, chunk_size=2048, compression='none') as w:
        w.add_topic('/numbers', Float64MultiArray)
        for i in range(n):
            w.write('/numbers', Float64MultiArray(data=[float(i)] * 8), 1_000_000 * (i + 1))
    return directory


def run(*args):
    return subprocess.run([sys.executable, '-m', 'pg_node', 'reindex', *map(str, args)],
                          cwd=REPO, capture_output=True, text=True, timeout=120)


def test_reindex_makes_a_killed_learners_bag_whole_and_leaves_a_whole_one(tmp_path):
    run_dir = tmp_path / 'run'
    whole, cut = write_bag(run_dir / 'bag'), write_bag(run_dir / 'bag_1')
    (mcap,) = cut.glob('*.mcap')
    with open(mcap, 'r+b') as f:                    # as SIGKILL leaves it: no summary
        f.truncate(mcap.stat().st_size * 2 // 3)
    original = mcap.read_bytes()
    with pytest.raises(Exception):
        with Reader(cut) as reader:
            list(reader.messages())
    res = run(run_dir)
    assert res.returncode == 0, res.stderr
    assert f'{whole}: 1 file(s), 400 messages, already whole' in res.stdout
    assert f'{cut}: rewrote' in res.stdout and 'repaired' in res.stdout
    with Reader(cut) as reader:
        n = sum(1 for _ in reader.messages())
        assert 0 < n == reader.message_count < 400   # what was before the cut
    assert not res.stderr
    # the user's bytes are never discarded: the damaged original is kept beside the repair
    kept = mcap.with_name(mcap.name + '.damaged')
    assert kept.read_bytes() == original
    assert f'{cut}: the damaged original is kept as {kept}' in res.stdout


def test_reindex_says_nothing_recoverable_and_leaves_the_file_and_metadata(tmp_path):
    """Random bytes named .mcap: they were replaced by an empty MCAP, 'repaired', exit 0."""
    bag = write_bag(tmp_path / 'bag')
    (mcap,) = bag.glob('*.mcap')
    noise = bytes(range(256)) * 20
    mcap.write_bytes(noise)
    metadata = (bag / 'metadata.yaml').read_bytes()
    res = run(bag)
    assert res.returncode == 1, res.stdout
    assert res.stderr.strip() == (f'reindex: {mcap}: nothing recoverable (not an MCAP file '
                                  '(bad magic)); left as it is'), res.stderr
    assert 'repaired' not in res.stdout
    assert mcap.read_bytes() == noise and (bag / 'metadata.yaml').read_bytes() == metadata
    assert sorted(p.name for p in bag.iterdir()) == sorted(['metadata.yaml', mcap.name])


def test_reindex_discard_damaged_keeps_only_the_repair(tmp_path):
    bag = write_bag(tmp_path / 'bag')
    (mcap,) = bag.glob('*.mcap')
    with open(mcap, 'r+b') as f:
        f.truncate(mcap.stat().st_size // 2)
    res = run(bag, '--discard-damaged')
    assert res.returncode == 0 and 'repaired' in res.stdout, res.stderr
    assert sorted(p.name for p in bag.iterdir()) == sorted(['metadata.yaml', mcap.name])


def test_reindex_refuses_what_is_not_a_bag_in_one_line(tmp_path):
    res = run(tmp_path / 'nonexistent')
    assert res.returncode == 1 and res.stderr.strip().count('\n') == 0
    assert 'is not a directory' in res.stderr and 'Traceback' not in res.stderr
    (tmp_path / 'empty').mkdir()
    res = run(tmp_path / 'empty')
    assert res.returncode == 1 and 'no bag in' in res.stderr and 'Traceback' not in res.stderr
