"""
The critic's side of the training protocol, without ROS: which rollouts make which batch.

:class:`CriticBatching` takes the critic node's events (a rollout of version v, number s
from actor a arrived; the batch of version v was sent) and returns its decisions; the node
keeps the topics, the annotation (phi, V) and the counters.

- A rollout is known by ``(actor, rollout number, version)``. One seen before is an actor's
  re-send (no new weights came): it is not annotated again; the batch made from it is sent
  again instead, when there is one, because the batch or the weights may have been lost and
  the learner answers a repeated batch by publishing its weights again.
- In ``sync`` mode a batch holds one rollout of each of the ``num_actors`` actors, all of the
  same version, side by side in actor-id order, so the batch never depends on which message
  came first. Completing version v's group drops the groups of older versions (they can
  never be learned from); a rollout of an older version than a waiting group (the learner
  restarted from a checkpoint) drops the groups of the newer versions it lost.
- In ``async`` mode every new rollout is a batch of its own.

A restarted critic starts with nothing seen: a re-sent rollout is new to it. Invariants,
checked in code (a broken one is a bug and raises ``AssertionError``): a batch holds each
actor once, in actor order; only a batch of the rollouts last handed out is kept as sent.
"""
from collections import OrderedDict
from typing import Any, List, NamedTuple, Optional, Tuple

#: rollouts remembered to recognise a re-send
SEEN_MAX = 1000
#: batches kept for re-sending, the newest sent
SENT_MAX = 4


class RolloutStep(NamedTuple):
    """
    The decision about one rollout.

    ``duplicate``: seen before, ``resend`` the batch to send again (None: none was sent);
    otherwise ``parts`` (``[(actor, rollout)]``, empty while the group waits) make the batch
    of ``version``, and ``stale`` groups were dropped.
    """

    duplicate: bool = False
    resend: Any = None
    version: Optional[int] = None
    parts: List[Tuple[int, Any]] = []
    stale: int = 0


class CriticBatching:
    """
    Rollouts seen, groups waiting for their actors, batches sent.

    >>> c = CriticBatching(sync=True, num_actors=2)
    >>> c.on_rollout(1, 0, 0, 'b').parts
    []
    >>> c.on_rollout(0, 0, 0, 'a').parts
    [(0, 'a'), (1, 'b')]
    >>> c.sent(0, 'batch 0'); c.on_rollout(1, 0, 0, 'b')
    RolloutStep(duplicate=True, resend='batch 0', version=None, parts=[], stale=0)
    """

    def __init__(self, sync: bool, num_actors: int):
        self.sync = bool(sync)
        self.num_actors = int(num_actors)
        self.seen = OrderedDict()              # (actor, rollout number, version), oldest first
        self.groups = {}                       # version -> {actor: rollout}
        self.batches = OrderedDict()           # version -> last batch sent, oldest sent first
        self.handed_out = None                 # version of the newest batch's parts

    def on_rollout(self, actor: int, seq: int, version: int, rollout) -> RolloutStep:
        """Decide about ``rollout`` number ``seq`` of ``actor``, sampled by ``version``."""
        key = (actor, seq, version)
        if key in self.seen:
            return RolloutStep(duplicate=True, resend=self.batches.get(version))
        self.seen[key] = True
        while len(self.seen) > SEEN_MAX:
            self.seen.popitem(last=False)
        if not self.sync:
            return self._hand_out(version, [(actor, rollout)], 0)
        stale = 0
        for newer in [v for v in self.groups if v > version]:
            del self.groups[newer]
            stale += 1
        group = self.groups.setdefault(version, {})
        group[actor] = rollout
        if len(group) < self.num_actors:
            return RolloutStep(version=version, stale=stale)
        del self.groups[version]
        for old in [v for v in self.groups if v < version]:
            del self.groups[old]
            stale += 1
        return self._hand_out(version, sorted(group.items()), stale)

    def _hand_out(self, version: int, parts, stale: int) -> RolloutStep:
        actors = [a for a, _ in parts]
        if actors != sorted(set(actors)):
            raise AssertionError(f'a batch of actors {actors}: each once, in order')
        self.handed_out = version
        return RolloutStep(version=version, parts=parts, stale=stale)

    def sent(self, version: int, batch):
        """Keep ``batch``, made of the parts last handed out, for re-sending."""
        if version != self.handed_out:
            raise AssertionError(f'a batch of version {version} sent, but the rollouts '
                                 f'handed out were of version {self.handed_out}')
        self.handed_out = None
        self.batches[version] = batch
        self.batches.move_to_end(version)
        while len(self.batches) > SENT_MAX:
            # the oldest *sent*, not the lowest version: after a learner restart the
            # versions go back, and the batch just sent must stay ready for a re-send
            self.batches.popitem(last=False)
