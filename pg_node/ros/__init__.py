"""
The ROS 2 layer: the nodes, their wire formats and the helpers they share.

Nodes (one module each, ``main`` is the executable): ``sim_node``, ``actor_node``,
``critic_node``, ``learner_node``, ``replay_node``. Wire formats: ``table_msg`` (the one codec
of pg_node's array messages), ``transition`` (simulator to actor) and ``messages`` (rollouts,
batches, weights). ``node_utils`` declares parameters and handles shutdown. A node is thin:
parameters in, topics in and out, a call into the layers below.
"""
