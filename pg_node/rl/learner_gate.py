"""
The learner's side of the training protocol, without ROS: which batch it learns from.

:class:`LearnerGate` takes the learner node's events (a batch of version v, number s
arrived; a batch was learned from) and returns its verdict; the node keeps the topics, the
update, the logs and the counters.

- A batch is known by ``(version, batch number)``. The batch last learned from, received
  again (the critic re-sends it when an actor's rollout comes again), is not learned from
  twice: the learner publishes its weights again instead, in case they were lost.
- In ``sync`` mode only a batch sampled by the current policy version is learned from
  (on-policy A2C); in ``async`` mode one up to ``max_policy_lag`` versions old. Any other,
  a newer one included, is refused (and the node counts it).

Invariants, checked in code (a broken one is a bug of the caller and raises
``AssertionError``, also under ``python -O``): only the batch just let in is learned from,
once, its version within ``[version - max_lag, version]``, and each learned batch advances
the policy version by exactly one.
"""
from enum import Enum


class Verdict(Enum):
    """What the learner does with a batch (:meth:`LearnerGate.on_batch`)."""

    LEARN = 'learn from it: one update, one new version'
    REPEAT = 'publish the weights again: it was learned from already'
    REFUSE = 'refuse it: sampled by a version other than those allowed'


class LearnerGate:
    """
    The batch last learned from and the lag allowed.

    >>> g = LearnerGate(sync=True, max_policy_lag=4)
    >>> g.on_batch(0, 0, policy_version=1).name, g.on_batch(1, 0, policy_version=1).name
    ('REFUSE', 'LEARN')
    >>> g.learned(policy_version=2); g.on_batch(1, 0, policy_version=2).name
    'REPEAT'
    """

    def __init__(self, sync: bool, max_policy_lag: int):
        self.max_lag = 0 if sync else int(max_policy_lag)
        self.last_batch = None                 # (version, number) of the batch last learned
        self.admitted = None                   # (batch key, policy version) let in, unlearned

    def on_batch(self, version: int, seq: int, policy_version: int) -> Verdict:
        """Judge batch number ``seq`` of ``version`` at the current ``policy_version``."""
        self.admitted = None
        key = (version, seq)
        if key == self.last_batch:
            return Verdict.REPEAT
        if not 0 <= policy_version - version <= self.max_lag:
            return Verdict.REFUSE
        self.admitted = (key, policy_version)
        return Verdict.LEARN

    def learned(self, policy_version: int):
        """Note that the batch just let in was learned from, making ``policy_version``."""
        if self.admitted is None:
            raise AssertionError('learned from a batch the gate did not let in (refused, '
                                 'repeated, or learned already)')
        (version, seq), before = self.admitted
        if not before - self.max_lag <= version <= before:
            raise AssertionError(f'learned from a batch of version {version} at version '
                                 f'{before}: outside the lag allowed, {self.max_lag}')
        if policy_version != before + 1:
            raise AssertionError(f'policy version {before} went to {policy_version} after one '
                                 'batch, not to the next')
        self.last_batch = (version, seq)
        self.admitted = None
