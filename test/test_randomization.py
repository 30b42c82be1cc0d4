"""
Domain randomization (``pg_node.common.perturbations``, ``pg_node.sim.randomization``).

Each term changes what it says and nothing else, is drawn when it says, from the
distribution it says; the episode starts stay the nominal ones; stepping arms in groups is
stepping them together; bad terms are refused in one line.
"""
import math

import gymnasium as gym
import mujoco
import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.param_schema import ConfigError
from pg_node.common.paths import resolve_model
from pg_node.common.perturbations import BadTerm, parse_perturbation, parse_term
from pg_node.sim.arm_task import ArmSpec, ArmTask
import pg_node.sim.gym_env  # noqa: F401  (registers the ids)
from pg_node.sim.observation import ObservationBuilder
from pg_node.sim.randomization import Randomizer
import pytest

REACHER = resolve_model('reacher2')
EVERY_TERM = {'mass': 'uniform 0.5 2', 'damping': 'log_uniform 0.5 3',
              'frictionloss': 'add uniform 0 0.05 startup', 'armature': 'gaussian 1 0.1 every 7',
              'gear': 'uniform 0.6 1.4', 'latency': 'uniform 0 2', 'obs_noise': '0.01',
              'vel_noise': 'gaussian 0.05 0.01', 'action_noise': '0.05',
              'target_noise': 'uniform 0 0.01', 'servo_bandwidth': 'log_uniform 2 20',
              'servo_latency': 'uniform 0 0.03', 'payload': 'uniform 0 0.5'}


def actions(steps, n, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, (steps, n, 2))


@pytest.mark.parametrize('term, text, message', [
    ('mass', 'uniform 1.5 0.7', 'mass: the range 1.5 0.7 is empty (need a <= b)'),
    ('mass', 'uniform 0 2', 'a mass scale must stay > 0 (it can draw 0)'),
    ('mass', 'gaussian 1 0.5', 'a mass scale must stay > 0 (it can draw -0.5)'),
    ('damping', 'log_uniform 0 2', 'damping: log_uniform 0 2 needs 0 < a'),
    ('latency', 'uniform 0 1.5', 'latency is whole control steps'),
    ('latency', '11', 'latency must stay within 0..10 control steps'),
    ('latency', 'scale 2', 'latency: only abs applies'),
    ('obs_noise', 'uniform -0.1 0.1', 'a noise std must be >= 0 (it can draw -0.1)'),
    ('gear', 'uniform 0.5', 'gear: uniform needs two numbers, got 0.5'),
    ('gear', 'triangular 0.5 1', 'gear: cannot read'),
    ('gear', 'uniform 0.5 1 every 0', 'need a whole number of control steps >= 1'),
    ('gear', 'uniform a 1', "gear: 'a' is not a number"),
    ('torque', '1', "unknown term 'torque'"),
    ('servo_bandwidth', 'uniform 0 5', 'a servo bandwidth must stay > 0 Hz (it can draw 0)'),
    ('servo_latency', 'uniform 0 2', 'the servo latency must stay within 0..1 s'),
    ('servo_latency', 'scale 0.01', 'servo_latency: only abs applies'),
    ('payload', 'gaussian 0.5 0.5', 'a payload must be >= 0 kg (it can draw -1)'),
])
def test_bad_terms_are_refused_in_one_line(term, text, message):
    with pytest.raises(BadTerm) as err:
        parse_term(term, text)
    assert message in str(err.value) and '\n' not in str(err.value)


def test_parameters_validate_terms_and_take_bare_numbers():
    cfg = load_config(None, ['randomize_obs_noise=0.02', 'randomize_mass=uniform 0.5 2'])
    assert cfg['sim_node']['randomize_obs_noise'] == '0.02'
    assert cfg['sim_node']['randomize_mass'] == 'uniform 0.5 2'
    with pytest.raises(ConfigError, match="parameter 'sim_node.randomize_mass': 'uniform 2 1'"
                                          ' is not allowed: mass: the range 2 1 is empty'):
        load_config(None, ['randomize_mass=uniform 2 1'])


def test_an_add_that_takes_a_model_value_below_zero_is_refused():
    # reacher2's joints have damping 1
    ArmTask(REACHER, randomization={'damping': 'add -1 startup'}).close()
    with pytest.raises(BadTerm, match='the damping of this model would reach -0.5'):
        ArmTask(REACHER, randomization={'damping': 'add -1.5'})


def test_perturbation_keys():
    got = parse_perturbation(['mass_scale=1.3', 'latency_steps=2', 'obs_noise=0.02',
                              'damping_add=0.5', 'servo_bandwidth=5', 'payload=0.5'])
    assert {t: s.text() for t, s in got.items()} == {
        'mass': 'scale 1.3 startup', 'latency': 'abs 2 startup', 'obs_noise': 'abs 0.02 startup',
        'damping': 'add 0.5 startup', 'servo_bandwidth': 'abs 5 startup',
        'payload': 'abs 0.5 startup'}
    for bad, message in [(['mass=1.3', 'mass_scale=1'], 'mass given twice'),
                         (['weight_scale=2'], 'unknown key; known: mass_scale'),
                         (['mass_scale'], 'write KEY=VALUE'),
                         (['latency_steps=1.5'], 'latency is whole control steps'),
                         (['mass_scale=0'], 'a mass scale must stay > 0')]:
        with pytest.raises(BadTerm, match=message):
            parse_perturbation(bad)


def test_fixed_perturbations_change_exactly_their_model_fields():
    nominal = ArmTask(REACHER, num_envs=2)
    terms = parse_perturbation(['mass_scale=1.3', 'damping_scale=2', 'gear_scale=0.8',
                                'armature_add=0.5', 'frictionloss_abs=0.1'])
    task = ArmTask(REACHER, num_envs=2, randomization=terms)
    base, links, dofs = nominal.model, [1, 2, 3], task.spec.dof_adr
    for m in task.models:
        assert np.allclose(m.body_mass[links], 1.3 * base.body_mass[links])
        assert np.allclose(m.body_inertia[links], 1.3 * base.body_inertia[links])
        assert m.body_mass[4] == base.body_mass[4]          # the target is no link
        assert np.allclose(m.dof_damping[dofs], 2 * base.dof_damping[dofs])
        assert np.allclose(m.dof_armature[dofs], base.dof_armature[dofs] + 0.5)
        assert np.allclose(m.dof_frictionloss[dofs], 0.1)
        assert np.allclose(m.actuator_gear[:, 0], 0.8 * base.actuator_gear[:, 0])
        assert np.all(m.dof_damping[2:] == base.dof_damping[2:])   # the target's slides
    # the shared nominal model is untouched
    assert np.allclose(task.model.body_mass, base.body_mass)
    nominal.close()
    task.close()


def test_episode_starts_are_the_nominal_ones_whatever_the_terms():
    """The terms draw from generators of their own: the same starts and goals."""
    a = ArmTask(REACHER, num_envs=4, seed=7, max_episode_steps=5)
    b = ArmTask(REACHER, num_envs=4, seed=7, max_episode_steps=5, randomization=EVERY_TERM)
    a.reset(), b.reset()
    acts = actions(12, 4)
    for t in range(12):
        a.step(acts[t]), b.step(acts[t])
        fresh = a.episode_step == 0
        if fresh.any():
            for i in np.flatnonzero(fresh):
                assert np.array_equal(a.datas[i].qpos, b.datas[i].qpos)
                assert np.array_equal(a.target_pos()[i], b.target_pos()[i])
    a.close(), b.close()


def test_stepping_groups_in_turn_is_stepping_all_arms_with_every_term():
    whole = ArmTask(REACHER, num_envs=6, seed=3, max_episode_steps=4,
                    randomization=EVERY_TERM)
    parts = ArmTask(REACHER, num_envs=6, seed=3, max_episode_steps=4,
                    randomization=EVERY_TERM)
    whole.reset(), parts.reset()
    acts = actions(20, 6)
    for t in range(20):
        o1, r1, *_ = whole.step(acts[t])
        a = parts.step(acts[t][:2], slice(0, 2))
        b = parts.step(acts[t][2:], slice(2, 6))
        assert np.array_equal(o1, np.concatenate([a[0], b[0]]))
        assert np.array_equal(r1, np.concatenate([a[1], b[1]]))
    assert np.array_equal(whole.randomizer.values, parts.randomizer.values)
    whole.close(), parts.close()


def test_latency_applies_each_command_that_many_steps_late():
    task = ArmTask(REACHER, num_envs=3, seed=0, max_episode_steps=6,
                   randomization=parse_perturbation(['latency_steps=2']))
    task.reset()
    acts = actions(9, 3) * 0.5
    for t in range(9):
        task.step(acts[t])
        # step k of an episode started at step 0 or 6 applies the command of step k - 2 of
        # it, and zero before (step 5 ends the episode: the reset clears the controls)
        k = t % 6
        want = acts[t - 2] if k >= 2 else np.zeros((3, 2))
        if k != 5:
            assert np.array_equal(np.array([d.ctrl for d in task.datas]), want), t
    task.close()


def test_reset_and_every_terms_are_redrawn_when_they_say():
    task = ArmTask(REACHER, num_envs=2, seed=0, max_episode_steps=4,
                   randomization={'mass': 'uniform 0.5 2', 'gear': 'uniform 0.5 2 startup',
                                  'armature': 'uniform 0.5 2 every 3'})
    r = task.randomizer
    task.reset()
    seen = []
    for t in range(12):
        seen.append((r.value(0, 'mass').copy(), r.value(0, 'gear').copy(),
                     r.value(0, 'armature').copy()))
        task.step(np.zeros((2, 2)))
    changed = [[not np.array_equal(seen[t][k], seen[t - 1][k]) for t in range(1, 12)]
               for k in range(3)]
    # seen[t] is the value before step t. mass: new at each reset (steps 3 and 7 end
    # episodes); gear: never; armature: each value serves 3 steps (0-2 the startup draw,
    # then 3-5, 6-8, 9-11, drawn as steps 3, 6, 9 begin), so seen[4], [7], [10] differ
    assert [t + 1 for t, c in enumerate(changed[0]) if c] == [4, 8]
    assert not any(changed[1])
    assert [t + 1 for t, c in enumerate(changed[2]) if c] == [4, 7, 10]
    task.close()


@pytest.mark.parametrize('text, mean, var', [
    ('uniform 0.02 0.06', 0.04, 0.04 ** 2 / 12),
    ('log_uniform 0.01 0.1', 0.09 / math.log(10),
     (0.1 ** 2 - 0.01 ** 2) / (2 * math.log(10)) - (0.09 / math.log(10)) ** 2),
    ('gaussian 0.05 0.01', 0.05, 0.01 ** 2 * 0.9733),   # truncated at 3 std
])
def test_distributions_have_their_mean_within_sampling_error(text, mean, var):
    """Per-arm draws of 4000 arms: the mean within 4 standard errors of the exact one."""
    n = 4000
    model = mujoco.MjModel.from_xml_path(str(REACHER))
    r = Randomizer(model, ArmSpec.from_model(model), {'obs_noise': parse_term('obs_noise', text)},
                   n, seed=1)
    x = r.values[:, 0]
    lo, hi = r.terms['obs_noise'].bounds
    assert x.min() >= lo and x.max() <= hi
    assert abs(x.mean() - mean) < 4 * math.sqrt(var / n), (x.mean(), mean)
    assert abs(x.var() / var - 1) < 0.1


def test_observation_noise_is_in_the_observation_only():
    a = ArmTask(REACHER, num_envs=2, seed=5)
    b = ArmTask(REACHER, num_envs=2, seed=5,
                randomization=parse_perturbation(['obs_noise=0.05', 'target_noise=0.02']))
    oa, ob = a.reset(), b.reset()
    assert not np.allclose(oa, ob)
    act = actions(1, 2)[0]
    ra, rb = a.step(act)[1], b.step(act)[1]
    assert np.array_equal(ra, rb)                 # the true reward, the same arm state
    obs = b.observe()
    q_noisy = np.arctan2(obs[:, 2:4], obs[:, 0:2])
    q_true = a.joint_state()[0]
    assert 0.01 < np.abs(q_noisy - q_true).mean() < 0.15
    # what a robot computes from noisy encoders and a noisy target: the fingertip by
    # forward kinematics of the noisy angles (policy_node's ObservationBuilder)
    target = b.target_pos()
    target[:, :2] = obs[:, 4:6]                     # the goal's x, y as observed (noisy)
    rebuilt = ObservationBuilder(b.model)(q_noisy, obs[:, 6:8], target)
    assert np.allclose(rebuilt, obs, atol=1e-12)
    a.close(), b.close()


def test_gymnasium_env_takes_the_terms_and_reseeds_them():
    env = gym.make('pg_node/Reacher2-v0', randomization={'mass': 'uniform 0.5 2',
                                                         'obs_noise': '0.01'})
    nominal = gym.make('pg_node/Reacher2-v0')
    o1, _ = env.reset(seed=3)
    m1 = env.unwrapped.task.randomizer.value(0, 'mass').copy()
    o2, _ = env.reset(seed=3)
    assert np.array_equal(o1, o2)
    assert np.array_equal(m1, env.unwrapped.task.randomizer.value(0, 'mass'))
    on, _ = nominal.reset(seed=3)
    assert np.array_equal(env.unwrapped.task.datas[0].qpos, nominal.unwrapped.task.datas[0].qpos)
    assert not np.array_equal(on, o1)
    env.close(), nominal.close()


#: one link in the vertical x-z plane on a stiff position servo (kp, kv critically damped for
#: its inertia of about 1.08 kg m^2: natural frequency 96 rad/s), its own gravity compensated
PENDULUM = """
<mujoco>
  <compiler angle="radian"/>
  <option timestep="0.002" integrator="implicitfast"/>
  <worldbody>
    <body name="link" pos="0 0 1" gravcomp="1">
      <joint name="joint0" type="hinge" axis="0 1 0" armature="1" range="-3 3" limited="true"/>
      <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.02" mass="1"/>
      <site name="fingertip" pos="0.5 0 0"/>
    </body>
    <body name="target" mocap="true" pos="0.5 0 1">
      <geom type="sphere" size="0.02" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <position name="joint0" joint="joint0" kp="10000" kv="208" ctrlrange="-1 1"/>
  </actuator>
  <custom>
    <numeric name="pg_init_qpos_noise" data="0"/>
    <numeric name="pg_init_qvel_noise" data="0"/>
  </custom>
</mujoco>
"""


@pytest.fixture
def pendulum(tmp_path):
    path = tmp_path / 'pendulum.xml'
    path.write_text(PENDULUM)
    return path


def step_response(path, terms, steps, command=0.5):
    """Return the servo's ctrl and the joint angle after each physics step of a step command."""
    task = ArmTask(path, num_envs=1, seed=0, frame_skip=1, max_episode_steps=None,
                   randomization=terms)
    task.reset()
    task.set_state(0, np.zeros(1), np.zeros(1))
    ctrl, q = [], []
    for _ in range(steps):
        task.step(np.full((1, 1), command))
        ctrl.append(task.datas[0].ctrl[0])
        q.append(task.datas[0].qpos[0])
    task.close()
    return np.array(ctrl), np.array(q)


def test_servo_lag_is_the_first_order_step_response_the_docs_give(pendulum):
    """
    ``servo_bandwidth`` f and ``servo_latency`` L: ctrl is ``1 - exp(-(t - L) / tau)``.

    The servo's setpoint after k physics steps of a step command is exactly the documented
    one (``tau = 1 / (2 pi f)``, dead time L in whole steps); the joint behind a stiff servo
    (critically damped at 96 rad/s: 63% of a step in 2.15 / 96 s) reaches 63% of the step
    between L + tau and L + tau plus that, where without the term it takes that alone.
    """
    f, latency, dt, steps = 1.0, 0.01, 0.002, 400
    tau = 1 / (2 * math.pi * f)
    ctrl, q = step_response(pendulum, {'servo_bandwidth': f'{f}',
                                       'servo_latency': f'{latency}'}, steps)
    k = np.arange(1, steps + 1) - round(latency / dt)      # steps since the dead time ended
    want = 0.5 * -np.expm1(-np.maximum(k, 0) * dt / tau)
    np.testing.assert_allclose(ctrl, want, rtol=1e-12, atol=1e-15)
    final = 0.5                      # MuJoCo's position actuator: ctrl is the angle, rad
    assert abs(q[-1] - final) < 0.01
    rise = dt * (1 + np.argmax(q >= 0.632 * final))
    own = 2.15 / 96
    assert latency + tau <= rise <= latency + tau + own + dt, (rise, latency + tau)
    ctrl0, q0 = step_response(pendulum, {}, steps)
    assert np.all(ctrl0 == 0.5)
    assert dt * (1 + np.argmax(q0 >= 0.632 * final)) <= own + dt


def test_a_position_servos_lag_starts_at_the_start_angle(pendulum):
    """
    The servo terms take the command before an episode as the one that holds the start pose.

    A position servo's zero control is mid-range: a lag and dead time starting there pulled
    the arm towards it at every episode start (this stiff servo from 0.8 to 0.34 rad in
    20 ms, before the fix). Holding the start angle, the arm stays to 1e-6 rad; motors and
    velocity servos keep zero, as before.
    """
    path = pendulum
    path.write_text(PENDULUM.replace('data="0"/>\n    <numeric name="pg_init_qvel',
                                     'data="0"/>\n    <numeric name="pg_init_qpos" '
                                     'data="0.8"/>\n    <numeric name="pg_init_qvel'))
    task = ArmTask(path, num_envs=1, seed=0, frame_skip=1, max_episode_steps=None,
                   randomization={'servo_bandwidth': '1', 'servo_latency': '0.01'})
    task.reset()
    assert task.datas[0].qpos[0] == 0.8
    np.testing.assert_allclose(task.hold_controls(np.array([0.8])), [0.8])
    for _ in range(10):                                     # 20 ms, holding the angle
        task.step(np.full((1, 1), 0.8))
        assert task.datas[0].ctrl[0] == pytest.approx(0.8, abs=1e-12)
    assert abs(task.datas[0].qpos[0] - 0.8) < 1e-6
    task.close()
    motors = ArmTask(REACHER, num_envs=1)
    assert np.array_equal(motors.hold_controls(np.array([0.5, -1.0])), np.zeros(2))
    motors.close()


def test_servo_terms_off_by_value_are_the_nominal_arm_to_the_bit():
    """A dead time of 0 and no bandwidth: the per-physics-step path is the nominal one."""
    a = ArmTask(REACHER, num_envs=2, seed=4)
    b = ArmTask(REACHER, num_envs=2, seed=4,
                randomization={'servo_latency': '0', 'payload': '0'})
    a.reset(), b.reset()
    for act in actions(10, 2):
        assert np.array_equal(a.step(act)[0], b.step(act)[0])
    a.close(), b.close()


def test_payload_pulls_at_the_fingertip_with_its_weight(pendulum):
    """
    ``payload`` m: the generalized force ``m g L`` on the horizontal link (L = 0.5 m).

    The link's own weight is compensated (gravcomp), so from rest with its servo off the
    unknown payload alone sets it falling, at about ``m g L / I`` (I about 1.08 kg m^2).
    """
    m, L, g = 0.4, 0.5, 9.81
    task = ArmTask(pendulum, num_envs=1, seed=0, frame_skip=1, max_episode_steps=None,
                   randomization={'payload': f'{m}'})
    task.reset()
    task.set_state(0, np.zeros(1), np.zeros(1))
    task.models[0].actuator_gainprm[0, 0] = task.models[0].actuator_biasprm[0, 1:3] = 0.0
    task.step(np.zeros((1, 1)))
    d = task.datas[0]
    # a force -m g z at (L, 0, 0) about the y axis: (L, 0, 0) x (0, 0, -m g) = m g L y
    assert d.qfrc_applied[0] == pytest.approx(m * g * L, rel=1e-9)
    inertia = task.model.dof_armature[0] + 1 * L ** 2 / 3
    assert d.qacc[0] == pytest.approx(m * g * L / inertia, rel=0.05)
    task.close()


def test_damping_and_friction_reach_zero_on_an_arm_that_has_none(tmp_path):
    """``abs uniform 0 x``: a torque robot's near-zero damping and friction, drawn per joint."""
    task = ArmTask(REACHER, num_envs=200, seed=0,
                   randomization={'damping': 'abs uniform 0 0.1',
                                  'frictionloss': 'abs log_uniform 0.0001 0.05'})
    damping = np.array([m.dof_damping[task.spec.dof_adr] for m in task.models])
    friction = np.array([m.dof_frictionloss[task.spec.dof_adr] for m in task.models])
    assert damping.min() < 0.001 and damping.max() <= 0.1
    assert friction.min() < 0.0002 and friction.max() <= 0.05
    task.close()
