"""
Ctrl-C is quick: the first stops the nodes and says how to skip what follows, the second skips it.

``train`` evaluates the policy after the nodes stop (100 episodes, 14 s); ``play --gif``
draws the animation. Before, a second Ctrl-C changed nothing: it was ignored while the nodes
stopped, and the evaluation ran on. ``play``'s case is in ``test_play_cli.py``.
"""
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from domains import ros_domain
from pg_node.tools import processes
import pytest

REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID = ros_domain(base=180, spread=20)


def test_interrupts_raise_only_where_asked_and_count_every_signal():
    interrupts = processes.Interrupts()
    with interrupts.handled():
        os.kill(os.getpid(), signal.SIGINT)     # counted only: nodes are being stopped
        time.sleep(0.05)
        assert interrupts.count == 1
        with pytest.raises(KeyboardInterrupt) as caught:
            with interrupts.raising():
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(1.0)
        assert str(caught.value) == 'signal SIGTERM' and interrupts.count == 2
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
        assert interrupts.count == 3
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def wait_for(path: Path, text: str, proc, timeout: float) -> str:
    """Return the output so far once it holds ``text``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = path.read_text() if path.exists() else ''     # a node's log comes at its start
        if text in out:
            return out
        assert proc.poll() is None, out
        time.sleep(0.2)
    raise AssertionError(f'no {text!r} within {timeout} s:\n{path.read_text()}')


def start_train(run_dir: Path, log: Path, *args) -> subprocess.Popen:
    """Start ``python -m pg_node train --run-dir RUN ARGS`` in its own session, into ``log``."""
    env = dict(processes.child_env(DOMAIN_ID), AMENT_PREFIX_PATH=os.environ.get(
        'AMENT_PREFIX_PATH', sys.prefix))
    with open(log, 'w') as out:
        return subprocess.Popen([sys.executable, '-m', 'pg_node', 'train', '--run-dir',
                                 str(run_dir), *args], env=env, cwd=REPO, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)


@pytest.mark.e2e
def test_train_the_first_ctrl_c_says_how_to_skip_the_evaluation_the_second_skips_it(
        tmp_path):
    run_dir, log = tmp_path / 'run', tmp_path / 'out.txt'
    # an evaluation that would take minutes: only a skip ends the command in time
    proc = start_train(run_dir, log, '--total-steps', '10000000', '--eval-episodes', '5000',
                       'checkpoint_every=2')
    try:
        wait_for(log, '; learning', proc, 240)   # no terminal: lines
        deadline = time.monotonic() + 120       # until the first checkpoint: then it evaluates
        while not any((run_dir / 'checkpoints').glob('ckpt_*.pt')):
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        said = wait_for(log, 'stopping the nodes', proc, 30)
        line = [ln for ln in said.splitlines() if 'stopping the nodes' in ln]
        assert line == ['interrupted: stopping the nodes; Ctrl-C again skips the evaluation '
                        'that follows (5000 episodes)'], said
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    finally:
        processes.stop(proc)
    text = log.read_text()
    assert proc.returncode == 130, text             # interrupted: a shell's 128 + SIGINT
    assert 'Traceback' not in text, text
    assert f'evaluation skipped (Ctrl-C): python -m pg_node eval {run_dir} evaluates the run' \
        in text, text
    assert 'deterministic evaluation' not in text
    summary = json.loads((run_dir / 'summary.json').read_text())
    assert summary['interrupted'] and summary['evaluation'] == 'skipped', summary
    assert 'eval_return' not in summary
    assert (run_dir / 'learning_curve.png').exists()


@pytest.mark.e2e
def test_train_interrupted_before_it_learned_anything_says_so_and_evaluates_nothing(
        tmp_path):
    """Ctrl-C during the bring-up: exit 130, no evaluation of the untrained policy."""
    run_dir, log = tmp_path / 'run', tmp_path / 'out.txt'
    # a rollout of 640k steps: the first update is far off when the signal comes
    proc = start_train(run_dir, log, 'n_steps=10000')
    try:
        wait_for(log, 'starting nodes...', proc, 120)
        # the learner (policy version 0) and the actor are up: the rollout has begun
        wait_for(run_dir / 'logs' / 'critic_and_learner.log', 'learner: a2c, version 0', proc,
                 120)
        wait_for(run_dir / 'logs' / 'sim_and_actor.log', 'actor 0: 64 arms', proc, 120)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    finally:
        processes.stop(proc)
    text = log.read_text()
    assert proc.returncode == 130, text
    assert 'nothing learned yet (stopped before the first update): no evaluation' in text
    assert 'evaluating' not in text and 'bring-up not over: no update yet' in text, text
    summary = json.loads((run_dir / 'summary.json').read_text())
    assert summary['evaluation'] == 'nothing learned' and summary['total_steps'] == 0
