"""
Wire layout of the per-control-step transition message that ``sim_node`` publishes.

One ``std_msgs/Float64MultiArray`` per control step carries all ``N`` arms
(topic ``/pg_node/transition``). ``data`` is a header followed by an ``N x W`` row-major
matrix, one row per arm:

* ``layout.data_offset = 1``: ``data[0]`` is ``seq``, the message's sequence number (0 for
  the first message, +1 for every new one: a control step or a world reset; a repeated
  ``seq`` is a re-send of the same transition after a lock-step timeout);
* ``layout.dim[0]``: ``label='env'``, ``size=N``, ``stride=N*W``;
* ``layout.dim[1:]``: one entry per field of a row, in row order, ``label`` = field name,
  ``size`` = its width, ``stride`` = its width too; ``W`` is the sum of the widths.

Fields of row ``i`` (``D`` = observation size of the model, 10 for ``reacher2``):

=================  =====  ================================================================
label              size   meaning
=================  =====  ================================================================
``obs``            D      observation to act on (first of a new episode after a reset)
``reward``         1      reward of the previous command (0 after a start or world reset)
``terminated``     1      1.0 if the previous command ended the episode in a terminal state
``truncated``      1      1.0 if the previous command ended the episode on the time limit
``final_obs``      D      observation the previous command reached; equals ``obs`` unless
                          the episode ended, then bootstrap ``V(final_obs)`` on truncation
``episode_id``     1      id of the episode ``obs`` belongs to (unique over the sim's life)
``episode_step``   1      control steps taken in that episode (0 at its first observation)
=================  =====  ================================================================

``reward``, ``terminated``, ``truncated`` and ``final_obs`` belong to the episode that the
previous message's ``episode_id`` named for that arm. A message whose ``episode_step`` is
0 without ``terminated``/``truncated`` comes from a start or world reset (an episode cut
short by a reset has no final transition). Flags are 0.0/1.0 and ids/counters are
whole numbers (exact in float64 up to 2**53). The functions here are pure numpy; the two
``*_msg`` helpers import ``std_msgs`` lazily.
"""
import array
from dataclasses import dataclass

import numpy as np
from pg_node import table_msg

HEADER_SIZE = 1
ENV_LABEL = 'env'
# field name -> width; None is the observation size
FIELDS = (
    ('obs', None),
    ('reward', 1),
    ('terminated', 1),
    ('truncated', 1),
    ('final_obs', None),
    ('episode_id', 1),
    ('episode_step', 1),
)
BOOL_FIELDS = ('terminated', 'truncated')
INT_FIELDS = ('episode_id', 'episode_step')
MAX_ABS = table_msg.MAX_ABS


@dataclass
class Transition:
    """One control step of all ``N`` arms, field names as in the module's table."""

    seq: int
    obs: np.ndarray
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    final_obs: np.ndarray
    episode_id: np.ndarray
    episode_step: np.ndarray

    @property
    def num_envs(self) -> int:
        """Return the number of arms ``N``."""
        return int(np.shape(self.obs)[0])


def field_sizes(obs_dim: int):
    """Return ``[(label, size), ...]`` of one row for observations of size ``obs_dim``."""
    return [(name, obs_dim if size is None else size) for name, size in FIELDS]


def pack(tr: Transition):
    """
    Pack ``tr`` into ``(dims, data_offset, data)``.

    ``dims`` is ``[(label, size, stride), ...]`` as described in the module docstring and
    ``data`` a flat float64 array of length ``1 + N * W``.
    """
    obs = np.asarray(tr.obs, dtype=np.float64)
    if obs.ndim != 2:
        raise ValueError(f'obs must be (N, obs_dim), got shape {obs.shape}')
    n, obs_dim = obs.shape
    cols = []
    for name, size in field_sizes(obs_dim):
        col = np.asarray(getattr(tr, name), dtype=np.float64).reshape(n, -1)
        if col.shape[1] != size:
            raise ValueError(f'field {name!r} has {col.shape[1]} values per env, '
                             f'expected {size}')
        cols.append(col)
    rows = np.concatenate(cols, axis=1)
    width = rows.shape[1]
    dims = [(ENV_LABEL, n, n * width)] + [(name, size, size)
                                          for name, size in field_sizes(obs_dim)]
    data = np.concatenate([[float(tr.seq)], rows.ravel()])
    return dims, HEADER_SIZE, data


def unpack(dims, data_offset: int, data) -> Transition:
    """
    Check a ``(dims, data_offset, data)`` layout and return the :class:`Transition`.

    Raise ``ValueError`` naming the first mismatch: wrong labels or order, inconsistent
    sizes or strides, a data length that does not match, non-whole ids or flags not 0/1,
    non-finite values or values beyond :data:`MAX_ABS`.
    """
    dims = [(str(label), int(size), int(stride)) for label, size, stride in dims]
    data = np.asarray(data, dtype=np.float64)
    if data_offset != HEADER_SIZE:
        raise ValueError(f'data_offset is {data_offset}, expected {HEADER_SIZE}')
    names = [name for name, _ in FIELDS]
    if len(dims) != 1 + len(names) or dims[0][0] != ENV_LABEL:
        raise ValueError(f'dim labels {[d[0] for d in dims]} are not '
                         f'{[ENV_LABEL] + names}')
    if [d[0] for d in dims[1:]] != names:
        raise ValueError(f'field labels {[d[0] for d in dims[1:]]} are not {names}')
    obs_dim = dims[1][1]
    if obs_dim < 1:
        raise ValueError('obs must have at least one value')
    for (label, size, stride), (_, want) in zip(dims[1:], field_sizes(obs_dim)):
        if size != want or stride != size:
            raise ValueError(f'field {label!r} has size {size} / stride {stride}, '
                             f'expected {want}')
    n = dims[0][1]
    width = sum(size for _, size, _ in dims[1:])
    if n < 1 or dims[0][2] != n * width:
        raise ValueError(f'env dim has size {n} / stride {dims[0][2]}, expected stride '
                         f'{n * width} for row width {width}')
    if data.shape != (HEADER_SIZE + n * width,):
        raise ValueError(f'data has {data.size} values, layout needs {HEADER_SIZE + n * width}')
    rows = data[HEADER_SIZE:].reshape(n, width)
    fields, col = {}, 0
    for name, size in field_sizes(obs_dim):
        block = rows[:, col:col + size]
        col += size
        if name in BOOL_FIELDS:
            if not np.all((block == 0.0) | (block == 1.0)):
                raise ValueError(f'field {name!r} must hold 0.0 or 1.0')
            fields[name] = block[:, 0].astype(bool)
        elif name in INT_FIELDS:
            if not np.all(np.isfinite(block)) or np.any(block != np.round(block)):
                raise ValueError(f'field {name!r} must hold whole numbers')
            fields[name] = block[:, 0].astype(np.int64)
        elif not np.all(np.isfinite(block)) or np.any(np.abs(block) > MAX_ABS):
            raise ValueError(f'field {name!r} holds non-finite or absurd values '
                             f'(|x| > {MAX_ABS:g})')
        elif size == 1:
            fields[name] = block[:, 0].copy()
        else:
            fields[name] = block.copy()
    seq = data[0]
    if not np.isfinite(seq) or seq != round(seq):
        raise ValueError('seq must be a whole number')
    return Transition(seq=int(seq), **fields)


def to_msg(tr: Transition):
    """Return ``tr`` as a ``std_msgs/Float64MultiArray``."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    dims, offset, data = pack(tr)
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in dims]
    msg.layout.data_offset = offset
    msg.data = array.array('d', data.tobytes())
    return msg


def from_msg(msg) -> Transition:
    """Return the :class:`Transition` in a ``std_msgs/Float64MultiArray`` (ValueError if bad)."""
    dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
    return unpack(dims, msg.layout.data_offset, np.asarray(msg.data, dtype=np.float64))
