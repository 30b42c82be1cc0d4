"""
sim_node: the simulated arm(s) as a ROS 2 driver would offer them.

The physics and the task are :class:`pg_node.sim.arm_task.ArmTask`; this node only moves data.

Topics published:

* ``/joint_states`` (``sensor_msgs/JointState``), every control step while it has a
  subscriber, one message for all arms: names ``arm<i>/<joint>`` (``<joint>`` the model's
  joint name, ``i`` from 0) for several arms, the plain ``<joint>`` for one (the names of
  ``robot_description``), position (rad), velocity (rad/s), effort (actuator torque, N m),
  stamped with simulated time;
* ``/arm<i>/joint_states`` for each arm ``i`` in ``view_arms`` (default ``0``): the same for
  that arm alone, with plain names, so that ``robot_state_publisher`` can draw it;
* ``/robot_description`` (``std_msgs/String``, reliable, transient local, once at start):
  the arm's URDF (:func:`pg_node.sim.urdf_export.robot_description`: for an imported arm
  the vendor's, the file the model names in ``pg_source_urdf`` relative to its folder;
  else, or with one warning line when that file is missing, one written from the MuJoCo
  model with its kinematics);
* ``/clock`` (``rosgraph_msgs/Clock``): simulated time, ``control steps * dt``, every
  control step while it has a subscriber; it never goes back, not even on a world reset;
* ``/target`` (``geometry_msgs/PointStamped``): one message per arm whenever its target
  changes (episode start) while someone subscribes, and every arm's current target when a
  subscriber joins (on its matched event, or within 0.5 s if that event was lost),
  ``frame_id = 'arm<i>'`` and the point in that arm's own coordinates; reliable,
  transient-local, depth ``num_envs``, so a late subscriber gets the current targets (only
  while someone subscribes: unheard, they set the p99 of the lock-step round trip; the
  figure is in docs/results/PROFILE.md);
* ``/pg_node/transition`` (``std_msgs/Float64MultiArray``): every control step, the layout
  of :mod:`pg_node.ros.transition`; reliable, transient-local, depth ``lock_step_groups``
  (one message per group: a subscriber needs that depth too, or it may keep only the
  last group's message of a step);
* ``/pg_node/markers`` (``visualization_msgs/MarkerArray``) at ``marker_rate`` Hz of wall
  time while it has a subscriber: three markers in ``frame_id`` for all arms, the links
  (``LINE_LIST``, ns ``links``), the fingertips and the targets (``SPHERE_LIST``, ns
  ``fingertips`` and ``targets``); arm ``i`` is drawn shifted by its place on a square
  grid with ``marker_spacing`` between arms (frame ``arm<i>`` is ``frame_id`` shifted so);
* ``/pg_node/scene`` (``visualization_msgs/MarkerArray``) at ``scene_rate`` Hz of wall time
  while it has a subscriber: each arm of ``view_arms`` as ``robot_description`` draws it
  (its geoms at their world poses), its goal, fingertip and the fingertip's trail over the
  last ``trail_length`` control steps of the episode, all in ``frame_id`` with arm ``i``
  shifted as in ``pg_node/markers`` (:mod:`pg_node.sim.scene`, :mod:`pg_node.ros.scene_msg`);
* ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``) at ``diagnostics_rate`` Hz: mode,
  paused, steps, simulated time, steps per second, commands received / dropped (wrong size,
  non-finite, absurd) / clipped / ignored, lock-step timeouts, ``physics_resets`` (arms whose
  physics blew up: their episode ended, the arm reset, a WARN; in real time also
  ``episodes_finished`` and their ``final_distance_mean_m``); in lock-step also the round
  trips since the last diagnostics (a transition published -> the command answering it
  received): how many, median and p99 in ms (``round_trip_log`` keeps every one in a file).

Subscribed: ``pg_node/commands`` (``std_msgs/Float64MultiArray``, as ros2_control's
forward_command_controller): ``num_envs * n_actuators`` values, arm-major (arm 0's
actuators in model order, then arm 1's...), in the policy's control units, or with
``command_interface`` ``effort`` / ``position`` / ``velocity`` in N m / rad / rad/s as a
robot's controller takes them (``policy_node`` sends those, absolute angles even for a
policy of relative targets, :mod:`pg_node.control.position_delta`;
:mod:`pg_node.control.interfaces` maps them back), taken as serialised bytes
(``raw=True``) and decoded into numpy; bytes that do not decode count as a message of
another size. A message of another size, with a non-finite value or with an
absurd one (beyond ``ABSURD_COMMAND``, e.g. 1e300) is dropped, counted and warned about
(at most once a second); other values outside the actuators' control range are clipped to
it, counted (``commands_clipped``) and warned about.
In lock-step every accepted command is a control step, so dropping an absurd command (rather
than clipping it) also keeps the actor's command/outcome pairing intact; and only the command
that answers the current transition is accepted (its layout's tag, :mod:`pg_node.ros.command`):
another publisher's, an untagged one or a late duplicate is ignored and counted
(``commands_ignored``). In real-time mode any valid command is held, tag or not.

In real-time mode with ``command_interface`` ``effort``, ``position`` or ``velocity`` (the
robot's stand-in) it also subscribes ``arm_controller/joint_trajectory``
(``trajectory_msgs/JointTrajectory``, what ``policy_node`` sends by default) and follows it
as Jazzy's joint trajectory controller with zero gains would
(:class:`pg_node.control.jtc.JtcFollower`): each arm's actuated joints, named as in
``/joint_states`` (plain for one arm, ``arm<i>/<joint>`` for several), in N m or rad; a
message JTC rejects is dropped with an error naming the rule (counted
``trajectories_rejected``); an accepted point is applied at its ``time_from_start`` and
held, and ``jtc_cmd_timeout`` s after the last point the controller's hold: zero effort, or
the positions measured then (counted ``trajectory_timeouts``), until the next accepted
message. Once a trajectory was accepted it sets the command, and ``command_timeout`` no
longer applies.

No node subscribes ``joint_states``: it is an output for tools (RViz, Foxglove, the bag);
the simulator takes input only on ``pg_node/commands`` (training's own name, never a real
controller's ``arm_controller/commands``; ``play`` remaps it there, as the robot's stand-in),
on ``arm_controller/joint_trajectory`` as above, and on its services. A command tagged with
another run's token (:mod:`pg_node.ros.command`) is dropped and counted
(``foreign_messages``).

Modes (parameter ``mode``):

* ``lock_step`` (default): each accepted command is one control step, then a transition is
  published; with no command for ``lock_step_timeout`` s the last transition and joint
  state are re-sent (same ``seq`` and stamp) and the wait logged, so neither side hangs on
  a lost message and a late ``/joint_states`` subscriber still sees the arm. With
  ``lock_step_groups`` G > 1 the arms are stepped in G contiguous groups, each with its own
  transition messages (:mod:`pg_node.ros.transition`: group ``g`` has the ``seq`` numbers
  ``k * G + g``) and its own commands (``n_g x n_actuators`` values answering the group's
  transition): the simulator steps one group while the actor answers another. Arms do not
  interact, so this is the same computation as stepping them all at once; ``/clock`` and
  ``/joint_states`` follow the last group;
* ``real_time``: control steps at ``real_time_factor / dt`` Hz of wall time with the last
  command held, zero torque once it is older than ``command_timeout`` s.

Services (names as in mujoco_ros2_control): ``~/reset_world`` (``std_srvs/Trigger``: the
world as it started, every arm re-seeded from ``seed`` and starting its first episode again
under a new id; publishes a transition), ``~/set_pause`` (``std_srvs/SetBool``) and
``~/step_simulation`` (``std_srvs/Trigger``: while paused, one control step with the held
command; refused when not paused). While paused, lock-step commands are held, not stepped.

Topic names other than ``/diagnostics`` are relative: started in a namespace
(``--ros-args -r __ns:=/arm1``) the node publishes ``/arm1/joint_states``,
``/arm1/pg_node/transition``... and listens on ``/arm1/pg_node/commands``, so several
simulator/actor pairs can share one graph; in the root namespace the names are as above.

Parameters: :data:`pg_node.common.params.SIM_PARAMS` (and the shared ``model``, ``num_envs``,
``seed``) list them with their defaults, descriptions and allowed values; the shipped
``config/pg_node.yaml`` holds the same defaults, as a file to copy and edit.
"""
import array
import collections
import math
from pathlib import Path
import time
from typing import Optional

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PointStamped
import numpy as np
from pg_node.bag.ros_types import float64_field
from pg_node.common.bounds import MAX_ABS
from pg_node.common.param_schema import arm_indices, ConfigError
from pg_node.common.params import params_for
from pg_node.common.paths import resolve_model
from pg_node.common.perturbations import from_params
from pg_node.common.run import COMMANDS, CONTROLLER_TRAJECTORY
from pg_node.control import interfaces
from pg_node.control import jtc
from pg_node.control.joint_map import arm_joint_names
from pg_node.control.status import RepeatedWarnings
from pg_node.ros import command
from pg_node.ros import jtc_msg
from pg_node.ros import table_msg
from pg_node.ros import transition
from pg_node.ros.parameters import declare_params
from pg_node.ros.run_protocol import EndWithLearner, RANDOMIZATION, RunGuard
from pg_node.ros.runtime import params_help, run
from pg_node.ros.scene_msg import scene_markers
from pg_node.sim.actuation import actuators
from pg_node.sim.arm_task import arm_groups, ArmTask
from pg_node.sim.scene import Scene
from pg_node.sim.urdf_export import robot_description, UrdfExportError
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

#: A command value beyond this (N m before gear) is not a torque but a bug: dropped, not
#: clipped. Values between the control range and this are clipped (counted, warned).
ABSURD_COMMAND = MAX_ABS


def sim_stamp(seconds: float) -> Time:
    """Return ``seconds`` of simulated time as a ``builtin_interfaces/Time``."""
    nanos = int(round(seconds * 1e9))
    return Time(sec=nanos // 1_000_000_000, nanosec=nanos % 1_000_000_000)


def randomization_msg(task: ArmTask, arms, run: int, sim_seed: int) -> Float64MultiArray:
    """
    Return the drawn terms of ``arms`` as a table: header ``run sim_seed``, then per arm.

    Fields: ``arm``, ``episode_id``, ``episode_step`` (of the episode the values hold for,
    from that step on) and one column per drawn value, labelled as
    :attr:`pg_node.sim.randomization.Randomizer.labels` (``mass/body0``, ``latency``...).
    ``sim_seed`` tells several simulators of one run apart.
    """
    r, arms = task.randomizer, np.asarray(arms)
    fields = {'arm': arms, 'episode_id': task.episode_id[arms],
              'episode_step': task.episode_step[arms]}
    fields.update({label: r.values[arms, c] for c, label in enumerate(r.labels)})
    dims, offset, data = table_msg.pack([run, sim_seed], fields)
    return table_msg.to_msg(dims, offset, data)


class SimNode(Node):
    """Publish simulated arms and step them on torque commands."""

    def __init__(self, **node_options):
        """
        Declare parameters, build the task and the ROS interfaces, publish the start.

        ``node_options`` go to rclpy's ``Node`` (``context``, ``parameter_overrides``: how a
        test runs the node in its own process).
        """
        super().__init__('sim_node', **node_options)
        p = declare_params(self, params_for('sim_node'), self.on_parameter)
        self.mode = p['mode']
        self.task = ArmTask(resolve_model(p['model']), num_envs=p['num_envs'], seed=p['seed'],
                            frame_skip=p['frame_skip'],
                            max_episode_steps=p['max_episode_steps'],
                            reward_dist_weight=p['reward_dist_weight'],
                            reward_control_weight=p['reward_control_weight'],
                            randomization=from_params(p),
                            num_threads=p['physics_threads'] or None,
                            # a robot's stand-in gets absolute angles from policy_node
                            relative_actions=p['command_interface'] == 'control',
                            position_delta=p['position_delta'])
        self.params = p
        self.interface = p['command_interface']
        self.actuators = actuators(self.task.model)
        refused = self.interface != 'control' and interfaces.check(self.actuators,
                                                                   self.interface)
        if refused:
            raise ConfigError(f"parameter 'sim_node.command_interface': {refused}")
        self.run = RunGuard(self, p['run_id'])
        self.end_with_learner = EndWithLearner(self, self.run)   # ros2 run: end with it
        n, spec = self.task.num_envs, self.task.spec
        # one arm: the model's plain names, as robot_description has them; several: arm<i>/
        self.joint_names = arm_joint_names(spec.joint_names, n, plain=n == 1)
        self.view_arms = arm_indices(p['view_arms'])
        if any(i >= n for i in self.view_arms):
            raise ConfigError(f"parameter 'sim_node.view_arms': {p['view_arms']!r} names an arm "
                              f'beyond the {n} simulated (0..{n - 1})')
        self.offsets = self.grid_offsets(p['marker_spacing'])
        self.counters = {'steps': 0, 'commands_received': 0, 'commands_dropped_size': 0,
                         'commands_dropped_nonfinite': 0, 'commands_dropped_absurd': 0,
                         'commands_clipped': 0, 'commands_ignored': 0,
                         'lock_step_timeouts': 0, 'transitions_resent': 0,
                         'trajectories_received': 0, 'trajectories_rejected': 0,
                         'trajectory_timeouts': 0, 'episodes_finished': 0,
                         'physics_resets': 0}
        self.repeated = RepeatedWarnings(period=30.0)   # a warning, then once in 30 s
        self.distance_sum = 0.0           # the final distances of the finished episodes
        self.paused = bool(p['start_paused'])
        self.held = np.zeros((n, self.task.act_dim))
        self.held_time = -math.inf
        # at most one group per arm; real time steps every arm on each tick: one group
        self.groups = arm_groups(n, min(p['lock_step_groups'], n)
                                 if self.mode == 'lock_step' else 1)
        self.group_seq = [-1] * len(self.groups)       # seq of its current transition
        self.last_transitions = [None] * len(self.groups)
        self.last_sent = time.monotonic()
        # lock-step round trips (ns): each group's transition out -> the answer in
        self.sent_ns = [None] * len(self.groups)
        self.trips = collections.deque(maxlen=100_000)     # since the last diagnostics
        self.trip_log = array.array('q') if p['round_trip_log'] else None
        self._diag_steps, self._diag_time = 0, time.monotonic()

        # one transition per group kept: a group's message must not push out another's
        reliable_latched = QoSProfile(depth=len(self.groups),
                                      reliability=ReliabilityPolicy.RELIABLE,
                                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.target_readers = 0
        targets_qos = QoSProfile(depth=n, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_joints = self.create_publisher(JointState, 'joint_states', 10)
        # per shown arm, plain names: what robot_state_publisher takes with robot_description
        self.pub_arm_joints = {i: self.create_publisher(JointState, f'arm{i}/joint_states', 10)
                               for i in self.view_arms}
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_description = self.create_publisher(String, 'robot_description', latched)
        try:
            description = robot_description(self.task.model, self.task.model_path)
            self.pub_description.publish(String(data=description.urdf))
            if description.problem:
                self.get_logger().warning(f'robot_description {description.origin}: '
                                          f'{description.problem}')
            else:
                self.get_logger().info(f'robot_description: {description.origin}')
        except UrdfExportError as exc:          # the arm trains; ROS tools lack its URDF
            self.get_logger().warning(f'no robot_description: {exc}')
        self.pub_clock = self.create_publisher(Clock, 'clock', 10)
        self.pub_target = self.create_publisher(
            PointStamped, 'target', targets_qos,
            event_callbacks=PublisherEventCallbacks(matched=self.on_target_matched))
        self.pub_transition = self.create_publisher(Float64MultiArray, 'pg_node/transition',
                                                    reliable_latched)
        self.pub_markers = self.create_publisher(MarkerArray, 'pg_node/markers', 1)
        # the view_arms as robot_description shows them, in frame_id (pg_node.sim.scene)
        self.scene = Scene(self.task.model, self.view_arms, self.offsets, p['trail_length'])
        self.scene_watched = False      # the trail is recorded only while someone watches
        self.pub_scene = self.create_publisher(MarkerArray, 'pg_node/scene', 1)
        self.pub_draws = None
        if self.task.randomizer is not None:
            # every arm's drawn terms when they change (the learner writes them to the bag)
            self.pub_draws = self.create_publisher(
                Float64MultiArray, self.run.topic(RANDOMIZATION),
                QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.sub_cmd = self.create_subscription(Float64MultiArray, COMMANDS, self.on_command, 10,
                                                raw=True)
        self.follower = None
        if self.mode == 'real_time' and self.interface in jtc.FOLLOWED_FIELD:
            # the robot's joint trajectory controller (pg_node.control.jtc): its joints are
            # each arm's actuated joints, in actuator order
            self.actuated = [spec.joint_names.index(j) for j in self.actuators.joints]
            self.follower = jtc.JtcFollower(
                arm_joint_names(self.actuators.joints, n, plain=n == 1),
                self.interface, p['jtc_cmd_timeout'], flags=jtc.stand_in_flags(
                    self.interface, p['jtc_d_gain']), d=[p['jtc_d_gain']])
            self.create_subscription(JointTrajectory, CONTROLLER_TRAJECTORY,
                                     self.on_trajectory, 10)
        self.create_service(Trigger, '~/reset_world', self.on_reset_world)
        self.create_service(SetBool, '~/set_pause', self.on_set_pause)
        self.create_service(Trigger, '~/step_simulation', self.on_step_simulation)
        self.timers_by_param = {
            'marker_rate': self.create_timer(1.0, self.publish_markers),
            'scene_rate': self.create_timer(1.0, self.publish_scene),
            'diagnostics_rate': self.create_timer(1.0, self.publish_diagnostics)}
        if self.mode == 'real_time':
            self.timers_by_param['real_time_factor'] = self.create_timer(
                1.0, self.on_real_time_tick)
        else:
            self.timers_by_param['lock_step_timeout'] = self.create_timer(
                1.0, self.on_lock_step_watch)
        for name in self.timers_by_param:
            self.on_parameter(name, p[name])
        self.create_timer(0.5, self.watch_target_readers)

        self.publish_reset(self.task.reset())
        self.get_logger().info(
            f'{self.mode}: {n} x {p["model"]} ({self.task.act_dim} actuators, joints '
            f'{", ".join(spec.joint_names)}), dt {self.task.dt:g} s, seed {p["seed"]}')
        if self.task.randomizer is not None:
            self.get_logger().info('randomized per arm: ' + ', '.join(
                f'{t} {v.text()}' for t, v in self.task.randomizer.terms.items()))

    def grid_offsets(self, spacing: float) -> np.ndarray:
        """Return where each arm is drawn: a square grid ``spacing`` apart."""
        n = self.task.num_envs
        cols = math.ceil(math.sqrt(n))
        return np.array([[(i % cols) * spacing, (i // cols) * spacing, 0.0] for i in range(n)])

    def on_parameter(self, name: str, value) -> None:
        """Apply a live parameter: the timers' periods and the marker grid follow it."""
        periods = {'marker_rate': lambda v: 1.0 / v if v > 0 else None,
                   'scene_rate': lambda v: 1.0 / v if v > 0 else None,
                   'diagnostics_rate': lambda v: 1.0 / v,
                   'real_time_factor': lambda v: self.task.dt / v,
                   'lock_step_timeout': lambda v: min(0.1, v / 2)}
        if name == 'marker_spacing':
            self.offsets = self.grid_offsets(value)
            if hasattr(self, 'scene'):
                self.scene.offsets = self.offsets
        timer = self.timers_by_param.get(name)
        if timer is not None:
            period = periods[name](value)
            if period is None:
                timer.cancel()
            else:
                timer.timer_period_ns = int(period * 1e9)
                timer.reset()

    @property
    def sim_time(self) -> float:
        """Return the simulated time in seconds (control steps times dt)."""
        return self.counters['steps'] * self.task.dt

    # --- commands -------------------------------------------------------------------------

    def on_command(self, msg):
        """
        Check, clip and hold a torque command; in lock-step, take one control step.

        ``msg``: the subscription's serialised bytes (``raw=True``: decoded straight into
        numpy, :func:`pg_node.ros.table_msg.from_cdr`) or a ``Float64MultiArray``.
        """
        arrived = time.perf_counter_ns()
        self.counters['commands_received'] += 1
        if isinstance(msg, bytes):
            try:
                msg = table_msg.from_cdr(msg)
            except ValueError as exc:
                self.counters['commands_dropped_size'] += 1
                self.get_logger().warning(f'dropped a command: {exc}',
                                          throttle_duration_sec=1.0)
                return
        cmd = np.asarray(msg.data, dtype=np.float64)
        g, arms = None, slice(0, self.task.num_envs)
        answers = command.transition_of(msg)
        # an actor's command (tagged) of another run: never a control step, in any mode
        if answers is not None and self.run.foreign(command.run_of(msg), COMMANDS):
            return
        if self.mode == 'lock_step':
            # the group whose transition it answers (seq k * G + g); untagged: all arms
            if answers is not None:
                g = answers % len(self.groups)
                arms = self.groups[g]
        n_arms = arms.stop - arms.start
        if cmd.size != n_arms * self.task.act_dim:
            self.counters['commands_dropped_size'] += 1
            group = f' of group {g}' if g is not None and len(self.groups) > 1 else ''
            self.get_logger().warning(
                f'dropped a command of {cmd.size} values, expected '
                f'{n_arms * self.task.act_dim} ({n_arms} arms{group} x {self.task.act_dim} '
                'actuators)', throttle_duration_sec=1.0)
            return
        if not np.all(np.isfinite(cmd)):
            self.counters['commands_dropped_nonfinite'] += 1
            self.get_logger().warning('dropped a command with a non-finite value',
                                      throttle_duration_sec=1.0)
            return
        if np.any(np.abs(cmd) > ABSURD_COMMAND):
            self.counters['commands_dropped_absurd'] += 1
            self.get_logger().warning(
                f'dropped a command with an absurd value ({np.abs(cmd).max():g}, more than '
                f'{ABSURD_COMMAND:g}): a bug upstream, not a torque to clip',
                throttle_duration_sec=1.0)
            return
        if self.mode == 'lock_step' and (g is None or answers != self.group_seq[g]):
            # lock-step takes one step per answer to its current transition: a command
            # of another publisher, or a late duplicate, must not step it out of turn
            self.counters['commands_ignored'] += 1
            at = ', '.join(map(str, self.group_seq))
            self.get_logger().warning(
                f'ignored a command for transition {answers} (lock-step, at transition '
                f'{at}): only the answer to the current transition steps it',
                throttle_duration_sec=1.0)
            return
        if g is not None and self.sent_ns[g] is not None:
            trip = arrived - self.sent_ns[g]
            self.trips.append(trip)
            if self.trip_log is not None:
                self.trip_log.append(trip)
            self.sent_ns[g] = None
        cmd = cmd.reshape(n_arms, self.task.act_dim)
        if self.interface != 'control':       # the robot's stand-in: N m or rad in
            cmd = interfaces.INTERFACES[self.interface].from_si(self.actuators, cmd)
        clipped = np.clip(cmd, self.task.spec.ctrl_low, self.task.spec.ctrl_high)
        if not np.array_equal(clipped, cmd):
            self.counters['commands_clipped'] += 1
            self.get_logger().warning(
                f'clipped a command to the control range [{self.task.spec.ctrl_low.min():g}, '
                f'{self.task.spec.ctrl_high.max():g}] (largest value {np.abs(cmd).max():g})',
                throttle_duration_sec=1.0)
        self.held[arms] = clipped
        self.held_time = time.monotonic()
        if self.mode == 'lock_step' and not self.paused:
            self.step_group(g)

    def on_trajectory(self, msg: JointTrajectory):
        """Take a trajectory as the joint trajectory controller would, or log its rejection."""
        self.counters['trajectories_received'] += 1
        reason = self.follower.receive(jtc_msg.trajectory(msg), self.clock_seconds())
        if reason is not None:
            self.counters['trajectories_rejected'] += 1
            self.get_logger().error(f'rejected a trajectory on {CONTROLLER_TRAJECTORY} as a '
                                    f'joint trajectory controller would: {reason}',
                                    throttle_duration_sec=1.0)

    def clock_seconds(self) -> float:
        """Return the node's clock in s: the trajectory controller's time."""
        return self.get_clock().now().nanoseconds * 1e-9

    def on_real_time_tick(self):
        """
        Take one control step with the held command, or zero torque if it is stale.

        Once the trajectory input took a message, its controller sets the command instead
        (held, and JTC's hold after ``jtc_cmd_timeout``).
        """
        if self.paused:
            return
        if self.follower is not None and self.follower.points is not None:
            self.follow_trajectory()
        elif time.monotonic() - self.held_time > self.params['command_timeout']:
            self.held = np.zeros_like(self.held)
        self.control_step(self.held)

    def follow_trajectory(self):
        """Hold the trajectory controller's command (SI, joint order) as controls."""
        timeouts = self.follower.timeouts
        q, qdot, _ = self.task.joint_state()
        measured = q.reshape(self.task.num_envs, -1)[:, self.actuated].ravel()
        speeds = qdot.reshape(self.task.num_envs, -1)[:, self.actuated].ravel()
        si = self.follower.command(self.clock_seconds(), measured, speeds)
        if self.follower.timeouts != timeouts:
            self.counters['trajectory_timeouts'] += 1
            self.get_logger().warning(
                f'{CONTROLLER_TRAJECTORY}: aborted due to command timeout (no '
                f"trajectory for jtc_cmd_timeout {self.params['jtc_cmd_timeout']:g} s): "
                + {'effort': 'zero effort', 'velocity': 'zero velocity'}.get(
                    self.interface, 'holding the positions measured now'))
        if si is not None:
            ctrl = interfaces.INTERFACES[self.interface].from_si(
                self.actuators, si.reshape(self.task.num_envs, -1))
            self.held = np.clip(ctrl, self.task.spec.ctrl_low, self.task.spec.ctrl_high)

    def on_lock_step_watch(self):
        """Re-send the last transition when no command came for ``lock_step_timeout``."""
        if self.paused or self.last_transitions[0] is None:
            return
        waited = time.monotonic() - self.last_sent
        if waited >= self.params['lock_step_timeout']:
            self.counters['lock_step_timeouts'] += 1
            self.get_logger().info(
                f'no command for {waited:.1f} s, re-sending transition '
                f'{", ".join(map(str, self.group_seq))}', throttle_duration_sec=10.0)
            for g, msg in enumerate(self.last_transitions):
                self.sent_ns[g] = time.perf_counter_ns()       # its round trip starts again
                self.pub_transition.publish(msg)
                self.counters['transitions_resent'] += 1
            self.publish_joint_states(sim_stamp(self.sim_time))
            self.last_sent = time.monotonic()

    # --- stepping and publishing ----------------------------------------------------------

    def control_step(self, act: np.ndarray):
        """Step every arm once with ``act`` (``(N, n_actuators)``), group by group."""
        self.held = act
        for g in range(len(self.groups)):
            self.step_group(g)

    def step_group(self, g: int):
        """Step group ``g``'s arms once with their held command and publish the results."""
        arms = self.groups[g]
        obs, reward, terminated, truncated, info = self.task.step(self.held[arms], arms)
        if info['blown_up'].any():
            self.count_blow_ups(arms, info['blown_up'])
        if self.mode == 'real_time':
            self.log_episodes(arms, terminated | truncated, info)
        last = g == len(self.groups) - 1
        if last:
            self.counters['steps'] += 1      # a control step: every group has stepped
            if self.scene_watched:
                self.scene.record(self.task.datas, self.task.episode_step)
        self.publish_state(g, self.group_transition(g, obs, reward, terminated, truncated,
                                                    info['final_obs']), last)
        self.publish_draws()

    def count_blow_ups(self, arms: slice, blown: np.ndarray):
        """Count and report arms whose physics blew up (ArmTask ended and reset them)."""
        self.counters['physics_resets'] += int(blown.sum())
        first = arms.start + int(np.flatnonzero(blown)[0])
        line = self.repeated.line('physics', (
            f'the physics of arm {first} blew up (an observation beyond {MAX_ABS:g}, or '
            'MuJoCo reset a state it found unstable): its episode ended and the arm was '
            'reset; a model whose arms keep doing this needs a smaller timestep, armature or '
            'hard limits (arm import checks them)'), time.monotonic())
        if line:
            self.get_logger().warning(f"{line} [{self.counters['physics_resets']} so far]")

    def log_episodes(self, arms: slice, ended: np.ndarray, info: dict):
        """
        Log each episode that ended, with its final fingertip distance; count them.

        In real time sim_node stands in for a robot and nobody trains: this is how well the
        policy driving it reaches (in m, as node logs are; diagnostics keep the mean).
        """
        for i in np.flatnonzero(ended):
            distance = float(info['distance'][i])
            self.counters['episodes_finished'] += 1
            self.distance_sum += distance
            self.get_logger().info(
                f'episode {int(info["final_episode_id"][i])} (arm {arms.start + i}): final '
                f'fingertip distance {distance:.4f} m')

    def publish_draws(self):
        """Publish the terms the arms drew since the last call, one row per arm."""
        if self.pub_draws is None:
            return
        arms = self.task.randomizer.take_drawn()
        if arms:
            self.pub_draws.publish(randomization_msg(self.task, arms, self.run.token,
                                                     self.params['seed']))

    def group_transition(self, g: int, obs, reward, terminated, truncated,
                         final_obs) -> transition.Transition:
        """Return group ``g``'s next transition, numbered and tagged with its episodes."""
        arms = self.groups[g]
        return transition.Transition(
            seq=self.next_seq(g), obs=obs, reward=reward, terminated=terminated,
            truncated=truncated, final_obs=final_obs,
            episode_id=self.task.episode_id[arms].copy(),
            episode_step=self.task.episode_step[arms].copy(), first_arm=arms.start,
            groups=len(self.groups), run=self.run.token)

    def next_seq(self, g: int) -> int:
        """Return the seq of group ``g``'s next message: ``k * G + g`` for its ``k``-th."""
        seq = self.group_seq[g] + len(self.groups) if self.group_seq[g] >= 0 else g
        self.group_seq[g] = seq
        return seq

    @property
    def seq(self) -> int:
        """Return the latest seq any group published (-1 before the first)."""
        return max(self.group_seq)

    def publish_reset(self, obs: np.ndarray):
        """Publish the transitions announcing fresh episodes in every arm (``obs``)."""
        for g, arms in enumerate(self.groups):
            k = arms.stop - arms.start
            no = np.zeros(k, dtype=bool)
            tr = self.group_transition(g, obs[arms], np.zeros(k), no, no, obs[arms])
            self.publish_state(g, tr, g == len(self.groups) - 1)
        self.publish_draws()

    def publish_state(self, g: int, tr: transition.Transition, last: bool = True):
        """
        Publish group ``g``'s transition ``tr``, its new targets, and clock and joint states.

        The transition goes first: in lock-step it is what the actor waits for, so the
        other messages are built while the actor answers. ``/clock`` and ``/joint_states``
        go out once all groups have stepped (``last``), and only when someone subscribes
        them (no subscriber sees the difference; in training nobody does, the learner
        records joint states from its batches); so do new targets (a subscriber that
        joins gets them all from :meth:`on_target_matched`).
        """
        self.last_transitions[g] = transition.to_cdr(tr)   # bytes: publish sends them as is
        self.sent_ns[g] = time.perf_counter_ns()
        self.pub_transition.publish(self.last_transitions[g])
        self.last_sent = time.monotonic()
        stamp = sim_stamp(self.sim_time)
        if last and self.pub_clock.get_subscription_count():
            self.pub_clock.publish(Clock(clock=stamp))
        if last:
            self.publish_joint_states(stamp)
        if not self.watch_target_readers(stamp) and self.target_readers:
            new = np.flatnonzero(tr.episode_step == 0)
            if new.size:
                self.publish_targets(tr.first_arm + new, stamp)

    def publish_targets(self, arms: np.ndarray, stamp: Time):
        """Publish the current target of each of ``arms``, stamped ``stamp``."""
        targets = self.task.target_pos()
        for i in arms:
            point = PointStamped()
            point.header.stamp = stamp
            point.header.frame_id = f'arm{i}'
            point.point = Point(x=float(targets[i, 0]), y=float(targets[i, 1]),
                                z=float(targets[i, 2]))
            self.pub_target.publish(point)

    def on_target_matched(self, info):
        """
        Give a subscriber that joins ``/target`` every arm's current target.

        A join shows as more subscribers than the node last saw or, if one left and another
        joined in between, as a positive ``current_count_change``; the first event can come
        with a change of 0 (Fast DDS counted the match while the publisher was being made,
        before the event was listened for), so the count decides too.
        """
        if info.current_count > self.target_readers or info.current_count_change > 0:
            self.publish_targets(np.arange(self.task.num_envs), sim_stamp(self.sim_time))
        self.target_readers = info.current_count

    def watch_target_readers(self, stamp: Optional[Time] = None) -> bool:
        """
        Give new ``/target`` subscribers the current targets if no matched event did.

        A middleware need not report a match that happened before the executor listened for
        its events (rmw_zenoh did not, ros2/rmw_zenoh#586); every control step compares the
        subscriber count too, and a timer does it while the simulation waits (paused, or
        no command in lock-step). Returns whether every target was published.
        """
        readers = self.pub_target.get_subscription_count()
        joined = readers > self.target_readers
        if joined:
            self.publish_targets(np.arange(self.task.num_envs),
                                 stamp if stamp is not None else sim_stamp(self.sim_time))
        self.target_readers = readers
        return joined

    def publish_joint_states(self, stamp: Time):
        """Publish the joint states, combined and per shown arm, where someone subscribes."""
        if self.pub_joints.get_subscription_count():
            self.pub_joints.publish(self.joint_state_msg(stamp))
        readers = [i for i, pub in self.pub_arm_joints.items() if pub.get_subscription_count()]
        if readers:
            pos, vel, eff = self.task.joint_state()
            for i in readers:
                js = JointState(name=list(self.task.spec.joint_names))
                js.header.stamp = stamp
                js.position = float64_field(pos[i])
                js.velocity = float64_field(vel[i])
                js.effort = float64_field(eff[i])
                self.pub_arm_joints[i].publish(js)

    def joint_state_msg(self, stamp: Time) -> JointState:
        """Return every arm's joint state as one ``JointState`` stamped ``stamp``."""
        pos, vel, eff = self.task.joint_state()
        js = JointState()
        js.header.stamp = stamp
        js.name = self.joint_names
        js.position = float64_field(pos)
        js.velocity = float64_field(vel)
        js.effort = float64_field(eff)
        return js

    def publish_markers(self):
        """
        Publish links, fingertips and targets of all arms as three list markers.

        One ``LINE_LIST`` holds every arm's links and one ``SPHERE_LIST`` each the fingertips
        and the targets, each arm shifted by its grid offset: three markers whatever the
        number of arms (single markers per arm were once the simulator's largest cost:
        docs/results/PROFILE.md, "Measurements and incidents behind code choices").
        """
        if not self.pub_markers.get_subscription_count():
            return                      # nobody draws them: do not spend the time
        stamp = sim_stamp(self.sim_time)
        n = self.task.num_envs
        links = self.task.link_positions().reshape(n, -1, 3) + self.offsets[:, None, :]
        tips = self.task.fingertip_pos() + self.offsets
        targets = self.task.target_pos() + self.offsets
        out = MarkerArray()
        for ns, kind, rgb, size, points in (
                ('links', Marker.LINE_LIST, (0.0, 0.4, 0.6), 0.02, links.reshape(-1, 3)),
                ('fingertips', Marker.SPHERE_LIST, (0.0, 0.8, 0.6), 0.025, tips),
                ('targets', Marker.SPHERE_LIST, (0.9, 0.2, 0.2), 0.025, targets)):
            marker = self._marker(stamp, ns, 0, kind, rgb, size)
            marker.points = [Point(x=x, y=y, z=z) for x, y, z in points.tolist()]
            out.markers.append(marker)
        self.pub_markers.publish(out)

    def publish_scene(self):
        """Publish the view_arms' links, goals and fingertip trails while someone watches."""
        self.scene_watched = bool(self.pub_scene.get_subscription_count())
        if self.scene_watched:
            self.pub_scene.publish(scene_markers(self.scene.views(self.task.datas),
                                                 sim_stamp(self.sim_time),
                                                 self.params['frame_id']))

    def _marker(self, stamp, ns: str, i: int, kind: int, rgb, size: float) -> Marker:
        """Return a marker with the common fields filled in."""
        marker = Marker()
        marker.header.stamp = stamp
        marker.header.frame_id = self.params['frame_id']
        marker.ns = ns
        marker.id = i
        marker.type = kind
        marker.action = Marker.ADD
        marker.pose.orientation.w = 1.0
        marker.scale.x = marker.scale.y = marker.scale.z = size
        marker.color.r, marker.color.g, marker.color.b = rgb
        marker.color.a = 1.0
        return marker

    def publish_diagnostics(self):
        """Publish the counters as one DiagnosticStatus."""
        now = time.monotonic()
        rate = (self.counters['steps'] - self._diag_steps) / max(now - self._diag_time, 1e-9)
        self._diag_steps, self._diag_time = self.counters['steps'], now
        dropped = (self.counters['commands_dropped_size']
                   + self.counters['commands_dropped_nonfinite']
                   + self.counters['commands_dropped_absurd'])
        status = DiagnosticStatus()
        status.name = 'sim_node: simulated arms'
        status.hardware_id = f'{self.params["model"]} x {self.task.num_envs}'
        blown = self.counters['physics_resets']
        status.level = DiagnosticStatus.WARN if dropped or blown else DiagnosticStatus.OK
        status.message = ('paused' if self.paused else self.mode) + (
            f', {dropped} commands dropped' if dropped else '') + (
            f', {blown} arms reset after their physics blew up' if blown else '')
        values = dict(self.counters, foreign_messages=self.run.dropped, run_id=self.run.run_id,
                      mode=self.mode, paused=self.paused,
                      sim_time=round(self.sim_time, 6), steps_per_second=round(rate, 1),
                      num_envs=self.task.num_envs)
        if self.mode == 'real_time':
            done = self.counters['episodes_finished']
            values['final_distance_mean_m'] = round(self.distance_sum / done, 5) if done else '-'
        if self.mode == 'lock_step':
            # the round trips since the last diagnostics (none while paused or waiting)
            ms = np.asarray(self.trips, dtype=np.float64) / 1e6
            self.trips.clear()
            values['round_trips'] = ms.size
            values['round_trip_ms_median'] = round(float(np.median(ms)), 3) if ms.size else '-'
            values['round_trip_ms_p99'] = (round(float(np.percentile(ms, 99)), 3)
                                           if ms.size else '-')
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status]
        self.pub_diag.publish(msg)

    # --- services -------------------------------------------------------------------------

    def on_reset_world(self, request, response):
        """
        Put the world back as it started and publish it (logged: it cuts episodes short).

        Every arm is re-seeded from ``seed``, as at start: it starts again the episodes it
        started with (their ids go on counting), as mujoco_ros2_control's ``reset_world``
        goes back to the initial keyframe. ``play`` calls it once the policy commands, so
        that the same ``--seed`` plays the same episodes however long the policy took.
        """
        self.publish_reset(self.task.reset(seed=self.params['seed']))
        response.success = True
        response.message = f'new episodes {self.task.episode_id.tolist()}'
        self.get_logger().info(f'~/reset_world called: {response.message}')
        return response

    def on_set_pause(self, request, response):
        """Pause (``data=True``) or resume the simulation (logged)."""
        self.paused = bool(request.data)
        response.success = True
        response.message = 'paused' if self.paused else 'running'
        self.get_logger().info(f'~/set_pause called: {response.message}')
        return response

    def on_step_simulation(self, request, response):
        """Take one control step with the held command while paused."""
        if not self.paused:
            response.success = False
            response.message = 'not paused: pause with ~/set_pause first'
            return response
        self.control_step(self.held)
        response.success = True
        response.message = f'stepped to seq {self.seq}'
        return response

    def close(self):
        """Stop the stepping threads; write the round trips if ``round_trip_log`` asks."""
        self.task.close()
        if self.trip_log is None:
            return
        path = self.params['round_trip_log']
        try:
            np.save(Path(path).expanduser(), np.frombuffer(self.trip_log, dtype=np.int64))
        except OSError as exc:
            self.get_logger().error(f'could not write the round trips to {path}: {exc}')
            return
        self.get_logger().info(f'{len(self.trip_log)} lock-step round trips written to {path}')


def main(args=None):
    """Run sim_node until Ctrl-C or an external shutdown."""
    if params_help('sim_node', params_for('sim_node'), args):
        return 0
    return run(SimNode, args, cleanup=lambda node: node.close())


if __name__ == '__main__':
    raise SystemExit(main())
