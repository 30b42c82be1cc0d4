"""
A trained policy outside training: found from a run, a checkpoint or an exported file.

Three sources give the same thing, a :class:`TrainedPolicy` that maps numpy observations to
the Gaussian's mean and standard deviation, plus its *card*: what a robot needs to feed it
and read it (observation layout, joint names, control range, control step, the arm model):

* a run directory (its ``checkpoints/``, the newest readable one), a directory of
  ``ckpt_*.pt`` files or one such file: the policy network in torch, the card built from
  the checkpoint's configuration and the run's ``params.yaml`` (``frame_skip`` and the
  ``randomize_<term>`` terms, which the card's ``physics`` records);
* an exported ``*.onnx`` file (:mod:`pg_node.rl.onnx_export`) with its card beside it as
  JSON (``policy.onnx`` -> ``policy.json``): run by onnxruntime, torch is never imported.

Every problem with a source is a :class:`PolicySourceError` whose message is one line.
"""
import json
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
from pg_node.common.run_dir import RunDir

CARD_FORMAT = 'pg_node policy card 1'


class PolicySourceError(ValueError):
    """A policy source that cannot be used; the message says why, in one line."""


def sidecar_path(onnx_path) -> Path:
    """Return where the card of an exported policy lives: ``x.onnx`` -> ``x.json``."""
    return Path(onnx_path).with_suffix('.json')


def find_checkpoint(path) -> Tuple[dict, Path]:
    """
    Return ``(state, file)``: the policy checkpoint that ``path`` names.

    ``path`` is a run directory (with ``checkpoints/``), a directory of ``ckpt_*.pt`` files
    (the newest that loads) or one such file; a critic's checkpoint is refused.
    """
    import torch
    from pg_node.rl.checkpoint import list_checkpoints, load_latest
    path = Path(path)
    if path.is_dir() and RunDir(path).checkpoints.is_dir():
        path = RunDir(path).checkpoints
    if path.is_dir():
        state, _ = load_latest(path)
        if state is None:
            raise PolicySourceError(f'no readable checkpoint in {path} (give a run directory, '
                                    f'its checkpoints/, a ckpt_*.pt file or an .onnx file)')
        file = next(p for p, v in list_checkpoints(path) if v == state['version'])
    elif path.is_file():
        try:
            state = torch.load(path, map_location='cpu', weights_only=False)
        except Exception as exc:  # noqa: B902 - any unreadable file is reported, in one line
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise PolicySourceError(f'cannot read checkpoint {path}: {first}') from None
        file = path
    else:
        raise PolicySourceError(f'no such file or directory: {path}')
    if not isinstance(state, dict) or not {'policy', 'config', 'obs_dim'} <= set(state):
        kind = ('critic (value function)' if isinstance(state, dict) and 'value_fn' in state
                else 'no')
        raise PolicySourceError(f'{path} holds {kind} checkpoints, not policy ones; give the '
                                f'run directory or its checkpoints/')
    return state, file


def run_sim_params(run_dir: Path) -> Dict:
    """Return ``sim_node``'s parameters from ``run_dir/params.yaml`` (none: ``{}``)."""
    import yaml
    params = RunDir(run_dir).params
    try:
        raw = yaml.safe_load(params.read_text()) or {}
    except (OSError, yaml.YAMLError):
        return {}
    if not isinstance(raw, dict):
        return {}
    for key in ('/**/sim_node', 'sim_node'):
        values = (raw.get(key) or {}).get('ros__parameters')
        if isinstance(values, dict):
            return values
    return {}


def _frame_skip_of(sim: Dict) -> int:
    """Return a run's ``sim_node.frame_skip`` (its parameters ``sim``), else the default."""
    from pg_node.common.params import SIM_PARAMS
    value = sim.get('frame_skip')
    return value if isinstance(value, int) and value else SIM_PARAMS['frame_skip'].default


def run_frame_skip(run_dir: Path) -> int:
    """Return ``sim_node.frame_skip`` from ``run_dir/params.yaml``, else the default."""
    return _frame_skip_of(run_sim_params(run_dir))


def _randomization_of(sim: Dict) -> Dict[str, str]:
    """Return a run's ``randomize_<term>`` texts that are on, ``{term: text}``."""
    from pg_node.common.perturbations import from_params
    return {t: text for t, text in from_params(sim).items() if text}


def _position_delta_of(sim: Dict) -> float:
    """Return a run's ``sim_node.position_delta`` (none: 0)."""
    value = sim.get('position_delta')
    return float(value) if isinstance(value, (int, float)) else 0.0


def card_position_delta(card: Dict) -> Optional[List[float]]:
    """Return the card's ``max_position_delta`` (rad per joint), None for absolute targets."""
    return (card.get('command_interfaces') or {}).get('position', {}).get('max_position_delta')


def card_control(card: Dict) -> Dict:
    """
    Return the evaluation keywords of the control a card's policy was trained with.

    ``frame_skip`` (its control step) and ``position_delta`` (its bounded changes, None for
    absolute targets or other interfaces), as :func:`pg_node.rl.evaluate.evaluate_policy`
    and the PyBullet evaluation take them.
    """
    return {'frame_skip': int(card['frame_skip']), 'position_delta': card_position_delta(card)}


def make_card(model_name: str, obs_dim: int, act_dim: int, frame_skip: int,
              source: Dict, randomization: Optional[Dict[str, str]] = None,
              position_delta=None) -> Dict:
    """
    Return the card of a policy trained on ``model_name`` with ``frame_skip``.

    ``position_delta``: the run's ``sim_node.position_delta`` (None or 0: the model's own
    ``pg_position_delta``, if any): recorded as ``max_position_delta`` like an import's.

    The arm model's MJCF text is kept in the card (``model_xml``), so that the card alone
    is enough to compute the observation's forward kinematics. ``physics`` records what the
    policy was trained on (:func:`pg_node.sim.training_physics.training_physics`), with the
    run's ``randomization`` (``{term: text}``, the ``randomize_<term>`` parameters).
    """
    from pg_node.sim.training_physics import training_physics
    import mujoco
    from pg_node.common.paths import resolve_model
    from pg_node.control.interfaces import card as command_card
    from pg_node.sim.actuation import actuators
    from pg_node.sim.arm_task import ArmSpec, with_position_delta
    try:
        model_path = resolve_model(model_name)
        model = mujoco.MjModel.from_xml_path(str(model_path))
        spec = with_position_delta(model, ArmSpec.from_model(model), position_delta)
    except (OSError, ValueError) as exc:
        raise PolicySourceError(f'arm model {model_name!r} of the policy: '
                                f'{" ".join(str(exc).split())}') from None
    layout = spec.obs_layout
    if layout.size != obs_dim or model.nu != act_dim:
        raise PolicySourceError(
            f'the policy has {obs_dim} observations and {act_dim} actions, its model '
            f'{model_name!r} {layout.size} and {model.nu}')

    interfaces = command_card(actuators(model))
    if spec.position_delta is not None and 'position' in interfaces:
        # relative targets: what policy_node must do with the action (an old card, without
        # the key, means absolute targets)
        interfaces['position']['max_position_delta'] = [float(v) for v in spec.position_delta]
        interfaces['position']['targets'] = ('relative: measured angle + action x '
                                             'max_position_delta (rad per control step)')

    def bound(values):
        return [float(v) if np.isfinite(v) else None for v in values]

    return {
        'format': CARD_FORMAT,
        'model': str(model_name),
        'model_xml': Path(model_path).read_text(),
        'joint_names': list(spec.joint_names),
        'actuator_names': list(spec.actuator_names),
        'observation': {'size': int(obs_dim), 'layout': layout.card(),
                        'normalization': 'inside the policy'},
        'action': {'size': int(act_dim), 'low': bound(spec.ctrl_low),
                   'high': bound(spec.ctrl_high),
                   'meaning': 'actuator control (MuJoCo ctrl: torque / gear), joint order'},
        # what a robot's controller takes: per interface the model has, its unit and range
        'command_interfaces': interfaces,
        # what it was trained on: who carries the weight, damping, armature, steps, terms
        'physics': training_physics(model, spec, frame_skip, list(interfaces),
                                    randomization or {}),
        'control_step': float(model.opt.timestep * frame_skip),
        'timestep': float(model.opt.timestep),
        'frame_skip': int(frame_skip),
        'fingertip_site': 'fingertip',
        'target_dim': int(spec.target_dim),
        'source': source,
    }


def checkpoint_card(state: dict, file: Path) -> Dict:
    """Return the card of a policy checkpoint (``frame_skip`` from its run, else the default)."""
    sim = run_sim_params(Path(file).resolve().parent.parent)     # the run's, read once
    source = {'checkpoint': str(Path(file).resolve()), 'policy_version': int(state['version']),
              'env_steps': int(state.get('env_steps', 0))}
    return make_card(state['config']['model'], int(state['obs_dim']), int(state['act_dim']),
                     _frame_skip_of(sim), source, _randomization_of(sim),
                     _position_delta_of(sim))


class TrainedPolicy:
    """A policy and its card; :meth:`mean_std` maps observations ``(N, D)`` to ``(N, A)``."""

    kind = ''

    def __init__(self, card: Dict, source: Path):
        """Keep the card and where the policy came from."""
        self.card = card
        self.source = Path(source)
        self.obs_dim = int(card['observation']['size'])
        self.act_dim = int(card['action']['size'])

    def mean_std(self, obs: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Return the Gaussian's mean and standard deviation, float64 ``(N, A)`` each."""
        raise NotImplementedError

    def mean(self, obs: np.ndarray) -> np.ndarray:
        """Return the deterministic action mu(obs)."""
        return self.mean_std(obs)[0]

    def describe(self) -> str:
        """Return one line: what runs the policy and where it came from."""
        src = self.card.get('source', {})
        version = src.get('policy_version')
        return (f'{self.kind} {self.source}' + (f' (policy version {version})'
                                                if version is not None else ''))


class TorchPolicy(TrainedPolicy):
    """A checkpoint's :class:`~pg_node.rl.policy.GaussianPolicy`, run by torch."""

    kind = 'torch'

    def __init__(self, state: dict, file: Path, threads: Optional[int] = 1):
        """
        Build the network the checkpoint's configuration describes and load its weights.

        ``threads`` sets torch's intra-op threads (None leaves them): with torch's default
        of one per core, a batch of 16 observations took 18 ms instead of 0.9 ms on this
        project's busy 2-core machine, as the threads wait for each other.
        """
        import torch
        if threads is not None:
            torch.set_num_threads(threads)
        from pg_node.rl.learner import policy_from_checkpoint
        super().__init__(checkpoint_card(state, file), file)
        self.policy = policy_from_checkpoint(state)
        self.policy.eval()
        self._torch = torch

    def mean_std(self, obs):
        """Return the mean and standard deviation, computed in float32 as in training."""
        with self._torch.no_grad():
            o = self._torch.as_tensor(np.asarray(obs), dtype=self._torch.float32)
            mu, std = self.policy.mean_std(o)
        return mu.numpy().astype(np.float64), std.numpy().astype(np.float64)


class OnnxPolicy(TrainedPolicy):
    """An exported policy, run by onnxruntime (no torch)."""

    kind = 'onnx'

    def __init__(self, path: Path, threads: int = 1):
        """Open the ONNX file with one intra-op thread and read its card."""
        card_file = sidecar_path(path)
        try:
            card = json.loads(card_file.read_text())
        except OSError as exc:
            raise PolicySourceError(f'the card of {path} is missing: cannot read {card_file} '
                                    f'({exc.strerror})') from None
        except ValueError as exc:
            raise PolicySourceError(f'{card_file} is not JSON: {exc}') from None
        if not isinstance(card, dict) or card.get('format') != CARD_FORMAT:
            raise PolicySourceError(f'{card_file} is not a pg_node policy card '
                                    f'(format {CARD_FORMAT!r})')
        super().__init__(card, path)
        import onnxruntime
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        try:
            self.session = onnxruntime.InferenceSession(
                str(path), options, providers=['CPUExecutionProvider'])
        except Exception as exc:  # noqa: B902 - onnxruntime raises its own types; one line
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise PolicySourceError(f'cannot load {path} with onnxruntime: {first}') from None

    def mean_std(self, obs):
        """Return the mean and standard deviation computed by the exported graph."""
        mu, std = self.session.run(['mean', 'std'],
                                   {'obs': np.asarray(obs, dtype=np.float32)})
        return mu.astype(np.float64), std.astype(np.float64)


def load_trained_policy(path) -> TrainedPolicy:
    """Return the policy at ``path``: an ``.onnx`` export, a run, checkpoints or a checkpoint."""
    path = Path(path).expanduser()
    if path.suffix == '.onnx':
        if not path.is_file():
            raise PolicySourceError(f'no such file: {path}')
        return OnnxPolicy(path)
    state, file = find_checkpoint(path)
    return TorchPolicy(state, file)
