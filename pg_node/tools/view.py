"""
``python -m pg_node view [RUN]``: the arm in the Foxglove app, live or from a run's bag.

For a viewer without a ROS install: a Foxglove WebSocket server (Foxglove's own SDK,
``foxglove-sdk``) on ``--host``:``--port`` (default ``127.0.0.1:8765``); in the Foxglove app,
*Open connection* -> *Foxglove WebSocket* -> ``ws://HOST:PORT``, then *Import layout*
``config/pg_node.foxglove.json`` (docs/watch.md).

* **live** (no RUN): a ROS node in this process subscribes the graph's topics and serves
  them as the CDR bytes they came in (schema ``ros2msg``, what Foxglove decodes):
  ``pg_node/scene``, ``pg_node/markers``, ``robot_description``, ``joint_states``,
  ``arm<i>/joint_states``, ``target``, ``policy_node/markers``, ``/diagnostics`` and every
  ``pg_node/metrics/*`` topic there is (looked for each second). ``-r __ns:=/exp1`` style
  namespaces: ``--ns /exp1`` (served without it, as the layout names them). The server
  keeps no message for a client that joins later, so the last ``robot_description`` and
  each arm's last ``target`` are served again every second.
* **bag** (RUN: a run directory with ``bag/``, a bag directory or ``.mcap``): every topic of
  the bag, at ``--rate`` times the recorded pace (``--loop`` starts over), and the scene
  rebuilt from its ``/joint_states`` and ``/target`` (in place of the bag's own
  ``/pg_node/scene``, arm 0 once a second, ``record_scene_period``):
  the ``--view-arms`` of the recorded arms, on ``pg_node/scene`` as ``sim_node`` draws them
  (:mod:`pg_node.sim.scene`), at most ``--scene-rate`` Hz of wall time.

Both serve the frames ``arm<i>`` (``/target``'s) as Foxglove ``FrameTransforms`` on ``/tf``:
``frame_id`` (``world``) shifted by the arm's place on ``sim_node``'s grid
(``--spacing``, its ``marker_spacing``), for the arms whose targets were seen.
"""
import argparse
import math
from pathlib import Path
import sys
import time
from typing import Dict, Optional

import numpy as np
from pg_node.common.run_dir import RunDir

DEFAULT_PORT = 8765
LIVE_TOPICS = {
    'pg_node/scene': 'visualization_msgs/msg/MarkerArray',
    'pg_node/markers': 'visualization_msgs/msg/MarkerArray',
    'robot_description': 'std_msgs/msg/String',
    'joint_states': 'sensor_msgs/msg/JointState',
    'target': 'geometry_msgs/msg/PointStamped',
    'policy_node/markers': 'visualization_msgs/msg/MarkerArray',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
}
#: topics a latecomer must still get: subscribed reliable and transient local
LATCHED = ('robot_description', 'target')
#: the metrics config/pg_node.foxglove.json plots (their channels are made before serving)
LAYOUT_METRICS = ('episode_return', 'policy_loss', 'value_loss', 'entropy')
#: the scene bag mode rebuilds
SCENE_TOPIC, SCENE_TYPE = '/pg_node/scene', 'visualization_msgs/msg/MarkerArray'


def grid_offsets(n: int, spacing: float) -> np.ndarray:
    """
    Return sim_node's grid offsets of ``n`` arms ``spacing`` apart (``sim_node.grid_offsets``).

    >>> grid_offsets(3, 0.5).tolist()
    [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0]]
    """
    cols = math.ceil(math.sqrt(n))
    return np.array([[(i % cols) * spacing, (i // cols) * spacing, 0.0] for i in range(n)])


class Served:
    """
    The Foxglove server and its channels: ROS messages as CDR, arm frames as ``/tf``.

    Every channel whose topic is known in advance is made before the server starts: the
    SDK (``foxglove-sdk`` 0.30) sends a channel made while a client is connected to that
    client before it records the channel as advertised to it, so a client that subscribes
    at once (as the Foxglove app does) can be told ``Unknown channel ID`` and never get a
    message (``connected_client.rs``, ``advertise_channels``: ``send_control_msg`` before
    ``advertised_channels.insert``). Channels that exist when a client connects are
    advertised before the client's connection task sends anything, so they are safe.
    """

    def __init__(self, host: str, port: int, frame_id: str, spacing: float,
                 topics: Optional[Dict[str, str]] = None):
        """Make the channels of ``topics`` (name -> ROS type), then start the server."""
        import foxglove
        from foxglove.channels import FrameTransformsChannel
        self.foxglove = foxglove
        self.channels: Dict[str, object] = {}
        self.tf = FrameTransformsChannel('/tf')
        for topic, type_name in (topics or {}).items():
            try:
                self.channel(topic, type_name)
            except KeyError:                # a type not installed: made, or not, on first use
                pass
        self.server = foxglove.start_server(name='pg_node', host=host, port=port)
        self.frame_id, self.spacing = frame_id, spacing
        self.arms = 0                       # arms whose frames are served (from /target)

    @property
    def port(self) -> int:
        """Return the port the server listens on."""
        return self.server.port

    def channel(self, topic: str, type_name: str):
        """Return the channel of ``topic``, made on first use (KeyError: type unknown)."""
        channel = self.channels.get(topic)
        if channel is None:
            from pg_node.bag.ros_types import message_definition
            encoding, text = message_definition(type_name)
            channel = self.channels[topic] = self.foxglove.Channel(
                topic, message_encoding='cdr',
                schema=self.foxglove.Schema(name=type_name, encoding=encoding,
                                            data=text.encode()))
        return channel

    def publish(self, topic: str, type_name: str, cdr: bytes, log_ns: int) -> None:
        """Serve one ROS message's CDR bytes on ``topic``."""
        self.channel(topic, type_name).log(bytes(cdr), log_time=log_ns)

    def see_target_frame(self, frame: str) -> None:
        """Note a target's frame: ``arm<i>`` makes sure arms 0..i have frames."""
        if frame.startswith('arm') and frame[3:].isdigit():
            self.arms = max(self.arms, int(frame[3:]) + 1)

    def publish_frames(self, log_ns: int) -> None:
        """Serve the frames ``arm<i>`` in ``frame_id``, as sim_node's grid places the arms."""
        if not self.arms:
            return
        from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3
        self.tf.log(FrameTransforms(transforms=[
            FrameTransform(parent_frame_id=self.frame_id, child_frame_id=f'arm{i}',
                           translation=Vector3(x=float(x), y=float(y), z=float(z)),
                           rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
            for i, (x, y, z) in enumerate(grid_offsets(self.arms, self.spacing))]),
            log_time=log_ns)

    def stop(self) -> None:
        """Stop the server."""
        self.server.stop()


def serve_live(served: Served, ns: str, stop_after: Optional[float]) -> int:
    """Forward the live graph's topics until Ctrl-C (or ``stop_after`` s)."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    rclpy.init()
    node = rclpy.create_node('pg_node_view', namespace=ns or '/')
    latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    subscribed = set()
    kept = {}           # (topic, frame) -> the last latched message

    def subscribe(topic: str, type_name: str):
        from pg_node.bag.ros_types import message_class
        full = node.resolve_topic_name(topic)
        if full in subscribed:
            return
        subscribed.add(full)

        # served without the run's namespace: the shipped layout names /pg_node/scene...
        shown = full[len(ns):] if ns and full.startswith(ns.rstrip('/') + '/') else full

        def forward(cdr, full=shown, type_name=type_name):
            served.publish(full, type_name, cdr, time.time_ns())
            key = full
            if full.endswith('/target'):
                from rclpy.serialization import deserialize_message
                key = deserialize_message(cdr, message_class(type_name)).header.frame_id
                served.see_target_frame(key)
            if topic in LATCHED:            # the server keeps nothing: given again each second
                kept[(full, key)] = (type_name, cdr)
        node.create_subscription(message_class(type_name), topic, forward,
                                 latched if topic in LATCHED else 10, raw=True)

    def discover():
        for topic, type_name in LIVE_TOPICS.items():
            subscribe(topic, type_name)
        for name, types in node.get_topic_names_and_types():
            if ((('/pg_node/metrics/' in name or name.endswith('/joint_states'))
                    and name.startswith(ns or '/') and types)):
                subscribe(name, types[0])
        served.publish_frames(time.time_ns())
        for (full, _), (type_name, cdr) in list(kept.items()):
            served.publish(full, type_name, cdr, time.time_ns())
    discover()
    node.create_timer(1.0, discover)
    deadline = None if stop_after is None else time.monotonic() + stop_after
    try:
        while rclpy.ok() and (deadline is None or time.monotonic() < deadline):
            rclpy.spin_once(node, timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _bag_path(run: Path) -> Path:
    return RunDir(run).bag if RunDir(run).has_bag() else run


def serve_bag(served: Served, reader, model_path: str, view_arms, rate: float,
              scene_rate: float, loop: bool, stop_after: Optional[float]) -> int:
    """
    Serve the topics of ``reader`` (a BagReader) at ``rate`` x its pace, with the scene.

    Ctrl-C (or ``stop_after`` s) stops.
    """
    import mujoco
    from builtin_interfaces.msg import Time
    from pg_node.ros.scene_msg import scene_markers
    from pg_node.sim.scene import Scene
    from rclpy.serialization import serialize_message
    model = mujoco.MjModel.from_xml_path(model_path)
    arms = 0
    for conn in reader.messages(topics=['/target'], deserialize=True):
        served.see_target_frame(conn.msg.header.frame_id)
        arms = served.arms
    arms = max(arms, max(view_arms, default=-1) + 1, 1)
    offsets = grid_offsets(arms, served.spacing)
    datas = [mujoco.MjData(model) for _ in range(arms)]
    scene = Scene(model, [i for i in view_arms if i < arms], offsets)
    spec = scene.spec
    joints = list(spec.joint_names)
    steps = np.zeros(arms, dtype=int)
    deadline = None if stop_after is None else time.monotonic() + stop_after
    last_scene = 0.0
    try:
        while True:
            start_wall, start_log = time.monotonic(), None
            for m in reader.messages(deserialize=False):
                if deadline is not None and time.monotonic() > deadline:
                    return 0
                if start_log is None:
                    start_log = m.log_time_ns
                if rate > 0:
                    due = (m.log_time_ns - start_log) / 1e9 / rate
                    wait = due - (time.monotonic() - start_wall)
                    if wait > 0:
                        time.sleep(wait)
                if m.topic == SCENE_TOPIC:      # the bag's own (arm 0, 1 Hz): rebuilt here
                    continue
                served.publish(m.topic, m.msg_type, m.data, time.time_ns())
                if m.topic == '/target':
                    point = reader_msg(m)
                    i = _arm_of(point.header.frame_id)
                    if i is not None and i < arms:
                        _set_target(spec, datas[i], point.point)
                        steps[i] = 0
                elif m.topic == '/joint_states':
                    js = reader_msg(m)
                    for k, name in enumerate(js.name):
                        arm, _, joint = name.partition('/')
                        i = _arm_of(arm) if joint else 0
                        joint = joint or name
                        if i is not None and i < arms and joint in joints:
                            datas[i].qpos[spec.qpos_adr[joints.index(joint)]] = js.position[k]
                    for d in datas:
                        mujoco.mj_kinematics(model, d)
                    scene.record(datas, steps)
                    steps += 1
                    now = time.monotonic()
                    if scene_rate > 0 and now - last_scene >= 1.0 / scene_rate:
                        last_scene = now
                        stamp = Time(sec=js.header.stamp.sec, nanosec=js.header.stamp.nanosec)
                        served.publish(SCENE_TOPIC, SCENE_TYPE,
                                       serialize_message(scene_markers(
                                           scene.views(datas), stamp, served.frame_id)),
                                       time.time_ns())
                        served.publish_frames(time.time_ns())
            if not loop:
                return 0
    except KeyboardInterrupt:
        return 0


def reader_msg(m):
    """Return the message of a raw :class:`pg_node.bag.reader.BagMessage`."""
    from pg_node.bag.ros_types import message_class
    from rclpy.serialization import deserialize_message
    return deserialize_message(m.data, message_class(m.msg_type))


def _arm_of(frame: str) -> Optional[int]:
    return int(frame[3:]) if frame.startswith('arm') and frame[3:].isdigit() else None


def _set_target(spec, data, point) -> None:
    xyz = np.array([point.x, point.y, point.z])
    if spec.target_mocap >= 0:
        data.mocap_pos[spec.target_mocap] = xyz
    else:
        data.qpos[spec.target_qpos_adr] = xyz[:spec.target_dim]


def main(argv=None) -> int:
    """Serve the live graph or a bag to the Foxglove app; return the exit status."""
    from pg_node.common.param_schema import arm_indices
    parser = argparse.ArgumentParser(prog='python -m pg_node view',
                                     description=__doc__.split('\n\n')[0].strip('`'))
    parser.add_argument('run', nargs='?', help='run directory, bag directory or .mcap '
                                               '(none: the live graph)')
    parser.add_argument('--host', default='127.0.0.1',
                        help='address to listen on (0.0.0.0: every interface)')
    parser.add_argument('--port', type=int, default=DEFAULT_PORT, help='0: a free one')
    parser.add_argument('--ns', default='', help='live: the namespace of the run (/exp1)')
    parser.add_argument('--frame-id', default='world', help="sim_node's frame_id")
    parser.add_argument('--spacing', type=float, default=0.7,
                        help="sim_node's marker_spacing: where the frames arm<i> are")
    parser.add_argument('--view-arms', default='0', help='bag: the arms the scene draws')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='bag: times the recorded pace (0: as fast as possible)')
    parser.add_argument('--scene-rate', type=float, default=10.0,
                        help='bag: scene messages per second of wall time at most')
    parser.add_argument('--loop', action='store_true', help='bag: start over at the end')
    parser.add_argument('--model', help='bag: MJCF path or shipped model name (default: '
                                        "the bag's)")
    parser.add_argument('--stop-after', type=float, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    try:
        view_arms = arm_indices(args.view_arms)
    except ValueError as exc:
        print(f'view: --view-arms: {exc}', file=sys.stderr)
        return 2
    reader = model_path = None
    # served as view serves them: live without the namespace (and what the shipped layout
    # shows of the topics found later), a bag's as recorded
    from pg_node.bag.recorder import metric_topic
    topics = {'/' + topic.lstrip('/'): type_name for topic, type_name in LIVE_TOPICS.items()}
    topics.update({metric_topic(name): 'std_msgs/msg/Float64' for name in LAYOUT_METRICS})
    topics['/arm0/joint_states'] = 'sensor_msgs/msg/JointState'
    if args.run:
        bag = _bag_path(Path(args.run))
        if not bag.exists():
            print(f'view: no run, bag or .mcap at {args.run}', file=sys.stderr)
            return 1
        from pg_node.tools.render import _model_path
        try:
            model_path = _model_path(bag, args.model)
        except (ValueError, OSError) as exc:
            print(f'view: {exc}', file=sys.stderr)
            return 2
        from pg_node.bag.reader import BagReader
        try:
            reader = BagReader(bag, warn=False)
            topics = {name: info.msg_type for name, info in reader.topics.items()}
        except (ValueError, OSError) as exc:
            print(f'view: {bag}: {exc}', file=sys.stderr)
            return 1
        topics[SCENE_TOPIC] = SCENE_TYPE
    try:
        served = Served(args.host, args.port, args.frame_id, args.spacing, topics)
    except (RuntimeError, OSError, ValueError) as exc:   # the SDK's FoxgloveError: port taken
        hint = ' (another view or server has it? --port 0 takes a free one)' \
            if args.port else ''
        print(f'view: cannot serve on {args.host}:{args.port}: {exc}{hint}', file=sys.stderr)
        return 2
    print(f'view: serving on ws://{args.host}:{served.port} (Foxglove app: Open connection '
          '-> Foxglove WebSocket; layout config/pg_node.foxglove.json); Ctrl-C stops',
          flush=True)
    try:
        if reader is None:
            return serve_live(served, args.ns, args.stop_after)
        try:
            return serve_bag(served, reader, model_path, view_arms, args.rate, args.scene_rate,
                             args.loop, args.stop_after)
        except (ValueError, OSError) as exc:
            print(f'view: {bag}: {exc}', file=sys.stderr)
            return 1
    finally:
        served.stop()


if __name__ == '__main__':
    raise SystemExit(main())
