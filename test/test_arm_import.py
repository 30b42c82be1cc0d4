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
import shutil
import struct
import subprocess
import sys

import gymnasium as gym
import mujoco
import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.paths import resolve_model
from pg_node.control.interfaces import card
from pg_node.sim import urdf_import
from pg_node.sim.actuation import actuators
from pg_node.sim.arm_task import ArmTask
from pg_node.sim.urdf_import import (import_urdf, ImportOptions, read_urdf, resolve_mesh,
                                     training_settings, UrdfImportError)
from pg_node.tools import arm
import pytest

REPO = Path(__file__).resolve().parent.parent
FIXTURES = Path(__file__).resolve().parent / 'fixtures' / 'urdf'
TWO_LINK = FIXTURES / 'two_link.urdf'
DAE = FIXTURES / 'dae_mesh.urdf'
XACRO = FIXTURES / 'xacro_pkg' / 'urdf' / 'arm.urdf.xacro'
ARM7 = REPO / 'pg_node' / 'sim' / 'models' / 'arm7.xml'
#: ``--target-region`` that keeps every reachable goal (the import chooses one otherwise)
ANYWHERE = ('--target-region', 0, 0, 0, 'inf')


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
    # reacher2's efforts: the import's cap (issue 55) would lower them
    assert arm.main(['import', str(TWO_LINK), '--tip', 'fingertip', '--max-acceleration', 'inf',
                     '-o', str(out)]) == 0
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
    # xacro's own errors too (it prints and exits when run as its command)
    bad = tmp_path / 'bad.urdf.xacro'
    bad.write_text('<robot name="x" xmlns:xacro="http://www.ros.org/wiki/xacro"><link name="a"/>'
                   '<xacro:foo/></robot>')
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'arm', 'import', str(bad),
                           '--tip', 'a', '-o', str(tmp_path / 'x.xml')],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 1 and done.stderr.count('\n') == 1, done.stderr
    assert done.stderr.startswith(f'arm import: xacro cannot expand {bad}: unknown macro name')


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


def test_meshes_are_copied_beside_the_model_and_load_anywhere(tmp_path, capsys, monkeypatch):
    """The meshes go to <model>_meshes/, named by absolute path: no folder matters any more."""
    write_stl(tmp_path / 'ws' / 'src' / 'mypkg' / 'meshes' / 'link.stl')
    urdf = with_mesh(tmp_path / 'ws' / 'src' / 'mypkg' / 'urdf' / 'r.urdf',
                     'package://mypkg/meshes/link.stl')
    out = tmp_path / 'out' / 'arm.xml'
    out.parent.mkdir()
    code, stdout, err = run_import(capsys, urdf, '--tip', 'fingertip', '-o', out)
    assert code == 0, err
    copy = tmp_path / 'out' / 'arm_meshes' / 'link.stl'
    assert copy.read_bytes() == (tmp_path / 'ws' / 'src' / 'mypkg' / 'meshes' /
                                 'link.stl').read_bytes()
    assert f'file="{copy}"' in out.read_text()
    assert f'meshes: 1 file copied to {copy.parent}' in stdout
    # the source tree gone, another working directory: the model and its text still load
    # (a policy's card keeps the text and compiles it wherever play or policy_node run)
    shutil.rmtree(tmp_path / 'ws')
    monkeypatch.chdir(tmp_path)
    assert mujoco.MjModel.from_xml_string(out.read_text()).nmesh == 1
    assert ArmTask(out).model.nmesh == 1
    # --no-visual-meshes keeps only the collision geometry
    code, _, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--no-visual-meshes',
                              '-o', tmp_path / 'n.xml')
    assert code == 0
    assert mujoco.MjModel.from_xml_path(str(tmp_path / 'n.xml')).ngeom == 3  # ground, link1,
    # target
    # a model folder that does not exist is said so, and nothing is written
    bad = tmp_path / 'nowhere' / 'arm.xml'
    err = one_line_error(capsys, DAE, '--tip', 'tool0', '-o', bad)
    assert 'cannot write' in err and 'No such file or directory' in err
    assert not bad.parent.exists()


def test_a_policy_card_of_an_imported_arm_loads_from_any_folder(tmp_path, capsys,
                                                                monkeypatch):
    """
    What play, export and policy_node compile: the card's model_xml, from anywhere.

    The card keeps the model's text (pg_node.rl.trained_policy.make_card); play writes it
    to the run's log folder for sim_node; policy_node compiles it in its own working
    directory. Relative mesh paths failed there ("Error opening file '../...stl'").
    """
    from pg_node.rl.trained_policy import make_card
    from pg_node.sim.observation import ObservationBuilder
    run = tmp_path / 'runs' / 'a'
    run.mkdir(parents=True)
    out = run / 'arm.xml'
    code, stdout, err = run_import(capsys, DAE, '--tip', 'tool0', '-o', out)
    assert code == 0, err
    assert f'train with: python -m pg_node train --config arm7 model:={out} ' in stdout
    card = make_card(str(out), 3 * 2 + 2 * 3, 2, 2, {})
    elsewhere = tmp_path / 'elsewhere' / 'deeper'
    elsewhere.mkdir(parents=True)
    monkeypatch.chdir(elsewhere)
    builder = ObservationBuilder(mujoco.MjModel.from_xml_string(card['model_xml']))
    assert builder.model.nmesh >= 1
    np.testing.assert_allclose(builder.fingertips(np.zeros((1, 2)))[0], [0.25, 0, 0.16],
                               atol=1e-9)
    log = tmp_path / 'log'
    log.mkdir()
    (log / 'model.xml').write_text(card['model_xml'])   # play's model for sim_node
    task = ArmTask(log / 'model.xml', num_envs=2)
    task.reset()
    obs, reward, *_ = task.step(np.ones((2, 2)))
    assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward))


def stl_bounds(path: Path) -> np.ndarray:
    """Return the bounding box ``[[min xyz], [max xyz]]`` of a binary STL file."""
    data = path.read_bytes()
    (count,) = struct.unpack('<I', data[80:84])
    records = np.frombuffer(data[84:84 + 50 * count], dtype=np.dtype(
        [('normal', '<f4', 3), ('v', '<f4', (3, 3)), ('attr', '<u2')]))
    points = records['v'].reshape(-1, 3)
    return np.array([points.min(axis=0), points.max(axis=0)])


def test_collada_meshes_are_converted_to_stl_in_metres(tmp_path, capsys, monkeypatch):
    out = tmp_path / 'dae.xml'
    code, stdout, err = run_import(capsys, DAE, '--tip', 'tool0', '-o', out)
    assert code == 0 and 'warning' not in err, err
    assert 'meshes: 1 file (1 converted to STL) copied to' in stdout
    stl = tmp_path / 'dae_meshes' / 'cube_mm.stl'
    # 50 mm cube lifted 10 mm by its node, in millimetres: metres, with the node's transform
    np.testing.assert_allclose(stl_bounds(stl), [[0, 0, 0.01], [0.05, 0.05, 0.06]], atol=1e-7)
    model = mujoco.MjModel.from_xml_path(str(out))
    link0 = model.body('link0').id
    meshes = [g for g in range(model.ngeom) if model.geom_bodyid[g] == link0
              and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert len(meshes) == 2     # the visual and the collision geometry, both from the .dae
    # a COLLADA file that is not one: the visual gives way to the collision geometry, the
    # collision mesh to a sphere, each with a warning that says why
    broken = tmp_path / 'robot'
    shutil.copytree(DAE.parent / 'meshes', broken / 'meshes')
    (broken / 'meshes' / 'cube_mm.dae').write_text('<COLLADA><asset>')
    shutil.copy(DAE, broken / 'dae_mesh.urdf')
    code, _, err = run_import(capsys, broken / 'dae_mesh.urdf', '--tip', 'tool0', '-o',
                              tmp_path / 'b.xml')
    assert code == 0, err
    assert "visual mesh 'meshes/cube_mm.dae' cannot be converted (" in err
    assert 'showing the collision geometry instead' in err
    assert "collision mesh 'meshes/cube_mm.dae' cannot be converted (" in err
    assert 'a sphere of radius 0.02 m stands in' in err
    # without trimesh the import still works, and says what to install
    monkeypatch.setitem(sys.modules, 'trimesh', None)
    code, _, err = run_import(capsys, DAE, '--tip', 'tool0', '-o', tmp_path / 'c.xml')
    assert code == 0, err
    assert 'is .dae, and converting it needs trimesh (pip install trimesh pycollada)' in err


def test_an_inertia_mujoco_rejects_is_balanced_with_a_warning(tmp_path, capsys):
    """
    Balanced, not refused: vendors ship such inertias, the import must take them.

    MuJoCo's balanceinertia sets the three principal moments to their mean: the warning
    names the link and both sets, so that the URDF can be fixed where it matters.
    """
    out = tmp_path / 'bad.xml'
    code, _, err = run_import(capsys, FIXTURES / 'bad_inertia.urdf', '--tip', 'tool0', '-o',
                              out)
    assert code == 0, err
    assert ("warning: link 'link1': MuJoCo rejects its inertia (principal moments 0.001 "
            '0.001 0.003 kg m^2 break A + B >= C); balanced to 0.001667 each' in err)
    assert 'link0' not in err
    model = mujoco.MjModel.from_xml_path(str(out))    # the written model needs no balancing
    np.testing.assert_allclose(model.body('link1').inertia, [0.005 / 3] * 3, rtol=1e-5)
    np.testing.assert_allclose(np.sort(model.body('link0').inertia), [0.0005, 0.004, 0.004])
    # an inertia that is not positive definite cannot be balanced: refused, naming the link
    text = (FIXTURES / 'bad_inertia.urdf').read_text().replace(
        'ixx="0.001" iyy="0.001" izz="0.003"', 'ixx="0.001" iyy="-0.001" izz="0.001"')
    (tmp_path / 'neg.urdf').write_text(text)
    err = one_line_error(capsys, tmp_path / 'neg.urdf', '--tip', 'tool0', '-o', out)
    assert "link 'link1': its <inertia> is not positive definite (principal moments -0.001 " \
           '0.001 0.001 kg m^2)' in err


def test_links_without_mass_are_named(tmp_path, capsys):
    out = tmp_path / 'zero.xml'
    code, _, err = run_import(capsys, FIXTURES / 'zero_mass.urdf', '--tip', 'tool0', '-o',
                              out)
    assert code == 0, err
    lines = [line for line in err.splitlines() if 'mass' in line or 'inertial' in line]
    assert lines == [
        'warning: links without an <inertial>, so MuJoCo weighed their collision geometry at '
        '1000 kg/m^3: link0 (1 kg); give them the real mass and inertia',
        "warning: links with geometry but no mass: link1; each weighs 0.001 kg (MuJoCo's "
        'minimum): right for a marker, wrong for a part',
        "warning: joint 'joint1' moves no mass (links link1, link2, tool0): at 0.001 kg each "
        "(MuJoCo's minimum) it spins up at any torque; give them <inertial> elements",
        "warning: joint 'joint2' moves no mass (links link2, tool0): at 0.001 kg each "
        "(MuJoCo's minimum) it spins up at any torque; give them <inertial> elements"], err
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.body('link0').mass[0] == pytest.approx(1.0)
    assert model.body('link1').mass[0] == pytest.approx(0.001)
    # a massless frame on a link with mass (tool0 on a UR, panda_hand_tcp) is not named
    two = TWO_LINK.read_text()
    (tmp_path / 'two.urdf').write_text(two)
    code, _, err = run_import(capsys, tmp_path / 'two.urdf', '--tip', 'fingertip', '-o', out)
    assert code == 0 and 'mass' not in err and 'inertial' not in err, err


def test_continuous_joints_turn_without_end(tmp_path, capsys):
    out = tmp_path / 'cont.xml'
    code, stdout, err = run_import(capsys, FIXTURES / 'continuous.urdf', '--tip', 'tip',
                                   '--velocity-damping', *ANYWHERE, '--max-acceleration',
                                   'inf', '-o', out)
    assert code == 0, err
    assert 'arm joints (2): joint0, joint1' in stdout
    assert "joint 'joint0' has no effort limit; using 1 N m" in err
    assert "joint 'joint0' has no velocity limit; its damping stays" in err
    model = mujoco.MjModel.from_xml_path(str(out))
    assert not model.jnt_limited.any()
    np.testing.assert_allclose(model.actuator_gear[:, 0], [1.0, 5.0])
    np.testing.assert_allclose(model.dof_damping, [0.5, 5.0 / 3.0], rtol=1e-5)  # URDF, e/v
    # targets all the way round: no gap of more than 20 degrees in their bearings
    points = ArmTask(out).spec.target_points
    bearings = np.sort(np.arctan2(points[:, 1], points[:, 0]))
    gaps = np.diff(np.concatenate([bearings, bearings[:1] + 2 * np.pi]))
    assert gaps.max() < np.radians(20)


def test_mimic_on_the_chain_couples_and_below_the_tip_is_fixed(tmp_path, capsys):
    """
    A <mimic> on the chain is MuJoCo's joint equality, and it holds; one below the tip goes.

    joint1 = 0.2 + 0.5 joint0: no actuator, no place in the observation; the targets are
    drawn with it coupled. The equality is soft: under random commands joint1 lags (the
    import measures and prints by how much); at rest it settles onto its mimic.
    """
    out = tmp_path / 'mimic.xml'
    code, stdout, err = run_import(capsys, FIXTURES / 'mimic.urdf', '--tip', 'tip',
                                   '--velocity-damping', '--timestep', 0.02, *ANYWHERE,
                                   '-o', out)
    assert code == 0, err
    assert 'arm joints (2): joint0, joint2' in stdout
    assert 'fixed joints (2): finger_left_joint, finger_right_joint' in stdout
    lag = float(re.search(r'joint1 = 0.2 \+ 0.5 x joint0 \(within ([0-9.e-]+) rad', stdout)[1])
    assert 0 < lag < 0.5
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.nu == 2 and model.njnt == 3 and model.neq == 1     # the fingers' is gone
    assert model.joint(model.eq_obj1id[0]).name == 'joint1'
    np.testing.assert_allclose(model.eq_data[0, :2], [0.2, 0.5])
    task = ArmTask(out, num_envs=1, seed=0, max_episode_steps=None)
    assert task.spec.joint_names == ('joint0', 'joint2')
    task.reset()
    a0, a1 = (model.joint(n).qposadr[0] for n in ('joint0', 'joint1'))
    data = task.datas[0]
    rng = np.random.default_rng(1)
    errors = []
    for _ in range(50):
        task.step(rng.uniform(-1, 1, size=(1, 2)))
        errors.append(data.qpos[a1] - 0.2 - 0.5 * data.qpos[a0])
    assert np.all(np.isfinite(errors)) and np.max(np.abs(errors[5:])) < 0.5
    for _ in range(200):                # at rest (zero command, gravity compensated)
        task.step(np.zeros((1, 2)))
    assert abs(data.qpos[a1] - 0.2 - 0.5 * data.qpos[a0]) < 1e-3
    # every target is the fingertip of joint angles with joint1 on its mimic
    points = task.spec.target_points
    angles = np.random.default_rng(0).uniform([-2.5, -2.5], [2.5, 2.5], size=(20, 2))
    fresh = mujoco.MjData(model)

    def coupled_tip(q0, q2):
        fresh.qpos[[a0, a1, model.joint('joint2').qposadr[0]]] = q0, 0.2 + 0.5 * q0, q2
        mujoco.mj_kinematics(model, fresh)
        return fresh.site('fingertip').xpos.copy()

    for point, (q0, q2) in zip(points, angles):
        np.testing.assert_allclose(coupled_tip(q0, q2), point, atol=1e-4)
    # policy_node's observation (measured arm joints only) puts joint1 on its mimic too
    from pg_node.sim.observation import ObservationBuilder
    tips = ObservationBuilder(model).fingertips(angles)
    for tip, (q0, q2) in zip(tips, angles):
        np.testing.assert_allclose(tip, coupled_tip(q0, q2), atol=1e-12)


def test_a_gripper_below_the_tip_is_fixed_with_its_mass(tmp_path, capsys):
    out = tmp_path / 'gripper.xml'
    code, stdout, err = run_import(capsys, FIXTURES / 'gripper.urdf', '--tip', 'tool0', '-o',
                                   out)
    assert code == 0, err
    assert 'arm joints (2): joint0, joint1' in stdout
    assert 'fixed joints (4): finger_left, finger_right, slider, camera_pan' in stdout
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.njnt == 2 and model.nu == 2 and model.neq == 0
    # the hand (0.4 kg), fingers and slider (3 x 0.05) and camera (0.1) ride on link1
    assert model.body('link1').subtreemass[0] == pytest.approx(0.5 + 0.65 + 0.001)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.site('fingertip').xpos, [0.4, 0, 0.1], atol=1e-12)
    task = ArmTask(out, num_envs=2)
    task.reset()
    for _ in range(25):
        obs, reward, *_ = task.step(np.ones((2, 2)))
    assert np.all(np.isfinite(obs))


def test_xacro_files_are_expanded_with_their_arguments(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, stdout, err = run_import(capsys, XACRO, '--tip', 'tip', *ANYWHERE)
    assert code == 0, err
    assert 'arm joints (2): link0_joint, link1_joint' in stdout
    # the robot's name, not the file's, in the folder git ignores
    assert (tmp_path / 'models' / 'xacro_arm.xml').is_file()
    reach = np.linalg.norm(ArmTask('models/xacro_arm.xml').spec.target_points[:, :2],
                           axis=1).max()
    assert reach == pytest.approx(0.2, abs=0.005)
    code, stdout, err = run_import(capsys, XACRO, '--tip', 'left_tip', '--xacro-arg',
                                   'length:=0.2', '--xacro-arg', 'prefix:=left_', '-o',
                                   'long.xml')
    assert code == 0, err
    assert 'arm joints (2): left_link0_joint, left_link1_joint' in stdout
    reach = np.linalg.norm(ArmTask('long.xml').spec.target_points[:, :2], axis=1).max()
    assert reach == pytest.approx(0.4, abs=0.01)
    # $(find xacro_pkg) is looked for as package:// meshes are: here, above the file; a copy
    # elsewhere finds it with --package-path, and says where it looked without
    alone = tmp_path / 'alone' / 'arm.urdf.xacro'
    alone.parent.mkdir()
    shutil.copy(XACRO, alone)
    err = one_line_error(capsys, alone, '--tip', 'tip', '-o', 'x.xml')
    assert "$(find xacro_pkg): package 'xacro_pkg' not found; looked in:" in err
    code, _, err = run_import(capsys, alone, '--tip', 'tip', '--package-path', FIXTURES,
                              '-o', 'x.xml')
    assert code == 0, err
    # errors: an undefined argument, broken xacro, --xacro-arg on a URDF, a bad --xacro-arg
    undefined = tmp_path / 'undefined.urdf.xacro'
    undefined.write_text(XACRO.read_text().replace('$(arg length)', '$(arg size)'))
    shutil.copytree(XACRO.parent.parent, tmp_path / 'xacro_pkg')
    err = one_line_error(capsys, undefined, '--tip', 'tip', '-o', 'x.xml')
    assert 'Undefined substitution argument size' in err
    assert '(give it: --xacro-arg size:=VALUE)' in err
    broken = tmp_path / 'broken.urdf.xacro'
    broken.write_text(XACRO.read_text().replace('${length} 0 0', '${length +} 0 0'))
    err = one_line_error(capsys, broken, '--tip', 'tip', '-o', 'x.xml')
    assert f'xacro cannot expand {broken}' in err
    err = one_line_error(capsys, TWO_LINK, '--tip', 'fingertip', '--xacro-arg', 'a:=1')
    assert '--xacro-arg is for .xacro files' in err
    with pytest.raises(SystemExit) as exc:
        arm.main(['import', str(XACRO), '--tip', 'tip', '--xacro-arg', 'length=2'])
    assert exc.value.code == 2 and "'length=2' is not NAME:=VALUE" in capsys.readouterr().err


def model_text(path, name: str) -> str:
    """Return the custom text ``name`` of the model at ``path`` ('' when it has none)."""
    model = mujoco.MjModel.from_xml_path(str(path))
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, name)
    if i < 0:
        return ''
    adr, size = model.text_adr[i], model.text_size[i]
    return bytes(model.text_data[adr:adr + size - 1]).decode()


def test_torque_defaults_add_no_damping_and_what_the_command_says(tmp_path, capsys):
    """
    Motor actuators: the URDF's damping only, a 0.002 s timestep, gravity compensation.

    A robot in torque mode enforces no velocity damping, so the defaults add none (the
    URDF's <dynamics damping> 1 stays); undamped, a torque arm needs the finer step (0.02 s
    blows up, see the example-robot-data test), which the train command's frame_skip:=20
    keeps at a 0.04 s control step. The model keeps what it assumes (pg_physics_assumptions).
    The fixture's 35 g links at 200 N m diverge under the recipe's damping of 0 (issue 55):
    the import gives them the smallest armature that holds, and says so.
    """
    out = tmp_path / 'arm.xml'
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '-o', out)
    assert code == 0 and not err, err
    assert ("physics: timestep 0.002 s (implicitfast), the URDF's damping (no velocity "
            'damping), armature 0.01 kg m^2, gravity compensation on, motor actuators, hard '
            'joint limits') in stdout
    assert 'chose armature: 0.01 kg m^2 on every arm joint, the smallest of ' in stdout
    # and 2000 rad/s^2 at most: 21 N m of the URDF's 200 (issue 55)
    assert 'chose efforts: capped at 2000 rad/s^2 x each joint' in stdout
    assert (f"model:={out} frame_skip:=20 randomize_damping='abs uniform 0 0.1' "
            in stdout)
    assert ('  (a control step of 20 x 0.002 s = 0.04 s, 50-step episodes of 2 s)'
            in stdout)
    model = mujoco.MjModel.from_xml_path(str(out))
    assert model.opt.timestep == 0.002
    np.testing.assert_allclose(model.dof_damping, [1, 1])
    np.testing.assert_allclose(model.dof_armature, [0.01, 0.01])
    np.testing.assert_allclose(model.actuator_gear[:, 0], [21.3, 20.3])
    assert model.body_gravcomp[model.body('link1').id] == 1.0
    said = model_text(out, 'pg_physics_assumptions')
    assert 'gravity compensation: the robot cancels' in said and 'velocity' not in said
    assert said.startswith('armature: every arm joint has 0.01 kg m^2')
    assert said.splitlines()[-1].startswith("effort: each arm joint's effort at most 2000")
    # position servos get no velocity damping either (issue 46), and the 0.02 s step
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--actuator',
                                   'position', '-o', out)
    assert code == 0 and ("timestep 0.02 s (implicitfast), the URDF's damping (no velocity "
                          'damping)') in stdout


def test_velocity_damping_is_the_old_default_kept_as_an_assumption(tmp_path, capsys):
    """
    ``--velocity-damping``: damping = effort / velocity limit, said in the model's text.

    It holds full torque to the URDF's velocity limit (10 rad/s here); without it, at
    0.002 s, bang-bang torques spin reacher2's joints past 100 rad/s.
    """
    out = tmp_path / 'arm.xml'
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--velocity-damping',
                                   '--timestep', 0.02, '-o', out)
    assert code == 0 and not err, err
    assert ('physics: timestep 0.02 s (implicitfast), velocity damping (effort / velocity '
            'limit, an assumption), gravity compensation on, motor actuators') in stdout
    assert (f'train with: python -m pg_node train --config arm7 model:={out}  (a control step '
            'of 2 x 0.02 s = 0.04 s, 50-step episodes of 2 s)') in stdout
    model = mujoco.MjModel.from_xml_path(str(out))
    np.testing.assert_allclose(model.dof_damping, [200 / 10] * 2)
    assert model_text(out, 'pg_physics_assumptions').startswith(
        'velocity_damping: each arm joint is damped by effort / velocity limit (N m s/rad), '
        "as if the robot's controller enforced it; a robot in torque mode does not")

    def fastest(path):
        task = ArmTask(path, num_envs=4, seed=0, frame_skip=training_settings(
            mujoco.MjModel.from_xml_path(str(path)).opt.timestep)[0])
        task.reset()
        rng = np.random.default_rng(0)
        top = 0.0
        for _ in range(50):
            task.step(rng.choice([-1.0, 1.0], size=(4, 2)))
            top = max(top, max(np.abs(d.qvel[task.spec.dof_adr]).max() for d in task.datas))
        return top

    assert fastest(out) < 1.5 * 10
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip',
                                   '--no-gravity-compensation', '--max-acceleration', 'inf',
                                   '-o', out)
    # (the armature the import gives the fixture's light links, issue 55, does not hold them;
    # its effort cap would)
    assert code == 0 and ("the URDF's damping (no velocity damping), armature 0.1 kg m^2, "
                          'gravity compensation off') in stdout
    assert model_text(out, 'pg_physics_assumptions').startswith('armature: ')
    assert 'velocity' not in model_text(out, 'pg_physics_assumptions')
    assert fastest(out) > 100
    # --damping replaces velocity damping unless that is asked for too
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--damping', 3,
                                   '-o', out)
    assert code == 0 and 'damping 3 N m s/rad (no velocity damping)' in stdout and not err
    assert 'timestep 0.02 s' in stdout
    np.testing.assert_allclose(mujoco.MjModel.from_xml_path(str(out)).dof_damping, [3, 3])
    assert 'damping: every arm joint is damped by 3 N m s/rad' in model_text(
        out, 'pg_physics_assumptions')
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--damping', 3,
                                   '--velocity-damping', '--timestep', 0.01, '-o', out)
    np.testing.assert_allclose(mujoco.MjModel.from_xml_path(str(out)).dof_damping, [20, 20])
    assert 'frame_skip:=4  (a control step of 4 x 0.01 s' in stdout


#: the arms of PyPI's example-robot-data: (URDF under robots/, tip link, arm joints)
EXAMPLE_ARMS = {
    'ur3': ('ur_description/urdf/ur3_robot.urdf', 'tool0', 6),
    'ur5': ('ur_description/urdf/ur5_robot.urdf', 'tool0', 6),
    'ur10': ('ur_description/urdf/ur10_robot.urdf', 'tool0', 6),
    'panda': ('panda_description/urdf/panda.urdf', 'panda_hand_tcp', 7),
    'kinova': ('kinova_description/robots/kinova.urdf', 'j2s6s200_end_effector', 6),
    'xarm7': ('xarm_description/urdf/xarm7.urdf', 'link_eef', 7),
    'z1': ('z1_description/urdf/z1.urdf', 'gripperStator', 6),
    'so100': ('so_arm_description/urdf/so100.urdf', 'gripper', 5),
    'so101': ('so_arm_description/urdf/so101.urdf', 'gripper_frame_link', 5),
}


@pytest.fixture(scope='module')
def example_robot_data():
    """Return the share/ folder of PyPI's example-robot-data (requirements.in pins it)."""
    from importlib.metadata import distribution
    dist = distribution('example-robot-data')
    share = Path(dist.locate_file('cmeel.prefix/share'))
    assert (share / 'example-robot-data' / 'robots').is_dir(), share
    return share


@pytest.mark.parametrize('name', list(EXAMPLE_ARMS))
def test_example_robot_data_arms_import_and_simulate(name, example_robot_data, tmp_path,
                                                     capsys, monkeypatch):
    """
    Vendors' URDFs as they ship (COLLADA meshes, massless frames, grippers, continuous joints).

    Each imports with velocity damping at 0.02 s (the defaults before issue 46), has its arm
    joints, and 50 control steps of bang-bang commands from another folder stay finite,
    every joint within 3x its URDF velocity limit (seen: 1.0-2.4x; without velocity damping
    at 0.02 s UR5, Panda, Z1 and SO-101 reach 10^4-10^8 rad/s and MuJoCo resets them as
    unstable).
    """
    rel, tip, joints = EXAMPLE_ARMS[name]
    urdf = example_robot_data / 'example-robot-data' / 'robots' / rel
    out = tmp_path / 'models' / f'{name}.xml'
    out.parent.mkdir()
    code, stdout, err = run_import(capsys, urdf, '--tip', tip, '--package-path',
                                   example_robot_data, '--targets', 100, '--velocity-damping',
                                   '--timestep', 0.02, '-o', out)
    assert code == 0, err
    assert f'arm joints ({joints}): ' in stdout
    monkeypatch.chdir(tmp_path)
    task = ArmTask(out, num_envs=2, seed=0)
    assert len(task.spec.joint_names) == task.model.nu == joints
    # the start pose is inside the limits by the start's noise (a Kinova's zero is not)
    spec = task.spec
    low, high = spec.joint_range[spec.joint_limited].T
    home = spec.init_qpos[spec.joint_limited]
    assert np.all(home >= low + 0.1 - 1e-6) and np.all(home <= high - 0.1 + 1e-6)
    task.reset()
    robot = read_urdf(urdf)
    limits = np.array([float(robot.find(f'joint[@name="{j}"]/limit').get('velocity'))
                       for j in task.spec.joint_names])
    rng = np.random.default_rng(0)
    fastest = np.zeros(joints)
    for _ in range(50):
        obs, reward, *_ = task.step(rng.choice([-1.0, 1.0], size=(2, joints)))
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(reward))
        for data in task.datas:
            fastest = np.maximum(fastest, np.abs(data.qvel[task.spec.dof_adr]))
    assert np.all(fastest < 3 * limits), (fastest, limits)


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


def test_the_checks_run_on_the_complete_model_compiled_once(monkeypatch):
    """
    The build compiles the robot once to read it, once for the goals, once for the checks.

    The checks' model is the written one (the goals, the mocap target, the custom data in
    it); the first compile is MuJoCo's own (``spec.compile`` in ``_load_spec``).
    """
    compiled, checked = [], []
    compile_, checks = urdf_import._compile, urdf_import._checks

    def counting(spec):
        compiled.append(spec)
        return compile_(spec)

    def recording(model, *args, **kwargs):
        checked.append(model)
        return checks(model, *args, **kwargs)

    monkeypatch.setattr(urdf_import, '_compile', counting)
    monkeypatch.setattr(urdf_import, '_checks', recording)
    result = import_urdf(TWO_LINK, ImportOptions(tip='fingertip', targets=20))
    assert len(compiled) == 2 and len(checked) == 1
    written = mujoco.MjModel.from_xml_string(result.xml)
    model = checked[0]
    assert (model.nbody, model.nnumeric, model.ntext) == (
        written.nbody, written.nnumeric, written.ntext)
    np.testing.assert_array_equal(model.numeric_data, written.numeric_data)
    assert model.body('target').mocapid[0] == 0


def test_the_task_step_chooses_the_start_pose_within_the_limits():
    """``_task``: zero moved inside the limits by the start's noise, or ``home`` checked."""
    robot = urdf_import._Robot(urdf=None, path=TWO_LINK, base='base_link', arm=['a', 'b', 'c'],
                               coupled={}, joints={}, warnings=[],
                               ranges=np.array([[0.05, 1.0], [-np.pi, np.pi], [-1.0, -0.5]]))
    task = urdf_import._task(robot, ImportOptions(tip='x', target_region=(0, 0, 1, 0.5)))
    np.testing.assert_allclose(task.home, [0.15, 0.0, -0.6])
    assert task.region == (0, 0, 1, 0.5) and task.min_height == 0.0 and task.points is None
    task = urdf_import._task(robot, ImportOptions(tip='x', home=[0.5, 3.0, -0.7]))
    np.testing.assert_array_equal(task.home, [0.5, 3.0, -0.7])
    with pytest.raises(UrdfImportError, match='outside the joint limits'):
        urdf_import._task(robot, ImportOptions(tip='x', home=[0.0, 0.0, -0.7]))


def test_velocity_damping_is_off_unless_asked_for():
    """A plain bool, off in the options and on the command line alike."""
    assert ImportOptions(tip='x').velocity_damping is False
    args = arm.parser().parse_args(['import', 'r.urdf', '--tip', 'x'])
    assert arm.options(args).velocity_damping is False
    args = arm.parser().parse_args(['import', 'r.urdf', '--tip', 'x', '--velocity-damping'])
    assert arm.options(args).velocity_damping is True


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
from pg_node.sim import urdf_import
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
        assert list(client.joint_states[-1].name) == list(names)   # one arm: plain
        tr = client.step([0.5] * 7)
        assert tr.obs.shape == (1, 27) and np.all(np.isfinite(tr.reward))
        client.spin_until(lambda: client.joint_states[-1].effort[0] != 0.0)
        assert client.joint_states[-1].effort[0] == pytest.approx(0.5 * 87)
        assert proc.poll() is None
    finally:
        client.close()
        rc, log = stop_node(proc)
    assert rc == 0 and 'Traceback' not in log, log[-2000:]


@pytest.mark.parametrize('name, armature', [('ur5', False), ('panda', False),
                                            ('so101', True)])
def test_torque_defaults_of_vendor_arms_are_stable_or_given_an_armature(
        name, armature, example_robot_data, tmp_path, capsys):
    """
    With the defaults (motor, no added damping, 0.002 s) UR5 and Panda stay stable.

    Under bang-bang full torque and the recipe's randomization at its ends neither diverges
    (seen: 160-280 rad/s at most, what a torque robot reaches before its over-speed fault)
    and the import adds nothing; the SO-101's light links diverge at 0.002 s, so the import
    gives them the smallest armature that holds and says so (issue 55; before it, a warning).
    """
    rel, tip, _ = EXAMPLE_ARMS[name]
    urdf = example_robot_data / 'example-robot-data' / 'robots' / rel
    out = tmp_path / f'{name}.xml'
    code, stdout, err = run_import(capsys, urdf, '--tip', tip, '--package-path',
                                   example_robot_data, '--targets', 50, '--no-visual-meshes',
                                   '-o', out)
    assert code == 0, err
    assert 'unstable' not in err and 'diverges' not in err, err
    assert ('chose armature: ' in stdout) == armature, stdout
    model = mujoco.MjModel.from_xml_path(str(out))
    robot = read_urdf(urdf)
    urdf_damping = []
    for i in range(model.nu):
        dynamics = robot.find(f'joint[@name="{model.actuator(i).name}"]/dynamics')
        urdf_damping.append(float(dynamics.get('damping', 0)) if dynamics is not None else 0)
    dofs = model.jnt_dofadr[model.actuator_trnid[:, 0]]
    np.testing.assert_allclose(model.dof_damping[dofs], urdf_damping)
    assert model.opt.timestep == 0.002


def test_velocity_servos_take_the_urdf_velocity_limits(tmp_path, capsys):
    """--actuator velocity: u is u x the URDF velocity limit (rad/s), gain effort / limit."""
    out = tmp_path / 'vel.xml'
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--actuator',
                                   'velocity', '--armature', 0.1, '-o', out)
    assert code == 0 and not err, err
    assert 'velocity actuators' in stdout and "the URDF's damping (no velocity" in stdout
    model = mujoco.MjModel.from_xml_path(str(out))
    act = actuators(model)
    assert list(act.kind) == ['velocity', 'velocity']
    assert card(act) == {'velocity': {'unit': 'rad/s', 'low': [-10.0, -10.0],
                                      'high': [10.0, 10.0]}}
    np.testing.assert_allclose(model.actuator_biasprm[:, 2], -200.0 / 10.0)
    data = mujoco.MjData(model)
    data.ctrl[:] = 0.5                      # 5 rad/s, less the URDF damping's share
    for _ in range(10):                     # 0.2 s: joint1 stays inside its +-3 rad
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(data.qvel[:2], 5.0 * 20.0 / 21.0, rtol=0.02)
    # the light links without armature chatter under the clamped force: warned of
    code, _, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--actuator',
                              'velocity', '-o', out)
    assert code == 0 and 'faster than 3 times its velocity limit' in err
    # a joint without a velocity limit is refused in one line
    urdf = tmp_path / 'no_limit.urdf'
    urdf.write_text(TWO_LINK.read_text().replace('velocity="10"', 'velocity="0"'))
    code, _, err = run_import(capsys, urdf, '--tip', 'fingertip', '--actuator', 'velocity',
                              '-o', out)
    assert code == 1 and '--actuator velocity needs a <limit velocity>' in err
    assert len(err.strip().splitlines()) == 1


def test_the_import_prints_the_recipe_measured_for_its_interface(
        tmp_path, capsys, monkeypatch):
    """
    Issue 46 item 6: the recipe that learned, per command interface, or that none was.

    Velocity servos, velocity-damped motors and both kinds of position servos have one
    (measured on the UR5, BENCHMARKS.md), undamped motors one measured on the Panda; the
    position lines say what was measured, short of the goal or unsafe as it was.
    """
    out = tmp_path / 'arm.xml'
    cases = ((['--actuator', 'velocity', '--armature', 0.1],
              'recipe measured for velocity actuators: import with --actuator velocity, '),
             (['--velocity-damping', '--timestep', 0.02],
              'recipe measured for motor, velocity damping actuators: import with '
              '--velocity-damping --timestep 0.02, '),
             ([], 'recipe measured for motor actuators: import with the defaults '),
             (['--actuator', 'position'],
              'recipe measured for position actuators: import with --actuator position '
              '--kp 500 --kv 20 --timestep 0.005 (absolute targets'),
             (['--actuator', 'position', '--position-delta', 0.05],
              'recipe measured for position, bounded changes actuators: import with '
              '--actuator position --kp 500 --kv 20 --timestep 0.005 --position-delta 0.04'))
    for flags, said in cases:
        code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', *flags,
                                       '-o', out)
        assert code == 0, err
        last = stdout.strip().splitlines()[-1]
        assert last.startswith(said), last
    for flags, train, result in arm.RECIPES.values():
        assert train.startswith('--config arm7') and 'within 2 cm' in result
    # an interface without a measured recipe says so
    monkeypatch.delitem(arm.RECIPES, 'position')
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--actuator',
                                   'position', '-o', out)
    assert code == 0, err
    assert stdout.strip().splitlines()[-1].startswith(
        'recipe: none measured yet for position actuators; ')


# --- issue 55: the import tries what it prints, and chooses the task from the URDF ---

def pybullet_iiwa() -> Path:
    """Return pybullet_data's KUKA iiwa URDF (300 N m on every joint, a 0.3 kg last link)."""
    pybullet_data = pytest.importorskip('pybullet_data')
    return Path(pybullet_data.getDataPath()) / 'kuka_iiwa' / 'model.urdf'


#: the new user's import of issue 55 item 4: a start pose and goals in front, given
IIWA_TASK = ('--tip', 'lbr_iiwa_link_7', '--home', 0, 0.5, 0, -1.2, 0, 1.0, 0,
             '--target-region', 0.5, 0, 0.4, 0.3, '--targets', 100, '--no-visual-meshes')


def printed_training(stdout: str):
    """Return the one printed train command's ``(model, frame_skip, {term: text})``."""
    lines = [line for line in stdout.splitlines() if 'python -m pg_node train' in line]
    assert len(lines) == 1, stdout                  # one command, not two
    argv = shlex.split(lines[0].partition('train with: ')[2].partition('  (')[0])
    assert argv[:5] == ['python', '-m', 'pg_node', 'train', '--config']
    given = dict(arg.replace(':=', '=', 1).split('=', 1) for arg in argv[6:])
    terms = {key[len('randomize_'):]: value for key, value in given.items()
             if key.startswith('randomize_')}
    return given['model'], int(given['frame_skip']), terms


def fastest_under(model, frame_skip, terms, steps=50):
    """Return the fastest joint (rad/s) of 8 arms under bang-bang commands and ``terms``."""
    task = ArmTask(model, num_envs=8, seed=0, frame_skip=frame_skip, max_episode_steps=50,
                   randomization=terms)
    task.reset()
    rng = np.random.default_rng(0)
    top = 0.0
    for _ in range(steps):
        task.step(rng.choice([-1.0, 1.0], size=(8, task.act_dim)))
        speeds = [np.abs(d.qvel[task.spec.dof_adr]).max() for d in task.datas]
        top = max(top, float(np.nan_to_num(max(speeds), nan=np.inf)))
    task.close()
    return top


def test_the_import_holds_the_model_under_the_recipe_it_prints(tmp_path, capsys):
    """
    Issue 55 item 4: pybullet_data's iiwa with a --home and a --target-region, as printed.

    Before, the import's check (one 2 s rollout, no randomization) passed while the printed
    recipe's randomize_damping (down to 0, below the URDF's 0.5) took the 0.3 kg last link
    past 1e6 rad/s within 26 control steps. Now the check runs the printed randomization
    at both ends of its ranges and gives the joints the smallest armature that holds; the
    printed command, run as printed (its randomization drawn), stays finite and below the
    divergence speed. With nothing left to choose, the import refuses and says why.
    """
    out = tmp_path / 'iiwa.xml'
    code, stdout, err = run_import(capsys, pybullet_iiwa(), *IIWA_TASK, '--no-hard-limits',
                                   '-o', out)
    assert code == 0 and 'diverges' not in err, err
    chose = [line for line in stdout.splitlines() if line.startswith('chose armature: ')]
    assert len(chose) == 1, stdout
    armature = float(chose[0].split()[2])
    model, frame_skip, terms = printed_training(stdout)
    assert Path(model) == out and frame_skip == 20
    assert terms['damping'] == 'abs uniform 0 0.1'
    assert fastest_under(model, frame_skip, terms) < urdf_import.DIVERGED_SPEED
    assert 'armature: every arm joint has' in model_text(out, 'pg_physics_assumptions')
    assert f'armature: {armature:g} kg m^2' in model_text(out, 'pg_import_choices')
    # the armature is what holds it: the same model without it diverges under the recipe
    # (the damping 0 end)
    bare = tmp_path / 'bare.xml'
    bare.write_text(out.read_text().replace(f'armature="{armature:g}"', 'armature="0"'))
    assert fastest_under(bare, frame_skip, {'damping': 'abs 0'}) > urdf_import.DIVERGED_SPEED
    # nothing left to choose (armature and timestep given): refused, with the reason
    code, stdout, err = run_import(capsys, pybullet_iiwa(), *IIWA_TASK, '--no-hard-limits',
                                   '--armature', 0, '--timestep', 0.002, '-o', bare)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert ("MuJoCo diverges under the training's commands: joint" in err
            and 'control steps of bang-bang commands on the ' in err
            and '--armature' in err), err


def test_the_import_prints_one_train_command_with_its_recipe(tmp_path, capsys):
    """The recipe's --config and randomization, the timestep's frame_skip: one command."""
    out = tmp_path / 'arm.xml'
    for flags, config, extra in (
            ([], '--config arm7', " frame_skip:=20 randomize_damping='abs uniform 0 0.1' "),
            (['--actuator', 'velocity', '--armature', 0.1], '--config arm7',
             " randomize_servo_bandwidth='uniform 5 20' "),
            (['--actuator', 'position', '--timestep', 0.005, '--position-delta', 0.04],
             '--config arm7', ' frame_skip:=8 reward_control_weight:=0.05 ')):
        code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', *flags,
                                       '-o', out)
        assert code == 0, err
        train = [line for line in stdout.splitlines() if 'pg_node train' in line]
        assert len(train) == 1, stdout
        assert train[0].startswith(f'train with: python -m pg_node train {config} '
                                   f'model:={out}'), train[0]
        assert extra in train[0], train[0]
        assert 'trained with the command above: ' in stdout.splitlines()[-1]
    # no recipe for an interface: the plain command, still one
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--actuator',
                                   'position', '-o', out)
    assert code == 0 and stdout.count('pg_node train') == 1


def test_the_import_says_why_fewer_targets_were_kept(tmp_path, capsys):
    """
    Fewer goals than asked: how many drawn poses each filter removed.

    A 2 cm ball at the two-link arm's edge of reach holds few of the poses drawn (50 a
    target at most); goals below a height the planar arm never reaches: none, refused.
    """
    out = tmp_path / 'arm.xml'
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--targets', 100,
                                   '--target-region', 0.2, 0, 0.01, 0.02, '-o', out)
    assert code == 0, err
    said = re.search(r'(\d+) of 100 reachable targets \(the poses drawn for the rest: '
                     r'(\d+) outside the goal region; 50 draws a target at most\)', stdout)
    assert said and int(said[1]) + int(said[2]) == 5000, stdout
    assert int(said[1]) < 100
    code, stdout, err = run_import(capsys, TWO_LINK, '--tip', 'fingertip', '--targets', 10,
                                   '--target-min-height', 0.05, '-o', out)
    assert code == 1 and err.strip() == ('arm import: no reachable target is left: 500 '
                                         'below z = 0.05 m'), err
    assert urdf_import.rejected_text({'below the base plane': 3, 'in self-collision': 0,
                                      'outside the goal region': 2}) == (
        '3 below the base plane, 2 outside the goal region')


def test_the_import_writes_where_git_ignores_it(tmp_path, capsys, monkeypatch):
    """Without -o: models/<robot>.xml and its meshes, a folder the repository ignores."""
    monkeypatch.chdir(tmp_path)
    urdf = with_mesh(tmp_path / 'urdf' / 'arm.urdf', 'link1.stl')
    write_stl(tmp_path / 'urdf' / 'link1.stl')
    code, stdout, err = run_import(capsys, urdf, '--tip', 'fingertip')
    assert code == 0, err
    assert (tmp_path / 'models' / 'two_link.xml').is_file()
    assert (tmp_path / 'models' / 'two_link_meshes' / 'link1.stl').is_file()
    assert 'wrote models/two_link.xml' in stdout
    for path in ('models/two_link.xml', 'models/two_link_meshes/link1.stl'):
        done = subprocess.run(['git', 'check-ignore', '-q', path], cwd=REPO)
        assert done.returncode == 0, f'git does not ignore {path}'


def test_the_import_chooses_the_task_from_the_urdf_and_says_why(tmp_path, capsys):
    """
    Issue 55 item 1: with no --home and no --target-region the import chooses both.

    The start pose is in the middle half of every joint's range, without self-collision,
    its fingertip above the base and out in front; the goals are a ball of 0.35 x the reach
    around that fingertip, above the base plane. Hard limits are on, and every choice is
    in the model (pg_import_choices) with its reason; each flag replaces its choice.
    """
    out = tmp_path / 'iiwa.xml'
    code, stdout, err = run_import(capsys, pybullet_iiwa(), '--tip', 'lbr_iiwa_link_7',
                                   '--targets', 200, '--no-visual-meshes', '-o', out)
    assert code == 0, err
    choices = model_text(out, 'pg_import_choices').splitlines()
    assert [line.split(':')[0] for line in choices][:5] == [
        'home', 'goal region', 'efforts', 'hard limits', 'timestep']
    assert all(f'chose {line}' in stdout for line in choices)
    task = ArmTask(out)
    spec, model = task.spec, task.model
    low, high = spec.joint_range.T
    home = spec.init_qpos
    quarter = (high - low) / 4
    assert np.all(home >= low + quarter - 1e-3) and np.all(home <= high - quarter + 1e-3)
    tip = fingertip_positions(model, spec.joint_names, [home])[0]
    reach = float(re.search(r'reach ([0-9.]+) m', choices[0])[1])
    assert 0.9 < reach < 1.3                          # the iiwa: 1.18 m to its flange
    assert tip[2] >= 0.2 * reach and np.linalg.norm(tip[:2]) >= 0.3 * reach - 1e-3
    region = [float(v) for v in choices[1].split('(')[0].split(':')[1].split()]
    np.testing.assert_allclose(region[:3], tip, atol=1e-3)
    assert region[3] == pytest.approx(0.35 * reach, abs=0.02)
    points = spec.target_points
    assert len(points) == 200 and np.all(points[:, 2] >= 0)
    assert np.all(np.linalg.norm(points - region[:3], axis=1) <= region[3] + 1e-3)
    arm = [model.joint(name).id for name in spec.joint_names]
    np.testing.assert_allclose(model.jnt_solref[arm, 0], 2 * model.opt.timestep)
    # the flags replace the choices, and nothing chosen is said
    code, stdout, err = run_import(capsys, pybullet_iiwa(), *IIWA_TASK, '--armature', 0.2,
                                   '--timestep', 0.002, '--no-hard-limits', '-o', out)
    assert code == 0, err
    assert 'chose ' not in stdout and model_text(out, 'pg_import_choices') == ''
    model = mujoco.MjModel.from_xml_path(str(out))
    np.testing.assert_allclose(model.numeric('pg_init_qpos').data, [0, 0.5, 0, -1.2, 0, 1, 0])
    np.testing.assert_allclose(model.jnt_solref[:7, 0], 0.02)       # MuJoCo's default
    np.testing.assert_allclose(model.dof_armature, 0.2)


def test_the_chosen_start_pose_and_goals_are_free_of_self_collision():
    """The chooser's kinematics: a folded pose of the Panda collides, its ready pose not."""
    urdf = REPO / 'pg_node' / 'sim' / 'models' / 'urdf' / 'panda.urdf'
    robot = read_urdf(urdf)
    base, _, chain, joints = urdf_import._chain(robot, None, 'panda_hand_tcp')
    arm_joints, coupled = urdf_import._couplings(chain, joints)
    parts = urdf_import._Robot(urdf=robot, path=urdf, base=base, arm=arm_joints,
                               coupled=coupled, joints=joints, warnings=[])
    opts = ImportOptions(tip='panda_hand_tcp', choose=True)
    spec, model = urdf_import._mujoco_spec(parts)
    urdf_import._joints(spec, model, parts, urdf_import.with_defaults(opts))
    kin = urdf_import._Kinematics(parts, opts)
    kin.tip([0, -0.785, 0, -2.356, 0, 1.571, 0.785])
    assert not kin.collides()
    kin.tip([0, 1.7, 0, -3.0, 0, 0.0, 0])               # the hand folded into the base
    assert kin.collides()
    home, why = urdf_import._choose_home(kin, kin.reach(np.random.default_rng(0)), 0)
    kin.tip(home)
    assert not kin.collides() and 'without self-collision' in why
