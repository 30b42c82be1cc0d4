r"""
How much slower ``ArmTask.step`` gets after an idle gap, in one process, with no ROS at all.

Feeds PROFILE.md, "Session of 2026-12-02 12:25 UTC", the table "idle gap before each step"
(64 arms; one stepping thread with the caller spinning through the gap against two threads
with the caller sleeping through it). That table came from ``/tmp/gap2.py``, which this
replaces. In the graph each process sleeps between its turns, so each turn starts cold;
this shows the same slow-down without any messages: before each step the caller waits
``gap`` ms, either spinning on ``time.perf_counter`` (its core stays busy) or in
``time.sleep`` (the core may idle, the stepping thread too), and only the step is timed::

    AMENT_PREFIX_PATH=$PWD/.venv PYTHONPATH=$PWD .venv/bin/python bench/step_after_gap.py \
        [--arms 64] [--steps 600] [--repeats 4] [--gaps 0,0.9,3] [--modes spin1,sleep2]

A mode is ``spin`` or ``sleep`` followed by the number of stepping threads (``spin1``,
``spin2``, ``sleep1``, ``sleep2``). The task is the default parameters' (model, frame skip,
episode length); actions are drawn uniformly in the control range once, the same for every
mode. Each repeat runs every mode and gap in turn, ``--steps`` steps each, and takes the
median step time; the table gives, per mode and gap, the range of those medians over the
repeats and their median. Not a test: nothing is asserted. Run nothing else meanwhile.
"""
import argparse
from pathlib import Path
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

MODES = {'spin1': ('spin', 1), 'spin2': ('spin', 2), 'sleep1': ('sleep', 1),
         'sleep2': ('sleep', 2)}
DESCRIBE = {'spin': 'the caller spinning through the gap',
            'sleep': 'the caller sleeping through the gap'}


def make_task(arms: int, threads: int):
    """Return an ArmTask of the default parameters with ``threads`` stepping threads."""
    from pg_node.common.config_files import load_config
    from pg_node.common.paths import resolve_model
    from pg_node.sim.arm_task import ArmTask
    cfg = load_config()
    sim = cfg['sim_node']
    task = ArmTask(resolve_model(cfg['/**']['model']), num_envs=arms, seed=0,
                   frame_skip=sim['frame_skip'], max_episode_steps=sim['max_episode_steps'],
                   num_threads=threads)
    task.reset()
    return task


def step_times(task, actions, gap_s: float, wait: str):
    """Step through ``actions``, waiting ``gap_s`` before each step; return each step's s."""
    clock = time.perf_counter
    out = []
    for act in actions:
        if gap_s > 0:
            if wait == 'spin':
                end = clock() + gap_s
                while clock() < end:
                    pass
            else:
                time.sleep(gap_s)
        t0 = clock()
        task.step(act)
        out.append(clock() - t0)
    return out


def main(argv=None) -> int:
    """Run the repeats; print one markdown row per mode."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--arms', type=int, default=64)
    parser.add_argument('--steps', type=int, default=600, help='steps per mode, gap, repeat')
    parser.add_argument('--repeats', type=int, default=4)
    parser.add_argument('--gaps', default='0,0.9,3', help='idle gaps before each step, ms')
    parser.add_argument('--modes', default='spin1,sleep2',
                        help=f'comma-separated, of {", ".join(MODES)}')
    args = parser.parse_args(argv)
    gaps = [float(g) for g in args.gaps.split(',')]
    modes = args.modes.split(',')
    unknown = [m for m in modes if m not in MODES]
    if unknown:
        parser.error(f'unknown mode(s) {", ".join(unknown)}; known: {", ".join(MODES)}')
    tasks = {n: make_task(args.arms, n) for n in sorted({MODES[m][1] for m in modes})}
    try:
        any_task = next(iter(tasks.values()))
        lo, hi = any_task.spec.ctrl_low, any_task.spec.ctrl_high
        actions = np.random.default_rng(0).uniform(lo, hi, (args.steps, args.arms, len(lo)))
        for task in tasks.values():                 # warm up: caches, the thread pool
            step_times(task, actions[:50], 0.0, 'spin')
        medians = {(m, g): [] for m in modes for g in gaps}
        for _ in range(args.repeats):
            for m in modes:
                wait, threads = MODES[m]
                for g in gaps:
                    times = step_times(tasks[threads], actions, g / 1e3, wait)
                    medians[m, g].append(1e3 * statistics.median(times))
    finally:
        for task in tasks.values():
            task.close()
    print(f'ArmTask.step of {args.arms} arms, median ms of {args.steps} steps, '
          f"{args.repeats} repeats: the repeats' range (their median)")
    print()
    print('| idle gap before each step | ' + ' | '.join(f'{g:g} ms' for g in gaps) + ' |')
    print('|---|' + '---|' * len(gaps))
    for m in modes:
        wait, threads = MODES[m]
        cells = [f'{min(v):.2f}-{max(v):.2f} ({statistics.median(v):.2f})'
                 for v in (medians[m, g] for g in gaps)]
        label = f"{threads} thread{'s' if threads > 1 else ''}, {DESCRIBE[wait]}"
        print(f'| {label} | ' + ' | '.join(cells) + ' |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
