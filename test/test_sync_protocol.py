"""
The training protocol's three machines, driven by hand, with no node and no DDS.

The actor's (when it may act, what a repeated transition means, when a rollout goes
again), the critic's (which rollouts make a batch, what a repeated rollout gets) and the
learner's (which batch it learns from). Each invariant the machines check has a test that
makes it fire. The graph that drives them is tested end to end in test_training_graph.py.
"""
from pg_node.rl.actor_sync import ActorSync, resend_timeout, RolloutTag, Step
from pg_node.rl.critic_batching import CriticBatching, SEEN_MAX, SENT_MAX
from pg_node.rl.learner_gate import LearnerGate, Verdict
import pytest


# --- the actor ----------------------------------------------------------------------------

def rollout(actor: ActorSync) -> RolloutTag:
    """Start and seal one rollout, as the node does from its first command to its send."""
    actor.start_rollout()
    return actor.seal_rollout()


def test_actor_lock_step_cycle_waits_for_each_next_version():
    a = ActorSync(sync=True)
    assert not a.may_act and a.waiting() == 'weights'
    assert a.on_weights(0) is False and a.may_act and a.waiting() == 'nothing'
    assert rollout(a) == RolloutTag(version=0, seq=0, lag=0)
    assert not a.may_act and a.waiting() == 'version 1'
    a.on_weights(0)                        # the latched weights again: still waiting
    assert not a.may_act
    a.on_weights(1)
    assert a.may_act
    assert rollout(a) == RolloutTag(version=1, seq=1, lag=0)
    assert a.wait_for == 2


def test_actor_resends_a_lost_rollout_after_the_timeout_and_stops_when_answered():
    a = ActorSync(sync=True)
    a.on_weights(0)
    assert not a.resend_due(100.0, 5.0)    # nothing sent yet
    rollout(a)
    a.sent(10.0)
    assert not a.resend_due(15.0, 5.0)
    assert a.resend_due(15.01, 5.0)
    a.sent(15.01)                          # the re-send starts the timeout again
    assert not a.resend_due(20.0, 5.0) and a.resend_due(20.02, 5.0)
    a.on_weights(1)
    assert not a.resend_due(1000.0, 5.0)


def test_resend_timeout_adds_the_rollouts_time_on_a_slow_link():
    assert resend_timeout(5.0, 0) == 5.0
    assert resend_timeout(5.0, 137_500) == 5.09          # arm7's 1.1 MB
    assert resend_timeout(2.0, 15_000) == 2.01           # reacher2's 0.12 MB


def test_actor_async_never_waits_and_reports_the_lag():
    a = ActorSync(sync=False)
    a.on_weights(0)
    a.start_rollout()
    a.on_weights(3)                        # newer weights mid-rollout
    assert a.seal_rollout() == RolloutTag(version=0, seq=0, lag=3)
    assert a.may_act and a.waiting() == 'nothing'
    a.sent(0.0)
    assert not a.resend_due(1000.0, 5.0)


def test_actor_learner_restart_voids_the_partial_rollout_and_the_wait():
    a = ActorSync(sync=True)
    a.on_weights(5)
    rollout(a)
    assert a.wait_for == 6
    assert a.on_weights(3) is True         # the learner resumed an older checkpoint
    assert a.may_act and a.wait_for is None
    a.start_rollout()
    assert a.on_weights(2) is True
    with pytest.raises(AssertionError, match='never started'):
        a.seal_rollout()                   # the partial rollout was void
    assert rollout(a) == RolloutTag(version=2, seq=1, lag=0)


def test_a_restarted_actor_acts_with_the_latched_version_and_numbers_from_zero():
    a = ActorSync(sync=True)
    a.on_weights(41)                       # the learner's latched weights
    assert a.may_act
    assert rollout(a) == RolloutTag(version=41, seq=0, lag=0)


def test_actor_transitions_in_order_then_repeated_then_skipped():
    a = ActorSync(sync=True, groups=2)
    kinds = [a.on_transition(s % 2, s, answered=False, waiting=False, partial=s > 1).step
             for s in range(4)]
    assert kinds == [Step.NEXT] * 4        # group g of 2 numbers 2k + g
    again = a.on_transition(1, 3, answered=True, waiting=False, partial=True)
    assert again == (Step.REPEAT_ANSWERED, 3) and again.step.repeated
    assert a.on_transition(1, 3, answered=False, waiting=True, partial=True).step is \
        Step.REPEAT_WAITING
    assert a.on_transition(1, 3, answered=False, waiting=False, partial=False).step is \
        Step.REPEAT_UNANSWERED
    assert not Step.NEXT.repeated and not Step.SKIPPED.repeated
    # a restarted simulator numbers from 0 again: the partial rollout is void
    assert a.on_transition(0, 0, answered=False, waiting=False, partial=True) == \
        (Step.SKIPPED, 2)
    # a jump with nothing gathered is just the next transition
    assert a.on_transition(0, 10, answered=False, waiting=False, partial=False).step is \
        Step.NEXT
    a.set_groups(1)
    assert a.on_transition(0, 7, answered=False, waiting=False, partial=False) == \
        (Step.NEXT, -1)


def test_actor_invariant_no_rollout_without_weights_or_while_waiting():
    a = ActorSync(sync=True)
    with pytest.raises(AssertionError, match='may not act'):
        a.start_rollout()
    a.on_weights(0)
    rollout(a)
    with pytest.raises(AssertionError, match='may not act'):
        a.start_rollout()                  # sync: version 1 is awaited


def test_actor_invariant_a_rollout_is_sealed_once_and_sent_after_sealing():
    a = ActorSync(sync=False)
    with pytest.raises(AssertionError, match='never sealed'):
        a.sent(0.0)
    a.on_weights(0)
    rollout(a)
    with pytest.raises(AssertionError, match='never started'):
        a.seal_rollout()


def test_actor_invariant_a_rollout_is_not_newer_than_the_weights_held():
    a = ActorSync(sync=False)
    a.on_weights(2)
    a.start_rollout()
    a.version = 1                          # a driver that lowered the version by hand
    with pytest.raises(AssertionError, match='of version 2 sealed while the actor holds'):
        a.seal_rollout()


def test_actor_invariant_rollout_numbers_never_go_back():
    a = ActorSync(sync=False)
    a.on_weights(0)
    rollout(a)
    a.rollout_seq = 0                      # a driver that set the counter back
    with pytest.raises(AssertionError, match='numbers went back'):
        rollout(a)


# --- the critic ---------------------------------------------------------------------------

def test_critic_one_actor_each_rollout_is_a_batch():
    c = CriticBatching(sync=True, num_actors=1)
    for v in range(3):
        step = c.on_rollout(0, v, v, f'r{v}')
        assert (step.duplicate, step.version, step.parts, step.stale) == \
            (False, v, [(0, f'r{v}')], 0)
        c.sent(v, f'batch {v}')


@pytest.mark.parametrize('order', [(0, 1, 2), (2, 0, 1), (1, 2, 0)])
def test_critic_several_actors_make_one_batch_in_actor_order(order):
    c = CriticBatching(sync=True, num_actors=3)
    steps = [c.on_rollout(a, 0, 4, f'r{a}') for a in order]
    assert [s.parts for s in steps[:2]] == [[], []]
    assert steps[2].version == 4 and steps[2].parts == [(0, 'r0'), (1, 'r1'), (2, 'r2')]


def test_critic_a_duplicate_gets_the_batch_made_from_it_once_there_is_one():
    c = CriticBatching(sync=True, num_actors=2)
    c.on_rollout(0, 7, 3, 'r0')
    assert c.on_rollout(0, 7, 3, 'r0').duplicate            # its group still waits
    assert c.on_rollout(0, 7, 3, 'r0').resend is None
    c.on_rollout(1, 7, 3, 'r1')
    c.sent(3, 'batch 3')
    step = c.on_rollout(1, 7, 3, 'r1')
    assert step.duplicate and step.resend == 'batch 3' and not step.parts
    # the same rollout number of another version is a new rollout
    assert not c.on_rollout(1, 7, 4, 'r1').duplicate


def test_critic_completing_a_version_drops_the_older_groups():
    c = CriticBatching(sync=True, num_actors=2)
    c.on_rollout(0, 0, 1, 'a')                 # actor 1's rollout of version 1 never came
    c.on_rollout(0, 1, 2, 'b')
    step = c.on_rollout(1, 1, 2, 'c')
    assert step.parts == [(0, 'b'), (1, 'c')] and step.stale == 1 and not c.groups


def test_critic_an_older_version_after_a_learner_restart_drops_the_newer_groups():
    c = CriticBatching(sync=True, num_actors=2)
    c.on_rollout(0, 0, 5, 'a')
    c.on_rollout(0, 1, 6, 'b')
    step = c.on_rollout(1, 0, 3, 'c')          # the learner went back to version 3
    assert step.stale == 2 and step.parts == [] and list(c.groups) == [3]


def test_critic_async_every_rollout_is_a_batch_of_its_own():
    c = CriticBatching(sync=False, num_actors=2)
    assert c.on_rollout(1, 0, 2, 'a').parts == [(1, 'a')]
    c.sent(2, 'batch')
    assert c.on_rollout(0, 0, 0, 'b').parts == [(0, 'b')]   # an old version too
    assert c.on_rollout(1, 0, 2, 'a').resend == 'batch'


def test_critic_keeps_the_newest_sent_batches_also_when_versions_go_back():
    c = CriticBatching(sync=True, num_actors=1)
    versions = [10, 11, 12, 13, 3]             # a learner restart: version 3 is the newest
    for k, v in enumerate(versions):
        c.on_rollout(0, k, v, 'r')
        c.sent(v, f'batch {v}')
    assert list(c.batches) == versions[-SENT_MAX:]
    assert c.on_rollout(0, 4, 3, 'r').resend == 'batch 3'
    assert c.on_rollout(0, 0, 10, 'r').resend is None         # forgotten: none to re-send


def test_critic_a_version_sent_again_is_the_newest_sent():
    c = CriticBatching(sync=True, num_actors=1)
    for k, v in enumerate([5, 6, 7, 8, 5, 9]):   # the learner went back to version 5
        c.on_rollout(0, k, v, 'r')
        c.sent(v, f'batch {v} #{k}')
    assert list(c.batches) == [7, 8, 5, 9] and c.batches[5] == 'batch 5 #4'


def test_critic_forgets_the_oldest_rollouts_beyond_its_memory():
    c = CriticBatching(sync=False, num_actors=1)
    for k in range(SEEN_MAX + 1):
        c.on_rollout(0, k, 0, 'r')
    assert len(c.seen) == SEEN_MAX
    assert c.on_rollout(0, SEEN_MAX, 0, 'r').duplicate
    assert not c.on_rollout(0, 0, 0, 'r').duplicate


def test_a_restarted_critic_takes_a_resent_rollout_as_new():
    before = CriticBatching(sync=True, num_actors=1)
    before.on_rollout(0, 9, 9, 'r')
    after = CriticBatching(sync=True, num_actors=1)
    assert after.on_rollout(0, 9, 9, 'r').parts == [(0, 'r')]


def test_critic_invariant_only_the_batch_handed_out_is_kept_as_sent():
    c = CriticBatching(sync=True, num_actors=1)
    with pytest.raises(AssertionError, match='handed out were of version None'):
        c.sent(0, 'batch')
    c.on_rollout(0, 0, 0, 'r')
    with pytest.raises(AssertionError, match='of version 1 sent'):
        c.sent(1, 'batch')
    c.sent(0, 'batch')
    with pytest.raises(AssertionError):
        c.sent(0, 'batch')                     # sent twice


def test_critic_invariant_a_batch_holds_each_actor_once_in_order():
    c = CriticBatching(sync=True, num_actors=2)
    for parts in ([(1, 'a'), (0, 'b')], [(0, 'a'), (0, 'b')]):
        with pytest.raises(AssertionError, match='each once, in order'):
            c._hand_out(0, parts, 0)


# --- the learner --------------------------------------------------------------------------

def test_learner_sync_learns_only_the_current_version():
    g = LearnerGate(sync=True, max_policy_lag=4)       # the lag applies to async only
    assert g.max_lag == 0
    assert g.on_batch(2, 0, policy_version=3) is Verdict.REFUSE
    assert g.on_batch(4, 0, policy_version=3) is Verdict.REFUSE
    assert g.on_batch(3, 0, policy_version=3) is Verdict.LEARN
    g.learned(policy_version=4)
    assert g.on_batch(3, 0, policy_version=4) is Verdict.REPEAT     # the critic's re-send
    assert g.on_batch(3, 1, policy_version=4) is Verdict.REFUSE


@pytest.mark.parametrize('lag,verdict', [(-1, Verdict.REFUSE), (0, Verdict.LEARN),
                                         (1, Verdict.LEARN), (2, Verdict.LEARN),
                                         (3, Verdict.REFUSE)])
def test_learner_async_learns_within_the_lag_allowed(lag, verdict):
    g = LearnerGate(sync=False, max_policy_lag=2)
    assert g.on_batch(10 - lag, 0, policy_version=10) is verdict


def test_learner_lock_step_cycle_learns_each_batch_once():
    g = LearnerGate(sync=True, max_policy_lag=0)
    version = 0
    for k in range(5):
        assert g.on_batch(version, k, version) is Verdict.LEARN
        version += 1
        g.learned(version)
        assert g.on_batch(version - 1, k, version) is Verdict.REPEAT


def test_a_restarted_learner_learns_a_resent_batch_of_its_version():
    g = LearnerGate(sync=True, max_policy_lag=0)       # resumed at version 7
    assert g.on_batch(7, 3, policy_version=7) is Verdict.LEARN


def test_learner_invariant_only_a_batch_let_in_is_learned_and_only_once():
    g = LearnerGate(sync=True, max_policy_lag=0)
    with pytest.raises(AssertionError, match='did not let in'):
        g.learned(1)
    g.on_batch(1, 0, policy_version=0)
    with pytest.raises(AssertionError, match='did not let in'):
        g.learned(1)                       # it was refused
    g.on_batch(0, 0, policy_version=0)
    g.learned(1)
    with pytest.raises(AssertionError, match='did not let in'):
        g.learned(2)                       # learned already


def test_learner_invariant_one_batch_advances_the_version_by_one():
    g = LearnerGate(sync=True, max_policy_lag=0)
    g.on_batch(0, 0, policy_version=0)
    with pytest.raises(AssertionError, match='went to 2'):
        g.learned(2)


def test_learner_invariant_a_learned_batch_is_within_the_lag():
    g = LearnerGate(sync=False, max_policy_lag=1)
    g.admitted = ((3, 0), 5)               # a driver that let in a batch by hand
    with pytest.raises(AssertionError, match='outside the lag allowed, 1'):
        g.learned(6)
