"""
Tests of pg_node.bag.recorder: batches from a real ArmTask, read back with PyPI rosbags.

Batches are built by stepping :class:`pg_node.sim.arm_task.ArmTask` with random actions (some
outside the control range), so observations, rewards and episode boundaries are the real
ones, and the true joint positions, velocities and episode returns are known.
"""
from collections import defaultdict

import numpy as np
from pg_node.bag.recorder import EpisodeRecorder, metric_topic, parse_episode
from pg_node.common.paths import resolve_model
from pg_node.ros.messages import Batch
from pg_node.sim.arm_task import ArmTask
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores
import yaml

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
T0 = 1_700_000_000_000_000_000
WALL_STEP = 250_000_000  # ns of wall time between record_batch calls
MODEL = resolve_model('reacher2')


class Source:
    """Two actors' ArmTasks side by side, producing Batches and remembering the truth."""

    def __init__(self, arms=(3, 2), max_episode_steps=7, seed=3, torque=None):
        self.tasks = [ArmTask(MODEL, num_envs=n, seed=seed + 100 * a,
                              max_episode_steps=max_episode_steps)
                      for a, n in enumerate(arms)]
        self.obs = [task.reset() for task in self.tasks]
        self.seq = [0 for _ in self.tasks]
        self.rng = np.random.default_rng(seed)
        self.torque = torque            # None: random actions; a number: that on every joint
        self.truth = []  # per step: (qpos, qvel) of actor 0, each (n_arms, n_joints)
        self.returns = {}  # (actor, arm, episode_id) -> Gymnasium-style episode return
        self.rewards = defaultdict(float)  # (actor, arm, episode_id) -> sum of rewards

    def batch(self, T):
        """Step every task T times; return the Batch the critic would have sent."""
        cols = defaultdict(list)
        for _ in range(T):
            row = defaultdict(list)
            for a, task in enumerate(self.tasks):
                pos, vel, _ = task.joint_state()
                if a == 0:
                    self.truth.append((pos, vel))
                act = (self.rng.normal(0.0, 1.0, (task.num_envs, task.act_dim))
                       if self.torque is None
                       else np.full((task.num_envs, task.act_dim), self.torque))
                ep_step, ep_id = task.episode_step.copy(), task.episode_id.copy()
                obs_before = self.obs[a]
                self.obs[a], rew, term, trunc, info = task.step(
                    np.clip(act, task.spec.ctrl_low, task.spec.ctrl_high))
                for i in range(task.num_envs):
                    self.rewards[(a, i, int(ep_id[i]))] += rew[i]
                    if not np.isnan(info['episode_return'][i]):
                        self.returns[(a, i, int(info['final_episode_id'][i]))] = (
                            info['episode_return'][i])
                row['obs'].append(obs_before)
                row['act'].append(act)
                row['rew'].append(rew)
                row['terminated'].append(term)
                row['truncated'].append(trunc)
                row['ep_step'].append(ep_step)
                row['episode_id'].append(ep_id)
                row['seq'].append(np.full(task.num_envs, self.seq[a]))
                row['actor'].append(np.full(task.num_envs, a))
                self.seq[a] += 1
            for k, v in row.items():
                cols[k].append(np.concatenate(v, axis=0))
        arrays = {k: np.stack(v) for k, v in cols.items()}
        shape = arrays['rew'].shape
        return Batch(logp=np.zeros(shape), adv=np.zeros(shape), ret=np.zeros(shape), **arrays)

    def close(self):
        for task in self.tasks:
            task.close()


def read_bag(path):
    """Return {topic: [(log_time, msg)]}, the connections and the metadata of a bag."""
    out = defaultdict(list)
    with Reader(path) as reader:
        conns = {c.topic: c for c in reader.connections}
        for c, t, raw in reader.messages():
            out[c.topic].append((t, TYPESTORE.deserialize_cdr(raw, c.msgtype)))
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())
    return out, conns, meta


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    """Record 6 batches of 5 steps from 3 + 2 arms (episodes of 7 steps), then metrics."""
    path = tmp_path_factory.mktemp('rec') / 'bag'
    src = Source()
    rec = EpisodeRecorder(path, MODEL, record_arms=2, split_max_episodes=0)
    T, n_batches = 5, 6
    for b in range(n_batches):
        rec.record_batch(src.batch(T), policy_version=b, t_wall_ns=T0 + (b + 1) * WALL_STEP)
        rec.record_metrics({'policy_loss': 0.5 - b, 'episode_return': float('nan'),
                            'note': 'not a number'}, T0 + (b + 1) * WALL_STEP)
    open_before = rec.open_episodes()
    assert rec.mark_cut_short(1, 1, open_before[(1, 1)], T0 + 10 * WALL_STEP, 99)
    assert not rec.mark_cut_short(1, 1, open_before[(1, 1)], T0 + 10 * WALL_STEP)
    written = rec.episodes_written
    rec.close()
    rec.close()
    src.close()
    return path, src, open_before, written, T, n_batches


def test_topic_counts_types_and_qos(recorded):
    path, src, open_before, written, T, n_batches = recorded
    msgs, conns, meta = read_bag(path)
    steps = T * n_batches
    for topic in ('/clock', '/joint_states', '/pg_node/commands', '/pg_node/reward'):
        assert len(msgs[topic]) == steps, topic
    # episodes of 7 steps over 30 steps: arms start episodes at steps 0, 7, 14, 21, 28
    assert len(msgs['/target']) == 2 * 5
    finished = 5 * 4  # 5 arms, 4 completed episodes each
    assert len(msgs['/pg_node/episode']) == finished + 1 == written
    assert len(msgs['/pg_node/metrics/policy_loss']) == n_batches
    assert '/pg_node/metrics/episode_return' not in msgs  # NaN is not written
    assert conns['/target'].msgtype == 'geometry_msgs/msg/PointStamped'
    assert conns['/pg_node/episode'].msgtype == 'diagnostic_msgs/msg/DiagnosticStatus'
    qos = {e['topic_metadata']['name']: e['topic_metadata']['offered_qos_profiles']
           for e in meta['rosbag2_bagfile_information']['topics_with_message_count']}
    assert set(qos) >= {'/clock', '/joint_states', '/target', '/pg_node/commands',
                        '/pg_node/reward', '/pg_node/episode', '/pg_node/metrics/policy_loss'}
    assert qos['/target'][0]['durability'] == 'transient_local'
    assert qos['/target'][0]['depth'] == 2
    assert qos['/pg_node/episode'][0]['depth'] == 100
    custom = meta['rosbag2_bagfile_information']['custom_data']
    assert custom['pg_node.model'] == str(MODEL)
    assert float(custom['pg_node.dt']) == pytest.approx(0.02)


def test_joint_states_are_the_true_state(recorded):
    path, src, *_ = recorded
    msgs, _, _ = read_bag(path)
    js = msgs['/joint_states']
    assert list(js[0][1].name) == ['arm0/joint0', 'arm0/joint1', 'arm1/joint0', 'arm1/joint1']
    for (t, msg), (qpos, qvel) in zip(js, src.truth):
        got = np.asarray(msg.position).reshape(2, 2)
        np.testing.assert_allclose(got, qpos[:2], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(np.asarray(msg.velocity).reshape(2, 2), qvel[:2])
    # joint0 is unlimited: the test is only worth something if some angle left (-pi, pi]
    # or at least moved; the random torques move it by more than 0.1 rad
    moved = np.ptp([q[0][0, 0] for q in src.truth])
    assert moved > 0.1


def test_joint_states_keep_a_spinning_joints_actual_angle(tmp_path):
    """
    Full torque spins the unlimited shoulder past pi: the bag has its actual angle.

    sim_node publishes the joint's position as MuJoCo has it (a continuous joint is not
    wrapped, as ROS drivers do); the bag, which only sees cos and sin in the observation,
    must show the same numbers, across batches and from each episode's start.
    """
    src = Source(arms=(2,), max_episode_steps=60, torque=1.0)
    rec = EpisodeRecorder(tmp_path / 'bag', MODEL, record_arms=2, split_max_episodes=0)
    for b in range(15):
        rec.record_batch(src.batch(8), policy_version=b, t_wall_ns=T0 + (b + 1) * WALL_STEP)
    rec.close()
    src.close()
    js = read_bag(tmp_path / 'bag')[0]['/joint_states']
    assert len(js) == len(src.truth) == 120
    for (t, msg), (qpos, _) in zip(js, src.truth):
        np.testing.assert_allclose(np.asarray(msg.position).reshape(2, 2), qpos,
                                   rtol=0, atol=1e-9)
    shoulder = np.array([q[0, 0] for q, _ in src.truth])
    assert np.abs(shoulder).max() > 2 * np.pi       # it did leave (-pi, pi], several times


def test_effort_commands_rewards_and_stamps(recorded):
    path, src, *_ = recorded
    msgs, _, _ = read_bag(path)
    gear = 200.0
    for (_, js), (_, cmd), (_, rew), (_, clk) in zip(
            msgs['/joint_states'], msgs['/pg_node/commands'], msgs['/pg_node/reward'],
            msgs['/clock']):
        data = np.asarray(cmd.data)
        assert np.all(np.abs(data) <= 1.0)
        np.testing.assert_allclose(np.asarray(js.effort), data * gear, rtol=0, atol=1e-12)
        assert [d.label for d in cmd.layout.dim] == ['arm', 'actuator']
        assert len(rew.data) == 2
        assert (js.header.stamp.sec, js.header.stamp.nanosec) == (
            clk.clock.sec, clk.clock.nanosec)
    clipped = np.concatenate([np.asarray(m.data) for _, m in msgs['/pg_node/commands']])
    assert np.any(np.abs(clipped) == 1.0)  # some sampled actions were clipped
    stamps = [m.clock.sec + m.clock.nanosec * 1e-9 for _, m in msgs['/clock']]
    np.testing.assert_allclose(stamps, 0.02 * np.arange(len(stamps)), atol=1e-9)


def test_log_times_spread_between_calls(recorded):
    path, src, open_before, written, T, n_batches = recorded
    msgs, _, _ = read_bag(path)
    times = [t for t, _ in msgs['/clock']]
    assert times == sorted(times)
    # first batch: spread over T * dt before its call; later ones over the previous call
    assert times[T - 1] == T0 + WALL_STEP
    np.testing.assert_array_equal(np.diff(times[T:2 * T]), WALL_STEP // T)
    assert times[-1] == T0 + n_batches * WALL_STEP
    assert all(t % WALL_STEP == 0 for t, _ in msgs['/pg_node/episode'])


def test_episode_summaries_sum_rewards_across_batches(recorded):
    path, src, open_before, *_ = recorded
    msgs, _, _ = read_bag(path)
    eps = [parse_episode(m) for _, m in msgs['/pg_node/episode']]
    normal = [e for e in eps if not e['cut_short']]
    assert len(normal) == 20
    for e in normal:
        key = (int(e['actor']), int(e['arm']), int(e['episode_id']))
        assert e['return'] == pytest.approx(src.returns[key], abs=1e-12)
        assert e['return'] == pytest.approx(src.rewards[key], abs=1e-12)
        assert e['length'] == 7 and e['recorded_steps'] == 7
        assert e['truncated'] == 1.0 and e['terminated'] == 0.0 and e['level'] == 0
    # summaries name the policy version of the batch in which the episode ended
    assert {e['policy_version'] for e in normal} == {1, 2, 4, 5}
    (cut,) = [e for e in eps if e['cut_short']]
    key = (1, 1, open_before[(1, 1)])
    assert (int(cut['actor']), int(cut['arm']), int(cut['episode_id'])) == key
    assert cut['level'] == 1 and cut['policy_version'] == 99
    assert cut['return'] == pytest.approx(src.rewards[key], abs=1e-12)
    assert cut['length'] == 2  # steps 28 and 29 of 30


def test_target_is_the_goal_of_each_episode(recorded):
    path, src, *_ = recorded
    msgs, _, _ = read_bag(path)
    for (_, point), first_step in zip(msgs['/target'], [0, 0, 7, 7, 14, 14, 21, 21, 28, 28]):
        assert point.header.frame_id in ('arm0', 'arm1')
        assert point.header.stamp.sec + point.header.stamp.nanosec * 1e-9 == pytest.approx(
            0.02 * first_step)
        assert point.point.z == 0.0
        assert np.hypot(point.point.x, point.point.y) < 0.2


def test_reset_mid_episode_is_cut_short_and_split_by_episodes(tmp_path):
    src = Source(arms=(2,), max_episode_steps=4, seed=5)
    rec = EpisodeRecorder(tmp_path / 'bag', 'reacher2', record_arms=4, split_max_episodes=3)
    rec.record_batch(src.batch(3), 0, T0 + WALL_STEP)
    src.tasks[0].reset_env(1)  # a world reset of arm 1 in the middle of its episode
    rec.record_batch(src.batch(6), 1, T0 + 2 * WALL_STEP)
    rec.record_metrics({'env_steps': 18}, T0 + 2 * WALL_STEP)
    rec.close()
    src.close()
    assert len(list((tmp_path / 'bag').glob('*.mcap'))) >= 2
    msgs, _, _ = read_bag(tmp_path / 'bag')
    eps = [parse_episode(m) for _, m in msgs['/pg_node/episode']]
    cut = [e for e in eps if e['cut_short']]
    assert len(cut) == 1 and cut[0]['arm'] == 1 and cut[0]['recorded_steps'] == 3
    assert len(eps) == rec.episodes_written == 1 + 2 + 1  # arm 0 ended twice, arm 1 once
    assert len(msgs['/joint_states']) == 9
    assert msgs['/pg_node/metrics/env_steps'][0][1].data == 18.0
    assert metric_topic('loss/pi') == '/pg_node/metrics/loss_pi'


def test_closed_recorder_refuses_batches(tmp_path):
    rec = EpisodeRecorder(tmp_path / 'bag', MODEL)
    rec.close()
    src = Source(arms=(1,))
    with pytest.raises(RuntimeError):
        rec.record_batch(src.batch(1), 0, T0)
    src.close()


def test_docstring_examples():
    import doctest
    import pg_node.bag.recorder
    failures, tried = doctest.testmod(pg_node.bag.recorder)
    assert tried >= 1 and failures == 0


def test_the_scene_of_arm_0_is_drawn_at_most_once_per_period(tmp_path):
    """
    With ``draw_scene``, ``/pg_node/scene`` holds arm 0 as sim_node draws it, for RViz.

    At most one message per 0.5 s of log time (the steps come 50 ms apart), the first at
    the first step; each has the fingertip where MuJoCo puts it for the recorded angles,
    the episode's goal, and the trail of the episode's steps so far.
    """
    import mujoco
    from pg_node.ros.scene_msg import scene_markers
    from pg_node.sim.arm_task import ArmSpec
    path = tmp_path / 'bag'
    src = Source()
    rec = EpisodeRecorder(path, MODEL, record_arms=2, split_max_episodes=0,
                          draw_scene=scene_markers, scene_period=0.5)
    goals, at = [], ArmSpec.from_model(src.tasks[0].model).obs_layout.slices['target']
    for b in range(8):
        batch = src.batch(5)
        goals += [obs[0, at] for obs in batch.obs]
        rec.record_batch(batch, policy_version=b, t_wall_ns=T0 + (b + 1) * WALL_STEP)
    rec.close()
    src.close()
    msgs, conns, meta = read_bag(path)
    assert conns['/pg_node/scene'].msgtype == 'visualization_msgs/msg/MarkerArray'
    steps = [t for t, _ in msgs['/clock']]
    scenes = msgs['/pg_node/scene']
    times = [t for t, _ in scenes]
    assert times[0] == steps[0] and set(times) <= set(steps) and len(scenes) >= 3
    for a, b in zip(times, times[1:]):              # the first step 0.5 s after the last
        assert b - a >= 500_000_000 and not [t for t in steps if a + 500_000_000 <= t < b]
    model = mujoco.MjModel.from_xml_path(str(MODEL))
    spec, data = ArmSpec.from_model(model), mujoco.MjData(model)
    for t, msg in scenes:
        k = steps.index(t)
        data.qpos[spec.qpos_adr] = src.truth[k][0][0]
        mujoco.mj_kinematics(model, data)
        spheres = [m for m in msg.markers if m.type == 2]
        goal, tip = spheres[-2].pose.position, spheres[-1].pose.position
        np.testing.assert_allclose([tip.x, tip.y, tip.z], data.site_xpos[spec.fingertip_site],
                                   atol=1e-9)
        np.testing.assert_allclose([goal.x, goal.y], goals[k], atol=1e-9)
        trail = [m for m in msg.markers if m.type == 4]             # LINE_STRIP
        episode_step = k % 7                        # episodes of 7 steps from step 0
        assert len(trail[0].points) == (episode_step + 1 if episode_step else 0)
        assert {m.header.frame_id for m in msg.markers} == {'world'}
