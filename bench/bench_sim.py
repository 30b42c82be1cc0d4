"""
Benchmark: control steps per second of the simulated arm, 1, 16 and 64 arms.

Run from the repository root (as the Makefile sets the environment)::

    AMENT_PREFIX_PATH=$PWD/.venv PYTHONPATH=$PWD .venv/bin/python bench/bench_sim.py

Rows, for ``reacher2`` with 2 physics steps per control step:

* ``mj_step loop``: ``mj_step(m, d, nstep=2)`` over a list of ``MjData``;
* ``mj_step threads``: the same loop split over 2 threads (``mj_step`` drops the GIL);
* ``rollout 1 thread`` / ``rollout 2 threads``: one ``mujoco.rollout`` call per control
  step for all arms (state in, state out);
* ``ArmTask.step``: the task in-process (stepping, observation, reward, auto-reset);
* ``gym Reacher-v5`` / ``gym pg_node/Reacher2-v0``: one Gymnasium env, for comparison;
* ``sim_node lock-step``: ``python -m pg_node.ros.sim_node`` as a process and a minimal
  client here that answers every transition with a command (one DDS round trip per step).

``arm steps/s`` counts one arm advanced by one control step; ``batch steps/s`` counts
calls (for N arms, ``arm steps/s = N * batch steps/s``). Not a test: nothing is asserted.
"""
import argparse
from concurrent.futures import ThreadPoolExecutor
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import mujoco
import mujoco.rollout
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from pg_node.common.paths import resolve_model  # noqa: E402
from pg_node.sim.arm_task import ArmTask  # noqa: E402

FRAME_SKIP = 2


def rate(step, seconds):
    """Call ``step`` for about ``seconds`` and return calls per second."""
    step()
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        step()
        count += 1
    return count / (time.perf_counter() - start)


def plain_mujoco(model, n, seconds):
    """Yield ``(name, batch steps/s)`` for the raw MuJoCo ways of stepping ``n`` arms."""
    datas = [mujoco.MjData(model) for _ in range(n)]
    act = np.random.default_rng(0).uniform(-1, 1, (n, model.nu))

    def advance(envs):
        for i in envs:
            datas[i].ctrl[:] = act[i]
            mujoco.mj_step(model, datas[i], nstep=FRAME_SKIP)

    yield 'mj_step loop', rate(lambda: advance(range(n)), seconds)
    if n > 1:
        with ThreadPoolExecutor(2) as pool:
            halves = [range(0, n // 2), range(n // 2, n)]
            yield 'mj_step threads', rate(lambda: list(pool.map(advance, halves)), seconds)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.zeros((n, mujoco.mj_stateSize(model, spec)))
    for i, d in enumerate(datas):
        mujoco.mj_getState(model, d, state[i], spec)
    control = np.repeat(act[:, None, :], FRAME_SKIP, axis=1)
    for threads in (1, 2):
        workers = [mujoco.MjData(model) for _ in range(threads)]
        with mujoco.rollout.Rollout(nthread=threads) as roller:
            def roll():
                out, _ = roller.rollout(model, workers, state, control, nstep=FRAME_SKIP)
                state[:] = out[:, -1]
            yield f'rollout {threads} thread{"s" if threads > 1 else ""}', rate(roll, seconds)


def in_process(n, seconds):
    """Yield ``(name, batch steps/s)`` for ArmTask and, with one arm, the Gymnasium envs."""
    task = ArmTask(resolve_model('reacher2'), num_envs=n, seed=0)
    task.reset()
    acts = np.random.default_rng(0).uniform(-1, 1, (64, n, 2))
    k = iter(range(10**12))
    yield (f'ArmTask.step ({task.num_threads} thread{"s" if task.num_threads > 1 else ""})',
           rate(lambda: task.step(acts[next(k) % 64]), seconds))
    task.close()
    if n == 1:
        import gymnasium as gym
        import pg_node.sim.gym_env  # noqa: F401
        for env_id in ('Reacher-v5', 'pg_node/Reacher2-v0'):
            env = gym.make(env_id)
            env.reset(seed=0)
            action = np.zeros(2)

            def gym_step():
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset()
            yield f'gym {env_id}', rate(gym_step, seconds)


def through_node(n, seconds, domain_id):
    """Return lock-step batch steps/s of sim_node driven by a minimal client."""
    from pg_node.common.run import COMMANDS
    from pg_node.ros import command
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [sys.executable, '-m', 'pg_node.ros.sim_node', '--ros-args', '-p', f'num_envs:={n}',
         '-p', 'lock_step_groups:=1'],                  # one transition per step
        env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        start_new_session=True)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('bench_client', context=context)
    pub = node.create_publisher(Float64MultiArray, '/' + COMMANDS, 10)
    act = np.full((n, 2), 0.1)
    count = [0]

    def on_transition(msg):
        count[0] += 1
        pub.publish(command.to_msg(act, int(msg.data[0])))   # the answer to this transition

    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(Float64MultiArray, '/pg_node/transition', on_transition, qos)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 30
        while not (count[0] > 20 and pub.get_subscription_count()):
            if time.monotonic() > deadline:
                raise RuntimeError('sim_node did not answer')
            executor.spin_once(timeout_sec=0.1)
            if count[0] and not pub.get_subscription_count():
                count[0] = 0
        start_count, start = count[0], time.perf_counter()
        while time.perf_counter() - start < seconds:
            executor.spin_once(timeout_sec=0.1)
        return (count[0] - start_count) / (time.perf_counter() - start)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if proc.poll() is not None:
                break
            proc.send_signal(sig)
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                pass


def main():
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--arms', type=int, nargs='+', default=[1, 16, 64])
    parser.add_argument('--seconds', type=float, default=2.0)
    parser.add_argument('--no-node', action='store_true', help='skip the sim_node rows')
    args = parser.parse_args()
    model = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))
    domain_id = 200 + os.getpid() % 30
    print(f'{"arms":>4}  {"way":<30} {"batch steps/s":>14} {"arm steps/s":>12}')
    for n in args.arms:
        rows = list(plain_mujoco(model, n, args.seconds)) + list(in_process(n, args.seconds))
        if not args.no_node:
            rows.append(('sim_node lock-step', through_node(n, args.seconds, domain_id)))
        for name, batches in rows:
            arms = n if name.startswith(('mj_step', 'rollout', 'ArmTask', 'sim_node')) else 1
            print(f'{n:>4}  {name:<30} {batches:>14,.0f} {batches * arms:>12,.0f}',
                  flush=True)


if __name__ == '__main__':
    main()
