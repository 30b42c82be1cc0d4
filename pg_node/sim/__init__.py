"""
The simulator layer: the MuJoCo arm task and its Gymnasium environment.

``arm_task`` steps many copies of an arm model side by side (observations, rewards, episode
bookkeeping); ``observation`` builds the same observation from measured joint states (for a
policy driving a real arm); ``envs`` registers the Gymnasium ids and ``gym_env`` is the
environment; ``view`` frames the arm for rendering; ``models/`` holds the MJCF arms. It
imports MuJoCo and numpy only: no ``rclpy``, no torch.
"""
