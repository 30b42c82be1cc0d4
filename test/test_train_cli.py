"""
``python -m pg_node train`` as a user sees it: the console text, ``summary.json``, a resume.

One short real run (4096 steps, the four nodes as processes) and a resume of it to 6144
steps; stderr is not a terminal here, so the progress is printed as plain lines.
"""
import json
import os
from pathlib import Path
import re
import subprocess
import sys

from domains import ros_domain
import pytest

REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID = ros_domain(base=40, spread=60)

pytestmark = pytest.mark.e2e


def train(run_dir, total, timeout=300):
    env = dict(os.environ, PYTHONPATH=str(REPO), ROS_DOMAIN_ID=str(DOMAIN_ID),
               AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))
    env.pop('MUJOCO_GL', None)
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'train', '--total-steps',
                           str(total), '--run-dir', str(run_dir), '--eval-episodes', '4'],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout, json.loads((run_dir / 'summary.json').read_text())


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    """Return ``(run dir, first output, first summary, resumed output, resumed summary)``."""
    run_dir = tmp_path_factory.mktemp('train') / 'run'
    out1, sum1 = train(run_dir, 4096)
    out2, sum2 = train(run_dir, 6144)
    return run_dir, out1, sum1, out2, sum2


def test_start_line_names_the_algorithm(runs):
    _, out, _, _, _ = runs
    first, second = out.splitlines()[:2]
    assert first.startswith('pg_node: training a2c (phi = gae), 1 x 64 x reacher2 (sync)'), first
    assert 'for 4096 steps' in first
    # the run's name on the network, and where the graph reaches (the tests keep it local)
    assert second.startswith('run id run: topics /run/pg_node/..., graph on this machine '
                             'only (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST'), second


def test_progress_says_starting_then_labels_every_figure(runs):
    _, out, summary, _, _ = runs
    lines = out.splitlines()
    assert lines[2] == 'starting nodes...'
    assert re.fullmatch(r'nodes up after \d+\.\d s; learning', lines[3]), lines[3]
    progress = [ln for ln in lines if ln.startswith('step ')]
    assert progress, out
    assert re.fullmatch(r'step \d+/4096: ([\d,]+|n/a) steps/s \(since the first update\), '
                        r'ETA (\d\d:\d\d|n/a), '
                        r"training episodes' mean return (-?\d+\.\d\d|n/a \(no episode "
                        r'finished yet\)), policy version \d+', progress[0]), progress[0]
    # one speed in the whole output: the same figure in the last line as in summary.json
    assert len(re.findall(r'steps/s', out)) == len(progress) + 1
    sps = f"{summary['steps_per_second']:,.0f} steps/s from its first update to its last"
    assert sps in out
    evaluation = [ln for ln in lines if ln.startswith('deterministic evaluation: return ')]
    assert evaluation == [f"deterministic evaluation: return {summary['eval_return']:.2f} +/- "
                          f"{summary['eval_return_std']:.2f} over 4 episodes, final distance "
                          f"{100 * summary['eval_final_distance']:.2f} cm, "
                          f"{100 * summary['eval_reached']:.0f}% within 2 cm, policy "
                          f"version {summary['policy_version']}"]
    assert "training episodes' mean return (last update): " in out


def test_summary_separates_bringup_training_and_wall_time(runs):
    _, _, summary, _, _ = runs
    assert summary['session_steps'] == summary['total_steps'] == 4096
    assert summary['resumed_from_version'] is None
    assert 0 < summary['bringup_seconds'] < summary['wall_seconds_total']
    training = summary['session_training_seconds']
    assert 0 < training <= summary['wall_seconds'] < summary['wall_seconds_total']
    curve = summary['curve']
    first_update = curve[0]['env_steps']
    assert summary['steps_per_second'] == pytest.approx(
        (4096 - first_update) / training, rel=1e-6)


def test_summary_reports_each_nodes_memory_and_cpu(runs):
    """Peak memory and CPU seconds of every node; the nodes that only act hold no torch."""
    _, out, summary, _, _ = runs
    nodes = summary['nodes']
    # train's default: the simulator and the actor in one process, the critic and the
    # learner in another (--separate: a process each)
    assert set(nodes) == {'sim_and_actor', 'critic_and_learner'}
    for name, u in nodes.items():
        # a 4096-step run trains for a second or two: a node's CPU in it may round to 0
        assert 0 <= u['cpu_seconds_training'] <= u['cpu_seconds'], (name, u)
        assert u['cpu_seconds'] > 0 and 20 < u['peak_rss_mb'] < 4000, (name, u)
    assert sum(u['cpu_seconds_training'] for u in nodes.values()) > 0, nodes
    # torch alone maps several hundred MB; the simulator and the actor never import it
    assert nodes['sim_and_actor']['peak_rss_mb'] < 300 < \
        nodes['critic_and_learner']['peak_rss_mb']
    line = next(ln for ln in out.splitlines() if ln.startswith('nodes (peak memory'))
    assert f"sim_and_actor {nodes['sim_and_actor']['peak_rss_mb']:.0f} MB" in line


def test_resume_says_so_and_counts_this_session_only(runs):
    run_dir, _, sum1, out, summary = runs
    lines = out.splitlines()
    version = sum1['policy_version']
    assert lines[2].startswith(f'resumed from policy version {version} (4096 steps learned, '), \
        out
    assert summary['resumed_from_version'] == version
    assert summary['total_steps'] == 6144 and summary['session_steps'] == 2048
    # this session's speed: its own rows of progress.csv, not the whole run's clock
    rows = [r for r in summary['curve'] if r['env_steps'] > 4096]
    speed = (rows[-1]['env_steps'] - rows[0]['env_steps']) / (
        rows[-1]['wall_seconds'] - rows[0]['wall_seconds'])
    assert summary['steps_per_second'] == pytest.approx(speed, rel=1e-6)
    assert summary['session_training_seconds'] == pytest.approx(
        rows[-1]['wall_seconds'] - rows[0]['wall_seconds'], abs=1e-6)
    assert '2048 steps learned in this session (6144 in all): ' in out


@pytest.mark.parametrize('pairs', [1, 2])
def test_compose_runs_each_simulator_and_its_actor_as_one_process(tmp_path, pairs):
    """By default one process per pair and one for the critic and the learner."""
    from pg_node.common.config_files import load_config
    from pg_node.tools.train import learner_process, node_commands, sim_seeds
    cfg = load_config(None, [f'num_actors={pairs}', 'seed=5', 'num_envs=16'])
    params = tmp_path / 'params.yaml'
    apart, together = node_commands(params, cfg), node_commands(params, cfg, compose=True)
    tags = [''] if pairs == 1 else [f'_{i}' for i in range(pairs)]
    assert set(together) == {'critic_and_learner', *(f'sim_and_actor{t}' for t in tags)}
    assert together['critic_and_learner'][:3] == [sys.executable, '-m',
                                                  'pg_node.ros.critic_and_learner']
    # the pair-less ROS arguments of both (the one parameter file, no namespace)
    assert together['critic_and_learner'][3:] == apart['critic_node'][3:] \
        == apart['learner_node'][3:]
    assert (learner_process(), learner_process(compose=True)) == ('learner_node',
                                                                  'critic_and_learner')
    for t in tags:
        sim, both = apart[f'sim_node{t}'], together[f'sim_and_actor{t}']
        assert both[:3] == [sys.executable, '-m', 'pg_node.ros.sim_and_actor']
        assert both[3:] == sim[3:] == apart[f'actor_node{t}'][3:]   # the namespace, if any
    assert list(sim_seeds(cfg, compose=True).values()) == list(sim_seeds(cfg).values())
    assert set(sim_seeds(cfg, compose=True)) == {f'sim_and_actor{t}' for t in tags}


def test_resume_names_its_bag_in_the_summary_and_replay_info(runs, capsys):
    """A resumed run's learner writes bag_1/: the summary and replay --info name it."""
    run_dir, out1, sum1, out, summary = runs
    assert sum1['bags'] == sum1['session_bags'] == ['bag']
    assert summary['bags'] == ['bag', 'bag_1'] and summary['session_bags'] == ['bag_1']
    lines = out.splitlines()
    assert f'{"bag:":<11} {run_dir / "bag"}' in lines, out
    assert f'{"bag:":<11} {run_dir / "bag_1"} (this session)' in lines, out
    assert f'{"bag:":<11} {run_dir / "bag"}' in out1.splitlines()
    from pg_node.ros.replay_node import main
    assert main(['--info', str(run_dir)]) == 0
    named = [ln.split()[1] for ln in capsys.readouterr().out.splitlines()
             if ln.startswith('bag: ')]
    assert named == [str(run_dir / 'bag'), str(run_dir / 'bag_1')]


def test_a_finished_run_is_left_as_it_is(runs):
    """Training a run that learned its total_steps: one line, exit 0, not a file touched."""
    run_dir, _, _, _, summary = runs
    files = {p: p.stat().st_mtime_ns for p in run_dir.rglob('*') if p.is_file()}
    out, again = train(run_dir, 6144)
    assert out.strip() == (f"{run_dir}: already learned {summary['total_steps']} steps "
                           '(total_steps 6144); raise --total-steps to go on'), out
    assert again == summary
    assert {p: p.stat().st_mtime_ns for p in run_dir.rglob('*') if p.is_file()} == files
