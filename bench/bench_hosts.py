"""
Benchmark: one run on one host and on several (network namespaces), sync and async.

Behind BENCHMARKS.md's multi-host table (issue 29). For each placement it trains
``--steps`` environment steps with ``python -m pg_node train`` and prints one row: steps/s
from the first update to the last (the learner's clock), and the lock-step round trip
(a transition published to the command answering it, every one of the run: ``sim_node``'s
``round_trip_log``): within rollouts as median and p99, and the hand-over at a rollout's
end (the wait for the update, in sync mode) as median. Placements:

* one host, shared memory (Fast DDS's default transports);
* one host, UDP only (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``);
* a learner host and 1 worker host, and a learner host and 2 worker hosts: network
  namespaces on a bridge (:mod:`bench.lan`), UDP only, multicast discovery; one
  simulator/actor pair per worker host (``num_actors`` = worker hosts).

Then what crosses the network per update (the rollout of each worker host in, the weights
to each out, sized from the real messages) and the updates per second that a 1 GbE link
(125 MB/s) would carry at most. Needs root (namespaces)::

    .venv/bin/python bench/bench_hosts.py --steps 100000

The virtual network is this machine's memory: it shows the cost of UDP and of the hosts'
separate DDS participants, not a real LAN's latency. Nothing is asserted.
"""
import argparse
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.lan import dds_env, Lan, unavailable  # noqa: E402
from bench.tax import split_round_trips  # noqa: E402
import numpy as np  # noqa: E402
from pg_node.common.config_files import load_config  # noqa: E402
from pg_node.common.params import defaults, SHARED  # noqa: E402
from pg_node.common.run_dir import RunDir  # noqa: E402
from pg_node.tools import processes  # noqa: E402


def train_args(run_dir, steps, mode, actors, *extra):
    return [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir), '--no-progress',
            '--eval-episodes', '1', '--total-steps', str(steps), f'sync_mode={mode}',
            f'num_actors={actors}', *extra]


def base_env():
    return dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED='1',
                AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))


def trips(paths):
    """
    Return the round trips of the .npy files: within rollouts (p50, p99), hand-overs (p50).

    Within a rollout the actor answers at once; after a rollout's last step it waits for the
    next weights (sync) or sends the rollout first (async): that round trip is the hand-over
    (:func:`bench.tax.split_round_trips`, the first 25 rollouts left out).
    """
    n_steps = defaults('actor_node')['n_steps']
    parts = [split_round_trips(np.load(p), n_steps, skip_rollouts=25)
             for p in paths if Path(p).is_file()]
    inside = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
    ends = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
    if not inside.size:
        return None, None, None
    return (float(np.median(inside)), float(np.percentile(inside, 99)),
            float(np.median(ends)) if ends.size else None)


def one_host(tmp, steps, mode, shm):
    log = tmp / 'trips.npy'
    env = base_env() if shm else dds_env(base_env(), discovery='LOCALHOST')
    done = subprocess.run(train_args(tmp / 'run', steps, mode, 1,
                                     f'sim_node.round_trip_log={log}'),
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        raise RuntimeError(done.stdout[-2000:] + done.stderr[-2000:])
    summary = RunDir(tmp / 'run').read_summary()
    return summary['steps_per_second'], trips([log])


def several_hosts(tmp, steps, mode, workers):
    with Lan(1 + workers) as lan:
        env = dds_env(base_env())
        learner = lan.hosts[0].popen(
            train_args(tmp / 'learner', steps, mode, workers, '--part', 'learner',
                       '--run-id', 'bench'), tmp / 'learner.out', env)
        for i, host in enumerate(lan.hosts[1:]):
            host.popen(train_args(tmp / f'w{i}', steps, mode, workers, '--part', 'workers',
                                  '--actors', str(i), '--run-id', 'bench',
                                  f'sim_node.round_trip_log={tmp / f"trips{i}.npy"}'),
                       tmp / f'w{i}.out', env)
        while learner.poll() is None:
            failed = [p for p in lan.procs[1:] if p.poll() not in (None, 0)]
            if failed:                     # a worker host refused or died: say why
                raise RuntimeError(Path(failed[0].log.name).read_text()[-3000:])
            time.sleep(0.5)
        for proc in lan.procs[1:]:
            proc.wait(120)                 # the worker hosts end by themselves
        if learner.returncode != 0:
            raise RuntimeError((tmp / 'learner.out').read_text()[-3000:])
    summary = RunDir(tmp / 'learner').read_summary()
    return summary['steps_per_second'], trips([tmp / f'trips{i}.npy' for i in range(workers)])


def bytes_per_update(workers: int) -> dict:
    """Return the bytes of one rollout and one weights message, and what crosses per update."""
    from pg_node.rl.learner import make_policy
    from pg_node.rl.rollout_buffer import RolloutArrays
    from pg_node.rl.weights import flatten_state
    from pg_node.ros import messages, table_msg
    cfg = load_config(None)
    n, t = cfg[SHARED]['num_envs'], cfg['actor_node']['n_steps']
    obs, act = 10, 2                                       # reacher2
    z = np.zeros((t, n))
    ro = RolloutArrays(obs=np.zeros((t, n, obs)), act=np.zeros((t, n, act)), logp=z, rew=z,
                       terminated=z.astype(bool), truncated=z.astype(bool),
                       final_obs=np.zeros((t, n, obs)), ep_step=z.astype(int),
                       episode_id=z.astype(int), seq=z.astype(int))
    rollout = len(table_msg.to_cdr(*messages.pack_rollout(ro, 0, 0, 0)))
    policy = make_policy(obs, act, {**cfg['learner_node'], **cfg['actor_node']})
    weights = len(table_msg.to_cdr(*messages.pack_weights(*flatten_state(policy), 0, 0)))
    return {'rollout': rollout, 'weights': weights, 'per_update': workers * (rollout + weights)}


def main():
    """Train once per placement and mode; print the table and the bytes per update."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[1])
    parser.add_argument('--steps', type=int, default=100_000)
    args = parser.parse_args()
    why = unavailable()
    if why is not None:
        print(f'bench_hosts: {why}', file=sys.stderr)
        return 2
    with processes.terminate_as_interrupt():     # SIGTERM too: the namespaces go
        return table(args.steps)


def table(steps: int) -> int:
    """Print the table of every placement and mode, then the bytes per update."""
    placements = [('one host, shared memory', lambda tmp, m: one_host(tmp, steps, m, True)),
                  ('one host, UDP only', lambda tmp, m: one_host(tmp, steps, m, False)),
                  ('learner + 1 worker host, UDP',
                   lambda tmp, m: several_hosts(tmp, steps, m, 1)),
                  ('learner + 2 worker hosts, UDP',
                   lambda tmp, m: several_hosts(tmp, steps, m, 2))]
    print(f'{steps} steps a run, 64 arms per simulator, reacher2\n')
    print('| placement | mode | steps/s | round trip within rollouts p50 / p99 (ms) | '
          'hand-over p50 (ms) |')
    print('|---|---|---|---|---|')
    for name, run in placements:
        for mode in ('sync', 'async'):
            with tempfile.TemporaryDirectory() as tmp:
                rate, (p50, p99, hand) = run(Path(tmp), mode)
            trip = '-' if p50 is None else f'{p50:.2f} / {p99:.2f}'
            over = '-' if hand is None else f'{hand:.2f}'
            print(f'| {name} | {mode} | {rate:,.0f} | {trip} | {over} |', flush=True)
    for workers in (1, 2):
        size = bytes_per_update(workers)
        print(f'\n{workers} worker host(s): per update {size["per_update"] / 1e3:.1f} kB cross '
              f'the network (each worker host: its rollout {size["rollout"] / 1e3:.1f} kB out, '
              f'the weights {size["weights"] / 1e3:.1f} kB in); 1 GbE (125 MB/s) carries at '
              f'most {125e6 / size["per_update"]:,.0f} updates/s '
              f'= {125e6 / size["per_update"] * 512 * workers:,.0f} steps/s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
