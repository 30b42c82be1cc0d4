"""
Tests of pg_node.control.obs_layout and of every place that lays out an observation.

The layout itself: its slices tile the vector in order and its card form round-trips. Then,
for each shipped arm model, each site that builds or reads an observation (``ArmTask``,
``ObservationBuilder``, the bag recorder, the policy card, ``play``) against the layout and
against the arm's true state, so that a site that lays the fields out its own way fails here.
"""
from collections import defaultdict
import doctest
import json
from pathlib import Path

import mujoco
import numpy as np
from pg_node.bag.recorder import EpisodeRecorder
from pg_node.common.paths import resolve_model
from pg_node.control import obs_layout
from pg_node.control.obs_layout import FIELDS, ObsLayout
from pg_node.rl.trained_policy import make_card
from pg_node.ros.messages import Batch
from pg_node.sim.arm_task import ArmTask
from pg_node.sim.observation import ObservationBuilder
from pg_node.tools.play import Episodes
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

MODELS = sorted(p.stem for p in (Path(__file__).parent.parent / 'pg_node' / 'sim'
                                 / 'models').glob('*.xml'))
SHAPES = [(('a',), 1), (('a', 'b'), 2), (('a', 'b', 'c', 'd', 'e'), 3), (tuple('1234567'), 3)]


def test_docstring_examples():
    failures, tried = doctest.testmod(obs_layout)
    assert tried > 0 and failures == 0


def test_the_shipped_models_are_there():
    assert MODELS == ['arm5_3d', 'arm7', 'reacher2']


@pytest.mark.parametrize('joints, k', SHAPES)
def test_slices_tile_the_observation_in_order(joints, k):
    layout = ObsLayout(joints, k)
    nj = len(joints)
    sizes = {'cos_q': nj, 'sin_q': nj, 'target': k, 'qdot': nj, 'fingertip_minus_target': k}
    assert list(layout.slices) == list(FIELDS) == list(sizes)
    start = 0
    for name in FIELDS:
        sl = layout.slices[name]
        assert (sl.start, sl.stop, sl.step) == (start, start + sizes[name], None), name
        assert layout.field_size(name) == sizes[name]
        start = sl.stop
    assert layout.size == start == 3 * nj + 2 * k
    covered = np.concatenate([np.arange(layout.size)[layout.slices[n]] for n in FIELDS])
    np.testing.assert_array_equal(covered, np.arange(layout.size))


def test_reacher2s_layout_is_the_one_its_policies_were_trained_with():
    layout = ObsLayout(('joint0', 'joint1'), 2)
    assert [(s.start, s.stop) for s in layout.slices.values()] == [
        (0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    # what every card and bag written so far holds: it must keep reading
    joints, axes = ['joint0', 'joint1'], ['x', 'y']
    assert layout.card() == [
        {'name': 'cos_q', 'size': 2, 'of': joints},
        {'name': 'sin_q', 'size': 2, 'of': joints},
        {'name': 'target', 'size': 2, 'of': axes},
        {'name': 'qdot', 'size': 2, 'of': joints},
        {'name': 'fingertip_minus_target', 'size': 2, 'of': axes},
    ]


@pytest.mark.parametrize('joints, k', SHAPES)
def test_card_form_round_trips(joints, k):
    layout = ObsLayout(joints, k)
    card = json.loads(json.dumps(layout.card()))
    back = ObsLayout.from_card(card)
    assert back == layout and back.slices == layout.slices and back.size == layout.size
    assert back.card() == card


def test_a_layout_that_is_not_pg_nodes_is_refused():
    card = ObsLayout(('a', 'b'), 2).card()
    swapped = [card[0], card[1], card[3], card[2], card[4]]
    resized = [dict(card[0]), *card[1:]]
    resized[0]['size'] = 3
    for bad in (swapped, resized, card[:4], card + [{'name': 'extra', 'size': 1}],
                [{'name': 'cos_q'}], ['cos_q']):
        with pytest.raises(ValueError, match='is not the one pg_node builds'):
            ObsLayout.from_card(bad)
    for joints, k in (((), 2), (('a',), 0), (('a',), 4), (('a',), 1.5)):
        with pytest.raises(ValueError, match='at least one joint and a 1-3 D target'):
            ObsLayout(joints, k)
    with pytest.raises(KeyError, match="no observation field 'q'"):
        ObsLayout(('a',), 1).field_size('q')


@pytest.fixture(scope='module', params=MODELS)
def arm(request):
    """Return a stepped ArmTask of one shipped model, with its name and its layout."""
    task = ArmTask(resolve_model(request.param), num_envs=3, seed=4, max_episode_steps=None)
    task.reset()
    rng = np.random.default_rng(0)
    for _ in range(5):
        task.step(rng.uniform(task.spec.ctrl_low, task.spec.ctrl_high, (3, task.act_dim)))
    for data in task.datas:     # positions of the step's angles (test_export says why)
        mujoco.mj_kinematics(task.model, data)
    yield request.param, task, ObsLayout(task.spec.joint_names, task.spec.target_dim)
    task.close()


def test_every_site_has_the_layouts_size(arm, tmp_path):
    name, task, layout = arm
    assert task.spec.obs_layout == layout                  # what actor and learner size by
    assert (task.obs_layout, task.obs_dim) == (layout, layout.size)
    assert task.observe().shape == (3, layout.size)
    builder = ObservationBuilder(task.model)
    assert (builder.obs_layout, builder.obs_dim) == (layout, layout.size)
    rec = EpisodeRecorder(tmp_path / 'bag', name, record_arms=1)
    assert (rec.obs_layout, rec.obs_dim) == (layout, layout.size)
    rec.close()
    card = make_card(name, layout.size, task.act_dim, 2, {})
    assert card['observation']['size'] == layout.size
    assert card['observation']['layout'] == layout.card()
    assert ObsLayout.from_card(json.loads(json.dumps(card))['observation']['layout']) == layout
    assert card['joint_names'] == list(layout.joint_names)


def test_the_tasks_observation_holds_each_field_of_the_true_state(arm):
    _, task, layout = arm
    obs = task.observe()
    q, qdot, _ = task.joint_state()
    target, tip = task.target_pos(), task.fingertip_pos()
    k = layout.target_dim
    assert np.ptp(q) > 0.01 and np.abs(qdot).max() > 0.01     # a state worth telling apart
    want = {'cos_q': np.cos(q), 'sin_q': np.sin(q), 'target': target[:, :k], 'qdot': qdot,
            'fingertip_minus_target': (tip - target)[:, :k]}
    for name in FIELDS:
        np.testing.assert_allclose(obs[:, layout.slices[name]], want[name], rtol=0,
                                   atol=1e-12, err_msg=name)


def test_the_builder_makes_the_tasks_observation_field_by_field(arm):
    """From the same angles, velocities and goal, the builder and the task agree."""
    _, task, layout = arm
    obs = task.observe()
    q, qdot, _ = task.joint_state()
    built = ObservationBuilder(task.model)(q, qdot, task.target_pos())
    assert built.shape == obs.shape
    for name in FIELDS:
        atol = 1e-9 if name == 'fingertip_minus_target' else 1e-12
        np.testing.assert_allclose(built[:, layout.slices[name]], obs[:, layout.slices[name]],
                                   rtol=0, atol=atol, err_msg=name)


def test_play_reads_angles_and_distance_through_the_cards_layout(arm):
    _, task, layout = arm
    obs = task.observe()
    q = task.joint_state()[0]
    episodes = Episodes(ObsLayout.from_card(layout.card()))
    for i in range(len(obs)):
        np.testing.assert_allclose(episodes.angles(obs[i]), np.angle(np.exp(1j * q[i])),
                                   rtol=0, atol=1e-12)
    vec = (task.fingertip_pos() - task.target_pos())[:, :layout.target_dim]
    np.testing.assert_allclose(np.linalg.norm(obs[:, episodes.vec], axis=1),
                               np.linalg.norm(vec, axis=1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(obs[:, episodes.target],
                               task.target_pos()[:, :layout.target_dim], rtol=0, atol=1e-12)


def test_the_recorder_turns_the_observation_back_into_the_true_joint_state(arm, tmp_path):
    name, task, layout = arm
    obs = task.observe()
    q, qdot, _ = task.joint_state()
    goal = task.target_pos()
    n, T = task.num_envs, 1
    shape = (T, n)
    batch = Batch(obs=obs[None], act=np.zeros((T, n, task.act_dim)), rew=np.zeros(shape),
                  terminated=np.zeros(shape, bool), truncated=np.zeros(shape, bool),
                  ep_step=np.full(shape, 3), episode_id=np.arange(n)[None],
                  seq=np.zeros(shape, int), actor=np.zeros(shape, int), logp=np.zeros(shape),
                  adv=np.zeros(shape), ret=np.zeros(shape))
    rec = EpisodeRecorder(tmp_path / 'bag', name, record_arms=n, split_max_episodes=0)
    rec.record_batch(batch, policy_version=0, t_wall_ns=1_000_000_000)
    rec.close()
    store, msgs = get_typestore(Stores.ROS2_JAZZY), defaultdict(list)
    with Reader(tmp_path / 'bag') as reader:
        for c, _, raw in reader.messages():
            msgs[c.topic].append(store.deserialize_cdr(raw, c.msgtype))
    (js,) = msgs['/joint_states']
    np.testing.assert_allclose(np.reshape(js.position, q.shape), np.angle(np.exp(1j * q)),
                               rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.reshape(js.velocity, qdot.shape), qdot)
    k = layout.target_dim
    points = {p.header.frame_id: [p.point.x, p.point.y, p.point.z] for p in msgs['/target']}
    for i in range(n):
        np.testing.assert_allclose(points[f'arm{i}'][:k], goal[i, :k], rtol=0, atol=1e-12)
