"""The worked examples in the math modules' docstrings are tests too."""
import doctest
import importlib

import pytest

MODULES = ['pg_node.rl.rollout', 'pg_node.rl.returns', 'pg_node.rl.baselines', 'pg_node.rl.gae',
           'pg_node.ros.command', 'pg_node.rl.natural_gradient',
           'pg_node.ros.policy_node', 'bench.tax', 'pg_node.tools.hosts',
           'pg_node.tools.train', 'pg_node.tools.play', 'pg_node.rl.actor_sync',
           'pg_node.rl.critic_batching', 'pg_node.rl.learner_gate', 'pg_node.ros.replay_node',
           'bench.bench_reach', 'pg_node.sim.actuation', 'pg_node.control.status',
           'pg_node.common.run_dir', 'pg_node.tools.stall']


@pytest.mark.parametrize('name', MODULES)
def test_docstring_examples(name):
    failures, tried = doctest.testmod(importlib.import_module(name))
    assert tried > 0 and failures == 0
