"""
The terms of :mod:`pg_node.common.perturbations` applied to the arms of an ``ArmTask``.

:class:`Randomizer` holds what differs per arm: a copy of the ``MjModel`` with its drawn
masses, damping, friction, armature and gears (only when such a term is on; the arms
share one model otherwise), each arm's recent commands (latency), its servos' state (their
dead time's recent inputs and their lag's output) and the noise of its next observation.
It draws from generators of its own, so the task's episode starts are the same with and
without it.
"""
import copy
import math
from typing import Dict, List, Mapping

import mujoco
import numpy as np
from pg_node.common.perturbations import BadTerm, POSITIVE, STREAM, TERMS, TermSpec

#: the joint terms and the ``MjModel`` field of the arm joints' dofs each one changes
DOF_FIELDS = {'damping': 'dof_damping', 'frictionloss': 'dof_frictionloss',
              'armature': 'dof_armature'}


def _arm_bodies(model: mujoco.MjModel, target_body: int) -> np.ndarray:
    """Return the bodies that are links of the arm: not the world, not the target's."""
    bodies = []
    for b in range(1, model.nbody):
        root = b
        while model.body_parentid[root] != 0:
            root = model.body_parentid[root]
        if b != target_body and root != target_body and model.body_mass[b] > 0:
            bodies.append(b)
    return np.array(bodies, dtype=int)


class Randomizer:
    """
    The terms of one :class:`~pg_node.sim.arm_task.ArmTask`, for its ``num_envs`` arms.

    Holds one ``MjModel`` per arm when a model term is on (they differ), the arms' command
    histories for latency, and the current noise of each arm's observation.
    """

    def __init__(self, model: mujoco.MjModel, spec, terms: Mapping[str, TermSpec],
                 num_envs: int, seed: int):
        self.base = model
        self.terms = dict(terms)
        self.num_envs = num_envs
        self.nj, self.k = len(spec.joint_ids), spec.target_dim
        self.act_dim = model.nu
        self.bodies = _arm_bodies(model, spec.target_body)
        self.dofs = np.asarray(spec.dof_adr)
        self._check_nominal()
        has_model_terms = any(TERMS[t].kind == 'model' for t in self.terms)
        self.models = ([copy.deepcopy(model) for _ in range(num_envs)] if has_model_terms
                       else [model] * num_envs)
        self._scratch = [mujoco.MjData(m) for m in self.models] if has_model_terms else None
        # each term's columns of ``values``: one per link / joint / motor it draws for
        self.cols, self.labels = {}, []
        for term, labels in self._labels(model).items():
            self.cols[term] = slice(len(self.labels), len(self.labels) + len(labels))
            self.labels += labels
        self.values = np.full((num_envs, len(self.labels)), np.nan)
        latency = self.terms.get('latency')
        self.history = (int(math.floor(latency.bounds[1])) + 1) if latency else 1
        self.hist = np.zeros((num_envs, self.history, self.act_dim))
        self.latency = np.zeros(num_envs, dtype=np.int64)
        self.noise_q = np.zeros((num_envs, self.nj))
        self.noise_v = np.zeros((num_envs, self.nj))
        self.noise_t = np.zeros((num_envs, self.k))
        # the noise terms that are on: (array the noise goes to, column of its std)
        self._noise = [(out, self.cols[t].start) for t, out in (
            ('obs_noise', self.noise_q), ('vel_noise', self.noise_v),
            ('target_noise', self.noise_t)) if t in self.terms]
        self._noise_width = sum(out.shape[1] for out, _ in self._noise)
        self.steps = np.zeros(num_envs, dtype=np.int64)
        self._fk = mujoco.MjData(model) if 'obs_noise' in self.terms else None
        self._qpos_adr, self._tip = spec.qpos_adr, spec.fingertip_site
        # servo tracking and payload act at every physics step (physics_steps)
        self.timestep = float(model.opt.timestep)
        servo_latency = self.terms.get('servo_latency')
        self.sub_history = (int(round(servo_latency.bounds[1] / self.timestep)) + 1
                            if servo_latency else 1)
        self.sub_hist = np.zeros((num_envs, self.sub_history, self.act_dim))
        self.servo_out = np.zeros((num_envs, self.act_dim))
        self.per_physics_step = any(t in self.terms for t in
                                    ('servo_bandwidth', 'servo_latency', 'payload'))
        self._tip_body = int(model.site_bodyid[self._tip])
        self.seed(seed)

    def _nominal(self, term: str) -> np.ndarray:
        """Return the nominal model's values that model term ``term`` changes."""
        if term == 'mass':
            return self.base.body_mass[self.bodies]
        if term == 'gear':
            return self.base.actuator_gear[:, 0]
        return getattr(self.base, DOF_FIELDS[term])[self.dofs]

    def _check_nominal(self):
        """Refuse an ``add`` whose range takes a nominal value below zero."""
        for term, spec in self.terms.items():
            if spec.operation != 'add' or TERMS[term].kind != 'model':
                continue
            lowest = float(np.min(self._nominal(term))) + spec.bounds[0]
            positive = term in POSITIVE
            if lowest < 0 or (lowest <= 0 and positive):
                raise BadTerm(f'{term} {spec.text()}: the {term} of this model would reach '
                              f'{lowest:g}; it must stay {"> 0" if positive else ">= 0"}')
        if 'mass' in self.terms and not len(self.bodies):
            raise BadTerm('mass: this model has no links with mass to change')

    def _labels(self, model) -> Dict[str, List[str]]:
        """Name each term's drawn values: ``mass/<body>``, ``damping/<joint>``, ``latency``."""
        def name(kind, i):
            return mujoco.mj_id2name(model, kind, int(i)) or str(int(i))
        labels = {}
        for term in self.terms:
            if term == 'mass':
                labels[term] = [f'mass/{name(mujoco.mjtObj.mjOBJ_BODY, b)}'
                                for b in self.bodies]
            elif term in DOF_FIELDS:
                labels[term] = [f'{term}/{name(mujoco.mjtObj.mjOBJ_JOINT, j)}'
                                for j in model.dof_jntid[self.dofs]]
            elif term in ('gear', 'servo_bandwidth'):
                labels[term] = [f'{term}/{name(mujoco.mjtObj.mjOBJ_ACTUATOR, a)}'
                                for a in range(model.nu)]
            else:
                labels[term] = [term]
        return labels

    def seed(self, seed: int):
        """Give arm ``i`` the generator ``PCG64(SeedSequence(seed + i, spawn_key=(1,)))``."""
        self.rngs = [np.random.Generator(np.random.PCG64(
            np.random.SeedSequence(int(seed) + i, spawn_key=(STREAM,))))
            for i in range(self.num_envs)]
        self.drawn = set()
        for i in range(self.num_envs):
            self._draw(i, startup=True)

    def _sample(self, spec: TermSpec, rng, size) -> np.ndarray:
        if spec.distribution == 'uniform':
            if spec.term == 'latency':
                return rng.integers(int(spec.a), int(spec.b) + 1, size=size).astype(float)
            return rng.uniform(spec.a, spec.b, size=size)
        if spec.distribution == 'log_uniform':
            x = np.exp(rng.uniform(math.log(spec.a), math.log(spec.b), size=size))
        else:
            x = np.clip(rng.normal(spec.a, spec.b, size=size), *spec.bounds)
        return np.rint(x) if spec.term == 'latency' else x

    def _draw(self, i: int, startup: bool = False, every: bool = False):
        """Draw arm ``i``'s terms that are due: at startup all, else by their ``when``."""
        rng, changed_model = self.rngs[i], False
        for term, spec in self.terms.items():
            due = (startup or (spec.when == 'reset' and not every)
                   or (spec.when == 'every' and every))
            if due:
                cols = self.cols[term]
                self.values[i, cols] = self._sample(spec, rng, cols.stop - cols.start)
                changed_model |= TERMS[term].kind == 'model'
                self.drawn.add(i)
        if changed_model:
            self._apply_model(i)
        if 'latency' in self.terms:
            self.latency[i] = int(self.values[i, self.cols['latency']][0])

    def value(self, i: int, term: str) -> np.ndarray:
        """Return arm ``i``'s current draw of ``term`` (one value per link/joint/motor)."""
        return self.values[i, self.cols[term]]

    def _apply_model(self, i: int):
        """Write arm ``i``'s model terms over the nominal values of its own ``MjModel``."""
        m, base = self.models[i], self.base

        def applied(term):
            spec, v, nominal = self.terms[term], self.value(i, term), self._nominal(term)
            if spec.operation == 'scale':
                return nominal * v
            if spec.operation == 'add':
                return nominal + v
            return np.broadcast_to(v, nominal.shape).copy()

        if 'mass' in self.terms:
            b = self.bodies
            mass = applied('mass')
            m.body_mass[b] = mass
            m.body_inertia[b] = base.body_inertia[b] * (mass / base.body_mass[b])[:, None]
        for term, field in DOF_FIELDS.items():
            if term in self.terms:
                getattr(m, field)[self.dofs] = applied(term)
        if 'gear' in self.terms:
            m.actuator_gear[:, 0] = applied('gear')
        # the constants MuJoCo derives from masses and armature (invweight0, ...)
        mujoco.mj_setConst(m, self._scratch[i])

    def on_reset(self, i: int, hold=0.0):
        """
        Arm ``i`` starts an episode: redraw its reset terms, clear its commands.

        ``hold``: the controls the commands before the episode are taken to be (the
        latency history, the servo's dead time and lag), the ones that hold the arm where it
        starts (:meth:`pg_node.sim.arm_task.ArmTask.hold_controls`): zero for motors and
        velocity servos, the start angle for position servos, whose zero control is the
        middle of the joint's range.
        """
        self._draw(i)
        self.hist[i] = hold
        self.sub_hist[i] = hold
        self.servo_out[i] = hold
        self.draw_noise(i)

    def before_step(self, lo: int, hi: int):
        """Redraw the ``every N`` terms of arms ``lo..hi-1`` that are due."""
        periodic = [s.every for s in self.terms.values() if s.when == 'every']
        if periodic:
            for i in range(lo, hi):
                if any(self.steps[i] and self.steps[i] % n == 0 for n in periodic):
                    self._draw(i, every=True)
        self.steps[lo:hi] += 1

    def applied_action(self, act: np.ndarray, lo: int, hi: int) -> np.ndarray:
        """Return the commands arms ``lo..hi-1`` apply now: late by their latency, noisy."""
        if self.history > 1:
            self.hist[lo:hi, 1:] = self.hist[lo:hi, :-1]
            self.hist[lo:hi, 0] = act
            act = self.hist[np.arange(lo, hi), self.latency[lo:hi]]
        spec = self.terms.get('action_noise')
        if spec is not None:
            act = act + np.stack([self.rngs[i].standard_normal(self.act_dim)
                                  for i in range(lo, hi)]) * self._std('action_noise', lo, hi)
        return act

    def physics_steps(self, i: int, act: np.ndarray, model: mujoco.MjModel,
                      data: mujoco.MjData, n: int):
        """
        Step arm ``i`` ``n`` physics steps with command ``act``, through its servos, loaded.

        At each physics step the command enters the servo's dead time (``servo_latency``,
        whole physics steps), whose output ``x`` drives the first-order lag
        ``dy/dt = (x - y) / tau``, ``tau = 1 / (2 pi servo_bandwidth)``, advanced exactly
        over the step (``y += (1 - exp(-timestep / tau)) (x - y)``, ``x`` held over the step)
        and applied as ``ctrl`` during that step: from rest, a unit step reads
        ``1 - exp(-k timestep / tau)`` after ``k`` steps. Without a bandwidth ``y = x``.
        ``payload``: its weight pulls at the fingertip site, as ``qfrc_applied`` computed
        from the site's position the previous step left (the newest MuJoCo has).
        """
        bandwidth = self.terms.get('servo_bandwidth')
        alpha = (-np.expm1(-2 * math.pi * self.value(i, 'servo_bandwidth') * self.timestep)
                 if bandwidth else None)
        delay = (int(round(self.value(i, 'servo_latency')[0] / self.timestep))
                 if 'servo_latency' in self.terms else 0)
        weight = (self.value(i, 'payload')[0] * model.opt.gravity
                  if 'payload' in self.terms else None)
        hist, y = self.sub_hist[i], self.servo_out[i]
        for _ in range(n):
            x = act
            if self.sub_history > 1:
                hist[1:] = hist[:-1]
                hist[0] = act
                x = hist[delay]
            if alpha is None:
                y[:] = x
            else:
                y += alpha * (x - y)
            data.ctrl[:] = y
            if weight is not None:
                data.qfrc_applied[:] = 0.0
                mujoco.mj_applyFT(model, data, weight, np.zeros(3),
                                  data.site_xpos[self._tip].copy(), self._tip_body,
                                  data.qfrc_applied)
            mujoco.mj_step(model, data)

    def _std(self, term: str, lo: int, hi: int) -> np.ndarray:
        return self.values[lo:hi, self.cols[term]]

    def draw_noise(self, i: int):
        """Draw arm ``i``'s observation noise for its next observation (one draw)."""
        if not self._noise_width:
            return
        z, col = self.rngs[i].standard_normal(self._noise_width), 0
        for out, std_col in self._noise:
            width = out.shape[1]
            out[i] = z[col:col + width] * self.values[i, std_col]
            col += width

    def take_drawn(self) -> List[int]:
        """Return the arms that drew new values since the last call (sorted), and forget."""
        drawn, self.drawn = sorted(self.drawn), set()
        return drawn

    def fingertips(self, q: np.ndarray) -> np.ndarray:
        """
        Return the fingertips ``(n, 3)`` at joint angles ``q``, by forward kinematics.

        Under ``obs_noise`` the observation's fingertip-to-target part is computed from the
        noisy angles, as a robot computes it from its encoders (ObservationBuilder).
        """
        out, d = np.empty((len(q), 3)), self._fk
        for i, angles in enumerate(q):
            d.qpos[self._qpos_adr] = angles
            mujoco.mj_kinematics(self.base, d)
            out[i] = d.site_xpos[self._tip]
        return out

    @property
    def has_obs_noise(self) -> bool:
        """Return whether any observation noise term is on."""
        return bool(self._noise_width)
