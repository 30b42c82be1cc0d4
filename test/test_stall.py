"""
A run that learns nothing says why and stops (``train``'s stall watch, issue 56).

An arm imported with an unstable recipe showed ``starting nodes...`` for 11 minutes: the
cause was only in a node's log. The watch names the cause on the progress line and stops the
run in bounded time, with one line.
"""
from pathlib import Path
from types import SimpleNamespace

from pg_node.common.run_dir import RunDir
from pg_node.tools.progress_view import ProgressView, supervise
from pg_node.tools.stall import idle_processes, last_complaint, stall_cause, StallWatch

WARN = ('[WARN] [1796665690.789329071] [run.actor_node]: dropped a transition: field '
        "'obs' holds absurd values (|x| > 1e+06)\n")


def test_the_watch_counts_from_the_newest_step_and_never_stops_at_zero():
    w = StallWatch(notice=5.0, stop=0.0, now=0.0)
    assert [w.update(t, None) for t in (4.0, 6.0, 1e6)] == ['ok', 'notice', 'notice']
    w = StallWatch(notice=5.0, stop=10.0, now=0.0)
    assert w.update(9.0, 64) == 'ok' and w.update(18.0, 64) == 'notice'
    assert w.update(19.0, 64) == 'stop' and w.quiet(19.0) == 10.0


def test_the_newest_complaint_since_the_mark_is_named_with_its_log(tmp_path):
    old, new = tmp_path / 'sim_and_actor.log', tmp_path / 'critic_and_learner.log'
    old.write_text('[WARN] [1.0] [run.sim_node]: before the stall\n')
    new.write_text('[INFO] [2.0] [run.learner_node]: learner: a2c\n')
    marks = {'sim_and_actor': old.stat().st_size, 'critic_and_learner': 0}
    logs = {'sim_and_actor': old, 'critic_and_learner': new}
    assert last_complaint(logs, marks) is None          # an INFO, and a WARN from before
    with open(old, 'a') as f:
        f.write(WARN)
    assert last_complaint(logs, marks) == (
        "sim_and_actor.log: [run.actor_node] dropped a transition: field 'obs' holds absurd "
        'values (|x| > 1e+06)')


def test_the_cause_puts_a_restart_first_then_idle_nodes_then_the_warning():
    assert stall_cause(['critic_and_learner'], ['sim_and_actor'], 'x') == \
        'critic_and_learner waiting to be restarted'
    assert stall_cause([], [], None) == 'the nodes run, and their logs say nothing new'
    assert idle_processes({'a': 3.0, 'b': 9.0}, {'a': 3.0, 'b': 2.0}, ['a', 'b']) == ['a']


class StuckSupervisor:
    """Nodes that run and learn nothing: a simulator stopped, the actor complaining."""

    def __init__(self, run_dir: Path):
        self.run = RunDir(run_dir)
        self.run.logs.mkdir(parents=True)
        self.commands = {'sim_and_actor': [], 'critic_and_learner': []}
        self.procs = dict.fromkeys(self.commands, SimpleNamespace())
        self.next_start, self.failed, self.cpu_at_first_update = {}, None, None
        self.cpu = {'sim_and_actor': 1.0, 'critic_and_learner': 1.0}

    def start_all(self):
        self.run.log('sim_and_actor').write_text('[INFO] [1.0] [run.sim_node]: started\n')

    def check(self):
        self.cpu['critic_and_learner'] += 0.1          # the learner waits, spinning
        with open(self.run.log('sim_and_actor'), 'a') as f:
            f.write(WARN)
        return 'running'

    def cpu_seconds(self):
        return dict(self.cpu)


def test_a_run_that_learns_nothing_stops_with_one_line_that_names_the_cause(tmp_path):
    sup = StuckSupervisor(tmp_path / 'run')
    view = ProgressView(sup.run.progress, 1000, None, bar=False)
    state = supervise(sup, view, stall_timeout=1.0, notice=0.2, period=0.05)
    assert state == 'stalled'
    assert sup.failed.startswith('no step learned for 1 s: sim_and_actor used no CPU since '
                                 'then (stopped, or blocked?); the newest warning: '
                                 'sim_and_actor.log: [run.actor_node] dropped a transition')
    assert sup.failed.endswith(f'(logs in {sup.run.logs}; --stall-timeout S waits longer, '
                               '0 never stops)')
