"""The ROS-free training roles: parameters, buffers, wire formats, checkpoints, learning."""
import os

import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.param_schema import ConfigError, Param
from pg_node.common.run_dir import last_progress, read_progress
from pg_node.rl.checkpoint import list_checkpoints, load_latest, save_checkpoint
from pg_node.rl.critic import Critic
from pg_node.rl.learner import EpisodeStats, Learner
from pg_node.rl.policy import GaussianPolicy
from pg_node.rl.rollout_buffer import RolloutBuffer
from pg_node.rl.train_inprocess import train_inprocess
from pg_node.rl.weights import flatten_state, load_flat_state
from pg_node.ros import messages
from pg_node.ros import table_msg
import pytest
import torch
import yaml


@pytest.mark.parametrize('override,key', [
    ('gamma=1.5', 'gamma'),
    ('gamma=-0.1', 'gamma'),
    ('learning_rate=-0.001', 'learning_rate'),
    ('learning_rate=0', 'learning_rate'),
    ('estimator=gea', 'estimator'),
    ('num_envs=2.5', 'num_envs'),
    ('normalize_advantage=maybe', 'normalize_advantage'),
    ('hidden_sizes=[64, -1]', 'hidden_sizes'),
    ('gae_lambda=nan', 'gae_lambda'),
])
def test_bad_values_are_refused_naming_key_value_and_rule(override, key):
    with pytest.raises(ConfigError) as exc:
        load_config(None, [override])
    text = str(exc.value)
    assert key in text and override.split('=', 1)[1].split(',')[0].strip('[') in text
    assert 'expected' in text


def test_overrides_take_key_colon_equals_value_as_ros_users_write_it():
    """``model:=...`` is what ``arm import`` prints (issue 33): the same as ``model=...``."""
    colon = load_config(None, ['model:=arm5_3d', 'critic_node.vf_epochs:=3'])
    assert colon == load_config(None, ['model=arm5_3d', 'critic_node.vf_epochs=3'])
    assert colon['/**']['model'] == 'arm5_3d' and colon['critic_node']['vf_epochs'] == 3


def test_unknown_keys_and_sections_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="unknown parameter 'gama'"):
        load_config(None, ['gama=0.9'])
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump({'critic_node': {'ros__parameters': {'gama': 0.9}}}))
    with pytest.raises(ConfigError, match="unknown parameter 'gama' in section 'critic_node'"):
        load_config(bad)
    bad.write_text(yaml.safe_dump({'critc_node': {'ros__parameters': {}}}))
    with pytest.raises(ConfigError, match="unknown section 'critc_node'"):
        load_config(bad)
    with pytest.raises(ConfigError, match='cannot read config file'):
        load_config(tmp_path / 'missing.yaml')


def test_shared_values_reach_every_node_and_node_values_win(tmp_path):
    f = tmp_path / 'c.yaml'
    f.write_text(yaml.safe_dump({
        '/**': {'ros__parameters': {'num_envs': 8, 'seed': 3}},
        'actor_node': {'ros__parameters': {'n_steps': 4, 'seed': 5}},
    }))
    sim = {'num_envs': Param(1, 'arms', low=1), 'seed': Param(0, 's')}
    cfg = load_config(f, ['learning_rate=3e-4'], {'extra_node': sim})
    assert cfg['extra_node']['num_envs'] == 8
    assert cfg['critic_node']['num_envs'] == 8 and cfg['sim_node']['num_envs'] == 8
    assert 'hidden_sizes' not in cfg['sim_node']
    assert cfg['actor_node']['seed'] == 5 and cfg['critic_node']['seed'] == 3
    assert cfg['learner_node']['learning_rate'] == pytest.approx(3e-4)
    assert cfg['actor_node']['n_steps'] == 4


def test_shipped_config_is_valid_and_equals_the_defaults():
    """config/pg_node.yaml documents the defaults: every node's values equal the table's."""
    from pg_node.common.params import defaults, SCHEMA, SHARED_PARAMS
    from pg_node.common.paths import default_config
    raw = yaml.safe_load(default_config().read_text())
    assert set(raw) == {'/**'} | {f'/**/{name}' for name in SCHEMA}
    assert raw['/**']['ros__parameters'] == {k: p.default for k, p in SHARED_PARAMS.items()}
    cfg = load_config(default_config())
    for name in SCHEMA:
        assert cfg[name] == defaults(name), name
        given = raw[f'/**/{name}']['ros__parameters']
        assert set(given) == set(SCHEMA[name]), name


def test_rollout_buffer_and_message_round_trip():
    rng = np.random.default_rng(0)
    T, N, D, A = 3, 4, 5, 2
    buf = RolloutBuffer(T, N, D, A)
    for t in range(T):
        buf.add_action(rng.normal(size=(N, D)), rng.normal(size=(N, A)), rng.normal(size=N),
                       np.full(N, t), np.arange(N), t + 10)
        with pytest.raises(RuntimeError):
            buf.add_action(np.zeros((N, D)), np.zeros((N, A)), np.zeros(N), 0, 0)
        buf.add_outcome(rng.normal(size=N), rng.random(N) < 0.2, rng.random(N) < 0.2,
                        rng.normal(size=(N, D)))
    ro = buf.finish()
    assert not buf.full and buf.pos == 0
    msg = table_msg.to_msg(*messages.pack_rollout(ro, version=7, actor_id=2, rollout_seq=9))
    header, back = messages.unpack_rollout(*table_msg.from_msg(msg), obs_dim=D, act_dim=A)
    assert header == {'version': 7, 'actor_id': 2, 'rollout_seq': 9, 'n_steps': T,
                      'num_envs': N, 'run': 0}
    for k, v in ro.as_dict().items():
        np.testing.assert_array_equal(getattr(back, k), v)
        assert getattr(back, k).dtype == v.dtype


@pytest.mark.parametrize('breakage', ['label', 'size', 'short', 'flag', 'nan', 'obs_dim'])
def test_malformed_rollouts_are_refused(breakage):
    ro = RolloutBuffer(1, 2, 3, 1)
    ro.add_action(np.zeros((2, 3)), np.zeros((2, 1)), np.zeros(2), 0, 0)
    ro.add_outcome(np.zeros(2), np.zeros(2, bool), np.zeros(2, bool), np.zeros((2, 3)))
    dims, off, data = messages.pack_rollout(ro.finish(), 0, 0, 0)
    obs_dim = 3
    if breakage == 'label':
        dims[2] = ('action', *dims[2][1:])
    elif breakage == 'size':
        dims[1] = ('obs', 4, 4)
    elif breakage == 'short':
        data = data[:-1]
    elif breakage == 'flag':
        data[off + 3 + 1 + 1 + 1] = 0.5     # terminated of row 0
    elif breakage == 'nan':
        data[off] = np.nan
    elif breakage == 'obs_dim':
        obs_dim = 4
    with pytest.raises(ValueError):
        messages.unpack_rollout(dims, off, data, obs_dim=obs_dim)


def test_weights_round_trip_and_layout_mismatch():
    pol = GaussianPolicy(10, 2)
    pol.obs_norm.update(np.random.default_rng(0).normal(size=(50, 10)))
    layout, vec = flatten_state(pol)
    msg = table_msg.to_msg(*messages.pack_weights(layout, vec, 5, 1000))
    header, layout2, vec2 = messages.unpack_weights(*table_msg.from_msg(msg))
    assert header == {'version': 5, 'env_steps': 1000, 'run': 0}
    other = GaussianPolicy(10, 2)
    load_flat_state(other, layout2, vec2)
    obs = torch.randn(3, 10)
    torch.testing.assert_close(other.mean_action(obs), pol.mean_action(obs))
    with pytest.raises(ValueError, match='layout does not match'):
        load_flat_state(GaussianPolicy(10, 3), layout2, vec2)
    bad = vec2.copy()
    bad[0] = np.inf
    with pytest.raises(ValueError, match='non-finite'):
        load_flat_state(other, layout2, bad)


def test_weights_table_is_the_generic_table_of_one_row_per_tensor():
    """pack_weights' shortcut (the vector is the row) builds what table_msg.pack builds."""
    pol = GaussianPolicy(10, 2)
    layout, vec = flatten_state(pol)
    assert [name for name, _ in layout] == list(pol.state_dict())
    np.testing.assert_array_equal(
        vec, np.concatenate([v.double().reshape(-1).numpy() for v in pol.state_dict().values()]))
    fields, pos = {}, 0
    for name, shape in layout:
        n = int(np.prod(shape))
        fields[f'{name}[{"x".join(map(str, shape))}]'] = vec[pos:pos + n][None]
        pos += n
    dims, offset, data = messages.pack_weights(layout, vec, 5, 1000)
    ref = table_msg.pack((5, 1000, 0), fields)
    assert (dims, offset) == (ref[0], ref[1])
    np.testing.assert_array_equal(data, ref[2])
    with pytest.raises(ValueError, match='layout needs'):
        messages.pack_weights(layout, vec[:-1], 5, 1000)
    for broken, match in (([dims[0], ('w',) + dims[1][1:]] + dims[2:], 'name\\[shape\\]'),
                          ([dims[0], ('log_std[3]',) + dims[1][1:]] + dims[2:], 'does not hold')):
        with pytest.raises(ValueError, match=match):
            messages.unpack_weights(broken, offset, data)


def test_checkpoints_are_atomic_and_corrupt_ones_skipped(tmp_path):
    for v in (1, 2, 3):
        save_checkpoint(tmp_path, v, {'x': v}, keep=2)
    assert [v for _, v in list_checkpoints(tmp_path)] == [3, 2]
    assert not [p for p in os.listdir(tmp_path) if p.endswith('.tmp')]
    # corrupt the newest: it is reported and the next one is used
    (tmp_path / 'ckpt_00000003.pt').write_bytes(b'not a checkpoint')
    state, problems = load_latest(tmp_path)
    assert state['version'] == 2 and state['x'] == 2
    assert len(problems) == 1 and 'ckpt_00000003.pt' in problems[0]
    assert load_latest(tmp_path / 'none') == (None, [])


def _cfg(**over):
    return load_config(None, [f'{k}={v}' for k, v in over.items()])


def test_learner_versions_and_keeps_its_weights_on_a_skipped_step():
    cfg = _cfg(num_envs=2)
    learner = Learner(4, 1, {**cfg['learner_node'], **cfg['actor_node']})
    stats = learner.learn(np.zeros((3, 2, 4)), np.zeros((3, 2, 1)), np.zeros((3, 2)),
                          np.random.default_rng(0).normal(size=(3, 2)))
    assert learner.version == 1 and stats['policy_version'] == 1
    # a batch whose step is not finite: skipped, weights and statistics kept, version moves on
    before = {k: v.clone() for k, v in learner.policy.state_dict().items()}
    stats = learner.learn(np.zeros((3, 2, 4)), np.zeros((3, 2, 1)), np.zeros((3, 2)),
                          np.full((3, 2), np.nan))
    assert stats['skipped_updates'] == 1 and learner.version == 2
    for k, v in learner.policy.state_dict().items():
        assert torch.equal(v, before[k]), k


def _stats_one_step_at_a_time(stats, rew, terminated, truncated, episode_id, actor):
    """EpisodeStats.update as the definition reads: each (step, column) in turn."""
    done = np.asarray(terminated) | np.asarray(truncated)
    for t in range(rew.shape[0]):
        for n in range(rew.shape[1]):
            key, ep = (int(actor[t, n]), n), int(episode_id[t, n])
            cur = stats.open.get(key)
            if cur is None or cur[0] != ep:
                cur = stats.open[key] = [ep, 0.0, 0]
            cur[1] += float(rew[t, n])
            cur[2] += 1
            if done[t, n]:
                stats.returns.append(cur[1])
                stats.lengths.append(cur[2])
                del stats.open[key]
    stats.returns, stats.lengths = stats.returns[-stats.window:], stats.lengths[-stats.window:]


@pytest.mark.parametrize('T,N', [(1, 3), (8, 64), (16, 5)])
def test_episode_stats_sum_as_one_step_at_a_time(T, N):
    # the learner adds whole columns at once; returns, lengths and the open sums must be
    # exactly (bit for bit) those of adding one reward at a time, resets and ends included
    rng = np.random.default_rng(T * 100 + N)
    fast, slow = EpisodeStats(window=40), EpisodeStats(window=40)
    eid, step = np.arange(N) * 1000, np.zeros(N, int)
    actor = np.broadcast_to(np.arange(N) % 2, (T, N))
    for _ in range(40):
        rew = rng.normal(size=(T, N)) * 7
        ids, term, trunc = np.empty((T, N), int), np.zeros((T, N), bool), np.zeros((T, N), bool)
        for t in range(T):
            if rng.random() < 0.03:      # a reset: every episode cut short
                eid, step = eid + 1, np.zeros(N, int)
            ids[t], step = eid, step + 1
            trunc[t] = step >= rng.integers(3, 40)
            term[t] = rng.random(N) < 0.02
            ended = term[t] | trunc[t]
            eid, step = np.where(ended, eid + 1, eid), np.where(ended, 0, step)
        fast.update(rew, term, trunc, ids, actor)
        _stats_one_step_at_a_time(slow, rew, term, trunc, ids, actor)
        assert fast.returns == slow.returns and fast.lengths == slow.lengths
        assert fast.open == slow.open
    assert len(fast.returns) >= 10  # episodes did end, in every case


def test_learner_checkpoint_resume(tmp_path):
    cfg = _cfg()
    c = {**cfg['learner_node'], **cfg['actor_node']}
    a = Learner(4, 1, c)
    a.learn(np.ones((2, 2, 4)), np.ones((2, 2, 1)), np.zeros((2, 2)), np.ones((2, 2)))
    a.save(tmp_path)
    b = Learner(4, 1, c)
    state, problems = b.resume(tmp_path)
    assert b.version == a.version == 1 and not problems
    for p, q in zip(a.policy.parameters(), b.policy.parameters()):
        assert torch.equal(p, q)


def test_live_settings_reach_the_updates_and_the_configured_rate_survives_a_resume(tmp_path):
    """``configure`` (what ``ros2 param set`` calls) changes what the next update uses."""
    cfg = _cfg(algo='ppo')
    c = {**cfg['learner_node'], **cfg['actor_node']}
    a = Learner(4, 1, c)
    for name, value in (('learning_rate', 3e-4), ('ent_coef', 0.01), ('clip_range', 0.1),
                        ('n_epochs', 3), ('batch_size', 2), ('max_grad_norm', 0.0),
                        ('normalize_advantage', False)):
        a.configure(name, value)
        assert c[name] == value
    u = a.update
    assert [g['lr'] for g in u.opt.param_groups] == [3e-4]
    assert (u.ent_coef, u.clip_range, u.n_epochs, u.batch_size, u.max_grad_norm,
            u.normalize_advantage) == (0.01, 0.1, 3, 2, 0.0, False)
    a.save(tmp_path)
    # resumed with another configured rate: the configuration wins over the saved optimiser
    b = Learner(4, 1, {**c, 'learning_rate': 5e-3})
    b.resume(tmp_path)
    assert b.update.learning_rate == 5e-3 and a.update.learning_rate == 3e-4
    critic = Critic(4, cfg['critic_node'])
    for name, value, attr, want in (('vf_learning_rate', 2e-3, 'learning_rate', 2e-3),
                                    ('vf_coef', 1.0, 'vf_coef', 1.0),
                                    ('vf_max_grad_norm', 1.0, 'max_grad_norm', 1.0),
                                    ('vf_epochs', 4, 'n_epochs', 4),
                                    ('vf_batch_size', 0, 'batch_size', None),
                                    ('gamma', 0.99, None, None)):
        critic.configure(name, value)
        assert critic.cfg[name] == value
        if attr is not None:
            assert getattr(critic.update, attr) == want


def _random_rollout(n_steps, truncate_at, seed, n_envs=3, obs_dim=4):
    """Return a rollout of random numbers, every episode truncated at ``truncate_at``."""
    buf = RolloutBuffer(n_steps, n_envs, obs_dim, 1)
    rng = np.random.default_rng(seed)
    for t in range(n_steps):
        buf.add_action(rng.normal(size=(n_envs, obs_dim)), rng.normal(size=(n_envs, 1)),
                       np.zeros(n_envs), t, 0)
        buf.add_outcome(rng.normal(size=n_envs), np.zeros(n_envs, bool),
                        np.array([t == truncate_at] * n_envs), rng.normal(size=(n_envs, obs_dim)))
    return buf.finish()


def test_critic_annotates_with_the_chosen_estimator():
    cfg = _cfg(estimator='optimal_baseline', num_envs=3)
    critic = Critic(4, cfg['critic_node'])
    ro = _random_rollout(5, truncate_at=2, seed=0)
    with pytest.raises(ValueError, match='sampling policy'):
        critic.annotate(ro)
    pol = GaussianPolicy(4, 1)
    adv, ret, stats = critic.annotate(ro, pol)
    assert adv.shape == ret.shape == (5, 3) and np.isfinite(adv).all()
    assert {'value_loss', 'explained_variance'} <= set(stats)


def test_critic_judges_with_v_as_it_is_then_fits():
    """critic_node's order (judge, send, fit) gives exactly annotate's phi, targets and V."""
    # one full-batch pass of V (the default fits 10): its reported loss is V's before the step
    cfg = _cfg(estimator='gae', num_envs=3, vf_epochs=1)['critic_node']
    ro = _random_rollout(6, truncate_at=3, seed=1)
    one, two = Critic(4, cfg), Critic(4, cfg)

    def params(critic):
        return torch.cat([p.detach().reshape(-1) for p in critic.value_fn.parameters()])

    before = params(two)
    adv, ret, judged = two.judge(ro)
    assert torch.equal(params(two), before)    # judging updates the normaliser, not V's weights
    v = two.value_fn.value_numpy(ro.obs)
    fitted = two.fit(ro.obs, ret)
    ref_adv, ref_ret, ref_stats = one.annotate(ro)
    assert np.array_equal(adv, ref_adv) and np.array_equal(ret, ref_ret)
    assert np.array_equal(flatten_state(one.value_fn)[1], flatten_state(two.value_fn)[1])
    assert not torch.equal(params(two), before)
    # the judged metrics are V's before its step: for A2C's one full-batch step, the loss
    # and explained variance that step reports (float32 there, float64 here)
    assert judged['value_loss'] == pytest.approx(np.mean((ret - v) ** 2), rel=1e-12)
    assert judged['value_loss'] == pytest.approx(fitted['value_loss'], rel=1e-5)
    assert judged['explained_variance'] == pytest.approx(fitted['explained_variance'],
                                                         abs=1e-5)


@pytest.mark.slow
def test_inprocess_a2c_learns_to_reach():
    """
    200k steps of A2C beat the untrained policy by far more than the noise.

    Both policies are evaluated on the same 100 episodes (same seeds, so the same starts
    and targets): the per-episode differences are paired, and their standard error is the
    noise the gain is compared with.
    """
    from pg_node.rl.evaluate import evaluate_policy
    from pg_node.rl.learner import make_policy
    # one pass of V per batch at gamma 0.9 (the defaults before issue 48): the point is that
    # A2C learns, at half the CPU of ten passes (bench/bench_reach.py measures the defaults)
    cfg = _cfg(num_envs=16, gamma=0.9, vf_epochs=1)
    policy = make_policy(10, 2, {**cfg['learner_node'], **cfg['actor_node']})
    untrained = evaluate_policy(policy, 'reacher2', 100)
    summary = train_inprocess(cfg, 200_000)
    diff = np.array(summary['eval_returns']) - np.array(untrained['eval_returns'])
    se = diff.std(ddof=1) / np.sqrt(diff.size)
    assert diff.mean() > 6 * se, (untrained['eval_return'], summary['eval_return'], se)
    assert summary['eval_return'] > -10
    assert summary['policy_version'] == summary['learner'].version > 1000


def test_read_progress_leaves_out_a_line_still_being_written(tmp_path):
    """A reader racing the learner sees complete rows only, never a number cut in two."""
    path = tmp_path / 'progress.csv'
    path.write_text('wall_seconds,env_steps,episode_return\n1.0,512,-40.5\n2.0,1024,\n'
                    '3.0,1536,-3')         # the learner is writing -38.25: not finished
    rows = read_progress(path)
    assert [r['env_steps'] for r in rows] == [512.0, 1024.0]
    assert rows[0]['episode_return'] == -40.5 and np.isnan(rows[1]['episode_return'])
    path.write_text(path.read_text() + '8.25\n')
    assert read_progress(path)[-1] == {'wall_seconds': 3.0, 'env_steps': 1536.0,
                                       'episode_return': -38.25}
    assert read_progress(tmp_path / 'missing.csv') == []


def test_last_progress_reads_the_newest_finished_row_from_the_tail(tmp_path):
    """The watcher's tail read gives read_progress's last row, from any cut of the file."""
    path = tmp_path / 'progress.csv'
    assert last_progress(path) is None
    rows = ''.join(f'{i}.5,{512 * i},-{i}.25\n' for i in range(1, 400))
    path.write_text('wall_seconds,env_steps,episode_return\n' + rows + '400.5,204')
    assert len(read_progress(path)) == 399
    for tail in (8192, 100, 37, 5):         # the tail starts inside a row, or holds none
        assert last_progress(path, tail) == (read_progress(path)[-1] if tail >= 37 else None)
    path.write_text(path.read_text() + '800,-400.25\n')
    assert last_progress(path, 100) == {'wall_seconds': 400.5, 'env_steps': 204800.0,
                                        'episode_return': -400.25}


def test_docs_parameter_table_is_the_parameter_table():
    """docs/ros_graph.md's table is generated from the table the nodes declare (no drift)."""
    from pathlib import Path
    from pg_node.tools.param_docs import markdown_table
    page = (Path(__file__).resolve().parent.parent / 'docs' / 'ros_graph.md').read_text()
    start = page.index('<!-- parameter table:')
    end = page.index('<!-- end of parameter table -->')
    shown = page[start:end].split('\n', 1)[1].strip()
    assert shown == markdown_table()
