"""The worked examples in the math modules' docstrings are tests too."""
import doctest
import importlib

import pytest

MODULES = ['pg_node.rollout', 'pg_node.returns', 'pg_node.baselines', 'pg_node.gae']


@pytest.mark.parametrize('name', MODULES)
def test_docstring_examples(name):
    failures, tried = doctest.testmod(importlib.import_module(name))
    assert tried > 0 and failures == 0
