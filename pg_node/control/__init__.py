"""
The robot-facing layer: what an arm receives and what a policy sees, with no ROS and no engine.

A robot's controller speaks command interfaces in SI units, and a policy sees an observation
laid out one way. This layer holds the rules of that boundary as plain numpy code, so that
training (the simulator layer), deployment (``policy_node``) and the tools share one copy of
each and test it without a live node or a physics engine (``test/test_architecture.py``
imports it with rclpy, MuJoCo, torch, onnxruntime and PyBullet blocked).

One concept a module: ``interfaces`` (the command-interface registry: unit, actuator kind,
hold, joint-limit rule, trajectory field, the SI maps over a plain ``Actuators`` record),
``guards`` (``CommandGuard``: range, ramp, smoothing, rate limit, joint limits, over-speed,
one named step each), ``status`` (guard events, node states and faults with a severity: the
diagnostics level comes from it), ``joint_map`` (joint states to the model's joints),
``targets`` (goal frames and the reach clamp), ``watchdog`` (stale joint states), ``estop``
(the latched emergency stop), ``composers`` (the joint trajectory point a controller gets),
``jtc`` (Jazzy's joint trajectory controller: its acceptance rules, parameters and hold) and
``obs_layout`` (the observation's one layout). ``pg_node.sim.actuation`` reads the
``Actuators`` record out of a MuJoCo model; ``pg_node.ros.policy_node`` is the ROS glue.
"""
