"""
The measurements behind ``python -m bench``, one function per thing measured.

Each returns plain numbers (no tables, no plots; :mod:`bench.suite` makes those):

* throughput: raw ``mj_step`` and the task in-process (taken from ``bench/bench_sim.py``),
  ``sim_node`` lock-step with a minimal client, A2C in-process, the training graph
  (``python -m pg_node train``), SB3 A2C training;
* latency: :mod:`bench.latency_probe` (sim_node timing its own round trips) driven by a
  client that answers every transition at once;
* learning: SB3 A2C / PPO and pg_node (graph and in-process) with deterministic evaluations at
  fixed step counts and a training-return curve against wall-clock time.

Every step count is in environment steps (one arm advanced by one control step). Node
processes are started in their own session and stopped with SIGINT, then SIGTERM, then
SIGKILL. Each run joins a domain of its own (:func:`domain_id`): ``ROS_DOMAIN_ID`` when it is
set, as the tests do, so that a bench inside an isolated run stays inside it.
"""
import importlib.util
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time
from typing import Dict, List, Optional, Sequence

import numpy as np
from pg_node.common.run_dir import RunDir
from pg_node.tools.processes import child_env, REPO, stop

_domain_counter = [0]


def domain_id(background: bool = False) -> int:
    """
    Return the ROS domain id of one run.

    With ``ROS_DOMAIN_ID`` set, that id, and the id after it for a ``background`` graph that
    runs beside another run (the tests' convention, ``test/domains.py``: a run set apart by
    ``ROS_DOMAIN_ID`` must not hear, nor be heard by, a neighbour's graph; the runs of one
    bench follow one another). Unset: an id unique within this process (1..99), from the pid.
    """
    given = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if given.isdigit():
        return int(given) + int(background)
    _domain_counter[0] += 1
    return 1 + (os.getpid() * 7 + _domain_counter[0]) % 99


# --- throughput ----------------------------------------------------------------------------

def _bench_sim():
    """Import ``bench/bench_sim.py`` (a script, not part of the package)."""
    spec = importlib.util.spec_from_file_location('bench_sim', REPO / 'bench' / 'bench_sim.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def raw_mujoco(seconds: float) -> float:
    """Return env steps/s of ``mj_step(m, d, nstep=frame_skip)`` on one reacher2 MjData."""
    import mujoco
    from pg_node.common.paths import resolve_model
    bs = _bench_sim()
    model = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))
    name, rate = next(bs.plain_mujoco(model, 1, seconds))
    assert name == 'mj_step loop'
    return rate


def task_in_process(n: int, seconds: float) -> float:
    """Return env steps/s of ``ArmTask.step`` with ``n`` arms (``n`` x calls/s)."""
    bs = _bench_sim()
    _, rate = next(bs.in_process(n, seconds))
    return rate * n


def sim_node_lock_step(n: int, seconds: float) -> float:
    """Return env steps/s of sim_node lock-step driven by bench_sim's minimal client."""
    return _bench_sim().through_node(n, seconds, domain_id()) * n


def a2c_in_process(steps: int, seed: int = 0) -> Dict:
    """Train pg_node A2C in-process for ``steps``; return its summary (numbers only)."""
    from pg_node.common.config_files import load_config
    from pg_node.rl.train_inprocess import train_inprocess
    summary = train_inprocess(load_config(None, [f'seed={seed}']), steps, eval_episodes=10)
    return {k: summary[k] for k in ('total_steps', 'wall_seconds', 'steps_per_second')}


def make_sb3(algo: str, env_id: str, seed: int, n_envs: int = 8):
    """Return an SB3 ``A2C`` or ``PPO`` with its default settings on ``n_envs`` envs."""
    import pg_node.sim.gym_env  # noqa: F401  (registers pg_node/Reacher2-v0)
    from stable_baselines3 import A2C, PPO
    from stable_baselines3.common.env_util import make_vec_env
    # make_vec_env asks for render_mode='rgb_array' unless told otherwise; nothing is
    # rendered here, so say so (Gymnasium's own Reacher-v5 gets the same)
    env = make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs={'render_mode': None})
    from stable_baselines3.common.logger import Logger
    cls = {'a2c': A2C, 'ppo': PPO}[algo]
    model = cls('MlpPolicy', env, seed=seed, device='cpu', verbose=0)
    # learn() would otherwise configure a logger that makes an empty $TMPDIR/SB3-<time>
    # folder at every call; nothing is logged here
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def sb3_throughput(steps: int, algo: str = 'a2c', seed: int = 0) -> Dict:
    """
    Return env steps/s of SB3 training (``algo``, 8 envs, defaults) on pg_node/Reacher2.

    The clock starts when training starts (after ``learn``'s set-up, which the first call in
    a process makes slow with lazy imports) and includes every rollout and update.
    """
    from stable_baselines3.common.callbacks import BaseCallback
    model = make_sb3(algo, 'pg_node/Reacher2-v0', seed)
    start = []

    class Clock(BaseCallback):

        def _on_training_start(self):
            start.append(time.perf_counter())

        def _on_step(self):
            return True

    model.learn(steps, callback=Clock())
    wall = time.perf_counter() - start[0]
    model.get_env().close()
    return {'total_steps': int(model.num_timesteps), 'wall_seconds': wall,
            'steps_per_second': model.num_timesteps / wall}


def graph_available() -> bool:
    """Return whether ``python -m pg_node train`` exists in this checkout."""
    return importlib.util.find_spec('pg_node.tools.train') is not None


def run_graph(run_dir: Path, steps: int, seed: int, overrides: Sequence[str] = (),
              timeout: float = 3600.0, log=None) -> Dict:
    """
    Run the training graph (``python -m pg_node train``) and return its ``summary.json``.

    Raises RuntimeError if it fails or writes no summary.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir),
           '--total-steps', str(steps), '--seed', str(seed), '--no-progress', *overrides]
    with open(run_dir / 'bench_train.log', 'w') as out:
        proc = subprocess.Popen(cmd, cwd=REPO, env=child_env(domain_id()), stdout=out,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        try:
            rc = proc.wait(timeout)
        except subprocess.TimeoutExpired:
            stop(proc)
            raise RuntimeError(f'training graph did not finish in {timeout:.0f} s') from None
        except KeyboardInterrupt:
            stop(proc)
            raise
    summary = RunDir(run_dir).read_summary()
    if rc != 0 or summary is None:
        tail = (run_dir / 'bench_train.log').read_text(errors='replace')[-2000:]
        raise RuntimeError(f'{" ".join(cmd)} exited with {rc}:\n{tail}')
    return summary


# --- latency -------------------------------------------------------------------------------

def lock_step_latency(n: int, steps: int, warmup: int = 200, timeout: float = 600.0,
                      ros_args: Sequence[str] = ()) -> Dict:
    """
    Drive :mod:`bench.latency_probe` for ``warmup + steps`` lock-step steps; return stats.

    The client answers every new transition at once with a fixed command tagged as its answer
    (as the actor does, :mod:`pg_node.ros.command`), so what is
    measured is the graph's round trip, not a policy. Returns median/p99/max/mean in ms, the
    number of round trips and the client-side steps/s. ``ros_args`` are added to the
    probe's ``--ros-args`` (e.g. ``-p marker_rate:=0.0``).
    """
    from pg_node.common.run import COMMANDS
    from pg_node.ros import command
    from pg_node.ros.runtime import make_executor
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray
    domain = domain_id()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / 'round_trips.npy'
        proc = subprocess.Popen(
            [sys.executable, '-m', 'bench.latency_probe', str(out), '--ros-args',
             '-p', f'num_envs:={n}', '-p', 'lock_step_groups:=1', *ros_args],
            cwd=REPO, env=child_env(domain), stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL, start_new_session=True)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('bench_latency_client', context=context)
        pub = node.create_publisher(Float64MultiArray, '/' + COMMANDS, 10)
        act = np.full((n, 2), 0.1)
        state = {'count': 0, 'last_seq': None}

        def on_transition(msg):
            seq = msg.data[0]
            if seq == state['last_seq']:
                return  # a re-send after a timeout: already answered
            state['last_seq'] = seq
            state['count'] += 1
            pub.publish(command.to_msg(act, int(seq)))   # the answer to this transition

        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Float64MultiArray, 'pg_node/transition', on_transition, qos)
        # the executor the nodes use (the actor answers with it in training)
        executor = make_executor(context)
        executor.add_node(node)
        try:
            deadline = time.monotonic() + 60
            while not pub.get_subscription_count() or state['count'] == 0:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError('latency probe (sim_node) did not come up')
                executor.spin_once(timeout_sec=0.1)
            # a command published before sim_node's subscription matched may be lost:
            # the lock-step timeout re-sends the transition and the client answers again
            state['last_seq'] = None
            start = time.perf_counter()
            first = state['count']
            deadline = time.monotonic() + timeout
            # one more: the last command may still be on its way when the probe is stopped
            while state['count'] - first < warmup + steps + 1:
                if time.monotonic() > deadline:
                    raise RuntimeError('latency run timed out')
                executor.spin_once(timeout_sec=0.5)
            wall = time.perf_counter() - start
            done = state['count'] - first
        finally:
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=context)
            stop(proc)
        if not out.is_file():
            raise RuntimeError('latency probe wrote no round trips')
        trips = np.load(out)
    ms = trips[warmup:warmup + steps].astype(np.float64) / 1e6
    if ms.size == 0:
        raise RuntimeError('no round trips measured')
    return {'num_envs': n, 'round_trips': int(ms.size), 'median_ms': float(np.median(ms)),
            'p99_ms': float(np.percentile(ms, 99)), 'max_ms': float(ms.max()),
            'mean_ms': float(ms.mean()), 'steps_per_second': done * n / wall,
            'samples_ms': ms}


# --- learning ------------------------------------------------------------------------------

def first_time_at(curve: List[Dict], threshold: float) -> Optional[float]:
    """Return the first ``wall_seconds`` of a curve whose ``episode_return`` >= threshold."""
    for point in curve:
        ret = point.get('episode_return')
        if ret is not None and np.isfinite(ret) and ret >= threshold:
            return float(point['wall_seconds'])
    return None


def value_at(curve: List[Dict], steps: int) -> Optional[float]:
    """Return the curve's ``episode_return`` at the last point with ``env_steps <= steps``."""
    best = None
    for point in curve:
        ret = point['episode_return']        # None: summary.json's null (no episode yet)
        if point['env_steps'] <= steps * 1.0001 and ret is not None and np.isfinite(ret):
            best = float(point['episode_return'])
    return best


def sb3_learning(algo: str, env_id: str, steps: int, seed: int, eval_points: Sequence[int],
                 eval_episodes: int = 20) -> Dict:
    """
    Train SB3 ``algo`` (defaults, 8 envs) on ``env_id``; evaluate at ``eval_points``.

    Evaluations use the deterministic policy on 10 separate environments seeded apart from
    training and their time is left out of ``wall_seconds``. The curve holds, after every
    rollout, the mean return of the last 100 training episodes (SB3's ``ep_info_buffer``).
    """
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy
    model = make_sb3(algo, env_id, seed)
    eval_env = make_vec_env(env_id, n_envs=10, seed=seed + 10_000,
                            env_kwargs={'render_mode': None})
    points = sorted({int(p) for p in eval_points})
    rec = {'curve': [], 'evals': {}, 'eval_time': 0.0}

    class Recorder(BaseCallback):

        def _on_training_start(self):
            rec['t0'] = time.perf_counter()

        def _wall(self):
            return time.perf_counter() - rec['t0'] - rec['eval_time']

        def _on_step(self):
            while points and self.num_timesteps >= points[0]:
                t = time.perf_counter()
                mean, std = evaluate_policy(self.model, eval_env, eval_episodes,
                                            deterministic=True)
                rec['evals'][points.pop(0)] = (float(mean), float(std))
                rec['eval_time'] += time.perf_counter() - t
            return True

        def _on_rollout_end(self):
            buf = self.model.ep_info_buffer
            if buf:
                rec['curve'].append({'env_steps': int(self.num_timesteps),
                                     'wall_seconds': self._wall(),
                                     'episode_return': float(np.mean([e['r'] for e in buf]))})

    model.learn(steps, callback=Recorder())
    wall = time.perf_counter() - rec['t0'] - rec['eval_time']
    for p in points:  # budget ended before a point (rounding to whole rollouts)
        rec['evals'][p] = evaluate_policy(model, eval_env, eval_episodes, deterministic=True)
    model.get_env().close()
    eval_env.close()
    return {'evals': {int(k): float(v[0]) for k, v in rec['evals'].items()},
            'curve': rec['curve'], 'wall_seconds': wall, 'total_steps': int(model.num_timesteps),
            'steps_per_second': model.num_timesteps / wall}


def inprocess_learning(steps: int, seed: int, eval_points: Sequence[int],
                       eval_episodes: int = 100) -> Dict:
    """Train pg_node A2C in-process; deterministic evaluations at ``eval_points``."""
    from pg_node.common.config_files import load_config
    from pg_node.rl import train_inprocess as tip
    from pg_node.rl.evaluate import evaluate_policy
    points = sorted({int(p) for p in eval_points})
    rec = {'curve': [], 'evals': {}, 'eval_time': 0.0}

    def callback(stats):
        rec['curve'].append({'env_steps': stats['env_steps'],
                             'wall_seconds': stats['wall_seconds'] - rec['eval_time'],
                             'episode_return': stats['episode_return']})
        while points and stats['env_steps'] >= points[0]:
            t = time.perf_counter()
            res = evaluate_policy(stats['learner'].policy, 'reacher2', eval_episodes, seed)
            rec['evals'][points.pop(0)] = res['eval_return']
            rec['eval_time'] += time.perf_counter() - t

    summary = tip.train_inprocess(load_config(None, [f'seed={seed}']), steps, callback,
                                  eval_episodes=eval_episodes)
    for p in points:
        rec['evals'][p] = summary['eval_return']
    wall = summary['wall_seconds'] - rec['eval_time']
    return {'evals': rec['evals'], 'curve': rec['curve'], 'wall_seconds': wall,
            'total_steps': summary['total_steps'],
            'steps_per_second': summary['total_steps'] / wall,
            'final_eval': summary['eval_return']}


def graph_learning(run_dir: Path, steps: int, seed: int, eval_points: Sequence[int]) -> Dict:
    """Train through the ROS graph; the final deterministic evaluation and its curve."""
    summary = run_graph(run_dir, steps, seed)
    curve = [dict(p) for p in summary.get('curve', [])]
    return {'evals': {int(steps): float(summary['eval_return'])} if steps in eval_points else {},
            'final_eval': float(summary['eval_return']), 'curve': curve,
            'wall_seconds': float(summary['wall_seconds']),
            'total_steps': int(summary['total_steps']),
            'steps_per_second': float(summary['steps_per_second'])}


# --- profile -------------------------------------------------------------------------------

#: Written as ``sitecustomize.py`` into a directory put first on the children's PYTHONPATH:
#: every ``python -m pg_node...`` process profiles itself with cProfile and writes its stats
#: at exit (after Ctrl-C too), so the nodes are profiled without changing their code.
_PROFILE_HOOK = """
import atexit, cProfile, os, signal, sys
_out = os.environ.get('PG_NODE_PROFILE_DIR')
_argv = getattr(sys, 'orig_argv', [])
_mod = next((a for a in _argv if a.startswith('pg_node')), None)
if _out and _mod:
    _prof = cProfile.Profile()
    if os.environ.get('PG_NODE_PROFILE_ON_SIGNAL'):
        # from SIGUSR1 on (Python runs handlers on the main thread, the one profiled)
        signal.signal(signal.SIGUSR1, lambda *_: _prof.enable())
    else:
        _prof.enable()

    def _dump():
        _prof.disable()
        _prof.dump_stats(os.path.join(_out, f'{_mod}.{os.getpid()}.prof'))
    atexit.register(_dump)
"""

#: what each node's wall time goes to, by the function that spends it (cProfile ``tottime``)
PROFILE_GROUPS = (
    # the events executor waits, takes and deserialises in C++, inside its spin_once
    ('waiting (executor: idle; events executor: also take)',
     ('_rclpy_pybind11.wait', '_rclpy_pybind11.spin_once')),
    ('publish (serialise + DDS write)',
     ('_rclpy_pybind11.publish', '_rclpy_pybind11.rclpy_serialize')),
    ('take (DDS read + deserialise)', ('_rclpy_pybind11.take',)),
    ('message objects (Python)', ('/msg/_',)),
    ('torch', ('torch/', "method 'run_backward'", 'torch._C')),
    ('physics (mj_step, thread-pool waits)', ('mujoco', "'acquire' of '_thread.lock'")),
    ('start-up (imports, loading)', ('importlib', "'marshal.loads'", 'create_dynamic',
                                     'exec_dynamic', '_ctypes.dlopen')),
)


def grouped(stats, top: int = 8) -> Dict:
    """
    Return where a profile's time went: total, :data:`PROFILE_GROUPS` and the top functions.

    ``stats``: a ``pstats.Stats``. Each function's own time (tottime) goes to the first group
    whose keys its file and name hold, the rest to 'other Python'; ``inside``: every pg_node
    function's cumulative seconds by ``file:function``; ``top``: the pg_node functions with
    the most cumulative time.
    """
    total = stats.total_tt
    groups = {g: 0.0 for g, _ in PROFILE_GROUPS}
    for (file, line, func), (_, _, tt, _, _) in stats.stats.items():
        where = f'{file}:{func}'
        for g, keys in PROFILE_GROUPS:
            if any(k in where for k in keys):
                groups[g] += tt
                break
    groups['other Python'] = total - sum(groups.values())
    funcs = sorted(
        ((ct, nc, f'{Path(file).name}:{func}')
         for (file, line, func), (_, nc, _, ct, _) in stats.stats.items()
         if '/pg_node/' in file and func not in ('<module>', 'main', 'run')),
        reverse=True)[:top]
    inside = {}
    for (file, line, func), (_, _, _, ct, _) in stats.stats.items():
        if '/pg_node/' in file:
            key = f'{Path(file).name}:{func}'
            inside[key] = inside.get(key, 0.0) + ct
    return {'total_seconds': total, 'groups': groups, 'inside': inside,
            'top': [{'function': f, 'calls': n, 'cumulative_seconds': c}
                    for c, n, f in funcs]}


def profile_inprocess(steps: int, seed: int = 0, overrides: Sequence[str] = (),
                      top: int = 8, warmup: int = 0) -> Dict:
    """
    Train in one process (``train_inprocess``, no evaluation) under cProfile; return as above.

    The same computation as the graph's (its lock-step reference); ``nodes`` has one entry,
    'in-process'. cProfile sees the calling thread only, as in the graph's processes.
    ``warmup``: profiled from the first update past that many steps on.
    """
    import cProfile
    import pstats
    from pg_node.common.config_files import load_config
    from pg_node.rl.train_inprocess import train_inprocess
    cfg = load_config(None, [f'seed={seed}', *overrides])
    prof = cProfile.Profile()
    found = {'profiled_from_steps': 0}

    def start(progress):
        if not found.get('on') and progress['env_steps'] >= warmup:
            found.update(on=True, profiled_from_steps=int(progress['env_steps']))
            prof.enable()
    if not warmup:
        start({'env_steps': 0})
    try:
        summary = train_inprocess(cfg, steps, start, eval_episodes=1)
    finally:
        prof.disable()
    found.pop('on', None)
    return {'steps': steps, 'overrides': list(overrides), **found,
            'steps_per_second': summary['steps_per_second'],
            'nodes': {'in-process': grouped(pstats.Stats(prof), top)}}


def _children(pid: int) -> List[int]:
    """Return the processes whose parent is ``pid`` (from /proc)."""
    found = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _signal_after(run_dir: Path, warmup: int, found: Dict, done) -> None:
    """Send SIGUSR1 to train's node processes once progress.csv passes ``warmup`` steps."""
    import signal
    run = RunDir(run_dir)
    while not done.wait(0.2):
        row = run.last_progress()
        if row and row['env_steps'] >= warmup:
            for train in _children(os.getpid()):
                for pid in _children(train):
                    os.kill(pid, signal.SIGUSR1)
            found['profiled_from_steps'] = int(row['env_steps'])
            return


def profile_graph(steps: int, seed: int = 0, overrides: Sequence[str] = (),
                  top: int = 8, warmup: int = 0) -> Dict:
    """
    Run the training graph with every node under cProfile; return where each node's time went.

    Per node: total profiled seconds split into :data:`PROFILE_GROUPS` (the rest is
    'other Python'), and the ``top`` pg_node functions by cumulative time. ``warmup``: the
    node processes are profiled from the first update past that many steps on (SIGUSR1 once
    ``progress.csv`` shows it; ``profiled_from_steps`` says where), not from their start.
    """
    import threading
    import pstats
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        hook, prof_dir = tmp / 'hook', tmp / 'prof'
        hook.mkdir()
        prof_dir.mkdir()
        (hook / 'sitecustomize.py').write_text(_PROFILE_HOOK)
        saved = {k: os.environ.get(k) for k in ('PYTHONPATH', 'PG_NODE_PROFILE_DIR',
                                                'PG_NODE_PROFILE_ON_SIGNAL')}
        os.environ['PYTHONPATH'] = os.pathsep.join(
            [str(hook)] + ([saved['PYTHONPATH']] if saved['PYTHONPATH'] else []))
        os.environ['PG_NODE_PROFILE_DIR'] = str(prof_dir)
        found, done = {'profiled_from_steps': 0}, threading.Event()
        if warmup:
            os.environ['PG_NODE_PROFILE_ON_SIGNAL'] = '1'
            threading.Thread(target=_signal_after, args=(tmp / 'run', warmup, found, done),
                             daemon=True).start()
        try:
            summary = run_graph(tmp / 'run', steps, seed, overrides)
        finally:
            done.set()
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        nodes = {}
        for path in sorted(prof_dir.glob('*.prof')):
            module = path.name.rsplit('.', 2)[0]  # pg_node.<node> or pg_node (train)
            name = module.partition('.')[2] or 'train (bring-up, progress)'
            if name.startswith('train') and warmup:
                continue                       # train itself was not signalled
            nodes[name] = grouped(pstats.Stats(str(path)), top)
    return {'steps': steps, 'overrides': list(overrides), **found,
            'steps_per_second': summary['steps_per_second'], 'nodes': nodes}
