"""
Messages the tests send to the nodes: an actor's rollout for reacher2 (``OBS`` and ``ACT``).

Not a test module: ``test_faults`` and ``test_critic_and_learner`` import it (pytest puts
this folder on ``sys.path``, as for ``domains``).
"""
import numpy as np
from pg_node.rl.rollout_buffer import RolloutArrays
from pg_node.ros import messages
from pg_node.ros import table_msg

OBS, ACT = 10, 2                # reacher2: observation and action sizes
N, T = 2, 4                     # arms and control steps of a sample rollout


def make_rollout(rollout_seq: int, version: int = 0, obs_dim: int = OBS, first_seq: int = 0,
                 run: int = 0, **change):
    """
    Return actor 0's rollout ``rollout_seq`` of policy ``version`` as a message.

    Seeded by ``rollout_seq``; transition numbers ``first_seq``.. ``first_seq + T - 1``;
    ``run``: the run token in its header; ``change`` replaces whole fields (malformed
    rollouts).
    """
    rng = np.random.default_rng(rollout_seq)
    steps = np.repeat(np.arange(T)[:, None], N, 1) + first_seq
    f = {'obs': rng.normal(size=(T, N, obs_dim)), 'act': rng.normal(size=(T, N, ACT)),
         'logp': np.zeros((T, N)), 'rew': rng.normal(size=(T, N)),
         'terminated': np.zeros((T, N), bool), 'truncated': np.zeros((T, N), bool),
         'final_obs': rng.normal(size=(T, N, obs_dim)), 'ep_step': steps,
         'episode_id': np.zeros((T, N), int), 'seq': steps}
    f.update(change)
    return table_msg.to_msg(*messages.pack_rollout(RolloutArrays(**f), version, 0,
                                                   rollout_seq, run))
