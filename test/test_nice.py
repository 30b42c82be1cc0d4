"""The critic and the learner give way to the lock-step loop: ``nice`` and ``sched_idle``."""
import json
import os
from pathlib import Path
import subprocess
import sys
import time

from domains import ros_domain
from pg_node.tools.processes import child_env, REPO, stop

DOMAIN = ros_domain(base=140, spread=80)


def thread_nices(pid) -> dict:
    """Return ``{tid: niceness}`` of every thread of ``pid`` (field 19 of its stat)."""
    out = {}
    for task in Path(f'/proc/{pid}/task').iterdir():
        try:
            stat = (task / 'stat').read_text()
        except OSError:
            continue                       # the thread ended meanwhile
        out[int(task.name)] = int(stat.rsplit(')', 1)[1].split()[16])
    return out


def run_child(code: str):
    """Run ``code`` in a fresh Python (this folder importable); return its printed JSON."""
    env = child_env()
    env['PYTHONPATH'] += os.pathsep + str(Path(__file__).parent)
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_take_nice_renices_every_thread_and_never_lowers():
    """Threads started before and after take the niceness; a lower one later changes nothing."""
    code = (
        'import threading, json, os\n'
        'from pg_node.ros.runtime import take_nice\n'
        'from test_nice import thread_nices\n'
        'stop = threading.Event()\n'
        'before = threading.Thread(target=stop.wait); before.start()\n'
        'first = take_nice(6)\n'
        'after = threading.Thread(target=stop.wait); after.start()\n'
        'raised = thread_nices(os.getpid())\n'
        'second = take_nice(3)\n'
        'kept = thread_nices(os.getpid())\n'
        'stop.set()\n'
        'print(json.dumps([first, second, list(raised.values()), list(kept.values())]))\n')
    first, second, raised, kept = run_child(code)
    assert first is None and second is None
    # main, the thread started before, the one after, and whatever the imports started
    assert len(raised) >= 3 and set(raised) == {6}
    assert set(kept) == {6}


def thread_policies(pid) -> set:
    """Return the set of the scheduling policies of ``pid``'s threads."""
    out = set()
    for task in Path(f'/proc/{pid}/task').iterdir():
        try:
            out.add(os.sched_getscheduler(int(task.name)))
        except OSError:
            continue                       # the thread ended meanwhile
    return out


def test_take_idle_puts_every_thread_under_sched_idle():
    """Threads started before and after take SCHED_IDLE, the niceness stays as it was."""
    code = (
        'import threading, json, os\n'
        'from pg_node.ros.runtime import take_idle, take_nice\n'
        'from test_nice import thread_nices, thread_policies\n'
        'stop = threading.Event()\n'
        'before = threading.Thread(target=stop.wait); before.start()\n'
        'take_nice(4)\n'
        'refused = take_idle()\n'
        'after = threading.Thread(target=stop.wait); after.start()\n'
        'policies = sorted(thread_policies(os.getpid()))\n'
        'nices = sorted(set(thread_nices(os.getpid()).values()))\n'
        'count = len(thread_nices(os.getpid()))\n'
        'stop.set()\n'
        'print(json.dumps([refused, policies, nices, count]))\n')
    refused, policies, nices, count = run_child(code)
    assert refused is None and count >= 3
    assert policies == [os.SCHED_IDLE] and nices == [4]


def node_nices(node: str, run_dir: Path, ros_args=(), policies=None) -> set:
    """
    Start ``node``; return the set of its threads' niceness once it has reniced itself.

    ``policies``, a list, gets the set of its threads' scheduling policies at that time.
    """
    proc = subprocess.Popen(
        [sys.executable, '-m', f'pg_node.ros.{node}', '--ros-args',
         '-p', f'run_dir:={run_dir}',
         *ros_args],
        env=child_env(DOMAIN), cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True, start_new_session=True)
    # the niceness the node starts with: this process's (``nice -n 3 make test`` gives 3)
    start = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        deadline = time.monotonic() + 90
        nices = {}
        while time.monotonic() < deadline and proc.poll() is None:
            nices = thread_nices(proc.pid)
            # the node renices after it is built: wait for the main thread to change, then
            # give the rest of the threads a moment
            if nices.get(proc.pid, start) != start:
                time.sleep(0.5)
                if policies is not None:
                    policies.append(thread_policies(proc.pid))
                return set(thread_nices(proc.pid).values())
            time.sleep(0.2)
        raise AssertionError(f'{node} kept niceness {nices} (exit {proc.poll()}): '
                             f'{proc.stderr.read() if proc.poll() is not None else ""}')
    finally:
        assert stop(proc) == 0


def test_learner_and_critic_run_nice_by_default_and_take_the_parameter(tmp_path):
    """Every thread of the learner (default 10) and the critic (-p nice:=7) is reniced."""
    assert node_nices('learner_node', tmp_path / 'learner') == {10}
    assert node_nices('critic_node', tmp_path / 'critic', ['-p', 'nice:=7']) == {7}


def test_learner_and_critic_run_under_sched_idle_in_sync_mode_unless_told_not_to(tmp_path):
    """The default (sync): every thread SCHED_IDLE; sched_idle:=false or async: normal."""
    for args, want in (((), os.SCHED_IDLE),
                       (('-p', 'sched_idle:=false'), os.SCHED_OTHER),
                       (('-p', 'sync_mode:=async'), os.SCHED_OTHER)):
        policies = []
        assert node_nices('critic_node', tmp_path / 'critic', args, policies) == {10}
        assert policies == [{want}], args
    policies = []
    node_nices('critic_and_learner', tmp_path / 'both', (), policies)
    assert policies == [{os.SCHED_IDLE}]
