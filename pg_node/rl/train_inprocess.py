"""
Training in one process, with the very classes the nodes wrap: the reference for the ROS graph.

The simulator, actor, critic and learner steps are called in turn, as the graph runs them in
lock-step synchronous mode; what differs is only the transport. The policy is sampled for
the simulator's groups of arms in turn (``lock_step_groups``), as the actor answers them.
Useful to tune hyperparameters, to compare the graph's learning against, and for profiling.
"""
import time
from typing import Callable, Dict, Optional

import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.common.perturbations import from_params
from pg_node.rl.critic import Critic
from pg_node.rl.evaluate import evaluate_policy
from pg_node.rl.learner import Learner
from pg_node.rl.rollout_buffer import RolloutBuffer
from pg_node.rl.sampler import make_rng, NumpySampler
from pg_node.sim.arm_task import arm_groups, ArmTask
import torch


def task_of(cfg: Dict[str, Dict]) -> ArmTask:
    """Return the simulator node's task: its arms, episode length, rewards, randomization."""
    shared, sim = cfg['/**'], cfg['sim_node']
    return ArmTask(resolve_model(shared['model']), num_envs=shared['num_envs'],
                   seed=shared['seed'], frame_skip=sim['frame_skip'],
                   max_episode_steps=sim['max_episode_steps'],
                   reward_dist_weight=sim['reward_dist_weight'],
                   reward_control_weight=sim['reward_control_weight'],
                   randomization=from_params(sim), position_delta=sim['position_delta'])


def train_inprocess(cfg: Dict[str, Dict], total_steps: int,
                    callback: Optional[Callable[[Dict], None]] = None,
                    eval_episodes: int = 100) -> Dict:
    """
    Train for ``total_steps`` environment steps; return the final summary.

    ``cfg`` is :func:`pg_node.common.config_files.load_config`'s result: every node's section,
    the simulator's (episode length, reward weights, randomization) included.
    """
    torch.set_num_threads(1)
    shared = cfg['/**']
    a_cfg, c_cfg, l_cfg = cfg['actor_node'], cfg['critic_node'], cfg['learner_node']
    task = task_of(cfg)
    learner = Learner(task.obs_dim, task.act_dim, {**l_cfg, **a_cfg})
    critic = Critic(task.obs_dim, c_cfg)
    buf = RolloutBuffer(a_cfg['n_steps'], task.num_envs, task.obs_dim, task.act_dim)
    # the actor node's sampler and generator (actor_id 0), loaded with the state the learner
    # publishes after each update: the same arithmetic, hence the same bits, as the graph
    sampler = NumpySampler.from_config(task.obs_dim, task.act_dim, {**l_cfg, **a_cfg})
    sampler.load(*learner.weights())
    rng = make_rng(shared['seed'])
    groups = arm_groups(task.num_envs, min(shared['lock_step_groups'], task.num_envs))
    lo, hi = task.spec.ctrl_low, task.spec.ctrl_high
    obs = task.reset()
    ep_step = task.episode_step.copy()
    ep_id = task.episode_id.copy()
    recent = []
    t0 = time.perf_counter()
    steps = 0
    policy = learner.policy
    try:
        while steps < total_steps:
            for _ in range(a_cfg['n_steps']):
                # the actor answers the simulator's groups of arms one after the other
                parts = [sampler.sample(obs[arms], rng) for arms in groups]
                act, logp = (np.concatenate(x) for x in zip(*parts))
                buf.add_action(obs, act, logp, ep_step, ep_id, 0)
                obs, rew, term, trunc, info = task.step(np.clip(act, lo, hi))
                buf.add_outcome(rew, term, trunc, info['final_obs'])
                ep_step, ep_id = info['episode_step'], info['episode_id']
                done = ~np.isnan(info['episode_return'])
                recent.extend(info['episode_return'][done].tolist())
            ro = buf.finish()
            adv, ret, c_stats = critic.annotate(ro, policy)
            l_stats = learner.learn(ro.obs, ro.act, ro.logp, adv)
            sampler.load(*learner.weights())
            steps += ro.rew.size
            recent = recent[-100:]
            if callback is not None:
                callback({'env_steps': steps, 'wall_seconds': time.perf_counter() - t0,
                          'episode_return': float(np.mean(recent)) if recent else float('nan'),
                          'learner': learner, 'critic': critic, **c_stats, **l_stats})
    finally:
        task.close()
    wall = time.perf_counter() - t0
    summary = {'total_steps': steps, 'wall_seconds': wall, 'steps_per_second': steps / wall,
               'policy_version': learner.version}
    summary.update(evaluate_policy(policy, shared['model'], eval_episodes, shared['seed'],
                                   frame_skip=cfg['sim_node']['frame_skip'],
                                   position_delta=cfg['sim_node']['position_delta']))
    summary['learner'] = learner
    summary['critic'] = critic
    return summary
