"""
A node's ``/diagnostics`` status and the rate counters it reports.

Each node publishes one ``diagnostic_msgs/DiagnosticStatus`` of its own from its counters, as
``diagnostic_updater`` would, with a level and a one-line message.
"""
import time
from typing import Dict

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node


class Diagnostics:
    """Publishes one ``DiagnosticStatus`` of a node on ``/diagnostics`` from its counters."""

    def __init__(self, node: Node, name: str, hardware_id: str = ''):
        self.node = node
        self.name = name
        self.hardware_id = hardware_id
        self.pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)

    def publish(self, values: Dict, level: int = DiagnosticStatus.OK, message: str = 'ok'):
        """Publish ``values`` (stringified) with a level and a one-line message."""
        status = DiagnosticStatus(name=self.name, hardware_id=self.hardware_id,
                                  level=level, message=message)
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [status]
        self.pub.publish(msg)


class RateCounter:
    """Counts events and reports their rate since the last report."""

    def __init__(self):
        self.count = 0
        self._last_count = 0
        self._last_time = time.monotonic()

    def add(self, n: int = 1):
        """Count ``n`` events."""
        self.count += n

    def rate(self) -> float:
        """Return events per second since the previous call."""
        now = time.monotonic()
        r = (self.count - self._last_count) / max(now - self._last_time, 1e-9)
        self._last_count, self._last_time = self.count, now
        return r
