"""Hand-made actuator records of reacher2, for the tests of :mod:`pg_node.control`."""
import numpy as np
from pg_node.control.interfaces import Actuators

INF = np.inf
#: reacher2's joints' largest inertia, kg m^2 (pg_node.sim.actuation.joint_inertia)
INERTIA = np.array([1.0011533624389368, 1.000179039365328])


def record(gain, b1, b2, gear, affine=(True, True)) -> Actuators:
    """
    Two actuators on joint0 (unlimited) and joint1 ([-3, 3] rad), controls in [-1, 1].

    reacher2's joints: damping 1 N m s/rad, no force limit, the largest inertia that
    :func:`pg_node.sim.actuation.joint_inertia` finds (armature 1 and the links).
    """
    two = np.ones(2)
    return Actuators(names=('joint0', 'joint1'), joints=('joint0', 'joint1'), gain=gain * two,
                     b0=0 * two, b1=b1 * two, b2=b2 * two, gear=gear * two, ctrl_low=-two,
                     ctrl_high=two, joint_low=np.array([-INF, -3.0]),
                     joint_high=np.array([INF, 3.0]), affine=np.array(affine), damping=two,
                     force_limit=INF * two, inertia=INERTIA)


#: reacher2's motors: 200 N m at u = 1
REACHER2 = record(gain=1.0, b1=0.0, b2=0.0, gear=200.0)
#: reacher2 with position servos (test_safety.POSITION_XML): u is the angle 3 u rad
POSITION_SERVOS = record(gain=150.0, b1=-50.0, b2=-5.0, gear=1.0)
#: reacher2 with velocity servos (kv 10): u is the speed 2 u rad/s
VELOCITY_SERVOS = record(gain=20.0, b1=0.0, b2=-10.0, gear=1.0)
