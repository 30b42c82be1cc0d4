"""
pybullet_node: the robot's stand-in on PyBullet, from the robot's own URDF (issue 45).

Where ``sim_node`` is pg_node's MuJoCo model of the arm, this node is a second physics engine
reading the vendor's URDF (:class:`pg_node.sim.pybullet_arm.PybulletArm`), offered as a
ros2_control robot offers itself, so that ``policy_node`` drives it as it would the robot
(``python -m pg_node play RUN --robot pybullet``; docs/sim_to_sim.md). One arm, real time.

Published:

* ``robot_description`` (``std_msgs/String``, reliable, transient local): the URDF as shipped;
* ``joint_states`` (``sensor_msgs/JointState``) every control period: the arm joints' plain
  names (as a robot's ``joint_state_broadcaster`` gives them), position (rad), velocity
  (rad/s) and effort (the torque applied, N m, gravity compensation included), stamped with
  simulated time;
* ``clock`` (``rosgraph_msgs/Clock``): simulated time, control periods x period;
* ``target`` (``geometry_msgs/PointStamped``, reliable, transient local, ``frame_id``
  ``base_link``): the goal of each episode, when it starts;
* ``pg_node/transition`` (``std_msgs/Float64MultiArray``, :mod:`pg_node.ros.transition`):
  every control period, the observation (the model's kinematics at PyBullet's angles, the
  fingertip-to-target vector PyBullet's), the task's reward and the episode's count, for
  ``play`` to sum.

Subscribed, in SI units of ``command_interface`` (``effort`` N m, ``position`` rad or
``velocity`` rad/s; before any command 0 of the interface: zero effort, zero velocity (the
velocity motors hold the arm where it is) or angles 0):

* ``arm_controller/commands`` (``std_msgs/Float64MultiArray``), as ros2_control's forward
  command controller (``effort_controllers/JointGroupEffortController`` and its position and
  velocity siblings, config/controllers/forward_velocity.yaml): one value per arm joint in
  the URDF's joint order; the last command is held forever (the controller has no timeout:
  a velocity keeps the arm moving); a message of another size or with a non-finite value is
  dropped with a warning;
* ``arm_controller/joint_trajectory`` (``trajectory_msgs/JointTrajectory``), as Jazzy's joint
  trajectory controller with zero gains (:class:`pg_node.control.jtc.JtcFollower`) and the
  ``allow_*`` flags of the shipped controller of the interface (``jtc.SHIPPED_FLAGS``: the
  velocity one allows a non-zero last velocity, config/controllers/jtc_velocity.yaml):
  applied at each point's ``time_from_start`` (the point's ``velocities`` on the velocity
  interface, its ``ff_velocity_scale`` 1), and ``jtc_cmd_timeout`` s after the last point
  the controller's hold (zero effort, zero velocity, or the positions measured then). Once
  a trajectory was accepted, it sets the command.

Service: ``~/reset_world`` (``std_srvs/Trigger``), as ``sim_node``'s: the episodes drawn
again from ``seed`` as at start (the next one under a new id, the held command kept);
``play`` calls it once the policy commands, so the same ``--seed`` plays the same episodes.

Episodes: each ``max_episode_steps`` control periods the arm is put at a new start with a
new goal, drawn as ``sim_node`` with the same ``seed`` draws them (an
:class:`pg_node.sim.arm_task.ArmTask` of ``model``, never stepped), and the held command is
kept. At start the node logs in one line where PyBullet's reading of the URDF and the MuJoCo
model disagree (:func:`pg_node.sim.pybullet_check.compare`: joints, limits, masses,
kinematics), and every warning of the URDF's loading.

Parameters: :data:`pg_node.common.params.PYBULLET_PARAMS`.
"""
from pathlib import Path

from geometry_msgs.msg import Point, PointStamped
import numpy as np
from pg_node.bag.ros_types import float64_field
from pg_node.common.param_schema import ConfigError
from pg_node.common.params import PYBULLET_PARAMS
from pg_node.common.paths import resolve_model
from pg_node.common.run import CONTROLLER_COMMANDS, CONTROLLER_TRAJECTORY
from pg_node.control import interfaces
from pg_node.control import jtc
from pg_node.ros import jtc_msg
from pg_node.ros import transition
from pg_node.ros.parameters import declare_params
from pg_node.ros.runtime import params_help, run
from pg_node.ros.sim_node import sim_stamp
from pg_node.sim.actuation import actuators
from pg_node.sim.arm_task import ArmTask
from pg_node.sim.observation import ObservationBuilder
from pg_node.sim.pybullet_arm import PybulletArm, PybulletError, robot_urdf
from pg_node.sim.pybullet_check import compare
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
TARGET_FRAME = 'base_link'


class PybulletNode(Node):
    """One arm in PyBullet behind a forward controller's and a JTC's topics."""

    def __init__(self, **node_options):
        """Load the model and the URDF, publish the description and the first episode."""
        super().__init__('pybullet_node', **node_options)
        p = self.params = declare_params(self, PYBULLET_PARAMS)
        self.task = ArmTask(resolve_model(p['model']), num_envs=1, seed=p['seed'],
                            frame_skip=p['frame_skip'],
                            max_episode_steps=p['max_episode_steps'])
        m, s = self.task.model, self.task.spec
        try:
            urdf = robot_urdf(m, p['model'], p['urdf'])
        except PybulletError as exc:
            raise ConfigError(f"parameter 'pybullet_node.urdf': {exc}") from None
        self.interface = p['command_interface']
        self.actuators = actuators(m)
        refused = interfaces.check(self.actuators, self.interface)
        if refused:
            raise ConfigError(f"parameter 'pybullet_node.command_interface': {refused}")
        try:
            self.arm = PybulletArm(urdf, s.joint_names, control_period=self.task.dt,
                                   gravity_compensation=p['gravity_compensation'],
                                   package_paths=[p['package_path']] if p['package_path']
                                   else ())
        except PybulletError as exc:
            raise ConfigError(f"parameter 'pybullet_node.urdf': {exc}") from None
        log = self.get_logger()
        for line in self.arm.warnings:
            log.warning(f'URDF: {line}')
        agreement = compare(m, self.arm)
        (log.warning if agreement.disagreements else log.info)(agreement.line())
        self.joints = list(s.joint_names)
        self.builder = ObservationBuilder(m)
        self.tip = (m.body(int(m.site_bodyid[s.fingertip_site])).name,
                    m.site_pos[s.fingertip_site].copy())
        self.vec = self.task.obs_layout.slices['fingertip_minus_target']
        self.held = np.zeros(len(self.joints))       # effort 0 until a command comes
        self.steps = 0
        self.seq = -1
        self.episode_id = -1
        self.follower = jtc.JtcFollower(self.joints, self.interface, p['jtc_cmd_timeout'],
                                        flags=jtc.stand_in_flags(self.interface,
                                                                 p['jtc_d_gain']),
                                        d=[p['jtc_d_gain']])

        self.pub_description = self.create_publisher(String, 'robot_description', LATCHED)
        self.pub_description.publish(String(data=Path(urdf).read_text()))
        self.pub_joints = self.create_publisher(JointState, 'joint_states', 10)
        self.pub_clock = self.create_publisher(Clock, 'clock', 10)
        self.pub_target = self.create_publisher(PointStamped, 'target', LATCHED)
        self.pub_transition = self.create_publisher(
            Float64MultiArray, 'pg_node/transition',
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.create_subscription(Float64MultiArray, CONTROLLER_COMMANDS, self.on_command, 10)
        self.create_subscription(JointTrajectory, CONTROLLER_TRAJECTORY, self.on_trajectory,
                                 10)
        self.create_service(Trigger, '~/reset_world', self.on_reset_world)
        self.start_episode()
        self.create_timer(self.task.dt / p['real_time_factor'], self.on_tick)
        log.info(f'{p["model"]} in PyBullet from {urdf}: joints {", ".join(self.joints)}, '
                 f'{self.interface} commands, control period {self.task.dt:g} s in '
                 f'{self.arm.substeps} steps of {self.arm.timestep:.3g} s, '
                 + (f'gravity compensation {"on" if p["gravity_compensation"] else "off"}'
                    if self.interface == 'effort' else
                    f"the {self.interface} motors carry the arm's weight"))

    @property
    def sim_time(self) -> float:
        """Return the simulated time in s."""
        return self.steps * self.task.dt

    def start_episode(self, seed=None):
        """
        Draw a new start and goal, put the arm there, publish the goal and a transition.

        ``seed``: draw from a generator seeded anew (the episodes as at start), not the next.
        """
        if seed is None:
            self.task.reset_env(0)
        else:
            self.task.reset(seed=seed)
        q, qd, _ = self.task.joint_state()
        self.goal = self.task.target_pos()[0]
        self.arm.set_state(q[0], qd[0])
        self.episode_id += 1
        self.episode_step = 0
        stamp = sim_stamp(self.sim_time)
        self.pub_target.publish(PointStamped(
            header=self._header(stamp), point=Point(x=float(self.goal[0]),
                                                    y=float(self.goal[1]),
                                                    z=float(self.goal[2]))))
        obs = self.observe()
        self.publish_transition(obs, 0.0, False, obs)

    def on_reset_world(self, request, response):
        """Start the episodes again as drawn at start (``sim_node``'s ``~/reset_world``)."""
        self.start_episode(seed=self.params['seed'])
        response.success = True
        response.message = f'new episodes [{self.episode_id}]'
        self.get_logger().info(f'~/reset_world called: {response.message}')
        return response

    def _header(self, stamp):
        from std_msgs.msg import Header
        return Header(stamp=stamp, frame_id=TARGET_FRAME)

    def observe(self) -> np.ndarray:
        """Return the observation: the model's, with PyBullet's fingertip-to-target vector."""
        q, qd, _ = self.arm.state()
        obs = self.builder(q[None], qd[None], self.goal[None])[0]
        k = self.task.spec.target_dim
        obs[self.vec] = (self.arm.link_position(*self.tip) - self.goal)[:k]
        return obs

    def on_command(self, msg: Float64MultiArray):
        """Hold a forward controller's command (SI units of the interface) forever."""
        data = np.asarray(msg.data, dtype=float)
        if data.shape != (len(self.joints),) or not np.all(np.isfinite(data)):
            self.get_logger().warning(
                f'dropped a command on {CONTROLLER_COMMANDS} of {data.size} values (need '
                f'{len(self.joints)} finite ones)', throttle_duration_sec=1.0)
            return
        self.held = data

    def on_trajectory(self, msg: JointTrajectory):
        """Take a trajectory as the joint trajectory controller would, or log its rejection."""
        reason = self.follower.receive(jtc_msg.trajectory(msg), self.now())
        if reason is not None:
            self.get_logger().error(f'rejected a trajectory on {CONTROLLER_TRAJECTORY} as a '
                                    f'joint trajectory controller would: {reason}',
                                    throttle_duration_sec=1.0)

    def now(self) -> float:
        """Return the controllers' time (s): the simulated time."""
        return self.sim_time

    def on_tick(self):
        """One control period with the command the controllers hold; publish the results."""
        if self.follower.points is not None:
            timeouts = self.follower.timeouts
            q, qdot, _ = self.arm.state()
            cmd = self.follower.command(self.now(), q, qdot)
            if self.follower.timeouts != timeouts:
                self.get_logger().warning(
                    f'{CONTROLLER_TRAJECTORY}: aborted due to command timeout (jtc_cmd_timeout '
                    f"{self.params['jtc_cmd_timeout']:g} s)")
            if cmd is not None:
                self.held = cmd
        self.arm.step(self.held, mode=self.interface)
        self.steps += 1
        self.episode_step += 1
        ctrl = interfaces.INTERFACES[self.interface].from_si(self.actuators, self.held)
        obs = self.observe()
        dist = float(np.linalg.norm(self.arm.link_position(*self.tip) - self.goal))
        reward = (-self.task.reward_dist_weight * dist
                  - self.task.reward_control_weight * float(np.square(ctrl).sum()))
        stamp = sim_stamp(self.sim_time)
        self.pub_clock.publish(Clock(clock=stamp))
        self.publish_joint_states(stamp)
        done = self.episode_step >= self.task.max_episode_steps
        self.publish_transition(obs, reward, done, obs)
        if done:
            self.start_episode()

    def publish_joint_states(self, stamp):
        """Publish the arm's joint state stamped ``stamp``."""
        pos, vel, eff = self.arm.state()
        self.pub_joints.publish(JointState(
            header=self._header(stamp), name=self.joints, position=float64_field(pos),
            velocity=float64_field(vel), effort=float64_field(eff)))

    def publish_transition(self, obs, reward: float, truncated: bool, final_obs):
        """Publish one transition of the single arm."""
        self.seq += 1
        no = np.zeros(1, dtype=bool)
        self.pub_transition.publish(transition.to_msg(transition.Transition(
            seq=self.seq, obs=obs[None], reward=np.array([reward]), terminated=no,
            truncated=np.array([truncated]), final_obs=final_obs[None],
            episode_id=np.array([self.episode_id]), episode_step=np.array([self.episode_step]))))

    def close(self):
        """Disconnect PyBullet."""
        self.arm.close()


def main(args=None):
    """Run pybullet_node until Ctrl-C or an external shutdown."""
    if params_help('pybullet_node', PYBULLET_PARAMS, args):
        return 0
    return run(PybulletNode, args, cleanup=lambda node: node.close())


if __name__ == '__main__':
    raise SystemExit(main())
