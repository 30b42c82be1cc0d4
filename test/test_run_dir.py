"""A run directory's layout, and its files written and read back through ``RunDir``."""
import json
import math

from pg_node.common.run_dir import (last_progress, progress_rows, read_progress, RunDir,
                                    strict_json)
import pytest

FIELDS = ('wall_seconds', 'env_steps', 'episode_return', 'policy_version')


def test_the_layout_names_every_file_of_a_run(tmp_path):
    run = RunDir(tmp_path / 'r')
    assert not run.path.exists()                    # naming creates nothing
    assert run.make() is run and run.path.is_dir()
    assert {name: getattr(run, name).relative_to(run.path).as_posix() for name in (
        'params', 'progress', 'checkpoints', 'summary', 'logs', 'tensorboard', 'curve')} == {
        'params': 'params.yaml', 'progress': 'progress.csv', 'checkpoints': 'checkpoints',
        'summary': 'summary.json', 'logs': 'logs', 'tensorboard': 'tensorboard',
        'curve': 'learning_curve.png'}
    assert run.log('sim_and_actor') == run.path / 'logs' / 'sim_and_actor.log'


def test_the_next_bag_is_the_first_free_one_and_bags_read_in_that_order(tmp_path):
    run = RunDir(tmp_path)
    assert run.next_bag() == tmp_path / 'bag' and run.bags() == [] and not run.has_bag()
    names = []
    for _ in range(12):                 # bag_10 and bag_11 sort after bag_9, not after bag_1
        names.append(run.next_bag().name)
        run.next_bag().mkdir()
    assert names == ['bag'] + [f'bag_{k}' for k in range(1, 12)]
    assert run.has_bag()
    for other in ('bags', 'bag_', 'bag_x', 'bag_1_2'):
        (tmp_path / other).mkdir()
    (tmp_path / 'bag_12').write_text('a file, not a bag')
    assert [b.name for b in run.bags()] == names
    # a name that anything holds is not free
    assert run.next_bag().name == 'bag_13'


def test_the_writers_rows_read_back_with_nan_as_empty_cells(tmp_path):
    run = RunDir(tmp_path)
    writer = run.progress_writer(FIELDS)
    writer.write(1.23456, {'env_steps': 512.0, 'episode_return': float('nan'),
                           'policy_version': 1.0})
    writer.write(2.5, {'env_steps': 1024.0, 'episode_return': -3.5, 'policy_version': 2.0})
    writer.close()
    # the learner's format, byte for byte: csv's own line ends, ms, NaN as nothing
    assert run.progress.read_bytes() == (b'wall_seconds,env_steps,episode_return,'
                                         b'policy_version\r\n1.235,512.0,,1.0\r\n'
                                         b'2.5,1024.0,-3.5,2.0\r\n')
    rows = run.read_progress()
    assert [r['env_steps'] for r in rows] == [512.0, 1024.0]
    assert math.isnan(rows[0]['episode_return']) and rows[1]['episode_return'] == -3.5
    assert run.last_progress() == rows[-1] == last_progress(run.progress)
    # a second session appends without a second header, and reads from its own offset
    size = run.progress.stat().st_size
    writer = run.progress_writer(FIELDS)
    writer.write(3.0, {'env_steps': 1536.0, 'episode_return': -2.0, 'policy_version': 3.0})
    writer.flush()
    assert [r['env_steps'] for r in run.read_progress(since=size)] == [1536.0]
    assert len(run.read_progress()) == 3
    writer.close()


def test_a_torn_last_line_is_no_row_for_any_reader(tmp_path):
    run = RunDir(tmp_path)
    run.progress.write_bytes(b'wall_seconds,env_steps\r\n1.0,512.0\r\n2.0,10')
    assert [r['env_steps'] for r in run.read_progress()] == [512.0]
    assert run.last_progress() == {'wall_seconds': 1.0, 'env_steps': 512.0}
    assert progress_rows(['wall_seconds,env_steps\n', '1.0,5']) == []
    with open(run.progress, 'ab') as f:
        f.write(b'24.0\r\n')
    assert run.last_progress() == {'wall_seconds': 2.0, 'env_steps': 1024.0}


def test_no_progress_file_reads_as_no_rows(tmp_path):
    run = RunDir(tmp_path / 'missing')
    assert run.read_progress() == [] and read_progress(run.progress, since=10) == []
    assert run.last_progress() is None


def test_the_summary_is_strict_json_and_reads_back(tmp_path):
    run = RunDir(tmp_path)
    assert run.read_summary() is None
    summary = {'steps_per_second': float('nan'), 'curve': [{'r': float('inf')}, {'r': -1.5}],
               'bags': ('bag', 'bag_1'), 'path': tmp_path}
    run.write_summary(summary)
    text = run.summary.read_text()
    assert 'NaN' not in text and 'Infinity' not in text
    json.loads(text, parse_constant=pytest.fail)     # strict: no constant JSON lacks
    assert run.read_summary() == {'steps_per_second': None, 'curve': [{'r': None}, {'r': -1.5}],
                                  'bags': ['bag', 'bag_1'], 'path': str(tmp_path)}
    assert strict_json({'a': [float('-inf'), 2]}) == {'a': [None, 2]}


def test_checkpoints_are_seen_by_their_file_names(tmp_path):
    run = RunDir(tmp_path)
    assert not run.has_checkpoint()
    run.checkpoints.mkdir()
    (run.checkpoints / '.ckpt_abc.tmp').write_text('')  # a save in progress
    assert not run.has_checkpoint()
    (run.checkpoints / 'ckpt_00000007.pt').write_text('')
    assert run.has_checkpoint()


@pytest.mark.parametrize('inside', ['', 'checkpoints', 'checkpoints/ckpt_00000007.pt'])
def test_a_checkpoint_names_its_run(tmp_path, inside):
    run = RunDir(tmp_path / 'exp1')
    assert RunDir.of_checkpoint(run.path / inside).path == run.path.resolve()


def test_the_checkpoints_the_learner_writes_are_the_ones_the_run_sees(tmp_path):
    from pg_node.rl.checkpoint import checkpoint_path, list_checkpoints
    run = RunDir(tmp_path)
    run.checkpoints.mkdir()
    checkpoint_path(run.checkpoints, 7).write_text('')
    assert run.has_checkpoint()
    assert list_checkpoints(run.checkpoints) == [(run.checkpoints / 'ckpt_00000007.pt', 7)]
