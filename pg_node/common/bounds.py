"""
The largest magnitude a real value may have in pg_node: on the wire, and in a simulated arm.

Observations, actions, rewards, advantages and torque commands of an arm stay far below
:data:`MAX_ABS`; a value beyond it is a bug upstream (1e300) or physics that blew up, and
one such value would poison the running observation statistics for good. The wire format
(:mod:`pg_node.ros.table_msg`) refuses it, and the simulator (:mod:`pg_node.sim.arm_task`)
ends the episode of an arm whose observation passes it, resets the arm and counts it.
"""

MAX_ABS = 1e6
