"""
The arm in PyBullet from the robot's URDF (issue 45): semantics, engine agreement, eval.

No ROS: :class:`pg_node.sim.pybullet_arm.PybulletArm` against MuJoCo's import of the same
URDF, :func:`pg_node.sim.pybullet_check.compare` on the vendor arms of example-robot-data,
and ``python -m pg_node eval --engine pybullet`` as a process.
"""
from importlib.metadata import distribution
import json
import os
from pathlib import Path
import subprocess
import sys

import mujoco
import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.paths import default_config
from pg_node.rl.evaluate import evaluate_in_pybullet, evaluate_policy
from pg_node.rl.learner import Learner
from pg_node.sim.pybullet_arm import prepare_urdf, PybulletArm, PybulletError, urdf_of
from pg_node.sim.pybullet_check import compare
from pg_node.sim.urdf_import import BOUND_MASS, import_urdf, ImportOptions, write_model
import pytest
import torch

REPO = Path(__file__).resolve().parent.parent
FIXTURES = REPO / 'test' / 'fixtures'
TWO_LINK = FIXTURES / 'urdf' / 'two_link.urdf'
REACHER2 = FIXTURES / 'reacher2.urdf'      # no damping: PyBullet's 1/240 s step
SHARE = Path(distribution('example-robot-data').locate_file('cmeel.prefix/share'))
ROBOTS = SHARE / 'example-robot-data' / 'robots'
UR5 = ROBOTS / 'ur_description' / 'urdf' / 'ur5_joint_limited_robot.urdf'
PANDA = ROBOTS / 'panda_description' / 'urdf' / 'panda.urdf'
#: ur_description's UR5e as its driver loads it (scripts/ur_description_urdf.py)
UR5E = REPO / 'pg_node' / 'sim' / 'models' / 'urdf' / 'ur5e.urdf'
JOINTS = ['joint0', 'joint1']
UR5_JOINTS = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
              'wrist_2_joint', 'wrist_3_joint']


def imported(tmp_path, urdf, tip, **options) -> Path:
    """Import ``urdf`` with ``arm import``'s defaults and return the model's path."""
    out = tmp_path / f'{urdf.stem}.xml'
    result = import_urdf(urdf, ImportOptions(tip=tip, package_paths=[str(SHARE)],
                                             visual_meshes=False, targets=50, **options),
                         out_path=out, command=f'python -m pg_node arm import {urdf} --tip {tip}')
    write_model(result, out)
    return out


@pytest.fixture
def arm():
    a = PybulletArm(TWO_LINK, JOINTS, control_period=0.04)
    yield a
    a.close()


def test_links_without_inertial_weigh_what_mujoco_gives_them_and_other_joints_are_fixed():
    text, warnings = prepare_urdf(FIXTURES / 'urdf' / 'gripper.urdf', ['joint0'])
    assert any('1 kg' in w for w in warnings)
    import xml.etree.ElementTree as ET
    root = ET.fromstring(text)
    moving = [j.get('name') for j in root.iter('joint') if j.get('type') != 'fixed']
    assert moving == ['joint0']
    for link in root.iter('link'):
        assert link.find('inertial/mass') is not None
    with pytest.raises(PybulletError, match='has no joint nope'):
        prepare_urdf(TWO_LINK, ['joint0', 'nope'])


def test_limits_damping_and_efforts_come_from_the_urdf(arm):
    assert arm.damping.tolist() == [1.0, 1.0]
    assert arm.lower[0] == -np.inf and (arm.lower[1], arm.upper[1]) == (-3.0, 3.0)
    assert arm.effort_limit.tolist() == [200.0, 200.0]
    assert arm.masses()['fingertip'] == pytest.approx(BOUND_MASS)
    # the damping on 1.3e-4 kg m^2 needs a step far below PyBullet's 1/240 s
    assert arm.timestep < 5e-5 and arm.substeps * arm.timestep == pytest.approx(0.04)


def test_a_torque_moves_the_arm_as_mujoco_moves_its_import(tmp_path, arm):
    """N m in, the same motion out: units, damping and inertias agree with MuJoCo's."""
    model = mujoco.MjModel.from_xml_path(str(imported(tmp_path, TWO_LINK, 'fingertip')))
    data = mujoco.MjData(model)
    tau = np.array([0.3, -0.2])
    data.qpos[:2] = arm_q = [0.3, 0.5]
    data.ctrl[:] = tau / model.actuator_gear[:, 0]
    mujoco.mj_step(model, data, nstep=20)      # 0.04 s
    arm.set_state(arm_q)
    arm.step(tau)
    q, qd, effort = arm.state()
    np.testing.assert_allclose(effort, tau)
    np.testing.assert_allclose(q, data.qpos[:2], atol=2e-3)
    np.testing.assert_allclose(qd, data.qvel[:2], rtol=0.05, atol=0.01)
    assert np.abs(qd).max() > 0.1


def test_hard_limits_stop_mujoco_near_where_pybullet_stops(tmp_path, arm):
    """
    ``arm import --hard-limits``: joint1 driven into its limit (3 rad) as PyBullet stops it.

    20 N m on joint1 from 2.5 rad for 0.4 s: PyBullet's limit is a hard constraint (3.0 rad);
    MuJoCo's default soft limit lets the light fixture sink through it (8.2 rad seen), the
    hard one (``solreflimit`` 2 x 0.002 s) holds it within 0.41 rad of it.
    """
    tau = np.array([0.0, 20.0])
    arm.set_state([0.0, 2.5])
    arm.step(tau, periods=10)
    stopped = arm.state()[0][1]
    assert stopped == pytest.approx(3.0, abs=1e-3)
    reached = {}
    for hard in (False, True):
        folder = tmp_path / ('hard' if hard else 'soft')
        folder.mkdir()
        model = mujoco.MjModel.from_xml_path(str(imported(folder, TWO_LINK, 'fingertip',
                                                          hard_limits=hard)))
        assert model.jnt_solref[1][0] == pytest.approx(0.004 if hard else 0.02)
        data = mujoco.MjData(model)
        data.qpos[:2] = [0.0, 2.5]
        data.ctrl[:] = tau / model.actuator_gear[:, 0]
        mujoco.mj_step(model, data, nstep=200)
        reached[hard] = data.qpos[1]
    assert reached[True] - stopped < 0.5 and reached[False] - stopped > 4, reached
    from pg_node.tools import arm as arm_cli
    argv = ['import', str(TWO_LINK), '--tip', 'fingertip']
    assert arm_cli.options(arm_cli.parser().parse_args(argv + ['--hard-limits'])).hard_limits
    assert not arm_cli.options(arm_cli.parser().parse_args(argv)).hard_limits


def test_the_stable_step_matters(arm):
    """Twice PyBullet's stable bound and the damped joints ring at its 100 rad/s cap."""
    fast = PybulletArm(TWO_LINK, JOINTS, control_period=0.04, max_timestep=4 * arm.timestep)
    for a in (arm, fast):
        a.set_state([0.3, 0.5], [1.0, -1.0])
        a.step([0.0, 0.0])
    assert np.abs(arm.state()[1]).max() < 1e-3
    assert np.abs(fast.state()[1]).max() > 10
    fast.close()


def test_efforts_are_clamped_to_the_urdf_limit_and_default_motors_are_off():
    a = PybulletArm(REACHER2, JOINTS, control_period=0.04)
    a.step([0.0, 1e4])
    assert a.state()[2][1] == 200.0
    a.set_state([0.0, 0.0], [1.0, 0.0])       # no damping in this URDF: it coasts
    a.step([0.0, 0.0])
    assert a.state()[1][0] == pytest.approx(1.0, rel=0.05)
    a.close()


def test_position_and_velocity_modes_follow_their_targets(arm):
    arm.set_state([0.0, 0.0])
    arm.step([0.5, -0.4], mode='position', periods=10)
    np.testing.assert_allclose(arm.state()[0], [0.5, -0.4], atol=0.01)
    arm.step([0.5, -5.0], mode='position', periods=10)    # kept inside joint1's limits
    assert arm.state()[0][1] == pytest.approx(-3.0, abs=0.01)
    arm.set_state([0.0, 0.0])
    arm.step([0.2, 0.1], mode='velocity', periods=2)
    np.testing.assert_allclose(arm.state()[1], [0.2, 0.1], atol=0.01)
    with pytest.raises(PybulletError, match='2 finite values'):
        arm.step([np.nan, 0.0])


def test_gravity_compensation_holds_the_ur5_and_without_it_the_arm_falls():
    pose = [0.0, -1.0, 1.0, -1.0, -1.5, 0.0]
    moved = []
    for compensate in (True, False):
        a = PybulletArm(UR5, UR5_JOINTS, control_period=0.04, gravity_compensation=compensate,
                        package_paths=[str(SHARE)])
        a.set_state(pose)
        a.step(np.zeros(6), periods=10)     # 0.4 s
        moved.append(np.abs(a.state()[0] - pose).max())
        a.close()
    assert moved[0] < 5e-3 and moved[1] > 0.1, moved


def test_a_payload_pulls_its_weight_at_the_tip_unknown_to_the_gravity_compensation():
    """
    ``set_payload``: m g at a point of the tip link, which the compensation does not hold.

    The arm sags under the payload; given the torque ``-J^T m g`` (J the point's linear
    Jacobian) on top of the compensation it holds still again, so the force is m g, there.
    """
    pose, offset, kg = [0.0, -1.0, 1.0, -1.0, -1.5, 0.0], [0.0, 0.0, 0.05], 2.0
    a = PybulletArm(UR5, UR5_JOINTS, control_period=0.04, gravity_compensation=True,
                    package_paths=[str(SHARE)])
    try:
        a.set_state(pose)
        a.set_payload('tool0', offset, kg)
        a.step(np.zeros(6), periods=5)
        sag = np.abs(a.state()[0] - pose).max()
        a.set_state(pose)
        zero = [0.0] * len(a.dof_ids)
        q = [s[0] for s in a.client.getJointStates(a.body, a.dof_ids)]
        jac = np.array(a.client.calculateJacobian(a.body, a.links['tool0'], offset, q, zero,
                                                  zero)[0])[:, a._dof_index]
        a.step(-jac.T @ (kg * np.array([0.0, 0.0, -9.81])), periods=5)
        held = np.abs(a.state()[0] - pose).max()
        with pytest.raises(PybulletError, match='no moving link'):
            a.set_payload('nowhere', offset, kg)
        with pytest.raises(PybulletError, match='kg >= 0'):
            a.set_payload('tool0', offset, -1.0)
        a.set_payload('tool0', offset, 0.0)
        assert a.payload is None
    finally:
        a.close()
    assert sag > 0.02 and held < 1e-3, (sag, held)


@pytest.mark.parametrize('urdf, tip', [(UR5, 'tool0'), (PANDA, 'panda_link8'),
                                       (UR5E, 'tool0'), (TWO_LINK, 'fingertip')])
def test_pybullet_reads_the_vendor_arm_as_pg_node_imports_it(tmp_path, urdf, tip):
    model = mujoco.MjModel.from_xml_path(str(imported(tmp_path, urdf, tip)))
    from pg_node.sim.arm_task import ArmSpec
    a = PybulletArm(urdf, ArmSpec.from_model(model).joint_names, control_period=0.04,
                    package_paths=[str(SHARE)])
    found = compare(model, a)
    a.close()
    assert found.disagreements == [] and found.position_error < 1e-3, found.line()
    assert found.links_compared >= 5 and 'agree' in found.line()


def test_a_moved_joint_is_said(tmp_path):
    model = mujoco.MjModel.from_xml_path(str(imported(tmp_path, TWO_LINK, 'fingertip')))
    other = tmp_path / 'other.urdf'
    other.write_text(TWO_LINK.read_text().replace('<origin xyz="0.1 0 0"/>',
                                                  '<origin xyz="0.105 0 0"/>')
                     .replace('lower="-3" upper="3"', 'lower="-2" upper="3"'))
    a = PybulletArm(other, JOINTS, control_period=0.04)
    line = compare(model, a).line()
    a.close()
    assert 'link frames up to 5 mm apart' in line and 'joint1 limits -2..3' in line, line


def test_urdf_of_reads_the_import_command():
    assert urdf_of("python -m pg_node arm import '/a b/r.urdf' --tip t") == '/a b/r.urdf'
    assert urdf_of(None) is None and urdf_of('python -m pg_node train') is None


class Constant:
    """A policy that always asks for the same control."""

    def __init__(self, u):
        self.u = torch.as_tensor(u, dtype=torch.float32)

    def mean_action(self, obs):
        return self.u.expand(len(obs), -1)


def test_the_same_episodes_end_where_mujoco_ends_them(tmp_path):
    """A steady 0.3 N m swing: episode for episode, the engines agree to the millimetre."""
    model = imported(tmp_path, TWO_LINK, 'fingertip')
    policy = Constant([0.0015, -0.001])
    mj = evaluate_policy(policy, str(model), n_episodes=4, frame_skip=20)
    pb = evaluate_in_pybullet(policy, str(model), TWO_LINK, n_episodes=4, frame_skip=20,
                              max_episode_steps=50)
    np.testing.assert_allclose(pb['eval_final_distances'], mj['eval_final_distances'],
                               atol=2e-3)
    np.testing.assert_allclose(pb['eval_returns'], mj['eval_returns'], rtol=0.02)
    assert np.ptp(mj['eval_final_distances']) > 0.01     # distinct episodes


def test_eval_engine_pybullet_runs_the_policy_on_the_urdf_it_was_imported_from(tmp_path):
    model = imported(tmp_path, REACHER2, 'body1')
    run_dir = tmp_path / 'run'
    sections = load_config(default_config(), [f'run_dir={run_dir}', f'model={model}'])
    cfg = {k: v for section in sections.values() for k, v in section.items()}
    Learner(12, 2, cfg).save(run_dir / 'checkpoints')
    env = dict(os.environ, PYTHONPATH=str(REPO))

    def run(*args):
        return subprocess.run([sys.executable, '-m', 'pg_node', 'eval', str(run_dir), *args],
                              env=env, capture_output=True, text=True, timeout=120)
    done = run('--engine', 'pybullet', '--episodes', '2', '--json')
    assert done.returncode == 0, done.stderr
    res = json.loads(done.stdout)
    assert res['pybullet_urdf'] == str(REACHER2) and res['eval_episodes'] == 2
    assert 0 < res['eval_final_distance'] < 1
    bad = run('--engine', 'pybullet', '--urdf', str(tmp_path / 'none.urdf'))
    assert bad.returncode == 2 and 'no URDF' in bad.stderr and 'Traceback' not in bad.stderr
    bad = run('--engine', 'pybullet', '--perturb', 'mass_scale=2')
    assert bad.returncode == 2 and '--perturb is for --engine mujoco' in bad.stderr
    # a payload applies in PyBullet (its effect: the test above); this arm's joints turn
    # about the vertical, so its weight turns none of them: the same episodes, the same end
    heavy = run('--engine', 'pybullet', '--episodes', '2', '--perturb', 'payload=5')
    assert heavy.returncode == 0 and ', with payload=5:' in heavy.stdout, heavy.stderr
    heavy = json.loads(run('--engine', 'pybullet', '--episodes', '2', '--perturb', 'payload=5',
                           '--json').stdout)
    assert heavy['eval_final_distance'] == pytest.approx(res['eval_final_distance'], abs=1e-9)
    assert heavy['perturbation'] == {'payload': 'abs 5 startup'}


def test_velocity_servos_run_as_velocity_commands(tmp_path):
    """
    An arm of velocity servos (issue 46) runs in PyBullet on its velocity motors.

    It was refused ("command_interface position needs position actuators"). A steady
    0.1 rad/s on both joints: the engines end the same episodes within a few millimetres
    (MuJoCo's servo loses the URDF damping's share of the speed, 1/21, PyBullet's motor not).
    """
    model = imported(tmp_path, TWO_LINK, 'fingertip', actuator='velocity', armature=0.1)
    policy = Constant([0.01, 0.01])
    mj = evaluate_policy(policy, str(model), n_episodes=4, frame_skip=2)
    pb = evaluate_in_pybullet(policy, str(model), TWO_LINK, n_episodes=4, frame_skip=2,
                              max_episode_steps=50)
    np.testing.assert_allclose(pb['eval_final_distances'], mj['eval_final_distances'],
                               atol=5e-3)
    assert np.ptp(mj['eval_final_distances']) > 0.01     # distinct episodes


def test_relative_position_targets_run_around_pybullets_angles(tmp_path):
    """
    A policy of bounded changes (a run's ``position_delta``) commands ``q + u d`` in PyBullet.

    A zero change holds each episode's start in both engines, which then end the same
    episodes within a few millimetres; taken as absolute targets (the angle 0, a radian
    from the start) the arm would move. (A steady non-zero change is a ramp, which the
    engines' servos follow with different lags: MuJoCo's ``kp``, ``kv`` against PyBullet's
    motor.)
    """
    model = imported(tmp_path, TWO_LINK, 'fingertip', actuator='position', home=[1.0, 1.0])
    policy = Constant([0.0, 0.0])
    mj = evaluate_policy(policy, str(model), n_episodes=4, frame_skip=2, position_delta=0.1)
    pb = evaluate_in_pybullet(policy, str(model), TWO_LINK, n_episodes=4, frame_skip=2,
                              max_episode_steps=50, position_delta=0.1)
    absolute = evaluate_policy(policy, str(model), n_episodes=4, frame_skip=2)
    np.testing.assert_allclose(pb['eval_final_distances'], mj['eval_final_distances'],
                               atol=5e-3)
    assert np.max(np.abs(np.subtract(absolute['eval_final_distances'],
                                     mj['eval_final_distances']))) > 0.02
    assert np.ptp(mj['eval_final_distances']) > 0.01     # distinct episodes
