"""
Benchmark probe: time stamps at the lock-step loop's and the hand-over's points, per process.

Behind PROFILE.md's "Session of 2026-12-02 08:30 UTC" tables. Not part of the package: the
stamps are written into a *separate checkout* of the code, so nothing of it runs in a normal
training. ``apply`` patches a checkout (a git worktree); a training run from it with
``PROBE_DIR`` set writes each process's stamps there (``CLOCK_MONOTONIC``, shared by all
processes of the machine) when it exits; ``report`` reads them::

    git worktree add /tmp/trace HEAD
    .venv/bin/python bench/trace_points.py apply /tmp/trace
    mkdir /tmp/stamps /tmp/stamps_ip
    # then from /tmp/trace, with PYTHONPATH=/tmp/trace and AMENT_PREFIX_PATH=<the .venv>:
    # PROBE_DIR=/tmp/stamps python -m pg_node train --total-steps 300000 --no-progress
    # PROBE_DIR=/tmp/stamps_ip python -c 'from bench.tax import *;
    #     inprocess_rate(300000)'
    .venv/bin/python bench/trace_points.py report /tmp/stamps /tmp/stamps_ip

Prints the hand-over chain (actor sends the rollout ... the simulator has the first command
of the next), the simulator's work and round trip by step of the rollout, its work piece
by piece, ArmTask.step's two stepping threads by step of the rollout, and the same pieces
of the in-process loop. Nothing is asserted.
"""
import argparse
import collections
from pathlib import Path
import statistics
import sys

STAMPS = """import atexit
import os
import time

EV = []


def mark(name):
    EV.append((name, time.monotonic_ns()))


def _dump():
    where = os.environ.get('PROBE_DIR')
    if where:
        with open(f'{where}/probe_{os.getpid()}.txt', 'w') as f:
            f.writelines(f'{n} {t}\\n' for n, t in EV)


atexit.register(_dump)
"""

_STEP = ('        obs, reward, terminated, truncated, info = '
         'self.task.step(self.held[arms], arms)\n')
_LEARN = '        stats = self.learner.learn(batch.obs, batch.act, batch.logp, batch.adv)\n'
_SEND = '        self.pub_transition.publish(self.last_transitions[g])\n'
_IP_STEP = '                obs, rew, term, trunc, info = task.step(np.clip(act, lo, hi))\n'

#: file -> [(text, the same text with stamps)]; each text must occur once
POINTS = {
    'pg_node/ros/actor_node.py': [
        ('        ro = concat_arms([b.finish() for b in self.bufs])\n',
         "        mark('a_ro0')\n        ro = concat_arms([b.finish() for b in self.bufs])\n"),
        ('        self.pub_rollout.publish(self.last_rollout)\n        self.last_rollout_time',
         "        self.pub_rollout.publish(self.last_rollout)\n        mark('a_ro1')\n"
         '        self.last_rollout_time'),
        ('the awaited one."""\n', 'the awaited one."""\n        mark(\'a_w0\')\n'),
        ('        self.pub_cmd.publish(command.to_cdr(cmd, tr.seq))\n',
         "        self.pub_cmd.publish(command.to_cdr(cmd, tr.seq))\n        mark('a_cmd')\n")],
    'pg_node/ros/critic_node.py': [
        ('annotate once its group is complete."""\n',
         'annotate once its group is complete."""\n        mark(\'c_ro0\')\n'),
        ('        adv, ret, stats = self.critic.judge(ro, policy)\n',
         "        mark('c_j0')\n        adv, ret, stats = self.critic.judge(ro, policy)\n"
         "        mark('c_j1')\n"),
        ('        self.pub_batch.publish(msg)\n        # V learns',
         "        self.pub_batch.publish(msg)\n        mark('c_b1')\n        # V learns"),
        ('        self.last_stats = self.critic.fit(obs, ret)\n',
         "        mark('c_f0')\n        self.last_stats = self.critic.fit(obs, ret)\n"
         "        mark('c_f1')\n")],
    'pg_node/ros/learner_node.py': [
        ('publish, log and checkpoint."""\n',
         'publish, log and checkpoint."""\n        mark(\'l_b0\')\n'),
        (_LEARN, f"        mark('l_l0')\n{_LEARN}        mark('l_l1')\n"),
        ('        self.publish_weights()\n        now_ns = time.time_ns()\n',
         "        self.publish_weights()\n        mark('l_w1')\n"
         '        now_ns = time.time_ns()\n'),
        ("        if self.learner.env_steps >= self.cfg['total_steps']:\n"
         '            self.finish()\n\n    def check_sim',
         "        mark('l_end')\n        if self.learner.env_steps >= self.cfg['total_steps']:\n"
         '            self.finish()\n\n    def check_sim')],
    'pg_node/ros/sim_node.py': [
        (f'{_SEND}        self.last_sent', f"{_SEND}        mark('s_tr')\n        self.last_sent"),
        ("        self.counters['commands_received'] += 1\n",
         "        mark('s_cmd')\n        self.counters['commands_received'] += 1\n"),
        (_STEP, f"        mark('s_st0')\n{_STEP}        mark('s_st1')\n"),
        ('        self.last_transitions[g] = transition.to_cdr(tr)',
         "        mark('s_b0')\n        self.last_transitions[g] = transition.to_cdr(tr)"),
        (_SEND, f"        mark('s_b1')\n{_SEND}")],
    'pg_node/sim/arm_task.py': [
        ('        def advance(envs):\n            for i in envs:\n',
         '        def advance(envs):\n'
         "            w = 'm' if threading.get_ident() == main else 'w'\n"
         "            mark(f'k_{w}0')\n            for i in envs:\n"),
        ('                mujoco.mj_step(m, datas[i], nstep=n)\n\n',
         "                mujoco.mj_step(m, datas[i], nstep=n)\n            mark(f'k_{w}1')\n\n"),
        ('        chunks = self._chunks_of(lo, hi)\n',
         '        main = threading.get_ident()\n        chunks = self._chunks_of(lo, hi)\n'
         "        mark('k_sub')\n"),
        ('        for job in others:\n            job.result()\n',
         "        for job in others:\n            job.result()\n        mark('k_join')\n")],
    'pg_node/rl/train_inprocess.py': [
        ('            ro = buf.finish()\n',
         "            mark('i_b0')\n            ro = buf.finish()\n"),
        ('            adv, ret, c_stats = critic.annotate(ro, policy)\n',
         '            adv, ret, c_stats = critic.annotate(ro, policy)\n'
         "            mark('i_ann')\n"),
        ('            l_stats = learner.learn(ro.obs, ro.act, ro.logp, adv)\n',
         '            l_stats = learner.learn(ro.obs, ro.act, ro.logp, adv)\n'
         "            mark('i_learn')\n"),
        ('            sampler.load(*learner.weights())\n            steps',
         "            sampler.load(*learner.weights())\n            mark('i_load')\n"
         '            steps'),
        (_IP_STEP, f"                mark('i_s0')\n{_IP_STEP}                mark('i_s1')\n")],
}


def apply(tree: Path) -> int:
    """Write the stamps into the checkout ``tree``."""
    if not (tree / '.git').exists() or (tree / 'pg_node' / 'probe_ts.py').exists():
        print(f'{tree}: not a fresh checkout (git worktree add ...)', file=sys.stderr)
        return 2
    for rel, points in POINTS.items():
        path = tree / rel
        text = path.read_text()
        for old, new in points:
            if text.count(old) != 1:
                print(f'{rel}: the point {old.strip()[:60]!r} is not there once: the code '
                      'moved, update POINTS', file=sys.stderr)
                return 2
            text = text.replace(old, new)
        text = text.replace('\nimport numpy as np\n',
                            '\nimport numpy as np\nfrom pg_node.probe_ts import mark\n'
                            'import threading\n', 1)
        path.write_text(text)
    (tree / 'pg_node' / 'probe_ts.py').write_text(STAMPS)
    print(f'stamped {len(POINTS)} files in {tree}')
    return 0


def _events(where: Path):
    ev = []
    for f in where.glob('probe_*.txt'):
        for line in f.read_text().split('\n'):
            if line:
                name, t = line.split()
                ev.append((int(t), name))
    return sorted(ev)


def _ms(values):
    return f'{statistics.median(values):6.2f}' if values else '     -'


def report(graph: Path, inprocess: Path = None, skip: int = 50) -> int:
    """Print the tables of a graph run's stamps (and an in-process run's)."""
    ev = _events(graph)
    order = ['a_ro0', 'a_ro1', 'c_ro0', 'c_j0', 'c_j1', 'c_b1', 'l_b0', 'l_l0', 'l_l1', 'l_w1',
             'a_w0', 'a_cmd', 's_cmd']
    cycles, cur = [], {}
    for t, n in ev:
        if n == 'a_ro0':
            if all(k in cur for k in order):
                cycles.append(cur)
            cur = {'a_ro0': t}
        elif cur and n not in cur:
            cur[n] = t
    cycles = cycles[skip:]
    print(f'hand-over: {len(cycles)} rollouts (first {skip} skipped), median ms')
    for a, b in zip(order[:-1], order[1:]):
        print(f'  {a:6s} -> {b:6s} {_ms([(c[b] - c[a]) / 1e6 for c in cycles])}')
    print(f'  rollout sent -> first command at the simulator '
          f'{_ms([(c["s_cmd"] - c["a_ro0"]) / 1e6 for c in cycles])}')
    for a, b in (('c_b1', 'c_f0'), ('c_f0', 'c_f1'), ('l_w1', 'l_end')):
        print(f'  after it, off the path: {a} -> {b} '
              f'{_ms([(c[b] - c[a]) / 1e6 for c in cycles if a in c and b in c])}')
    work, trip = collections.defaultdict(list), collections.defaultdict(list)
    k, last_tr, last_cmd = None, None, None
    for t, n in ev:
        if n == 'a_w0':
            k = -1
        elif n == 's_cmd' and k is not None:
            k += 1
            if last_tr is not None and k > 0:
                trip[k].append((t - last_tr) / 1e6)
            last_cmd = t
        elif n == 's_tr' and k is not None and last_cmd is not None:
            work[k].append((t - last_cmd) / 1e6)
            last_tr = t
    print('simulator by step of the rollout (0: the first after new weights), median ms')
    print('  step  command -> transition sent   round trip before it')
    for p in sorted(work):
        print(f'  {p:4d}  {_ms(work[p])}                   {_ms(trip.get(p, []))}')
    sim = [(t, n) for t, n in ev if n.startswith('s_')]
    seq = ['s_cmd', 's_st0', 's_st1', 's_b0', 's_b1', 's_tr']
    parts = collections.defaultdict(list)
    for i in range(len(sim) - len(seq) + 1):
        if [n for _, n in sim[i:i + len(seq)]] == seq:
            for (t0, a), (t1, b) in zip(sim[i:i + len(seq)], sim[i + 1:i + len(seq)]):
                parts[f'{a} -> {b}'].append((t1 - t0) / 1e6)
    if parts:
        print('simulator pieces (command in, task.step, build, to_cdr, publish), median ms')
        for name, v in parts.items():
            print(f'  {name:16s} {_ms(v)}')
    _stepping_threads(ev)
    if inprocess is not None:
        ev = _events(inprocess)
        _stepping_threads(ev)
        ev = [(t, n) for t, n in ev if not n.startswith('k_')]
        pairs = collections.defaultdict(list)
        for (t0, a), (t1, b) in zip(ev, ev[1:]):
            pairs[f'{a} -> {b}'].append((t1 - t0) / 1e6)
        print('in-process (i_s0 -> i_s1: task.step; i_s1 -> i_s0: sampling), median ms')
        for name in ('i_s0 -> i_s1', 'i_s1 -> i_s0', 'i_b0 -> i_ann', 'i_ann -> i_learn',
                     'i_learn -> i_load', 'i_load -> i_s0'):
            print(f'  {name:18s} {_ms(pairs.get(name, []))}')
    return 0


def _stepping_threads(ev) -> None:
    """Print ArmTask.step's two threads by step of the rollout: wake-up, chunks, the step."""
    rows = collections.defaultdict(lambda: collections.defaultdict(list))
    names = ('k_m0', 'k_m1', 'k_w0', 'k_w1', 'k_join')
    k, cur = 0, None

    def close():
        if cur and all(n in cur for n in names):
            r = rows[k]
            r['wake'].append(cur['k_w0'] - cur['k_sub'])
            r['main'].append(cur['k_m1'] - cur['k_m0'])
            r['worker'].append(cur['k_w1'] - cur['k_w0'])
            r['step'].append(cur['k_join'] - cur['k_sub'])

    for t, n in ev:
        if n in ('a_w0', 'i_load'):           # new weights: the next step is step 0
            close()
            k, cur = -1, None
        elif n == 'k_sub':
            close()
            k, cur = k + 1, {'k_sub': t}
        elif cur is not None and n in names and n not in cur:
            cur[n] = t
    close()
    if not rows:
        return

    def med_p90(v):
        v = sorted(v)
        return f'{statistics.median(v) / 1e3:5.0f} /{v[int(len(v) * 0.9)] / 1e3:5.0f}'
    print("ArmTask.step by step of the rollout, us, median / p90: the second thread's "
          "wake-up, each thread's envs, the whole")
    print('  step  wake          main          worker        step')
    for p in sorted(rows):
        cells = [med_p90(rows[p][c]) for c in ('wake', 'main', 'worker', 'step')]
        print(f'  {p:4d}  ' + '  '.join(cells))


def main(argv=None) -> int:
    """``apply TREE`` or ``report GRAPH_STAMPS [INPROCESS_STAMPS]``."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[1])
    sub = ap.add_subparsers(dest='cmd', required=True)
    sub.add_parser('apply').add_argument('tree', type=Path)
    rep = sub.add_parser('report')
    rep.add_argument('graph', type=Path)
    rep.add_argument('inprocess', type=Path, nargs='?')
    args = ap.parse_args(argv)
    if args.cmd == 'apply':
        return apply(args.tree)
    return report(args.graph, args.inprocess)


if __name__ == '__main__':
    sys.exit(main())
