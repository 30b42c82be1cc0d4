"""
The three message kinds the training graph adds, laid out with :mod:`pg_node.ros.table_msg`.

All are ``std_msgs/Float64MultiArray``; rows are time-major (row ``t * N + n`` is step t of
arm n). Flags are 0.0/1.0 and ids whole numbers.

``/pg_node/rollout`` (actor -> critic), header ``version, actor_id, rollout_seq, n_steps,
num_envs``; fields ``obs[D] act[A] logp rew terminated truncated final_obs[D] ep_step
episode_id seq`` (``seq``: the number of the transition message the action answered).

``/pg_node/batch`` (critic -> learner), header ``version, n_actors, batch_seq, n_steps,
num_envs, value_loss, explained_variance``; fields ``obs[D] act[A] logp adv ret rew
terminated truncated ep_step episode_id seq actor``. ``num_envs`` counts the arms of all
actors, side by side in actor-id order.

Unpacking refuses (``ValueError``) a layout that does not match, non-finite values, flags
other than 0/1, ids that are not whole, and real values beyond
:data:`pg_node.ros.table_msg.MAX_ABS`.

``/pg_node/policy_weights`` (learner -> actors, critic; transient-local), header
``version, env_steps``; one row whose fields are the policy's tensors in ``state_dict``
order, each labelled ``name[shape]`` (e.g. ``mu.weight[2x64]``) with its element count as
width.

Every header ends with ``run``, the token of the run that sent it
(:func:`pg_node.common.run.run_token`); a header without it (one value shorter) is read as
token 0, the empty run id's. Receivers compare it with their own run's (:func:`foreign`).
"""
from dataclasses import dataclass
import functools
import re
from typing import Dict, List, Tuple

import numpy as np
from pg_node.rl.rollout_buffer import RolloutArrays
from pg_node.ros import table_msg

ROLLOUT_HEADER = ('version', 'actor_id', 'rollout_seq', 'n_steps', 'num_envs', 'run')
BATCH_HEADER = ('version', 'n_actors', 'batch_seq', 'n_steps', 'num_envs', 'value_loss',
                'explained_variance', 'run')
WEIGHTS_HEADER = ('version', 'env_steps', 'run')
BOOL_FIELDS = ('terminated', 'truncated')
INT_FIELDS = ('ep_step', 'episode_id', 'seq', 'actor')


def _rollout_widths(obs_dim=None, act_dim=None):
    return {'obs': obs_dim, 'act': act_dim, 'logp': 1, 'rew': 1, 'terminated': 1,
            'truncated': 1, 'final_obs': obs_dim, 'ep_step': 1, 'episode_id': 1, 'seq': 1}


def _batch_widths(obs_dim=None, act_dim=None):
    return {'obs': obs_dim, 'act': act_dim, 'logp': 1, 'adv': 1, 'ret': 1, 'rew': 1,
            'terminated': 1, 'truncated': 1, 'ep_step': 1, 'episode_id': 1, 'seq': 1,
            'actor': 1}


def _header_size(names, data_offset: int) -> int:
    """Return the header size of a message: with its ``run`` token, or one shorter."""
    return len(names) - 1 if data_offset == len(names) - 1 else len(names)


def _header(names, values) -> Dict[str, float]:
    out = dict(zip(names, (float(v) for v in values)))
    out.setdefault('run', 0.0)          # sent without a token: the empty run id's
    for key in ('version', 'actor_id', 'rollout_seq', 'n_steps', 'num_envs', 'n_actors',
                'batch_seq', 'env_steps', 'run'):
        if key in out:
            v = out[key]
            if not np.isfinite(v) or v != round(v) or v < 0:
                raise ValueError(f'header {key!r} must be a whole number >= 0, got {v}')
            out[key] = int(v)
    return out


def _fields(table: Dict[str, np.ndarray], T: int, N: int) -> Dict[str, np.ndarray]:
    if T * N != len(next(iter(table.values()))):
        raise ValueError(f'{len(next(iter(table.values())))} rows do not make '
                         f'n_steps x num_envs = {T} x {N}')
    checked = table_msg.check_fields(table, BOOL_FIELDS, INT_FIELDS)
    return {name: value.reshape(T, N, *value.shape[1:]) for name, value in checked.items()}


def _rows(a):
    a = np.asarray(a)
    return a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])


def foreign(header: Dict[str, float], token: int) -> bool:
    """Return whether a message's header is of another run than the one of ``token``."""
    return header['run'] != token


def pack_rollout(ro: RolloutArrays, version: int, actor_id: int, rollout_seq: int,
                 run: int = 0):
    """Return the packed ``/pg_node/rollout`` table of a finished rollout of run ``run``."""
    header = (version, actor_id, rollout_seq, ro.n_steps, ro.num_envs, run)
    return table_msg.pack(header, {k: _rows(v) for k, v in ro.as_dict().items()})


def unpack_rollout(dims, offset, data, obs_dim=None, act_dim=None
                   ) -> Tuple[Dict[str, float], RolloutArrays]:
    """Return ``(header, rollout)``; ValueError if the layout or values are wrong."""
    head, table = table_msg.unpack(dims, offset, data, _header_size(ROLLOUT_HEADER, offset),
                                   _rollout_widths(obs_dim, act_dim))
    header = _header(ROLLOUT_HEADER, head)
    fields = _fields(table, header['n_steps'], header['num_envs'])
    return header, RolloutArrays(**fields)


@dataclass
class Batch:
    """An annotated batch as the learner receives it, each array ``(T, N, ...)``."""

    obs: np.ndarray
    act: np.ndarray
    logp: np.ndarray
    adv: np.ndarray
    ret: np.ndarray
    rew: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    ep_step: np.ndarray
    episode_id: np.ndarray
    seq: np.ndarray
    actor: np.ndarray


def pack_batch(batch: Batch, header: Dict[str, float]):
    """Return the packed ``/pg_node/batch`` table (``header['run']``: 0 if missing)."""
    values = [header.get(k, 0) if k == 'run' else header[k] for k in BATCH_HEADER]
    return table_msg.pack(values, {k: _rows(getattr(batch, k)) for k in _batch_widths()})


def unpack_batch(dims, offset, data, obs_dim=None, act_dim=None
                 ) -> Tuple[Dict[str, float], Batch]:
    """Return ``(header, batch)``; ValueError if the layout or values are wrong."""
    head, table = table_msg.unpack(dims, offset, data, _header_size(BATCH_HEADER, offset),
                                   _batch_widths(obs_dim, act_dim))
    header = _header(BATCH_HEADER, head)
    return header, Batch(**_fields(table, header['n_steps'], header['num_envs']))


_LABEL = re.compile(r'^(.+)\[([0-9x]*)\]$')


def pack_weights(layout: List[Tuple[str, tuple]], vec, version: int, env_steps: int,
                 run: int = 0):
    """Return the packed ``/pg_node/policy_weights`` table of a flattened state."""
    vec = np.asarray(vec, dtype=np.float64).reshape(-1)
    dims = _weights_dims(tuple((str(name), tuple(int(d) for d in shape))
                               for name, shape in layout))
    if dims[0][2] != vec.size:
        raise ValueError(f'weights vector has {vec.size} values, layout needs {dims[0][2]}')
    # one row: the table is the vector itself (what table_msg.pack makes of these fields)
    return list(dims), len(WEIGHTS_HEADER), np.concatenate([(version, env_steps, run), vec])


@functools.lru_cache(maxsize=8)
def _weights_dims(layout: tuple) -> tuple:
    """Return the dims of a weights table of ``layout``: a rows dim, then ``name[shape]``."""
    fields = tuple((f'{name}[{"x".join(str(d) for d in shape)}]', int(np.prod(shape)))
                   for name, shape in layout)
    width = sum(n for _, n in fields)
    return ((table_msg.ROWS_LABEL, 1, width),) + tuple((label, n, n) for label, n in fields)


def unpack_weights(dims, offset, data):
    """Return ``(header, layout, vector)`` of a weights message."""
    widths = {str(d[0]): None for d in dims[1:]}
    head, table = table_msg.unpack(dims, offset, data, _header_size(WEIGHTS_HEADER, offset),
                                   widths)
    layout = _weights_layout(tuple((label, block.shape[1]) for label, block in table.items()),
                             table.matrix.shape[0])
    vec = table.matrix[0].copy() if layout else np.zeros(0)    # the one row, in field order
    return _header(WEIGHTS_HEADER, head), list(layout), vec


@functools.lru_cache(maxsize=8)
def _weights_layout(fields: tuple, rows: int) -> tuple:
    """Return ``((name, shape), ...)`` of weights fields ``((label, width), ...)``."""
    layout = []
    for label, width in fields:
        m = _LABEL.match(label)
        if m is None:
            raise ValueError(f'weights field {label!r} is not of the form name[shape]')
        shape = tuple(int(d) for d in m.group(2).split('x')) if m.group(2) else ()
        if int(np.prod(shape)) != width or rows != 1:
            raise ValueError(f'weights field {label!r} does not hold {shape} values')
        layout.append((m.group(1), shape))
    return tuple(layout)
