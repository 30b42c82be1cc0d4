"""
The estimator labs: bias and variance of every gradient estimator against a known gradient.

``linear_gaussian`` is a control problem whose policy gradient and value function are exact;
``variance`` runs every estimator on the same batches of it; ``arm`` does the same on the
simulated arm with a partly trained policy, against a very large batch. No ``rclpy``.
"""
