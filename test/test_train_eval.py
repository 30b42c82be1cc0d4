"""
``train``'s closing evaluation runs the policy at the run's control step (issue 46).

A run trained at ``frame_skip:=20`` (an arm imported at 0.002 s) evaluated at the default 2
would act ten times as often in episodes a tenth as long: its summary's final distance then
said 17 cm where ``python -m pg_node eval`` of the same checkpoint said 2.9 cm.
"""
from pg_node.common.config_files import load_config
from pg_node.rl.checkpoint import load_latest
from pg_node.rl.evaluate import evaluate_policy
from pg_node.rl.learner import policy_from_checkpoint
from pg_node.rl.train_inprocess import train_inprocess
from pg_node.tools.train import evaluate_run
import yaml


def saved_run(tmp_path, sim_params):
    """Train 4096 steps of reacher2 in-process, save it as a run with ``sim_params``."""
    summary = train_inprocess(load_config(None, ['num_envs=8']), 4096, eval_episodes=1)
    run = tmp_path / 'run'
    summary['learner'].save(run / 'checkpoints')
    (run / 'params.yaml').write_text(yaml.safe_dump(
        {'/**/sim_node': {'ros__parameters': sim_params}}))
    return run, summary['learner']


def test_the_run_is_evaluated_at_its_own_frame_skip(tmp_path):
    run, _ = saved_run(tmp_path, {'frame_skip': 5})
    got = evaluate_run(run, 4)
    state, _ = load_latest(run / 'checkpoints')
    policy = policy_from_checkpoint(state)
    at = {k: evaluate_policy(policy, 'reacher2', 4, state['config']['seed'], frame_skip=k)
          for k in (2, 5)}
    assert got['eval_final_distances'] == at[5]['eval_final_distances']
    assert got['eval_final_distances'] != at[2]['eval_final_distances']
