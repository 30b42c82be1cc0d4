"""
``replay --info`` tells a damaged bag from a whole one; ``replay`` exits as the doc says.

The exit codes are the ones docs/troubleshooting.md lists. Before: ``--info`` printed
metadata.yaml's counts and exited 0 for a bag whose file was cut in half, counted a file
``reindex`` had left out of the metadata, and named only ``bag/`` of a resumed run.
"""
from pathlib import Path
import re
import shutil

from pg_node.bag.writer import reindex
from pg_node.ros.replay_node import EXIT_DAMAGED, EXIT_NOTHING, EXIT_OK, EXIT_USAGE, main
from test_reindex_cli import write_bag

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / 'bags' / 'sample'


def cut_bag(directory):
    """Write a bag, then cut its file as SIGKILL leaves it; return the file."""
    (mcap,) = write_bag(directory).glob('*.mcap')
    with open(mcap, 'r+b') as f:
        f.truncate(mcap.stat().st_size * 2 // 3)
    return mcap


def count(out):
    return int(re.search(r'/numbers\s+\S+\s+(\d+)', out).group(1))


def test_info_names_a_damaged_file_and_counts_what_reindex_kept(tmp_path, capsys):
    bag = tmp_path / 'cut'
    mcap = cut_bag(bag)
    assert main(['--info', str(bag)]) == EXIT_DAMAGED == 3
    out = capsys.readouterr().out
    assert f'damaged: {mcap}: stopped at byte ' in out and 'truncated record' in out
    assert count(out) == 400      # what metadata.yaml says, and the line says so
    assert 'what metadata.yaml says' in out and f'pg_node reindex {bag}' in out
    reindex(bag)
    assert main(['--info', str(bag)]) == EXIT_OK
    out = capsys.readouterr().out
    assert 'damaged: ' not in out and 'files: 1' in out
    assert 0 < count(out) < 400


def test_info_after_reindex_counts_the_files_the_metadata_lists(tmp_path, capsys):
    bag = write_bag(tmp_path / 'bag')
    junk = bag / 'bag_1.mcap'
    junk.write_bytes(bytes(range(256)) * 20)
    report = reindex(bag)
    assert [name for name, _ in report.unrecoverable] == [junk.name]   # left beside the bag
    assert main(['--info', str(bag)]) == EXIT_OK
    out = capsys.readouterr().out
    assert 'files: 1' in out and count(out) == 400
    assert f'not read: {junk} (not listed in metadata.yaml, not an MCAP file)' in out


def test_info_of_a_resumed_run_names_each_bag(tmp_path, capsys):
    run = tmp_path / 'run'
    for name in ('bag', 'bag_1'):
        shutil.copytree(SAMPLE, run / name)
    assert main(['--info', str(run)]) == EXIT_OK
    out = capsys.readouterr().out
    assert [ln.split()[1] for ln in out.splitlines() if ln.startswith('bag: ')] == [
        str(run / 'bag'), str(run / 'bag_1')]


def exit_codes_of_the_doc():
    """Return {code: text} of the table 'exit code of `replay`' in troubleshooting.md."""
    text = (REPO / 'docs' / 'troubleshooting.md').read_text()
    table = text.split('| exit code of `replay` | when |', 1)[1].split('\n\n', 1)[0]
    rows = re.finditer(r'^\| (\d) \| (.*) \|$', table, re.M)
    return {int(m.group(1)): m.group(2) for m in rows}


def test_exit_codes_are_the_ones_the_doc_lists(tmp_path, capsys):
    doc = exit_codes_of_the_doc()
    assert sorted(doc) == [EXIT_OK, EXIT_NOTHING, EXIT_USAGE, EXIT_DAMAGED] == [0, 1, 2, 3]
    cut_bag(tmp_path / 'cut')
    seen = {main(['--info', str(SAMPLE)]): 'played to its end',
            main(['--info', str(tmp_path / 'nothing-here')]): 'no bag there',
            main([str(SAMPLE), '--rate', '-1']): 'a bad option',
            main(['--info']): 'a bad option',
            main(['--info', str(tmp_path / 'cut')]): 'a file is damaged'}
    capsys.readouterr()
    assert len(seen) == 4, seen
    for code, words in seen.items():
        assert words in doc[code], (code, doc[code])
