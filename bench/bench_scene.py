"""
What watching the scene costs training: sim_node's ``pg_node/scene`` against none.

Usage::

    python bench/bench_scene.py [--steps 100000] [--repeats 3] [--rates 4 10]
                                [--model reacher2] [--view-arms 0]

Two measures, printed as tables:

* **in-process cost**: the work a watched scene adds to sim_node, timed on a 64-arm task
  in this process: one scene message (:meth:`pg_node.sim.scene.Scene.views`, the
  ``MarkerArray`` of :func:`pg_node.ros.scene_msg.scene_markers` and its serialisation) and
  one trail record per control step; at ``rate`` messages per second and the graph's
  control steps per second (its steps/s / 64), the share of one second they take. The
  overview markers (``pg_node/markers``, 10 Hz, all arms) are timed the same way. Load on
  the machine barely changes these (CPU time of small calls).
* **graph**: the default training (``python -m pg_node train``, 64 arms) for ``--steps``
  steps, with nobody watching, and with a subscriber on ``pg_node/scene`` at each rate
  (``markers`` off in all rows, so that only the scene differs), interleaved ``--repeats``
  times; the median steps/s of each and its ratio to the unwatched median. On a shared
  machine the spread of the repeats is printed beside: a difference below it is noise.

The load average is printed before and after.
"""
import argparse
import os
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def watch(seconds: float) -> None:
    """Subscribe every ``.../pg_node/scene`` topic for ``seconds``; print messages received."""
    import rclpy
    from visualization_msgs.msg import MarkerArray
    rclpy.init()
    node = rclpy.create_node('bench_scene_watcher')
    got, subscribed = [0], set()
    deadline = time.monotonic() + seconds
    try:
        while time.monotonic() < deadline:
            for name, _types in node.get_topic_names_and_types():
                if name.endswith('pg_node/scene') and name not in subscribed:
                    node.create_subscription(MarkerArray, name,
                                             lambda _m: got.__setitem__(0, got[0] + 1), 1)
                    subscribed.add(name)
            rclpy.spin_once(node, timeout_sec=0.2)
    except KeyboardInterrupt:           # the bench stops it with SIGINT when training ends
        pass
    print(f'{got[0]} scene messages on {sorted(subscribed)}', flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def in_process(model: str, view_arms, num_envs: int = 64, calls: int = 300):
    """Return seconds per scene message, per trail record and per overview-markers message."""
    import rclpy
    from rclpy.serialization import serialize_message
    from builtin_interfaces.msg import Time
    from pg_node.common.paths import resolve_model
    from pg_node.ros.scene_msg import scene_markers
    from pg_node.sim.arm_task import ArmTask
    from pg_node.sim.scene import Scene
    del rclpy
    task = ArmTask(resolve_model(model), num_envs=num_envs, seed=0)
    task.reset()
    task.step(np.zeros((num_envs, task.act_dim)))
    offsets = np.zeros((num_envs, 3))
    scene = Scene(task.model, view_arms, offsets, trail_length=50)
    for _ in range(60):
        scene.record(task.datas, task.episode_step + 1)

    def timed(fn):
        fn()
        t0 = time.process_time()        # CPU time: what the work takes from training
        for _ in range(calls):
            fn()
        return (time.process_time() - t0) / calls

    message = timed(lambda: serialize_message(
        scene_markers(scene.views(task.datas), Time(sec=1), 'world')))
    record = timed(lambda: scene.record(task.datas, task.episode_step + 1))

    from geometry_msgs.msg import Point
    from visualization_msgs.msg import Marker, MarkerArray

    def overview():                      # sim_node.publish_markers' work, without a node
        links = task.link_positions().reshape(num_envs, -1, 3) + offsets[:, None, :]
        out = MarkerArray()
        for kind, points in ((Marker.LINE_LIST, links.reshape(-1, 3)),
                             (Marker.SPHERE_LIST, task.fingertip_pos() + offsets),
                             (Marker.SPHERE_LIST, task.target_pos() + offsets)):
            m = Marker(type=kind)
            m.points = [Point(x=x, y=y, z=z) for x, y, z in points.tolist()]
            out.markers.append(m)
        serialize_message(out)
    return message, record, timed(overview)


def graph_rate(steps: int, watcher_rate, model: str, view_arms: str) -> float:
    """Return the graph's steps/s with a scene watcher at ``watcher_rate`` Hz (None: none)."""
    from bench import runs as br
    from pg_node.tools.processes import child_env, stop
    over = ['sim_node.marker_rate=0.0', f'model={model}', f"sim_node.view_arms='{view_arms}'"]
    watcher = None
    if watcher_rate is not None:
        over.append(f'sim_node.scene_rate={watcher_rate}')
        watcher = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), '--watch', '3600'],
            env=child_env(br.domain_id()), cwd=REPO, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    else:
        over.append('sim_node.scene_rate=0.0')
    try:
        with tempfile.TemporaryDirectory() as tmp:
            summary = br.run_graph(Path(tmp) / 'run', steps, 0, [*over, '--eval-episodes', '1'])
    finally:
        if watcher is not None:
            stop(watcher)
            out = watcher.stdout.read().strip().splitlines()
            print(f'    watcher: {out[-1] if out else "(no output)"}', flush=True)
    return float(summary['steps_per_second'])


def main(argv=None) -> int:
    """Print the in-process and graph tables."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--steps', type=int, default=100_000)
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--rates', type=float, nargs='+', default=[4.0, 10.0])
    ap.add_argument('--model', default='reacher2')
    ap.add_argument('--view-arms', default='0')
    ap.add_argument('--no-graph', action='store_true', help='only the in-process table')
    ap.add_argument('--watch', type=float, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.watch:
        watch(args.watch)
        return 0
    arms = [int(a) for a in args.view_arms.replace(',', ' ').split()]
    print(f'load average before: {os.getloadavg()}')
    message, record, overview = in_process(args.model, arms)
    print(f'\nin-process cost ({args.model}, 64 arms, view_arms {arms})\n')
    print('| work | per call | calls per s | share of 1 s |')
    print('|---|---|---|---|')
    control_hz = 10_000 / 64            # a default graph's steps/s (order of) per arm
    print(f'| trail record (per control step) | {record * 1e6:.1f} us | {control_hz:.0f} | '
          f'{100 * record * control_hz:.2f}% |')
    for rate in args.rates:
        print(f'| scene message at {rate:g} Hz | {message * 1e3:.2f} ms | {rate:g} | '
              f'{100 * message * rate:.2f}% |')
    print(f'| overview markers (64 arms) at 10 Hz | {overview * 1e3:.2f} ms | 10 | '
          f'{100 * overview * 10:.2f}% |')
    if args.no_graph:
        return 0
    rows = [None, *args.rates]
    rates = {r: [] for r in rows}
    for k in range(args.repeats):
        for r in rows:
            rate = graph_rate(args.steps, r, args.model, args.view_arms)
            rates[r].append(rate)
            print(f'  repeat {k}: {"no watcher" if r is None else f"scene at {r:g} Hz"}: '
                  f'{rate:.0f} steps/s', flush=True)
    base = statistics.median(rates[None])
    print(f'\ngraph ({args.steps} steps, 64 arms, markers off, {args.repeats} repeats '
          'interleaved)\n')
    print('| scene | median steps/s | min..max | vs unwatched |')
    print('|---|---|---|---|')
    for r in rows:
        med = statistics.median(rates[r])
        print(f'| {"not watched" if r is None else f"{r:g} Hz"} | {med:.0f} | '
              f'{min(rates[r]):.0f}..{max(rates[r]):.0f} | {100 * (med / base - 1):+.1f}% |')
    print(f'\nload average after: {os.getloadavg()}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
