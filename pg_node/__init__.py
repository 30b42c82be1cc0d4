"""
pg_node: likelihood-ratio policy gradients for a MuJoCo robot arm over ROS 2.

The package is cut into layers (see docs/architecture.md): ``common``, ``sim``,
``rl`` and ``lab`` never import ``rclpy``; ``bag``, ``ros`` and ``tools`` build on them.
Importing ``pg_node`` registers its Gymnasium ids (``pg_node/Reacher2-v0``,
``pg_node/Arm5-v0``, ``pg_node/Arm7-v0``) and nothing heavier: neither rclpy, torch nor
MuJoCo is loaded.
"""
from pg_node.sim.envs import register_envs

__version__ = '0.1.0'

register_envs()
