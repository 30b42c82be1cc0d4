r"""
How far a trained position policy's targets lie from where the joints are (issue 46).

A position servo on a real arm takes a target and drives the joint there; a target far from
the joint's angle is a jump its driver refuses or turns into a protective stop. A UR
e-Series driver ignores a target more than 0.04 rad from the previous one within its 2 ms
cycle (20 rad/s, Universal_Robots_Client_Library c5d1e26,
``resources/external_control.urscript``:96,143-147), and 3.15 rad/s, the UR5's velocity
limit, is 0.126 rad per 0.04 s control step. This script runs a run's policy
deterministically in MuJoCo (the episodes of ``eval``: 100, seed 0) and prints, per control
step, how far each commanded target (rad) lies from the joint's measured angle and from the
previous step's target: the largest, the 99th percentile and the share of commands beyond
0.04 and 0.126 rad (1e-9 rad of rounding allowed: a full change is exactly the delta). A
policy of bounded changes (``max_position_delta`` in its card) keeps each target within its
delta of the angle measured by construction, not of the previous target; an absolute one
keeps neither::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/position_jumps.py RUN_DIR \
        [--episodes 100] [--seed 0]

Not a test: nothing is asserted.
"""
import argparse
from pathlib import Path
import sys

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

#: rad: a UR e-Series driver's largest change per 2 ms cycle, the UR5's speed x 0.04 s
LIMITS = (0.04, 0.126)


def jumps(targets: np.ndarray, q: np.ndarray) -> dict:
    """
    Return the statistics of ``targets`` and ``q`` ``(steps, episodes, joints)``, rad.

    ``from_q``: ``|target - q|`` at each step; ``step``: ``|target_t - target_(t-1)|``.

    >>> t = np.array([[[0.0]], [[0.1]], [[0.1]]]); q = np.zeros((3, 1, 1))
    >>> r = jumps(t, q)
    >>> round(r['from_q']['max'], 3), round(r['step']['max'], 3), r['step']['beyond'][0]
    (0.1, 0.1, 0.5)
    """
    out = {}
    for name, x in (('from_q', np.abs(targets - q)),
                    ('step', np.abs(np.diff(targets, axis=0)))):
        out[name] = {'max': float(x.max()), 'p99': float(np.percentile(x, 99)),
                     'beyond': [float(np.mean(x > limit + 1e-9)) for limit in LIMITS]}
    return out


def main() -> int:
    """Run the policy, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('run', help='a run directory, its checkpoints/ or a ckpt_*.pt file')
    parser.add_argument('--episodes', type=int, default=100)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    import torch
    from pg_node.common.paths import resolve_model
    from pg_node.control import position_delta
    from pg_node.control.interfaces import INTERFACES
    from pg_node.rl.evaluate import EVAL_SEED_OFFSET
    from pg_node.rl.learner import policy_from_checkpoint
    from pg_node.rl.trained_policy import card_position_delta, checkpoint_card, find_checkpoint
    from pg_node.sim.actuation import actuators
    from pg_node.sim.arm_task import ArmTask
    state, file = find_checkpoint(args.run)
    card = checkpoint_card(state, file)
    delta = card_position_delta(card)
    policy = policy_from_checkpoint(state)
    task = ArmTask(resolve_model(state['config']['model']), num_envs=args.episodes,
                   seed=args.seed + EVAL_SEED_OFFSET, frame_skip=int(card['frame_skip']),
                   position_delta=delta)
    servo, act = INTERFACES['position'], actuators(task.model)
    low, high = servo.si_range(act)
    obs = task.reset()
    targets, angles = [], []
    with torch.no_grad():
        for _ in range(task.max_episode_steps):
            u = policy.mean_action(torch.as_tensor(obs, dtype=torch.float32)).numpy()
            u = np.clip(u.astype(np.float64), task.spec.ctrl_low, task.spec.ctrl_high)
            q = task.joint_state()[0]
            if task.position_delta is not None:
                target = position_delta.targets(u, q, task.position_delta, low, high)
            else:
                target = servo.to_si(act, u)
            targets.append(target)
            angles.append(q)
            obs = task.step(u)[0]
    task.close()
    r = jumps(np.array(targets), np.array(angles))
    kind = (f'bounded changes of {np.max(task.position_delta):g} rad' if delta
            else 'absolute targets')
    print(f'{file} ({kind}), {args.episodes} episodes x {task.max_episode_steps} steps')
    print('| rad | largest | 99th percentile | beyond 0.04 rad | beyond 0.126 rad |')
    print('|---|---:|---:|---:|---:|')
    for name, what in (('from_q', 'target - measured angle'),
                       ('step', 'target - previous target')):
        s = r[name]
        print(f"| {what} | {s['max']:.3f} | {s['p99']:.3f} | {100 * s['beyond'][0]:.2f}% | "
              f"{100 * s['beyond'][1]:.2f}% |")
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
