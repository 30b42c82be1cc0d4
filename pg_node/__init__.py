"""
pg_node: likelihood-ratio policy gradients for a MuJoCo robot arm over ROS 2.

The math (policy, value function, estimators of phi, losses) lives in modules that never
import ``rclpy``; only the ``*_node.py`` modules and the bag tools touch ROS.
"""

__version__ = '0.1.0'
