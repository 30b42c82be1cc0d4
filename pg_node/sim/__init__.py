"""
The simulator layer: the MuJoCo arm task and its Gymnasium environment.

``arm_task`` steps many copies of an arm model side by side (observations, rewards, episode
bookkeeping); ``gym_env`` wraps it as ``pg_node/Reacher2-v0``; ``models/`` holds the MJCF
arms. It imports MuJoCo and numpy only: no ``rclpy``, no torch.
"""
