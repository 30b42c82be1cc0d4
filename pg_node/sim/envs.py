"""
pg_node's Gymnasium ids, registered without importing MuJoCo, torch or rclpy.

``import pg_node`` calls :func:`register_envs`, so ``gymnasium.make('pg_node/Reacher2-v0')``
works after it; the environment class (:mod:`pg_node.sim.gym_env`) is imported by Gymnasium
only when an environment is made.
"""

#: id -> shipped model
ENV_IDS = {'pg_node/Reacher2-v0': 'reacher2', 'pg_node/Arm5-v0': 'arm5_3d',
           'pg_node/Arm7-v0': 'arm7'}
REACHER2_ID, ARM5_ID, ARM7_ID = ENV_IDS
MAX_EPISODE_STEPS = 50


def register_envs() -> bool:
    """Register the ids with Gymnasium (once); return False when Gymnasium is not installed."""
    try:
        import gymnasium
    except ImportError:
        return False
    for env_id, model in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point='pg_node.sim.gym_env:ArmEnv',
                               max_episode_steps=MAX_EPISODE_STEPS, kwargs={'model': model})
    return True
