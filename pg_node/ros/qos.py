"""
The QoS profiles of pg_node's topics between its nodes (sensor data uses rclpy's own).

A latched topic is one a late or restarted subscriber still gets (the policy's weights, the
learner's state); the training stream between the nodes is reliable and volatile.
"""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Reliable, keep-last-1, transient-local: a late or restarted subscriber gets the latest.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST)
#: Reliable, volatile, a few deep: the rollouts and batches between training nodes.
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
