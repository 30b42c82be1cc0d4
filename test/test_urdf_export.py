"""
The URDF written from each hand-written arm: it parses, and its kinematics are MuJoCo's.

Parsed by MuJoCo's own URDF compiler (as :mod:`pg_node.sim.kinematics_check` does), checked
with that check at a tolerance far below its default, and the fingertip link's world
position compared with the model's fingertip site at random joint angles.
"""
import mujoco
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmSpec
from pg_node.sim.kinematics_check import _urdf_model, compare_kinematics
from pg_node.sim.urdf_export import export_urdf, UrdfExportError
import pytest

ARMS = ('reacher2', 'arm5_3d', 'arm7')


@pytest.mark.parametrize('arm', ARMS)
def test_the_urdf_has_the_models_kinematics(arm):
    model = mujoco.MjModel.from_xml_path(str(resolve_model(arm)))
    urdf = export_urdf(model)
    assert compare_kinematics(model, urdf, tolerance=1e-6) is None
    other = _urdf_model(urdf)
    spec = ArmSpec.from_model(model)
    tip = 'fingertip_site' if arm == 'reacher2' else 'fingertip'
    a, b = mujoco.MjData(model), mujoco.MjData(other)
    rng = np.random.default_rng(0)
    low, high = spec.angle_bounds()
    for _ in range(5):
        q = rng.uniform(low, high)
        for m, d in ((model, a), (other, b)):
            for name, value in zip(spec.joint_names, q):
                d.qpos[m.jnt_qposadr[m.joint(name).id]] = value
            mujoco.mj_kinematics(m, d)
        np.testing.assert_allclose(b.xpos[other.body(tip).id],
                                   a.site_xpos[spec.fingertip_site], atol=1e-7)


def test_a_moved_joint_is_seen_by_the_check():
    """The comparison can fail: the exported URDF with joint1 shifted 5 mm is refused."""
    model = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))
    urdf = export_urdf(model).replace('<origin xyz="0.1 0 0" rpy="0 0 0" />',
                                      '<origin xyz="0.105 0 0" rpy="0 0 0" />')
    assert '5.0 mm away' in compare_kinematics(model, urdf)


def test_a_body_with_two_joints_is_refused():
    model = mujoco.MjModel.from_xml_string("""
      <mujoco><worldbody><body name="b"><joint name="j0" axis="0 0 1"/>
        <joint name="j1" axis="0 1 0"/><geom size="0.1"/><site name="fingertip"/></body>
        <body name="target" mocap="true"/></worldbody>
        <actuator><motor joint="j0"/><motor joint="j1"/></actuator></mujoco>""")
    with pytest.raises(UrdfExportError, match="body 'b' has 2 joints"):
        export_urdf(model)


def test_an_imported_arm_is_described_by_its_vendors_urdf_even_moved(tmp_path):
    """
    ``arm import`` names the URDF relative to the model, so the folder can move.

    The model and its URDF are moved together: the description is the vendor's file, read
    from the new place. The URDF left behind: the URDF is written from the model, and
    ``problem`` says which file is missing (the line sim_node logs).
    """
    import shutil
    from pg_node.sim.urdf_export import robot_description, source_urdf, WRITTEN
    from pg_node.sim.urdf_import import ImportOptions, import_urdf, write_model
    shipped = resolve_model('arm7').parent / 'urdf' / 'panda.urdf'
    vendor = tmp_path / 'a' / 'robot' / 'panda.urdf'
    vendor.parent.mkdir(parents=True)
    shutil.copyfile(shipped, vendor)
    out = tmp_path / 'a' / 'models' / 'panda.xml'
    out.parent.mkdir()
    write_model(import_urdf(vendor, ImportOptions(tip='panda_hand_tcp'), out_path=out), out)
    assert '"../robot/panda.urdf"' in out.read_text()      # nothing of this machine
    assert str(tmp_path) not in out.read_text()
    shutil.move(tmp_path / 'a', tmp_path / 'b')
    moved = tmp_path / 'b' / 'models' / 'panda.xml'
    model = mujoco.MjModel.from_xml_path(str(moved))
    described = robot_description(model, moved)
    assert described.urdf == shipped.read_text() and not described.problem
    assert described.origin == str(tmp_path / 'b' / 'robot' / 'panda.urdf')
    assert compare_kinematics(model, described.urdf, tolerance=1e-6) is None
    (tmp_path / 'b' / 'robot' / 'panda.urdf').unlink()    # the URDF did not come along
    described = robot_description(model, moved)
    assert described.origin == WRITTEN
    assert described.problem == ("the model's vendor URDF (pg_source_urdf) "
                                 f"{tmp_path / 'b' / 'robot' / 'panda.urdf'} cannot be read: "
                                 'No such file or directory')
    assert compare_kinematics(model, described.urdf, tolerance=1e-6) is None
    # a copy of the model's text without its file (a card's model_xml): written, and said so
    described = robot_description(model)
    assert described.origin == WRITTEN and 'is relative' in described.problem
    assert source_urdf(mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))) is None


def test_the_shipped_arm7_names_its_urdf_by_a_relative_path():
    from pg_node.sim.urdf_export import robot_description
    path = resolve_model('arm7')
    described = robot_description(mujoco.MjModel.from_xml_path(str(path)), path)
    assert described.origin == str(path.parent / 'urdf' / 'panda.urdf')
    assert described.urdf == (path.parent / 'urdf' / 'panda.urdf').read_text()
    assert 'pg_source_urdf" data="urdf/panda.urdf"' in path.read_text()


def test_the_command_prints_what_sim_node_publishes(tmp_path, capsys):
    from pg_node.sim.urdf_export import main
    assert main(['arm5_3d']) == 0
    model = mujoco.MjModel.from_xml_path(str(resolve_model('arm5_3d')))
    assert capsys.readouterr().out == export_urdf(model)
    assert main(['arm7']) == 0
    urdf = resolve_model('arm7').parent / 'urdf' / 'panda.urdf'
    assert capsys.readouterr().out == urdf.read_text()
    lost = tmp_path / 'arm7.xml'                    # the model without its URDF beside it
    lost.write_text(resolve_model('arm7').read_text())
    assert main([str(lost)]) == 0
    out, err = capsys.readouterr()
    assert err == (f"urdf_export: the model's vendor URDF (pg_source_urdf) "
                   f"{tmp_path / 'urdf' / 'panda.urdf'} cannot be read: No such file or "
                   'directory; written from the model instead\n')
    assert out.startswith('<?xml version="1.0"?>\n<!-- written by pg_node.sim.urdf_export')
    assert main(['no_such_arm']) == 1
    assert capsys.readouterr().err.startswith('urdf_export: ')
