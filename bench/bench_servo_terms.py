"""
Benchmark: what the per-physics-step randomization terms cost the simulated arm (issue 46).

Run from the repository root (as the Makefile sets the environment)::

    AMENT_PREFIX_PATH=$PWD/.venv PYTHONPATH=$PWD .venv/bin/python bench/bench_servo_terms.py

64 arms of ``reacher2`` and of ``arm7`` (frame_skip 2), one thread, 200 control steps of
uniform random commands through ``ArmTask.step``, with no term, with ``latency`` (applied
once per control step) and with ``servo_bandwidth``, ``servo_latency`` and ``payload``
(applied at every physics step, from Python: ``Randomizer.physics_steps``). Prints arm
control steps per second. Not a test: nothing is asserted.
"""
import time

import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmTask

CASES = [('nominal', {}), ('latency', {'latency': 'uniform 0 2'}),
         ('servo + payload', {'servo_bandwidth': 'uniform 2 20',
                              'servo_latency': 'uniform 0 0.02', 'payload': 'uniform 0 0.5'})]


def main(arms: int = 64, steps: int = 200) -> None:
    """Print one row per model and case: arm control steps per second."""
    print(f'| model | terms | arm steps/s ({arms} arms, {steps} steps, 1 thread) |')
    print('|---|---|---:|')
    for name in ('reacher2', 'arm7'):
        for label, terms in CASES:
            task = ArmTask(resolve_model(name), num_envs=arms, seed=0, frame_skip=2,
                           randomization=terms, num_threads=1)
            task.reset()
            act = np.random.default_rng(0).uniform(-1, 1, (steps, arms, task.act_dim))
            t0 = time.perf_counter()
            for k in range(steps):
                task.step(act[k])
            seconds = time.perf_counter() - t0
            task.close()
            print(f'| {name} | {label} | {steps * arms / seconds:,.0f} |')


if __name__ == '__main__':
    main()
