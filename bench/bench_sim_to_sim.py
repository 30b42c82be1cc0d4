r"""
Benchmark: sim-to-sim, a policy in MuJoCo (its training model) and in PyBullet (the URDF).

For each ``--policy LABEL=RUN`` (a run directory with ``checkpoints/``, trained on a model
``arm import`` made from a URDF), the same ``--episodes`` episodes as ``eval`` in both
engines (:func:`pg_node.rl.evaluate.evaluate_policy` and
:func:`pg_node.rl.evaluate.evaluate_in_pybullet`), and a Markdown table: policy x engine
-> mean return, mean final distance (cm), share within 2 cm, and the ratio of the final
distances (PyBullet / MuJoCo)::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/bench_sim_to_sim.py \
        --policy nominal=/tmp/p45/tl_nom --policy randomized=/tmp/p45/tl_dr [--episodes 100]

A second table splits each policy's episodes by whether its arm comes within
``LIMIT_MARGIN`` rad of a joint limit in MuJoCo (stepped physics step by physics step): the
engines model a limit differently (MuJoCo a soft constraint the arm sinks into and springs
back from, PyBullet a hard one), and a policy that leans on the limit meets another arm.

``--mujoco-timestep DT`` adds two rows per policy: MuJoCo at a shorter physics step (the
control period kept), to tell the training model's integration error apart from the other
engine, and the same with every joint limit made hard (:func:`mujoco_at`). Not a test:
nothing is asserted. Run nothing else meanwhile (2 cores).
"""
import argparse
from pathlib import Path
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

#: rad: an episode "reaches a limit" when a joint comes this close to it
LIMIT_MARGIN = 0.05


def limit_episodes(policy, model: str, episodes: int, seed: int, frame_skip: int):
    """Return, per episode of ``eval``, whether a limited joint came near its limit."""
    import numpy as np
    from pg_node.rl.evaluate import EVAL_SEED_OFFSET
    from pg_node.sim.arm_task import ArmTask
    import torch
    task = ArmTask(model, num_envs=episodes, seed=seed + EVAL_SEED_OFFSET, frame_skip=1,
                   max_episode_steps=None)
    s = task.spec
    low = np.where(s.joint_limited, s.joint_range[:, 0] + LIMIT_MARGIN, -np.inf)
    high = np.where(s.joint_limited, s.joint_range[:, 1] - LIMIT_MARGIN, np.inf)
    near = np.zeros(episodes, dtype=bool)
    obs = task.reset()
    for _ in range(50):
        with torch.no_grad():
            act = policy.mean_action(torch.as_tensor(obs, dtype=torch.float32)).numpy()
        act = np.clip(act.astype(np.float64), s.ctrl_low, s.ctrl_high)
        for _ in range(frame_skip):
            obs = task.step(act)[0]
            q = task.joint_state()[0]
            near |= np.any((q < low) | (q > high), axis=1)
    task.close()
    return near


def mujoco_at(model_path: str, timestep: float, out_dir: Path, hard_limits: bool = False
              ) -> str:
    """
    Return a copy of the model with physics step ``timestep`` (its meshes' paths kept).

    ``hard_limits``: every joint limit as stiff as MuJoCo makes one (``solreflimit`` time
    constant 2 x ``timestep``, critically damped; the default is 0.02 s).
    """
    import mujoco
    spec = mujoco.MjSpec.from_file(model_path)
    spec.option.timestep = timestep
    if hard_limits:
        for joint in spec.joints:
            joint.solref_limit = [2 * timestep, 1.0]
    tag = '_hard' if hard_limits else ''
    out = out_dir / f'{Path(model_path).stem}_dt{timestep:g}{tag}.xml'
    out.write_text(spec.to_xml())
    return str(out)


def main() -> int:
    """Evaluate every policy in both engines and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--policy', action='append', required=True, metavar='LABEL=RUN')
    parser.add_argument('--episodes', type=int, default=100)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--mujoco-timestep', type=float)
    parser.add_argument('--urdf', help="the robot's URDF (default: the one arm import made "
                                       'each model from)')
    args = parser.parse_args()
    from pg_node.common.paths import resolve_model
    from pg_node.rl.evaluate import evaluate_in_pybullet, evaluate_policy
    from pg_node.rl.learner import policy_from_checkpoint
    from pg_node.rl.trained_policy import checkpoint_card, find_checkpoint
    from pg_node.sim.arm_task import ArmTask
    from pg_node.sim.pybullet_arm import model_urdf
    rows, splits = [], []
    scratch = Path(tempfile.mkdtemp(prefix='sim_to_sim_'))
    for item in args.policy:
        label, _, run = item.partition('=')
        state, file = find_checkpoint(run)
        card = checkpoint_card(state, file)
        model = str(resolve_model(state['config']['model']))
        task = ArmTask(model)
        urdf = args.urdf or model_urdf(task.model)
        task.close()
        policy = policy_from_checkpoint(state)
        fs = int(card['frame_skip'])
        arm = Path(model).stem
        t0 = time.perf_counter()
        mj = evaluate_policy(policy, model, args.episodes, args.seed, frame_skip=fs)
        rows.append((arm, label, f'MuJoCo ({card["physics"]["timestep"]:g} s)', mj,
                     time.perf_counter() - t0))
        if args.mujoco_timestep:
            t0 = time.perf_counter()
            factor = round(card['physics']['timestep'] / args.mujoco_timestep)
            fine = evaluate_policy(policy, mujoco_at(model, args.mujoco_timestep, scratch),
                                   args.episodes, args.seed, frame_skip=fs * factor)
            rows.append((arm, label, f'MuJoCo ({args.mujoco_timestep:g} s)', fine,
                         time.perf_counter() - t0))
            t0 = time.perf_counter()
            hard = evaluate_policy(policy, mujoco_at(model, args.mujoco_timestep, scratch, True),
                                   args.episodes, args.seed, frame_skip=fs * factor)
            rows.append((arm, label, f'MuJoCo ({args.mujoco_timestep:g} s, hard limits)', hard,
                         time.perf_counter() - t0))
        t0 = time.perf_counter()
        pb = evaluate_in_pybullet(policy, model, urdf, args.episodes, args.seed, frame_skip=fs)
        rows.append((arm, label, f'PyBullet ({pb["pybullet_timestep"]:.3g} s)', pb,
                     time.perf_counter() - t0))
        near = limit_episodes(policy, model, args.episodes, args.seed, fs)
        splits.append((arm, label, near, mj, pb))
        print(f'{label}: done', file=sys.stderr, flush=True)
    print('| arm | policy | engine (physics step) | return | final distance (cm) | '
          'within 2 cm | x MuJoCo | wall s |')
    print('|---|---|---|---:|---:|---:|---:|---:|')
    base = {}
    for arm, label, engine, res, wall in rows:
        d = 100 * res['eval_final_distance']
        base.setdefault((arm, label), d)
        print(f"| {arm} | {label} | {engine} | {res['eval_return']:.2f} | {d:.2f} | "
              f"{100 * res['eval_reached']:.0f}% | {d / base[(arm, label)]:.2f} | "
              f'{wall:.0f} |')
    import numpy as np
    print()
    print(f'| arm | policy | episodes | near a limit (< {LIMIT_MARGIN:g} rad) in MuJoCo | '
          'MuJoCo final distance (cm) | PyBullet final distance (cm) | episodes > 1 cm apart |')
    print('|---|---|---:|---|---:|---:|---:|')
    for arm, label, near, mj, pb in splits:
        d_mj = 100 * np.array(mj['eval_final_distances'])
        d_pb = 100 * np.array(pb['eval_final_distances'])
        for name, mask in (('yes', near), ('no', ~near)):
            if mask.any():
                print(f'| {arm} | {label} | {mask.sum()} | {name} | {d_mj[mask].mean():.2f} | '
                      f'{d_pb[mask].mean():.2f} | '
                      f'{int(np.sum(np.abs(d_mj - d_pb)[mask] > 1))} |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
