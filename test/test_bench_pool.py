"""
``python -m bench --jobs``: runs in worker processes, the same numbers, Ctrl-C.

Nothing here times anything: it checks where runs went, that pg_node's evaluations do not
depend on running beside another, and that an interrupted bench keeps what finished.
"""
import json
import operator
import os
from pathlib import Path
import signal
import subprocess
import sys
import time
import uuid

from bench.pool import guarded, run_all
import pytest

REPO = Path(__file__).resolve().parent.parent


def collect(tasks, jobs):
    got, order = {}, []
    run_all(tasks, jobs, lambda i, res: got.__setitem__(i, res), order.append)
    return got, order


def test_sequential_runs_here_in_order_and_announces_each():
    got, order = collect([(os.getpid, ()), (operator.mul, (6, 7))], jobs=1)
    assert got == {0: os.getpid(), 1: 42} and order == [0, 1]


def test_jobs_run_in_other_processes_and_keep_each_result_with_its_task():
    tasks = [(os.getpid, ())] * 2 + [(operator.mul, (k, 10)) for k in (1, 2)]
    got, order = collect(tasks, jobs=2)
    assert order == []          # with workers, when a task starts is not seen
    assert sorted(got) == list(range(4))
    pids = {got[i] for i in range(2)}
    assert os.getpid() not in pids and len(pids) == 2   # a fresh process per task
    assert [got[2], got[3]] == [10, 20]


def test_a_failing_task_becomes_its_error_and_the_others_finish():
    got, _ = collect([(operator.truediv, (1, 0)), (operator.add, (1, 2))], jobs=2)
    assert got == {0: {'error': 'division by zero'}, 1: 3}
    assert guarded(int, ('x',)) == {'error': "invalid literal for int() with base 10: 'x'"}


def bench_env(mark):
    return dict(os.environ, PYTHONPATH=str(REPO), PGN_TEST_MARK=mark)


def processes_marked(mark):
    """Return the pids of live processes whose environment holds ``mark``."""
    found = []
    for proc in Path('/proc').iterdir():
        try:
            if proc.name.isdigit() and f'PGN_TEST_MARK={mark}'.encode() in (
                    proc / 'environ').read_bytes():
                found.append(int(proc.name))
        except OSError:
            pass
    return found


@pytest.mark.slow
def test_learning_runs_two_at_a_time_evaluate_as_one_alone(tmp_path):
    from bench.runs import inprocess_learning
    cmd = [sys.executable, '-m', 'bench', '--quick', '--only', 'learning',
           '--jobs', '2', '--learners', 'pg_node_inprocess:2', '--learning-steps', '2048',
           '--out', str(tmp_path)]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO,
                         env=bench_env(uuid.uuid4().hex), timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    learning = json.loads((tmp_path / 'bench_results.json').read_text())['learning']
    runs = learning['runs']['pg_node_inprocess']
    assert learning['jobs'] == 2 and [r['seed'] for r in runs] == [0, 1]
    alone = inprocess_learning(2048, 1, learning['points'], learning['eval_episodes'])
    assert {int(p): v for p, v in runs[1]['evals'].items()} == alone['evals']
    assert '**2 runs other than the graph' in (tmp_path / 'BENCHMARKS.md').read_text()


@pytest.mark.slow
def test_ctrl_c_keeps_the_finished_runs_in_one_line_and_leaves_no_worker(tmp_path):
    mark = uuid.uuid4().hex
    cmd = [sys.executable, '-m', 'bench', '--quick', '--only', 'curves',
           '--jobs', '2', '--out', str(tmp_path)]
    # as from a terminal, whatever this test run inherited: the workers must not see the
    # group's SIGINT through an inherited SIG_IGN but by ignoring it themselves
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            cwd=REPO, env=bench_env(mark), start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    try:
        for line in proc.stderr:
            lines.append(line)
            if sum('seed 0: ' in x for x in lines) >= 2:     # two runs have finished
                break
        os.killpg(proc.pid, signal.SIGINT)   # a terminal's Ctrl-C reaches the whole group
        rest = proc.stderr.read()
        rc = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)     # the bench and its workers
            proc.wait()
    assert rc == 130, ''.join(lines) + rest
    assert 'Traceback' not in rest and 'KeyboardInterrupt' not in rest, rest
    assert [x for x in rest.splitlines() if x.startswith('bench: interrupted')], rest
    data = json.loads((tmp_path / 'bench_results.json').read_text())
    assert data.get('interrupted') and not data.get('complete')
    finished = [r for runs in data['curves']['runs'].values() for r in runs]
    assert 2 <= len(finished) < 13 and all('evals' in r for r in finished)
    assert '**Incomplete' in (tmp_path / 'BENCHMARKS.md').read_text()
    deadline = time.monotonic() + 10
    while processes_marked(mark) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert processes_marked(mark) == []
