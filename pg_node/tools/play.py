"""
``python -m pg_node play RUN``: watch a trained policy act, as it would on a robot.

Starts ``sim_node`` in real-time mode and ``policy_node`` with the policy (a run directory,
a checkpoint or an exported ``.onnx``) as processes, and prints each episode's target, return
and the fingertip's final distance to the target (cm), summed from the simulator's
transitions. Once the policy commands, ``play`` resets the simulator's world
(``~/reset_world``, which re-seeds every arm from ``--seed``) and plays the episodes that begin
there, numbered from 1 by the simulator's ids: the same ``--seed`` plays the same episodes
(targets and start poses) however long the policy took to start. The nodes' logs go to a
temporary folder, removed at the end unless a node failed (``--log-dir`` keeps them). Ctrl-C
stops the nodes; with ``--gif`` a second one skips the drawing. ``--gif out.gif`` draws the first
``--gif-episodes`` episodes of arm 0 with MuJoCo's offscreen renderer, in this process (which
never trains: no torch optimiser runs beside the OpenGL context), from the observations the
simulator published: the angles from ``cos q``/``sin q``, the goal from the target field.

The two nodes run in a namespace of their own (``/play_<pid>``), where ``policy_node``
publishes ``arm_controller/joint_trajectory`` as on a robot (efforts in N m, ramped in from
zero over its ``ramp_time``; ``autostart``, on simulated time) and the simulator, the robot's
stand-in, takes them there as a joint trajectory controller would (``command_interface``
the card's: effort for motors, else the servos' position or velocity;
``arm_controller/commands`` too, for
``command_message:=forward``); and on this machine only
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the environment sets it): a real
controller on the lab network never hears them.

Either stand-in steps its physics the card's ``frame_skip`` times per control step: the
control step the policy was trained with (:func:`robot_argv`).

``--robot pybullet`` puts ``pybullet_node`` in the simulator's place: PyBullet on the robot's
own URDF (``--urdf``, default the one ``arm import`` made the model from), one arm, behind the
same controller topics and on the card's command interface, its ``~/reset_world`` called as
``sim_node``'s (docs/sim_to_sim.md).

``--perturb KEY=VALUE ...`` (the keys of ``eval --perturb``) makes the simulator an arm that
is not the policy's model, as hardware is: ``mass_scale=1.5 gear_scale=0.7
latency_steps=2 obs_noise=0.01`` gives heavier links, weaker motors, commands applied two
control steps late and noisy ``joint_states`` (``sim_node``'s ``randomize_<term>``
parameters, fixed values). The return is the true one; under noise, the final distance is
the one the policy's sensors saw.
"""
import argparse
import os
from pathlib import Path
import re
import shutil
import sys
import tempfile
import time

import numpy as np
from pg_node.control.obs_layout import ObsLayout
from pg_node.tools.args import positive_float, positive_int


def parse_args(argv):
    """Return the parsed command line."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node play',
        description='Run a trained policy on the simulated arm in real time and report it.')
    parser.add_argument('policy', help='a run directory, its checkpoints/, a ckpt_*.pt file or '
                                       'an exported .onnx file')
    parser.add_argument('--episodes', type=positive_int, default=5,
                        help='episodes to play (all arms together; default: %(default)s)')
    parser.add_argument('--arms', type=positive_int, default=1,
                        help='arms in the simulator (default: %(default)s)')
    parser.add_argument('--seed', type=int, default=0,
                        help='simulator seed: the same seed plays the same episodes (default: 0)')
    parser.add_argument('--real-time-factor', type=positive_float, default=1.0,
                        help='simulated seconds per wall second (default: %(default)s)')
    parser.add_argument('--gif', help='write an animation of arm 0 (.gif)')
    parser.add_argument('--gif-episodes', type=positive_int, default=1,
                        help='episodes of arm 0 in the animation (default: %(default)s)')
    parser.add_argument('--perturb', nargs='+', action='extend', default=[],
                        metavar='KEY=VALUE',
                        help='play on an arm that is not the model, e.g. mass_scale=1.5 '
                             'gear_scale=0.7 latency_steps=2 obs_noise=0.01 (the keys of eval '
                             '--perturb)')
    parser.add_argument('--robot', choices=('sim', 'pybullet'), default='sim',
                        help="the robot's stand-in: sim_node (MuJoCo on the model) or "
                             "pybullet_node (PyBullet on the robot's URDF; default: "
                             '%(default)s)')
    parser.add_argument('--urdf', help='with --robot pybullet: the URDF of the robot '
                                       '(default: the one the model was imported from)')
    parser.add_argument('--log-dir', help="where the nodes' logs go (default: a temporary "
                                          'directory)')
    return parser.parse_args(argv)


class Episodes:
    """
    Episode returns and final distances summed from a stream of transitions.

    Only the episodes whose simulator id is at least :attr:`first_id` are played (the ones
    that began at the world reset ``play`` asks for once the policy commands, and after
    it), numbered from 1 by that id: episode ``k`` is the same start (arm, target, pose)
    for the same ``--seed``, whatever the load.
    """

    def __init__(self, obs_layout):
        """Take the observation's :class:`~pg_node.control.obs_layout.ObsLayout`."""
        at = obs_layout.slices
        self.cos, self.sin = at['cos_q'], at['sin_q']
        self.target, self.vec = at['target'], at['fingertip_minus_target']
        self.first_id = None            # the episodes from this simulator id on count
        self.prev = None
        self.running = {}               # episode id -> [return, arm, frames]
        # (number, arm, return, distance, frames), in the order they end; frames
        # [(observation, return so far), ...]
        self.finished = []

    def add(self, tr):
        """Take one transition."""
        prev = self.prev
        if prev is not None and tr.seq != prev.seq + 1:
            self.running.clear()
        if prev is not None:
            for i in range(tr.num_envs):
                ep = int(prev.episode_id[i])
                if ep not in self.running:
                    continue
                entry = self.running[ep]
                entry[0] += float(tr.reward[i])
                if tr.truncated[i] or tr.terminated[i]:
                    del self.running[ep]
                    entry[2].append((tr.final_obs[i], entry[0]))
                    if self.first_id is not None and ep >= self.first_id:
                        dist = float(np.linalg.norm(tr.final_obs[i, self.vec]))
                        self.finished.append((ep - self.first_id + 1, i, entry[0], dist,
                                              entry[2]))
                elif tr.episode_id[i] != ep:
                    del self.running[ep]        # cut short by a world reset
                else:
                    entry[2].append((tr.obs[i], entry[0]))
        for i in range(tr.num_envs):
            if tr.episode_step[i] == 0:
                self.running[int(tr.episode_id[i])] = [0.0, i, [(tr.obs[i], 0.0)]]
        self.prev = tr

    def line(self, done) -> str:
        """Return the console line of a finished episode (distances in cm)."""
        number, arm, ret, dist, frames = done
        target = ', '.join(f'{100 * v:.1f}' for v in frames[0][0][self.target])
        return (f'episode {number:4d} (arm {arm}): target ({target}) cm, return {ret:8.3f}, '
                f'final fingertip distance {100 * dist:.2f} cm')

    def angles(self, obs):
        """Return the joint angles of an observation."""
        return np.arctan2(obs[self.sin], obs[self.cos])


def render_frames(card, frames, episodes, width=400, height=400):
    """Return RGB frames of arm 0's episodes: ``[(obs, return so far), ...]`` per episode."""
    from pg_node.sim.view import draw_pose, framing_camera, use_headless_gl
    use_headless_gl()
    import mujoco
    from pg_node.sim.arm_task import ArmSpec
    from PIL import Image, ImageDraw
    model = mujoco.MjModel.from_xml_string(card['model_xml'])
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    spec = ArmSpec.from_model(model)
    data = mujoco.MjData(model)
    camera = framing_camera(model, spec.target_dim)
    renderer = mujoco.Renderer(model, height=height, width=width)
    out = []
    try:
        for number, (ep, steps, ret) in enumerate(episodes):
            for k, (obs, so_far) in enumerate(steps):
                image = Image.fromarray(draw_pose(renderer, camera, model, data, spec,
                                                  frames.angles(obs), obs[frames.target]))
                draw = ImageDraw.Draw(image)
                dist = float(np.linalg.norm(obs[frames.vec]))
                draw.rectangle([0, height - 40, width, height], fill=(0, 0, 0))
                draw.text((8, height - 36), f'episode {ep} (arm 0)  step {k}/{len(steps) - 1}'
                          f'  t = {k * card["control_step"]:.2f} s', fill=(255, 255, 255))
                draw.text((8, height - 20), f'return {so_far:.2f} of {ret:.2f}  distance '
                          f'{100 * dist:.1f} cm', fill=(255, 255, 255))
                out.append(np.asarray(image))
    finally:
        renderer.close()
    return out


def main(argv=None) -> int:
    """Run ``python -m pg_node play``."""
    args = parse_args(argv)
    if args.gif and Path(args.gif).suffix.lower() != '.gif':
        print(f'play: --gif {args.gif}: the animation is written as .gif', file=sys.stderr)
        return 2
    from pg_node.common.perturbations import BadTerm, parse_perturbation
    try:
        perturbation = parse_perturbation(args.perturb)
    except BadTerm as exc:
        print(f'play: {exc}', file=sys.stderr)
        return 2
    if args.robot == 'pybullet' and (args.perturb or args.arms > 1 or args.gif):
        print('play: --robot pybullet is one arm as it is: no --perturb, --arms or --gif',
              file=sys.stderr)
        return 2
    from pg_node.rl.trained_policy import (find_checkpoint, checkpoint_card, OnnxPolicy,
                                           PolicySourceError)
    source = Path(args.policy).expanduser()
    try:
        if source.suffix == '.onnx':
            if not source.is_file():
                raise PolicySourceError(f'no such file: {source}')
            card = OnnxPolicy(source).card
        else:
            card = checkpoint_card(*find_checkpoint(source))
    except PolicySourceError as exc:
        print(f'play: {exc}', file=sys.stderr)
        return 1
    # the nodes run in the repository folder: every path they are given is absolute
    temporary = args.log_dir is None
    log_dir = Path(args.log_dir or tempfile.mkdtemp(prefix='pg_node_play_')).resolve()
    log_dir.mkdir(parents=True, exist_ok=True)
    keep = True         # a crash keeps the logs
    try:
        code, keep = play(args, card, source, perturbation, log_dir, temporary)
        return code
    finally:
        if temporary and not keep:
            shutil.rmtree(log_dir, ignore_errors=True)


def first_episode(response) -> int:
    """
    Return the first id of the episodes ``sim_node``'s ``~/reset_world`` answered it began.

    >>> from types import SimpleNamespace
    >>> first_episode(SimpleNamespace(success=True, message='new episodes [7, 8]'))
    7
    """
    ids = re.search(r'\[([\d,\s]+)\]', response.message or '')
    if not response.success or ids is None:
        raise RuntimeError(f"sim_node's ~/reset_world answered {response.message!r}")
    return min(int(i) for i in ids.group(1).split(','))


def play(args, card, source: Path, perturbation, log_dir: Path, temporary: bool):
    """Start the nodes, report the episodes, draw the GIF; return (exit code, keep the logs)."""
    model = _model_param(card, log_dir)
    from pg_node.common.paths import resolve_model
    if args.robot == 'pybullet':
        # which URDF pybullet_node would load, asked here: its refusal belongs on the console
        import mujoco
        from pg_node.sim.pybullet_arm import PybulletError, robot_urdf
        try:
            robot_urdf(mujoco.MjModel.from_xml_path(str(resolve_model(model))),
                       card['model'], args.urdf)
        except PybulletError as exc:
            print(f'play: --robot pybullet: {exc}', file=sys.stderr)
            return 2, False
    from pg_node.common.perturbations import BadTerm, PARAM_PREFIX
    if perturbation:
        # a perturbation this arm cannot take (an add below zero) is refused here, not in
        # the simulator's log
        from pg_node.sim.arm_task import ArmTask
        try:
            ArmTask(resolve_model(model), randomization=perturbation).close()
        except BadTerm as exc:
            print(f'play: --perturb: {exc}', file=sys.stderr)
            return 2, False
    perturb_params = [a for term, spec in perturbation.items()
                      for a in ('-p', f'{PARAM_PREFIX}{term}:={spec.text()}')]
    from diagnostic_msgs.msg import DiagnosticArray
    from pg_node.ros import transition
    from pg_node.tools import processes
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import Trigger
    from pg_node.common.run import CONTROLLER_TRAJECTORY
    from trajectory_msgs.msg import JointTrajectory
    from pg_node.tools.train import discovery_env
    os.environ.update(discovery_env(network=False)[0])
    env = processes.child_env()
    namespace = f'/play_{os.getpid()}'
    episodes = Episodes(ObsLayout.from_card(card['observation']['layout']))
    rclpy.init()
    node = rclpy.create_node('pg_node_play', namespace=namespace)
    commands, ready = [], []
    node.create_subscription(JointTrajectory, CONTROLLER_TRAJECTORY,
                             lambda m: commands.append(1), 10)
    node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: ready.extend(s for s in m.status if s.name.endswith('/policy_node: trained '
                                                                      'policy')), 10)
    node.create_subscription(
        Float64MultiArray, 'pg_node/transition',
        lambda m: episodes.add(transition.from_msg(m)),
        QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    stand_in = 'pybullet_node' if args.robot == 'pybullet' else 'sim_node'
    reset_world = node.create_client(Trigger, f'{stand_in}/reset_world')
    reset = None
    procs = {}
    code = shown = 0
    keep = interrupted = False
    # the card's interface (effort where the actuators take it): the one the policy learned
    offered = list(card.get('command_interfaces') or ['effort'])
    interface = 'effort' if 'effort' in offered else offered[0]
    on = f' perturbed ({" ".join(args.perturb)})' if args.perturb else ''
    logs = (f'logs in {log_dir} (removed at the end unless a node fails; --log-dir keeps '
            'them)' if temporary else f'logs in {log_dir}')
    print(f'play: {source} on {args.arms} x {card["model"]}{on} in real time '
          f'(x{args.real_time_factor:g}), seed {args.seed}, in namespace {namespace}; '
          f'{logs}', flush=True)
    interrupts = processes.Interrupts()
    with interrupts.handled():
        try:
            with interrupts.raising():
                procs['policy_node'] = processes.start_logged(
                    [sys.executable, '-m', 'pg_node.ros.policy_node', '--ros-args', '-r',
                     f'__ns:={namespace}', '-p', f'policy:={source.resolve()}',
                     '-p', 'autostart:=true', '-p', 'use_sim_time:=true',
                     # its joint states come from the sim, started next; the sim is its own
                     # robot, with no controller node whose joints parameter could be read
                     '-p', 'configure_timeout:=120.0', '-p', 'controller_timeout:=0.0',
                     '-p', f'command_interface:={interface}',
                     # pybullet_node latches the URDF: the policy's kinematics are checked
                     '-p', 'require_robot_description:='
                     + ('true' if args.robot == 'pybullet' else 'false')],
                    log_dir / 'policy_node.log', env)
                # the simulator starts once the policy is loaded (torch's import alone can
                # take seconds)
                deadline = time.monotonic() + 120
                while not ready and procs['policy_node'].poll() is None \
                        and time.monotonic() < deadline:
                    rclpy.spin_once(node, timeout_sec=0.1)
                procs[stand_in] = processes.start_logged(
                    robot_argv(args, card, model, namespace, interface, perturb_params),
                    log_dir / f'{stand_in}.log', env)
                deadline = time.monotonic() + 120 + 5 * args.episodes

                def arm0_done():
                    return sum(1 for f in episodes.finished if f[1] == 0)

                while (len(episodes.finished) < args.episodes
                       or (args.gif and arm0_done() < args.gif_episodes)):
                    rclpy.spin_once(node, timeout_sec=0.05)
                    # once the policy commands, the world starts again as seeded: the
                    # episodes played do not depend on how long the policy took to start
                    if reset is None and commands and reset_world.service_is_ready():
                        reset = reset_world.call_async(Trigger.Request())
                    if episodes.first_id is None and reset is not None and reset.done():
                        episodes.first_id = first_episode(reset.result())
                    for done in episodes.finished[shown:]:
                        print(episodes.line(done), flush=True)
                    shown = len(episodes.finished)
                    dead = [name for name, p in procs.items() if p.poll() is not None]
                    if dead or time.monotonic() > deadline:
                        why = (f'{dead[0]} exited with code {procs[dead[0]].returncode}'
                               if dead else 'no episodes finished in time')
                        print(f'play: {why}; see {log_dir}', file=sys.stderr)
                        code, keep = 1, True
                        break
        except KeyboardInterrupt:
            interrupted = True
            later = (f'; Ctrl-C again skips drawing {args.gif}' if args.gif
                     and any(f[1] == 0 for f in episodes.finished) else '')
            print(f'play: interrupted: stopping the nodes{later}', file=sys.stderr, flush=True)
        finally:
            # a second Ctrl-C is counted, not raised: it must not leave nodes behind
            for p in procs.values():
                processes.stop_logged(p)
            node.destroy_node()
            rclpy.try_shutdown()
        done = episodes.finished
        for one in done[shown:]:
            print(episodes.line(one))
        if done:
            rets = np.array([d[2] for d in done])
            dists = 100 * np.array([d[3] for d in done])
            print(f'{len(done)} episode{"s" * (len(done) != 1)}: return {rets.mean():.3f} '
                  f'+/- {rets.std():.3f}, final distance {dists.mean():.2f} cm '
                  f'(median {np.median(dists):.2f} cm)')
        if not args.gif or not done:
            return code, keep
        arm0 = [(ep, frames, ret) for ep, arm, ret, _, frames in done if arm == 0]
        if not arm0:
            print('play: no finished episode of arm 0 to draw', file=sys.stderr)
            return 1, keep
        if interrupted and interrupts.count >= 2:
            print(f'play: {args.gif} not drawn (Ctrl-C again)', file=sys.stderr)
            return code, keep
        arm0 = arm0[:args.gif_episodes]
        steps = sum(len(frames) for _, frames, _ in arm0)
        print(f'rendering {len(arm0)} episode(s) of arm 0 ({steps} frames) to {args.gif} '
              '(Ctrl-C skips it) ...', flush=True)
        try:
            with interrupts.raising():
                from pg_node.tools.render import write_animation
                images = render_frames(card, episodes, arm0)
                write_animation(images, Path(args.gif), fps=1.0 / card['control_step'])
        except KeyboardInterrupt:
            print(f'play: {args.gif} not drawn (Ctrl-C)', file=sys.stderr)
            return code, keep
    print(f'wrote {args.gif} ({len(images)} frames)')
    return code, keep


def robot_argv(args, card, model: str, namespace: str, interface: str,
               perturb_params) -> list:
    """
    Return the command line of the robot's stand-in (``--robot``): sim_node or pybullet_node.

    Both step the physics ``frame_skip`` times per control step, the card's: the control
    step the policy was trained with.
    """
    from pg_node.common.run import COMMANDS, CONTROLLER_COMMANDS
    common = ['-r', f'__ns:={namespace}', '-p', f'model:={model}', '-p', f'seed:={args.seed}',
              '-p', f'frame_skip:={card["frame_skip"]}',
              '-p', f'real_time_factor:={args.real_time_factor}',
              '-p', f'command_interface:={interface}']
    if args.robot == 'pybullet':
        urdf = ['-p', f'urdf:={Path(args.urdf).resolve()}'] if args.urdf else []
        return [sys.executable, '-m', 'pg_node.ros.pybullet_node', '--ros-args', *common,
                *urdf]
    return [sys.executable, '-m', 'pg_node.ros.sim_node', '--ros-args', *common,
            '-r', f'{COMMANDS}:={CONTROLLER_COMMANDS}', '-p', 'mode:=real_time',
            '-p', f'num_envs:={args.arms}', *perturb_params]


def _model_param(card, log_dir: Path) -> str:
    """Return the model for sim_node: the card's name if shipped, else its MJCF written out."""
    from pg_node.common.paths import resolve_model
    try:
        path = resolve_model(card['model'])
        if path.read_text() == card['model_xml']:
            return card['model']
    except OSError:
        pass
    out = log_dir / 'model.xml'
    out.write_text(card['model_xml'])
    return str(out)
