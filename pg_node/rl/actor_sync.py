"""
The actor's side of the training protocol, without ROS: when it may act, what it re-sends.

:class:`ActorSync` takes the actor node's events (policy weights of version v arrived, a
transition ``seq`` of group g arrived, a rollout is started, sealed, sent; a timer tick at
time t) and returns its decisions; the node keeps the topics, the buffers and the counters.

- It acts only once it holds weights. In ``sync`` mode, after sealing a rollout sampled by
  version v it waits for version v + 1 (exact on-policy A2C); if none comes within the
  resend timeout (:func:`resend_timeout`) the node sends the rollout again, so a lost
  message or a restarted critic cannot stall the graph. In ``async`` mode it never waits.
- Weights of an older version than it holds (a learner restarted from a checkpoint) void
  the partial rollout: it was sampled with weights the learner no longer has.
- A lock-step simulator numbers its transitions, group g of G sending ``k * G + g``. The same
  number again is a re-send: the command already sent is sent again when it was answered
  (the first was lost), ignored while the answer waits, answered when it never was. A number
  that skips (a restarted simulator, a world reset) voids the partial rollout, whose last
  command's outcome is unknown.

Invariants, checked in code (a broken one is a bug of the caller and raises
``AssertionError``, also under ``python -O``): a rollout starts only when acting is allowed,
a sealed rollout was started and sampled by a version not newer than the one held, and the
rollout numbers only count up.
"""
from enum import Enum
from typing import NamedTuple

#: bytes per second a rollout is given on the way to the critic and back as weights: a
#: tenth of a 1 GbE link, so that a re-send never starts while the first is still in flight
LINK_BYTES_PER_SECOND = 12.5e6


def resend_timeout(configured: float, values: int) -> float:
    """
    Return the seconds to wait for new weights before re-sending a rollout of ``values``.

    ``rollout_resend_timeout`` plus the rollout's time on a tenth of a 1 GbE link: the
    ``arm7`` preset's rollouts are 1.1 MB, 0.09 s more; reacher2's 0.12 MB, 0.01 s.

    >>> resend_timeout(5.0, 125_000)
    5.08
    """
    return configured + round(8 * values / LINK_BYTES_PER_SECOND, 2)


class Step(Enum):
    """What to do with a transition (:meth:`ActorSync.on_transition`)."""

    NEXT = 'record its outcome and answer it'
    SKIPPED = 'discard the partial rollout, then answer it'
    REPEAT_ANSWERED = 'send the command already sent for it again'
    REPEAT_WAITING = 'ignore it: its answer waits for acting to be allowed'
    REPEAT_UNANSWERED = 'answer it: it was never answered'

    @property
    def repeated(self) -> bool:
        """Return whether the transition came before (the simulator re-sent it)."""
        return self.name.startswith('REPEAT')


class TransitionStep(NamedTuple):
    """The decision about one transition and the number the group had before it."""

    step: Step
    previous: int


class RolloutTag(NamedTuple):
    """What a sealed rollout is tagged with: the version that sampled it and its number."""

    version: int
    seq: int
    lag: int                        # versions held beyond the sampling one


class ActorSync:
    """
    The actor's protocol state: the policy version held, the one awaited, the rollouts sent.

    >>> a = ActorSync(sync=True)
    >>> a.on_weights(0), a.may_act
    (False, True)
    >>> a.start_rollout(); a.seal_rollout(), a.may_act, a.waiting()
    (RolloutTag(version=0, seq=0, lag=0), False, 'version 1')
    >>> a.sent(10.0); a.resend_due(14.0, 5.0), a.resend_due(15.5, 5.0)
    (False, True)
    >>> a.on_weights(1), a.may_act
    (False, True)
    """

    def __init__(self, sync: bool, groups: int = 1):
        self.sync = bool(sync)
        self.version = -1                      # no weights yet: do not act
        self.wait_for = None                   # version awaited in sync mode
        self.rollout_version = None            # version that sampled the partial rollout
        self.rollout_seq = 0                   # number of the next rollout sealed
        self.sealed = None                     # tag of the newest rollout sealed
        self.last_sent = None                  # time it was last sent
        self.set_groups(groups)

    # --- weights ----------------------------------------------------------------------------

    def on_weights(self, version: int) -> bool:
        """
        Hold ``version``; return whether the partial rollout is void (the version went back).

        A version older than the one held means the learner restarted from a checkpoint: a
        rollout gathered with newer weights would be refused, so it starts over and waits
        for nothing.
        """
        went_back = version < self.version
        if went_back:
            self.discard()
            self.wait_for = None
        self.version = version
        if self.wait_for is not None and self.version >= self.wait_for:
            self.wait_for = None
        return went_back

    @property
    def may_act(self) -> bool:
        """Return whether a command may be sampled: weights held, no version awaited."""
        return self.version >= 0 and self.wait_for is None

    def waiting(self) -> str:
        """Return what the actor waits for, as its diagnostics say it."""
        if self.version < 0:
            return 'weights'
        return f'version {self.wait_for}' if self.wait_for is not None else 'nothing'

    # --- transitions ------------------------------------------------------------------------

    def set_groups(self, groups: int):
        """Expect the simulator's transitions in ``groups`` groups, none seen yet."""
        self.groups = int(groups)
        self.last_seq = [-1] * self.groups

    def on_transition(self, group: int, seq: int, answered: bool, waiting: bool,
                      partial: bool) -> TransitionStep:
        """
        Decide about transition ``seq`` of ``group``; remember it unless it is ignored.

        ``answered``: the group's last command waits for its outcome; ``waiting``: the
        group's last transition waits to be answered; ``partial``: the group's buffer holds
        steps of a rollout.
        """
        previous = self.last_seq[group]
        if seq == previous:
            if answered:
                return TransitionStep(Step.REPEAT_ANSWERED, previous)
            if waiting:
                return TransitionStep(Step.REPEAT_WAITING, previous)
            step = Step.REPEAT_UNANSWERED
        elif seq != previous + self.groups and partial:
            step = Step.SKIPPED
        else:
            step = Step.NEXT
        self.last_seq[group] = seq
        return TransitionStep(step, previous)

    # --- rollouts ---------------------------------------------------------------------------

    def start_rollout(self):
        """Note that the first command of a rollout is sampled now, with the version held."""
        if not self.may_act:
            raise AssertionError(f'a rollout started while the actor may not act (version '
                                 f'{self.version}, waiting for {self.wait_for})')
        self.rollout_version = self.version

    def discard(self):
        """Forget the partial rollout (its steps are dropped)."""
        self.rollout_version = None

    def seal_rollout(self) -> RolloutTag:
        """
        Tag the full rollout for sending; in sync mode, wait for the next version.

        The rollout's number is one above the last one sealed.
        """
        if self.rollout_version is None:
            raise AssertionError('a rollout sealed that was never started (or was discarded)')
        if self.rollout_version > self.version:
            raise AssertionError(f'a rollout of version {self.rollout_version} sealed while '
                                 f'the actor holds version {self.version}')
        if self.sealed is not None and self.rollout_seq <= self.sealed.seq:
            raise AssertionError(f'rollout number {self.rollout_seq} after '
                                 f'{self.sealed.seq}: the numbers went back')
        self.sealed = RolloutTag(self.rollout_version, self.rollout_seq,
                                 self.version - self.rollout_version)
        self.rollout_seq += 1
        self.rollout_version = None
        if self.sync:
            self.wait_for = self.sealed.version + 1
        return self.sealed

    def sent(self, now: float):
        """Note that the sealed rollout was (re-)sent at ``now`` (seconds, monotonic)."""
        if self.sealed is None:
            raise AssertionError('a rollout sent that was never sealed')
        self.last_sent = now

    def resend_due(self, now: float, timeout: float) -> bool:
        """Return whether the sealed rollout should go again: no awaited version for long."""
        return (self.wait_for is not None and self.last_sent is not None
                and now - self.last_sent > timeout)
