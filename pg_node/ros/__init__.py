"""
The ROS 2 layer: the nodes, their wire formats and the helpers they share.

Nodes (one module each, ``main`` is the executable): ``sim_node``, ``actor_node``,
``critic_node``, ``learner_node``, ``replay_node``, and ``policy_node`` (a trained policy
driving any arm through ``joint_states``). Wire formats: ``table_msg`` (the one codec of
pg_node's array messages), ``transition`` (simulator to actor), ``command`` (the tagged
torque command) and ``messages`` (rollouts, batches, weights). ``parameters`` declares each
node's parameters with their limits and applies live changes. What the nodes share, one
concern a module: ``qos`` (the profiles of pg_node's topics), ``diagnostics`` (a node's
``/diagnostics`` status and rate counters), ``run_protocol`` (a run's topics, token and end)
and ``runtime`` (init, executor, stop signals, the ``main`` loop). A node is thin:
parameters in, topics in and out, a call into the layers below.
"""
