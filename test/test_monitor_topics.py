"""
monitor and topics: the view's content from known messages, headless runs over DDS.

The e2e tests publish metrics, episode summaries and diagnostics from the test process at
known rates, and run ``python -m pg_node monitor --once`` and ``python -m pg_node topics
--json`` as processes in the same (test-only) DDS domain.
"""
import json
import os
from pathlib import Path
import subprocess
import sys
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from domains import ros_domain, ros_domains
from pg_node.common.run import run_topic
from pg_node.tools.monitor import MonitorState, sparkline
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rich.console import Console
from std_msgs.msg import Float64

REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID = ros_domain(base=110, spread=100)


def text_of(renderable) -> str:
    console = Console(record=True, width=160, file=open(os.devnull, 'w'))
    console.print(renderable)
    return console.export_text()


def cells(line):
    """Return the stripped cells of a rich table row."""
    return [c.strip() for c in line.split('│')[1:-1]]


def episode(ret, cut_short=False):
    status = DiagnosticStatus(name='episode')
    status.values = [KeyValue(key='return', value=repr(ret)),
                     KeyValue(key='cut_short', value='true' if cut_short else 'false')]
    return status


def test_sparkline_scales_to_the_range():
    assert sparkline([]) == ''
    assert sparkline([float('nan'), 1.0, 2.0]) == '▁█'
    assert sparkline(range(100), width=5) == '▁▃▅▆█'


def test_state_renders_metrics_episodes_and_stale_nodes():
    state = MonitorState(stale=5.0)
    for i in range(10):
        state.on_metric('episode_return', -40.0 + i, now=100.0 + i)
    state.on_metric('policy_loss', 0.25, now=109.0)
    state.on_metric('zzz_custom', 7.0, now=109.0)
    for r in (-10.0, -8.0):
        state.on_episode(episode(r))
    state.on_episode(episode(-3.0, cut_short=True))
    diag = DiagnosticArray()
    diag.status = [DiagnosticStatus(level=DiagnosticStatus.WARN, name='sim_node: arms',
                                    message='2 commands dropped'),
                   DiagnosticStatus(level=DiagnosticStatus.OK, name='learner_node',
                                    message='learning')]
    state.on_diagnostics(diag, now=100.0)
    diag.status = diag.status[1:]
    state.on_diagnostics(diag, now=108.0)
    text = text_of(state.render(now=110.0))
    lines = text.splitlines()
    row = cells(next(line for line in lines if 'episode_return' in line))
    assert row[:3] == ['episode_return', '-31', sparkline(range(10))]
    # the usual metrics first, others after
    assert text.index('episode_return') < text.index('policy_loss') < text.index('zzz_custom')
    assert cells(next(line for line in lines if 'policy_loss' in line))[1] == '0.25'
    eps = cells(next(line for line in lines if '-9.000' in line))
    assert eps[0] == '3' and eps[1] == '-9.000' and eps[3] == '1'
    sim = next(line for line in lines if 'sim_node: arms' in line)
    assert 'STALE' in sim  # 10 s old
    assert 'OK' in next(line for line in lines if 'learner_node' in line)


class Publisher:
    """Publish metrics (20 Hz), episode summaries and diagnostics (2 Hz) in a thread."""

    def __init__(self, run='', loss=0.125):
        """Create the node of run ``run`` and start spinning."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.run, self.loss_value = run, loss
        self.node = rclpy.create_node('fake_training', context=self.context)
        self.ret = self.node.create_publisher(Float64, run_topic(run, 'metrics/episode_return'),
                                              10)
        self.loss = self.node.create_publisher(Float64, run_topic(run, 'metrics/policy_loss'),
                                               10)
        self.eps = self.node.create_publisher(DiagnosticStatus, run_topic(run, 'episode'), 10)
        self.diag = self.node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.i = 0
        self.node.create_timer(0.05, self.fast)
        self.node.create_timer(0.5, self.slow)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def fast(self):
        self.i += 1
        self.ret.publish(Float64(data=-40.0 + 0.1 * self.i))
        self.loss.publish(Float64(data=self.loss_value))

    def slow(self):
        self.eps.publish(episode(-12.5))
        array = DiagnosticArray()
        array.status = [DiagnosticStatus(level=DiagnosticStatus.WARN, name='fake_node: test',
                                         message=f'hello from the test of run {self.run!r}',
                                         values=[KeyValue(key='run_id', value=self.run)])]
        self.diag.publish(array)

    def close(self):
        self.executor.shutdown()
        self.thread.join(5)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def run(*args, timeout=60, columns=160, domain=DOMAIN_ID):
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONPATH=str(REPO),
               COLUMNS=str(columns))
    env.pop('MUJOCO_GL', None)
    return subprocess.run([sys.executable, '-m', 'pg_node', *args], env=env, cwd=REPO,
                          capture_output=True, text=True, timeout=timeout,
                          start_new_session=True)


@pytest.fixture(scope='module')
def publisher():
    pub = Publisher()
    yield pub
    pub.close()


@pytest.mark.e2e
def test_monitor_once_shows_live_metrics_and_nodes(publisher):
    done = run('monitor', '--once', '--duration', '6')  # discovery can take seconds
    assert done.returncode == 0, done.stderr
    out = done.stdout
    row = cells(next(line for line in out.splitlines() if 'episode_return' in line))
    value = float(row[1])
    assert -40.0 < value < 0.0
    assert '0.125' in next(line for line in out.splitlines() if 'policy_loss' in line)
    node = next(line for line in out.splitlines() if 'fake_node: test' in line)
    assert 'WARN' in node and 'hello from the test' in node
    assert '-12.500' in out  # mean return of the episode summaries


@pytest.mark.e2e
def test_topics_lists_types_endpoints_and_rates(publisher):
    done = run('topics', '--json', '--discovery', '2', '--duration', '3')
    assert done.returncode == 0, done.stderr
    rows = {r['name']: r for r in json.loads(done.stdout)}
    ret = rows['/pg_node/metrics/episode_return']
    assert ret['types'] == ['std_msgs/msg/Float64']
    assert ret['publishers'] == 1 and ret['subscribers'] == 0
    assert 12.0 < ret['rate_hz'] < 28.0  # published at 20 Hz
    diag = rows['/diagnostics']
    assert diag['types'] == ['diagnostic_msgs/msg/DiagnosticArray']
    assert 1.0 < diag['rate_hz'] < 3.5  # 2 Hz
    plain = run('topics', '--discovery', '4', '--duration', '0.5', columns=80)
    assert plain.returncode == 0 and '/pg_node/metrics/policy_loss' in plain.stdout
    lines = plain.stdout.splitlines()
    assert max(len(line) for line in lines) <= 80, plain.stdout
    assert 'diagnostic_msgs/msg/DiagnosticArray' in plain.stdout and '…' not in plain.stdout


class Graph:
    """A graph whose topic list changes at given times of a clock that only ``spin`` moves."""

    def __init__(self, *changes):
        self.changes = changes          # (time, topic names from then on)
        self.now = 0.0
        self.asked = []

    def names(self):
        current = [names for at, names in self.changes if at <= self.now][-1]
        self.asked.append((self.now, current))
        return current

    def spin(self, seconds):
        self.now = round(self.now + seconds, 6)


BASIC = ['/parameter_events', '/rosout']


def test_discovery_waits_for_a_node_that_comes_late():
    """The first answers hold only the basic topics, then one node's, then another's."""
    from pg_node.tools.topics import wait_for_discovery
    late = BASIC + ['/joint_states', '/arm/commands']
    graph = Graph((0.0, BASIC), (1.0, BASIC + ['/joint_states']), (1.4, late))
    assert wait_for_discovery(graph.names, graph.spin, settle=0.5, longest=5.0,
                              clock=lambda: graph.now)
    assert graph.asked[-1][1] == late              # the late node's topic was waited for
    last_change = min(t for t, names in graph.asked if names == late)
    # ended once the list had settled (within one poll)
    assert last_change + 0.5 - 1e-9 <= graph.now <= last_change + 0.6 + 1e-9


def test_discovery_ends_early_on_an_idle_graph_and_at_the_longest_on_an_empty_one():
    from pg_node.tools.topics import wait_for_discovery
    idle = Graph((0.0, BASIC + ['/joint_states']))
    assert wait_for_discovery(idle.names, idle.spin, settle=0.5, longest=5.0,
                              clock=lambda: idle.now)
    assert 0.5 - 1e-9 <= idle.now <= 0.6 + 1e-9    # not the 5 s at most
    empty = Graph((0.0, BASIC))                    # only the basic topics: no answer yet
    assert not wait_for_discovery(empty.names, empty.spin, settle=0.5, longest=5.0,
                                  clock=lambda: empty.now)
    assert 5.0 - 1e-9 <= empty.now <= 5.1 + 1e-9


def test_one_runs_discovery_waits_for_that_runs_topics():
    """Another participant's topics settle first; the run asked for comes 2 s later."""
    from pg_node.tools.topics import wait_for_discovery
    other = BASIC + ['/diagnostics', '/exp_a/pg_node/episode']
    late = other + ['/exp_b/pg_node/episode']
    graph = Graph((0.0, other), (2.0, late))

    def wanted(name):
        return name.startswith('/exp_b/')
    assert wait_for_discovery(graph.names, graph.spin, settle=0.5, longest=5.0,
                              clock=lambda: graph.now, wanted=wanted)
    assert graph.asked[-1][1] == late and 2.5 - 1e-9 <= graph.now <= 2.6 + 1e-9
    absent = Graph((0.0, other))                   # the run never comes: the longest wait
    assert not wait_for_discovery(absent.names, absent.spin, settle=0.5, longest=5.0,
                                  clock=lambda: absent.now, wanted=wanted)
    assert 5.0 - 1e-9 <= absent.now <= 5.1 + 1e-9


def test_topics_help_says_how_long_it_waits_for_discovery():
    done = run('topics', '--help', columns=100)
    assert done.returncode == 0, done.stderr
    text = ' '.join(done.stdout.split())
    assert 'has not changed for --settle seconds' in text and '(default: 5.0)' in text


GRAPH_ROWS = [  # the longest names and types of a training graph
    {'name': '/arm3/pg_node/transition', 'types': ['std_msgs/msg/Float64MultiArray'],
     'publishers': 1, 'subscribers': 1, 'count': 123456, 'rate_hz': 1234.5},
    {'name': '/pg_node/metrics/explained_variance', 'types': ['std_msgs/msg/Float64'],
     'publishers': 1, 'subscribers': 10, 'count': 20, 'rate_hz': 9.8},
    {'name': '/diagnostics', 'types': ['diagnostic_msgs/msg/DiagnosticArray'],
     'publishers': 4, 'subscribers': 0, 'count': 8, 'rate_hz': 4.0},
    {'name': '/replay_node/parameter_events_of_a_long_name', 'types': ['foo_msgs/msg/Bar'],
     'publishers': 1, 'subscribers': 0, 'count': None, 'rate_hz': None},
]


@pytest.mark.parametrize('width', [80, 160])
def test_topics_table_fits_the_terminal_without_cutting(width):
    from pg_node.tools.topics import table
    console = Console(width=width, record=True, file=open(os.devnull, 'w'))
    console.print(table(GRAPH_ROWS, width))
    text = console.export_text()
    assert max(len(line) for line in text.splitlines()) <= width, text
    for r in GRAPH_ROWS:
        assert r['name'] in text and r['types'][0] in text
    assert '1234.5' in text and '123456' in text and '(not installed)' in text


def test_docstring_examples():
    import doctest
    import pg_node.tools.monitor
    failures, tried = doctest.testmod(pg_node.tools.monitor)
    assert tried >= 2 and failures == 0


@pytest.mark.parametrize('option', ['--duration', '--stale', '--refresh'])
def test_monitor_refuses_a_negative_time(option, capsys):
    from pg_node.tools.monitor import main
    bounded = [] if option == '--duration' else ['--duration', '0.5']  # (before the fix)
    with pytest.raises(SystemExit) as exc:
        main([option, '-1', '--once'] + bounded)
    assert exc.value.code == 2
    assert f'argument {option}: must be > 0, got -1' in capsys.readouterr().err


def test_a_run_picked_as_the_only_one_is_ambiguous_once_another_shows_up():
    state = MonitorState()
    state.runs = {'exp_a'}
    state.choose('exp_a')                       # what discovery does with the only run
    assert not state.ambiguous() and 'several' not in state.choice()
    state.runs.add('exp_b')                     # heard later: a slow discovery
    assert state.ambiguous()
    assert 'run exp_a' in state.choice() and 'exp_a, exp_b; choose one' in state.choice()
    state.asked = True                          # --run exp_a: the user chose
    assert not state.ambiguous() and 'several' not in state.choice()


@pytest.mark.e2e
def test_monitor_and_topics_tell_two_runs_apart(publisher):
    """Two runs on one domain: monitor asks which and shows the chosen one; topics names both."""
    other = Publisher(run='exp_b', loss=0.5)
    try:
        done = run('monitor', '--once', '--duration', '6')
        assert done.returncode == 2, done.stdout + done.stderr
        assert 'several runs on this ROS domain' in done.stderr and 'exp_b' in done.stderr
        done = run('monitor', '--once', '--duration', '6', '--run', 'exp_b')
        assert done.returncode == 0, done.stderr
        assert '0.5' in next(line for line in done.stdout.splitlines() if 'policy_loss' in line)
        node = next(line for line in done.stdout.splitlines() if 'fake_node: test' in line)
        assert "run 'exp_b'" in node                 # the other run's status is not shown
        assert "run ''" not in done.stdout
        # waits for exp_b's own participant, not only for the first one's /diagnostics
        listed = run('topics', '--discovery', '15', '--duration', '0.5', '--json', '--run',
                     'exp_b')
        names = {r['name'] for r in json.loads(listed.stdout)}
        assert '/exp_b/pg_node/metrics/policy_loss' in names and '/diagnostics' in names
        assert not any(n.startswith('/pg_node/') for n in names), names
        absent = run('topics', '--discovery', '1', '--duration', '0', '--run', 'exp_zzz')
        assert absent.returncode == 0 and absent.stderr.strip().splitlines() == [
            'topics: no topic of run exp_zzz found in 1 s (is it on this ROS_DOMAIN_ID?)'
        ], absent.stderr
        # two participants: under load the second may be found seconds after the first
        both = run('topics', '--discovery', '8', '--settle', '4', '--duration', '0.5')
        assert 'runs: (no run id), exp_b' in both.stdout, both.stdout
    finally:
        other.close()


@pytest.mark.e2e
def test_monitor_without_a_terminal_prints_plain_lines(publisher):
    """Before: the live view, its output a pipe, printed nothing until it was stopped."""
    done = run('monitor', '--duration', '6', '--every', '1')
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) >= 3, done.stdout
    assert not any(c in done.stdout for c in '│┃━\x1b'), done.stdout  # no table, no escapes
    last = lines[-1]
    assert 'episode_return ' in last and 'policy_loss 0.125' in last, last
    assert 'episodes (mean return -12.500' in last and '1 WARN' in last, last


@pytest.mark.e2e
@pytest.mark.parametrize('args', [['--wait', '2'], ['--once', '--duration', '2']],
                         ids=['lines', 'once'])
def test_monitor_that_hears_no_run_names_the_domain_and_fails(args):
    """A domain where nothing runs: one line naming ROS_DOMAIN_ID, exit code 1."""
    empty = ros_domains(2, base=110, spread=50)[1]      # the test's domain is the first
    done = run('monitor', *args, domain=empty, timeout=30)
    assert done.returncode == 1, done.stdout + done.stderr
    assert done.stderr.strip().splitlines() == [
        f'monitor: no pg_node run and no node heard on ROS domain {empty} '
        f'(ROS_DOMAIN_ID={empty}) in 2 s: is a training running, with the same ROS_DOMAIN_ID '
        '(and ROS_AUTOMATIC_DISCOVERY_RANGE) as here?'], done.stderr


def test_state_line_summarises_metrics_episodes_and_nodes():
    state = MonitorState(stale=5.0)
    state.runs, state.run = {'exp1'}, 'exp1'
    state.on_metric('policy_loss', 0.5, now=0.0)
    state.on_metric('episode_return', -3.0, now=0.0)
    state.on_episode(episode(-2.0))
    state.on_episode(episode(0.0, cut_short=True))
    array = DiagnosticArray()
    array.status = [DiagnosticStatus(level=DiagnosticStatus.OK, name='a'),
                    DiagnosticStatus(level=DiagnosticStatus.ERROR, name='b')]
    state.on_diagnostics(array, now=0.0)
    assert state.line(now=1.0) == ('run exp1: /exp1/pg_node/...: episode_return -3, '
                                   'policy_loss 0.5; 2 episodes (mean return -2.000 of the '
                                   'recent ones, 1 cut short); nodes 1 OK, 1 ERROR')
    assert state.line(now=10.0).endswith('; nodes 2 STALE')
    assert not state.heard_nothing() and MonitorState().heard_nothing()
