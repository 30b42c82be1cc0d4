"""
``python -m pg_node arm import``: a URDF as an arm model, and the shipped ``arm7`` made so.

The two-link fixture is ``reacher2`` written as a URDF; the imported arm must move its
fingertip exactly as ``reacher2`` does. Errors end in one line and a non-zero exit;
``package://`` meshes are found in the ament index, in ``--package-path`` folders and above
the URDF. The imported 7-joint arm works in the task, the Gymnasium environment, ``sim_node``
and ``render``, and a short training run improves its return.
"""
import os
from pathlib import Path
import re
import shlex
import struct
import subprocess
import sys

import gymnasium as gym
import mujoco
import numpy as np
from pg_node.common.params import load_config
from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmTask
from pg_node.sim.urdf_import import (import_urdf, ImportOptions, read_urdf, resolve_mesh,
                                     UrdfImportError)
from pg_node.tools import arm
import pytest

REPO = Path(__file__).resolve().parent.parent
FIXTURES = Path(__file__).resolve().parent / 'fixtures' / 'urdf'
TWO_LINK = FIXTURES / 'two_link.urdf'
ARM7 = REPO / 'pg_node' / 'sim' / 'models' / 'arm7.xml'


def write_stl(path: Path) -> Path:
    """Write a binary STL tetrahedron (5 cm) at ``path``."""
    v = [(0, 0, 0), (0.05, 0, 0), (0, 0.05, 0), (0, 0, 0.05)]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'wb') as f:
        f.write(b'\0' * 80 + struct.pack('<I', len(faces)))
        for face in faces:
            f.write(struct.pack('<3f', 0, 0, 0))
            for i in face:
                f.write(struct.pack('<3f', *v[i]))
            f.write(b'\0\0')
    return path


def with_mesh(path: Path, uri: str, kind: str = 'collision') -> Path:
    """Write the two-link fixture with link1's geometry replaced by the mesh ``uri``."""
    text = TWO_LINK.read_text()
    if kind == 'collision':
        cylinder = '<geometry><cylinder radius="0.01" length="0.1"/>'
        start = text.index('<collision>')
        end = text.index(cylinder, start) + len(cylinder)
        text = (text[:start] + f'<collision>\n      <geometry><mesh filename="{uri}"/>'
                + text[end:])
    else:
        text = text.replace('<collision>', f'<visual><geometry><mesh filename="{uri}"/>'
                                           '</geometry></visual>\n    <collision>')
    assert uri in text
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def run_import(capsys, *argv):
    """Run ``arm import`` in this process; return ``(exit code, stdout, stderr)``."""
    code = arm.main(['import', *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def fingertip_positions(model, joint_names, angles):
    """Return the fingertip site's world position at each row of ``angles``."""
    data = mujoco.MjData(model)
    adr = [model.joint(n).qposadr[0] for n in joint_names]
    site = model.site('fingertip').id
    out = []
    for q in angles:
        data.qpos[adr] = q
        mujoco.mj_kinematics(model, data)
        out.append(data.site_xpos[site].copy())
    return np.array(out)


@pytest.fixture(scope='module')
def two_link(tmp_path_factory):
    """Import the two-link fixture once; return the written model's path."""
    out = tmp_path_factory.mktemp('two_link') / 'two_link.xml'
    assert arm.main(['import', str(TWO_LINK), '--tip', 'fingertip', '-o', str(out)]) == 0
    return out


def test_two_link_urdf_moves_its_fingertip_as_reacher2(two_link):
    ours = mujoco.MjModel.from_xml_path(str(two_link))
    ref = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))
    joints = ['joint0', 'joint1']
    angles = np.random.default_rng(3).uniform(-3.0, 3.0, size=(50, 2))
    np.testing.assert_allclose(fingertip_positions(ours, joints, angles),
                               fingertip_positions(ref, joints, angles), rtol=0, atol=1e-9)
    # the same joints, limits and torques: joint0 unlimited, joint1 +-3 rad, 200 N m motors
    for name in joints:
        assert ours.jnt_limited[ours.joint(name).id] == ref.jnt_limited[ref.joint(name).id]
    np.testing.assert_array_equal(ours.joint('joint1').range, [-3.0, 3.0])
    np.testing.assert_array_equal(ours.actuator_gear[:, 0], ref.actuator_gear[:, 0])
    np.testing.assert_array_equal(ours.actuator_ctrlrange, ref.actuator_ctrlrange)
    assert ours.body('target').mocapid[0] == 0


def test_imported_arm_in_the_task_and_the_gym_env(two_link):
    task = ArmTask(two_link, num_envs=8, seed=1)
    points = task.spec.target_points
    assert points.shape == (1000, 3)
    # every stored target is within the arm's reach (0.21 m at the base's height)
    assert np.all(np.linalg.norm(points[:, :2], axis=1) <= 0.21 + 1e-4)
    np.testing.assert_allclose(points[:, 2], 0.01, atol=1e-4)
    task.reset()
    goals = task.target_pos()
    assert all(np.any(np.all(np.abs(points - g) < 1e-12, axis=1)) for g in goals)
    obs, reward, *_ = task.step(np.zeros((8, 2)))
    assert obs.shape == (8, 3 * 2 + 2 * 3) and np.all(np.isfinite(reward))
    task.close()
    env = gym.make('pg_node/Reacher2-v0', model=str(two_link))
    o1, _ = env.reset(seed=5)
    o2, _ = env.reset(seed=5)
    np.testing.assert_array_equal(o1, o2)
    for _ in range(3):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert obs.shape == env.observation_space.shape == (12,) and np.isfinite(reward)
    env.close()


def test_arm_joints_fixed_joints_and_options(tmp_path, capsys):
    out = tmp_path / 'pos.xml'
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--base', 'link0',
                                   '--actuator', 'position', '--kp', 50, '--kv', 2,
                                   '--gravity-compensation', '--tip-offset', 0, 0, 0.02,
                                   '--home', 0.5, '-o', out)
    assert code == 0, err
    assert 'arm joints (1): joint1' in stdout and 'fixed joints (1): joint0' in stdout
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.njnt == 1 and model.nu == 1
    assert model.body_gravcomp[model.body('link1').id] == 1.0
    np.testing.assert_allclose(model.site('fingertip').pos, [0, 0, 0.02])
    # u in [-1, 1] maps to the range [-3, 3]: the bias holds the joint where u says
    np.testing.assert_allclose(model.actuator_gainprm[0, 0], 50 * 3.0)
    np.testing.assert_allclose(model.actuator_biasprm[0, :3], [0.0, -50.0, -2.0])
    np.testing.assert_allclose(model.actuator_forcerange[0], [-200, 200])
    data = mujoco.MjData(model)
    data.ctrl[0] = 0.5
    for _ in range(3000):
        mujoco.mj_step(model, data)
    assert data.qpos[0] == pytest.approx(1.5, abs=0.01)
    assert ArmTask(out).spec.init_qpos.tolist() == [0.5]


MOBILE = """
  <link name="wheel"><inertial><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="wheel_joint" type="continuous"><parent link="base_link"/><child link="wheel"/>
    <origin xyz="0 0.2 0"/><axis xyz="0 1 0"/></joint>
  <link name="odom"/>
  <joint name="odom_joint" type="floating"><parent link="odom"/><child link="base_link"/></joint>
</robot>"""


def test_a_mobile_base_is_fixed_with_its_wheels(tmp_path, capsys):
    urdf = tmp_path / 'mobile.urdf'
    urdf.write_text(TWO_LINK.read_text().replace('</robot>', MOBILE))
    code, stdout, err = run_import(capsys, urdf, '--tip', 'fingertip', '-o', tmp_path / 'm.xml')
    assert code == 0, err
    assert 'arm joints (2): joint0, joint1' in stdout
    assert 'fixed joints (2): odom_joint, wheel_joint' in stdout
    model = mujoco.MjModel.from_xml_path(str(tmp_path / 'm.xml'))
    assert model.njnt == 2 and model.nu == 2


def one_line_error(capsys, *argv):
    code, _, err = run_import(capsys, *argv)
    assert code == 1
    assert err.count('\n') == 1 and err.startswith('arm import: '), err
    return err


def test_errors_are_one_line(tmp_path, capsys):
    out = tmp_path / 'x.xml'
    err = one_line_error(capsys, TWO_LINK, '--tip', 'hand', '-o', out)
    assert "unknown link 'hand' (--tip)" in err and 'fingertip' in err
    err = one_line_error(capsys, TWO_LINK, '--tip', 'fingertip', '--base', 'nope', '-o', out)
    assert "unknown link 'nope' (--base)" in err
    err = one_line_error(capsys, TWO_LINK, '--tip', 'fingertip', '--base', 'link1', '-o', out)
    assert "no revolute joint between 'link1' and 'fingertip'" in err
    err = one_line_error(capsys, TWO_LINK, '--tip', 'link0', '--base', 'camera_link', '-o', out)
    assert "'camera_link' (--base) is not above 'link0'" in err
    err = one_line_error(capsys, resolve_model('reacher2'), '--tip', 'fingertip', '-o', out)
    assert 'is not a URDF file' in err and '<mujoco>' in err
    (tmp_path / 'junk.urdf').write_text('<robot><link name="a"')
    err = one_line_error(capsys, tmp_path / 'junk.urdf', '--tip', 'a', '-o', out)
    assert 'is not a URDF file: not valid XML' in err
    err = one_line_error(capsys, tmp_path / 'missing.urdf', '--tip', 'a', '-o', out)
    assert 'cannot read' in err
    err = one_line_error(capsys, TWO_LINK, '--tip', 'fingertip', '--home', 0, '-o', out)
    assert '--home needs 2 angles' in err
    # a joint whose child link is not defined (it was said to be a second root link)
    text = TWO_LINK.read_text()
    (tmp_path / 'child.urdf').write_text(text.replace('<child link="link1"/>',
                                                      '<child link="lnk1"/>', 1))
    err = one_line_error(capsys, tmp_path / 'child.urdf', '--tip', 'fingertip', '-o', out)
    assert "names child link 'lnk1', which the URDF does not define" in err
    assert 'root link' not in err
    # a revolute joint without <limit>: ROS's URDF parser refuses it; it got no limits here
    no_limit = re.sub(r'(<joint name="joint1" type="revolute">.*?)<limit[^>]*/>', r'\1', text,
                      count=1, flags=re.S)
    assert no_limit != text
    (tmp_path / 'nolimit.urdf').write_text(no_limit)
    err = one_line_error(capsys, tmp_path / 'nolimit.urdf', '--tip', 'fingertip', '-o', out)
    assert "revolute joint 'joint1' has no <limit>" in err
    bad = with_mesh(tmp_path / 'robot' / 'r.urdf', 'package://nopkg/meshes/link.stl')
    err = one_line_error(capsys, bad, '--tip', 'fingertip', '-o', out)
    assert "mesh 'package://nopkg/meshes/link.stl' not found; looked in:" in err
    assert str(tmp_path / 'robot' / 'nopkg' / 'meshes') in err
    assert not out.exists()


def test_an_effort_limit_of_zero_is_named_as_such(tmp_path, capsys):
    """effort="0" was reported as 'has no effort limit'."""
    text = TWO_LINK.read_text().replace('lower="-3" upper="3" effort="200"',
                                        'lower="-3" upper="3" effort="0"')
    (tmp_path / 'zero.urdf').write_text(text)
    code, out, err = run_import(capsys, tmp_path / 'zero.urdf', '--tip', 'fingertip', '-o',
                                tmp_path / 'zero.xml')
    assert code == 0, err
    assert "joint 'joint1' has effort limit 0, which cannot move it; using 1 N m" in out + err
    assert "joint 'joint1' has no effort limit" not in out + err


def test_cli_error_has_no_traceback(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'arm', 'import', str(TWO_LINK),
                           '--tip', 'hand', '-o', str(tmp_path / 'x.xml')],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 1
    assert done.stderr.startswith('arm import: unknown link') and 'Traceback' not in done.stderr
    assert done.stderr.count('\n') == 1


def test_package_uris_resolve_in_the_ament_index_package_paths_and_above_the_urdf(
        tmp_path, monkeypatch):
    rel = 'meshes/link.stl'
    prefix = tmp_path / 'install'
    in_index = write_stl(prefix / 'share' / 'mypkg' / rel)
    in_folder = write_stl(tmp_path / 'pkgs' / 'mypkg' / rel)
    itself = write_stl(tmp_path / 'checkout' / 'mypkg' / rel)
    beside = write_stl(tmp_path / 'ws' / 'src' / 'mypkg' / rel)
    urdf_dir = tmp_path / 'ws' / 'src' / 'mypkg' / 'urdf'
    urdf_dir.mkdir()
    uri = 'package://mypkg/' + rel
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    assert resolve_mesh(uri, urdf_dir, [str(tmp_path / 'pkgs')]) == in_index.resolve()
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'elsewhere'))
    assert resolve_mesh(uri, urdf_dir, [str(tmp_path / 'pkgs')]) == in_folder.resolve()
    assert resolve_mesh(uri, urdf_dir, [str(tmp_path / 'checkout' / 'mypkg')]) == itself
    assert resolve_mesh(uri, urdf_dir) == beside.resolve()
    assert resolve_mesh('file://' + str(in_folder), urdf_dir) == in_folder.resolve()
    assert resolve_mesh('../meshes/link.stl', urdf_dir) == beside.resolve()
    with pytest.raises(UrdfImportError, match='not found; looked in: .*elsewhere'):
        resolve_mesh('package://otherpkg/x.stl', urdf_dir)


def test_meshes_compile_and_are_referenced_from_the_written_model(tmp_path, capsys):
    write_stl(tmp_path / 'ws' / 'src' / 'mypkg' / 'meshes' / 'link.stl')
    urdf = with_mesh(tmp_path / 'ws' / 'src' / 'mypkg' / 'urdf' / 'r.urdf',
                     'package://mypkg/meshes/link.stl')
    out = tmp_path / 'out' / 'arm.xml'
    out.parent.mkdir()
    code, _, err = run_import(capsys, urdf, '--tip', 'fingertip', '-o', out)
    assert code == 0, err
    model = ArmTask(out).model   # loads from any working directory: paths relative to out
    assert model.nmesh == 1
    assert 'file="../ws/src/mypkg/meshes/link.stl"' in out.read_text()
    # COLLADA: a visual .dae gives way to the collision geometry, with a warning
    dae = with_mesh(tmp_path / 'dae' / 'r.urdf', 'meshes/link.dae', kind='visual')
    code, _, err = run_import(capsys, dae, '--tip', 'fingertip', '-o', tmp_path / 'd.xml')
    assert code == 0 and "visual mesh 'meshes/link.dae' is .dae" in err
    assert 'collision geometry instead' in err
    # --no-visual-meshes keeps only the collision geometry
    code, _, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--no-visual-meshes',
                              '-o', tmp_path / 'n.xml')
    assert code == 0
    assert mujoco.MjModel.from_xml_path(str(tmp_path / 'n.xml')).ngeom == 3  # ground, link1,
    # target


def shipped_command():
    """Return the import command kept in arm7.xml, as argv after ``python -m pg_node arm``."""
    model = mujoco.MjModel.from_xml_path(str(ARM7))
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, 'pg_import_command')
    adr, size = model.text_adr[i], model.text_size[i]
    data = bytes(model.text_data[adr:adr + size - 1]).decode()
    argv = shlex.split(data)
    assert argv[:4] == ['python', '-m', 'pg_node', 'arm']
    return data, argv[4:]


def test_shipped_arm7_is_its_urdf_imported_by_the_command_it_names():
    command, argv = shipped_command()
    args = arm.parser().parse_args(argv)
    assert (REPO / args.output).resolve() == ARM7
    result = import_urdf(REPO / args.urdf, arm.options(args), out_path=ARM7, command=command)
    assert result.xml == ARM7.read_text()
    assert resolve_model('arm7') == ARM7
    assert read_urdf(REPO / args.urdf).get('name') == 'panda'
    task = ArmTask(resolve_model('arm7'))
    assert len(task.spec.joint_names) == 7 and task.model.nu == 7
    assert result.fixed_joints == ['panda_finger_joint1', 'panda_finger_joint2']


def test_import_refuses_home_outside_limits():
    with pytest.raises(UrdfImportError, match='outside the joint limits'):
        import_urdf(TWO_LINK, ImportOptions(tip='fingertip', home=[0.0, 3.5]))


def test_short_training_improves_the_imported_7_joint_arm():
    """
    40k steps with config/arm7.yaml (16 arms) raise the mean training return of 100 episodes.

    The return is the training one (the Gaussian policy's episodes), compared between the
    first 100 finished episodes and the last 100 (disjoint: 800 episodes end in 40k steps).
    Its noise: a return of the untrained policy is mostly the control penalty of its noise,
    7 joints x 50 steps of squared Gaussians of std 0.61, about -130 +- 10 an episode, so a
    mean of 100 has a standard error near 1 and a difference of two near 1.4; the gain asked
    for, 8, is more than 5 of those. Seen with seed 0: -122.3 -> -102.6. (The deterministic
    policy needs far longer to gain: 0.26 m to 0.12 m of final distance in 250k steps.)
    """
    from pg_node.rl.train_inprocess import train_inprocess
    cfg = load_config(REPO / 'config' / 'arm7.yaml', ['num_envs=16'])
    returns = []

    def callback(stats):
        returns.append((stats['env_steps'], stats['episode_return']))

    train_inprocess(cfg, 40_000, callback=callback, eval_episodes=4)
    # 16 arms end their 50-step episodes together every 800 steps: the 100th by step 5600
    first = next(r for steps, r in returns if steps >= 5600)
    last = returns[-1][1]
    assert last > first + 8.0, (first, last)


RENDER = """
import sys
import numpy as np
from pg_node.tools.render import Episode, render_episode
from pg_node.sim.arm_task import ArmTask
import gymnasium as gym
import pg_node  # noqa
task = ArmTask(sys.argv[1])
q0 = task.spec.init_qpos
ep = Episode(0, 0, task.spec.target_points[0])
for k in range(3):
    ep.stamps.append(k * 40_000_000)
    ep.positions.append(q0 + 0.3 * k)
    ep.rewards.append(-0.5)
frames = render_episode(ep, sys.argv[1], width=160, height=120)
env = gym.make('pg_node/Reacher2-v0', model=sys.argv[1], render_mode='rgb_array',
               width=160, height=120)
env.reset(seed=0)
np.save(sys.argv[2], np.stack(frames + [env.render()]))
"""


def test_render_and_gym_render_draw_the_imported_arm(tmp_path):
    out = tmp_path / 'frames.npy'
    env = dict(os.environ, MUJOCO_GL='osmesa')
    env['PYTHONPATH'] = str(REPO)
    done = subprocess.run([sys.executable, '-c', RENDER, str(ARM7), str(out)], env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    frames = np.load(out)
    assert frames.shape[0] == 4 and frames.shape[-1] == 3
    for frame in frames:
        assert frame.std() > 10       # not blank
    assert np.abs(frames[0].astype(int) - frames[2].astype(int)).sum() > 0  # the arm moved


@pytest.mark.e2e
def test_sim_node_runs_the_imported_arm(tmp_path):
    from test_sim_node import Client, start_node, stop_node
    proc = start_node(tmp_path, f'model:={ARM7}')
    client = Client()
    try:
        client.wait_ready(client.joint_states)
        names = ArmTask(ARM7).spec.joint_names
        assert list(client.joint_states[-1].name) == [f'arm0/{n}' for n in names]
        tr = client.step([0.5] * 7)
        assert tr.obs.shape == (1, 27) and np.all(np.isfinite(tr.reward))
        client.spin_until(lambda: client.joint_states[-1].effort[0] != 0.0)
        assert client.joint_states[-1].effort[0] == pytest.approx(0.5 * 87)
        assert proc.poll() is None
    finally:
        client.close()
        rc, log = stop_node(proc)
    assert rc == 0 and 'Traceback' not in log, log[-2000:]
