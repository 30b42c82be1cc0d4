"""
A topic handed over inside one process: the lock-step hop of the composed simulator and actor.

rclcpp's intra-process communication hands a message from a publisher to a subscription of
the same process without serialising it, writing it to the middleware and waking an
executor for it; rclpy has none. Between ``sim_node`` and ``actor_node`` composed in one
process (:mod:`pg_node.ros.sim_and_actor`) each control step then costs two DDS writes, two
takes and two executor wake-ups. A :class:`LocalHop` is that fast path for one topic, in
the spirit of rclcpp's: a message published through it is queued for the peer's callback
(:data:`PENDING`, delivered by :func:`deliver` in the process's spin loop,
:func:`pg_node.ros.runtime.run`), in order: the message itself, for the sim and the actor
the same CDR bytes their raw subscriptions take from DDS.

What the rest of the graph sees does not change:

* The message is also published on the real topic whenever it has a subscriber besides the
  peer (``ros2 topic echo``, a bag recorder, a probe): every message, as before. With none,
  the DDS write is skipped, so a transient-local topic's late joiner gets the messages from
  the next one on, not the last one before it joined.
* The peer keeps its DDS subscription, so a publisher in another process is still heard;
  the copy of a message that reached the peer through the hop and, for an outside
  subscriber's sake, through DDS too is dropped the second time it arrives (by its bytes:
  the CDR of a transition or a command is unique by its ``seq``), whichever path comes
  first.

The callbacks run where the executor's would, between two executor turns of the same
thread, so nothing runs concurrently. A chain of hand-overs (transition, command,
transition...) yields to the executor (timers, services, the learner's weights) after
:data:`SLICE` seconds.
"""
import collections
import time
from typing import Any, Callable, Deque, List, Tuple

#: hand-overs published in this process and not yet delivered: (receive, message), in order
PENDING: Deque[Tuple[Callable[[Any], None], Any]] = collections.deque()
#: seconds of hand-overs in a row before the executor gets a turn. A turn with nothing ready
#: costs about 0.1 ms (``spin_once(timeout_sec=0)`` of the events executor, on a busy 2-core
#: machine): a sync rollout's chain (8 control steps, about 14 ms with 64 arms) yields two or
#: three times, and 200 turns a second still serve the nodes' timers (10 Hz at most) and, in
#: async mode, the learner's weights
SLICE = 0.005
#: messages published on both paths whose second arrival is still to be dropped
TWINS = 64


class LocalHop:
    """
    One topic between a publisher and a subscription of two nodes of one process.

    Built from the publishing node's publisher and the receiving node's subscription; the
    publishing node then publishes through the hop (it has the publisher's ``publish``,
    ``get_subscription_count`` and ``topic_name``), and the subscription's callback gets each
    message once, through the hop or, from another process, through DDS.
    """

    def __init__(self, publisher, subscription):
        self.publisher = publisher
        self.topic_name = publisher.topic_name
        self._deliver = subscription.callback
        subscription.callback = self.receive          # DDS arrivals pass the twin check
        self.twins: Deque[List] = collections.deque(maxlen=TWINS)
        #: messages handed over, of them also written to DDS, and DDS copies dropped
        self.counters = {'handed_over': 0, 'also_published': 0, 'twins_dropped': 0}

    def get_subscription_count(self) -> int:
        """Return the topic's subscriptions, the peer's among them (as the publisher's)."""
        return self.publisher.get_subscription_count()

    def publish(self, msg) -> None:
        """Queue ``msg`` for the peer; write it to DDS too if anyone else subscribes."""
        if self.publisher.get_subscription_count() > 1:     # the peer's, and another's
            self.publisher.publish(msg)
            self.twins.append([msg, False])
            self.counters['also_published'] += 1
        PENDING.append((self.receive, msg))
        self.counters['handed_over'] += 1

    def receive(self, msg) -> None:
        """Give ``msg`` to the peer's callback, unless it is the second copy of one it had."""
        for i, twin in enumerate(self.twins):
            if twin[0] == msg:
                if twin[1]:
                    del self.twins[i]
                    self.counters['twins_dropped'] += 1
                    return
                twin[1] = True
                break
        self._deliver(msg)


def deliver(budget: float = SLICE) -> bool:
    """
    Deliver the pending hand-overs in order, for about ``budget`` seconds at most.

    A callback may publish through a hop again (the actor answers a transition with a
    command); that one is delivered in the same call while the budget lasts. Return whether
    any are still pending.
    """
    end = time.perf_counter() + budget
    while PENDING:
        receive, msg = PENDING.popleft()
        receive(msg)
        if time.perf_counter() > end:
            break
    return bool(PENDING)
