"""
``python -m pg_node eval <run dir or checkpoint>``: the deterministic return of a saved policy.

Takes a run directory (its ``checkpoints/``), a directory of policy checkpoints (the newest
valid one is used) or one ``ckpt_*.pt`` file. A directory of the critic's checkpoints
(``<run>/critic``), a ``--model`` whose observation or action size differs from the one the
policy was trained on, and an unreadable file are refused in one line.

``--perturb KEY=VALUE ...`` evaluates on an arm that is not the model, the same for every
episode: ``mass_scale=1.3 gear_scale=0.8 damping_scale=2 latency_steps=2 obs_noise=0.02``
(the keys of :func:`pg_node.common.perturbations.parse_perturbation`). The episodes are the
nominal evaluation's, so the two reports compare episode for episode.

``--engine pybullet`` runs the same episodes with the arm in PyBullet, loaded from the
robot's own URDF (``--urdf``, default: the one ``arm import`` made the model from, named in
its ``pg_import_command``), as :func:`pg_node.rl.evaluate.evaluate_in_pybullet` describes
(docs/sim_to_sim.md); of ``--perturb`` only ``payload=KG`` applies there (a weight at the
fingertip that the gravity compensation does not know, :meth:`PybulletArm.set_payload`).
"""
import argparse
import json
import os
import sys

from pg_node.tools.args import positive_int


def main(argv=None) -> int:
    """Run ``python -m pg_node eval``."""
    parser = argparse.ArgumentParser(prog='python -m pg_node eval',
                                     description='Evaluate a saved policy checkpoint.')
    parser.add_argument('checkpoint', help='a run directory, its checkpoints/ (the newest '
                                           'valid one is used) or a ckpt_*.pt file')
    parser.add_argument('--episodes', type=positive_int, default=100,
                        help='default: %(default)s')
    parser.add_argument('--seed', type=int, default=0, help='default: %(default)s')
    parser.add_argument('--model', help='arm model (default: the one it was trained on)')
    parser.add_argument('--perturb', nargs='+', action='extend', default=[],
                        metavar='KEY=VALUE',
                        help='evaluate on a changed arm: mass_scale, damping_scale, '
                             'frictionloss_scale, armature_scale, gear_scale (or _add, _abs), '
                             'latency_steps, obs_noise, vel_noise, action_noise, target_noise; '
                             'e.g. mass_scale=1.3 latency_steps=2')
    parser.add_argument('--engine', choices=('mujoco', 'pybullet'), default='mujoco',
                        help='the physics engine: MuJoCo on the model, or PyBullet on the '
                             'URDF of the robot (default: %(default)s)')
    parser.add_argument('--urdf', help='with --engine pybullet: the URDF of the robot '
                                       '(default: the one the model was imported from)')
    parser.add_argument('--json', action='store_true', help='print JSON')
    args = parser.parse_args(argv)
    if not os.path.exists(args.checkpoint):  # answered before torch is imported
        print(f'eval: no such file or directory: {args.checkpoint}', file=sys.stderr)
        return 1
    from pg_node.common.perturbations import BadTerm, parse_perturbation
    from pg_node.rl.evaluate import evaluate_policy
    from pg_node.rl.learner import policy_from_checkpoint
    from pg_node.rl.trained_policy import find_checkpoint, PolicySourceError
    try:
        perturbation = parse_perturbation(args.perturb)
    except BadTerm as exc:
        print(f'eval: {exc}', file=sys.stderr)
        return 2
    if args.engine == 'pybullet' and set(perturbation) - {'payload'}:
        print('eval: --perturb is for --engine mujoco (PyBullet is the other arm), but for '
              'payload=KG', file=sys.stderr)
        return 2
    try:
        state, ckpt_file = find_checkpoint(args.checkpoint)
    except PolicySourceError as exc:
        print(f'eval: {exc}', file=sys.stderr)
        return 1
    cfg = state['config']
    model = args.model or cfg['model']
    from pg_node.common.paths import resolve_model
    from pg_node.sim.arm_task import ArmTask
    try:
        # the perturbation checked against this model too (an add below zero)
        task = ArmTask(resolve_model(model), num_envs=1, randomization=perturbation)
    except BadTerm as exc:
        print(f'eval: --perturb: {exc}', file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:
        print(f'eval: --model {model}: {exc}', file=sys.stderr)
        return 2
    sizes = (task.obs_dim, task.act_dim)
    task.close()
    if sizes != (state['obs_dim'], state['act_dim']):
        print(f'eval: --model {model} has {sizes[0]} observations and {sizes[1]} actions; the '
              f'policy was trained on {cfg["model"]} with {state["obs_dim"]} and '
              f'{state["act_dim"]}', file=sys.stderr)
        return 2
    from pg_node.rl.trained_policy import card_control, checkpoint_card
    # the run's control step and, for a position policy, its bounded changes
    control = card_control(checkpoint_card(state, ckpt_file))
    if args.engine == 'pybullet':
        payload = perturbation['payload'].a if 'payload' in perturbation else 0.0
        res = _in_pybullet(args, state, model, task.model, control['frame_skip'],
                           control['position_delta'], payload)
        if res is None:
            return 2
    else:
        res = evaluate_policy(policy_from_checkpoint(state), model, args.episodes, args.seed,
                              perturbation=perturbation, **control)
    res['policy_version'] = int(state['version'])
    res['perturbation'] = {t: s.text() for t, s in perturbation.items()}
    del res['eval_returns'], res['eval_final_distances']
    if args.json:
        print(json.dumps(res))
    else:
        on = (' on an arm with ' + ' '.join(args.perturb)) if args.perturb else ''
        if args.engine == 'pybullet':
            on = (f" in PyBullet ({res['pybullet_urdf']}, step {res['pybullet_timestep']:.3g} s)"
                  + on.replace(' on an arm', ','))
        print(f"policy version {res['policy_version']}{on}: return {res['eval_return']:.2f} "
              f"+/- {res['eval_return_std']:.2f} over {args.episodes} episodes; final "
              f"distance {100 * res['eval_final_distance']:.2f} cm, "
              f"{100 * res['eval_reached']:.0f}% within 2 cm")
        if args.seed == state['config']['seed'] and args.engine == 'mujoco' \
                and not perturbation:
            # train's closing evaluation ran these very episodes (train.evaluate_run)
            print(f'(seed {args.seed}: the episodes train evaluated at its end; --seed N for '
                  'others)')
    return 0


def _in_pybullet(args, state, model: str, mj_model, frame_skip: int, position_delta=None,
                 payload: float = 0.0):
    """Return :func:`evaluate_in_pybullet`'s result, or None after saying why it cannot run."""
    from pg_node.rl.evaluate import evaluate_in_pybullet
    from pg_node.rl.learner import policy_from_checkpoint
    from pg_node.sim.pybullet_arm import PybulletError, robot_urdf
    try:
        urdf = robot_urdf(mj_model, model, args.urdf)
        res = evaluate_in_pybullet(policy_from_checkpoint(state), model, urdf, args.episodes,
                                   args.seed, frame_skip=frame_skip,
                                   position_delta=position_delta, payload=payload)
    except (PybulletError, ValueError) as exc:
        print(f'eval: --engine pybullet: {exc}', file=sys.stderr)
        return None
    for line in res.pop('pybullet_warnings'):
        print(f'eval: PyBullet: {line}', file=sys.stderr)
    res['pybullet_urdf'] = urdf
    return res
