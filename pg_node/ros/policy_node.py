"""
policy_node: a trained policy commanding arms in real time, with a robot's safety habits.

The policy (parameter ``policy``: a run directory, its ``checkpoints/``, a ``ckpt_*.pt`` file
or an exported ``.onnx`` file with its card, :mod:`pg_node.rl.trained_policy`) brings its
card: the arm model, its joint names, the observation layout, the control range and step.
An exported policy runs on onnxruntime: torch is then never imported.

**Lifecycle** (a managed node, as Nav2's and ros2_control's): it starts *unconfigured*.

* ``configure`` loads the policy, warms it up, waits up to ``configure_timeout`` s for the
  first joint state (and ``robot_description`` with ``require_robot_description``), checks
  its joint names, the kinematics (:mod:`pg_node.sim.kinematics_check`, within
  ``kinematics_tolerance``) when ``robot_description`` (``std_msgs/String``, transient
  local, as robot_state_publisher offers it) was received, and the controller's ``joints``
  parameter against the commanded joints (:mod:`pg_node.control.joint_map`; read from
  ``<controller_name>/get_parameters`` within ``controller_timeout``, else one warning); it
  opens the ``record``; a failure is logged in one line and the node stays unconfigured;
* ``activate`` starts commanding, ramping in from the hold command over ``ramp_time`` s;
* ``deactivate`` sends one hold command (zero effort, or the last commanded angles) and stops
  publishing;
* ``cleanup`` unloads the policy; ``shutdown`` (and SIGINT/SIGTERM) holds once if active.

``autostart:=true`` configures and activates at start (what ``play`` does; a failure is then
one line and exit code 2): the same configure, with the same waits and checks.

Subscribed:

* ``joint_states`` (``sensor_msgs/JointState``, best effort, so any publisher matches):
  matched by name to the model's arm joints, in any order, other joints ignored; one arm
  with the plain names (``joint0``) or several with ``arm<i>/`` prefixes, as ``sim_node``
  publishes them (``num_arms`` 0 takes as many arms as the first message holds;
  :mod:`pg_node.control.joint_map`). Position
  and velocity are needed; a message with a non-finite one is dropped and counted. A model
  joint missing from the message is an error that stops the node (exit code 2, one line);
* ``target`` (``geometry_msgs/PointStamped``, reliable; two subscriptions, transient local
  for a latched publisher such as ``sim_node`` and volatile for ``ros2 topic pub`` and
  RViz, a message through both counted once, :class:`pg_node.control.targets.Twins`): the
  goal, in the arm's base frame: ``frame_id`` ``base_frame`` or empty
  (every arm), or ``arm<i>`` (``sim_node``'s frame of arm ``i``'s base). Choose among
  robots by namespace (``-r __ns:=/left``), not by frame. Another frame goes through tf2
  where ``tf2_ros`` can be imported (a full ROS install; it is not on PyPI); otherwise it
  is refused, with one warning naming it. A target beyond the arm's reach
  (:meth:`pg_node.sim.observation.ObservationBuilder.reach`) is clamped onto it
  (:mod:`pg_node.control.targets`), with a warning once; then one outside the goals the
  policy trained on (its model's region or goal points,
  :class:`pg_node.control.targets.GoalSet`) is moved onto the nearest of them (one under
  the table is taken nowhere near it), with a warning once per spell of such targets, said
  in the reach's line where that one is beyond the reach too; a non-finite one is ignored,
  with a warning once (counted in ``/diagnostics``:
  ``targets_out_of_reach``, ``targets_clamped_to_trained``, ``targets_ignored``);
* ``estop`` (``std_msgs/Bool``, reliable): ``true`` latches an emergency stop; ``false``
  does not clear it. Service ``~/reset_estop`` (``std_srvs/Trigger``) clears it.
* the robot's own state, off by default: ``robot_program_running_topic``
  (``std_msgs/Bool``, transient local, as a UR's ``io_and_status_controller`` latches it)
  and ``speed_scaling_topic`` (``std_msgs/Float64`` in percent, best effort, as its
  ``speed_scaling_state_broadcaster`` sends it). A program not running, a speed scaling of
  0 (a protective stop, a pause) or no message yet on a followed topic holds at every tick
  (:class:`pg_node.control.deployment.RobotState`, state ``robot_stopped``, a warning and
  ``robot_stops`` once per spell); when the robot runs again, commanding ramps in from the
  hold over ``ramp_time``, so a stored command never runs at once.

Published:

* ``arm_controller/joint_trajectory`` (``trajectory_msgs/JointTrajectory``, the default
  ``command_message:=trajectory``), from a timer at ``control_rate`` Hz of steady time (0:
  one per control step of the policy), in SI units (REP-103), ``command_interface``
  ``effort`` (N m, from the model's gear: motor actuators), ``position`` (rad, from the
  joint range: position actuators; a card with ``max_position_delta`` makes the action a
  change around the measured angle, :mod:`pg_node.control.position_delta`) or
  ``velocity`` (rad/s: velocity actuators), :mod:`pg_node.control.interfaces`: each command as the
  message Jazzy's joint trajectory controller accepts and applies at once (stamp 0, one
  point at ``time_from_start`` 0; effort: the torques with the measured angles as
  positions and no velocities; position: the angles alone; velocity: the speeds with the
  measured angles as positions; :mod:`pg_node.control.composers`,
  the controller's rules :mod:`pg_node.control.jtc`). The controller holds each point until
  the next, and ``cmd_timeout`` after the last one its own hold (zero effort, or the angles
  measured then): the stop that holds if this node dies. ``command_message:=forward`` sends
  ``std_msgs/Float64MultiArray`` on ``arm_controller/commands`` instead (arms x actuators,
  arm-major, untagged: what ros2_control's forward command controllers take), which a
  forward controller applies until the next one, **forever** if this node dies. Each
  command is the policy's mean action
  (``deterministic``; else a sample) for the observation built as training builds it
  (:class:`pg_node.sim.observation.ObservationBuilder`), through the guards of
  :class:`pg_node.control.guards.CommandGuard`: control range, ramp, low-pass ``smoothing``,
  ``max_change`` per tick, the braking joint-limit guard (``joint_limit_margin``,
  ``max_deceleration``), ``max_velocity`` (at 0 from the model: the values taken are in
  ``/diagnostics``). No command is ever non-finite or out of range;
* ``/diagnostics`` (status ``<full node name>: trained policy``, one per robot's namespace):
  lifecycle and state (commanding, or why not), achieved command rate,
  the age of the joint state each command was computed from (median and p99), stale
  events, e-stops, each guard's acting, dropped states, CPU share, the policy's source and
  sha256;
* ``~/markers`` (``visualization_msgs/MarkerArray``) at ``marker_rate`` Hz while it has a
  subscriber: the goal the policy acts on (clamped), the goal as requested while it is
  clamped, and the fingertip, coloured by what the node does, holds included
  (:mod:`pg_node.ros.policy_markers`).

Safety: the **hold** command is an active stop (:mod:`pg_node.control.guards`): with the
effort interface a braking torque ``-M(q) qdot / (4 T)`` (the arm's inertia at the measured
pose: a quarter of every joint's speed off per control period ``T``; ``-hold_damping x qdot``
where that is given; and ``hold_stiffness`` back to where the hold began) from the newest
joint state at every tick, with the position interface
the last commanded angles (never a stale measured one), with the velocity interface zero
velocity. When the newest joint state is older
than ``state_timeout`` s, since it arrived or by its ``header.stamp`` (the node's clock: give
``use_sim_time:=true`` with a simulator; :mod:`pg_node.control.watchdog`), the hold command
is published at every control tick (never one message only: a forward command controller
holds the last command it got), its damping fading to zero torque over one more
``state_timeout`` (a stale velocity is no measure of the arm's), and a warning logged once
per stale spell; commanding resumes with the next fresh joint state, ramping in from the hold
over ``ramp_time``. A latched e-stop holds at every tick too, and its reset ramps in the
same way. The one hold left in force on deactivate or a stop is zero torque (a damping
torque from one velocity, kept forever by a forward controller, would push the arm) or the
last commanded angles. Before the first joint state and target nothing is published.
Diagnostics levels follow diagnostic_updater's habits (:mod:`pg_node.control.status`):
commanding OK; unconfigured, inactive or waiting WARN; commanding with no subscriber on the
command topic (no controller can listen; a subscriber does not prove an active one) or with
the controller's joints unread WARN; the robot's own stop WARN; stale states or a latched
e-stop ERROR.

``record`` (a bag directory) keeps every tick on ``/policy_node/ticks`` (a table per tick,
:mod:`pg_node.ros.table_msg`: header stamp and policy id, the first 48 bits of the policy's
sha256; per arm the state's age, observation, mean, action, guarded command and the command
in SI units; a hold tick has NaN for the observation, mean and action, and for the state
age unless stale states made it a hold); the bag's metadata holds the policy's full sha256.

Each tick's decision (the guarded command, the hold, or nothing, and the state saying why) is
made by :class:`pg_node.control.deployment.Deployment`, built on configure; this node
subscribes, times, publishes, records, logs and reports, and its one state (the lifecycle's
too) is the status that the deployment and the lifecycle callbacks set.

Parameters: :data:`pg_node.common.params.POLICY_PARAMS`.
"""
from collections import deque
import hashlib
from pathlib import Path
import sys
import time
from typing import Dict, List, Optional

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped
import mujoco
import numpy as np
from pg_node.bag.writer import BagWriter
from pg_node.common.param_schema import ConfigError
from pg_node.common.params import POLICY_PARAMS
from pg_node.common.run import CONTROLLER_COMMANDS, CONTROLLER_TRAJECTORY
from pg_node.control import interfaces, physics_check
from pg_node.control.composers import command_trajectory
from pg_node.control.deployment import Deployment, Event, JointSample, RobotState, Status
from pg_node.control.estop import EStop
from pg_node.control.guards import CommandGuard, GuardSettings
from pg_node.control.joint_map import arm_joint_names, controller_mismatch, joint_columns
from pg_node.control.status import (diagnostic_level, Fault, GuardEvent, NodeState,
                                    RepeatedWarnings, Severity)
from pg_node.control.targets import (BASE, clamp_to_reach, frame_key, GoalSet, target_array,
                                     Twins)
from pg_node.control.watchdog import Watchdog
from pg_node.rl.trained_policy import load_trained_policy, PolicySourceError
from pg_node.ros import command
from pg_node.ros import table_msg
from pg_node.ros.diagnostics import Diagnostics, RateCounter
from pg_node.ros.parameters import declare_params
from pg_node.ros.policy_markers import policy_markers
from pg_node.ros.runtime import params_help, run
from pg_node.sim.actuation import actuators, inertia_at, mass_matrix_at
from pg_node.sim.kinematics_check import compare_kinematics
from pg_node.sim.observation import ObservationBuilder
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from rclpy.wait_for_message import wait_for_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, Float64MultiArray, String
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import MarkerArray

#: the parameters of :class:`pg_node.control.guards.GuardSettings`
GUARD_PARAMS = ('smoothing', 'max_change', 'joint_limit_margin', 'max_velocity', 'ramp_time',
                'hold_damping', 'hold_stiffness', 'max_deceleration', 'max_position_delta',
                'max_acceleration')
#: /diagnostics levels of the control layer's severities
LEVELS = {Severity.OK: DiagnosticStatus.OK, Severity.WARN: DiagnosticStatus.WARN,
          Severity.ERROR: DiagnosticStatus.ERROR}
#: calls of the policy on configure before the first real one
WARM_UP = 5
#: seconds between two lines of the same guard's warning (the first comes at once)
REPEAT_PERIOD = 30.0
#: the record's topic: one message per control tick
TICKS_TOPIC = '/policy_node/ticks'
#: its table's columns, one row per arm
TICK_FIELDS = ('arm', 'state_age', 'observation', 'mean', 'action', 'command', 'command_si',
               'guards')
#: commands whose state ages the diagnostics summarise
AGE_WINDOW = 1000
#: how the ``target`` subscriptions and ``robot_description`` take a latched publisher's sample
LATCHED = QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL, history=HistoryPolicy.KEEP_LAST)
#: ... and ``target`` a volatile one's (``ros2 topic pub``, RViz's Publish Point)
VOLATILE = QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)


class PolicyNode(LifecycleNode):
    """Turn joint states and targets into guarded commands with a trained policy (managed)."""

    def __init__(self):
        """Declare parameters, subscribe, start the timers; configure and activate if asked."""
        super().__init__('policy_node')
        self.params = p = declare_params(self, POLICY_PARAMS, self.on_parameter)
        if not p['policy']:
            raise ConfigError("parameter 'policy_node.policy' is required: a run directory, a "
                              'ckpt_*.pt file or an exported .onnx file (-p policy:=PATH)')
        self.exit_code = None               # set on a fatal input: run() ends the process
        self.told = set()                   # the warnings given (once each)
        # a guard's warning: the first time, then with a count once in REPEAT_PERIOD s
        self.repeated = RepeatedWarnings(REPEAT_PERIOD)
        self.refusal: Optional[ConfigError] = None     # why the last configure failed
        # what configure builds (cleanup drops it): the decisions of each tick, the policy
        # and what the node publishes, records and reports of it
        self.core: Optional[Deployment] = None
        self.policy = self.builder = self.actuators = None
        self.joints: List[str] = []
        self.digest, self.policy_id = 'n/a', 0
        self.load_seconds = self.warm_up_ms = 0.0
        self.base, self.reach = np.zeros(3), 0.0
        self.goal_set: Optional[GoalSet] = None     # the goals the policy trained on
        self.recorder = self.tf_buffer = self._tf = None
        self.settings = GuardSettings(**{k: p[k] for k in GUARD_PARAMS})
        self.num_arms = p['num_arms']
        self.plain = False
        self._names: List[str] = []
        self._index = None
        self.joint_state: Optional[JointSample] = None     # the newest, the model's joints
        self.raw_targets: Dict[str, np.ndarray] = {}    # frame_id -> point, as received
        self.targets: Dict[object, np.ndarray] = {}     # 'base' or arm index -> goal
        self.requested: Dict[object, np.ndarray] = {}   # ... as asked, before the clamps
        self.clamped = set()                # the frames in a spell of clamped targets
        self.description = None             # robot_description, when published
        self.description_digest = 'none'    # its sha256's first 12 digits, for diagnostics
        self.kinematics = 'not checked'     # what configure found of robot_description
        self.controller_joints = 'not checked'  # what configure found of the controller
        self.joints_unchecked = False       # the controller's joints could not be read
        self.twins = Twins()                # a latched target comes through both subscriptions
        self.records_opened = 0
        self.watchdog = Watchdog()          # a stale spell outlives a cleanup in /diagnostics
        self.estop = EStop()                # latched until ~/reset_estop
        # what the node does: its one state (the lifecycle's too) and the text saying why
        self.status = Status(NodeState.UNCONFIGURED, 'unconfigured: waiting for configure')
        self.counters = {'commands': 0, 'hold_commands': 0, 'stale_events': 0, 'estops': 0,
                         'states_received': 0, 'states_dropped_nonfinite': 0,
                         'targets_ignored': 0, 'targets_out_of_reach': 0,
                         'targets_clamped_to_trained': 0, 'robot_stops': 0,
                         'controller_deactivations': 0,
                         **{f'guard_{e.key}': 0 for e in GuardEvent}}
        # ros2_control's controller manager (controller_manager): its client, and whether
        # a stop deactivated the arm controller (only a reset or activate undoes it)
        self.cm = None
        self.controller_stopped = False
        self.ages = deque(maxlen=AGE_WINDOW)
        self.rate = RateCounter()
        self._cpu = (time.process_time(), time.monotonic())

        if p['command_message'] == 'trajectory':
            self.pub = self.create_publisher(JointTrajectory, CONTROLLER_TRAJECTORY, 10)
        else:
            self.pub = self.create_publisher(Float64MultiArray, CONTROLLER_COMMANDS, 10)
        self.create_subscription(JointState, 'joint_states', self.on_joint_state,
                                 qos_profile_sensor_data)
        # a target from any reliable publisher: DDS matches a transient-local subscription
        # only with transient-local publishers (sim_node's), whose last sample it gets on
        # joining; the volatile one matches every reliable publisher, but gets no old sample.
        # The latched one's expected DURABILITY incompatibility with a volatile publisher is
        # not worth a warning here (the volatile one takes that publisher)
        self.create_subscription(
            PointStamped, 'target', lambda msg: self.on_target(msg, 'latched'), LATCHED,
            event_callbacks=SubscriptionEventCallbacks(incompatible_qos=lambda event: None))
        self.create_subscription(PointStamped, 'target',
                                 lambda msg: self.on_target(msg, 'volatile'), VOLATILE)
        self.create_subscription(String, 'robot_description', self.on_description, LATCHED)
        self.create_subscription(Bool, 'estop', self.on_estop,
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.create_service(Trigger, '~/reset_estop', self.on_reset_estop)
        # the robot's own state, as a UR's driver publishes it (off by default)
        self.robot = RobotState()
        if p['robot_program_running_topic']:
            self.robot.program_topic = self.resolve_topic_name(p['robot_program_running_topic'])
            self.create_subscription(Bool, self.robot.program_topic, self.on_program_running,
                                     LATCHED)
        if p['speed_scaling_topic']:
            self.robot.speed_topic = self.resolve_topic_name(p['speed_scaling_topic'])
            self.create_subscription(Float64, self.robot.speed_topic, self.on_speed_scaling,
                                     qos_profile_sensor_data)
        # the full name: two robots in two namespaces must not overwrite each other's status
        self.diagnostics = Diagnostics(self, f'{self.get_fully_qualified_name()}: trained policy',
                                       'policy_node')
        # steady clock: with use_sim_time the watchdog must still tick when /clock stops
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.timers_by_param = {
            'control_rate': self.create_timer(1.0, self.on_tick, clock=steady),
            'diagnostics_rate': self.create_timer(1.0, self.publish_diag, clock=steady)}
        # what it does, for RViz/Foxglove (pg_node.ros.policy_markers)
        self.pub_markers = self.create_publisher(MarkerArray, '~/markers', 1)
        self.timers_by_param['marker_rate'] = self.create_timer(1.0, self.publish_markers,
                                                                clock=steady)
        for name in self.timers_by_param:
            self.on_parameter(name, p[name])
        if p['autostart']:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise self.refusal
            self.trigger_activate()
        else:
            self.get_logger().info('unconfigured: waiting for the lifecycle transitions '
                                   '(configure, then activate; or autostart:=true)')

    @property
    def guard(self) -> Optional[CommandGuard]:
        """Return the configured deployment's CommandGuard, or None when unconfigured."""
        return self.core.guard if self.core is not None else None

    def control_rate(self) -> float:
        """Return the command rate in Hz: the parameter, or one per control step."""
        if self.params['control_rate'] or self.policy is None:
            return self.params['control_rate'] or 50.0
        return 1.0 / self.policy.card['control_step']

    def on_parameter(self, name: str, value) -> None:
        """Apply a live parameter: the timers follow their rates, the guards their settings."""
        if name in GUARD_PARAMS:
            setattr(self.settings, name, value)
            return
        if name == 'control_rate':
            period = 1.0 / self.control_rate()
            if self.guard is not None:
                self.guard.period = period      # the braking guard's tick
        elif name == 'diagnostics_rate':
            period = 1.0 / value
        elif name == 'marker_rate':
            period = 1.0 / value if value > 0 else None
        else:
            return
        timer = self.timers_by_param[name]
        if period is None:
            timer.cancel()
            return
        timer.timer_period_ns = int(period * 1e9)
        timer.reset()

    # --- lifecycle ------------------------------------------------------------------------

    def on_configure(self, state) -> TransitionCallbackReturn:
        """Load and warm up the policy, check joints and kinematics, open the record."""
        self.refusal = None
        try:
            self._configure()
        except ConfigError as exc:
            self.refusal = exc
            self.set_status(NodeState.UNCONFIGURED, f'unconfigured: configure failed: {exc}')
            if not self.params['autostart']:    # with it, run() reports it in one line, exits
                self.get_logger().error(f'configure failed: {exc}')
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def _configure(self):
        """Configure (:meth:`on_configure`); raise :class:`ConfigError`, the refusal."""
        p = self.params
        t0 = time.perf_counter()
        try:
            policy = load_trained_policy(p['policy'])
            model = mujoco.MjModel.from_xml_string(policy.card['model_xml'])
            builder = ObservationBuilder(model)
        except (PolicySourceError, ValueError) as exc:
            raise ConfigError(f"parameter 'policy_node.policy': {exc}") from exc
        card, interface = policy.card, p['command_interface']
        arm = actuators(model)
        _refuse(interfaces.check(arm, interface))
        joints = list(card['joint_names'])
        self._await_inputs()
        index = joint_columns(self._names, joints, self.num_arms)
        self.kinematics = 'not checked: no robot_description received'
        if self.description is not None:
            tolerance = p['kinematics_tolerance']
            reason = compare_kinematics(model, self.description, tolerance=tolerance)
            if reason is not None:
                raise ConfigError(f"robot_description is not the policy's arm: {reason}")
            self.kinematics = f'match robot_description within {1000 * tolerance:g} mm'
        # relative position targets (a card with max_position_delta): changes around q
        delta = (card.get('command_interfaces') or {}).get(interface, {}).get(
            'max_position_delta')
        guard = CommandGuard(arm, joints, interface, self.settings, 1.0 / self.control_rate(),
                             position_delta=delta, inertia_at=inertia_at(model, joints),
                             mass_at=mass_matrix_at(model, joints))
        commanded = arm_joint_names([joints[c] for c in guard.cols], len(index),
                                    joints[0] in self._names)
        self._check_controller(commanded)
        self._check_with_controller_manager()
        load_seconds = time.perf_counter() - t0
        t0 = time.perf_counter()
        for _ in range(WARM_UP):                # the first calls allocate; not on the robot
            policy.mean_std(np.zeros((max(self.num_arms, 1), policy.obs_dim)))
        warm_ms = 1e3 * (time.perf_counter() - t0) / WARM_UP
        with open(policy.source, 'rb') as f:
            digest = hashlib.file_digest(f, 'sha256').hexdigest()
        if p['record']:
            # a configure after a cleanup records into <record>_1, _2...: a bag is never reused
            path = Path(p['record']).expanduser()
            if self.records_opened:
                path = path.with_name(f'{path.name}_{self.records_opened}')
            try:
                self.recorder = BagWriter(path, custom_data={
                    'policy': policy.describe(), 'policy_sha256': digest,
                    'command_interface': interface})
                self.recorder.add_topic(TICKS_TOPIC, Float64MultiArray)
            except (OSError, ValueError) as exc:
                raise ConfigError(f"parameter 'policy_node.record': {exc}") from exc
            self.records_opened += 1
        self.core = Deployment(guard, builder, policy.mean_std, p,
                               np.random.default_rng(p['seed']), self.watchdog)
        self.policy, self.builder, self.actuators = policy, builder, arm
        self.joints, self.digest = joints, digest
        self.load_seconds, self.warm_up_ms = load_seconds, warm_ms
        self.policy_id = int(digest[:12], 16)
        self.base, self.reach = builder.reach()
        self.goal_set = GoalSet.of(builder.spec)
        self.set_status(NodeState.INACTIVE, 'inactive: configured, waiting for activate')
        self._tf_listener()
        for frame, point in list(self.raw_targets.items()):
            self._take_target(frame, point)
        self.on_parameter('control_rate', p['control_rate'])
        low, high = self.guard.interface.si_range(arm)
        unit = self.guard.interface.unit
        self.get_logger().info(
            f'configured: policy {policy.describe()} (sha256 {digest[:12]}) loaded in '
            f'{load_seconds:.2f} s, {warm_ms:.2f} ms per call warmed up: {card["model"]} '
            f"(joints {', '.join(joints)}); commands {interface} in {unit}, "
            f'{_ranges(low, high)}'
            + (f' (changes of at most {", ".join(f"{d:g}" for d in delta)} rad per step '
               'around the measured angles)' if delta else '')
            + f' at {self.control_rate():g} Hz; state_timeout '
            f'{p["state_timeout"]:g} s; kinematics {self.kinematics}; controller joints '
            f'{self.controller_joints}')
        physics = physics_check.warning(card.get('physics') or {}, p)
        if physics:                             # one line: the robot is not what it learned
            self.get_logger().warn(physics)

    def _await_inputs(self):
        """
        Wait (``configure_timeout``) for the first joint state, and robot_description if required.

        Not through the executor, which is running this very callback (a lifecycle
        transition) or not yet (autostart): rclpy's ``wait_for_message`` waits on a
        subscription of its own. Raise :class:`ConfigError` when one does not come.
        """
        p = self.params
        timeout = p['configure_timeout']
        wanted = []
        if not self._names:
            wanted.append(('joint_states', JointState, qos_profile_sensor_data,
                           self.on_joint_state, "is the robot's joint_state_broadcaster "
                           'running, and is joint_states remapped to its topic?'))
        if p['require_robot_description'] and self.description is None:
            wanted.append(('robot_description', String, LATCHED, self.on_description,
                           'is robot_state_publisher running? (require_robot_description)'))
        if not wanted:
            return
        topics = ' and '.join(self.resolve_topic_name(w[0]) for w in wanted)
        self.set_status(NodeState.UNCONFIGURED, f'configuring: waiting up to {timeout:g} s '
                                                f'for {topics}')
        self.get_logger().info(self.status.text)
        self.publish_diag()
        deadline = time.monotonic() + timeout
        for topic, msg_type, qos, take, hint in wanted:
            while True:
                # in slices of the diagnostics period, the status said at each: a supervisor
                # (play) or an operator sees what configure waits for
                left = deadline - time.monotonic()
                ok, msg = wait_for_message(
                    msg_type, self, topic, qos_profile=qos,
                    time_to_wait=max(min(left, 1.0 / p['diagnostics_rate']), 0.0))
                if ok or left <= 0:
                    break
                self.publish_diag()
            if not ok:
                raise ConfigError(f'no {self.resolve_topic_name(topic)} within {timeout:g} s '
                                  f'(configure_timeout): {hint}')
            take(msg)
        self.set_status(NodeState.UNCONFIGURED, 'unconfigured: configuring')

    def _check_controller(self, commanded: List[str]):
        """
        Compare the controller's ``joints`` parameter with the commanded joints.

        A controller is a node named as the controller, in the controller manager's namespace,
        whose parameter services stay on (ros2_control (jazzy 9ffbf97fd)
        controller_manager/src/controller_manager.cpp:2474-2479,
        controller_interface/src/controller_interface_base.cpp:77-79); ``joints`` is declared
        from load on. ``controller_name`` is resolved as the command topic
        ``arm_controller/commands`` is: relative names in this node's namespace, so a robot
        in ``/left`` with its controller manager there needs nothing, and an absolute name
        (``/arm_controller``) reaches a controller manager at the root. Raise
        :class:`ConfigError` when they differ (a parameter that cannot be read: a warning,
        once).
        """
        p = self.params
        timeout, name = p['controller_timeout'], p['controller_name']
        self.joints_unchecked = False
        if timeout == 0:
            self.controller_joints = 'not checked (controller_timeout 0)'
            return
        # a node of its own, spun by an executor of its own: this node's executor is busy
        # running this callback (or not running yet, with autostart)
        helper = rclpy.create_node(f'{self.get_name()}_controller_check', context=self.context,
                                   namespace=self.get_namespace(), use_global_arguments=False,
                                   start_parameter_services=False, enable_rosout=False)
        executor = SingleThreadedExecutor(context=self.context)
        try:
            service = helper.resolve_service_name(f'{name}/get_parameters')
            controller = service[:-len('/get_parameters')]
            served, why = None, f'no such service within {timeout:g} s (controller_timeout)'
            client = helper.create_client(GetParameters, f'{name}/get_parameters')
            if client.wait_for_service(timeout_sec=timeout):
                executor.add_node(helper)
                future = client.call_async(GetParameters.Request(names=['joints']))
                executor.spin_until_future_complete(future, timeout_sec=timeout)
                values = future.result().values if future.done() else None
                if values is None:
                    why = f'no answer within {timeout:g} s (controller_timeout)'
                elif values and values[0].type == ParameterType.PARAMETER_STRING_ARRAY:
                    served = list(values[0].string_array_value)
                else:
                    why = 'it has no joints parameter (a string array)'
        finally:
            executor.shutdown()
            helper.destroy_node()
        topic = self.pub.topic_name
        if not topic.startswith(controller + '/'):
            self.get_logger().warning(
                f'commands go to {topic}, not to controller {controller}: give '
                f'controller_name the controller that subscribes to {topic}')
        if served is None:
            self.joints_unchecked = True
            self.controller_joints = f'not checked: could not read {service} ({why})'
            self.warn_once(('controller', service), f'could not read {service}: joint order not '
                                                    f'checked ({why})')
            return
        _refuse(controller_mismatch(commanded, served, controller,
                                    ordered=p['command_message'] == 'forward'))
        self.controller_joints = f'match {controller}'

    def _check_with_controller_manager(self):
        """
        Refuse a controller that cannot carry the card's commands or has no dead-man.

        Read from ros2_control's controller manager (:mod:`pg_node.ros.controller_manager`,
        the rules in :mod:`pg_node.control.controller_check`); the client stays for the
        stops that deactivate the controller (``controller_stop``).
        """
        p = self.params
        self._close_controller_manager()
        if not p['controller_manager']:
            return
        from pg_node.ros.controller_manager import ControllerManagerClient, \
            ControllerManagerError
        try:
            self.cm = ControllerManagerClient(
                self.context, p['controller_manager'], max(p['controller_timeout'], 1.0),
                namespace=self.get_namespace(), name=f'{self.get_name()}_controller_manager')
        except ControllerManagerError as exc:
            _refuse(f"parameter 'policy_node.controller_manager': {exc}")
        reason = self.cm.refusal(self.controller_bare_name(), p['command_interface'],
                                 p['command_message'], p['allow_no_dead_man'],
                                 p['controller_hold'])
        if reason:
            self._close_controller_manager()
            _refuse(f"parameter 'policy_node.controller_manager': {reason}")

    def controller_bare_name(self) -> str:
        """Return the arm controller's name as list_controllers gives it (no namespace)."""
        return self.params['controller_name'].rstrip('/').rsplit('/', 1)[-1]

    def stops_controller(self) -> bool:
        """Whether a stop deactivates the arm controller (``controller_stop``)."""
        how = self.params['controller_stop']
        if how == 'auto':
            how = 'hold' if self.params['command_interface'] == 'effort' else 'deactivate'
        return self.cm is not None and how == 'deactivate'

    def stop_controller(self, why: str):
        """Deactivate the arm controller through the controller manager, when asked to."""
        if not self.stops_controller() or self.controller_stopped:
            return
        failed = self.cm.deactivate(self.controller_bare_name())
        if failed:
            self.get_logger().error(f'{why}: could not deactivate the arm controller: '
                                    f'{failed}; the hold command is all that stops the arm')
            return
        self.controller_stopped = True
        self.counters['controller_deactivations'] += 1
        self.get_logger().warning(f'{why}: arm controller {self.controller_bare_name()} '
                                  "deactivated (the robot's own stop acts); activate or "
                                  '~/reset_estop activates it again')

    def restart_controller(self) -> Optional[str]:
        """Activate the arm controller a stop deactivated (an explicit reset); None if done."""
        if not self.controller_stopped:
            return None
        failed = self.cm.activate(self.controller_bare_name())
        if failed is None:
            self.controller_stopped = False
        return failed

    def _close_controller_manager(self):
        if self.cm is not None:
            self.cm.close()
        self.cm, self.controller_stopped = None, False

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Start commanding, ramping in from hold over ``ramp_time``."""
        failed = self.restart_controller()
        if failed:
            self.get_logger().error(f'activate failed: the arm controller stays stopped: {failed}')
            return TransitionCallbackReturn.FAILURE
        self.status = self.core.activate(time.monotonic())
        self.get_logger().info(f'active: commanding, ramping in from hold over '
                               f'{self.settings.ramp_time:g} s')
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        """Send one hold command and stop publishing."""
        self.set_status(NodeState.INACTIVE, 'inactive: deactivated, one hold command sent')
        self._hold_once()
        self.stop_controller('deactivate')
        self.get_logger().info(self.status.text)
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        """Unload the policy and close the record."""
        self._close_record()
        self._close_controller_manager()
        self.core = self.policy = self.builder = self.goal_set = None
        self.targets.clear()
        self.requested.clear()
        self.clamped.clear()
        self.joints_unchecked, self.controller_joints = False, 'not checked'
        self.set_status(NodeState.UNCONFIGURED,
                        'unconfigured: cleaned up, waiting for configure')
        self.get_logger().info(self.status.text)
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        """Hold (if active) and close the record."""
        self.stop()
        self.set_status(NodeState.FINALIZED, 'finalized')
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state) -> TransitionCallbackReturn:
        """Hold, close the record and go back to unconfigured."""
        self.stop()
        self.core = self.policy = None
        self.set_status(NodeState.UNCONFIGURED, 'unconfigured: error, waiting for configure')
        return TransitionCallbackReturn.SUCCESS

    def stop(self):
        """On shutdown or a signal: one hold command if commanding, and the record closed."""
        if self.status.lifecycle == 'active':
            self.set_status(NodeState.INACTIVE, 'inactive: stopped, one hold command sent')
            self._hold_once()
            self.stop_controller('shutdown')
        self._close_record()

    def _hold_once(self):
        """Send the one hold left in force (deactivate, stop): zero torque or the angles."""
        hold = self.core.hold(self.joint_state) if self.core is not None else None
        if hold is not None:                    # a state was taken
            self.record(hold, self.publish(hold, hold=True), np.nan)

    def _close_record(self):
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None

    # --- inputs ---------------------------------------------------------------------------

    def on_joint_state(self, msg: JointState):
        """Keep the model joints' positions and velocities; end the node on a fatal mismatch."""
        if self.exit_code is not None:
            return
        if self.policy is None:
            self._names = list(msg.name)    # checked on configure
            return
        try:
            self._take_joint_state(msg)
        except ConfigError as exc:
            # one line and exit code 2, ended by run() after this callback: an exception
            # through the executor was logged as a FATAL callback error with a traceback
            print(f'configuration error: {exc}', file=sys.stderr, flush=True)
            self.exit_code = 2

    def _take_joint_state(self, msg: JointState):
        names = msg.name
        if self._index is None or names != self._names:
            index = joint_columns(list(names), self.joints, self.num_arms)
            if self._index is not None and len(index) != len(self._index):
                raise ConfigError(f'joint_states now holds {len(index)} arms, it held '
                                  f'{len(self._index)}')
            self._index, self._names = index, list(names)
            self.num_arms = len(index)
            self.plain = self.joints[0] in names
        n = len(names)
        if len(msg.position) != n or len(msg.velocity) != n:
            raise ConfigError(f'joint_states needs a position and a velocity for every joint: '
                              f'{n} names, {len(msg.position)} positions, '
                              f'{len(msg.velocity)} velocities')
        self.counters['states_received'] += 1
        q = np.asarray(msg.position)[self._index]
        qdot = np.asarray(msg.velocity)[self._index]
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qdot))):
            self.counters['states_dropped_nonfinite'] += 1
            self.get_logger().warning('dropped a joint state with a non-finite position or '
                                      'velocity', throttle_duration_sec=1.0)
            return
        stamp = msg.header.stamp
        self.joint_state = JointSample(q, qdot, time.monotonic(),
                                       (stamp.sec + 1e-9 * stamp.nanosec)
                                       if stamp.sec or stamp.nanosec else None)

    def on_description(self, msg: String):
        """Keep ``robot_description`` (URDF) for the kinematics check on configure."""
        self.description = msg.data
        self.description_digest = hashlib.sha256(msg.data.encode()).hexdigest()[:12]

    def on_program_running(self, msg: Bool):
        """Keep whether the robot's program runs (a UR's ``robot_program_running``)."""
        self.robot.program_running = bool(msg.data)

    def on_speed_scaling(self, msg: Float64):
        """Keep the robot's speed scaling in percent (a UR's ``speed_scaling``)."""
        self.robot.speed_scaling = float(msg.data)

    def on_estop(self, msg: Bool):
        """Latch the e-stop on ``true`` (``false`` leaves it as it is)."""
        if msg.data and self.estop.trip():
            self.counters['estops'] += 1
            self.get_logger().error('e-stop: latched; hold command at every tick until '
                                    '~/reset_estop')
            self.on_tick()          # at once, not at the next tick
            self.stop_controller('e-stop')

    def on_reset_estop(self, request, response):
        """Clear a latched e-stop; commanding resumes at the next tick."""
        response.success = True
        failed = self.restart_controller() if self.estop.latched else None
        if failed:
            response.success = False
            response.message = f'e-stop kept: the arm controller stays stopped: {failed}'
            self.get_logger().error(response.message)
        elif self.estop.reset():
            response.message = 'e-stop cleared: commanding resumes'
            self.get_logger().warning(response.message)
        else:
            response.message = 'no e-stop was latched'
        return response

    def on_target(self, msg: PointStamped, source: str = 'volatile'):
        """Keep a goal by its frame: the base frame, or ``arm<i>`` (sim_node's arm frames)."""
        point = np.array([msg.point.x, msg.point.y, msg.point.z])
        frame = msg.header.frame_id
        stamp = msg.header.stamp
        if self.twins.twin(source, (stamp.sec, stamp.nanosec, frame, point.tobytes())):
            return                  # a latched publisher's message, through the other one
        if not np.all(np.isfinite(point)):
            self.counters['targets_ignored'] += 1
            self.warn_once(('nonfinite', frame),
                           f'ignored a target with a non-finite coordinate for '
                           f'{frame or "the arm"}: ({point[0]:g}, {point[1]:g}, '
                           f'{point[2]:g}); the last finite one still holds (counted in '
                           '/diagnostics as targets_ignored)')
            return
        self.raw_targets[frame] = point
        if self.policy is not None:
            self._take_target(frame, point)

    def _take_target(self, frame: str, point: np.ndarray):
        """Resolve ``frame`` (base, arm, or tf2), clamp to the reach, and keep the goal."""
        key = frame_key(frame, self.params['base_frame'])
        if key is None:
            point = self._transform(frame, point)
            if point is None:
                self.counters['targets_ignored'] += 1
                return
            key = BASE
        reached, distance = clamp_to_reach(point, self.base, self.reach)
        goal, moved = self.goal_set.clamp(reached)
        trained = (f'; outside the goals the policy trained on ({self.goal_set.describe()}): '
                   f'taken as ({goal[0]:.3g}, {goal[1]:.3g}, {goal[2]:.3g}) (counted in '
                   '/diagnostics as targets_clamped_to_trained)') if moved else ''
        if distance is not None:
            # said once for the frame, with the clamp to the trained goals that follows it
            self.counters['targets_out_of_reach'] += 1
            self.warn_once(('reach', frame),
                           f'target ({point[0]:g}, {point[1]:g}, {point[2]:g}) in '
                           f"{frame or 'the base frame'} is {distance:.3g} m from the arm's "
                           f'base, beyond its reach of {self.reach:.3g} m: clamped to '
                           f'({reached[0]:.3g}, {reached[1]:.3g}, {reached[2]:.3g}) '
                           f'(counted in /diagnostics as targets_out_of_reach){trained}')
        if moved:
            self.counters['targets_clamped_to_trained'] += 1
            if frame not in self.clamped and distance is None:    # a spell begins: once
                self.get_logger().warning(
                    f'target ({point[0]:g}, {point[1]:g}, {point[2]:g}) in '
                    f"{frame or 'the base frame'} is{trained[1:]}")
            self.clamped.add(frame)
        else:
            self.clamped.discard(frame)
        self.targets[key] = goal
        self.requested[key] = point

    def _tf_listener(self):
        """Listen to tf2 where it can be imported (a full ROS install; not on PyPI)."""
        try:
            import tf2_ros
        except ImportError:
            return
        self.tf_buffer = tf2_ros.Buffer()
        self._tf = tf2_ros.TransformListener(self.tf_buffer, self)

    def _transform(self, frame: str, point: np.ndarray) -> Optional[np.ndarray]:
        """Return ``point`` in the base frame through tf2, or None (warned once)."""
        base = self.params['base_frame']
        if self.tf_buffer is None:
            self.warn_once(('frame', frame),
                           f'ignored targets in frame {frame!r}: only the base frame '
                           f'{base!r} (or an empty frame_id) is taken, and tf2_ros, which '
                           'would transform others, is not installed (counted in '
                           '/diagnostics as targets_ignored)')
            return None
        try:
            from rclpy.time import Time
            tf = self.tf_buffer.lookup_transform(base, frame, Time()).transform
        except Exception as exc:  # noqa: B902 - tf2's lookup errors, any of them: one line
            self.warn_once(('tf', frame), f'ignored targets in frame {frame!r}: no transform '
                                          f'to {base!r} ({type(exc).__name__})')
            return None
        r, t = tf.rotation, tf.translation
        return quat_rotate((r.w, r.x, r.y, r.z), point) + np.array([t.x, t.y, t.z])

    def warn_once(self, key, text: str):
        """Log ``text`` as a warning the first time ``key`` comes up."""
        if key not in self.told:
            self.told.add(key)
            self.get_logger().warning(text)

    # --- the control loop -----------------------------------------------------------------

    def on_tick(self):
        """Publish one command computed from the newest joint state, or say why not."""
        if self.status.lifecycle != 'active':
            return
        joints = self.joint_state
        tick = self.core.tick(joints, target_array(self.targets, self.num_arms, self.plain),
                              time.monotonic(), self.get_clock().now().nanoseconds * 1e-9,
                              self.estop.latched, self.robot.stop_reason())
        for event in tick.events:
            self.log_event(event, tick)
        for event in tick.guard_events:
            self.counters[f'guard_{event.key}'] += 1
            line = self.repeated.line(event, event.warning, time.monotonic()) \
                if event.severity >= Severity.WARN else None
            if line:
                self.get_logger().warning(line)
        if tick.command is not None:
            self.record(tick.command, self.publish(tick.command, hold=tick.hold), tick.age,
                        tick.obs, tick.mean, tick.action, tick.acted)
            if not tick.hold:
                self.ages.append(time.monotonic() - joints.arrival)
        self.status = tick.status

    def log_event(self, event: Event, tick):
        """Count and log what a tick found (:class:`pg_node.control.deployment.Event`)."""
        if event is Event.STALE:
            self.counters['stale_events'] += 1
            age, how, timeout = tick.age, tick.how, self.params['state_timeout']
            hint = (' (a simulator stamps simulated time: give policy_node '
                    'use_sim_time:=true)' if 'stamp' in how and age > 1e4 else '')
            self.get_logger().warning(
                f'joint states are {age:.3f} s old {how} (state_timeout {timeout:g} s): '
                f'hold command at every tick until fresh joint states come{hint}')
        elif event is Event.NO_TARGET:
            self.get_logger().info(f'not commanding: no target yet for {tick.waiting_for} (on '
                                   f"topic target, frame_id {self.params['base_frame']!r}"
                                   f"{' or arm0' if self.plain else ' or arm<i>'})")
        elif event is Event.FRESH:
            self.get_logger().info('fresh joint states: commanding again')
        elif event is Event.ROBOT_STOPPED:
            self.counters['robot_stops'] += 1
            self.get_logger().warning(f'{tick.status.text} (counted in /diagnostics as '
                                      'robot_stops)')
        elif event is Event.ROBOT_READY:
            self.get_logger().info(f'the robot runs again: commanding, ramping in from the '
                                   f'hold over {self.settings.ramp_time:g} s')

    def publish_markers(self):
        """Publish the goals and fingertips (:mod:`pg_node.ros.policy_markers`) if watched."""
        if self.builder is None or not self.pub_markers.get_subscription_count():
            return
        goals = target_array(self.targets, self.num_arms, self.plain)
        goals = None if isinstance(goals, str) else goals
        requested = None if goals is None else target_array(self.requested, self.num_arms,
                                                            self.plain)
        tips = None if self.joint_state is None else self.builder.fingertips(self.joint_state.q)
        arms = len(goals) if goals is not None else len(tips) if tips is not None else 0
        frame = self.params['marker_frame']
        frames = [frame or (self.params['base_frame'] if self.plain else f'arm{i}')
                  for i in range(arms)]
        self.pub_markers.publish(policy_markers(goals, tips, self.status.state, frames,
                                                self.get_clock().now().to_msg(), requested))

    def set_status(self, state: NodeState, text: str):
        """Note what the node is doing: the state (its level) and the text saying why."""
        self.status = Status(state, text)

    def publish(self, ctrl: np.ndarray, hold: bool = False) -> np.ndarray:
        """Publish controls ``ctrl`` (arms x actuators) in SI units; return those."""
        si = self.guard.interface.to_si(self.actuators, ctrl)
        if self.params['command_message'] == 'trajectory':
            self.pub.publish(self.trajectory(si, hold))
        else:
            self.pub.publish(command.to_msg(si))
        self.counters['commands'] += 1
        self.counters['hold_commands'] += int(hold)
        self.rate.add()
        return si

    def trajectory(self, si: np.ndarray, hold: bool = False) -> JointTrajectory:
        """
        Return ``si`` as JTC's "apply now, hold": stamp 0, one point at time 0.

        With ``controller_hold`` ``pd`` the point carries the measured speeds, and a hold is
        velocity 0, effort 0: the controller's own PD brake (:mod:`pg_node.control.composers`).
        """
        cols = self.guard.cols
        names = arm_joint_names([self.joints[c] for c in cols], self.num_arms, self.plain)
        qdot = (self.joint_state.qdot[:, cols] if self.params['controller_hold'] == 'pd'
                else None)
        composed = command_trajectory(self.guard.interface, si, self.joint_state.q[:, cols],
                                      names, qdot=qdot, hold=hold)
        (point,) = composed.points          # time_from_start 0, header.stamp 0: the defaults
        return JointTrajectory(joint_names=composed.joint_names,
                               points=[JointTrajectoryPoint(**point.fields)])

    def record(self, cmd, si, age, obs=None, mean=None, action=None, acted=None):
        """
        Write one tick into the record: per arm what came in, what the guards made of it.

        ``cmd`` and ``si``: the command sent, in controls and in SI units; a hold has no
        observation, mean or action (NaN in the record). ``acted``: the guards' events per
        arm, recorded as ``guards``, bit ``i`` for the ``i``-th
        :class:`pg_node.control.status.GuardEvent` (0 on a hold tick).
        """
        if self.recorder is None:
            return
        arms = len(cmd)
        if obs is None:
            obs = np.full((arms, self.policy.obs_dim), np.nan)
            mean = action = np.full((arms, self.policy.act_dim), np.nan)
        guards = np.zeros(arms)
        for bit, event in enumerate(GuardEvent):
            if acted is not None:
                guards += (1 << bit) * acted[event]
        fields = dict(zip(TICK_FIELDS, (np.arange(arms), np.full(arms, age), obs, mean, action,
                                        cmd, si, guards)))
        stamp = self.get_clock().now().nanoseconds
        msg = table_msg.to_msg(*table_msg.pack([stamp * 1e-9, self.policy_id], fields))
        self.recorder.write(TICKS_TOPIC, msg, time.time_ns())

    def publish_diag(self):
        """Publish state, rate, state ages, counters and the policy's source."""
        cpu, wall = time.process_time(), time.monotonic()
        cpu_share = (cpu - self._cpu[0]) / max(wall - self._cpu[1], 1e-9)
        self._cpu = (cpu, wall)
        ages = np.array(self.ages) * 1e3
        values = dict(
            state=self.status.text, lifecycle=self.status.lifecycle,
            commands_per_second=round(self.rate.rate(), 1),
            control_rate=round(self.control_rate(), 3),
            command_interface=self.params['command_interface'],
            state_age_median_ms=round(float(np.median(ages)), 3) if ages.size else 'n/a',
            state_age_p99_ms=round(float(np.percentile(ages, 99)), 3) if ages.size else 'n/a',
            state_age_window=int(ages.size), cpu_percent=round(100 * cpu_share, 1),
            num_arms=self.num_arms if self._index is not None else 'n/a',
            policy=self.policy.describe() if self.policy is not None else 'not loaded',
            policy_sha256=self.digest if self.policy is not None else 'n/a',
            load_seconds=round(self.load_seconds, 3) if self.policy is not None else 'n/a',
            warm_up_ms_per_call=(round(self.warm_up_ms, 3) if self.policy is not None
                                 else 'n/a'),
            trained_goals=(self.goal_set.describe() if self.goal_set is not None
                           else 'not loaded'),
            robot_program_running=_followed(self.robot.program_topic,
                                            self.robot.program_running),
            speed_scaling=_followed(self.robot.speed_topic, self.robot.speed_scaling),
            robot_description=self.description_digest, kinematics=self.kinematics,
            controller_joints=self.controller_joints,
            command_topic=self.pub.topic_name,
            command_subscribers=self.pub.get_subscription_count(),
            **(self.guard.describe() if self.guard is not None else {}),
            **self.counters)
        # diagnostic_updater's habits: idle WARN, stale or stopped ERROR, degraded WARN.
        # A subscriber count of 0 proves that no controller listens; more proves less: a
        # configured but inactive ros2_control controller subscribes too and drops what it
        # gets (ros2_controllers (jazzy ed360c97d)
        # forward_command_controller/src/forward_controllers_base.cpp:73-89, 131-149;
        # joint_trajectory_controller/src/joint_trajectory_controller.cpp:1002-1004,
        # 1393-1397); whether it is active only the controller manager's list_controllers says
        no_listener = self.status.lifecycle == 'active' and not values['command_subscribers']
        faults = [f for f, on in ((Fault.STALE_STATE, self.watchdog.stale),
                                  (Fault.ESTOP, self.estop.latched),
                                  (Fault.NO_LISTENER, no_listener),
                                  (Fault.JOINTS_UNCHECKED, self.joints_unchecked)) if on]
        message = self.status.text
        if no_listener:
            message += (f'; no subscriber on {self.pub.topic_name}: no controller is '
                        'listening (a subscriber would not prove an active one)')
        if self.joints_unchecked:
            message += f'; controller joints {self.controller_joints}'
        level = LEVELS[diagnostic_level(self.status.state, faults)]
        self.diagnostics.publish(values, level, message)


def tick_from_msg(msg: Float64MultiArray):
    """Return ``(header, {field: (arms, width)})`` of a recorded tick (header: stamp, id)."""
    return table_msg.unpack(*table_msg.from_msg(msg), header_size=2,
                            widths=dict.fromkeys(TICK_FIELDS))


def quat_rotate(wxyz, v: np.ndarray) -> np.ndarray:
    """
    Rotate ``v`` by the unit quaternion ``(w, x, y, z)``.

    >>> np.round(quat_rotate((np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)), [1.0, 0, 0]), 9)
    array([0., 1., 0.])
    """
    out = np.empty(3)
    mujoco.mju_rotVecQuat(out, np.asarray(v, dtype=float), np.asarray(wxyz, dtype=float))
    return out


def _followed(topic: str, value) -> str:
    """Return a robot state topic's last value for /diagnostics, or why there is none."""
    if not topic:
        return 'not followed'
    return 'no message yet' if value is None else str(value).lower()


def _refuse(reason: Optional[str]):
    """Raise :class:`ConfigError` with ``reason``, a check's refusal (None: it passed)."""
    if reason is not None:
        raise ConfigError(reason)


def _ranges(low: np.ndarray, high: np.ndarray) -> str:
    pairs = sorted({(float(a), float(b)) for a, b in zip(low, high)})
    return ', '.join(f'[{a:g}, {b:g}]' for a, b in pairs)


def main(args=None):
    """Run policy_node until Ctrl-C or an external shutdown (one hold command, if active)."""
    if params_help('policy_node', POLICY_PARAMS, args):
        return 0
    return run(PolicyNode, args, cleanup=lambda node: node.stop())


if __name__ == '__main__':
    raise SystemExit(main())
