"""
critic_and_learner: the critic and the learner in one process (``train``'s default).

The process is checked as a user meets it: rollouts in, new weights out, and SIGINT or
SIGTERM stopping both nodes with their checkpoints and the bag written. And the order that
keeps V's regression step off the hand-over's path: in one process the critic's step comes
after the learner has the batch, not before.
"""
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

from domains import ros_domain
import mujoco
from pg_node.common.paths import resolve_model
from pg_node.ros import messages
from pg_node.ros import table_msg
from pg_node.ros.qos import LATCHED, RELIABLE
from pg_node.tools import processes
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from sample_messages import make_rollout, N, T
from std_msgs.msg import Float64MultiArray
import yaml

DOMAIN_ID = ros_domain(base=130, spread=40)


@pytest.mark.e2e
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_critic_and_learner_learn_in_one_process_and_both_stop_cleanly(tmp_path, sig):
    run_dir = tmp_path / 'run'
    # with SIGTERM, the run's params.yaml (as train writes it) sets the simulator's
    # frame_skip: the bag's clock follows it (the learner took the default 2 before)
    frame_skip = 3 if sig == signal.SIGTERM else 2
    if sig == signal.SIGTERM:
        run_dir.mkdir()
        (run_dir / 'params.yaml').write_text(yaml.safe_dump(
            {'/**/sim_node': {'ros__parameters': {'frame_skip': frame_skip}}}))
    args = [sys.executable, '-m', 'pg_node.ros.critic_and_learner', '--ros-args']
    for p in (f'run_dir:={run_dir}', f'num_envs:={N}', f'n_steps:={T}'):
        args += ['-p', p]
    proc = processes.start_logged(args, tmp_path / 'critic_and_learner.log',
                                  processes.child_env(DOMAIN_ID))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    versions = []
    try:
        node = rclpy.create_node('critic_and_learner_test', context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        pub = node.create_publisher(Float64MultiArray, '/pg_node/rollout', RELIABLE)
        node.create_subscription(
            Float64MultiArray, '/pg_node/policy_weights',
            lambda m: versions.append(
                messages.unpack_weights(*table_msg.from_msg(m))[0]['version']), LATCHED)
        deadline = time.monotonic() + 60
        # the learner latches version 0 at start; each rollout of the newest version is
        # one batch, one update and one new version
        for k in range(2):
            while k not in versions or pub.get_subscription_count() < 1:
                assert time.monotonic() < deadline and proc.poll() is None, versions
                ex.spin_once(timeout_sec=0.05)
            pub.publish(make_rollout(k, version=k, first_seq=k * T))
        while 2 not in versions:
            assert time.monotonic() < deadline and proc.poll() is None, versions
            ex.spin_once(timeout_sec=0.05)
        # signalled at once: the learner's bookkeeping and V's step follow the weights, so
        # the signal may land inside a callback (or in the critic's timer); it must still
        # be a clean stop (runtime.stop_on_signals)
        ex.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
        proc.send_signal(sig)
        try:
            proc.wait(timeout=30)
        finally:
            code, log = processes.stop_logged(proc)
    assert code == 0, log[-3000:]
    assert 'Traceback' not in log and 'Exception in' not in log, log[-3000:]
    assert '[critic_node]: critic: phi = gae' in log and '[learner_node]: learner: a2c' in log
    # both saved on the way out: V after its two steps, the policy at version 2, the bag
    assert [p.name for p in sorted((run_dir / 'critic').glob('*.pt'))][-1] == \
        'ckpt_00000002.pt'
    assert [p.name for p in sorted((run_dir / 'checkpoints').glob('*.pt'))][-1] == \
        'ckpt_00000002.pt'
    meta = yaml.safe_load((run_dir / 'bag' / 'metadata.yaml').read_text())
    timestep = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2'))).opt.timestep
    assert float(meta['rosbag2_bagfile_information']['custom_data']['pg_node.dt']) == \
        pytest.approx(timestep * frame_skip)


ORDER_SCRIPT = textwrap.dedent("""
    import json, sys, time
    import rclpy
    from pg_node.rl.critic import Critic
    from pg_node.ros.critic_node import CriticNode
    from pg_node.ros.qos import RELIABLE
    from pg_node.ros.runtime import make_executor
    from std_msgs.msg import Float64MultiArray
    from sample_messages import make_rollout

    order = []
    fit = Critic.fit
    def logged_fit(self, *args):
        order.append('fit')
        return fit(self, *args)
    Critic.fit = logged_fit
    rclpy.init(args=['x', '--ros-args', '-p', f'run_dir:={sys.argv[1]}', '-p', 'num_envs:=2',
                     '-p', 'n_steps:=4'])
    critic = CriticNode()
    learner = rclpy.create_node('learner_stand_in')      # a learner of the same process
    learner.create_subscription(Float64MultiArray, '/pg_node/batch',
                                lambda m: order.append('batch'), RELIABLE)
    pub = learner.create_publisher(Float64MultiArray, '/pg_node/rollout', RELIABLE)
    executor = make_executor()
    executor.add_node(critic)
    executor.add_node(learner)
    for k in range(3):
        pub.publish(make_rollout(k, first_seq=4 * k))
        deadline = time.monotonic() + 20
        while len(order) < 2 * (k + 1) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    print(json.dumps(order))
""")


def test_critic_steps_v_after_a_learner_in_its_process_has_the_batch(tmp_path):
    """The learner (and then the actors) wait on the batch only, never on V's step."""
    env = processes.child_env(DOMAIN_ID)
    env['PYTHONPATH'] += os.pathsep + str(Path(__file__).parent)   # sample_messages
    out = subprocess.run([sys.executable, '-c', ORDER_SCRIPT, str(tmp_path)], env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    assert json.loads(out.stdout.splitlines()[-1]) == ['batch', 'fit'] * 3


def test_critic_and_learner_refuses_a_bad_learner_parameter_in_one_line(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'pg_node.ros.critic_and_learner', '--ros-args',
                          '-p', f'run_dir:={tmp_path}', '-p', 'n_steps:=0'],
                         env=processes.child_env(DOMAIN_ID), capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2, out.stderr[-3000:]
    errors = [ln for ln in out.stderr.splitlines() if not ln.startswith('[INFO]')]
    assert errors == ["configuration error: parameter 'learner_node.n_steps': 0 is not "
                      'allowed; expected an int with 1 <= value'], out.stderr
