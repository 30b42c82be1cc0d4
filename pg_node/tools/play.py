"""
``python -m pg_node play RUN``: watch a trained policy act, as it would on a robot.

Starts ``sim_node`` in real-time mode and ``policy_node`` with the policy (a run directory,
a checkpoint or an exported ``.onnx``) as processes, and prints each episode's return and the
fingertip's final distance to the target, summed from the simulator's transitions. Episodes
that began before the policy's first command are left out. ``--gif out.gif`` draws the first
``--gif-episodes`` episodes of arm 0 with MuJoCo's offscreen renderer, in this process (which
never trains: no torch optimiser runs beside the OpenGL context), from the observations the
simulator published: the angles from ``cos q``/``sin q``, the goal from the target field.

The two nodes run in a namespace of their own (``/play_<pid>``), where ``policy_node``
publishes ``arm_controller/joint_trajectory`` as on a robot (efforts in N m, ramped in from
zero over its ``ramp_time``; ``autostart``, on simulated time) and the simulator, the robot's
stand-in, takes them there as a joint trajectory controller would
(``command_interface:=effort``; ``arm_controller/commands`` too, for
``command_message:=forward``); and on this machine only
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the environment sets it): a real
controller on the lab network never hears them.

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
    parser.add_argument('--seed', type=int, default=0, help='simulator seed (default: 0)')
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
    parser.add_argument('--log-dir', help="where the nodes' logs go (default: a temporary "
                                          'directory)')
    return parser.parse_args(argv)


class Episodes:
    """Episode returns and final distances summed from a stream of transitions."""

    def __init__(self, obs_layout):
        """Take the observation's :class:`~pg_node.control.obs_layout.ObsLayout`."""
        at = obs_layout.slices
        self.cos, self.sin = at['cos_q'], at['sin_q']
        self.target, self.vec = at['target'], at['fingertip_minus_target']
        self.counted_from = None        # transitions after this seq count
        self.prev = None
        self.running = {}               # episode id -> [return, arm, start seq, frames]
        # (number, arm, return, distance, frames); numbered from 1 in the order they end:
        # the simulator's own ids count the episodes that began before the first command
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
                    entry[3].append((tr.final_obs[i], entry[0]))
                    if self.counted_from is not None and entry[2] > self.counted_from:
                        dist = float(np.linalg.norm(tr.final_obs[i, self.vec]))
                        self.finished.append((len(self.finished) + 1, i, entry[0], dist,
                                              entry[3]))
                else:
                    entry[3].append((tr.obs[i], entry[0]))
        for i in range(tr.num_envs):
            if tr.episode_step[i] == 0:
                self.running[int(tr.episode_id[i])] = [0.0, i, tr.seq, [(tr.obs[i], 0.0)]]
        self.prev = tr

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
                          f'{dist:.3f} m', fill=(255, 255, 255))
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
    from pg_node.common.perturbations import BadTerm, PARAM_PREFIX, parse_perturbation
    try:
        perturbation = parse_perturbation(args.perturb)
    except BadTerm as exc:
        print(f'play: {exc}', file=sys.stderr)
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
    log_dir = Path(args.log_dir or tempfile.mkdtemp(prefix='pg_node_play_')).resolve()
    log_dir.mkdir(parents=True, exist_ok=True)
    model = _model_param(card, log_dir)
    if perturbation:
        # a perturbation this arm cannot take (an add below zero) is refused here, not in
        # the simulator's log
        from pg_node.common.paths import resolve_model
        from pg_node.sim.arm_task import ArmTask
        try:
            ArmTask(resolve_model(model), randomization=perturbation).close()
        except BadTerm as exc:
            print(f'play: --perturb: {exc}', file=sys.stderr)
            return 2
    perturb_params = [a for term, spec in perturbation.items()
                      for a in ('-p', f'{PARAM_PREFIX}{term}:={spec.text()}')]
    from diagnostic_msgs.msg import DiagnosticArray
    from pg_node.ros import transition
    from pg_node.tools import processes
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray
    from pg_node.common.run import COMMANDS, CONTROLLER_COMMANDS, CONTROLLER_TRAJECTORY
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
    procs = {}
    code = shown = 0
    on = f' perturbed ({" ".join(args.perturb)})' if args.perturb else ''
    print(f'play: {source} on {args.arms} x {card["model"]}{on} in real time '
          f'(x{args.real_time_factor:g}) in namespace {namespace}; logs in {log_dir}',
          flush=True)
    try:
        with processes.terminate_as_interrupt():
            procs['policy_node'] = processes.start_logged(
                [sys.executable, '-m', 'pg_node.ros.policy_node', '--ros-args', '-r',
                 f'__ns:={namespace}', '-p', f'policy:={source.resolve()}',
                 '-p', 'autostart:=true', '-p', 'use_sim_time:=true',
                 # its joint states come from the sim, started next; the sim is its own
                 # robot, with no controller node whose joints parameter could be read
                 '-p', 'configure_timeout:=120.0', '-p', 'controller_timeout:=0.0'],
                log_dir / 'policy_node.log', env)
            # the simulator starts once the policy is loaded (torch's import alone can take
            # seconds), so that the first episodes are not spent without commands
            deadline = time.monotonic() + 120
            while not ready and procs['policy_node'].poll() is None \
                    and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            procs['sim_node'] = processes.start_logged(
                [sys.executable, '-m', 'pg_node.ros.sim_node', '--ros-args',
                 '-r', f'__ns:={namespace}', '-r', f'{COMMANDS}:={CONTROLLER_COMMANDS}',
                 '-p', 'mode:=real_time', '-p', 'command_interface:=effort',
                 '-p', f'num_envs:={args.arms}', '-p',
                 f'seed:={args.seed}', '-p', f'model:={model}',
                 '-p', f'real_time_factor:={args.real_time_factor}', *perturb_params],
                log_dir / 'sim_node.log', env)
            deadline = time.monotonic() + 120 + 5 * args.episodes

            def arm0_done():
                return sum(1 for f in episodes.finished if f[1] == 0)

            while (len(episodes.finished) < args.episodes
                   or (args.gif and arm0_done() < args.gif_episodes)):
                rclpy.spin_once(node, timeout_sec=0.05)
                if episodes.counted_from is None and commands and episodes.prev is not None:
                    episodes.counted_from = episodes.prev.seq
                for ep, arm, ret, dist, _ in episodes.finished[shown:]:
                    print(f'episode {ep:4d} (arm {arm}): return {ret:8.3f}, final fingertip '
                          f'distance {dist:.4f} m', flush=True)
                shown = len(episodes.finished)
                dead = [name for name, p in procs.items() if p.poll() is not None]
                if dead or time.monotonic() > deadline:
                    why = (f'{dead[0]} exited with code {procs[dead[0]].returncode}' if dead
                           else 'no episodes finished in time')
                    print(f'play: {why}; see {log_dir}', file=sys.stderr)
                    code = 1
                    break
    except KeyboardInterrupt:
        print('play: interrupted', file=sys.stderr)
    finally:
        with processes.shutting_down():
            for p in procs.values():
                processes.stop_logged(p)
        node.destroy_node()
        rclpy.try_shutdown()
    done = episodes.finished
    for ep, arm, ret, dist, _ in done[shown:]:
        print(f'episode {ep:4d} (arm {arm}): return {ret:8.3f}, final fingertip distance '
              f'{dist:.4f} m')
    if done:
        rets = np.array([d[2] for d in done])
        dists = np.array([d[3] for d in done])
        print(f'{len(done)} episodes: return {rets.mean():.3f} +/- {rets.std():.3f}, final '
              f'distance {dists.mean():.4f} m (median {np.median(dists):.4f} m)')
    if args.gif and done:
        arm0 = [(ep, frames, ret) for ep, arm, ret, _, frames in done if arm == 0]
        if not arm0:
            print('play: no finished episode of arm 0 to draw', file=sys.stderr)
            return 1
        from pg_node.tools.render import write_animation
        images = render_frames(card, episodes, arm0[:args.gif_episodes])
        write_animation(images, Path(args.gif), fps=1.0 / card['control_step'])
        print(f'wrote {args.gif} ({len(images)} frames)')
    return code


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
