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


def test_a_model_naming_its_urdf_describes_itself_with_it(tmp_path):
    from pg_node.sim.urdf_import import ImportOptions, import_urdf, write_model
    from pg_node.sim.urdf_export import robot_description
    panda = resolve_model('arm7').parent / 'urdf' / 'panda.urdf'
    out = tmp_path / 'panda.xml'
    write_model(import_urdf(panda, ImportOptions(tip='panda_hand_tcp'), out_path=out), out)
    urdf, origin = robot_description(mujoco.MjModel.from_xml_path(str(out)))
    assert origin == 'written from the MuJoCo model'     # arm import names no URDF (yet)
    spec = mujoco.MjSpec.from_file(str(out))
    spec.add_text(name='pg_source_urdf', data=str(panda.resolve()))
    out.write_text(spec.to_xml())
    model = mujoco.MjModel.from_xml_path(str(out))
    urdf, origin = robot_description(model)
    assert origin == str(panda.resolve()) and urdf == panda.read_text()
    moved = tmp_path / 'moved.xml'               # the vendor's file gone: one written
    moved.write_text(out.read_text().replace(str(panda.resolve()), str(tmp_path / 'x.urdf')))
    urdf, origin = robot_description(mujoco.MjModel.from_xml_path(str(moved)))
    assert origin == 'written from the MuJoCo model'
    assert compare_kinematics(model, urdf, tolerance=1e-6) is None


def test_the_command_prints_what_sim_node_publishes(tmp_path, capsys):
    from pg_node.sim.urdf_export import main
    assert main(['arm5_3d']) == 0
    model = mujoco.MjModel.from_xml_path(str(resolve_model('arm5_3d')))
    assert capsys.readouterr().out == export_urdf(model)
    assert main(['no_such_arm']) == 1
    assert capsys.readouterr().err.startswith('urdf_export: ')
