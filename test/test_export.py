"""
The exported policy (ONNX + card) equals its checkpoint, and the card says what a robot needs.

Policies are trained briefly in-process, so that the observation normaliser holds real
statistics; the export is compared with torch's ``mean_action`` on observations of the task
and on far-off ones (which the normaliser clips).
"""
import json
import subprocess
import sys

import mujoco
import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.paths import resolve_model
from pg_node.rl.onnx_export import export_policy
from pg_node.rl.train_inprocess import train_inprocess
from pg_node.rl.trained_policy import (find_checkpoint, load_trained_policy, OnnxPolicy,
                                       PolicySourceError, TorchPolicy)
from pg_node.sim.arm_task import ArmTask
from pg_node.sim.observation import ObservationBuilder
from pg_node.tools import processes
import pytest
import torch


def trained_run(tmp_path, *overrides, steps=4096):
    """Train ``steps`` steps in-process and save the policy as a run; return the run dir."""
    summary = train_inprocess(load_config(None, ['num_envs=8', *overrides]), steps,
                              eval_episodes=1)
    summary['learner'].save(tmp_path / 'run' / 'checkpoints')
    return tmp_path / 'run'


def task_observations(model='reacher2', n=8, steps=60, seed=1):
    """Return observations of random-torque episodes ``(steps * n, D)``."""
    task = ArmTask(resolve_model(model), num_envs=n, seed=seed)
    rng = np.random.default_rng(seed)
    out = [task.reset()]
    for _ in range(steps - 1):
        out.append(task.step(rng.uniform(-1, 1, (n, task.act_dim)))[0])
    task.close()
    return np.concatenate(out)


@pytest.mark.parametrize('overrides,model', [
    ((), 'reacher2'),
    (('activation=relu', 'hidden_sizes=[32]', 'state_dependent_std=true'), 'reacher2'),
    (('activation=elu', 'normalize_obs=false'), 'reacher2'),
    (('model=arm5_3d',), 'arm5_3d'),
])
def test_exported_policy_equals_the_checkpoint(tmp_path, overrides, model):
    run = trained_run(tmp_path, *overrides)
    torch_policy = load_trained_policy(run)
    assert isinstance(torch_policy, TorchPolicy)
    card_file = export_policy(torch_policy.policy, torch_policy.card, tmp_path / 'p.onnx')
    assert card_file == tmp_path / 'p.json'
    onnx_policy = load_trained_policy(tmp_path / 'p.onnx')
    assert isinstance(onnx_policy, OnnxPolicy)
    obs = task_observations(model)
    far = obs[:64] * 50.0                               # beyond the normaliser's clip
    for o in (obs, far, obs[:1]):
        with torch.no_grad():
            want_mu, want_std = torch_policy.policy.mean_std(
                torch.as_tensor(o, dtype=torch.float32))
        got_mu, got_std = onnx_policy.mean_std(o)
        np.testing.assert_allclose(got_mu, want_mu.numpy(), rtol=0, atol=1e-5)
        np.testing.assert_allclose(got_std, want_std.numpy(), rtol=1e-5, atol=1e-6)
    # the check can fail: another checkpoint's weights are not within 1e-5
    other = trained_run(tmp_path / 'other', 'seed=1', *overrides)
    assert np.abs(load_trained_policy(other).mean(obs) - onnx_policy.mean(obs)).max() > 1e-3


def test_card_describes_observation_joints_range_step_and_model(tmp_path):
    run = trained_run(tmp_path)
    res = subprocess.run([sys.executable, '-m', 'pg_node', 'export', str(run), '-o',
                          str(tmp_path / 'out' / 'policy.onnx')], env=processes.child_env(),
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert 'largest difference from the checkpoint' in res.stdout
    card = json.loads((tmp_path / 'out' / 'policy.json').read_text())
    assert card['joint_names'] == ['joint0', 'joint1']
    assert card['action'] == {'size': 2, 'low': [-1.0, -1.0], 'high': [1.0, 1.0],
                              'meaning': card['action']['meaning']}
    assert card['control_step'] == pytest.approx(0.02) and card['frame_skip'] == 2
    # what policy_node sends a robot: reacher2's motors, gear 200
    assert card['command_interfaces'] == {'effort': {'unit': 'N m', 'low': [-200.0, -200.0],
                                                     'high': [200.0, 200.0]}}
    assert card['model'] == 'reacher2' and card['onnx'] == 'policy.onnx'
    assert [(f['name'], f['size']) for f in card['observation']['layout']] == [
        ('cos_q', 2), ('sin_q', 2), ('target', 2), ('qdot', 2), ('fingertip_minus_target', 2)]
    state, _ = find_checkpoint(run)
    assert card['source']['policy_version'] == state['version']
    # the card alone rebuilds the observation: its model's kinematics are the task's
    task = ArmTask(resolve_model('reacher2'), num_envs=4, seed=2)
    obs = task.reset()
    q, qdot, _ = task.joint_state()
    builder = ObservationBuilder(mujoco.MjModel.from_xml_string(card['model_xml']))
    np.testing.assert_allclose(builder(q, qdot, task.target_pos()), obs, atol=1e-9)


def test_observation_builder_equals_the_task_after_steps():
    """
    Mid-episode the builder is the task's observation of fresh kinematics.

    The task reads positions as the last RK4 stage left them (as Reacher-v5 does): they
    differ from ``mj_kinematics`` at the step's angles by up to about 1e-3 m on the moving
    5-joint arm; after ``mj_kinematics`` on the task's own data the two agree exactly.
    """
    for model in ('reacher2', 'arm5_3d'):
        task = ArmTask(resolve_model(model), num_envs=8, seed=1)
        task.reset()
        rng = np.random.default_rng(0)
        for _ in range(20):
            stepped = task.step(rng.uniform(-1, 1, (8, task.act_dim)))[0]
        q, qdot, _ = task.joint_state()
        got = ObservationBuilder(task.model)(q, qdot, task.target_pos())
        np.testing.assert_allclose(got, stepped, atol=2e-3)
        for data in task.datas:
            mujoco.mj_kinematics(task.model, data)
        np.testing.assert_allclose(got, task.observe(), atol=1e-9)
        moved = ObservationBuilder(task.model)(q + 0.01, qdot, task.target_pos())
        assert not np.allclose(got, moved, atol=1e-4)
        task.close()


def test_export_refuses_bad_input_in_one_line(tmp_path):
    run = trained_run(tmp_path)
    (tmp_path / 'critic').mkdir()
    torch.save({'version': 1, 'value_fn': {}}, tmp_path / 'critic' / 'ckpt_00000001.pt')
    (tmp_path / 'junk.pt').write_text('not a checkpoint')
    for args, code, words in (
            ([str(tmp_path / 'missing'), '-o', 'x.onnx'], 1, 'no such file or directory'),
            ([str(tmp_path / 'critic'), '-o', 'x.onnx'], 1, 'critic'),
            ([str(tmp_path / 'junk.pt'), '-o', 'x.onnx'], 1, 'cannot read checkpoint'),
            ([str(run), '-o', str(tmp_path / 'x.pt')], 2, 'must end in .onnx')):
        res = subprocess.run([sys.executable, '-m', 'pg_node', 'export', *args],
                             env=processes.child_env(), capture_output=True, text=True,
                             timeout=120, cwd=tmp_path)
        assert res.returncode == code, res.stderr
        assert words in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
    (tmp_path / 'p.onnx').write_text('garbage')
    with pytest.raises(PolicySourceError, match='card of'):
        load_trained_policy(tmp_path / 'p.onnx')
