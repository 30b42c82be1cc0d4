"""
``python -m pg_node render <bag> --episode N -o FILE.gif``: an animation of a recorded episode.

The frames are drawn by MuJoCo's own offscreen renderer from the bag's ``/joint_states``
and ``/target`` (the topics :mod:`pg_node.bag.recorder` writes): each frame sets the
arm's joint positions and the goal into an ``MjData`` of the model, runs ``mj_forward`` and
renders; the goal is drawn as the model's target geom plus a larger translucent sphere, and
a caption strip (Pillow) gives the episode, the simulated time and the return (the sum of
the rewards on ``/pg_node/reward`` so far, and in total).

Episodes: each ``/target`` message (``frame_id`` ``arm<i>``) starts an episode of arm ``i``
that lasts until that arm's next goal. ``--episode N`` counts them from 0 in the order they
start (all recorded arms, or only ``--arm``'s). ``--list`` prints them.

Software rendering: without a display, MuJoCo needs ``MUJOCO_GL=osmesa`` (Debian
``libosmesa6``) or ``egl``; this module sets ``osmesa`` when ``MUJOCO_GL`` is unset, before
it imports MuJoCo. The model comes from ``--model``, else the bag's ``pg_node.model``
custom data, else ``reacher2``. Output: GIF (Pillow); ``.mp4`` needs ``imageio-ffmpeg``
(without it ``-o x.mp4`` is refused before anything is rendered).
"""
import argparse
from dataclasses import dataclass, field
import os
from pathlib import Path
import sys
from typing import List

import numpy as np
from pg_node.common.run_dir import RunDir
from pg_node.tools.args import positive_float, positive_int


@dataclass
class Episode:
    """One recorded episode of one arm: times, joint positions, goal, rewards."""

    arm: int
    start_ns: int  # simulated time of the first step
    target: np.ndarray
    stamps: List[int] = field(default_factory=list)
    positions: List[np.ndarray] = field(default_factory=list)
    rewards: List[float] = field(default_factory=list)

    @property
    def ret(self) -> float:
        """Return the sum of the recorded rewards."""
        return float(np.sum(self.rewards))


def _stamp(header_stamp) -> int:
    return int(header_stamp.sec) * 10**9 + int(header_stamp.nanosec)


def recorded_episodes(bag) -> List[Episode]:
    """
    Return the episodes of the recorded arms, in the order they start.

    A joint state belongs to the episode of its arm with the latest start not after its
    stamp; the ``/pg_node/reward`` message after a joint state holds that step's rewards,
    one per arm in ``/joint_states`` arm order.
    """
    from pg_node.bag.reader import BagReader
    reader = BagReader(bag, warn=False)
    episodes = []
    steps = []  # [stamp, {arm: positions}, rewards or None]
    names, index = None, {}
    for m in reader.messages(topics=['/target', '/joint_states', '/pg_node/reward'],
                             deserialize=True):
        msg = m.msg
        if msg is None:
            continue
        if m.topic == '/target':
            arm = msg.header.frame_id
            if arm.startswith('arm') and arm[3:].isdigit():
                episodes.append(Episode(int(arm[3:]), _stamp(msg.header.stamp),
                                        np.array([msg.point.x, msg.point.y, msg.point.z])))
        elif m.topic == '/joint_states':
            if list(msg.name) != names:
                names, index = list(msg.name), {}
                for j, name in enumerate(names):
                    arm, _, _ = name.partition('/')
                    if arm.startswith('arm') and arm[3:].isdigit():
                        index.setdefault(int(arm[3:]), []).append(j)
            pos = np.asarray(msg.position)
            steps.append([_stamp(msg.header.stamp),
                          {arm: pos[cols] for arm, cols in index.items()}, None])
        elif steps and steps[-1][2] is None:
            steps[-1][2] = dict(zip(sorted(steps[-1][1]), np.asarray(msg.data)))
    by_arm = {}
    for ep in sorted(episodes, key=lambda e: e.start_ns):
        by_arm.setdefault(ep.arm, []).append(ep)
    starts = {arm: np.array([e.start_ns for e in eps]) for arm, eps in by_arm.items()}
    for stamp, positions, rewards in steps:
        for arm, pos in positions.items():
            if arm not in starts:
                continue
            k = int(np.searchsorted(starts[arm], stamp, side='right')) - 1
            if k < 0:
                continue
            ep = by_arm[arm][k]
            ep.stamps.append(stamp)
            ep.positions.append(pos)
            if rewards is not None and arm in rewards:
                ep.rewards.append(float(rewards[arm]))
    return [ep for ep in episodes if ep.stamps]


def _model_path(bag, given):
    if given:
        from pg_node.common.paths import resolve_model
        return str(resolve_model(given))
    from pg_node.bag.reader import BagReader
    meta = BagReader(bag, warn=False).metadata or {}
    custom = (meta.get('rosbag2_bagfile_information', meta) or {}).get('custom_data') or {}
    path = custom.get('pg_node.model')
    if path and Path(path).is_file():
        return path
    from pg_node.common.paths import resolve_model
    return str(resolve_model(Path(path).stem if path else 'reacher2'))


def render_episode(ep: Episode, model_path: str, width=480, height=480, every=1,
                   caption=True):
    """Return the frames (``(H, W, 3)`` uint8 arrays) of one episode."""
    os.environ.setdefault('MUJOCO_GL', 'osmesa')
    import mujoco
    from pg_node.sim.arm_task import ArmSpec
    from pg_node.sim.view import draw_pose
    from PIL import Image, ImageDraw
    model = mujoco.MjModel.from_xml_path(model_path)
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    spec = ArmSpec.from_model(model)
    data = mujoco.MjData(model)
    renderer = mujoco.Renderer(model, height=height, width=width)
    camera = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(model, camera)
    camera.lookat[:] = [0.0, 0.0, 0.0]
    camera.distance = 1.4 * max(float(model.stat.extent), 0.1) if spec.target_dim > 2 else 0.75
    camera.elevation = -60.0 if spec.target_dim > 2 else -90.0
    camera.azimuth = 90.0
    goal = ep.target[:spec.target_dim]
    frames = []
    cum = np.cumsum(ep.rewards) if ep.rewards else np.zeros(0)
    try:
        for k in range(0, len(ep.stamps), every):
            image = Image.fromarray(draw_pose(renderer, camera, model, data, spec,
                                              ep.positions[k], goal))
            if caption:
                draw = ImageDraw.Draw(image)
                t = (ep.stamps[k] - ep.stamps[0]) / 1e9
                so_far = float(cum[min(k, len(cum) - 1)]) if len(cum) else float('nan')
                draw.rectangle([0, height - 40, width, height], fill=(0, 0, 0))
                draw.text((8, height - 36), f'arm {ep.arm}  t = {t:5.2f} s  step {k + 1}/'
                          f'{len(ep.stamps)}', fill=(255, 255, 255))
                draw.text((8, height - 20), f'return {ep.ret:.3f}  (so far {so_far:.3f})',
                          fill=(255, 255, 255))
            frames.append(np.asarray(image))
    finally:
        renderer.close()
    return frames


def mp4_writer_missing() -> str:
    """Return why an ``.mp4`` cannot be written here ('' when it can)."""
    import importlib.util
    if importlib.util.find_spec('imageio') is None:
        return 'writing .mp4 needs imageio and imageio-ffmpeg (pip install imageio-ffmpeg)'
    if importlib.util.find_spec('imageio_ffmpeg') is None:
        return ('writing .mp4 needs imageio-ffmpeg (pip install imageio-ffmpeg), which is not '
                'installed; .gif works without it')
    return ''


def write_animation(frames, path: Path, fps: float):
    """Write frames as an animated GIF (Pillow), or MP4 when imageio-ffmpeg is installed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == '.mp4':
        import imageio.v2 as imageio
        imageio.mimsave(path, frames, fps=fps)  # needs imageio-ffmpeg
        return
    from PIL import Image
    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], loop=0,
                   duration=max(20, int(round(1000 / fps))), optimize=False)


def main(argv=None) -> int:
    """Render one recorded episode; return the exit status."""
    parser = argparse.ArgumentParser(prog='python -m pg_node render',
                                     description=__doc__.split('\n\n')[0].strip('`'))
    parser.add_argument('bag', help='bag directory, .mcap file or run directory (with bag/)')
    parser.add_argument('--episode', '-e', type=int, default=0,
                        help='episode number, from 0 in start order (negative: from the end)')
    parser.add_argument('--arm', type=int, help="count only this arm's episodes")
    parser.add_argument('-o', '--output', type=Path, default=Path('episode.gif'))
    parser.add_argument('--model', help='MJCF path or shipped model name')
    parser.add_argument('--width', type=positive_int, default=480, help='pixels')
    parser.add_argument('--height', type=positive_int, default=480, help='pixels')
    parser.add_argument('--fps', type=positive_float,
                        help='frames per second (default: real time)')
    parser.add_argument('--every', type=positive_int, default=1,
                        help='render every k-th step')
    parser.add_argument('--list', action='store_true', help='list the episodes and exit')
    args = parser.parse_args(argv)
    if args.output.suffix.lower() == '.mp4' and not args.list and mp4_writer_missing():
        print(f'render: -o {args.output}: {mp4_writer_missing()}', file=sys.stderr)
        return 2
    bag = Path(args.bag)
    if RunDir(bag).has_bag():
        bag = RunDir(bag).bag
    try:
        episodes = recorded_episodes(bag)
    except (ValueError, OSError) as exc:
        print(f'render: {exc}', file=sys.stderr)
        return 1
    if args.arm is not None:
        episodes = [ep for ep in episodes if ep.arm == args.arm]
    if args.list:
        for i, ep in enumerate(episodes):
            print(f'{i:4d}  arm {ep.arm}  t0 {ep.start_ns / 1e9:9.3f} s  '
                  f'{len(ep.stamps):4d} steps  return {ep.ret:9.3f}')
        return 0
    if not episodes:
        print(f'render: no recorded episode (/target + /joint_states) in {bag}',
              file=sys.stderr)
        return 1
    if not -len(episodes) <= args.episode < len(episodes):
        print(f'render: episode {args.episode} out of range; the bag holds {len(episodes)}',
              file=sys.stderr)
        return 1
    ep = episodes[args.episode]
    try:
        model_path = _model_path(bag, args.model)
    except (ValueError, OSError) as exc:
        print(f'render: --model {args.model}: {exc}', file=sys.stderr)
        return 2
    frames = render_episode(ep, model_path, args.width, args.height, args.every)
    if args.fps:
        fps = args.fps
    elif len(ep.stamps) > 1:
        fps = min(50.0, 1e9 / np.median(np.diff(ep.stamps)) / max(1, args.every))
    else:
        fps = 10.0
    try:
        write_animation(frames, args.output, fps)
    except (ValueError, OSError) as exc:
        print(f'render: cannot write {args.output}: {exc} (.gif always works)', file=sys.stderr)
        return 1
    print(f'wrote {args.output}: {len(frames)} frames of {args.width}x{args.height} at '
          f'{fps:g} fps, arm {ep.arm}, return {ep.ret:.3f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
