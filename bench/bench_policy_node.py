"""
policy_node's control loop: achieved rate, state-to-command delay and CPU, torch against ONNX.

Usage::

    python bench/bench_policy_node.py [--policy RUN] [--seconds 10] [--rates 50 500]
                                      [--arms 1 64]

Without ``--policy`` a policy is trained for a few thousand steps in-process (its quality
does not matter here) and exported. For every policy path (the checkpoint through torch, the
export through onnxruntime), command rate and number of arms, ``policy_node`` runs as its own
process while this script publishes ``joint_states`` (``arm<i>/joint0...``) at the same rate
and the targets once, and counts the commands that come back. Reported:

* ``achieved_hz``: commands received per second over the measured window;
* ``delay_median_ms`` / ``delay_p99_ms``: the age of the joint state each command was computed
  from, as policy_node's diagnostics report it (receipt to publication, over its last 1000
  commands): a timer-driven loop waits for its tick, so up to one period is expected;
* ``cpu_percent``: policy_node's CPU time over the window (``/proc/<pid>/stat``) per wall
  second, in percent of one core.

Then start-up: seconds from starting the process to its first diagnostics message (imports,
policy load, DDS discovery) and its resident memory while commanding one arm at 50 Hz.
The load average is printed before and after: the machine may be shared.
"""
import argparse
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

DOMAIN_ID = int(os.environ.get('ROS_DOMAIN_ID', '') or 231)


def cpu_seconds(pid: int) -> float:
    """Return the user + system CPU seconds of process ``pid``."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def rss_mb(pid: int) -> float:
    """Return the resident memory of process ``pid`` in MB."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1]) / 1024
    return float('nan')


def make_policy(workdir: Path, given):
    """Return ``(run or checkpoint, onnx file)``: given, or trained briefly and exported."""
    from pg_node.common.run_dir import RunDir
    from pg_node.rl.onnx_export import export_policy
    from pg_node.rl.trained_policy import find_checkpoint, TorchPolicy
    if given is None:
        from pg_node.common.config_files import load_config
        from pg_node.rl.train_inprocess import train_inprocess
        summary = train_inprocess(load_config(None, ['num_envs=8']), 4096, eval_episodes=1)
        given = workdir / 'run'
        summary['learner'].save(RunDir(given).checkpoints)
    trained = TorchPolicy(*find_checkpoint(given))
    onnx = workdir / 'policy.onnx'
    export_policy(trained.policy, trained.card, onnx)
    return Path(given), onnx


class Feeder:
    """This script's ROS side: joint states out at a rate, commands and diagnostics in."""

    def __init__(self):
        """Join the bench's domain and spin in a thread."""
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PointStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from trajectory_msgs.msg import JointTrajectory
        self.rclpy, self.JointState, self.PointStamped = rclpy, JointState, PointStamped
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.node = rclpy.create_node('bench_policy_node', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.commands = 0
        self.diag = None
        self.diag_time = None
        self.node.create_subscription(JointTrajectory, '/arm_controller/joint_trajectory',
                                      self._on_command, 100)    # the default command_message
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)
        self.pub_js = self.node.create_publisher(JointState, '/joint_states', 10)
        self.pub_target = self.node.create_publisher(
            PointStamped, '/target', QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE,
                                                durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.timer = None
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self._stop:
            self.executor.spin_once(timeout_sec=0.01)

    def _on_command(self, msg):
        self.commands += 1

    def _on_diag(self, msg):
        for status in msg.status:
            if status.name.endswith('policy_node: trained policy'):
                self.diag = (status.message, {kv.key: kv.value for kv in status.values})
                if self.diag_time is None:
                    self.diag_time = time.monotonic()

    def feed(self, arms: int, rate: float):
        """Publish targets for ``arms`` arms once and joint states at ``rate`` Hz."""
        if self.timer is not None:
            self.node.destroy_timer(self.timer)
        for i in range(arms):
            point = self.PointStamped()
            point.header.frame_id = f'arm{i}'
            point.point.x, point.point.y, point.point.z = 0.1, 0.05, 0.01
            self.pub_target.publish(point)
        rng = np.random.default_rng(0)
        names = [f'arm{i}/joint{j}' for i in range(arms) for j in range(2)]
        msg = self.JointState(name=names)

        def tick():
            msg.position = rng.uniform(-1, 1, len(names)).tolist()
            msg.velocity = rng.uniform(-1, 1, len(names)).tolist()
            self.pub_js.publish(msg)

        self.timer = self.node.create_timer(1.0 / rate, tick)

    def close(self):
        """Stop spinning and leave the domain."""
        self._stop = True
        self.thread.join(5)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def start_node(policy: Path, params, log: Path):
    """Start policy_node as a process in the bench's domain."""
    from pg_node.tools import processes
    args = [sys.executable, '-m', 'pg_node.ros.policy_node', '--ros-args', '-p',
            f'policy:={policy}', '-p', 'autostart:=true',
            '-p', 'controller_timeout:=0.0']      # no controller here whose joints to read
    for p in params:
        args += ['-p', p]
    return processes.start_logged(args, log, processes.child_env(DOMAIN_ID))


def wait_for(condition, timeout):
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def loop_row(feeder, policy, kind, arms, rate, seconds, workdir):
    """Measure one configuration; return its table row."""
    from pg_node.tools import processes
    feeder.diag = feeder.diag_time = None
    feeder.feed(arms, rate)
    proc = start_node(policy, [f'control_rate:={rate}', 'state_timeout:=1.0'],
                      workdir / f'{kind}_{arms}_{rate}.log')
    try:
        if not wait_for(lambda: feeder.diag and feeder.diag[0] == 'commanding', 120):
            return [kind, arms, rate, 'no commands'] + [''] * 3
        time.sleep(2.0)                                   # warm-up
        c0, n0, t0 = cpu_seconds(proc.pid), feeder.commands, time.monotonic()
        time.sleep(seconds)
        c1, n1, t1 = cpu_seconds(proc.pid), feeder.commands, time.monotonic()
        time.sleep(1.2)                                   # a diagnostics after the window
        values = feeder.diag[1]
    finally:
        processes.stop_logged(proc)
    return [kind, arms, rate, f'{(n1 - n0) / (t1 - t0):.1f}', values['state_age_median_ms'],
            values['state_age_p99_ms'], f'{100 * (c1 - c0) / (t1 - t0):.1f}']


def startup_row(feeder, policy, kind, workdir):
    """Return ``[kind, seconds to first diagnostics, load seconds, RSS MB]``."""
    from pg_node.tools import processes
    feeder.diag = feeder.diag_time = None
    feeder.feed(1, 50.0)
    t0 = time.monotonic()
    proc = start_node(policy, [], workdir / f'startup_{kind}.log')
    try:
        if not wait_for(lambda: feeder.diag_time is not None, 120):
            return [kind, 'no diagnostics', '', '']
        up = feeder.diag_time - t0
        wait_for(lambda: feeder.diag and feeder.diag[0] == 'commanding', 30)
        time.sleep(3.0)
        mem = rss_mb(proc.pid)
        load = feeder.diag[1]['load_seconds']
    finally:
        processes.stop_logged(proc)
    return [kind, f'{up:.2f}', load, f'{mem:.0f}']


def table(header, rows):
    """Return rows as an aligned text table."""
    cells = [header] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[k]) for r in cells) for k in range(len(header))]
    return '\n'.join(' '.join(c.rjust(w) for c, w in zip(r, widths)) for r in cells)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--policy', help='a run directory or checkpoint (default: train one)')
    parser.add_argument('--seconds', type=float, default=10.0, help='measured window')
    parser.add_argument('--rates', type=float, nargs='+', default=[50.0, 500.0])
    parser.add_argument('--arms', type=int, nargs='+', default=[1, 64])
    parser.add_argument('--startup-runs', type=int, default=2)
    args = parser.parse_args(argv)
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=REPO,
                            capture_output=True, text=True).stdout.strip()
    print(f'commit {commit}, load average before: {os.getloadavg()}', flush=True)
    workdir = Path(tempfile.mkdtemp(prefix='bench_policy_node_'))
    run, onnx = make_policy(workdir, args.policy)
    feeder = Feeder()
    try:
        rows = []
        for arms in args.arms:
            for rate in args.rates:
                for kind, src in (('torch', run), ('onnx', onnx)):
                    rows.append(loop_row(feeder, src, kind, arms, rate, args.seconds, workdir))
                    print(' '.join(map(str, rows[-1])), file=sys.stderr, flush=True)
        ups = []
        for _ in range(args.startup_runs):
            for kind, src in (('torch', run), ('onnx', onnx)):
                ups.append(startup_row(feeder, src, kind, workdir))
    finally:
        feeder.close()
    print('\npolicy_node control loop (state publisher in this process at the same rate; '
          f'{args.seconds:g} s windows)')
    print(table(['policy', 'arms', 'rate_hz', 'achieved_hz', 'delay_median_ms',
                 'delay_p99_ms', 'cpu_percent'], rows))
    print('\nstart-up (process start to first diagnostics; policy load inside it; resident '
          'memory commanding 1 arm)')
    print(table(['policy', 'startup_s', 'load_s', 'rss_mb'], ups))
    print(f'\nload average after: {os.getloadavg()}; logs in {workdir}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
