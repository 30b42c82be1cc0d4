"""
The learning layer: the policy-gradient math, with no ``rclpy`` anywhere in it.

One concept per module, bottom up: ``rollout`` (the data), ``returns``, ``baselines``,
``gae`` and ``estimators`` (every choice of phi in the notes' eq. 20), ``networks``,
``normalization``, ``policy`` and ``value``, ``losses`` and ``a2c`` (A2C, PPO),
``natural_gradient`` (NPG, TRPO), ``updaters`` (the registry: the update ``algo`` names),
``rollout_buffer``, ``weights`` and ``checkpoint`` (what crosses process boundaries),
``logger`` (TensorBoard), the two jobs the nodes run, ``critic`` and ``learner``, and the
training protocol's rules as one machine per node: ``actor_sync``, ``critic_batching``,
``learner_gate``. ``evaluate`` and ``train_inprocess`` drive the simulator layer's ``ArmTask``
directly: the graph's computation in one process. ``trained_policy`` loads a policy from a
run, a checkpoint or an ONNX export (``onnx_export``) for use outside training.
"""
