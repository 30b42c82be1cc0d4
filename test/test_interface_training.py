"""
A short training with each command interface runs, and the card records the interface (issue 46).

reacher2 with motors (effort), with position servos (absolute targets, and relative ones
with a ``pg_position_delta``) and with velocity servos: one update each, in-process; the
policy's card lists the interface the actuators take with its unit and range (and the
position delta when the model has one), and its training physics names the interface.
Whether such a training learns is a benchmark, not a test.
"""
from pathlib import Path

import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.paths import resolve_model
from pg_node.rl.train_inprocess import train_inprocess
from pg_node.rl.trained_policy import load_trained_policy
import pytest
from test_safety import POSITION_XML
from test_velocity_interface import VELOCITY_XML

RELATIVE_XML = POSITION_XML.replace(
    '<custom>', '<custom>\n    <numeric name="pg_position_delta" data="0.1"/>')
CASES = {
    'effort': (Path(resolve_model('reacher2')).read_text(), 'N m', 200.0, None),
    'position': (POSITION_XML, 'rad', 3.0, None),
    'relative position': (RELATIVE_XML, 'rad', 3.0, [0.1, 0.1]),
    'velocity': (VELOCITY_XML, 'rad/s', 2.0, None),
}


@pytest.mark.parametrize('case', sorted(CASES))
def test_a_short_training_with_each_interface_records_it_in_the_card(tmp_path, case):
    xml, unit, bound, delta = CASES[case]
    interface = case.split()[-1]
    assert 'pg_position_delta' in xml or delta is None
    model = tmp_path / 'arm.xml'
    model.write_text(xml)
    cfg = load_config(None, [f'model={model}', 'num_envs=4', 'n_steps=8', 'seed=0'])
    summary = train_inprocess(cfg, 32, eval_episodes=1)
    assert np.all(np.isfinite(summary['eval_returns']))
    summary['learner'].save(tmp_path / 'checkpoints')
    card = load_trained_policy(tmp_path).card
    assert list(card['command_interfaces']) == [interface]
    entry = card['command_interfaces'][interface]
    assert entry['unit'] == unit
    np.testing.assert_allclose(entry['low'], [-bound, -bound])
    np.testing.assert_allclose(entry['high'], [bound, bound])
    assert entry.get('max_position_delta') == delta
    assert card['physics']['interfaces'] == [interface]
