"""
Bad input to the command-line tools and nodes: one line on stderr, a non-zero exit code.

Each case runs the real command as a process and checks its exit code, that stderr names
the problem, and that no traceback reached the user.
"""
import json
import os
from pathlib import Path
import subprocess
import sys

from domains import ros_domain
from pg_node.common.config_files import load_config
from pg_node.common.paths import default_config
from pg_node.rl.checkpoint import save_checkpoint
from pg_node.rl.learner import Learner
import pytest

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / 'bags' / 'sample'
DOMAIN_ID = ros_domain(base=120, spread=90)


def run(*args, timeout=120, module=None):
    """Run ``python -m pg_node <args>`` (or ``python -m <module> <args>``) in the test domain."""
    env = dict(os.environ, PYTHONPATH=str(REPO), ROS_DOMAIN_ID=str(DOMAIN_ID),
               AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))
    env.pop('MUJOCO_GL', None)
    cmd = [sys.executable, '-m', module or 'pg_node', *map(str, args)]
    return subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)


def refused(done, code, *words):
    """Assert ``done`` exited with ``code``, one clear line naming ``words``, no traceback."""
    assert done.returncode == code, (done.returncode, done.stdout, done.stderr)
    assert 'Traceback' not in done.stderr and 'Traceback' not in done.stdout, done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert lines, done.stdout
    for word in words:
        assert word in done.stderr, (word, done.stderr)


@pytest.fixture(scope='module')
def run_dir(tmp_path_factory):
    """Return a run directory with one policy (reacher2) and one critic checkpoint."""
    root = tmp_path_factory.mktemp('run')
    sections = load_config(default_config(), [f'run_dir={root}'])
    cfg = {k: v for section in sections.values() for k, v in section.items()}
    Learner(10, 2, cfg).save(root / 'checkpoints')
    save_checkpoint(root / 'critic', 1, {'value_fn': {}, 'vf_opt': {}})
    return root


# -- eval -------------------------------------------------------------------------------------
def test_eval_says_when_it_runs_the_episodes_train_evaluated(run_dir):
    """The run's own seed repeats train's closing evaluation: eval says so; another not."""
    same = run('eval', run_dir, '--episodes', 2)
    other = run('eval', run_dir, '--episodes', 2, '--seed', 1)
    assert same.returncode == other.returncode == 0, same.stderr + other.stderr
    assert '(seed 0: the episodes train evaluated at its end; --seed N for others)' \
        in same.stdout
    assert 'train evaluated' not in other.stdout


def test_eval_accepts_a_run_dir(run_dir):
    done = run('eval', run_dir, '--episodes', 2)
    assert done.returncode == 0, done.stderr
    assert 'policy version 0: return' in done.stdout


def test_eval_answers_a_missing_path_before_importing_torch(tmp_path):
    """``eval runs/nope`` is refused in one line with torch unimportable (it took seconds)."""
    from test_architecture import BLOCKER
    # BLOCKER's own imports after the blocker, then the command instead of the layers
    code = BLOCKER.split('import pg_node')[0] + (
        'import runpy\nsys.argv = ["pg_node", "eval", sys.argv[2]]\n'
        'runpy.run_module("pg_node", run_name="__main__")\n')
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, '-c', code, 'torch', str(tmp_path / 'nope')],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=60)
    refused(done, 1, f'eval: no such file or directory: {tmp_path / "nope"}')
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_eval_refuses_the_critic_dir(run_dir):
    refused(run('eval', run_dir / 'critic', '--episodes', 2), 1, 'critic', 'not policy')


def test_eval_refuses_a_model_of_other_sizes(run_dir):
    refused(run('eval', run_dir / 'checkpoints', '--model', 'arm5_3d', '--episodes', 2), 2,
            'arm5_3d', 'trained on reacher2')


def test_eval_refuses_zero_episodes(run_dir):
    refused(run('eval', run_dir, '--episodes', 0), 2, '--episodes')


def test_eval_on_a_perturbed_arm_reports_distance_and_reached_share(run_dir):
    done = run('eval', run_dir, '--episodes', 2, '--perturb', 'mass_scale=1.3',
               'latency_steps=2', '--json')
    assert done.returncode == 0, done.stderr
    res = json.loads(done.stdout)
    assert res['perturbation'] == {'mass': 'scale 1.3 startup', 'latency': 'abs 2 startup'}
    assert res['eval_final_distance'] > 0 and 0 <= res['eval_reached'] <= 1
    done = run('eval', run_dir, '--episodes', 2, '--perturb', 'gear_scale=0.8')
    assert 'on an arm with gear_scale=0.8: return' in done.stdout and 'within 2 cm' in done.stdout


@pytest.mark.parametrize('perturb, words', [
    ('torque_scale=2', "--perturb 'torque_scale': unknown key; known: mass_scale"),
    ('mass_scale=-1', 'a mass scale must stay > 0'),
    ('latency_steps=1.5', 'latency is whole control steps'),
    ('obs_noise=-0.1', 'a noise std must be >= 0'),
    ('damping_add=-2', 'the damping of this model would reach -1'),
    ('mass_scale', 'write KEY=VALUE'),
])
def test_eval_refuses_a_bad_perturbation_in_one_line(run_dir, perturb, words):
    refused(run('eval', run_dir, '--episodes', 2, '--perturb', perturb), 2, words)


@pytest.mark.parametrize('args, code, words', [
    ([], 2, 'give run directories to compare, or --train PRESETS'),
    (['--train', 'nosuch'], 2, "config 'nosuch' is neither an existing file nor a preset"),
    (['--train', 'ppo', '--seeds', 'a'], 2, "'a' is not a comma-separated list"),
    (['/nonexistent'], 1, 'no such file or directory'),
])
def test_robustness_refuses_bad_input_in_one_line(args, code, words):
    refused(run('robustness', *args), code, words)


# -- nodes and train ------------------------------------------------------------------------
@pytest.mark.parametrize('text, words', [
    ('a: [b\n', ['bad.yaml', 'Error at line 1']),               # not YAML
    ('gamma: 0.9\n', ['bad.yaml', 'before ros__parameters']),   # YAML, not a parameter file
])
def test_node_with_a_malformed_params_file(tmp_path, text, words):
    (tmp_path / 'bad.yaml').write_text(text)
    done = run('--ros-args', '--params-file', tmp_path / 'bad.yaml',
               module='pg_node.ros.sim_node', timeout=60)
    refused(done, 2, 'configuration error: ', "Couldn't parse params file", *words)
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


@pytest.mark.parametrize('text, words', [
    ('<mujoco><worldbody><bogus/></worldbody></mujoco>', ['unrecognized element', 'bogus']),
    ('not xml at all', ['XML parse error']),
])
def test_train_refuses_a_model_that_is_not_mjcf_before_starting(tmp_path, text, words):
    (tmp_path / 'bad.xml').write_text(text)
    done = run('train', f'model={tmp_path / "bad.xml"}', '--run-dir', tmp_path / 'run',
               timeout=60)
    refused(done, 2, "parameter 'model'", 'is not a valid MuJoCo model', *words)
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (tmp_path / 'run').exists()  # nothing was started


@pytest.mark.parametrize('override, words', [
    # a ROS 2 parameter cannot hold an empty list: the nodes crashed and were restarted
    ('hidden_sizes=[]', ["parameter 'hidden_sizes'", 'non-empty list of positive integers',
                         'cannot hold an empty list']),
    ('hidden_sizes=[64, 0]', ["parameter 'hidden_sizes'", '0 is not a positive integer']),
    ('foo=1', ["unknown parameter 'foo'", 'known: activation, actor_id']),
    ('learning_rte=3e-4', ["unknown parameter 'learning_rte'",
                           "did you mean 'learning_rate'"]),
    ('critic_node.vf_epoch=3', ["'vf_epoch' in section 'critic_node'",
                                "did you mean 'vf_epochs'"]),
    ('model:=nosuch.xml', ["parameter 'model'", "'nosuch.xml'", 'shipped: ']),
    # a setting the default update (a2c) does not have: it would be taken and ignored
    ('clip_range=0.3', ["parameter 'learner_node.clip_range'", "algo 'a2c' has no clip_range",
                        'its settings: learning_rate, optimizer']),
    ('gamma', ['not of the form key=value (or key:=value)']),
])
def test_train_refuses_a_bad_override_before_starting(tmp_path, override, words):
    done = run('train', override, '--run-dir', tmp_path / 'run', timeout=60)
    refused(done, 2, 'configuration error: ', *words)
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (tmp_path / 'run').exists()  # nothing was started


def test_train_says_to_quote_an_override_with_spaces(tmp_path):
    """The shell split ``randomize_latency=uniform 0 2``: the bare words were ignored."""
    done = run('train', 'randomize_latency=uniform', '0', '2', '--run-dir', tmp_path / 'run',
               timeout=60)
    refused(done, 2, "configuration error: override '0' looks like the rest of an override "
            "with spaces: quote it: 'randomize_latency=uniform 0 2'")
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (tmp_path / 'run').exists()  # nothing was started


def _not_an_arm(tmp_path, kind):
    """Write a model that MuJoCo compiles but that is no pg_node arm (or a URDF)."""
    import re
    text = (REPO / 'pg_node' / 'sim' / 'models' / 'reacher2.xml').read_text()
    if kind == 'no fingertip':
        text = text.replace('name="fingertip"', 'name="tip"')
    elif kind == 'no actuators':
        text = re.sub(r'<actuator>.*?</actuator>', '', text, flags=re.S)
    else:
        text = ('<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/>'
                '<inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>'
                '<joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
                '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>')
    path = tmp_path / 'arm.xml'
    path.write_text(text)
    return path


@pytest.mark.parametrize('kind, words', [
    ('no fingertip', ['is not a pg_node arm', "no site named 'fingertip'", 'docs/mjcf.md']),
    ('no actuators', ['is not a pg_node arm', 'no actuators', 'docs/mjcf.md']),
    ('urdf', ['is a URDF, not MJCF', 'python -m pg_node arm import']),
])
def test_a_model_that_is_no_arm_is_refused_before_any_node_starts(tmp_path, kind, words):
    """It compiled, then every node crashed with a traceback, was restarted and crashed."""
    model = _not_an_arm(tmp_path, kind)
    done = run('train', f'model={model}', '--run-dir', tmp_path / 'run', timeout=60)
    refused(done, 2, "configuration error: parameter 'model'", str(model), *words)
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (tmp_path / 'run').exists()  # nothing was started
    # a node started on its own (ros2 run) says the same in one line
    node = run('--ros-args', '-p', f'model:={model}', module='pg_node.ros.actor_node',
               timeout=60)
    refused(node, 2, 'configuration error: ', *words[:2])
    assert len(node.stderr.strip().splitlines()) == 1, node.stderr


def test_check_model_compiles_the_shipped_models():
    from pg_node.common.paths import check_model, models_dir
    for model in models_dir().glob('*.xml'):
        assert check_model(model.stem) == model


# -- runs and hosts (pg_node.common.run, pg_node.tools.hosts) --------------------------------
@pytest.mark.parametrize('args, words', [
    (['train', '--run-id', '1x'], ['--run-id', 'starting with a letter']),
    (['train', 'run_id=a-b'], ["parameter 'run_id'", 'starting with a letter']),
    (['train', '--part'], ['--part', 'expected one argument']),
    (['train', '--part', 'everything'], ['--part', 'invalid choice']),
    (['train', '--part', 'workers', 'num_actors=2'], ['--part workers needs --run-id']),
    (['train', '--part', 'workers', '--run-id', 'x', 'num_actors=2', '--actors', '1,2'],
     ['--actors 1,2', 'actor 2 is out of range', 'actors 0..1']),
    (['train', '--part', 'workers', '--run-id', 'x', '--actors', 'one'], ['--actors one']),
    (['train', '--actors', '0'], ['--actors is for --part workers']),
    (['monitor', '--run', 'a b'], ['--run', 'starting with a letter']),
    (['topics', '--run', '-x'], ['--run']),
])
def test_bad_run_and_host_options_are_one_line(tmp_path, args, words):
    done = run(*args, '--run-dir', tmp_path / 'run', timeout=60) if args[0] == 'train' \
        else run(*args, timeout=60)
    refused(done, 2, *words)
    last = done.stderr.strip().splitlines()[-1]           # after argparse's usage, if any
    assert 'error' in last and all(w in last for w in words), done.stderr
    assert not (tmp_path / 'run' / 'logs').exists()       # nothing was started


@pytest.mark.e2e
def test_a_worker_host_refuses_an_unknown_run_and_a_config_that_differs(tmp_path):
    """No learner announces the run: one line; a learner of other values: one line naming them."""
    done = run('train', '--part', 'workers', '--run-id', 'nobody_here', '--wait-learner', '2',
               'num_envs=2', '--run-dir', tmp_path / 'w0', timeout=60)
    refused(done, 2, "no learner host announces run 'nobody_here'", 'after 2 s')
    assert not (tmp_path / 'w0').exists()                      # a failed join leaves no folder
    env = dict(os.environ, PYTHONPATH=str(REPO), ROS_DOMAIN_ID=str(DOMAIN_ID),
               AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))
    learner = subprocess.Popen(
        [sys.executable, '-m', 'pg_node', 'train', '--part', 'learner', '--run-id', 'mm',
         '--run-dir', str(tmp_path / 'l'), '--no-progress', 'num_envs=8', 'num_actors=2',
         '--total-steps', '100000'], env=env, cwd=REPO, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        done = run('train', '--part', 'workers', '--run-id', 'mm', '--wait-learner', '60',
                   'num_envs=16', 'num_actors=2', 'seed=3', '--run-dir', tmp_path / 'w1',
                   timeout=120)
        refused(done, 2, "configuration differs from the learner host's",
                '/**.num_envs: 16 here, 8 on the learner host',
                '/**.seed: 3 here, 0 on the learner host')
        assert not (tmp_path / 'w1').exists()                  # no node, no run folder
    finally:
        import signal
        os.killpg(learner.pid, signal.SIGINT)
        out = learner.communicate(timeout=60)[0]
    assert learner.returncode == 130, out           # interrupted (Ctrl-C)


@pytest.mark.parametrize('args', [['render', SAMPLE, '--list'], ['replay', SAMPLE, '--info']],
                         ids=['render --list', 'replay --info'])
def test_a_reader_that_leaves_early_ends_the_command_quietly(args):
    """``... | head``: no BrokenPipeError traceback; the status SIGPIPE gives coreutils."""
    reader, writer = os.pipe()
    env = dict(os.environ, PYTHONPATH=str(REPO),
               AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))
    proc = subprocess.Popen([sys.executable, '-m', 'pg_node', *map(str, args)], env=env,
                            cwd=REPO, stdout=writer, stderr=subprocess.PIPE, text=True)
    os.close(writer)
    os.close(reader)            # the reader is gone before the first line: every write fails
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 141, err
    assert err == '', err


@pytest.mark.parametrize('args', [['--help'], [], ['train', '--help'], ['play', '--help'],
                                  ['replay', '--help']],
                         ids=['--help', 'no command', 'train --help', 'play --help',
                              'replay --help'])
def test_help_into_a_pipe_closed_early_ends_without_a_traceback(args):
    """``python -m pg_node --help | head``: the command list met a closed pipe in a traceback."""
    reader, writer = os.pipe()
    env = dict(os.environ, PYTHONPATH=str(REPO),
               AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))
    proc = subprocess.Popen([sys.executable, '-m', 'pg_node', *args], env=env, cwd=REPO,
                            stdout=writer, stderr=subprocess.PIPE, text=True)
    os.close(writer)
    os.close(reader)
    err = proc.communicate(timeout=120)[1]
    # argparse's own help swallows the error (0); the command list ends as SIGPIPE would
    assert proc.returncode in (0, 141), err
    assert err == '', err


# -- replay ------------------------------------------------------------------------------------
@pytest.mark.parametrize('param, words', [
    ('rate:=-3', ['rate must be >= 0', 'not -3']),             # an integer, taken as a double
    ('rate:=fast', ["parameter 'rate': 'fast' is not allowed; expected a number"]),
    ('loop:=3', ["parameter 'loop': 3 is not allowed; expected true or false"]),
    ('rat:=0.0', ["unknown parameter 'replay_node.rat' (did you mean 'rate'?)", 'allowed: bag']),
])
def test_replay_node_refuses_bad_parameters_in_one_line(param, words):
    """Before: InvalidParameterTypeException tracebacks, and an unknown parameter ignored."""
    done = run('--ros-args', '-p', f'bag:={SAMPLE}', '-p', param, module='pg_node.ros.replay_node',
               timeout=60)
    refused(done, 2, 'replay_node: ', *words)
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_replay_node_takes_an_integer_for_a_double():
    """``rate:=0`` (as fast as possible) and ``wait_timeout:=1``, as sim_node takes them."""
    done = run('--ros-args', '-p', f'bag:={SAMPLE}', '-p', 'rate:=0', '-p', 'wait_timeout:=1',
               '-p', 'wait_for_subscribers:=0', '-p', 'topics:=[/joint_states]',
               module='pg_node.ros.replay_node', timeout=60)
    assert done.returncode == 0, done.stderr
    assert 'as fast as possible' in done.stderr + done.stdout


def test_replay_rate_option_says_what_it_takes():
    done = run('replay', SAMPLE, '--rate', 'fast')
    refused(done, 2, 'argument --rate/-r: expected a number >= 0 (0: as fast as possible), '
                     "got 'fast'")


@pytest.mark.parametrize('name, instead', [('bench', 'python -m bench'),
                                           ('soak', 'python -m bench.soak')])
def test_a_command_that_left_the_package_says_where_it_went_in_one_line(name, instead):
    """The benchmarks and the soak live in the repository's ``bench`` package, not installed."""
    done = run(name, '--quick')
    refused(done, 2, f'`{instead}`', 'docs/benchmarks.md')
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def outside_venv(argv, blocked=()) -> subprocess.CompletedProcess:
    """
    Run ``python -m pg_node ARGV`` as a Python that is not the venv would run it.

    Without ``blocked``: the venv's site-packages off the path (numpy and the rest gone), the
    checkout on it, as ``python3 -m pg_node`` from the checkout's folder; with it, only the
    ``blocked`` modules are unimportable.
    """
    root = str(Path(__file__).resolve().parent.parent)
    strip = '' if blocked else 'sys.path[:] = [p for p in sys.path if "-packages" not in p]; '
    code = (f'import sys; {strip}sys.path.insert(0, {root!r}); '
            f'sys.modules.update(dict.fromkeys({list(blocked)!r})); '
            f'from pg_node.tools.cli import main; sys.exit(main({argv!r}))')
    return subprocess.run([sys.executable, '-I', '-c', code], capture_output=True, text=True,
                          timeout=120)


@pytest.mark.parametrize('argv, blocked, missing', [
    (['train', '--help'], (), 'numpy'),
    (['eval', 'runs/nope'], (), 'numpy'),
    (['replay', '--help'], ('mcap',), 'mcap'),
])
def test_outside_the_venv_a_command_says_to_activate_it_in_one_line(argv, blocked, missing):
    out = outside_venv(argv, blocked)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in out.stderr, out.stderr
    assert f'no {missing!r}' in lines[0] and 'source .venv/bin/activate' in lines[0]


def exit_codes_of_the_doc() -> dict:
    """Return troubleshooting.md's table of every command's exit codes: code -> when."""
    text = (REPO / 'docs' / 'troubleshooting.md').read_text()
    table = text.split('| exit code | when |')[1].split('\n\n')[0]
    return {int(row.split('|')[1]): row.split('|')[2] for row in table.splitlines()[2:]}


#: each command that takes a path, with what else it needs to get as far as reading it
PATH_COMMANDS = [('eval', ()), ('view', ()), ('play', ()), ('plot', ()), ('render', ()),
                 ('export', ('-o', 'x.onnx')), ('replay', ()), ('reindex', ()),
                 ('robustness', ())]


@pytest.mark.parametrize('command, extra', PATH_COMMANDS, ids=[c for c, _ in PATH_COMMANDS])
def test_a_path_that_is_not_there_exits_as_the_doc_says(tmp_path, command, extra):
    doc = exit_codes_of_the_doc()
    assert sorted(doc) == [0, 1, 2, 3, 130]
    assert f'`{command}`' in doc[1], doc[1]
    done = run(command, tmp_path / 'nope', *extra)
    refused(done, 1, 'nope')
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_view_on_a_busy_port_says_how_to_take_a_free_one():
    """A port another program listens on: one line that names ``--port 0``."""
    import socket
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = run('view', 'bags/sample', '--port', port, '--stop-after', 5)
    refused(done, 2, f'cannot serve on 127.0.0.1:{port}', '--port 0')
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
