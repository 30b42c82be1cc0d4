"""
policy_node: a trained policy commanding arms in real time, as on a robot.

The policy (parameter ``policy``: a run directory, its ``checkpoints/``, a ``ckpt_*.pt`` file
or an exported ``.onnx`` file with its card, :mod:`pg_node.rl.trained_policy`) brings its
card: the arm model, its joint names, the observation layout, the control range and step.
An exported policy runs on onnxruntime: torch is then never imported.

Subscribed:

* ``joint_states`` (``sensor_msgs/JointState``, best effort, so any publisher matches):
  matched by name to the model's arm joints, in any order, other joints ignored; one arm
  with the plain names (``joint0``) or several with ``arm<i>/`` prefixes, as ``sim_node``
  publishes them (``num_arms`` 0 takes as many arms as the first message holds). Position
  and velocity are needed; a message with a non-finite one is dropped and counted. A model
  joint missing from the message is an error that stops the node (exit code 2, one line);
* ``target`` (``geometry_msgs/PointStamped``, reliable + transient-local as ``sim_node``
  publishes it): the goal of arm ``i`` with ``frame_id`` ``arm<i>``, in that arm's frame;
  with plain joint names, any frame is the one arm's goal. A target beyond the arm's reach
  (:meth:`pg_node.sim.observation.ObservationBuilder.reach`) is commanded, with a warning
  once per arm; a non-finite one is ignored, with a warning once per arm (both counted in
  ``/diagnostics``).

Published:

* ``arm_controller/commands`` (``std_msgs/Float64MultiArray``, arms x actuators, arm-major,
  untagged: what ros2_control's forward command controller takes), from a timer at
  ``control_rate`` Hz (0: one per control step of the policy). Each command is the policy's
  mean action (``deterministic``; else a sample) for the observation built as training
  builds it (:class:`pg_node.sim.observation.ObservationBuilder`: the fingertip by forward
  kinematics at the measured angles), clipped to the control range; a non-finite action
  is replaced by zero effort, so no command is ever non-finite or out of range;
* ``/diagnostics``: state (commanding, or why not: no joint states yet, no target yet,
  stale joint states, e-stop latched), achieved command rate, the age of the joint state
  each command was computed from (median and p99 over the last commands), stale events,
  e-stops, dropped states, CPU share and the policy's source.

* ``estop`` (``std_msgs/Bool``, reliable): ``true`` latches an emergency stop; ``false``
  does not clear it. Service ``~/reset_estop`` (``std_srvs/Trigger``) clears it.

Safety: when the newest joint state is older than ``state_timeout`` s, zero effort is
published at every control tick (never one message only: a forward command controller
holds the last command it got) and a warning logged once per stale spell; commanding
resumes with the next fresh joint state. A latched e-stop publishes zero effort at every
tick too, whatever the states, until ``~/reset_estop``. Before the first joint state and
target nothing is published. Diagnostics levels follow diagnostic_updater's habits:
commanding OK, waiting (no states or no target yet) WARN, stale states or a latched e-stop
ERROR.

Parameters: :data:`pg_node.common.params.POLICY_PARAMS`.
"""
from collections import deque
import re
import sys
import time
from typing import Dict, List, Sequence

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped
import mujoco
import numpy as np
from pg_node.common.params import ConfigError, POLICY_PARAMS
from pg_node.rl.trained_policy import control_range, load_trained_policy, PolicySourceError
from pg_node.ros import command
from pg_node.ros.node_utils import Diagnostics, RateCounter, run
from pg_node.ros.parameters import declare_params
from pg_node.sim.observation import ObservationBuilder
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray
from std_srvs.srv import Trigger

PREFIXED = re.compile(r'^arm(\d+)/(.+)$')
#: a target this much beyond the arm's reach (ObservationBuilder.reach) is warned about
REACH_MARGIN = 1.05
#: commands whose state ages the diagnostics summarise
AGE_WINDOW = 1000


def joint_columns(names: Sequence[str], joints: Sequence[str], num_arms: int = 0
                  ) -> np.ndarray:
    """
    Return ``(arms, joints)`` indices into a JointState's arrays for the model's ``joints``.

    One arm with the plain names, or ``num_arms`` (0: as many as the message names) arms
    named ``arm<i>/<joint>``. Raises ConfigError naming the first model joint that is missing.

    >>> joint_columns(['wrist', 'joint1', 'joint0'], ['joint0', 'joint1']).tolist()
    [[2, 1]]
    >>> joint_columns(['arm1/joint0', 'arm0/joint0', 'arm1/x', 'arm0/x'], ['joint0', 'x'])
    array([[1, 3],
           [0, 2]])
    """
    where = {name: i for i, name in enumerate(names)}
    plain = [j for j in joints if j in where]
    if plain and num_arms <= 1:
        missing = [j for j in joints if j not in where]
        if missing:
            raise ConfigError(_missing(missing[0], joints, names))
        return np.array([[where[j] for j in joints]])
    if num_arms == 0:
        arms = {int(m.group(1)) for name in names
                if (m := PREFIXED.match(name)) and m.group(2) in joints}
        if not arms:
            raise ConfigError(_missing(joints[0], joints, names))
        num_arms = max(arms) + 1
    index = np.empty((num_arms, len(joints)), dtype=int)
    for i in range(num_arms):
        for k, j in enumerate(joints):
            col = where.get(f'arm{i}/{j}')
            if col is None:
                raise ConfigError(_missing(f'arm{i}/{j}', joints, names))
            index[i, k] = col
    return index


def _missing(joint: str, joints: Sequence[str], names: Sequence[str]) -> str:
    shown = ', '.join(list(names)[:8]) + (', ...' if len(names) > 8 else '')
    return (f"joint_states has no joint {joint!r}: the policy's arm has joints "
            f"{', '.join(joints)} (plain, or as arm<i>/<joint> for several arms); the message "
            f'names [{shown}] (remap joint_states, or give a model with these joint names)')


class PolicyNode(Node):
    """Turn joint states and targets into torque commands with a trained policy."""

    def __init__(self):
        """Load the policy, declare parameters, subscribe and start the control timer."""
        super().__init__('policy_node')
        self.params = p = declare_params(self, POLICY_PARAMS, self.on_parameter)
        if not p['policy']:
            raise ConfigError("parameter 'policy_node.policy' is required: a run directory, a "
                              'ckpt_*.pt file or an exported .onnx file (-p policy:=PATH)')
        t0 = time.perf_counter()
        try:
            self.policy = load_trained_policy(p['policy'])
            card = self.policy.card
            self.builder = ObservationBuilder(mujoco.MjModel.from_xml_string(card['model_xml']))
        except (PolicySourceError, ValueError) as exc:
            raise ConfigError(f"parameter 'policy_node.policy': {exc}") from None
        self.load_seconds = time.perf_counter() - t0
        self.base, self.reach = self.builder.reach()
        self.exit_code = None               # set on a fatal input: run() ends the process
        self.told = set()                   # the target warnings given (once each)
        self.joints = list(card['joint_names'])
        self.low, self.high = control_range(card)
        self.act_dim = self.policy.act_dim
        self.rng = np.random.default_rng(p['seed'])
        self.num_arms = p['num_arms']
        self.plain = False
        self._names: List[str] = []
        self._index = None
        self.q = self.qdot = None
        self.state_time = None
        self.targets: Dict[str, np.ndarray] = {}
        self.latest_target = None
        self.stale = False
        self.estop = False                  # latched until ~/reset_estop
        self.status = 'waiting: no joint_states yet'
        self.counters = {'commands': 0, 'zero_commands': 0, 'stale_events': 0, 'estops': 0,
                         'states_received': 0, 'states_dropped_nonfinite': 0,
                         'actions_nonfinite': 0, 'targets_ignored': 0,
                         'targets_out_of_reach': 0}
        self.ages = deque(maxlen=AGE_WINDOW)
        self.rate = RateCounter()
        self._cpu = (time.process_time(), time.monotonic())

        self.pub = self.create_publisher(Float64MultiArray, 'arm_controller/commands', 10)
        self.create_subscription(JointState, 'joint_states', self.on_joint_state,
                                 qos_profile_sensor_data)
        targets_qos = QoSProfile(depth=256, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL,
                                 history=HistoryPolicy.KEEP_LAST)
        self.create_subscription(PointStamped, 'target', self.on_target, targets_qos)
        self.create_subscription(Bool, 'estop', self.on_estop,
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.create_service(Trigger, '~/reset_estop', self.on_reset_estop)
        self.diagnostics = Diagnostics(self, 'policy_node: trained policy', self.policy.kind)
        self.timers_by_param = {'control_rate': self.create_timer(1.0, self.on_tick),
                                'diagnostics_rate': self.create_timer(1.0, self.publish_diag)}
        for name in self.timers_by_param:
            self.on_parameter(name, p[name])
        self.get_logger().info(
            f'policy {self.policy.describe()} loaded in {self.load_seconds:.2f} s: '
            f"{card['model']} (joints {', '.join(self.joints)}), "
            f'{self.control_rate():g} Hz, state_timeout {p["state_timeout"]:g} s')

    def control_rate(self) -> float:
        """Return the command rate in Hz: the parameter, or one per control step."""
        return self.params['control_rate'] or 1.0 / self.policy.card['control_step']

    def on_parameter(self, name: str, value) -> None:
        """Apply a live parameter: the timers follow their rates."""
        if name == 'control_rate':
            period = 1.0 / self.control_rate()
        elif name == 'diagnostics_rate':
            period = 1.0 / value
        else:
            return
        timer = self.timers_by_param[name]
        timer.timer_period_ns = int(period * 1e9)
        timer.reset()

    # --- inputs ---------------------------------------------------------------------------

    def on_joint_state(self, msg: JointState):
        """Keep the model joints' positions and velocities; end the node on a fatal mismatch."""
        if self.exit_code is not None:
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
            self.plain = self._index is not None and self.joints[0] in names
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
        self.q, self.qdot = q, qdot
        self.state_time = time.monotonic()

    def on_estop(self, msg: Bool):
        """Latch the e-stop on ``true`` (``false`` leaves it as it is)."""
        if msg.data and not self.estop:
            self.estop = True
            self.counters['estops'] += 1
            self.get_logger().error('e-stop: latched; zero effort at every tick until '
                                    '~/reset_estop')
            self.on_tick()          # at once, not at the next tick

    def on_reset_estop(self, request, response):
        """Clear a latched e-stop; commanding resumes at the next tick."""
        response.success = True
        if self.estop:
            self.estop = False
            response.message = 'e-stop cleared: commanding resumes'
            self.get_logger().warning(response.message)
        else:
            response.message = 'no e-stop was latched'
        return response

    def on_target(self, msg: PointStamped):
        """Keep each arm's goal by its frame (``arm<i>``)."""
        point = np.array([msg.point.x, msg.point.y, msg.point.z])
        frame = msg.header.frame_id or 'the arm'
        if not np.all(np.isfinite(point)):
            self.counters['targets_ignored'] += 1
            self.warn_once(('nonfinite', frame),
                           f'ignored a target with a non-finite coordinate for {frame}: '
                           f'({point[0]:g}, {point[1]:g}, {point[2]:g}); the last finite one '
                           'still holds (counted in /diagnostics as targets_ignored)')
            return
        distance = float(np.linalg.norm(point - self.base))
        if distance > REACH_MARGIN * self.reach:
            self.counters['targets_out_of_reach'] += 1
            self.warn_once(('reach', frame),
                           f'target ({point[0]:g}, {point[1]:g}, {point[2]:g}) for {frame} is '
                           f"{distance:.3g} m from the arm's base, beyond its reach of "
                           f'{self.reach:.3g} m: commanded anyway, the arm cannot get there '
                           '(counted in /diagnostics as targets_out_of_reach)')
        self.targets[msg.header.frame_id] = point
        self.latest_target = point

    def warn_once(self, key, text: str):
        """Log ``text`` as a warning the first time ``key`` comes up."""
        if key not in self.told:
            self.told.add(key)
            self.get_logger().warning(text)

    def target_array(self):
        """Return the goals ``(arms, 3)``, or the name of an arm without one."""
        if self.plain:
            return self.latest_target if self.latest_target is None else self.latest_target[None]
        out = np.empty((self.num_arms, 3))
        for i in range(self.num_arms):
            point = self.targets.get(f'arm{i}')
            if point is None:
                return f'arm{i}'
            out[i] = point
        return out

    # --- the control loop -----------------------------------------------------------------

    def on_tick(self):
        """Publish one command computed from the newest joint state, or say why not."""
        now = time.monotonic()
        if self.estop:
            self.status = 'e-stop latched: zero effort (clear with ~/reset_estop)'
            if self.num_arms:
                self.publish(np.zeros((self.num_arms, self.act_dim)), zero=True)
            return
        if self.state_time is None:
            self.status = 'waiting: no joint_states yet'
            return
        age = now - self.state_time
        if age > self.params['state_timeout']:
            if not self.stale:
                self.stale = True
                self.counters['stale_events'] += 1
                self.get_logger().warning(
                    f'joint states are {age:.3f} s old (state_timeout '
                    f'{self.params["state_timeout"]:g} s): zero effort at every tick until '
                    'fresh joint states come')
            # every tick, not once: a forward command controller holds its last command
            self.publish(np.zeros((self.num_arms, self.act_dim)), zero=True)
            self.status = (f'stale: joint states {age:.2f} s old, zero effort, waiting for '
                           'fresh ones')
            return
        target = self.target_array()
        if target is None or isinstance(target, str):
            status = f'waiting: no target yet for {target or "the arm"}'
            if status != self.status:
                self.get_logger().info(f'not commanding: no target yet for '
                                       f'{target or "the arm"} (on topic target)')
            self.status = status
            return
        if self.stale:
            self.stale = False
            self.get_logger().info('fresh joint states: commanding again')
        obs = self.builder(self.q, self.qdot, target)
        if self.params['deterministic']:
            act = self.policy.mean(obs)
        else:
            mu, std = self.policy.mean_std(obs)
            act = mu + std * self.rng.standard_normal(mu.shape)
        if not np.all(np.isfinite(act)):
            self.counters['actions_nonfinite'] += 1
            self.get_logger().warning('the policy gave a non-finite action: zero effort sent',
                                      throttle_duration_sec=1.0)
            act = np.zeros_like(act)
        self.publish(np.clip(act, self.low, self.high))
        self.ages.append(time.monotonic() - self.state_time)
        self.status = 'commanding'

    def publish(self, act: np.ndarray, zero: bool = False):
        """Publish ``act`` (arms x actuators) as an untagged forward command."""
        self.pub.publish(command.to_msg(act))
        self.counters['commands'] += 1
        self.counters['zero_commands'] += int(zero)
        self.rate.add()

    def publish_diag(self):
        """Publish state, rate, state ages, counters and the policy's source."""
        cpu, wall = time.process_time(), time.monotonic()
        cpu_share = (cpu - self._cpu[0]) / max(wall - self._cpu[1], 1e-9)
        self._cpu = (cpu, wall)
        ages = np.array(self.ages) * 1e3
        values = dict(
            state=self.status, commands_per_second=round(self.rate.rate(), 1),
            control_rate=round(self.control_rate(), 3),
            state_age_median_ms=round(float(np.median(ages)), 3) if ages.size else 'n/a',
            state_age_p99_ms=round(float(np.percentile(ages, 99)), 3) if ages.size else 'n/a',
            state_age_window=int(ages.size), cpu_percent=round(100 * cpu_share, 1),
            num_arms=self.num_arms if self._index is not None else 'n/a',
            policy=self.policy.describe(), policy_kind=self.policy.kind,
            load_seconds=round(self.load_seconds, 3), **self.counters)
        # diagnostic_updater's habits: idle WARN, stale or stopped ERROR
        level = (DiagnosticStatus.OK if self.status == 'commanding'
                 else DiagnosticStatus.ERROR if self.stale or self.estop
                 else DiagnosticStatus.WARN)
        self.diagnostics.publish(values, level, self.status)


def main(args=None):
    """Run policy_node until Ctrl-C or an external shutdown."""
    return run(PolicyNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
