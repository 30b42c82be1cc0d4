"""
The training physics a policy's card records, and what contradicts it (issue 46).

The card says who carried the arm's weight, the damping, armature and friction per joint,
the steps, the interfaces, the import's assumptions and the run's randomization terms;
:func:`pg_node.control.physics_check.contradictions` names each policy_node setting that
says the robot is otherwise (the end-to-end warning is in test_policy_node.py).
"""
import json
from pathlib import Path

import numpy as np
from pg_node.control.physics_check import contradictions, warning
from pg_node.rl.trained_policy import checkpoint_card, make_card
from pg_node.tools import arm
import pytest
import yaml

FIXTURES = Path(__file__).resolve().parent / 'fixtures' / 'urdf'


def test_arm7_card_records_the_assumed_velocity_damping_it_learned_on():
    """arm7 was imported with --velocity-damping --armature 0.1: the card says both."""
    physics = make_card('arm7', 27, 7, 2, {})['physics']
    assert physics['gravity_compensation'] == 'robot' and physics['interfaces'] == ['effort']
    # effort / velocity limit: 87 N m / 2.175 rad/s on joints 1-4, 12 / 2.61 on 5-7
    np.testing.assert_allclose(physics['damping'], [40] * 4 + [12 / 2.61] * 3, rtol=1e-4)
    assert physics['armature'] == [0.1] * 7 and physics['frictionloss'] == [0.0] * 7
    assert (physics['timestep'], physics['frame_skip']) == (0.02, 2)
    assert physics['control_period'] == pytest.approx(0.04)
    assert physics['integrator'] == 'implicitfast'
    assert physics['assumptions'][0].startswith('velocity_damping: each arm joint is damped')
    assert physics['assumptions'][1].startswith('armature: every arm joint has 0.1 kg m^2')
    assert physics['randomization'] == {}
    json.dumps(physics)                             # the exported card is JSON


def test_a_torque_import_card_has_only_the_robots_own_damping(tmp_path, capsys):
    out = tmp_path / 'two.xml'
    assert arm.main(['import', str(FIXTURES / 'two_link.urdf'), '--tip', 'fingertip', '-o',
                     str(out)]) == 0
    capsys.readouterr()
    physics = make_card(str(out), 12, 2, 20, {})['physics']
    assert physics['damping'] == [1.0, 1.0]         # the URDF's <dynamics damping>
    # the armature and effort cap the import chose for the fixture's light links (issue
    # 55), said so
    assert physics['armature'] == [0.01, 0.01]
    assert (physics['timestep'], physics['frame_skip']) == (0.002, 20)
    assert physics['control_period'] == pytest.approx(0.04)
    assert [a.split(':')[0] for a in physics['assumptions']] == [
        'armature', 'gravity compensation', 'effort']


def test_the_card_of_a_checkpoint_records_its_runs_randomization(tmp_path):
    """The run's params.yaml: frame_skip and the randomize_<term> texts that are on."""
    run = tmp_path / 'run'
    (run / 'checkpoints').mkdir(parents=True)
    (run / 'params.yaml').write_text(yaml.safe_dump({'/**/sim_node': {'ros__parameters': {
        'frame_skip': 3, 'randomize_payload': 'uniform 0 1', 'randomize_mass': '',
        'randomize_damping': 'abs uniform 0 0.1', 'randomize_servo_bandwidth': 5}}}))
    state = {'config': {'model': 'reacher2'}, 'obs_dim': 10, 'act_dim': 2, 'version': 1}
    card = checkpoint_card(state, run / 'checkpoints' / 'ckpt_1.pt')
    assert card['physics']['frame_skip'] == 3
    assert card['physics']['randomization'] == {
        'damping': 'abs uniform 0 0.1', 'servo_bandwidth': '5', 'payload': 'uniform 0 1'}


PHYSICS = {'control_period': 0.04, 'gravity_compensation': 'robot',
           'assumptions': ['velocity_damping: each arm joint is damped by effort / velocity '
                           'limit', 'armature: every arm joint has 0.1 kg m^2']}
AGREE = {'control_rate': 0.0, 'gravity_compensation': '', 'command_interface': 'position'}


@pytest.mark.parametrize('change, said', [
    ({'control_rate': 100.0}, 'control_rate 100 Hz, the policy was trained at 25 Hz (control '
                              'period 0.04 s)'),
    ({'gravity_compensation': 'policy'},
     'gravity_compensation policy, the policy was trained with the robot compensating gravity'),
    ({'command_interface': 'effort'}, 'command_interface effort, the policy was trained with '
                                      'a velocity damping (effort / velocity limit) that a '
                                      'robot in torque mode lacks'),
])
def test_each_contradiction_is_named(change, said):
    assert contradictions(PHYSICS, {**AGREE, **change}) == [said]


def test_agreeing_settings_and_old_cards_contradict_nothing():
    assert contradictions(PHYSICS, AGREE) == []
    assert contradictions(PHYSICS, {**AGREE, 'control_rate': 25.1,       # within 1%
                                    'gravity_compensation': 'robot'}) == []
    assert contradictions({}, {**AGREE, 'control_rate': 100.0}) == []    # before issue 46
    no_assumption = {**PHYSICS, 'assumptions': []}
    assert contradictions(no_assumption, {**AGREE, 'command_interface': 'effort'}) == []
    assert warning(PHYSICS, AGREE) == ''


def test_all_contradictions_are_one_line():
    line = warning(PHYSICS, {'control_rate': 50.0, 'gravity_compensation': 'policy',
                             'command_interface': 'effort'})
    assert '\n' not in line and line.count('; ') == 2
    assert line.startswith("the parameters contradict the policy card's physics: control_rate")


def test_play_and_trains_final_evaluation_step_as_the_card_says(tmp_path):
    """
    A run trained at ``frame_skip`` 3: train's final evaluation and play's robot use 3.

    ``eval`` and in-process training did; ``train``'s summary and ``play --robot sim``
    (and ``pybullet``) took the default, 2, a control step the policy never learned.
    """
    from argparse import Namespace
    from pg_node.common.config_files import load_config
    from pg_node.rl.evaluate import evaluate_policy
    from pg_node.rl.learner import policy_from_checkpoint
    from pg_node.rl.train_inprocess import train_inprocess
    from pg_node.rl.trained_policy import find_checkpoint
    from pg_node.tools.play import robot_argv
    from pg_node.tools.train import evaluate_run
    run = tmp_path / 'run'
    summary = train_inprocess(load_config(None, ['num_envs=4', 'n_steps=8']), 64,
                              eval_episodes=1)
    summary['learner'].save(run / 'checkpoints')
    (run / 'params.yaml').write_text(yaml.safe_dump(
        {'/**/sim_node': {'ros__parameters': {'frame_skip': 3}}}))
    got = evaluate_run(run, 2)
    state, file = find_checkpoint(run)
    assert got['checkpoint'] == str(file)

    def evaluated(frame_skip):
        return evaluate_policy(policy_from_checkpoint(state), 'reacher2', 2,
                               state['config']['seed'], frame_skip=frame_skip)
    assert evaluated(3) != evaluated(2)             # the check can fail
    assert {k: got[k] for k in evaluated(3)} == evaluated(3)
    card = checkpoint_card(state, file)
    for robot in ('sim', 'pybullet'):
        args = Namespace(robot=robot, seed=0, real_time_factor=1.0, urdf=None, arms=1)
        argv = robot_argv(args, card, 'reacher2', '/play_1', 'effort', [])
        assert [a for a in argv if a.startswith('frame_skip:=')] == ['frame_skip:=3']
