"""
pg_node's arm tasks as Gymnasium environments, so SB3 or CleanRL can train on them.

Importing this module registers

* ``pg_node/Reacher2-v0``: the ``reacher2`` arm (Reacher-v5's physics and task);
* ``pg_node/Arm5-v0``: the ``arm5_3d`` five-joint arm reaching in 3-D;

both with ``max_episode_steps=50`` (Gymnasium adds the ``TimeLimit`` wrapper). Any model
following the conventions of :mod:`pg_node.sim.arm_task` can be used with
``gymnasium.make('pg_node/Reacher2-v0', model='/path/arm.xml')``.

The environment is one :class:`~pg_node.sim.arm_task.ArmTask` with ``num_envs=1`` and no
truncation of its own. It draws from ``self.np_random``, exactly as ``Reacher-v5`` does, so
``reset(seed=s)`` of ``pg_node/Reacher2-v0`` gives the same episodes as ``Reacher-v5``'s.
``render_mode='rgb_array'`` draws the arm with MuJoCo's offscreen renderer, through a camera
that frames it (:func:`pg_node.sim.view.framing_camera`); on a machine without a display it
uses OSMesa by itself (:func:`pg_node.sim.view.use_headless_gl`).

Example (``import pg_node`` registers the ids; it imports neither rclpy nor torch)::

    import gymnasium as gym
    import pg_node  # noqa: F401
    from stable_baselines3 import PPO
    PPO('MlpPolicy', gym.make('pg_node/Reacher2-v0')).learn(100_000)
"""
from typing import Optional

import gymnasium
from gymnasium import spaces
import numpy as np

from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmTask
from pg_node.sim.envs import register_envs
from pg_node.sim.view import framing_camera, use_headless_gl


class ArmEnv(gymnasium.Env):
    """One arm of :class:`~pg_node.sim.arm_task.ArmTask` behind Gymnasium's ``Env`` API."""

    metadata = {'render_modes': ['rgb_array']}

    def __init__(self, model: str = 'reacher2', frame_skip: int = 2,
                 reward_dist_weight: float = 1.0, reward_control_weight: float = 1.0,
                 render_mode: Optional[str] = None, width: int = 320, height: int = 240,
                 randomization: Optional[dict] = None):
        """
        Load ``model`` (a shipped model's name or an MJCF path).

        ``render_mode='rgb_array'`` (what SB3's ``make_vec_env`` asks for) makes
        :meth:`render` return the arm drawn by MuJoCo's offscreen renderer; the renderer is
        created on the first call, so an environment that is never rendered needs no OpenGL.
        ``randomization`` takes the terms of :mod:`pg_node.sim.randomization`, as
        ``sim_node``'s ``randomize_<term>`` parameters do (``{'mass': 'uniform 0.7 1.5'}``);
        ``reset(seed=s)`` seeds them as the simulator's arm 0 of seed ``s``.
        """
        if render_mode not in (None, 'rgb_array'):
            raise ValueError(f'render_mode {render_mode!r} is not supported; use None or '
                             "'rgb_array'")
        self.render_mode = render_mode
        self._render_size = (int(height), int(width))
        self._renderer = None
        self._camera = None
        self.task = ArmTask(resolve_model(model), num_envs=1, frame_skip=frame_skip,
                            max_episode_steps=None, reward_dist_weight=reward_dist_weight,
                            reward_control_weight=reward_control_weight, num_threads=1,
                            randomization=randomization)
        spec = self.task.spec
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(self.task.obs_dim,),
                                            dtype=np.float64)
        # as Gymnasium's MujocoEnv: float32 bounds from the actuators' control ranges
        self.action_space = spaces.Box(spec.ctrl_low.astype(np.float32),
                                       spec.ctrl_high.astype(np.float32), dtype=np.float32)
        self.metadata = {'render_modes': ['rgb_array'],
                         'render_fps': int(np.round(1.0 / self.task.dt))}

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        """Start an episode drawn from ``self.np_random``; return ``(obs, info)``."""
        super().reset(seed=seed)
        if seed is not None and self.task.randomizer is not None:
            self.task.randomizer.seed(seed)
        self.task.rngs[0] = self.np_random
        self.task.reset_env(0)
        return self.task.observe()[0], {}

    def step(self, action):
        """Apply ``action`` for one control step; return Gymnasium's 5-tuple."""
        act = np.asarray(action, dtype=np.float64).reshape(1, self.task.act_dim)
        obs, reward, terminated, truncated, info = self.task.step(act)
        return (obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]),
                {'reward_dist': float(info['reward_dist'][0]),
                 'reward_ctrl': float(info['reward_ctrl'][0]),
                 'distance': float(info['distance'][0])})

    def render(self):
        """Return the current frame as an ``(height, width, 3)`` uint8 array (rgb_array)."""
        if self.render_mode != 'rgb_array':
            return None
        if self._renderer is None:
            import mujoco
            use_headless_gl()
            model = self.task.model
            height, width = self._render_size
            model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
            model.vis.global_.offheight = max(model.vis.global_.offheight, height)
            self._renderer = mujoco.Renderer(model, height, width)
            self._camera = framing_camera(model, self.task.spec.target_dim)
        self._renderer.update_scene(self.task.datas[0], self._camera)
        return self._renderer.render()

    def close(self):
        """Release the task and the renderer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.task.close()


register_envs()
