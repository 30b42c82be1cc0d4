"""
One way to choose the policy update: the registry, the settings each update has, the refusals.

The ``algo`` parameter offers exactly the registered updates; each builds itself from its own
settings; a setting of another update, set off its default, is refused in one line (in the
configuration, when the learner is built, and when it is changed live), while a setting the
update shares with others, or a default given back, is accepted.
"""
import inspect
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.param_schema import ConfigError
from pg_node.common.params import defaults, LEARNER_PARAMS
from pg_node.common.paths import default_config
from pg_node.rl import update_settings
from pg_node.rl.a2c import PolicyBatch, PPOUpdate
from pg_node.rl.learner import Learner
from pg_node.rl.policy import GaussianPolicy
from pg_node.rl.update_settings import check_algo_setting, check_settings
from pg_node.rl.updaters import make_updater, UPDATERS
import pytest
import torch

REPO = Path(__file__).resolve().parent.parent
#: the settings each update is built from (update_settings.SETTINGS is the one place)
ALGO_SETTINGS = {name: cls.settings for name, cls in UPDATERS.items()}
SETTINGS = sorted(set().union(*ALGO_SETTINGS.values()))


def other(key):
    """Return an allowed value of learner setting ``key`` other than its default."""
    param = LEARNER_PARAMS[key]
    value = param.default
    if param.choices is not None:
        return next(c for c in param.choices if c != value)
    if isinstance(value, bool):
        return not value
    if isinstance(value, float):
        return value * 2 if value else 0.25
    return value + 1


def learner_cfg(**change):
    return {**defaults('learner_node'), **defaults('actor_node'), **change}


def test_the_registry_holds_exactly_the_algos_the_parameter_offers():
    assert tuple(UPDATERS) == LEARNER_PARAMS['algo'].choices
    assert tuple(update_settings.SETTINGS) == tuple(UPDATERS)
    for name, cls in UPDATERS.items():
        assert cls.name == name
        assert cls.settings is update_settings.SETTINGS[name], name
        assert len(set(cls.settings)) == len(cls.settings), name


@pytest.mark.parametrize('algo', list(UPDATERS))
def test_every_argument_of_an_update_is_a_setting_the_configuration_reaches(algo):
    """No update takes a value the learner's parameters cannot give it (``seed``: shared)."""
    cls = UPDATERS[algo]
    takes = set(inspect.signature(cls.__init__).parameters) - {'self', 'policy', 'seed'}
    assert takes == set(cls.settings)
    assert set(cls.settings) <= set(LEARNER_PARAMS)


def test_every_setting_is_a_learner_parameter_and_its_description_names_its_updates():
    """``ppo: ...``, ``npg/trpo: ...``: the table's words agree with who has the setting."""
    for key in SETTINGS:
        assert key in LEARNER_PARAMS, key
    for key, param in LEARNER_PARAMS.items():
        head = param.description.split(':')[0]
        if key != 'algo' and set(head.split('/')) <= set(ALGO_SETTINGS):
            assert {a for a, has in ALGO_SETTINGS.items() if key in has} == \
                set(head.split('/')), key


@pytest.mark.parametrize('algo', list(UPDATERS))
def test_each_update_is_built_from_its_own_settings(algo):
    """Every setting the update declares is an attribute holding the configured value."""
    change = {k: other(k) for k in ALGO_SETTINGS[algo]}
    update = make_updater(GaussianPolicy(3, 1), learner_cfg(algo=algo, **change))
    assert type(update) is UPDATERS[algo]
    for key, value in change.items():
        assert getattr(update, key) == pytest.approx(value), key
    assert (update.optimizer_state() is None) == (algo in ('npg', 'trpo'))


@pytest.mark.parametrize('algo, key', [(a, k) for a in ALGO_SETTINGS for k in SETTINGS
                                       if k not in ALGO_SETTINGS[a]])
def test_a_setting_of_another_update_is_refused_in_the_configuration(algo, key):
    value = other(key)
    with pytest.raises(ConfigError) as err:
        load_config(None, [f'algo={algo}', f'{key}={value}'], check=check_settings)
    assert str(err.value) == (
        f"parameter 'learner_node.{key}': {value!r} is not allowed: algo {algo!r} has no "
        f'{key}; its settings: {", ".join(ALGO_SETTINGS[algo])}')
    with pytest.raises(ConfigError, match=f'has no {key}'):       # a node started with it
        Learner(4, 1, learner_cfg(algo=algo, **{key: value}))


@pytest.mark.parametrize('algo', list(UPDATERS))
def test_defaults_given_back_and_shared_settings_are_accepted(algo):
    """The shipped file lists every update's settings at their defaults: any algo takes it."""
    cfg = load_config(default_config(), [f'algo={algo}', 'ent_coef=0.01',
                                         'normalize_advantage=false'])
    assert cfg['learner_node']['algo'] == algo
    for key in SETTINGS:
        check_algo_setting(key, algo, key, LEARNER_PARAMS[key].default)


def test_a_preset_tuned_for_one_update_is_refused_under_another():
    from pg_node.common.paths import config_file
    with pytest.raises(ConfigError, match="'learner_node.learning_rate'.*algo 'trpo'"):
        load_config(config_file('ppo'), ['algo=trpo'], check=check_settings)


@pytest.mark.parametrize('algo', list(UPDATERS))
def test_live_changes_reach_the_update_or_are_refused(algo):
    """``Learner.configure`` (what ``ros2 param set`` calls) sets its own, refuses others'."""
    learner = Learner(4, 1, learner_cfg(algo=algo))
    for key in ALGO_SETTINGS[algo]:
        if LEARNER_PARAMS[key].live:
            learner.configure(key, other(key))
            assert getattr(learner.update, key) == pytest.approx(other(key))
            assert learner.cfg[key] == other(key)
    for key in SETTINGS:
        if key not in ALGO_SETTINGS[algo] and LEARNER_PARAMS[key].live:
            with pytest.raises(ConfigError, match=f"algo '{algo}' has no {key}"):
                learner.configure(key, other(key))
            assert learner.cfg[key] == LEARNER_PARAMS[key].default
            learner.configure(key, LEARNER_PARAMS[key].default)    # given back: accepted


@pytest.mark.parametrize('algo, merged', [('a2c', False), ('ppo', True), ('npg', False),
                                          ('trpo', False)])
def test_a_skipped_step_merges_the_observations_only_where_others_moved_the_policy(algo, merged):
    """PPO skips minibatches, the rest move the policy; the others skip the whole step."""
    small = {'batch_size': 2} if algo == 'ppo' else {}
    learner = Learner(4, 1, learner_cfg(algo=algo, **small))
    adv = np.ones(8)
    adv[0] = np.nan                     # one minibatch (PPO) or the whole step is skipped
    obs = np.random.default_rng(0).normal(size=(8, 4))
    count = float(learner.policy.obs_norm.count)
    stats = learner.learn(obs, np.zeros((8, 1)), np.zeros(8), adv)
    assert stats['skipped_updates'] >= 1
    assert (float(learner.policy.obs_norm.count) > count) == merged


def test_a_setting_added_to_the_table_is_checked_with_no_other_edit(monkeypatch):
    """SETTINGS is the one source: give A2C clip_range and every check follows at once."""
    with pytest.raises(ConfigError, match="algo 'a2c' has no clip_range"):
        load_config(None, ['algo=a2c', 'clip_range=0.3'], check=check_settings)
    monkeypatch.setitem(update_settings.SETTINGS, 'a2c',
                        update_settings.SETTINGS['a2c'] + ('clip_range',))
    cfg = load_config(None, ['algo=a2c', 'clip_range=0.3'], check=check_settings)
    assert cfg['learner_node']['clip_range'] == 0.3
    with pytest.raises(ConfigError) as err:
        check_algo_setting('max_kl', 'a2c', 'max_kl', 0.5)
    assert str(err.value).endswith('its settings: learning_rate, optimizer, ent_coef, '
                                   'max_grad_norm, normalize_advantage, clip_range')


def test_the_learner_section_alone_is_checked():
    """``check_settings`` passes a section without ``algo``; it labels keys by section."""
    check_settings('critic_node', {'clip_range': 0.3})
    with pytest.raises(ConfigError, match="^parameter 'learner_node.clip_range': 0.3"):
        check_settings('learner_node', {'algo': 'a2c', 'clip_range': 0.3})
    with pytest.raises(ConfigError, match="^parameter 'clip_range': 0.3"):
        check_settings('', {'algo': 'a2c', 'clip_range': 0.3})


def test_target_kl_from_the_configuration_reaches_ppo_and_ends_its_epochs(monkeypatch):
    """Default: PPO's own (never); a value from the file or ``ros2 param set`` is taken."""
    assert LEARNER_PARAMS['target_kl'].default == PPOUpdate(GaussianPolicy(3, 1)).target_kl
    cfg = load_config(default_config(), ['algo=ppo', 'target_kl=1e-9', 'n_epochs=3',
                                         'batch_size=64'], check=check_settings)
    learner = Learner(3, 1, {**cfg['actor_node'], **cfg['learner_node']})
    assert learner.update.target_kl == 1e-9
    torch.manual_seed(0)
    obs, act = torch.randn(16, 3), torch.randn(16, 1)
    with torch.no_grad():
        logp = learner.policy.distribution(obs).log_prob(act).sum(-1)
    batch = PolicyBatch(obs, act, logp, torch.randn(16))

    def epochs_run(update):
        losses = []
        loss = update._loss
        monkeypatch.setattr(update, '_loss', lambda *a: losses.append(1) or loss(*a))
        update.update(batch)
        return len(losses)                  # one minibatch per epoch: 16 samples, 64 a batch

    # the first epoch starts at the sampling policy (KL 0); the second exceeds 1.5e-9
    assert epochs_run(learner.update) == 2
    learner.configure('target_kl', 0.0)
    assert epochs_run(learner.update) == 3
    with pytest.raises(ConfigError, match="algo 'a2c' has no target_kl"):
        Learner(3, 1, learner_cfg(algo='a2c', target_kl=0.01))


def test_train_checks_the_algorithm_settings_without_torch():
    """The table and its check import no torch: train refuses a setting before it loads."""
    from test_architecture import BLOCKER
    code = BLOCKER.split('import pg_node')[0] + (
        'from pg_node.common.config_files import load_config\n'
        'from pg_node.rl.update_settings import check_settings\n'
        'load_config(None, ["algo=trpo"], check=check_settings)\n')
    done = subprocess.run([sys.executable, '-c', code, 'torch'], capture_output=True,
                          text=True, timeout=60, cwd=REPO, env={**os.environ,
                                                                'PYTHONPATH': str(REPO)})
    assert done.returncode == 0, done.stderr
