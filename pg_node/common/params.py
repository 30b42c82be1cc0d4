"""
Every node's parameters: default, meaning, and what values are allowed.

One table serves three readers: the nodes declare their ROS parameters from it (with the
description as ``ParameterDescriptor``, so ``ros2 param describe`` explains each), the
``python -m pg_node train`` bring-up validates the YAML file and ``key=value`` overrides
against it before starting anything (:mod:`pg_node.common.config_files`), and the parameter
table of docs/ros_graph.md and config/policy_node.yaml are generated from it
(:mod:`pg_node.tools.param_docs`). What a row is and how a value is checked is
:mod:`pg_node.common.param_schema`.

The YAML file (``config/pg_node.yaml``) follows ROS 2's parameter-file format: a section
``<node_name>: ros__parameters:`` per node, and ``/**: ros__parameters:`` for the values every
node shares (the arm model, the number of arms, the seed, the network shape).
"""
from typing import Any, Dict

from pg_node.common.param_schema import arm_indices, Param, POSITIVE, writable_file
from pg_node.common.paths import check_model
from pg_node.common.perturbations import PARAM_PREFIX, parse_term, TERMS
from pg_node.common.run import check_run_id

#: the parameter-file section of the values every node reads (:data:`SHARED_PARAMS`)
SHARED = '/**'

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

#: the policy updates ``algo`` names: pg_node.rl.updaters.UPDATERS, which this layer cannot
#: import (a test keeps the two equal); which settings each has, its class says
ALGOS = ('a2c', 'ppo', 'npg', 'trpo')

LEARNER_PARAMS: Dict[str, Param] = {
    'algo': Param('a2c', 'a2c: one gradient step per batch; ppo: clipped surrogate, epochs; '
                         'npg: natural gradient step of KL max_kl; trpo: npg with a line '
                         'search that keeps the KL within max_kl and improves the surrogate',
                  choices=ALGOS),
    'learning_rate': Param(1e-3, 'learning rate of the policy', **POSITIVE, live=True),
    'optimizer': Param('adam', 'optimiser of the policy', choices=('rmsprop', 'adam')),
    'ent_coef': Param(0.0, 'entropy bonus weight', low=0.0, live=True),
    'max_grad_norm': Param(0.5, 'gradient clipping of the policy (0: none)', low=0.0, live=True),
    'normalize_advantage': Param(True, 'scale phi to zero mean and unit std per batch', live=True),
    'n_epochs': Param(10, 'ppo: passes over each batch', low=1, live=True),
    'batch_size': Param(64, 'ppo: minibatch size', low=1, live=True),
    'clip_range': Param(0.2, 'ppo: clip range of the probability ratio', **POSITIVE, live=True),
    'target_kl': Param(0.0, "ppo: end a batch's epochs early once the approximate KL after an "
                            'epoch exceeds 1.5 x this (0: never)', low=0.0, live=True),
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
    'jtc_d_gain': Param(0.0, 'real_time, command_interface effort: the d gain (N m s/rad, every '
                             'joint) of the joint trajectory controller the node stands in '
                             "for: its effort is the point's plus d x (the point's velocity "
                             '- the measured one), and it takes points that end with a '
                             'velocity, as config/controllers/jtc_effort_pd.yaml; 0: the zero '
                             'gains of jtc_effort.yaml', low=0.0),
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
                                'trips show only in the diagnostics', validate=writable_file),
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
                               "every tick; 0: the arm's inertia matrix at the measured pose "
                               'over 4 control periods, M(q) qdot / (4 T): a quarter of every '
                               "joint's speed off per tick, coupled joints too, on a robot "
                               'with no damping of its own (never 0 N m). The value taken is '
                               'in /diagnostics (hold_damping_taken)', low=0.0,
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
    'robot_program_running_topic': Param(
        '', "the robot's program state (std_msgs/Bool, transient local): false holds until "
            'it is true again, then ramps in; a UR: '
            '/io_and_status_controller/robot_program_running; empty: not followed'),
    'speed_scaling_topic': Param(
        '', "the robot's speed scaling in percent (std_msgs/Float64): 0 (a protective stop, "
            'a pause) holds until it rises again, then ramps in; a UR: '
            '/speed_scaling_state_broadcaster/speed_scaling; empty: not followed'),
    'marker_rate': Param(10.0, '~/markers (the goal the policy acts on and, when clamped, the '
                               'one requested; the fingertip coloured by the state: '
                               'commanding, hold, e-stop, waiting) rate in Hz of '
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
    'controller_manager': Param('', "ros2_control's controller manager (controller_manager, "
                                    'or /controller_manager at the root); set, configure '
                                    "reads the controller's type, state and parameters from "
                                    'it and refuses one that cannot carry the commands or has '
                                    'no dead-man, and the stops can deactivate it '
                                    '(controller_stop); empty: none (a stand-in)'),
    'allow_no_dead_man': Param(False, 'with controller_manager: drive a controller that keeps '
                                      'the last command when policy_node dies (a forward '
                                      'controller, a JTC without cmd_timeout) all the same'),
    'controller_stop': Param('auto', 'with controller_manager, what an e-stop, a deactivate '
                                     'and a shutdown do besides the hold command: deactivate '
                                     "the arm controller (the robot's own stop acts; it is "
                                     'activated again only by ~/reset_estop or activate), hold '
                                     '(the hold command alone), auto (deactivate on the '
                                     'position and velocity interfaces, hold on effort: JTC '
                                     'deactivated writes 0 N m, which lets an arm whose weight '
                                     'the robot compensates coast)',
                             choices=('auto', 'deactivate', 'hold')),
    'controller_hold': Param('none', 'effort, command_message trajectory: pd: every point carries '
                                     'the measured speeds as its velocities and a hold is the '
                                     'point effort 0, velocity 0, so that a JTC with d gains '
                                     '(config/controllers/jtc_effort_pd.yaml) brakes from its '
                                     'own fresh state, -d x qdot, in a hold and after its '
                                     'cmd_timeout when policy_node dies (with '
                                     'controller_manager, configure checks its gains); none: no '
                                     "velocities, the JTC's timeout hold is 0 N m (zero gains)",
                             choices=('none', 'pd')),
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
    'jtc_d_gain': Param(0.0, 'command_interface effort: the d gain (N m s/rad, every joint) of '
                             'the joint trajectory controller on arm_controller/joint_trajectory '
                             "(its effort: the point's plus d x (the point's velocity - the "
                             'measured one); it takes points that end with a velocity, as '
                             'config/controllers/jtc_effort_pd.yaml); 0: zero gains', low=0.0),
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
