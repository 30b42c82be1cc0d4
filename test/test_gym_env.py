"""pg_node's Gymnasium ids: registration, Reacher-v5 equality, SB3's checker."""
import gymnasium as gym
from gymnasium.utils.env_checker import check_env
import numpy as np
from pg_node.sim.envs import ARM5_ID, ARM7_ID, REACHER2_ID
import pytest


def test_ids_are_registered_on_import():
    """In this process, by the tests' import of pg_node; the next test checks a fresh one."""
    assert REACHER2_ID == 'pg_node/Reacher2-v0' and ARM5_ID == 'pg_node/Arm5-v0'
    assert ARM7_ID == 'pg_node/Arm7-v0'
    for env_id in (REACHER2_ID, ARM5_ID, ARM7_ID):
        assert env_id in gym.registry
        assert gym.registry[env_id].max_episode_steps == 50


@pytest.mark.parametrize('env_id', [REACHER2_ID, ARM5_ID, ARM7_ID])
def test_gymnasium_and_sb3_checkers_pass(env_id):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env
    check_env(gym.make(env_id).unwrapped, skip_render_check=True)
    sb3_check_env(gym.make(env_id), warn=False)


def test_reacher2_v0_replays_reacher_v5_for_the_same_seed():
    ours, theirs = gym.make(REACHER2_ID), gym.make('Reacher-v5')
    assert ours.observation_space == theirs.observation_space
    assert ours.action_space == theirs.action_space
    o1, _ = ours.reset(seed=42)
    o2, _ = theirs.reset(seed=42)
    np.testing.assert_array_equal(o1, o2)
    rng = np.random.default_rng(9)
    truncations = 0
    for step in range(150):
        act = rng.uniform(-1, 1, 2)  # float64, so both penalties are computed alike
        o1, r1, te1, tr1, i1 = ours.step(act)
        o2, r2, te2, tr2, i2 = theirs.step(act)
        np.testing.assert_allclose(o1, o2, rtol=0, atol=1e-12)
        assert r1 == pytest.approx(r2, abs=1e-12)
        assert i1['reward_dist'] == pytest.approx(i2['reward_dist'], abs=1e-12)
        assert (te1, tr1) == (te2, tr2) == (False, (step + 1) % 50 == 0)
        if tr1:
            truncations += 1
            o1, _ = ours.reset()
            o2, _ = theirs.reset()
            np.testing.assert_array_equal(o1, o2)
    assert truncations == 3


def test_arm5_v0_spaces_and_time_limit():
    env = gym.make(ARM5_ID)
    assert env.observation_space.shape == (21,) and env.action_space.shape == (5,)
    env.reset(seed=0)
    for step in range(50):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert np.all(np.isfinite(obs)) and np.isfinite(reward) and reward < 0
        assert truncated == (step == 49) and not terminated


def test_model_kwarg_and_vector_env(tmp_path):
    env = gym.make(REACHER2_ID, model='arm5_3d')
    assert env.action_space.shape == (5,)
    venv = gym.make_vec(REACHER2_ID, num_envs=2, vectorization_mode='sync')
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (2, 10)
    obs, reward, *_ = venv.step(np.zeros((2, 2)))
    assert reward.shape == (2,)


def test_sb3_make_vec_env_default_render_mode_is_accepted():
    """SB3's make_vec_env asks for rgb_array; the env accepts it and renders only on request."""
    from stable_baselines3.common.env_util import make_vec_env
    venv = make_vec_env('pg_node/Reacher2-v0', n_envs=2, seed=0)
    try:
        assert venv.reset().shape == (2, 10)
        assert venv.get_attr('render_mode') == ['rgb_array', 'rgb_array']
    finally:
        venv.close()
    from pg_node.sim.gym_env import ArmEnv
    with pytest.raises(ValueError, match="render_mode 'human' is not supported"):
        ArmEnv(render_mode='human')


IMPORT_MAKE_RENDER = """
import sys
import numpy as np
import pg_node
import gymnasium as gym
env = gym.make('pg_node/Reacher2-v0', render_mode='rgb_array', width=240, height=240)
env.reset(seed=0)
heavy = sorted(m for m in ('rclpy', 'torch') if m in sys.modules)
frame = env.render()
env.close()
np.save(sys.argv[1], frame)
print(','.join(heavy) or 'none')
"""


def test_import_pg_node_registers_and_rgb_array_renders_headless(tmp_path):
    """``import pg_node`` then ``gym.make``: no rclpy or torch loaded; render needs no setup."""
    import os
    import subprocess
    import sys
    env = {k: v for k, v in os.environ.items()
           if k not in ('MUJOCO_GL', 'DISPLAY', 'WAYLAND_DISPLAY', 'PYOPENGL_PLATFORM')}
    out = tmp_path / 'frame.npy'
    res = subprocess.run([sys.executable, '-c', IMPORT_MAKE_RENDER, str(out)], env=env,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.split()[-1] == 'none'
    frame = np.load(out)
    assert frame.shape == (240, 240, 3) and frame.dtype == np.uint8
    # the camera frames the arm: its links (blue, unlike the grey floor and the pink walls)
    # show, start at the centre (the base is where the camera looks) and stay clear of the
    # picture's edges (the whole reach is in view)
    r, g, b = (frame[..., k].astype(int) for k in range(3))
    links = (b > r + 40) & (g > r)
    assert links.sum() > 100, links.sum()
    assert links[100:140, 100:140].any()
    assert links[12:-12, 12:-12].sum() == links.sum()
