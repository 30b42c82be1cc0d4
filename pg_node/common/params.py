"""
Every training parameter: default, meaning, and what values are allowed.

One table serves three readers: the nodes declare their ROS parameters from it (with the
description as ``ParameterDescriptor``, so ``ros2 param describe`` explains each), the
``python -m pg_node train`` bring-up validates the YAML file and ``key=value`` overrides
against it before starting anything, and the parameter table of docs/ros_graph.md is taken from it.
Validation refuses an unknown key, a value of the wrong type and a value out of range, with
a message that names the key, the value and what is allowed.

The YAML file (``config/pg_node.yaml``) follows ROS 2's parameter-file format: a section
``<node_name>: ros__parameters:`` per node, and ``/**: ros__parameters:`` for the values every
node shares (the arm model, the number of arms, the seed, the network shape).
"""
from dataclasses import dataclass
import difflib
import math
from pathlib import Path
import re
import shlex
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from pg_node.common.paths import check_model
from pg_node.common.perturbations import PARAM_PREFIX, parse_term, TERMS
from pg_node.common.run import check_run_id
import yaml

SHARED = '/**'


class ConfigError(ValueError):
    """A parameter file or override that cannot be used; the message says why."""


@dataclass(frozen=True)
class Param:
    """One parameter: its default (whose type is the parameter's type) and its limits."""

    default: Any
    description: str
    choices: Optional[Sequence[Any]] = None
    low: Optional[float] = None
    high: Optional[float] = None
    low_inclusive: bool = True
    #: extra check: called with the value, raises ValueError/OSError with the reason
    validate: Optional[Callable[[Any], Any]] = None
    #: True: may change while the node runs (``ros2 param set``); False: read-only
    live: bool = False
    #: a str parameter that also takes a bare number (YAML ``0.01``, ``key:=2``) as its text
    numbers_as_text: bool = False

    def allowed(self) -> str:
        """Describe the allowed values in words."""
        kind = type(self.default).__name__
        if isinstance(self.default, list):
            kind = 'non-empty list of positive integers'
        if self.choices is not None:
            return 'one of ' + ', '.join(repr(c) for c in self.choices)
        if self.low is not None or self.high is not None:
            lo = '' if self.low is None else (
                f'{self.low} <= ' if self.low_inclusive else f'{self.low} < ')
            hi = '' if self.high is None else f' <= {self.high}'
            return f'{_article(kind)} {kind} with {lo}value{hi}'
        return f'{_article(kind)} {kind}'

    def check(self, key: str, value):
        """Return ``value`` converted to the parameter's type, or raise ConfigError."""
        want = type(self.default)
        bad = ConfigError(f'parameter {key!r}: {value!r} is not allowed; '
                          f'expected {self.allowed()}')
        if want is bool:
            if not isinstance(value, bool):
                raise bad
        elif want is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise bad
        elif want is float:
            if isinstance(value, str):
                # YAML 1.1 reads 3e-4 (no dot) as a string; accept any float literal.
                try:
                    value = float(value)
                except ValueError:
                    raise bad from None
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad
            value = float(value)
            if not math.isfinite(value):
                raise bad
        elif want is str:
            if (self.numbers_as_text and isinstance(value, (int, float))
                    and not isinstance(value, bool)):
                value = repr(value)
            if not isinstance(value, str):
                raise bad
        elif want is list:
            if not isinstance(value, (list, tuple)):
                raise bad
            if not value:
                # a ROS 2 parameter cannot hold an empty list: it has no type, and the node
                # that declares it fails (ParameterUninitializedException)
                raise ConfigError(f'parameter {key!r}: [] is not allowed; expected '
                                  f'{self.allowed()} (a ROS 2 parameter cannot hold an empty '
                                  'list)')
            for v in value:
                if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                    raise ConfigError(f'parameter {key!r}: {list(value)!r} is not allowed: '
                                      f'{v!r} is not a positive integer; expected '
                                      f'{self.allowed()}')
            value = list(value)
        if self.choices is not None and value not in self.choices:
            raise bad
        if self.low is not None and (value < self.low or (value == self.low
                                                          and not self.low_inclusive)):
            raise bad
        if self.high is not None and value > self.high:
            raise bad
        if self.validate is not None:
            try:
                self.validate(value)
            except (ValueError, OSError) as exc:
                raise ConfigError(f'parameter {key!r}: {value!r} is not allowed: {exc}') from None
        return value


def _article(word: str) -> str:
    return 'an' if word[0] in 'aeiou' else 'a'


POSITIVE = {'low': 0.0, 'low_inclusive': False}

#: Values every node reads (the ``/**`` section).
SHARED_PARAMS: Dict[str, Param] = {
    'model': Param('reacher2',
                   'shipped arm model (reacher2, arm5_3d, arm7) or a path to an MJCF file',
                   validate=check_model),
    'num_envs': Param(64, 'arms simulated side by side (one message per step and group)',
                      low=1),
    'seed': Param(0, 'seed of the simulator, the policy initialisation and the sampling', low=0),
    'lock_step_groups': Param(1, 'lock-step: the simulator steps its arms in this many groups, '
                                 'each on its own command, so that one group is simulated '
                                 'while the actor answers another (same computation); at '
                                 'most num_envs', low=1),
    'hidden_sizes': Param([64, 64], 'hidden layer widths of the policy and value networks'),
    'activation': Param('tanh', 'hidden activation of both networks',
                        choices=('tanh', 'relu', 'elu')),
    'normalize_obs': Param(True, 'normalise observations by a running mean and variance'),
    'sync_mode': Param('sync', 'sync: actors wait for the weights of version k before rollout '
                               'k+1 (exact on-policy A2C); async: actors keep sampling with '
                               'stale weights up to max_policy_lag versions (A3C-style)',
                       choices=('sync', 'async')),
    'max_policy_lag': Param(4, "async mode: most versions a batch's policy may lag", low=0),
    'num_actors': Param(1, 'simulator/actor pairs feeding the critic and learner; in sync '
                           'mode one batch holds one rollout of each', low=1),
    'run_dir': Param('runs/latest', 'where checkpoints, the bag and progress files go'),
    'run_id': Param('', "the run's name on the ROS network: its topics are "
                        '/<run_id>/pg_node/..., and every node drops messages of another run '
                        "(letters, digits, '_'; empty: /pg_node/...; train and the launch file "
                        'always set one)', validate=check_run_id),
}

#: the training-side nodes (critic, learner) yield the cores to the lock-step loop
NICE = Param(10, "CPU niceness (0-19) of all the node's threads, as `nice -n` gives a "
                 'process: its work after each hand-over (fitting V; writing the bag, logs and '
                 'checkpoints) then gives way to the simulator and the actor, which wait on '
                 'each other every control step; the hand-over itself runs while those two '
                 'wait. Never lowered below what the node was started with', low=0, high=19)

SCHED_IDLE = Param(True, "in sync mode, run all the node's threads under Linux's SCHED_IDLE "
                         'policy (as `chrt --idle 0`): they take a core only when no other '
                         'thread wants it, so the work after each hand-over (fitting V; the '
                         "bag, logs, checkpoints) never delays the simulator's steps, and the "
                         'hand-over itself runs while the simulator and the actor wait for '
                         'it. Other busy programs on the machine then go first: set false '
                         'on a machine shared with other work (nice applies then). Async '
                         'mode keeps nice only: its simulator never waits')

ACTOR_PARAMS: Dict[str, Param] = {
    'n_steps': Param(8, 'control steps per arm in one rollout (rollout = n_steps x num_envs)',
                     low=1),
    'log_std_init': Param(-0.5, 'initial log standard deviation of the Gaussian policy',
                          low=-5.0, high=2.0),
    'state_dependent_std': Param(False, 'log-std from a network head instead of a parameter'),
    'actor_id': Param(0, 'id of this actor when several feed one critic/learner', low=0),
    'rollout_resend_timeout': Param(5.0, 'sync mode: seconds without new weights before the '
                                         'last rollout is sent again', **POSITIVE, live=True),
}

CRITIC_PARAMS: Dict[str, Param] = {
    'estimator': Param('gae', 'choice of phi (see pg_node.rl.estimators)',
                       choices=('total_return', 'reward_to_go', 'constant_baseline',
                                'optimal_baseline', 'time_baseline', 'value_baseline',
                                'td_residual', 'gae')),
    'gamma': Param(0.95, 'discount factor', low=0.0, high=1.0, live=True),
    'gae_lambda': Param(0.95, 'GAE lambda (also of the TD(lambda) value target)',
                        low=0.0, high=1.0, live=True),
    'value_target': Param('td_lambda', 'targets V is fitted to: td_lambda (GAE + V) or mc '
                                       '(empirical discounted return, section 4.5.1)',
                          choices=('td_lambda', 'mc')),
    'vf_learning_rate': Param(1e-3, 'learning rate of the value network', **POSITIVE, live=True),
    'vf_coef': Param(0.5, 'weight of the value loss', **POSITIVE, live=True),
    'vf_epochs': Param(10, 'passes over each batch when fitting V', low=1, live=True),
    'vf_batch_size': Param(0, 'minibatch size when fitting V (0: the whole batch)', low=0,
                           live=True),
    'vf_optimizer': Param('adam', 'optimiser of the value network', choices=('rmsprop', 'adam')),
    'vf_max_grad_norm': Param(0.5, 'gradient clipping of V (0: none)', low=0.0, live=True),
    'checkpoint_every': Param(100, 'batches between checkpoints of V', low=1, live=True),
    'nice': NICE,
    'sched_idle': SCHED_IDLE,
}

#: the policy updates ``algo`` names and the learner settings each has (the classes are
#: pg_node.rl.updaters.UPDATERS; this layer cannot import them, and train validates here)
ALGO_SETTINGS: Dict[str, Tuple[str, ...]] = {
    'a2c': ('learning_rate', 'optimizer', 'ent_coef', 'max_grad_norm', 'normalize_advantage'),
    'ppo': ('learning_rate', 'optimizer', 'ent_coef', 'max_grad_norm', 'normalize_advantage',
            'n_epochs', 'batch_size', 'clip_range'),
    'npg': ('ent_coef', 'normalize_advantage', 'max_kl', 'cg_iters', 'cg_damping'),
    'trpo': ('ent_coef', 'normalize_advantage', 'max_kl', 'cg_iters', 'cg_damping',
             'line_search_steps'),
}

LEARNER_PARAMS: Dict[str, Param] = {
    'algo': Param('a2c', 'a2c: one gradient step per batch; ppo: clipped surrogate, epochs; '
                         'npg: natural gradient step of KL max_kl; trpo: npg with a line '
                         'search that keeps the KL within max_kl and improves the surrogate',
                  choices=tuple(ALGO_SETTINGS)),
    'learning_rate': Param(1e-3, 'learning rate of the policy', **POSITIVE, live=True),
    'optimizer': Param('adam', 'optimiser of the policy', choices=('rmsprop', 'adam')),
    'ent_coef': Param(0.0, 'entropy bonus weight', low=0.0, live=True),
    'max_grad_norm': Param(0.5, 'gradient clipping of the policy (0: none)', low=0.0, live=True),
    'normalize_advantage': Param(True, 'scale phi to zero mean and unit std per batch', live=True),
    'n_epochs': Param(10, 'ppo: passes over each batch', low=1, live=True),
    'batch_size': Param(64, 'ppo: minibatch size', low=1, live=True),
    'clip_range': Param(0.2, 'ppo: clip range of the probability ratio', **POSITIVE, live=True),
    'max_kl': Param(0.01, 'npg/trpo: KL divergence of one policy step', **POSITIVE, live=True),
    'cg_iters': Param(10, 'npg/trpo: conjugate gradient iterations for F^-1 g', low=1),
    'cg_damping': Param(0.1, 'npg/trpo: damping added to the Fisher matrix in F v', low=0.0),
    'line_search_steps': Param(10, 'trpo: halvings of the step tried before giving up', low=1),
    'total_steps': Param(2_000_000, 'environment steps (all arms) to train for', low=1),
    'checkpoint_every': Param(100, 'policy versions between checkpoints', low=1, live=True),
    'record_arms': Param(4, 'arms of actor 0 whose every step is written to the bag '
                            '(episode summaries are written for all arms)', low=0),
    'record_scene_period': Param(1.0, 'seconds between pg_node/scene messages of recorded '
                                      'arm 0 written to the bag (the arm as sim_node draws '
                                      'it, for RViz on ros2 bag play); 0: none', low=0.0),
    'bag_split_episodes': Param(2000, 'episode summaries per bag file before a split', low=1),
    'exit_when_done': Param(True, 'stop the learner once total_steps are learned'),
    'nice': NICE,
    'sched_idle': SCHED_IDLE,
}


def check_algo_setting(label: str, algo: str, key: str, value) -> None:
    """
    Raise ConfigError if ``key`` is a setting ``algo``'s update lacks, set off its default.

    A value equal to the default passes: the shipped parameter file and ``ros2 param dump``
    list every parameter, every update's settings included, and giving those back changes
    nothing. Any other value would be taken and ignored, so it is refused, naming the
    settings ``algo`` has.
    """
    has = ALGO_SETTINGS[algo]
    if key in has or not any(key in s for s in ALGO_SETTINGS.values()):
        return
    if value != LEARNER_PARAMS[key].default:
        raise ConfigError(f'parameter {label!r}: {value!r} is not allowed: algo {algo!r} has '
                          f'no {key}; its settings: {", ".join(has)}')


def _writable_file(path: str) -> None:
    """Refuse a file name whose directory does not exist (the file is written at the end)."""
    if path and not Path(path).expanduser().parent.is_dir():
        raise ValueError(f'no directory {str(Path(path).expanduser().parent)!r} to write it in')


def arm_indices(text: str) -> List[int]:
    """
    Return the arm indices in ``text`` (``'0, 3'``; empty: none); ValueError if not.

    >>> arm_indices('0, 3'), arm_indices('')
    ([0, 3], [])
    """
    try:
        arms = [int(a) for a in text.replace(',', ' ').split()]
    except ValueError:
        raise ValueError(f'{text!r} is not arm indices separated by commas') from None
    if any(a < 0 for a in arms):
        raise ValueError(f'{text!r}: an arm index is 0 or more')
    return arms


SIM_PARAMS: Dict[str, Param] = {
    'frame_skip': Param(2, 'physics steps per control step', low=1),
    'max_episode_steps': Param(50, 'control steps after which an episode is truncated', low=1),
    'position_delta': Param(0.0, 'rad per control step: position servos: each action is a '
                                 'change of at most this around the measured angle (as '
                                 'arm import --position-delta; the card records it); 0: the '
                                 "model's pg_position_delta, or absolute targets", low=0.0),
    'reward_dist_weight': Param(1.0, 'weight of the fingertip distance in the reward', low=0.0),
    'reward_control_weight': Param(1.0, 'weight of the squared command norm in the reward',
                                   low=0.0),
    'mode': Param('lock_step', 'lock_step: one control step per command; real_time: wall '
                               'clock', choices=('lock_step', 'real_time')),
    'command_interface': Param('control', 'what pg_node/commands carries: control (the '
                                          "policy's units, what the actor sends), or as a "
                                          "robot's controller takes them: effort (N m), "
                                          'position (rad) or velocity (rad/s)',
                               choices=('control', 'effort', 'position', 'velocity')),
    'lock_step_timeout': Param(1.0, 'seconds without a command before the last transition '
                                    'is re-sent (lock_step)', **POSITIVE, live=True),
    'command_timeout': Param(0.5, 'seconds after which a held command drops to zero torque '
                                  '(real_time)', **POSITIVE, live=True),
    'jtc_cmd_timeout': Param(0.2, 'real_time, command_interface effort, position or velocity: '
                                  'the cmd_timeout of the joint trajectory controller the '
                                  'node stands in for on arm_controller/joint_trajectory (s '
                                  'after the last point before its hold: zero effort, the '
                                  'positions measured then, or zero velocity)', **POSITIVE),
    'real_time_factor': Param(1.0, 'simulated seconds per wall second (real_time)', **POSITIVE,
                              live=True),
    'start_paused': Param(False, 'start paused (step with ~/step_simulation)'),
    'marker_rate': Param(10.0, 'MarkerArray rate in Hz of wall time; 0 turns markers off',
                         low=0.0, live=True),
    'marker_spacing': Param(0.7, 'distance in m between arms drawn on the marker grid',
                            low=0.0, live=True),
    'frame_id': Param('world', 'frame of the markers', live=True),
    'view_arms': Param('0', 'arms shown to ROS tools, indices separated by commas (empty: '
                            'none): their joint states with plain names on '
                            'arm<i>/joint_states, their links in pg_node/scene',
                       validate=lambda text: arm_indices(text), numbers_as_text=True),
    'scene_rate': Param(4.0, 'pg_node/scene (the view_arms as robot_description shows them, '
                             'goal, fingertip trail) rate in Hz of wall time while it has a '
                             'subscriber; 0 turns it off', low=0.0, live=True),
    'trail_length': Param(50, "fingertip positions in pg_node/scene's trail", low=0),
    'diagnostics_rate': Param(1.0, 'diagnostics rate in Hz of wall time', **POSITIVE, live=True),
    'physics_threads': Param(0, 'threads stepping the arms (0: as the in-process training '
                                'does, 1 below 32 arms, else one per core up to 4); fewer '
                                'leave a core to the critic and learner while the arms step',
                             low=0),
    'in_process_hop': Param(True, 'when the actor shares the process (sim_and_actor, what '
                                  'train starts): hand transitions and commands to it inside '
                                  'the process, without DDS or an executor wake-up; each '
                                  'is still published on its topic while anyone else '
                                  'subscribes (pg_node.ros.local_hop). false: over DDS'),
    'round_trip_log': Param('', 'lock_step: a .npy file to write every round trip to when the '
                                'node stops (ns from just before a transition is published to '
                                'the arrival of the command that answers it); empty: the round '
                                'trips show only in the diagnostics', validate=_writable_file),
}
# domain randomization: one string per term, off when empty (pg_node.common.perturbations)
for _term, _info in TERMS.items():
    SIM_PARAMS[PARAM_PREFIX + _term] = Param(
        '', f'domain randomization: {_info.description} ({_info.default_op}'
            f'{", " + _info.unit if _info.unit else ""}); "[operation] distribution a b '
            '[reset|startup|every N]" or one value; empty: off (docs/robustness.md)',
        validate=lambda text, _t=_term: parse_term(_t, text), numbers_as_text=True)

#: policy_node: a trained policy run in real time (not part of the training graph, so not in
#: :data:`SCHEMA`, whose nodes ``train`` configures and ``config/pg_node.yaml`` lists).
POLICY_PARAMS: Dict[str, Param] = {
    'policy': Param('', 'the policy to run: a run directory, its checkpoints/, a ckpt_*.pt '
                        'file or an exported .onnx file (with its .json card beside it)'),
    'control_rate': Param(0.0, 'commands per second of wall time (0: one per control step of '
                               'the policy, 1 / control_step)', low=0.0, live=True),
    'state_timeout': Param(0.2, 'seconds after which joint states count as stale, by arrival '
                                'or by header.stamp: the hold command is sent at every tick '
                                'until fresh states come',
                           **POSITIVE, live=True),
    'deterministic': Param(True, 'command the mean action; false: sample from the Gaussian',
                           live=True),
    'seed': Param(0, 'seed of the sampling when deterministic is false', low=0),
    'num_arms': Param(0, 'arms to command (0: as many as joint_states holds, arm<i>/ '
                         'prefixed names, or one arm with plain names)', low=0),
    'diagnostics_rate': Param(1.0, 'diagnostics rate in Hz of wall time', **POSITIVE, live=True),
    'autostart': Param(False, 'configure and activate at start (what play does); false: a '
                              'managed node that waits for its lifecycle transitions'),
    'command_interface': Param('effort', 'what the commands are: joint efforts in N m (motor '
                                         'actuators), joint positions in rad (position '
                                         'actuators) or joint velocities in rad/s (velocity '
                                         'actuators)', choices=('effort', 'position', 'velocity')),
    'ramp_time': Param(0.5, 'seconds over which commands ramp in from the hold command after '
                            'every hold (activation, stale states, an e-stop reset, '
                            'over-speed; 0: at once)', low=0.0, live=True),
    'smoothing': Param(0.0, 'low-pass filter: weight of the previous command, 0 (off) to 0.95',
                       low=0.0, high=0.95, live=True),
    'max_change': Param(0.0, 'largest change of a command per control tick, as a share of '
                             "the actuator's range; 0: from the model, per actuator (effort: "
                             'max_deceleration x the joint inertia, a quarter of the range '
                             'with the default deceleration, so a brake sets in within a few '
                             'ticks; position: max_velocity x the control period, so the '
                             'target never runs ahead of the joint); 1: no limit. The value '
                             'taken is in /diagnostics (max_change_taken)', low=0.0, high=1.0,
                        live=True),
    'joint_limit_margin': Param(0.05, 'rad: effort: the braking guard stops a joint this far '
                                      'inside its limit (its braking distance at '
                                      'max_deceleration added); position: targets are kept '
                                      'this far inside the range', low=0.0, live=True),
    'max_velocity': Param(0.0, 'rad/s: an arm with a faster joint gets the hold command; 0: '
                               "each joint's limit from the model, its torque over its damping "
                               '(the URDF velocity limit for an arm imported with '
                               '--velocity-damping; no check where the model has no damping '
                               'or torque bound). The value taken is in /diagnostics '
                               '(max_velocity_taken)', low=0.0, live=True),
    'hold_damping': Param(0.0, 'N m s/rad: the effort hold is the torque -hold_damping x qdot '
                               '(- hold_stiffness x (q - q_hold)), from the newest state at '
                               "every tick; 0: each joint's damping in the model, the damping "
                               'the policy trained with and a torque-mode robot lacks. The '
                               'value taken is in /diagnostics (hold_damping_taken)', low=0.0,
                          live=True),
    'hold_stiffness': Param(0.0, 'N m/rad: the effort hold also pulls each joint back to the '
                                 'angle where the hold began (0: damping alone; a robot whose '
                                 'gravity compensation is off by some N m sags that N m / '
                                 'hold_stiffness)', low=0.0, live=True),
    'max_deceleration': Param(0.0, 'rad/s^2: the deceleration the effort joint-limit guard '
                                   'plans with: a joint whose stop distance qdot^2 / (2 '
                                   'max_deceleration) reaches joint_limit_margin of a limit is '
                                   "braked; 0: half of each joint's torque over its largest "
                                   'inertia in the model (the other half is slack for the tick '
                                   'and the pose). The value taken is in /diagnostics '
                                   '(max_deceleration_taken)', low=0.0, live=True),
    'max_position_delta': Param(0.0, 'rad: position interface: each target is kept within '
                                     "this of the measured angle; 0: the policy card's "
                                     'max_position_delta (a policy imported with '
                                     '--position-delta commands changes around the measured '
                                     'angle, at most that per control step), none for a '
                                     'policy with absolute targets', low=0.0, live=True),
    'max_acceleration': Param(0.0, 'rad/s^2: velocity interface: the commanded speed changes by '
                                   'at most this per second (holds and ramps included); 0: '
                                   "half of each joint's torque over its largest inertia in "
                                   'the model. The value taken is in /diagnostics '
                                   '(max_acceleration_taken)', low=0.0, live=True),
    'command_message': Param('trajectory', 'trajectory: each command as a one-point '
                                           'trajectory_msgs/JointTrajectory on '
                                           'arm_controller/joint_trajectory (a joint '
                                           'trajectory controller, whose cmd_timeout holds '
                                           'the arm when the commands stop: '
                                           'config/controllers/jtc_*.yaml); forward: '
                                           'std_msgs/Float64MultiArray on '
                                           'arm_controller/commands (forward command '
                                           'controllers, which keep the last command forever '
                                           'when the commands stop)',
                             choices=('trajectory', 'forward')),
    'base_frame': Param('base_link', "frame_id of targets in the arm's base frame (an empty "
                                     'frame_id is taken as this one too)'),
    'marker_rate': Param(10.0, '~/markers (the goal the policy acts on, the fingertip coloured '
                               'by the state: commanding, hold, e-stop, waiting) rate in Hz of '
                               'wall time while it has a subscriber; 0 turns it off', low=0.0,
                         live=True),
    'marker_frame': Param('', 'frame of ~/markers; empty: base_frame for one arm (plain joint '
                              "names), arm<i> for several (sim_node's frames); with sim_node "
                              'in RViz: world'),
    'record': Param('', 'bag directory to record every control tick into (MCAP; empty: none)'),
    'configure_timeout': Param(10.0, 'seconds configure waits for the first joint_states (and '
                                     'robot_description when require_robot_description), '
                                     'then refuses; with autostart too', **POSITIVE),
    'require_robot_description': Param(False, 'configure refuses without a robot_description '
                                              '(else it checks the kinematics only when one '
                                              'was received)'),
    'kinematics_tolerance': Param(0.001, 'm (and unit-vector components of the axes): largest '
                                         "deviation of robot_description's joints from the "
                                         "policy's model that configure accepts (calibrated "
                                         'arms differ by millimetres to centimetres)',
                                  **POSITIVE),
    'controller_name': Param('arm_controller', 'the controller the commands go to: configure '
                                               'reads its joints parameter (service '
                                               '<controller_name>/get_parameters, resolved '
                                               'as the command topic is) and refuses another '
                                               'set or order'),
    'controller_timeout': Param(2.0, "seconds configure waits for the controller's parameter "
                                     'service; then it warns once that the joint order was '
                                     'not checked (0: do not check)', low=0.0),
    'gravity_compensation': Param('', "who carries the arm's weight on this robot: robot (its "
                                      'driver compensates gravity, as a Franka in torque mode '
                                      'does) or policy (nothing does); empty: not stated. '
                                      'Configure warns in one line where it, control_rate or '
                                      "an effort interface contradicts the policy card's "
                                      'physics', choices=('', 'robot', 'policy')),
}

#: pybullet_node: the robot's stand-in on PyBullet (issue 45; not part of the training graph)
PYBULLET_PARAMS: Dict[str, Param] = {
    'model': SHARED_PARAMS['model'],
    'seed': Param(0, 'seed of the episodes: starts and goals drawn as sim_node draws them'),
    'urdf': Param('', "the robot's URDF as shipped (empty: the one arm import made the model "
                      'from, named in its pg_import_command)'),
    'package_path': Param('', 'a folder package:// meshes are looked up in, after '
                              'AMENT_PREFIX_PATH (empty: none)'),
    'frame_skip': Param(2, "the control period is frame_skip x the model's timestep", low=1),
    'max_episode_steps': Param(50, 'control steps after which a new episode starts', low=1),
    'command_interface': Param('effort', 'what the controllers take: effort (N m), position '
                                         '(rad) or velocity (rad/s)',
                               choices=('effort', 'position', 'velocity')),
    'gravity_compensation': Param(True, "the robot cancels the arm's weight (a torque robot's "
                                        'firmware does; effort only: position and velocity '
                                        'motors carry it); false: the commands must hold it'),
    'jtc_cmd_timeout': Param(0.2, 'the cmd_timeout of the joint trajectory controller on '
                                  'arm_controller/joint_trajectory (s after the last point '
                                  'before its hold)', **POSITIVE),
    'real_time_factor': Param(1.0, 'simulated seconds per wall second', **POSITIVE),
}

SCHEMA: Dict[str, Dict[str, Param]] = {
    'sim_node': SIM_PARAMS,
    'actor_node': ACTOR_PARAMS,
    'critic_node': CRITIC_PARAMS,
    'learner_node': LEARNER_PARAMS,
}


def defaults(section: str) -> Dict[str, Any]:
    """Return the default value of every parameter one node reads (shared ones included)."""
    return {k: p.default for k, p in params_for(section).items()}


#: The shared parameters a node reads, where it is not all of them.
NODE_SHARED = {'sim_node': ('model', 'num_envs', 'seed', 'lock_step_groups', 'run_id')}


def params_for(section: str) -> Dict[str, Param]:
    """Return the parameter table of one node, the shared parameters it reads included."""
    shared = {k: p for k, p in SHARED_PARAMS.items()
              if k in NODE_SHARED.get(section, SHARED_PARAMS)}
    return {**shared, **SCHEMA[section]}


def known_keys() -> set:
    """Return every parameter name some pg_node node reads."""
    return set(SHARED_PARAMS).union(*(set(t) for t in SCHEMA.values()))


_OVERRIDE = re.compile(r'([^=:]+)(:?=)(.*)', re.S)


def check_unquoted(overrides: Sequence[str]) -> None:
    """
    Raise ConfigError for a word after ``key=value`` that is no override: unquoted spaces.

    >>> try:
    ...     check_unquoted(['randomize_latency=uniform', '0', '2', 'seed=1'])
    ... except ConfigError as exc:
    ...     print(str(exc).split(': ')[-1])
    'randomize_latency=uniform 0 2'
    """
    texts = list(overrides)
    for i, text in enumerate(texts):
        if i == 0 or _OVERRIDE.fullmatch(text) is not None:
            continue
        if _OVERRIDE.fullmatch(texts[i - 1]) is None:
            return                  # a bare word first: parse_override says what is wrong
        end = i
        while end < len(texts) and _OVERRIDE.fullmatch(texts[end]) is None:
            end += 1
        whole = shlex.quote(' '.join(texts[i - 1:end]))
        raise ConfigError(f'override {text!r} looks like the rest of an override with spaces: '
                          f'quote it: {whole}')


def parse_override(text: str):
    """
    Split ``key=value`` or ``key:=value`` (value parsed as YAML: ``3``, ``0.5``, ``[64, 64]``).

    ``:=`` is how ROS users write a value (``-p key:=value``, launch arguments), so it is
    taken too.

    >>> parse_override('model:=my_arm.xml'), parse_override('actor_node.n_steps=16')
    (('model', 'my_arm.xml'), ('actor_node.n_steps', 16))
    """
    match = _OVERRIDE.fullmatch(text)
    if match is None:
        raise ConfigError(f'override {text!r} is not of the form key=value (or key:=value)')
    key, raw = match.group(1), match.group(3)
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f'override {text!r}: value is not valid YAML ({exc})') from None
    return key.strip(), value


def _did_you_mean(key: str, known) -> str:
    """
    Return ``" (did you mean 'x'?)"`` for the known names closest to ``key``, or nothing.

    >>> _did_you_mean('learning_rte', ['learning_rate', 'gamma'])
    " (did you mean 'learning_rate'?)"
    """
    close = difflib.get_close_matches(key, list(known), n=3, cutoff=0.7)
    return f' (did you mean {" or ".join(repr(c) for c in close)}?)' if close else ''


def load_config(path=None, overrides: Sequence[str] = (), extra_sections=None
                ) -> Dict[str, Dict[str, Any]]:
    """
    Read a parameter file, apply ``key=value`` overrides, validate, fill in defaults.

    Returns ``{section: {key: value}}`` for ``'/**'``, every node in :data:`SCHEMA` and every
    node in ``extra_sections`` (a map of node name to its own table, e.g. ``sim_node``'s).
    A node's value comes from its own section, else from ``/**`` if it is a shared key, else
    from the default; a node of :data:`SCHEMA` also receives every shared key. An override
    ``key=value`` goes to ``/**`` for a shared key, else to every node that has the key;
    ``node.key=value`` sets it in one node only.
    """
    extra = dict(extra_sections or {})
    tables = {SHARED: SHARED_PARAMS}
    tables.update({name: params_for(name) for name in SCHEMA})
    tables.update(extra)
    given = {name: {} for name in tables}
    check_unquoted(overrides)
    if path is not None:
        for name, params in _read_sections(path).items():
            if name not in tables:
                raise ConfigError(f'unknown section {name!r} in {path}; known: '
                                  f'{", ".join(tables)}')
            given[name].update(params)
    for text in overrides:
        key, value = parse_override(text)
        if '.' in key:
            name, _, key = key.partition('.')
            if name not in tables:
                raise ConfigError(f'override {text!r}: unknown node {name!r}; known: '
                                  f'{", ".join(tables)}')
            given[name][key] = value
        elif key in SHARED_PARAMS:
            given[SHARED][key] = value
        else:
            homes = [n for n, t in tables.items() if key in t]
            if not homes:
                known = sorted(set().union(*tables.values()))
                raise ConfigError(f'override {text!r}: unknown parameter {key!r}'
                                  f'{_did_you_mean(key, known)}; known: {", ".join(known)} '
                                  '(node.key=value sets one node only)')
            for name in homes:
                given[name][key] = value
    out = {}
    for name, table in tables.items():
        for key in given[name]:
            if key not in table:
                raise ConfigError(f'unknown parameter {key!r} in section {name!r}'
                                  f'{_did_you_mean(key, table)}; allowed: {", ".join(table)}')
        values = {}
        for key, param in table.items():
            if key in given[name]:
                value = given[name][key]
            elif key in SHARED_PARAMS and key in given[SHARED]:
                value = given[SHARED][key]
            elif key in SHARED_PARAMS:
                value = SHARED_PARAMS[key].default
            else:
                value = param.default
            label = key if name == SHARED else f'{name}.{key}'
            values[key] = param.check(label, value)
        if 'algo' in values:                     # the learner's section
            for key, value in values.items():
                check_algo_setting(f'{name}.{key}', values['algo'], key, value)
        out[name] = values
    return out


def _read_sections(path) -> Dict[str, Dict[str, Any]]:
    """Return ``{section: ros__parameters}`` of a ROS 2 parameter file, checking its shape."""
    try:
        with open(path) as f:
            raw = yaml.safe_load(f) or {}
    except OSError as exc:
        raise ConfigError(f'cannot read config file {path}: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise ConfigError(f'config file {path} is not valid YAML: {exc}') from None
    if not isinstance(raw, dict):
        raise ConfigError(f'config file {path} must map node names to sections')
    out = {}
    for name, section in raw.items():
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ConfigError(f'section {name!r} in {path} must hold a ros__parameters: map')
        out[node_key(str(name))] = params
    return out


def node_key(name: str) -> str:
    """
    Return the section a parameter-file key addresses: ``/**/sim_node`` and ``sim_node``.

    ``/**`` stays itself; ``/**/x``, ``/x`` and ``x`` all mean node ``x`` (pg_node's files use
    ``/**/x``, which reaches node ``x`` in any namespace).
    """
    if name == SHARED:
        return name
    for prefix in ('/**/', '/'):
        if name.startswith(prefix):
            return name[len(prefix):]
    return name


def markdown_table() -> str:
    """
    Return every node's parameters as a Markdown table (docs/ros_graph.md's, kept equal by a test).

    Columns: node (``/**`` for the shared ones), name, default, allowed values, and whether
    ``ros2 param set`` can change it while the node runs (live) or is refused (read-only).
    """
    rows = ['| node | parameter | default | allowed | at run time | meaning |',
            '|---|---|---|---|---|---|']
    for section, table in [(SHARED, SHARED_PARAMS), *SCHEMA.items()]:
        for name, p in table.items():
            rows.append(f'| `{section}` | `{name}` | `{p.default!r}` | {p.allowed()} | '
                        f'{"live" if p.live else "read-only"} | {p.description} |')
    return '\n'.join(rows)


#: the one-line command that writes config/policy_node.yaml from :data:`POLICY_PARAMS`
POLICY_FILE_COMMAND = 'python -m pg_node.common.params > config/policy_node.yaml'
#: what the shipped file says beside a parameter that has no useful default
POLICY_FILE_NOTES = {
    'policy': "REQUIRED: policy_node refuses to start with it empty. Put your policy's path "
              'here, or give it at start: policy:=PATH (ros2 launch pg_node '
              'deploy.launch.py), -p policy:=PATH (ros2 run pg_node policy_node --ros-args)',
}


def yaml_value(value) -> str:
    """
    Return ``value`` as a YAML flow scalar or list, quoted only where YAML needs it.

    >>> [yaml_value(v) for v in ('', 'effort', '0.01', True, 0.2, 3, [64, 64])]
    ["''", 'effort', "'0.01'", 'true', '0.2', '3', '[64, 64]']
    """
    text = yaml.safe_dump(value, default_flow_style=True, width=1000)
    return text.removesuffix('\n...\n').strip()


def parameter_file(node: str, table: Dict[str, Param], header: str, notes=None,
                   width: int = 99) -> str:
    """
    Return a ROS 2 parameter file of one node: every parameter at its default, explained.

    The section is ``/**/<node>``, which reaches the node in any namespace. Above each key,
    as comments: its meaning, its allowed values and whether ``ros2 param set`` may change it
    while the node runs (live) or not (read-only); then ``notes[key]``, if any.
    """
    import textwrap
    notes = notes or {}
    lines = [f'# {line}' if line else '#' for line in header.splitlines()]
    lines += [f'/**/{node}:', '  ros__parameters:']
    for key, p in table.items():
        at_run_time = 'live (ros2 param set)' if p.live else 'read-only'
        text = f'{p.description}. Allowed: {p.allowed()}; {at_run_time}.'
        for part in (text, notes.get(key)):
            if part:
                lines += textwrap.wrap(part, width, initial_indent='    # ',
                                       subsequent_indent='    # ', break_on_hyphens=False)
        lines.append(f'    {key}: {yaml_value(p.default)}')
    return '\n'.join(lines) + '\n'


def policy_node_file() -> str:
    """Return config/policy_node.yaml: :data:`POLICY_PARAMS` at their defaults, explained."""
    header = (
        "policy_node's parameters in ROS 2's parameter-file format, each at its default "
        'with its\nmeaning, allowed values and whether it may change while the node runs. '
        'The key\n/**/policy_node reaches policy_node in any namespace (namespace:= of '
        'deploy.launch.py,\n-r __ns:=). Copy this file, edit it and give it to '
        'launch/deploy.launch.py\n(params_file:=) or to ros2 run pg_node policy_node '
        '--ros-args --params-file FILE.\n\nGenerated from pg_node/common/params.py '
        '(POLICY_PARAMS); a test keeps it equal. Regenerate:\n  ' + POLICY_FILE_COMMAND)
    return parameter_file('policy_node', POLICY_PARAMS, header, POLICY_FILE_NOTES)


if __name__ == '__main__':
    print(policy_node_file(), end='')
