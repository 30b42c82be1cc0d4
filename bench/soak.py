"""
``python -m bench.soak --minutes N``: training with faults injected on a schedule, and a report.

The graph is started and supervised as ``python -m pg_node train`` does it (the same
:class:`pg_node.tools.supervisor.Supervisor`, with a large restart budget), with
``total_steps`` out of reach, so the run lasts as long as asked. After ``--warmup`` seconds
one fault is injected every ``--interval`` seconds, cycling through :data:`FAULTS`:

* ``kill <node>``: SIGKILL of ``sim_node``, ``actor_node``, ``critic_node``, ``learner_node``
  in turn; the supervisor restarts the node;
* ``stall <node>``: SIGSTOP for longer than the timeouts that cover a lost message
  (``rollout_resend_timeout`` for the critic and learner, ``lock_step_timeout`` for the
  simulator), then SIGCONT: the messages the node should have answered meanwhile go
  unanswered, the re-send paths must take over;
* ``garbage``: malformed messages on every input topic of the graph (commands of the wrong
  size, with NaN and with 1e300; a transition, rollout, batch and weights message whose
  layout fits nothing); every node must drop and count them.

The last interval is left free of faults so that recovery can be seen. The report says which
faults were injected and when, whether each was recovered from (the node restarted where it
was killed, and the policy version went past the version it had at the fault) and how long
that took, the environment steps lost (steps the learner learned after its newest checkpoint
and lost with it, and partial rollouts the actors discarded), the malformed messages sent and
those the nodes reported dropping, every bag directory and whether PyPI ``rosbags`` reads it
(after :func:`pg_node.bag.writer.reindex` where a killed learner left it unfinished), and the
resident memory (``VmRSS`` of ``/proc/<pid>/status``) of every node process.

Memory is measured per process (a restarted node is a new process): its baseline is taken
``--warmup`` seconds after the process started, once imports, network allocations, DDS
discovery and the first bag chunks are behind it, and compared with its last sample; a
process that lived too short for that is listed but not judged. ``--json`` prints the
report as JSON. The exit code is 0 when training advanced past every fault, every bag is
readable and no process grew by more than ``--max-growth`` percent.
"""
import argparse
from datetime import datetime
import json
import os
from pathlib import Path
import signal
import sys
import time

from pg_node.common.config_files import load_config
from pg_node.common.param_schema import ConfigError
from pg_node.common.params import SHARED
from pg_node.common.run import COMMANDS, pair_namespace, run_id_for_dir, run_topic
from pg_node.tools.processes import terminate_as_interrupt

NODES = ('sim_node', 'actor_node', 'critic_node', 'learner_node')
FAULTS = ('kill sim_node', 'kill actor_node', 'kill critic_node', 'kill learner_node',
          'garbage', 'stall critic_node', 'stall sim_node', 'stall learner_node')
#: Diagnostics counters that say a node dropped a malformed message.
DROP_COUNTERS = ('commands_dropped_size', 'commands_dropped_nonfinite',
                 'commands_dropped_absurd', 'transitions_dropped', 'weights_dropped',
                 'rollouts_dropped', 'dropped_batches')


def parse_args(argv):
    """Parse the command line."""
    parser = argparse.ArgumentParser(
        prog='python -m bench.soak',
        description='Train with faults injected on a schedule (kill each node in turn, '
                    'stall nodes, send malformed messages) and report what survived.')
    parser.add_argument('overrides', nargs='*', metavar='key=value',
                        help='override any parameter, as for train')
    parser.add_argument('--minutes', type=float, default=10.0, help='default: %(default)s')
    parser.add_argument('--config', help='ROS 2 parameter file (default: config/pg_node.yaml)')
    parser.add_argument('--run-dir', help='default: runs/soak-<date-time>')
    parser.add_argument('--warmup', type=float, default=20.0,
                        help='seconds before the first fault, and after a process start '
                             'before its memory baseline (default: %(default)s)')
    parser.add_argument('--interval', type=float,
                        help='seconds between faults (default: the run split evenly, '
                             'one interval left free at the end, 10 to 60 s)')
    parser.add_argument('--max-growth', type=float, default=10.0,
                        help='allowed resident memory growth in percent (default: '
                             '%(default)s)')
    parser.add_argument('--json', action='store_true', help='print the report as JSON')
    return parser.parse_args(argv)


def rss_bytes(pid: int):
    """Return the resident set size of ``pid`` from ``/proc`` (None if it is gone)."""
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def steps_lost_by_learner(rows, batch_steps: int) -> int:
    """
    Return the environment steps the learner lost with its restarts, from ``progress.csv``.

    A restarted learner resumes from its newest checkpoint: ``env_steps`` goes back, and the
    steps learned between that checkpoint and the crash are lost. ``rows``: the file's rows
    (:meth:`pg_node.common.run_dir.RunDir.read_progress`).
    """
    lost, prev = 0, None
    try:
        for row in rows:
            steps = int(row['env_steps'])
            if prev is not None and steps <= prev:
                lost += prev - (steps - batch_steps)
            prev = steps
    except (KeyError, ValueError):
        pass
    return lost


def check_bag(directory: Path) -> dict:
    """Read a bag with PyPI ``rosbags``; reindex it if that fails or counts disagree."""
    from pg_node.bag.writer import reindex

    def read():
        from rosbags.rosbag2 import Reader
        with Reader(directory) as reader:
            want = {c.id: c.msgcount for c in reader.connections}
            got = dict.fromkeys(want, 0)
            for conn, _, _ in reader.messages():
                got[conn.id] += 1
            episodes = sum(c.msgcount for c in reader.connections
                           if c.topic == '/pg_node/episode')
            return got == want, sum(got.values()), episodes

    out = {'bag': str(directory)}
    try:
        ok, n, episodes = read()
        if ok:
            return {**out, 'readable': True, 'reindexed': False, 'messages': n,
                    'episodes': episodes}
        problem = 'message counts in metadata.yaml differ from the files'
    except Exception as exc:  # noqa: B902 - any reader failure means: try reindex
        problem = f'{type(exc).__name__}: {exc}'
    try:
        reindex(directory)
        ok, n, episodes = read()
    except Exception as exc:  # noqa: B902
        return {**out, 'readable': False, 'reindexed': True, 'problem': problem,
                'error': f'{type(exc).__name__}: {exc}'}
    return {**out, 'readable': ok, 'reindexed': True, 'problem': problem, 'messages': n,
            'episodes': episodes}


class Injector:
    """A small rclpy node of the soak process: sends malformed messages, reads diagnostics."""

    def __init__(self, cfg: dict):
        from diagnostic_msgs.msg import DiagnosticArray
        from pg_node.ros.qos import LATCHED, RELIABLE
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import Float64MultiArray
        self.rclpy = rclpy
        self.Msg = Float64MultiArray
        self.latched, self.reliable = LATCHED, RELIABLE
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node('pg_node_soak', context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        run_id = cfg[SHARED]['run_id']
        self.ns = pair_namespace(run_id, 0, cfg[SHARED]['num_actors']).rstrip('/') + '/'
        import mujoco
        from pg_node.common.paths import resolve_model
        nu = mujoco.MjModel.from_xml_path(str(resolve_model(cfg[SHARED]['model']))).nu
        self.n_cmd = cfg[SHARED]['num_envs'] * nu
        self.counters = {}      # status name -> {counter: value}
        self.carried = {}       # status name -> {counter: sum over earlier processes}
        self.heard = {}         # status name -> time of its newest diagnostics message
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.on_diag, 50)
        from std_msgs.msg import Float64
        self.batch_steps = (cfg['actor_node']['n_steps'] * cfg[SHARED]['num_envs']
                            * cfg[SHARED]['num_actors'])
        self.env_steps = None       # the learner's newest env_steps metric
        self.learner_lost = 0
        self.node.create_subscription(Float64, run_topic(run_id, 'metrics/env_steps'),
                                      self.on_env_steps, 100)
        self.pub_cmd = self.node.create_publisher(Float64MultiArray, self.ns + COMMANDS, 10)
        self.pub_rollout = self.node.create_publisher(
            Float64MultiArray, run_topic(run_id, 'rollout'), RELIABLE)
        self.pub_batch = self.node.create_publisher(Float64MultiArray,
                                                    run_topic(run_id, 'batch'), RELIABLE)
        self.weights_topic = run_topic(run_id, 'policy_weights')
        self.latched_pubs = []

    def on_env_steps(self, msg):
        """
        Count the steps a restarted learner lost: it goes back to its newest checkpoint.

        The metric is published with every update, so the last value before the crash is
        what the learner had learned, also when its ``progress.csv`` was not yet flushed.
        """
        steps = int(msg.data)
        if self.env_steps is not None and steps <= self.env_steps:
            self.learner_lost += self.env_steps - (steps - self.batch_steps)
        self.env_steps = steps

    def on_diag(self, msg):
        """Keep each node's newest counters, carrying them over a restart."""
        for status in msg.status:
            values = {}
            for kv in status.values:
                try:
                    values[kv.key] = float(kv.value)
                except ValueError:
                    continue
            old = self.counters.get(status.name, {})
            carried = self.carried.setdefault(status.name, {})
            for key, value in values.items():
                if key in old and value < old[key]:    # a new process counts from 0 again
                    carried[key] = carried.get(key, 0.0) + old[key]
            self.counters[status.name] = values
            self.heard[status.name] = time.monotonic()

    def heard_since(self, node: str, since: float) -> bool:
        """Whether a diagnostics status of ``node`` (its name's prefix) arrived after ``since``."""
        return any(name.startswith(node) and t > since for name, t in self.heard.items())

    def total(self, key: str) -> float:
        """Return a counter summed over all nodes and all their processes."""
        return sum(v.get(key, 0.0) + self.carried.get(name, {}).get(key, 0.0)
                   for name, v in self.counters.items())

    def spin(self, seconds: float = 0.0):
        """Process callbacks for about ``seconds``."""
        end = time.monotonic() + seconds
        while True:
            self.ex.spin_once(timeout_sec=0.01)
            if time.monotonic() >= end:
                return

    def _msg(self, data, offset=0):
        import array
        msg = self.Msg()
        msg.layout.data_offset = offset
        msg.data = array.array('d', data)
        return msg

    def wait_for_subscribers(self, pub, timeout: float = 15.0):
        """
        Spin until ``pub`` is matched with a subscriber (at most ``timeout`` seconds).

        A node that a fault just killed may still be starting (importing torch takes seconds
        on a loaded machine); a message published before it subscribed is lost unseen.
        """
        end = time.monotonic() + timeout
        while pub.get_subscription_count() < 1 and time.monotonic() < end:
            self.spin(0.05)

    def garbage(self) -> dict:
        """
        Publish malformed messages on every input topic; return how many of each were sent.

        The actor reads transitions with keep-last-1 (the newest wins), so a malformed one
        can be superseded by the simulator's next transition before the actor reads it: it
        is then never processed at all. Five are sent, 20 ms apart; the report counts those
        the actor did see and drop.
        """
        sent = {}
        self.wait_for_subscribers(self.pub_cmd)
        for data in ([1.0, 2.0, 3.0], [float('nan')] * self.n_cmd, [1e300] * self.n_cmd):
            self.pub_cmd.publish(self._msg(data))
        sent['commands'] = 3
        for kind, pub in (('rollouts', self.pub_rollout), ('batches', self.pub_batch)):
            self.wait_for_subscribers(pub)
            pub.publish(self._msg([float('nan')] * 12, offset=5))
            sent[kind] = 1
        for kind, topic, n in (('transitions', self.ns + 'pg_node/transition', 5),
                               ('weights', self.weights_topic, 1)):
            # latched subscribers need a latched publisher
            pub = self.node.create_publisher(self.Msg, topic, self.latched)
            self.latched_pubs.append(pub)
            self.wait_for_subscribers(pub)
            for _ in range(n):
                pub.publish(self._msg([0.0] * 7, offset=3))
                self.spin(0.02)
            sent[kind] = n
        self.spin(0.5)
        for pub in self.latched_pubs:
            # gone before a node restarts, which would get it as its first message
            self.node.destroy_publisher(pub)
        self.latched_pubs = []
        return sent

    def close(self):
        """Leave the graph."""
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)


def all_nodes_up(sup, injector) -> bool:
    """
    Whether every node has published diagnostics since its newest (re)start.

    Malformed messages sent while a killed node is still starting would reach nobody: its
    subscriptions do not exist yet, and the dead process's may still look matched in DDS
    until its lease runs out.
    """
    return all(injector.heard_since(node, max(t for name, t in sup.started_at.items()
                                              if name.startswith(node)))
               for node in NODES)


class MemoryLog:
    """Resident memory of every node process, sampled over its life."""

    def __init__(self, warmup: float):
        self.warmup = warmup
        self.procs = {}         # pid -> {'node', 'started', 'baseline', 'last', ...}

    def sample(self, sup):
        """Sample the RSS of every running node process."""
        now = time.monotonic()
        for name, proc in sup.procs.items():
            if proc.poll() is not None:
                continue
            rec = self.procs.setdefault(proc.pid, {'node': name, 'pid': proc.pid,
                                                   'started': now, 'baseline': None,
                                                   'last': None, 'peak': 0})
            rss = rss_bytes(proc.pid)
            if rss is None:
                continue
            if rec['baseline'] is None and now - rec['started'] >= self.warmup:
                rec['baseline'], rec['baseline_at'] = rss, now
            rec['last'], rec['last_at'] = rss, now
            rec['peak'] = max(rec['peak'], rss)

    def report(self, t0: float, min_window: float, max_growth: float):
        """Return one entry per process: baseline, last, growth, judged or not."""
        out = []
        for rec in self.procs.values():
            entry = {'node': rec['node'], 'pid': rec['pid'],
                     'started_s': round(rec['started'] - t0, 1),
                     'rss_start_mb': None, 'rss_end_mb': None, 'growth_pct': None,
                     'judged': False}
            if rec['last'] is not None:
                entry['rss_end_mb'] = round(rec['last'] / 2**20, 1)
                entry['rss_peak_mb'] = round(rec['peak'] / 2**20, 1)
            if rec['baseline'] is not None:
                window = rec['last_at'] - rec['baseline_at']
                entry['rss_start_mb'] = round(rec['baseline'] / 2**20, 1)
                entry['window_s'] = round(window, 1)
                entry['growth_pct'] = round(100.0 * (rec['last'] / rec['baseline'] - 1), 2)
                entry['judged'] = window >= min_window
                entry['ok'] = not entry['judged'] or entry['growth_pct'] <= max_growth
            out.append(entry)
        return out


def run_soak(args) -> dict:
    """Run the soak; return the report."""
    from pg_node.common.paths import default_config
    from pg_node.common.run_dir import RunDir
    from pg_node.tools.supervisor import Supervisor
    from pg_node.tools.train import discovery_env, node_commands, sim_seeds, write_params
    run_dir = Path(os.path.abspath(args.run_dir or os.path.join(
        'runs', 'soak-' + datetime.now().strftime('%Y%m%d-%H%M%S'))))
    cfg = load_config(args.config or default_config(),
                      [f'run_id={run_id_for_dir(str(run_dir))}'] + list(args.overrides)
                      + ['total_steps=1000000000000', f'run_dir={run_dir}'])
    run = RunDir(run_dir).make()
    params = run.params
    write_params(cfg, params)
    total = args.minutes * 60.0
    interval = args.interval or min(60.0, max(10.0, (total - args.warmup) / (len(FAULTS) + 1)))
    batch_steps = (cfg['actor_node']['n_steps'] * cfg[SHARED]['num_envs']
                   * cfg[SHARED]['num_actors'])
    stall_for = {'sim_node': 3 * cfg['sim_node']['lock_step_timeout'] + 1.0,
                 'critic_node': cfg['actor_node']['rollout_resend_timeout'] + 3.0,
                 'learner_node': cfg['actor_node']['rollout_resend_timeout'] + 3.0}
    commands = node_commands(params, cfg)
    env, _ = discovery_env(network=False)
    sup = Supervisor(run_dir, commands, max_restarts=1000, seeds=sim_seeds(cfg), env=env)
    injector = Injector(cfg)
    memory = MemoryLog(args.warmup)
    faults, stalled = [], []       # stalled: (pid, resume at)
    garbage_sent = {}
    t0 = time.monotonic()
    next_fault = t0 + args.warmup
    last_sample = 0.0
    state = 'running'
    sup.start_all()
    try:
        while time.monotonic() - t0 < total and state == 'running':
            injector.spin(0.25)
            state = sup.check()
            now = time.monotonic()
            for pid, resume in list(stalled):
                if now >= resume:
                    _signal(pid, signal.SIGCONT)
                    stalled.remove((pid, resume))
            if now - last_sample >= 1.0:
                memory.sample(sup)
                last_sample = now
            row = run.last_progress()
            version = int(row['policy_version']) if row else -1
            steps = int(row['env_steps']) if row else 0
            for f in faults:
                if f['recovered_after_s'] is None and version > f['version_at_fault']:
                    f['recovered_after_s'] = round(now - t0 - f['at_s'], 1)
            if now >= next_fault and now - t0 < total - interval and not stalled:
                kind = FAULTS[len(faults) % len(FAULTS)]
                fault = {'fault': kind, 'at_s': round(now - t0, 1), 'version_at_fault': version,
                         'env_steps_at_fault': steps, 'recovered_after_s': None}
                action, _, name = kind.partition(' ')
                if action == 'garbage':
                    if not all_nodes_up(sup, injector):
                        next_fault = now + 1.0     # a restarted node is not up yet: soon
                        continue
                    n = injector.garbage()
                    for k, v in n.items():
                        garbage_sent[k] = garbage_sent.get(k, 0) + v
                    fault['messages'] = sum(n.values())
                else:
                    proc = sup.procs.get(name)
                    if proc is None or proc.poll() is not None:
                        next_fault = now + 1.0     # it is being restarted: try again soon
                        continue
                    fault['pid'] = proc.pid
                    if action == 'kill':
                        _signal(proc.pid, signal.SIGKILL)
                    else:
                        _signal(proc.pid, signal.SIGSTOP)
                        stalled.append((proc.pid, now + stall_for[name]))
                        fault['stalled_s'] = stall_for[name]
                faults.append(fault)
                next_fault = now + interval
        memory.sample(sup)
        injector.spin(1.5)                 # the newest diagnostics of every node
    finally:
        for pid, _ in stalled:
            _signal(pid, signal.SIGCONT)
        sup.stop_all()
        injector.close()
    wall = time.monotonic() - t0
    row = run.last_progress() or {}
    bags = [check_bag(d) for d in run.bags()
            if (d / 'metadata.yaml').exists() or any(d.glob('*.mcap'))]
    mem = memory.report(t0, min_window=min(30.0, max(10.0, wall / 4)),
                        max_growth=args.max_growth)
    dropped = {k: int(injector.total(k)) for k in DROP_COUNTERS}
    discarded = int(injector.total('rollouts_discarded'))
    # the metric stream sees what progress.csv may not have flushed before a SIGKILL
    learner_lost = max(injector.learner_lost,
                       steps_lost_by_learner(run.read_progress(), batch_steps))
    per_node = {}
    for name in commands:
        recs = [m for m in mem if m['node'] == name]
        per_node[name] = {'processes': len(recs), 'restarts': sup.restarts[name],
                          'rss_start_mb': recs[0]['rss_start_mb'] if recs else None,
                          'rss_end_mb': recs[-1]['rss_end_mb'] if recs else None}
    report = {
        'run_dir': str(run_dir), 'minutes': args.minutes, 'wall_seconds': round(wall, 1),
        'failed': state == 'failed', 'failure': getattr(sup, 'failed', None),
        'faults': faults,
        'faults_injected': len(faults),
        'recovered': sum(f['recovered_after_s'] is not None for f in faults),
        'restarts': dict(sup.restarts),
        'policy_version': int(row.get('policy_version', -1)) if row else -1,
        'env_steps': int(row.get('env_steps', 0)) if row else 0,
        'steps_lost': {'learner_since_checkpoint': learner_lost,
                       'partial_rollouts_discarded': discarded,
                       'upper_bound': learner_lost + discarded * cfg['actor_node']['n_steps']
                       * cfg[SHARED]['num_envs']},
        'malformed_sent': garbage_sent, 'malformed_reported_dropped': dropped,
        'bags': bags, 'all_bags_readable': bool(bags) and all(b['readable'] for b in bags),
        'memory': mem, 'memory_per_node': per_node,
        'max_growth_pct': args.max_growth, 'warmup_s': args.warmup,
        'memory_ok': all(m.get('ok', True) for m in mem),
    }
    report['ok'] = (not report['failed'] and report['all_bags_readable']
                    and report['memory_ok'] and report['recovered'] == len(faults))
    return report


def _signal(pid: int, sig):
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


def format_report(r: dict) -> str:
    """Return the report as text."""
    lines = [f'soak of {r["minutes"]:g} min ({r["wall_seconds"]:.0f} s), run dir {r["run_dir"]}',
             f'training: policy version {r["policy_version"]}, {r["env_steps"]} env steps'
             + ('; FAILED: ' + str(r['failure']) if r['failed'] else ''),
             f'faults injected: {r["faults_injected"]}, recovered: {r["recovered"]}']
    for f in r['faults']:
        rec = (f'recovered in {f["recovered_after_s"]:.1f} s' if f['recovered_after_s']
               is not None else 'NOT recovered')
        lines.append(f'  {f["at_s"]:7.1f} s  {f["fault"]:<20} at version '
                     f'{f["version_at_fault"]:<6} {rec}')
    lines.append('restarts: ' + ', '.join(f'{k} {v}' for k, v in r['restarts'].items()))
    sl = r['steps_lost']
    lines.append(f'steps lost: {sl["learner_since_checkpoint"]} learned after the newest '
                 f'checkpoint of a killed learner; {sl["partial_rollouts_discarded"]} partial '
                 f'rollouts discarded by actors (at most {sl["upper_bound"]} steps in all)')
    lines.append('malformed messages sent: ' + ', '.join(
        f'{k} {v}' for k, v in r['malformed_sent'].items()) + '; reported dropped: '
                 + ', '.join(f'{k} {v}' for k, v in r['malformed_reported_dropped'].items()
                             if v))
    lines.append('bags:')
    for b in r['bags']:
        how = ('readable' if b['readable'] else 'NOT readable') + (
            ' after reindex' if b['reindexed'] else '')
        lines.append(f'  {b["bag"]}: {how}, {b.get("messages", 0)} messages, '
                     f'{b.get("episodes", 0)} episode summaries')
    lines.append(f'resident memory (baseline {r["warmup_s"]:g} s after each process started; '
                 f'growth allowed {r["max_growth_pct"]:g}%):')
    for m in r['memory']:
        growth = ('-' if m['growth_pct'] is None else f'{m["growth_pct"]:+.1f}%')
        judged = '' if m['judged'] else ' (lived too short to judge)'
        lines.append(f'  {m["node"]:<14} pid {m["pid"]:<8} started {m["started_s"]:6.1f} s  '
                     f'start {m["rss_start_mb"]} MB  end {m["rss_end_mb"]} MB  '
                     f'{growth}{judged}')
    lines.append('result: ' + ('ok' if r['ok'] else 'PROBLEMS (see above)'))
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Run ``python -m bench.soak``."""
    args = parse_args(argv)
    try:
        with terminate_as_interrupt():
            report = run_soak(args)
    except ConfigError as exc:
        print(f'configuration error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130
    print(json.dumps(report, indent=2) if args.json else format_report(report))
    return 0 if report['ok'] else 1


if __name__ == '__main__':
    sys.exit(main())
