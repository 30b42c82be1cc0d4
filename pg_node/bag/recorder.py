"""
Write the episodes a learner learns from into a rosbag2 MCAP bag, from its annotated batches.

The learner owns an :class:`EpisodeRecorder` and hands it every :class:`pg_node.ros.messages.Batch`
it learns from. The recorder rebuilds the step messages from the batch arrays (cheaper than
subscribing to the simulator's high-rate topics, and exactly what was learned from) and
writes them with :class:`pg_node.bag.writer.BagWriter`. No ROS node is created here.

Topics (the contract the replay, plot and render tools and the README rely on):

* ``/clock`` (``rosgraph_msgs/Clock``), every step: simulated time ``seq * dt``;
* ``/joint_states`` (``sensor_msgs/JointState``), every step, for the recorded arms (arm
  columns ``0 .. record_arms - 1`` of actor ``record_actor``): names ``arm<i>/<joint>`` as
  sim_node names them, position the joint's actual angle as sim_node publishes it (not
  wrapped: a continuous joint's angle goes on past pi), recovered from the observation's
  ``cos q, sin q`` by unwrapping along each episode from its first step, velocity from
  the observation, effort ``clip(act, ctrl range) * gear`` (the torque the action applied
  during the step), stamped with simulated time;
* ``/target`` (``geometry_msgs/PointStamped``, reliable, transient-local, depth
  ``record_arms``): a recorded arm's goal at the first recorded step of each of its episodes,
  ``frame_id`` ``arm<i>``, the point from the observation's target field (world coordinates,
  ``z = 0`` for a planar goal);
* ``/pg_node/commands`` (``std_msgs/Float64MultiArray``), every step: the recorded
  arms' clipped actions, arm-major, layout dims ``arm`` x ``actuator``;
* ``/pg_node/reward`` (``std_msgs/Float64MultiArray``), every step: the recorded arms'
  rewards, layout dim ``arm``;
* ``/pg_node/episode`` (``diagnostic_msgs/DiagnosticStatus``, reliable, depth 100): one per
  finished episode of *every* arm of every actor, name ``episode``, level OK (WARN when cut
  short), values ``actor, arm, episode_id, return, length, terminated, truncated, cut_short,
  policy_version, recorded_steps``. ``return`` sums the rewards recorded for the episode,
  over as many batches as it spans; ``length`` is the episode's length in steps (from
  ``ep_step``), ``recorded_steps`` how many of them the recorder saw (fewer only when
  recording began mid-episode, whose return is then partial). Booleans are ``true`` /
  ``false``. ``split_max_episodes`` counts these messages;
* ``/pg_node/metrics/<name>`` (``std_msgs/Float64``): each finite value given to
  :meth:`EpisodeRecorder.record_metrics` (``episode_return``, ``policy_loss``, ...);
* ``/pg_node/scene`` (``visualization_msgs/MarkerArray``), with ``draw_scene``: recorded
  arm 0 as ``sim_node`` draws it (:class:`pg_node.sim.scene.Scene`: its links at the
  recorded angles, the goal, the fingertip and its trail), in frame ``world``, at most one
  message per ``scene_period`` seconds of log time (0: none), so that ``ros2 bag play``
  into RViz shows the arm without TF. ``draw_scene`` (``pg_node.ros.scene_msg.
  scene_markers``) is given by the owner: this layer makes no markers.

Log times: a batch's step messages are spread evenly over ``(previous call, t_wall_ns]``, so
that replay at the original rate goes at training pace; episode summaries and metrics are
logged at ``t_wall_ns``. Log times never go back: a ``t_wall_ns`` earlier than what is
already written is moved up to it. The open chunk is flushed whenever an episode ends.

An episode is cut short when its arm starts a new episode before the old one ended (a world
reset, an actor restart), when the owner calls :meth:`EpisodeRecorder.mark_cut_short`, or
when it calls :meth:`EpisodeRecorder.cut_short_actor` because that actor's simulator
restarted (the learner sees its transition numbers start again).
Episodes still open at :meth:`EpisodeRecorder.close` get no summary.

The bag's ``metadata.yaml`` ``custom_data`` holds ``pg_node.model`` (the MJCF path),
``pg_node.dt``, ``pg_node.record_arms`` and ``pg_node.joint_names`` for the tools that
read the bag.
"""
import math
import re
import threading
from types import SimpleNamespace
from typing import Callable, Dict, Optional

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped
import mujoco
import numpy as np
from pg_node.bag.ros_types import float64_field
from pg_node.bag.writer import BagWriter
from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmSpec
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension

EPISODE_TOPIC = '/pg_node/episode'
#: each episode's drawn randomization terms (domain randomization on)
RANDOMIZATION_TOPIC = '/pg_node/randomization'
#: the recorded actions (training's command topic, never a real controller's)
COMMANDS_TOPIC = '/pg_node/commands'
METRICS_PREFIX = '/pg_node/metrics/'
#: recorded arm 0 drawn as sim_node draws it (with ``draw_scene``)
SCENE_TOPIC = '/pg_node/scene'
EPISODE_KEYS = ('actor', 'arm', 'episode_id', 'return', 'length', 'terminated', 'truncated',
                'cut_short', 'policy_version', 'recorded_steps')
_DEFAULT = QoSProfile(depth=10)
#: QoS of ``/pg_node/episode``, in the bag and live (learner_node publishes each summary)
EPISODE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
_NAME_BAD = re.compile(r'[^A-Za-z0-9_]')


def metric_topic(name: str) -> str:
    """
    Return the topic of a metric: ``/pg_node/metrics/<name>`` with a valid ROS name.

    >>> metric_topic('episode_return'), metric_topic('loss/pi'), metric_topic('2x')
    ('/pg_node/metrics/episode_return', '/pg_node/metrics/loss_pi', '/pg_node/metrics/m_2x')
    """
    clean = _NAME_BAD.sub('_', str(name)) or 'unnamed'
    if not clean[0].isalpha():
        clean = 'm_' + clean
    return METRICS_PREFIX + clean


def sim_stamp(seconds: float) -> Time:
    """Return a ``builtin_interfaces/Time`` for a simulated time in seconds."""
    ns = int(round(seconds * 1e9))
    return Time(sec=ns // 10**9, nanosec=ns % 10**9)


def _fmt(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return 'true' if value else 'false'
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


def parse_episode(status) -> Dict[str, float]:
    """
    Turn a ``/pg_node/episode`` DiagnosticStatus (rclpy or rosbags) into a dict of numbers.

    Booleans become 1.0 / 0.0; ``level`` is added.
    """
    out = {'level': float(status.level[0] if isinstance(status.level, bytes)
                          else status.level)}
    for kv in status.values:
        v = kv.value.strip().lower()
        try:
            out[kv.key] = 1.0 if v == 'true' else 0.0 if v == 'false' else float(v)
        except ValueError:
            continue
    return out


class _Open:
    """One arm's open episode: its id and running sums."""

    __slots__ = ('episode_id', 'ret', 'recorded', 'last_ep_step')

    def __init__(self, episode_id):
        self.episode_id = int(episode_id)
        self.ret = 0.0
        self.recorded = 0
        self.last_ep_step = -1


class EpisodeRecorder:
    """
    Record annotated batches, metrics and episode summaries into a bag directory.

    :param directory: the bag directory to create (must not exist or be empty).
    :param model_path: the MJCF (or a shipped model name) the batches come from; joint
        names, control ranges and gears are read from it.
    :param record_arms: how many arms of actor ``record_actor`` get step messages.
    :param split_max_episodes: start a new file after this many episode summaries (0: never).
    :param split_max_bytes: start a new file at this size (0: never).
    :param dt: simulated seconds per control step; by default the model's timestep times
        ``frame_skip``.
    :param on_summary: called with each episode summary (a ``DiagnosticStatus``, as the
        CDR bytes the bag holds) after it is written, e.g. a publisher's ``publish`` (which
        sends bytes as they are), so that live tools see what the bag gets.
    :param draw_scene: ``(views, stamp, frame_id) -> MarkerArray`` (``scene_markers``):
        with it and a ``scene_period`` > 0 s, recorded arm 0 is drawn on ``/pg_node/scene``
        at most once per ``scene_period`` seconds of log time.
    """

    def __init__(self, directory, model_path, record_arms: int = 4,
                 split_max_episodes: int = 200, split_max_bytes: int = 64 << 20,
                 dt: Optional[float] = None, frame_skip: int = 2, record_actor: int = 0,
                 compression: str = 'zstd',
                 on_summary: Optional[Callable[[bytes], None]] = None,
                 draw_scene: Optional[Callable] = None, scene_period: float = 0.0):
        """Read the model and create the bag with its topics declared."""
        self.model_path = str(resolve_model(str(model_path)))
        model = mujoco.MjModel.from_xml_path(self.model_path)
        self.spec = ArmSpec.from_model(model)
        self.target_dim = self.spec.target_dim
        self.act_dim = model.nu
        self.obs_layout = self.spec.obs_layout
        self.obs_dim = self.obs_layout.size
        self.gear = model.actuator_gear[:, 0].copy()
        self.dt = float(dt) if dt is not None else float(model.opt.timestep * frame_skip)
        self.record_arms = int(record_arms)
        self.record_actor = int(record_actor)
        self.on_summary = on_summary
        self.episodes_written = 0
        self.batches_written = 0
        self._open: Dict[tuple, _Open] = {}
        self._closed_recently = {}  # (actor, arm) -> set of ended episode ids (bounded)
        self._last_t: Optional[int] = None
        self._target_for: Dict[int, int] = {}  # recorded arm -> episode of its last goal
        self._angles: Dict[int, np.ndarray] = {}  # recorded arm -> its last unwrapped angles
        self._names: Dict[bytes, list] = {}  # recorded arms -> their joint names
        self._msgs = SimpleNamespace(
            clock=Clock(), joints=JointState(), commands=Float64MultiArray(),
            reward=Float64MultiArray())
        self._layout_arms = None  # arms the layouts of commands and reward describe
        self._lock = threading.RLock()
        self.writer = BagWriter(
            directory, split_max_bytes=split_max_bytes, split_max_episodes=split_max_episodes,
            episode_topic=EPISODE_TOPIC, compression=compression,
            custom_data={'pg_node.model': self.model_path, 'pg_node.dt': repr(self.dt),
                         'pg_node.record_arms': str(self.record_arms),
                         'pg_node.joint_names': ','.join(self.spec.joint_names)})
        self.directory = self.writer.directory
        w = self.writer
        w.add_topic('/clock', Clock, _DEFAULT)
        w.add_topic('/joint_states', JointState, _DEFAULT)
        w.add_topic('/target', PointStamped, QoSProfile(
            depth=max(1, self.record_arms), reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        w.add_topic(COMMANDS_TOPIC, Float64MultiArray, _DEFAULT)
        w.add_topic('/pg_node/reward', Float64MultiArray, _DEFAULT)
        w.add_topic(EPISODE_TOPIC, DiagnosticStatus, EPISODE_QOS)
        self.scene = None
        if draw_scene is not None and scene_period > 0 and self.record_arms > 0:
            from visualization_msgs.msg import MarkerArray
            from pg_node.sim.scene import Scene
            self.draw_scene, self.scene_period_ns = draw_scene, int(scene_period * 1e9)
            self.scene_model = model
            self.scene_data = mujoco.MjData(model)
            self.scene = Scene(model, [0], np.zeros((1, 3)))
            self._scene_t: Optional[int] = None
            w.add_topic(SCENE_TOPIC, MarkerArray, _DEFAULT)

    # -- time ------------------------------------------------------------------------------
    def _clamp(self, t_ns) -> int:
        t_ns = int(t_ns)
        if self._last_t is not None and t_ns < self._last_t:
            t_ns = self._last_t
        return t_ns

    # -- batches ---------------------------------------------------------------------------
    def record_batch(self, batch, policy_version: int, t_wall_ns: int):
        """
        Write one annotated batch: step messages of the recorded arms, episode summaries.

        ``batch`` is a :class:`pg_node.ros.messages.Batch` (arrays ``(T, N, ...)``) whose
        columns are the arms of all actors side by side, ``batch.actor`` naming each
        column's actor; an arm's index is its column minus its actor's first column.
        """
        with self._lock:
            if self.writer.closed:
                raise RuntimeError('episode recorder is closed')
            obs = np.asarray(batch.obs, dtype=np.float64)
            T, N = obs.shape[:2]
            if obs.shape[2] != self.obs_dim:
                raise ValueError(f'obs has {obs.shape[2]} columns, the model gives '
                                 f'{self.obs_dim}')
            act = np.asarray(batch.act, dtype=np.float64).reshape(T, N, -1)
            rew = np.asarray(batch.rew, dtype=np.float64).reshape(T, N)
            term = np.asarray(batch.terminated).reshape(T, N).astype(bool)
            trunc = np.asarray(batch.truncated).reshape(T, N).astype(bool)
            ep_step = np.asarray(batch.ep_step).reshape(T, N).astype(np.int64)
            ep_id = np.asarray(batch.episode_id).reshape(T, N).astype(np.int64)
            seq = np.asarray(batch.seq).reshape(T, N).astype(np.int64)
            actors = np.asarray(batch.actor).reshape(T, N).astype(np.int64)[0]
            arm_of = np.empty(N, dtype=np.int64)
            first = {}
            for col, a in enumerate(actors):
                first.setdefault(int(a), col)
                arm_of[col] = col - first[int(a)]
            t_end = self._clamp(t_wall_ns)
            t_start = self._last_t if self._last_t is not None else (
                t_end - int(round(T * self.dt * 1e9)))
            t_start = min(t_start, t_end)
            cols = [c for c in range(N) if actors[c] == self.record_actor
                    and arm_of[c] < self.record_arms]
            for t in range(T):
                t_log = t_start + (t_end - t_start) * (t + 1) // T
                if cols:
                    self._write_step(t_log, obs[t, cols], act[t, cols], rew[t, cols],
                                     ep_id[t, cols], ep_step[t, cols], arm_of[cols],
                                     int(seq[t, cols[0]]))
            ended = self._accumulate(rew, term, trunc, ep_step, ep_id, actors, arm_of,
                                     int(policy_version), t_end)
            self._last_t = t_end
            self.batches_written += 1
            if ended:
                self.writer.flush(metadata=False)

    def _unwrapped(self, wrapped, arms, ep_step) -> np.ndarray:
        """
        Return the joints' actual angles from their wrapped ones, one row per recorded arm.

        An episode starts from angles within (-pi, pi] (every shipped model's initial
        state); from there each step adds the wrapped change, which is the true change as
        long as a joint turns less than pi in one control step. An arm first seen in the
        middle of an episode (a restarted learner) starts from its wrapped angle.
        """
        out = wrapped.copy()
        keys = arms.tolist()
        last = [self._angles.get(arm) for arm in keys]
        rows = [r for r, prev in enumerate(last) if prev is not None and ep_step[r] > 0]
        if rows:
            prev = np.stack([last[r] for r in rows])
            out[rows] = prev + np.angle(np.exp(1j * (wrapped[rows] - prev)))
        for r, arm in enumerate(keys):
            self._angles[arm] = out[r]
        return out

    def _write_step(self, t_log, obs, act, rew, ep_id, ep_step, arms, seq):
        k, at = self.target_dim, self.obs_layout.slices
        stamp = sim_stamp(seq * self.dt)
        w, m = self.writer, self._msgs
        # the writer serialises a message as it takes it, so one object of each type is
        # filled and written again every step (an rclpy message costs microseconds to make)
        m.clock.clock = stamp
        w.write('/clock', m.clock, t_log)
        act_c = np.clip(act, self.spec.ctrl_low, self.spec.ctrl_high)
        names = self._names.get(arms.tobytes())
        if names is None:
            names = self._names[arms.tobytes()] = [
                f'arm{int(i)}/{j}' for i in arms for j in self.spec.joint_names]
        js = m.joints
        js.header.stamp = stamp
        js.name = names
        angles = self._unwrapped(np.arctan2(obs[:, at['sin_q']], obs[:, at['cos_q']]), arms,
                                 ep_step)
        js.position = float64_field(angles)
        js.velocity = float64_field(obs[:, at['qdot']])
        js.effort = float64_field(act_c * self.gear)
        w.write('/joint_states', js, t_log)
        for r, arm in enumerate(arms.tolist()):
            eid = int(ep_id[r])
            if self._target_for.get(arm) != eid:
                # the first recorded step of this arm's episode: its goal
                self._target_for[arm] = eid
                point = PointStamped()
                point.header.stamp = stamp
                point.header.frame_id = f'arm{arm}'
                goal = obs[r, at['target']]
                point.point.x = float(goal[0])
                point.point.y = float(goal[1]) if k > 1 else 0.0
                point.point.z = float(goal[2]) if k > 2 else 0.0
                w.write('/target', point, t_log)
        cmd, reward = m.commands, m.reward
        if self._layout_arms != len(arms):
            self._layout_arms = len(arms)
            cmd.layout.dim = [
                MultiArrayDimension(label='arm', size=len(arms),
                                    stride=len(arms) * self.act_dim),
                MultiArrayDimension(label='actuator', size=self.act_dim, stride=self.act_dim)]
            reward.layout.dim = [MultiArrayDimension(label='arm', size=len(arms),
                                                     stride=len(arms))]
        cmd.data = float64_field(act_c)
        w.write(COMMANDS_TOPIC, cmd, t_log)
        reward.data = float64_field(rew)
        w.write('/pg_node/reward', reward, t_log)
        if self.scene is not None and arms[0] == 0:
            self._draw(t_log, stamp, angles[0], obs[0, at['target']], ep_step[:1])

    def _draw(self, t_log, stamp, angles, goal, ep_step) -> None:
        """Move arm 0's scene to this step (its trail grows); write it when one is due."""
        d, spec = self.scene_data, self.spec
        d.qpos[spec.qpos_adr] = angles
        if spec.target_mocap >= 0:
            d.mocap_pos[spec.target_mocap, :self.target_dim] = goal
        else:
            d.qpos[spec.target_qpos_adr] = goal
        mujoco.mj_kinematics(self.scene_model, d)
        self.scene.record([d], ep_step)
        if self._scene_t is None or t_log - self._scene_t >= self.scene_period_ns:
            self._scene_t = t_log
            self.writer.write(SCENE_TOPIC, self.draw_scene(self.scene.views([d]), stamp,
                                                           'world'), t_log)

    def _accumulate(self, rew, term, trunc, ep_step, ep_id, actors, arm_of, version, t_ns):
        """Update the running sums of every arm; write the episodes that end. Return count."""
        T, N = rew.shape
        done = term | trunc
        # a segment of a column is a run of steps of one episode, ended by a step that ends
        # the episode or by a change of episode id
        starts = np.zeros((T, N), dtype=bool)
        starts[0] = True
        starts[1:] = (ep_id[1:] != ep_id[:-1]) | done[:-1]
        pending = []  # (step, column, key, episode, terminated, truncated, cut_short)
        # most columns are one running episode from end to end: add their sums in one go
        through = (~starts[1:].any(axis=0) & ~done[-1]).tolist()
        # (summed row by row as one column alone is, so the float sums stay the same)
        sums = np.ascontiguousarray(rew.T).sum(axis=1).tolist()
        first_id, last_step = ep_id[0].tolist(), ep_step[-1]
        for col in range(N):
            key = (int(actors[col]), int(arm_of[col]))
            if through[col]:
                cur = self._open.get(key)
                if cur is not None and cur.episode_id == first_id[col]:
                    cur.ret += sums[col]
                    cur.recorded += T
                    cur.last_ep_step = int(last_step[col])
                    continue
            bounds = np.flatnonzero(starts[:, col]).tolist() + [T]
            for a, b in zip(bounds[:-1], bounds[1:]):
                eid = int(ep_id[a, col])
                cur = self._open.get(key)
                if cur is not None and cur.episode_id != eid:
                    # the arm moved on before its episode ended: a reset cut it short
                    del self._open[key]
                    pending.append((a, col, key, cur, False, False, True))
                    cur = None
                if cur is None:
                    if eid in self._closed_recently.get(key, ()):
                        continue  # steps of an episode already summarised: ignore
                    cur = self._open[key] = _Open(eid)
                cur.ret += float(rew[a:b, col].sum())
                cur.recorded += b - a
                cur.last_ep_step = int(ep_step[b - 1, col])
                if done[b - 1, col]:
                    del self._open[key]
                    pending.append((b - 1, col, key, cur, bool(term[b - 1, col]),
                                    bool(trunc[b - 1, col]), False))
        pending.sort(key=lambda p: (p[0], p[1]))
        for _, _, key, cur, terminated, truncated, cut_short in pending:
            self._summary(key, cur, version, t_ns, terminated=terminated,
                          truncated=truncated, cut_short=cut_short)
        return len(pending)

    def _summary(self, key, cur: Optional[_Open], version, t_ns, terminated=False,
                 truncated=False, cut_short=False, episode_id=None):
        actor, arm = key
        eid = cur.episode_id if cur is not None else int(episode_id)
        values = {
            'actor': actor, 'arm': arm, 'episode_id': eid,
            'return': cur.ret if cur is not None else 0.0,
            'length': (cur.last_ep_step + 1) if cur is not None else 0,
            'terminated': terminated, 'truncated': truncated, 'cut_short': cut_short,
            'policy_version': int(version),
            'recorded_steps': cur.recorded if cur is not None else 0}
        status = DiagnosticStatus()
        status.name = 'episode'
        status.level = DiagnosticStatus.WARN if cut_short else DiagnosticStatus.OK
        status.message = (f'actor {actor} arm {arm} episode {eid}: return '
                          f'{values["return"]:.3f} over {values["length"]} steps'
                          + (' (cut short)' if cut_short else ''))
        status.hardware_id = f'actor{actor}/arm{arm}'
        status.values = [KeyValue(key=k, value=_fmt(values[k])) for k in EPISODE_KEYS]
        recent = self._closed_recently.setdefault(key, [])
        recent.append(eid)
        del recent[:-8]
        data = serialize_message(status)  # once, for the bag and for on_summary
        self.writer.write(EPISODE_TOPIC, data, t_ns)
        self.episodes_written += 1
        if self.on_summary is not None:
            self.on_summary(data)

    def mark_cut_short(self, actor: int, arm: int, episode_id: int, t_wall_ns: int,
                       policy_version: int = -1) -> bool:
        """
        Write the summary of an episode a crash or reset cut short (level WARN).

        Its return is what was recorded so far. Return False (and write nothing) if that
        episode was already summarised, e.g. because the recorder saw the arm move on.
        """
        with self._lock:
            if self.writer.closed:
                return False
            key = (int(actor), int(arm))
            t_ns = self._clamp(t_wall_ns)
            cur = self._open.get(key)
            if cur is not None and cur.episode_id == int(episode_id):
                del self._open[key]
            elif int(episode_id) in self._closed_recently.get(key, ()):
                return False
            else:
                cur = None
            self._summary(key, cur, policy_version, t_ns, cut_short=True,
                          episode_id=episode_id)
            self._last_t = t_ns
            self.writer.flush()
            return True

    def cut_short_actor(self, actor: int, t_wall_ns: int, policy_version: int = -1) -> int:
        """
        Close every open episode of ``actor``'s arms as cut short; return how many.

        For a restarted simulator: its episodes start again at id 0, so the ids seen before
        are forgotten too (an old id that comes again is a new episode, not a repeat).
        """
        with self._lock:
            if self.writer.closed:
                return 0
            t_ns = self._clamp(t_wall_ns)
            keys = sorted(k for k in self._open if k[0] == int(actor))
            for key in keys:
                self._summary(key, self._open.pop(key), policy_version, t_ns, cut_short=True)
            for key in [k for k in self._closed_recently if k[0] == int(actor)]:
                del self._closed_recently[key]
            if int(actor) == self.record_actor:
                self._target_for.clear()
            self._last_t = t_ns
            if keys:
                self.writer.flush(metadata=False)
            return len(keys)

    # -- metrics ---------------------------------------------------------------------------
    def record_metrics(self, metrics: Dict[str, float], t_wall_ns: int):
        """Write each finite number of ``metrics`` on ``/pg_node/metrics/<name>``."""
        with self._lock:
            if self.writer.closed:
                raise RuntimeError('episode recorder is closed')
            t_ns = self._clamp(t_wall_ns)
            for name, value in metrics.items():
                try:
                    value = float(value)
                except (TypeError, ValueError):
                    continue
                if not math.isfinite(value):
                    continue
                topic = metric_topic(name)
                if topic not in self.writer.topics:
                    self.writer.add_topic(topic, Float64, _DEFAULT)
                self.writer.write(topic, Float64(data=value), t_ns)
            self._last_t = t_ns

    def record_randomization(self, msg, t_wall_ns: int):
        """
        Write a simulator's drawn randomization terms on ``/pg_node/randomization``.

        ``msg`` is the ``Float64MultiArray`` table ``sim_node`` publishes (one row per arm
        that drew: ``arm``, ``episode_id``, ``episode_step``, then the values by label), so
        each episode's masses, gains, latency and noise can be read back next to it.
        """
        with self._lock:
            if self.writer.closed:
                raise RuntimeError('episode recorder is closed')
            if RANDOMIZATION_TOPIC not in self.writer.topics:
                self.writer.add_topic(RANDOMIZATION_TOPIC, Float64MultiArray, _DEFAULT)
            self.writer.write(RANDOMIZATION_TOPIC, msg, self._clamp(t_wall_ns))

    def open_episodes(self) -> Dict[tuple, int]:
        """Return ``{(actor, arm): episode_id}`` of the episodes not yet summarised."""
        with self._lock:
            return {k: v.episode_id for k, v in self._open.items()}

    def close(self):
        """Finish the bag (idempotent); open episodes get no summary."""
        with self._lock:
            self.writer.close()

    def __enter__(self):
        """Return the recorder."""
        return self

    def __exit__(self, *exc):
        """Close the bag."""
        self.close()
        return False
