"""
The base layer: where pg_node's files are, and its parameter table.

``paths`` finds the shared files (config, launch, models) in a checkout or an install;
``params`` holds every node's parameters (default, type, range, meaning) and loads and checks
ROS 2 parameter files. Neither imports ``rclpy``, torch or MuJoCo, so every layer may use them.
"""
