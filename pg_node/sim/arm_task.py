"""
The reaching task on a MuJoCo arm, for ``num_envs`` arms at once (no ROS here).

The default model, ``reacher2``, reproduces Gymnasium's ``Reacher-v5`` step for step; any
MJCF that follows these conventions can be used instead:

* **arm joints** are the joints driven by actuators (``actuator_trntype`` joint), in actuator
  order; they must be hinges. Joint names, limits and control ranges are read from the model.
* a **site named** ``fingertip`` marks the end effector;
* a **body named** ``target`` is the goal. Either it is a mocap body (``mocap_pos`` is set
  to the goal, 3-D goals), or it carries 1-3 un-actuated slide joints along world x, y, z in
  that order whose qpos equals the world coordinate (``ref`` equal to the body position, as
  in Reacher-v5); the goal then has as many dimensions as the target has joints;
* optional ``<custom><numeric>`` fields: ``pg_target_radius`` (disc/ball radius of the goal,
  default 0.2), ``pg_target_center`` (default the origin), ``pg_init_qpos_noise`` (0.1),
  ``pg_init_qvel_noise`` (0.005), ``pg_init_qpos`` (the arm joints' start pose, one angle
  per arm joint; default the model's ``qpos0``) and ``pg_target_points`` (x y z of goals
  the arm can reach, 3 numbers a point, mocap targets only: each goal is one of them, drawn
  uniformly, in place of the ball; ``python -m pg_node arm import`` writes them) and
  ``pg_position_delta`` (position servos only: rad per control step, one or one per arm
  joint; the actions are then changes around the joints' angles, below; a run sets or
  replaces it with ``sim_node``'s ``position_delta``, :func:`with_position_delta`).

Episode start (as ``Reacher-v5.reset_model`` draws it, in the same order, so that an env
seeded like a Gymnasium env draws the same numbers):
``qpos = qpos0 + U(-a, a)`` over all ``nq`` (the arm joints' ``qpos0`` replaced by
``pg_init_qpos`` when given); the goal by rejection,
``g ~ U(-r, r)^k`` until ``|g| < r``, written over the target's qpos (or ``mocap_pos``), or
with ``pg_target_points`` the point of index ``integers(n_points)``;
``qvel = U(-b, b)`` over all ``nv`` with the target's velocities zeroed; then ``mj_forward``.

One control step applies ``act`` as ``ctrl`` (MuJoCo clamps it to ``ctrlrange``); with
``pg_position_delta`` ``d`` the servos' targets are ``clip(q + clip(act, -1, 1) d)`` within
the angles their control range reaches, ``q`` the angles at the step's start
(:mod:`pg_node.control.position_delta`), held for
``frame_skip`` physics steps, then reads

* observation ``[cos q, sin q, target, qdot, (fingertip - target)[:k]]`` with ``q``, ``qdot``
  the arm joints' positions and velocities and ``k`` the goal's dimension (the order and
  slices are :class:`pg_node.control.obs_layout.ObsLayout`'s);
* reward ``r = -reward_dist_weight * |fingertip - target| - reward_control_weight * sum(act^2)``,
  with the positions read after the physics steps from ``data.site_xpos`` exactly as
  Reacher-v5 reads ``data.xpos`` (under RK4 that is the last Runge-Kutta stage's kinematics,
  about 1e-6 m from a fresh ``mj_kinematics``; kept so that the numbers match Gymnasium's);
  ``act`` enters the penalty unclipped, also as in Reacher-v5.

An episode never terminates and is truncated after ``max_episode_steps`` control steps
(never, with ``None``: the Gymnasium wrapper leaves that to ``TimeLimit``).
Ended envs are reset at once (Gymnasium's same-step auto-reset, as SB3's ``VecEnv``): the
returned observation is the new episode's first one and ``info['final_obs']`` holds the
observation the action reached (for every env; it differs from ``obs`` only where an
episode ended), which is what ``V`` must be evaluated on to bootstrap a truncated return.

Randomness: env ``i`` has its own ``numpy.random.Generator(PCG64(SeedSequence(seed + i)))``,
the seeding of Gymnasium's vector envs, so env ``i`` of ``ArmTask(..., seed=s)`` draws what
``gymnasium.make('Reacher-v5').reset(seed=s + i)`` draws.

Stepping: ``mj_step(model, data_i, nstep=frame_skip)`` over one ``MjData`` per env, in a
plain loop, or split over a thread pool (``mj_step`` releases the GIL) from
``THREADS_FROM_ENVS`` envs on (``num_threads``): below it, on a busy 2-core machine, the
threads' hand-offs cost what they gain (``bench/bench_sim.py`` measures the ways). Only
stepping the ``MjData`` leaves the post-step ``xpos`` that Reacher-v5's reward reads, so
``mujoco.rollout`` is not used.
"""
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
import os
from typing import List, Mapping, Optional

import mujoco
import numpy as np
from pg_node.common.bounds import MAX_ABS
from pg_node.common.param_schema import ConfigError
from pg_node.common.perturbations import parse_terms
from pg_node.control import position_delta
from pg_node.control.interfaces import INTERFACES
from pg_node.control.obs_layout import ObsLayout
from pg_node.sim.actuation import actuators, ctrl_range
from pg_node.sim.randomization import Randomizer

FINGERTIP_SITE = 'fingertip'
TARGET_BODY = 'target'
THREADS_FROM_ENVS = 32


class NotAnArm(ConfigError):
    """
    The model compiles but breaks a convention of this module's docstring (docs/mjcf.md).

    A configuration error (the ``model`` parameter's), so a node started on such a model ends
    in one line like any other bad parameter. ``reason`` is what the model lacks; ``path``
    names the file when known.
    """

    def __init__(self, reason: str, path=None):
        self.reason = reason
        where = f'{path} is not a pg_node arm' if path else 'the model is not a pg_node arm'
        super().__init__(f'{where}: {reason} (docs/mjcf.md says what an arm needs)')


def check_arm(path, position_delta=None) -> 'ArmSpec':
    """
    Compile the MJCF at ``path`` and read it as an arm; return its :class:`ArmSpec`.

    ``position_delta``: a run's (:func:`with_position_delta`), checked against the model
    (a :class:`ConfigError` of its own).

    Raises :class:`NotAnArm` in one line naming the file and what it lacks, so that a
    configuration check refuses a model no node could use before any node starts (a
    compiled model that is not an arm made every node crash, restart and crash again).
    """
    model = mujoco.MjModel.from_xml_path(str(path))
    try:
        spec = ArmSpec.from_model(model)
    except NotAnArm as exc:
        raise NotAnArm(exc.reason, path) from None
    return with_position_delta(model, spec, position_delta)


def _custom_numeric(model: mujoco.MjModel, name: str, default):
    """Return the ``<custom><numeric>`` field ``name`` as an array, or ``default``."""
    idx = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if idx < 0:
        return np.asarray(default, dtype=np.float64)
    adr, size = model.numeric_adr[idx], model.numeric_size[idx]
    return np.array(model.numeric_data[adr:adr + size], dtype=np.float64)


@dataclass(frozen=True)
class ArmSpec:
    """What pg_node reads from an arm model: joints, actuators, fingertip and target."""

    joint_names: tuple
    joint_ids: np.ndarray
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    joint_range: np.ndarray
    joint_limited: np.ndarray
    actuator_names: tuple
    ctrl_low: np.ndarray
    ctrl_high: np.ndarray
    fingertip_site: int
    target_body: int
    target_mocap: int
    target_qpos_adr: np.ndarray
    target_dof_adr: np.ndarray
    target_dim: int
    target_radius: float
    target_center: np.ndarray
    init_qpos_noise: float
    init_qvel_noise: float
    link_bodies: np.ndarray
    link_parents: np.ndarray
    init_qpos: Optional[np.ndarray] = None
    target_points: Optional[np.ndarray] = None
    #: rad per control step per arm joint: actions are changes around the measured angle
    #: (``pg_position_delta``, :mod:`pg_node.control.position_delta`); None: absolute
    position_delta: Optional[np.ndarray] = None

    @property
    def obs_layout(self) -> ObsLayout:
        """Return the layout of this arm's observation."""
        return ObsLayout.of(self)

    def angle_bounds(self):
        """Return ``(low, high)`` of the arm joints: their limits, a full turn where none."""
        return (np.where(self.joint_limited, self.joint_range[:, 0], -np.pi),
                np.where(self.joint_limited, self.joint_range[:, 1], np.pi))

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> 'ArmSpec':
        """Read the conventions documented in the module docstring; raise NotAnArm if unmet."""
        if model.nu == 0:
            raise NotAnArm('the model has no actuators, so no arm joints')
        joint_ids, act_names = [], []
        for a in range(model.nu):
            if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
                raise NotAnArm(f'actuator {a} does not drive a joint')
            joint_ids.append(int(model.actuator_trnid[a, 0]))
            act_names.append(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
                             or f'actuator{a}')
        if len(set(joint_ids)) != len(joint_ids):
            raise NotAnArm('two actuators drive the same joint')
        joint_ids = np.array(joint_ids)
        for j in joint_ids:
            if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                raise NotAnArm(f'arm joint {j} is not a hinge')
        names = tuple(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f'joint{j}'
                      for j in joint_ids)
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, FINGERTIP_SITE)
        if site < 0:
            raise NotAnArm(f'the model has no site named {FINGERTIP_SITE!r}')
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, TARGET_BODY)
        if body < 0:
            raise NotAnArm(f'the model has no body named {TARGET_BODY!r}')
        mocap = int(model.body_mocapid[body])
        target_joints = [j for j in range(model.njnt) if model.jnt_bodyid[j] == body]
        if mocap >= 0:
            if target_joints:
                raise NotAnArm('a mocap target cannot have joints')
            dim = 3
        else:
            dim = len(target_joints)
            if not 1 <= dim <= 3:
                raise NotAnArm('the target must be a mocap body or have 1-3 slide joints')
            for k, j in enumerate(target_joints):
                if (model.jnt_type[j] != mujoco.mjtJoint.mjJNT_SLIDE
                        or not np.allclose(model.jnt_axis[j], np.eye(3)[k])):
                    raise NotAnArm('target joints must be slides along world x, y, z in order')
                if model.body_parentid[body] != 0 or not np.isclose(
                        model.body_pos[body][k], model.qpos0[model.jnt_qposadr[j]]):
                    raise NotAnArm('target slide joints need ref equal to the body position '
                                   'and the target body a child of the world')
            if set(target_joints) & set(joint_ids.tolist()):
                raise NotAnArm('target joints must not be actuated')
        center = _custom_numeric(model, 'pg_target_center', np.zeros(dim))
        if center.shape != (dim,):
            raise NotAnArm(f'pg_target_center needs {dim} numbers')
        init_qpos = _custom_numeric(model, 'pg_init_qpos', model.qpos0[
            model.jnt_qposadr[joint_ids]])
        if init_qpos.shape != (len(joint_ids),):
            raise NotAnArm(f'pg_init_qpos needs {len(joint_ids)} numbers (one per arm joint)')
        points = None
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, 'pg_target_points') >= 0:
            points = _custom_numeric(model, 'pg_target_points', [])
            if mocap < 0 or points.size == 0 or points.size % 3:
                raise NotAnArm('pg_target_points needs a mocap target and x y z per point')
            points = points.reshape(-1, 3)
        # bodies that carry an arm joint, and the fingertip's, to draw the links
        chain = sorted({int(model.jnt_bodyid[j]) for j in joint_ids}
                       | {int(model.site_bodyid[site])})
        ctrl_low, ctrl_high = ctrl_range(model)
        delta = None
        numeric = position_delta.MODEL_NUMERIC
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, numeric) >= 0:
            try:
                delta = position_delta.deltas(_custom_numeric(model, numeric, []),
                                              len(joint_ids))
            except ValueError as exc:
                raise NotAnArm(str(exc)) from None
            kinds = set(actuators(model).kind)
            if delta is not None and kinds != {'position'}:
                raise NotAnArm(f'{numeric} needs position servos; the '
                               f'actuators are {", ".join(sorted(kinds))}')
        return cls(
            joint_names=names,
            joint_ids=joint_ids,
            qpos_adr=model.jnt_qposadr[joint_ids].copy(),
            dof_adr=model.jnt_dofadr[joint_ids].copy(),
            joint_range=model.jnt_range[joint_ids].copy(),
            joint_limited=model.jnt_limited[joint_ids].astype(bool),
            actuator_names=tuple(act_names),
            ctrl_low=ctrl_low,
            ctrl_high=ctrl_high,
            fingertip_site=site,
            target_body=body,
            target_mocap=mocap,
            target_qpos_adr=np.array([model.jnt_qposadr[j] for j in target_joints], dtype=int),
            target_dof_adr=np.array([model.jnt_dofadr[j] for j in target_joints], dtype=int),
            target_dim=dim,
            target_radius=float(_custom_numeric(model, 'pg_target_radius', [0.2])[0]),
            target_center=center,
            init_qpos_noise=float(_custom_numeric(model, 'pg_init_qpos_noise', [0.1])[0]),
            init_qvel_noise=float(_custom_numeric(model, 'pg_init_qvel_noise', [0.005])[0]),
            link_bodies=np.array(chain, dtype=int),
            link_parents=model.body_parentid[chain].copy(),
            init_qpos=init_qpos,
            target_points=points,
            position_delta=delta,
        )


def arm_groups(num_envs: int, groups: int) -> List[slice]:
    """
    Split ``num_envs`` arms into ``groups`` contiguous slices of (nearly) equal size.

    >>> arm_groups(64, 2), arm_groups(5, 2)
    ([slice(0, 32, None), slice(32, 64, None)], [slice(0, 2, None), slice(2, 5, None)])
    """
    if not 1 <= groups <= num_envs:
        raise ValueError(f'{groups} groups of {num_envs} arms: need 1 <= groups <= arms')
    bounds = [num_envs * g // groups for g in range(groups + 1)]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def with_position_delta(model: mujoco.MjModel, spec: 'ArmSpec', value) -> 'ArmSpec':
    """
    Return ``spec`` with the position delta ``value`` (rad per control step) of a training run.

    ``value``: one number or one per arm joint; ``None`` or 0 keeps the model's own
    ``pg_position_delta`` (none: absolute targets). A training setting, so that a position
    policy trains with bounded changes without importing its arm again; the policy's card
    records it as an import's delta (``max_position_delta``). Raises :class:`ConfigError`
    (the parameter's) for a model whose actuators are not all position servos, or a value
    that is not one positive number or one per joint.
    """
    try:
        delta = position_delta.deltas(value, len(spec.joint_ids))
    except ValueError as exc:
        raise ConfigError("parameter 'position_delta': " + str(exc).replace(
            position_delta.MODEL_NUMERIC + ' ', '')) from None
    if delta is None:
        return spec
    kinds = set(actuators(model).kind)
    if kinds != {'position'}:
        raise ConfigError(f"parameter 'position_delta' needs position servos; the model's "
                          f'actuators are {", ".join(sorted(kinds))} (import the arm with '
                          f'--actuator position)')
    return replace(spec, position_delta=delta)


class ArmTask:
    """
    ``num_envs`` copies of a reaching task on one MuJoCo arm model, stepped together.

    ``episode_id[i]`` numbers episodes over the task's lifetime (0..N-1 at the first reset,
    then the next free number at each auto-reset, in env order); ``episode_step[i]`` counts
    the control steps taken in env ``i``'s current episode (0 right after a reset).
    """

    def __init__(self, model_path, num_envs: int = 1, seed: Optional[int] = None,
                 frame_skip: int = 2, max_episode_steps: Optional[int] = 50,
                 reward_dist_weight: float = 1.0, reward_control_weight: float = 1.0,
                 num_threads: Optional[int] = None,
                 randomization: Optional[Mapping[str, object]] = None,
                 relative_actions: bool = True, position_delta=None):
        """
        Load the model and make ``num_envs`` simulations of it; call ``reset`` next.

        ``num_threads`` threads step the envs (1: a plain loop); by default 1 below
        ``THREADS_FROM_ENVS`` envs, else the number of CPUs (at most 4).
        ``randomization`` maps terms of :mod:`pg_node.common.perturbations` to their strings
        (or :class:`~pg_node.common.perturbations.TermSpec`); empty or None: the nominal arm.
        ``relative_actions``: with a model's ``pg_position_delta``, actions are changes
        around the joints' angles (:mod:`pg_node.control.position_delta`); False takes them
        as absolute targets (a stand-in robot that gets its angles from ``policy_node``).
        ``position_delta`` (rad per control step, one or one per joint; None or 0: the
        model's): makes the actions such changes on a model without ``pg_position_delta``
        (:func:`with_position_delta`).
        """
        if (num_envs < 1 or frame_skip < 1
                or (max_episode_steps is not None and max_episode_steps < 1)):
            raise ValueError('num_envs, frame_skip and max_episode_steps must be >= 1')
        self.model_path = str(model_path)
        self.model = mujoco.MjModel.from_xml_path(self.model_path)
        self.spec = with_position_delta(self.model, ArmSpec.from_model(self.model),
                                        position_delta)
        self.num_envs = int(num_envs)
        self.frame_skip = int(frame_skip)
        self.max_episode_steps = max_episode_steps
        self.reward_dist_weight = float(reward_dist_weight)
        self.reward_control_weight = float(reward_control_weight)
        self.datas = [mujoco.MjData(self.model) for _ in range(self.num_envs)]
        #: rad per control step per joint when actions are relative (else None)
        self.position_delta = self.spec.position_delta if relative_actions else None
        self._actuators = actuators(self.model)
        self._servos = self._actuators if self.position_delta is not None else None
        # Each ``d.qpos``-style attribute access builds a new numpy view; the views stay
        # valid for the life of their MjData, so take them once and gather with one
        # ``np.array`` per field.
        self._views = {name: [getattr(d, name) for d in self.datas]
                       for name in ('qpos', 'qvel', 'qfrc_actuator', 'xpos', 'site_xpos',
                                    'mocap_pos', 'ctrl')}
        self.dt = self.model.opt.timestep * self.frame_skip
        self.n_joints = len(self.spec.joint_ids)
        self.act_dim = self.model.nu
        self.obs_layout = self.spec.obs_layout
        self.obs_dim = self.obs_layout.size
        self.episode_id = np.zeros(self.num_envs, dtype=np.int64)
        self.episode_step = np.zeros(self.num_envs, dtype=np.int64)
        self.episode_return = np.zeros(self.num_envs)
        #: per arm, the episodes ended because its physics blew up (step's ``blown_up``)
        self.blow_ups = np.zeros(self.num_envs, dtype=np.int64)
        self._reset_by_mujoco = np.zeros(self.num_envs, dtype=bool)
        self._next_episode_id = 0
        self._rngs = []
        terms = parse_terms(randomization or {})
        self.randomizer = None
        if terms:
            self.randomizer = Randomizer(self.model, self.spec, terms, self.num_envs,
                                         0 if seed is None else seed)
        #: the model each env steps with (one per env under a model term, else shared)
        self.models = (self.randomizer.models if self.randomizer is not None
                       else [self.model] * self.num_envs)
        self._seed(seed)
        if num_threads is None:
            num_threads = (1 if self.num_envs < THREADS_FROM_ENVS
                           else min(4, os.cpu_count() or 1))
        self.num_threads = max(1, min(int(num_threads), self.num_envs))
        self._pool = None
        self._chunks = [range(self.num_envs)]
        if self.num_threads > 1:
            # the calling thread steps the first chunk itself: one hand-off fewer per step
            self._pool = ThreadPoolExecutor(self.num_threads - 1, thread_name_prefix='arm_task')
            bounds = np.linspace(0, self.num_envs, self.num_threads + 1).astype(int)
            self._chunks = [range(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    def close(self):
        """Stop the stepping threads, if any."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def _seed(self, seed: Optional[int]):
        """Give env ``i`` the generator ``PCG64(SeedSequence(seed + i))``."""
        if seed is None:
            seed = int(np.random.SeedSequence().entropy)
        if self.randomizer is not None:
            self.randomizer.seed(seed)
        self._rngs = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed + i)))
                      for i in range(self.num_envs)]

    @property
    def rngs(self):
        """Return the per-env random generators (env ``i`` draws only from ``rngs[i]``)."""
        return self._rngs

    def reset(self, seed: Optional[int] = None) -> np.ndarray:
        """Start a new episode in every env and return the observations ``(N, obs_dim)``."""
        if seed is not None:
            self._seed(seed)
        for i in range(self.num_envs):
            self.reset_env(i)
        return self.observe()

    def reset_env(self, i: int):
        """Draw env ``i``'s initial state and goal as Reacher-v5 does (module docstring)."""
        m, d, s, rng = self.model, self.datas[i], self.spec, self._rngs[i]
        mujoco.mj_resetData(m, d)
        qpos = rng.uniform(low=-s.init_qpos_noise, high=s.init_qpos_noise, size=m.nq) + m.qpos0
        qpos[s.qpos_adr] += s.init_qpos - m.qpos0[s.qpos_adr]
        if s.target_points is not None:
            goal = s.target_points[rng.integers(len(s.target_points))].copy()
        else:
            # the goal, uniform in the disc/ball by rejection (Reacher-v5's loop)
            while True:
                goal = rng.uniform(low=-s.target_radius, high=s.target_radius,
                                   size=s.target_dim)
                if np.linalg.norm(goal) < s.target_radius:
                    break
            if np.any(s.target_center):
                goal = goal + s.target_center
        qvel = rng.uniform(low=-s.init_qvel_noise, high=s.init_qvel_noise, size=m.nv)
        if s.target_mocap >= 0:
            d.mocap_pos[s.target_mocap] = goal
        else:
            qpos[s.target_qpos_adr] = goal
            qvel[s.target_dof_adr] = 0.0
        d.qpos[:] = qpos
        d.qvel[:] = qvel
        if self.randomizer is not None:
            self.randomizer.on_reset(i, self.hold_controls(qpos[s.qpos_adr]))
            m = self.randomizer.models[i]
        mujoco.mj_forward(m, d)
        self.episode_id[i] = self._next_episode_id
        self._next_episode_id += 1
        self.episode_step[i] = 0
        self.episode_return[i] = 0.0

    def hold_controls(self, q: np.ndarray) -> np.ndarray:
        """
        Return the controls that apply no force to the arm at rest at angles ``q``.

        ``-(b0 + b1 q) / gain`` of each actuator's affine law
        (:mod:`pg_node.control.interfaces`): zero for the motors and velocity servos
        ``arm import`` writes, the control of the angle ``q`` for a position servo; zero for
        an actuator that does not follow the law. What the servo terms take as the command
        before an episode (:meth:`pg_node.sim.randomization.Randomizer.on_reset`).
        """
        act = self._actuators
        with np.errstate(divide='ignore', invalid='ignore'):
            hold = -(act.b0 + act.b1 * np.asarray(q, dtype=float)) / act.gain
        return np.where(act.affine, hold, 0.0)

    def set_state(self, i: int, qpos, qvel, target=None):
        """Put env ``i`` in a given state (and goal), as Gymnasium's ``set_state`` does."""
        d, s = self.datas[i], self.spec
        d.qpos[:] = qpos
        d.qvel[:] = qvel
        if target is not None:
            if s.target_mocap >= 0:
                d.mocap_pos[s.target_mocap] = target
            else:
                d.qpos[s.target_qpos_adr] = target
                d.qvel[s.target_dof_adr] = 0.0
        mujoco.mj_forward(self.models[i], d)

    def _gather(self, name: str, arms: slice = slice(None)) -> np.ndarray:
        """Return field ``name`` of the envs ``arms`` stacked: ``(n, ...)``, a copy."""
        return np.array(self._views[name][arms])  # 2-5x faster than np.stack for these lists

    def fingertip_pos(self) -> np.ndarray:
        """Return the fingertips' world positions ``(N, 3)`` as the last step left them."""
        return self._gather('site_xpos')[:, self.spec.fingertip_site]

    def target_pos(self) -> np.ndarray:
        """Return the goals' world positions ``(N, 3)``."""
        return self._gather('xpos')[:, self.spec.target_body]

    def joint_state(self):
        """
        Return arm joint ``(position, velocity, effort)``, each ``(N, n_joints)``.

        The effort is the actuator force on the joint (``qfrc_actuator``), in N m. Under
        observation noise, positions and velocities carry the current observation's noise
        (what a noisy encoder reports).
        """
        s, r = self.spec, self.randomizer
        pos, vel = self._gather('qpos')[:, s.qpos_adr], self._gather('qvel')[:, s.dof_adr]
        if r is not None and r.has_obs_noise:
            pos, vel = pos + r.noise_q, vel + r.noise_v
        return pos, vel, self._gather('qfrc_actuator')[:, s.dof_adr]

    def link_positions(self) -> np.ndarray:
        """Return ``(N, L, 2, 3)`` segments from each arm body's parent to the body, then tip."""
        s = self.spec
        xpos = self._gather('xpos')
        out = np.empty((self.num_envs, len(s.link_bodies) + 1, 2, 3))
        out[:, :-1, 0] = xpos[:, s.link_parents]
        out[:, :-1, 1] = xpos[:, s.link_bodies]
        out[:, -1, 0] = xpos[:, s.link_bodies[-1]]
        out[:, -1, 1] = self.fingertip_pos()
        return out

    def observe(self) -> np.ndarray:
        """Return the observations ``(N, obs_dim)`` of the current states."""
        return self._observe()[0]

    def _observe(self, arms: slice = slice(None)):
        """Return the observations and the fingertip-minus-target vectors ``(n, 3)``."""
        s, at = self.spec, self.obs_layout.slices
        k = s.target_dim
        qpos = self._gather('qpos', arms)
        obs = np.empty((len(qpos), self.obs_dim))
        q = qpos[:, s.qpos_adr]
        obs[:, at['qdot']] = self._gather('qvel', arms)[:, s.dof_adr]
        obs[:, at['target']] = (self._gather('mocap_pos', arms)[:, s.target_mocap]
                                if s.target_mocap >= 0 else qpos[:, s.target_qpos_adr])
        target = self._gather('xpos', arms)[:, s.target_body]
        vec = self._gather('site_xpos', arms)[:, s.fingertip_site] - target
        r = self.randomizer
        if r is not None and r.has_obs_noise:
            # sensors, not the world: the true vec stays for the reward
            seen = vec
            if 'obs_noise' in r.terms:
                q = q + r.noise_q[arms]
                seen = r.fingertips(q) - target
            obs[:, at['qdot']] += r.noise_v[arms]
            obs[:, at['target']] += r.noise_t[arms]
            obs[:, at['fingertip_minus_target']] = seen[:, :k] - r.noise_t[arms]
        else:
            obs[:, at['fingertip_minus_target']] = vec[:, :k]
        obs[:, at['cos_q']] = np.cos(q)
        obs[:, at['sin_q']] = np.sin(q)
        return obs, vec

    def _chunks_of(self, lo: int, hi: int):
        """Return the envs ``lo..hi-1`` split into one range per stepping thread."""
        if (lo, hi) == (0, self.num_envs):
            return self._chunks
        bounds = np.linspace(lo, hi, min(self.num_threads, hi - lo) + 1).astype(int)
        return [range(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    def step(self, act, arms: Optional[slice] = None):
        """
        Apply ``act (n, act_dim)`` to the envs ``arms`` for one control step; auto-reset.

        ``arms`` is a slice of the envs (default all, ``n = N``): a lock-step simulator that
        steps its arms in groups steps each group when its command comes. The envs do not
        interact, so stepping groups in turn is stepping them all, to the bit.

        Return ``obs, reward, terminated, truncated, info`` of those envs, with ``info``
        holding ``final_obs`` (the observation the action reached), ``episode_id`` and
        ``episode_step`` of the returned observation, ``final_episode_id`` (the episode
        the action was taken in), ``episode_return`` / ``episode_length`` (NaN / 0 where
        no episode ended), the two reward terms ``reward_dist`` and ``reward_ctrl`` and
        ``distance``, the true fingertip-to-target distance in m after the step, and
        ``blown_up``: the arms whose observation passed :data:`pg_node.common.bounds.MAX_ABS`
        (or was not finite), or whose state MuJoCo found bad and reset to the model's pose
        (its "simulation is unstable" warning): their episode ends there (``terminated``, no
        value after it) with the observation and reward bounded, and they are reset and
        counted (``blow_ups``).
        """
        lo, hi, _ = (slice(None) if arms is None else arms).indices(self.num_envs)
        sl = slice(lo, hi)
        act = np.asarray(act, dtype=np.float64)
        if act.shape != (hi - lo, self.act_dim):
            raise ValueError(f'act has shape {act.shape}, expected '
                             f'{(hi - lo, self.act_dim)}')
        n, datas, ctrl, models = self.frame_skip, self.datas, self._views['ctrl'], self.models
        applied, r = act, self.randomizer
        if self.position_delta is not None:
            # the action is a change around the joint's angle: the servo gets the target
            servo = INTERFACES['position']
            low, high = servo.si_range(self._servos)       # the angles the servos reach
            q = self._gather('qpos', sl)[:, self.spec.qpos_adr]
            target = position_delta.targets(act, q, self.position_delta, low, high)
            applied = servo.from_si(self._servos, target)
        if r is not None:
            r.before_step(lo, hi)
            applied = r.applied_action(applied, lo, hi)

        reset_by_mujoco = self._reset_by_mujoco

        def advance(envs):
            for i in envs:
                before = datas[i].time
                if r is not None and r.per_physics_step:    # servo tracking, payload
                    r.physics_steps(i, applied[i - lo], models[i], datas[i], n)
                else:
                    ctrl[i][:] = applied[i - lo]
                    mujoco.mj_step(models[i], datas[i], nstep=n)
                # MuJoCo resets a state gone bad itself (mj_checkPos/Vel/Acc: a warning,
                # mj_resetData, the time back to 0): the arm jumped to its model pose
                reset_by_mujoco[i] = datas[i].time < before + (n - 0.5) * models[i].opt.timestep

        chunks = self._chunks_of(lo, hi)
        others = [self._pool.submit(advance, c) for c in chunks[1:]] if self._pool else ()
        advance(chunks[0])
        for job in others:
            job.result()
        if r is not None and r.has_obs_noise:
            for i in range(lo, hi):
                r.draw_noise(i)
        obs, vec = self._observe(sl)
        # reward from the post-step positions, in Reacher-v5's order of operations
        distance = np.sqrt(np.einsum('ij,ij->i', vec, vec))
        reward_dist = -distance
        reward_dist *= self.reward_dist_weight
        reward_ctrl = -np.square(act).sum(axis=1) * self.reward_control_weight
        reward = reward_dist + reward_ctrl
        # physics that blew up (an unstable model, a torque far beyond what it can take):
        # the episode ends there, its values bounded, and the arm starts a new one
        blown = ~(np.abs(obs).max(axis=1) <= MAX_ABS) | reset_by_mujoco[sl]  # NaN counts
        if blown.any():
            obs = np.clip(np.nan_to_num(obs), -MAX_ABS, MAX_ABS)
            # the distance term of a finite fingertip stays (the arm's reach bounds it); a
            # non-finite one gives nothing rather than a value that would swamp the batch
            reward = np.where(np.isfinite(reward), reward, 0.0)
            self.blow_ups[sl] += blown
        self.episode_step[sl] += 1
        self.episode_return[sl] += reward
        terminated = blown
        if self.max_episode_steps is None:
            truncated = np.zeros(hi - lo, dtype=bool)
        else:
            truncated = self.episode_step[sl] >= self.max_episode_steps
        done = terminated | truncated
        final_obs = obs.copy()
        info = {
            'final_obs': final_obs,
            'final_episode_id': self.episode_id[sl].copy(),
            'episode_return': np.where(done, self.episode_return[sl], np.nan),
            'episode_length': np.where(done, self.episode_step[sl], 0),
            'reward_dist': reward_dist,
            'reward_ctrl': reward_ctrl,
            'distance': distance,
            'blown_up': blown,
        }
        for i in np.flatnonzero(done):
            self.reset_env(lo + int(i))
        if done.any():
            obs = obs.copy()
            obs[done] = self._observe(sl)[0][done]
        info['episode_id'] = self.episode_id[sl].copy()
        info['episode_step'] = self.episode_step[sl].copy()
        return obs, reward, terminated, truncated, info
