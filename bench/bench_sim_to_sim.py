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
engine, and the same with every joint limit made hard (:func:`mujoco_at`).
``--perturb KEY=VALUE ...`` (``eval --perturb``'s keys) adds a MuJoCo row per policy on that
arm, and a PyBullet row when it is only ``payload=KG`` (the weight PyBullet adds at the
fingertip, :meth:`pg_node.sim.pybullet_arm.PybulletArm.set_payload`).

``--iiwa DIR`` is the iiwa rows of BENCHMARKS.md "Sim-to-sim" in one command: it imports
pybullet_data's KUKA iiwa (:data:`IIWA_IMPORT`, hard limits) into ``DIR``, trains the
nominal policy (``arm7``) and the randomized one (``arm7`` + :data:`IIWA_TERMS`) in
process, ``--steps`` each (a run already in ``DIR`` is kept), and benches both against
the vendor's URDF::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/bench_sim_to_sim.py \
        --iiwa /tmp/iiwa --perturb payload=0.3

Not a test: nothing is asserted. Run nothing else meanwhile (2 cores).
"""
import argparse
from pathlib import Path
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

REPO = Path(__file__).resolve().parent.parent
#: rad: an episode "reaches a limit" when a joint comes this close to it
LIMIT_MARGIN = 0.05
#: ``arm import`` flags of the iiwa (pybullet_data's ``kuka_iiwa/model.urdf``): tip, start
#: pose, goals' ball, and joint limits as hard as the robot's end stops
IIWA_IMPORT = ['--tip', 'lbr_iiwa_link_7', '--home', '0', '0.5', '0', '-1.2', '0', '0.8', '0',
               '--target-region', '0.5', '0', '0.5', '0.3', '--hard-limits']
#: the randomized iiwa's terms: what a torque robot has that its model lacks (joint damping
#: and dry friction a little above the URDF's, a payload the gravity compensation does not
#: know, a dead time up to one control step: bench_ur5.TORQUE_TERMS, the damping added to
#: the URDF's 0.5 N m s/rad instead of replacing it). Not the ``dr`` preset's terms, whose
#: ``latency`` (0-2 whole control steps) kept the iiwa from learning (docs/sim_to_sim.md).
IIWA_TERMS = {'damping': 'add uniform 0 0.1', 'frictionloss': 'abs uniform 0 0.2',
              'payload': 'uniform 0 0.3', 'servo_latency': 'uniform 0 0.04'}
#: the iiwa's control step: 20 physics steps of 2 ms
IIWA_FRAME_SKIP = 20


def iiwa_urdf() -> Path:
    """Return pybullet_data's KUKA iiwa URDF."""
    import pybullet_data
    return Path(pybullet_data.getDataPath()) / 'kuka_iiwa' / 'model.urdf'


def train_iiwa(out: Path, steps: int, seed: int) -> list:
    """Import the iiwa into ``out``, train what is not there yet; return the policies."""
    from pg_node.common.run_dir import RunDir
    out.mkdir(parents=True, exist_ok=True)
    model = (out / 'iiwa.xml').resolve()
    if not model.exists():
        subprocess.run([sys.executable, '-m', 'pg_node', 'arm', 'import', str(iiwa_urdf()),
                        *IIWA_IMPORT, '-o', str(model)], check=True, cwd=REPO)
    policies = []
    for label, terms in (('nominal', {}), ('randomized', IIWA_TERMS)):
        run = (out / label).resolve()
        if not RunDir(run).checkpoints.is_dir():
            subprocess.run([sys.executable, str(REPO / 'bench' / 'train_inprocess.py'), 'arm7',
                            str(steps), f'model={model}', f'frame_skip={IIWA_FRAME_SKIP}',
                            f'seed={seed}',
                            *[f'randomize_{k}={v}' for k, v in terms.items()],
                            '--save', str(run)], check=True, cwd=REPO, stdout=sys.stderr)
        policies.append(f'{label}={run}')
    return policies


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
    parser.add_argument('--policy', action='append', default=[], metavar='LABEL=RUN')
    parser.add_argument('--episodes', type=int, default=100)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--mujoco-timestep', type=float)
    parser.add_argument('--urdf', help="the robot's URDF (default: the one arm import made "
                                       'each model from)')
    parser.add_argument('--perturb', nargs='+', action='extend', default=[],
                        metavar='KEY=VALUE', help="eval --perturb's keys: a MuJoCo row per "
                        'policy, and a PyBullet row for payload=KG alone')
    parser.add_argument('--iiwa', type=Path, metavar='DIR',
                        help='import and train the iiwa into DIR (IIWA_IMPORT, IIWA_TERMS)')
    parser.add_argument('--steps', type=int, default=2_500_000, help='--iiwa: steps per policy')
    args = parser.parse_args()
    from pg_node.common.perturbations import BadTerm, parse_perturbation
    try:
        perturbation = parse_perturbation(args.perturb)
    except BadTerm as exc:
        print(f'bench_sim_to_sim: {exc}', file=sys.stderr)
        return 2
    if args.iiwa:
        args.policy += train_iiwa(args.iiwa, args.steps, args.seed)
        args.urdf = args.urdf or str(iiwa_urdf())
    if not args.policy:
        print('bench_sim_to_sim: give --policy LABEL=RUN or --iiwa DIR', file=sys.stderr)
        return 2
    perturbed = ' '.join(args.perturb)
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
        if perturbation:
            t0 = time.perf_counter()
            res = evaluate_policy(policy, model, args.episodes, args.seed, frame_skip=fs,
                                  perturbation=perturbation)
            rows.append((arm, label, f'MuJoCo + {perturbed}', res, time.perf_counter() - t0))
        if set(perturbation) == {'payload'}:
            t0 = time.perf_counter()
            res = evaluate_in_pybullet(policy, model, urdf, args.episodes, args.seed,
                                       frame_skip=fs, payload=perturbation['payload'].a)
            rows.append((arm, label, f'PyBullet + {perturbed}', res, time.perf_counter() - t0))
        near = limit_episodes(policy, model, args.episodes, args.seed, fs)
        splits.append((arm, label, near, mj, pb))
        print(f'{label}: done', file=sys.stderr, flush=True)
    print('| arm | policy | engine (physics step) | return | final distance (cm) | '
          'within 2 cm | x MuJoCo | wall s |')
    print('|---|---|---|---:|---:|---:|---:|---:|')
    base = {}
    for arm, label, engine, res, wall in rows:
        d = 100 * res['eval_final_distance']
        # x MuJoCo: against the first MuJoCo row on the same arm (perturbed or not)
        on = engine.partition(' + ')[2]
        base.setdefault((arm, label, on), d)
        print(f"| {arm} | {label} | {engine} | {res['eval_return']:.2f} | {d:.2f} | "
              f"{100 * res['eval_reached']:.0f}% | {d / base[(arm, label, on)]:.2f} | "
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
