"""
A run's identity on the network (pg_node.common.run): names, tokens, and the wire formats.

Unit tests, no DDS: the run token travels in every header of pg_node's messages (and in an
actor's commands), a message without one is of the empty run id, and ``train`` puts every
node of a run in the run's namespace. The nodes' dropping of another run's messages is
tested against each running node in ``test_faults.py``; two trainings on one domain in
``test_training_graph.py``.
"""
import doctest
import os

import numpy as np
from pg_node.common import run
from pg_node.common.config_files import load_config
from pg_node.common.param_schema import ConfigError
from pg_node.ros import command, messages, table_msg, transition
import pytest
from sample_messages import make_rollout


def test_docstring_examples():
    failures, tried = doctest.testmod(run)
    assert tried >= 8 and failures == 0


@pytest.mark.parametrize('bad', ['1run', 'a-b', 'a/b', 'x' * 65, 'é'])
def test_run_id_must_be_a_ros_name_token(bad):
    with pytest.raises(ValueError):
        run.check_run_id(bad)
    with pytest.raises(ConfigError, match="parameter 'run_id'"):
        load_config(None, [f'run_id={bad}'])


def test_tokens_tell_runs_apart():
    ids = ['', 'exp1', 'exp2', 'run_20261203_081652', 'run_20261203_081653']
    tokens = [run.run_token(i) for i in ids]
    assert len(set(tokens)) == len(ids) and tokens[0] == 0
    assert all(float(t) == t and 0 <= t < 2 ** 32 for t in tokens)   # exact in a header


def test_rollout_batch_and_weights_carry_the_run_token():
    token = run.run_token('exp1')
    header, _ = messages.unpack_rollout(*table_msg.from_msg(make_rollout(3, run=token)))
    assert header['run'] == token and header['rollout_seq'] == 3
    assert not messages.foreign(header, token) and messages.foreign(header, 0)
    dims, offset, data = messages.pack_weights([('w', (2,))], [1.0, 2.0], 4, 100, run=token)
    header, layout, vec = messages.unpack_weights(dims, offset, data)
    assert (header['run'], header['version'], layout, vec.tolist()) == (
        token, 4, [('w', (2,))], [1.0, 2.0])
    # a header one value shorter (sent without a token) is of the empty run id
    header, _, _ = messages.unpack_weights(dims, offset - 1, np.delete(data, 2))
    assert header['run'] == 0 and header['env_steps'] == 100


@pytest.mark.parametrize('groups', [1, 3])
def test_transition_carries_the_run_token(groups):
    n = 2
    tr = transition.Transition(seq=5, obs=np.zeros((n, 4)), reward=np.zeros(n),
                               terminated=np.zeros(n, bool), truncated=np.zeros(n, bool),
                               final_obs=np.zeros((n, 4)), episode_id=np.arange(n),
                               episode_step=np.zeros(n, int), first_arm=2 if groups > 1 else 0,
                               groups=groups, run=run.run_token('exp1'))
    back = transition.from_cdr(transition.to_cdr(tr))
    assert (back.seq, back.first_arm, back.groups, back.run) == (
        5, tr.first_arm, groups, run.run_token('exp1'))
    dims, offset, data = transition.pack(tr)
    assert offset == (2 if groups == 1 else 4) and data[offset - 1] == tr.run
    old = transition.unpack(dims, offset - 1, np.delete(data, offset - 1))  # no token
    assert (old.seq, old.groups, old.run) == (5, groups, 0)


def test_commands_carry_the_run_token():
    msg = table_msg.from_cdr(command.to_cdr(np.zeros((2, 3)), seq=9, run=run.run_token('a')))
    assert (command.transition_of(msg), command.run_of(msg)) == (9, run.run_token('a'))
    assert command.run_of(command.to_msg(np.zeros((2, 3)))) == 0


def test_train_puts_every_node_in_the_runs_namespace(tmp_path):
    from pg_node.tools.train import node_commands

    def ros_args(cmd):
        return dict(zip(cmd[::1], cmd[1:]))

    for pairs in (1, 2):
        cfg = load_config(None, [f'num_actors={pairs}', 'run_id=exp1', 'num_envs=4'])
        cmds = node_commands(tmp_path / 'params.yaml', cfg, compose=True)
        assert ros_args(cmds['critic_and_learner'])['-r'] == '__ns:=/exp1'
        if pairs == 1:
            assert ros_args(cmds['sim_and_actor'])['-r'] == '__ns:=/exp1'
            continue
        for i in range(pairs):
            cmd = cmds[f'sim_and_actor_{i}']
            # one namespace remap only: rcl takes the first (two put both pairs in /exp1)
            assert [a for a in cmd if a.startswith('__ns:=')] == [f'__ns:=/exp1/arm{i}']
            own = (tmp_path / f'params_arm{i}.yaml').read_text()
            assert f'/exp1/arm{i}/sim_node:' in own and f'/exp1/arm{i}/actor_node:' in own


def test_train_takes_overrides_before_and_after_options():
    """docs/many_runs.md: train --part workers --actors 2,3 --run-id NAME num_actors=N."""
    from pg_node.tools.train import parse_args
    args = parse_args(['gamma=0.5', '--part', 'workers', '--actors', '2,3', '--run-id', 'x',
                       'num_actors=4'])
    assert args.overrides == ['gamma=0.5', 'num_actors=4'] and args.actors == '2,3'


def test_train_names_the_run_after_its_dir_and_keeps_dds_local(tmp_path):
    from pg_node.tools.train import discovery_env, parse_args, resolve_config
    cfg = resolve_config(parse_args(['--run-dir', str(tmp_path / '2026-12-03 exp.1')]))
    assert cfg['/**']['run_id'] == 'run_2026_12_03_exp_1'
    cfg = resolve_config(parse_args(['--run-dir', str(tmp_path), '--run-id', 'mine']))
    assert cfg['/**']['run_id'] == 'mine'
    cfg = resolve_config(parse_args(['--run-dir', str(tmp_path), 'run_id=given']))
    assert cfg['/**']['run_id'] == 'given'
    assert discovery_env(False, {})[0] == {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    assert discovery_env(True, {})[0] == {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
    assert discovery_env(True, {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'})[0] == {
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}


def test_the_test_suite_keeps_dds_on_this_machine():
    """conftest.py sets the localhost range (unless the user set one); nodes inherit it."""
    from pg_node.tools.processes import child_env
    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
    assert child_env(7)['ROS_AUTOMATIC_DISCOVERY_RANGE'] == os.environ[
        'ROS_AUTOMATIC_DISCOVERY_RANGE']


def test_training_topics_never_name_a_controller():
    """Training's command topic is its own: a real arm's controller never hears it."""
    assert run.COMMANDS != run.CONTROLLER_COMMANDS
    assert 'arm_controller' not in run.COMMANDS
