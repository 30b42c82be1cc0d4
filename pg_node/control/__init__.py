"""
The robot-facing layer: what an arm receives and what a policy sees, with no ROS and no MuJoCo.

A robot's controller speaks command interfaces (effort, position, velocity) in SI units, and a
policy sees an observation laid out one way. This layer holds the rules of that boundary as
plain numpy code, so that training (the simulator layer), deployment (``policy_node``) and the
tools share one copy of each and test it without a live node or a physics engine.
"""
