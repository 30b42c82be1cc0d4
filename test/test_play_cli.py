"""
``python -m pg_node play`` as a user meets it: repeatable episodes, quick Ctrl-C, no litter.

A policy barely trained in this process (the episodes' starts do not depend on its skill) is
exported as ONNX, so that ``policy_node`` starts without torch. The same ``--seed`` must play
the same episodes however many simulated steps pass before the policy commands: a run at
four times real time lets four times as many pass as one at real time, and before ``play``
reset the world once the policy commanded, the two played different episodes.
"""
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

from domains import ros_domain
from pg_node.common.config_files import load_config
from pg_node.tools import processes
import pytest

pytestmark = pytest.mark.e2e
REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID = ros_domain(base=190, spread=20)
LINE = re.compile(r'episode +(\d+) \(arm (\d)\): target \(([-\d., ]+)\) cm, return +-?[\d.]+, '
                  r'final fingertip distance [\d.]+ cm')


@pytest.fixture(scope='module')
def onnx(tmp_path_factory):
    """Return an exported policy (a few updates of training)."""
    from pg_node.rl.onnx_export import export_policy
    from pg_node.rl.train_inprocess import train_inprocess
    from pg_node.rl.trained_policy import find_checkpoint, TorchPolicy
    run = tmp_path_factory.mktemp('play_policy')
    summary = train_inprocess(load_config(None, ['num_envs=8', 'n_steps=8']), 512,
                              eval_episodes=1)
    summary['learner'].save(run / 'checkpoints')
    policy = TorchPolicy(*find_checkpoint(run))
    export_policy(policy.policy, policy.card, run / 'policy.onnx')
    return run / 'policy.onnx'


def environment(tmp: Path) -> dict:
    """Return play's environment, its temporary folder ``tmp`` (which must stay empty)."""
    tmp.mkdir()
    return dict(processes.child_env(DOMAIN_ID), TMPDIR=str(tmp),
                AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))


def play(onnx, tmp: Path, *args):
    """Run play; return its output and the episodes' lines as (number, arm, target)."""
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'play', str(onnx), *args],
                          env=environment(tmp), cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr[-3000:]
    episodes = [LINE.fullmatch(line) for line in done.stdout.splitlines()
                if line.startswith('episode')]
    assert episodes and all(episodes), done.stdout
    assert [p for p in tmp.iterdir() if p.is_dir()] == [], 'play left a folder in its TMPDIR'
    return done.stdout, [(int(m[1]), int(m[2]), m[3]) for m in episodes]


def test_the_same_seed_plays_the_same_episodes_whatever_passes_before_the_policy_commands(
        onnx, tmp_path):
    gif = tmp_path / 'play.gif'
    out1, first = play(onnx, tmp_path / 'tmp1', '--seed', '5', '--arms', '2', '--episodes', '4',
                       '--gif', str(gif))
    out2, again = play(onnx, tmp_path / 'tmp2', '--seed', '5', '--arms', '2', '--episodes', '4',
                       '--real-time-factor', '4')
    # numbered from 1 by the simulator's ids: arm 0 has the odd numbers, arm 1 the even ones
    assert [(n, arm) for n, arm, _ in first[:4]] == [(1, 0), (2, 1), (3, 0), (4, 1)], out1
    assert first[:4] == again[:4], (out1, out2)
    _, other = play(onnx, tmp_path / 'tmp3', '--seed', '6', '--arms', '2', '--episodes', '2')
    assert other[0][2] != first[0][2]           # another seed, other targets
    # the GIF is announced before it is drawn, distances in cm everywhere
    assert re.search(r'^rendering 1 episode\(s\) of arm 0 \(51 frames\) to .*play\.gif '
                     r'\(Ctrl-C skips it\) \.\.\.$', out1, re.M), out1
    assert f'wrote {gif} (51 frames)' in out1 and gif.exists()
    assert re.search(r'^4 episodes: return -?[\d.]+ \+/- [\d.]+, final distance [\d.]+ cm '
                     r'\(median [\d.]+ cm\)$', out1, re.M), out1


def test_ctrl_c_stops_play_and_a_second_one_skips_the_gif(onnx, tmp_path):
    gif, log, tmp = tmp_path / 'play.gif', tmp_path / 'out.txt', tmp_path / 'tmp'
    with open(log, 'w') as out:
        proc = subprocess.Popen([sys.executable, '-m', 'pg_node', 'play', str(onnx),
                                 '--episodes', '1000', '--arms', '2', '--gif', str(gif)],
                                env=environment(tmp),
                                cwd=REPO, stdout=out, stderr=subprocess.STDOUT,
                                start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while 'episode    1 (arm 0)' not in log.read_text():
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 30
        while 'stopping the nodes' not in log.read_text():
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        processes.stop(proc)
    text = log.read_text()
    assert proc.returncode == 0 and 'Traceback' not in text, text
    assert [ln for ln in text.splitlines() if 'stopping the nodes' in ln] == [
        f'play: interrupted: stopping the nodes; Ctrl-C again skips drawing {gif}'], text
    assert f'play: {gif} not drawn (Ctrl-C again)' in text and not gif.exists(), text
    assert [p for p in tmp.iterdir() if p.is_dir()] == []


def test_the_stand_in_steps_at_the_policys_control_step(tmp_path):
    """
    ``sim_node`` as the robot runs the run's ``frame_skip`` (issue 46).

    It ran the default 2 whatever the run: a Panda trained at ``frame_skip:=20`` (0.04 s)
    was played at 0.004 s a step, 50-step episodes of 0.2 s, and ended 15 cm away where
    ``eval`` said 2.9 cm. Here reacher2 at 4 x 0.01 s.
    """
    import yaml
    from pg_node.rl.train_inprocess import train_inprocess
    run = tmp_path / 'run'
    summary = train_inprocess(load_config(None, ['num_envs=8', 'n_steps=8', 'frame_skip=4']),
                              512, eval_episodes=1)
    summary['learner'].save(run / 'checkpoints')
    (run / 'params.yaml').write_text(yaml.safe_dump(
        {'/**/sim_node': {'ros__parameters': {'frame_skip': 4}}}))
    play(run, tmp_path / 'tmp', '--episodes', '1', '--log-dir', str(tmp_path / 'logs'))
    started = [ln for ln in (tmp_path / 'logs' / 'sim_node.log').read_text().splitlines()
               if 'real_time: 1 x' in ln]
    assert len(started) == 1 and ', dt 0.04 s,' in started[0], started


def test_robot_pybullet_on_an_arm_without_urdf_says_so_before_starting(onnx, tmp_path):
    """reacher2 has no URDF: the reason is play's one line; no node started, no logs kept."""
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'play', str(onnx), '--robot',
                           'pybullet'], env=environment(tmp_path / 'tmp'), cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.strip() == ('play: --robot pybullet: reacher2 was not made by arm '
                                   'import; give the URDF'), done.stderr
    assert 'starting' not in done.stdout, done.stdout
    assert [p for p in (tmp_path / 'tmp').iterdir() if p.is_dir()] == [], 'a log folder'
