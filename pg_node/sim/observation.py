"""
The task's observation rebuilt from measured joint states, as a robot would give them.

Training reads the observation out of the simulator (:meth:`pg_node.sim.arm_task.ArmTask.
observe`); a policy running on a robot has only joint positions, velocities and the goal.
:class:`ObservationBuilder` makes the same vector from those, laid out by
:class:`pg_node.control.obs_layout.ObsLayout`, the fingertip by forward kinematics
(``mj_kinematics``) of the arm model at the measured angles ``q``.
"""
import mujoco
import numpy as np
from pg_node.sim.arm_task import ArmSpec


class ObservationBuilder:
    """Observations of ``N`` arms of one model from joint angles, velocities and goals."""

    def __init__(self, model: mujoco.MjModel):
        """Read the arm's conventions from ``model`` (ValueError if it does not follow them)."""
        self.model = model
        self.spec = ArmSpec.from_model(model)
        self.data = mujoco.MjData(model)
        self.n_joints = len(self.spec.joint_names)
        self.obs_layout = self.spec.obs_layout
        self.obs_dim = self.obs_layout.size
        self._qpos = self.data.qpos
        self._tip = self.data.site_xpos[self.spec.fingertip_site]
        # joints moved by a joint equality (a URDF <mimic> on the chain, ``arm import``'s
        # coupled joints): (its qpos address, the leader's, the polynomial, both references)
        self._couplings = []
        for e in range(model.neq):
            if model.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT and model.eq_active0[e] \
                    and model.eq_obj2id[e] >= 0:
                a, b = (int(model.jnt_qposadr[model.eq_obj1id[e]]),
                        int(model.jnt_qposadr[model.eq_obj2id[e]]))
                self._couplings.append((a, b, model.eq_data[e, :5].copy(),
                                        float(model.qpos0[a]), float(model.qpos0[b])))

    def _kinematics(self):
        """Move the coupled joints as their equalities say, then run forward kinematics."""
        for _ in range(len(self._couplings)):        # a mimic of a mimic: in enough passes
            for a, b, poly, ref_a, ref_b in self._couplings:
                x = self._qpos[b] - ref_b
                self._qpos[a] = ref_a + poly[0] + x * (poly[1] + x * (poly[2] + x * (
                    poly[3] + x * poly[4])))
        mujoco.mj_kinematics(self.model, self.data)

    def fingertips(self, q: np.ndarray) -> np.ndarray:
        """Return the fingertip positions ``(N, 3)`` of arms at joint angles ``q (N, nj)``."""
        out = np.empty((len(q), 3))
        adr = self.spec.qpos_adr
        for i, angles in enumerate(q):
            self._qpos[adr] = angles
            self._kinematics()
            out[i] = self._tip
        return out

    def reach(self, samples: int = 2000, seed: int = 0):
        """
        Return ``(base, reach)``: the first arm joint's anchor, and how far the fingertip gets.

        The farthest fingertip from the base over ``samples`` joint configurations drawn in
        the joint limits (a full turn where a joint has none): what a target further away
        than this cannot be reached by any pose. Seeded: the same model, the same answer.

        >>> from pg_node.common.paths import resolve_model
        >>> b = ObservationBuilder(mujoco.MjModel.from_xml_path(str(resolve_model('reacher2'))))
        >>> round(b.reach()[1], 3)      # two links of 0.1 m and a fingertip 0.01 m out
        0.21
        """
        rng = np.random.default_rng(seed)
        low, high = self.spec.angle_bounds()
        q = rng.uniform(low, high, size=(samples, self.n_joints))
        self._qpos[self.spec.qpos_adr] = q[0]
        self._kinematics()
        base = self.data.xanchor[self.spec.joint_ids[0]].copy()
        tips = self.fingertips(q)
        return base, float(np.max(np.linalg.norm(tips - base, axis=1)))

    def __call__(self, q, qdot, target) -> np.ndarray:
        """
        Return the observations ``(N, obs_dim)``.

        ``q``, ``qdot``: ``(N, n_joints)`` in the model's joint order; ``target``: ``(N, 3)``
        goal positions in the arm's (world) frame, of which the first ``k`` count.
        """
        q = np.asarray(q, dtype=np.float64)
        qdot = np.asarray(qdot, dtype=np.float64)
        target = np.asarray(target, dtype=np.float64)
        k, at = self.spec.target_dim, self.obs_layout.slices
        obs = np.empty((len(q), self.obs_dim))
        obs[:, at['cos_q']] = np.cos(q)
        obs[:, at['sin_q']] = np.sin(q)
        obs[:, at['target']] = target[:, :k]
        obs[:, at['qdot']] = qdot
        obs[:, at['fingertip_minus_target']] = (self.fingertips(q) - target)[:, :k]
        return obs
