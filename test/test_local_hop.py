"""The in-process hop's rules, with stand-ins for rclpy's publisher and subscription."""
from pg_node.ros import local_hop
from pg_node.ros.local_hop import LocalHop
import pytest


class Publisher:
    """What the hop uses of an rclpy publisher: the DDS writes it would make."""

    topic_name = '/pg_node/transition'

    def __init__(self, subscribers):
        self.subscribers = subscribers
        self.written = []

    def get_subscription_count(self):
        return self.subscribers

    def publish(self, msg):
        self.written.append(msg)


class Subscription:
    """What the hop uses of an rclpy subscription: its callback."""

    def __init__(self):
        self.got = []
        self.callback = self.got.append


@pytest.fixture(autouse=True)
def empty_queue():
    local_hop.PENDING.clear()
    yield
    local_hop.PENDING.clear()


def test_only_the_peer_subscribes_nothing_is_written_and_each_message_arrives_once():
    pub, sub = Publisher(1), Subscription()
    hop = LocalHop(pub, sub)
    hop.publish(b'a')
    hop.publish(b'b')
    assert sub.got == []                   # delivered by the spin loop, not inside publish
    assert local_hop.deliver() is False
    assert sub.got == [b'a', b'b'] and pub.written == []
    assert hop.counters == {'handed_over': 2, 'also_published': 0, 'twins_dropped': 0}


@pytest.mark.parametrize('dds_first', [False, True])
def test_another_subscriber_gets_every_message_and_the_peer_each_once(dds_first):
    pub, sub = Publisher(2), Subscription()
    hop = LocalHop(pub, sub)
    for msg in (b'1', b'2', b'3'):
        hop.publish(msg)
    assert pub.written == [b'1', b'2', b'3']
    dds_copy = sub.callback                # the subscription now calls the hop
    if dds_first:
        for msg in pub.written:
            dds_copy(msg)
        local_hop.deliver()
    else:
        local_hop.deliver()
        for msg in pub.written:
            dds_copy(msg)
    assert sub.got == [b'1', b'2', b'3']
    assert hop.counters['twins_dropped'] == 3 and not hop.twins


def test_a_message_from_another_process_and_a_resent_one_are_delivered():
    pub, sub = Publisher(2), Subscription()
    hop = LocalHop(pub, sub)
    sub.callback(b'from elsewhere')        # not a copy of anything the hop handed over
    hop.publish(b'x')
    local_hop.deliver()
    sub.callback(b'x')                     # the DDS copy of x: dropped
    hop.publish(b'x')                      # x sent again (a lock-step re-send): delivered
    local_hop.deliver()
    assert sub.got == [b'from elsewhere', b'x', b'x']


def test_a_chain_of_hand_overs_yields_to_the_executor():
    pub, sub = Publisher(1), Subscription()
    hop = LocalHop(pub, sub)
    calls = []

    def answer(msg):                       # every message is answered with another
        calls.append(msg)
        hop.publish(msg + 1)

    hop._deliver = answer
    hop.publish(0)
    assert local_hop.deliver(budget=0.0) is True      # one, then the executor's turn
    assert calls == [0] and len(local_hop.PENDING) == 1
    assert local_hop.deliver(budget=0.001) is True
    assert calls[:3] == [0, 1, 2]
