"""
The scene's shapes are MuJoCo's geoms at their world poses, and its markers are the shapes.

A recorded state (arm5_3d, two arms, a few random steps): each capsule's cylinder sits at the
geom's pose, its end spheres at the ends of its ``fromto`` (the body's origin and 0.15 m or
so along the link), goal and fingertip where the task has them, all shifted by the arm's
offset; the trail restarts with an episode; the MarkerArray carries the same poses.
"""
from builtin_interfaces.msg import Time
import mujoco
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.ros.scene_msg import scene_markers
from pg_node.sim.arm_task import ArmTask
from pg_node.sim.scene import CYLINDER, Scene, SPHERE
import pytest
from visualization_msgs.msg import Marker

OFFSETS = np.array([[0.0, 0.0, 0.0], [0.7, 0.0, 0.0]])


@pytest.fixture(scope='module')
def recorded():
    task = ArmTask(resolve_model('arm5_3d'), num_envs=2, seed=3)
    task.reset()
    scene = Scene(task.model, [1], OFFSETS, trail_length=4)
    rng = np.random.default_rng(0)
    for _ in range(6):
        task.step(rng.uniform(-1, 1, (2, task.act_dim)))
        scene.record(task.datas, task.episode_step)
    return task, scene


def test_shapes_are_the_geoms_at_their_world_poses(recorded):
    task, scene = recorded
    (view,) = scene.views(task.datas)
    m, d = task.model, task.datas[1]
    capsules = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
                and m.body(m.geom_bodyid[g]).name != 'target']
    assert len(capsules) == 5
    cylinders = next(s for s in view.links if s.kind == CYLINDER)
    spheres = next(s for s in view.links if s.kind == SPHERE)
    assert len(cylinders.pos) == 5 and len(spheres.pos) == 10
    for k, g in enumerate(capsules):
        np.testing.assert_allclose(cylinders.pos[k], d.geom_xpos[g] + OFFSETS[1], atol=1e-12)
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, cylinders.quat[k])
        np.testing.assert_allclose(rot, d.geom_xmat[g], atol=1e-9)
        np.testing.assert_allclose(cylinders.scale[k, [0, 2]],
                                   [2 * m.geom_size[g, 0], 2 * m.geom_size[g, 1]])
        # each link's capsule starts at its body's origin (fromto="0 0 0 ...")
        start = d.xpos[m.geom_bodyid[g]] + OFFSETS[1]
        assert np.min(np.linalg.norm(spheres.pos - start, axis=1)) < 1e-9
    np.testing.assert_allclose(view.goal, task.target_pos()[1] + OFFSETS[1])
    np.testing.assert_allclose(view.tip, task.fingertip_pos()[1] + OFFSETS[1])
    assert len(view.trail) == 4
    np.testing.assert_allclose(view.trail[-1], view.tip)


def test_the_trail_restarts_with_an_episode(recorded):
    task, scene = recorded
    scene.record(task.datas, np.zeros(2, dtype=int))
    assert len(scene.views(task.datas)[0].trail) == 1


def test_the_markers_carry_the_shapes(recorded):
    task, scene = recorded
    views = scene.views(task.datas)
    msg = scene_markers(views, Time(sec=3), frame_id='world')
    shapes = sum(len(s.pos) for s in views[0].links)
    assert len(msg.markers) == shapes + 3                       # + goal, fingertip, trail
    assert {m.header.frame_id for m in msg.markers} == {'world'}
    assert {m.ns for m in msg.markers} == {'arm1'}
    assert len({m.id for m in msg.markers}) == len(msg.markers)
    cylinders = [m for m in msg.markers if m.type == Marker.CYLINDER]
    want = next(s for s in views[0].links if s.kind == CYLINDER)
    got = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z,
                     m.pose.orientation.w, m.pose.orientation.x, m.pose.orientation.y,
                     m.pose.orientation.z] for m in cylinders])
    np.testing.assert_allclose(got, np.hstack([want.pos, want.quat]))
    goal = msg.markers[shapes]
    np.testing.assert_allclose([goal.pose.position.x, goal.pose.position.y,
                                goal.pose.position.z], views[0].goal)
    assert msg.markers[-1].type == Marker.LINE_STRIP
