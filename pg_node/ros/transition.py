"""
Wire layout of the per-control-step transition message that ``sim_node`` publishes.

One ``std_msgs/Float64MultiArray`` per control step carries all ``N`` arms
(topic ``/pg_node/transition``), or one per group of arms when a lock-step simulator steps
its arms in ``G`` groups (``lock_step_groups``). ``data`` is a header followed by an
``N x W`` row-major matrix, one row per arm of the message:

* ``layout.data_offset = 1``: ``data[0]`` is ``seq``, the message's sequence number (0 for
  the first message, +1 for every new one: a control step or a world reset; a repeated
  ``seq`` is a re-send of the same transition after a lock-step timeout);
* ``layout.data_offset = 3`` (a group of ``G > 1``): ``data[1]`` is the index of the
  message's first arm and ``data[2]`` is ``G``. Group ``g``'s messages have the ``seq``
  numbers ``k * G + g`` (``k``: its control steps and resets so far), so each group counts
  up by ``G`` and ``seq % G`` names the group;
* the header's last value is ``run``, the token of the simulator's run
  (:func:`pg_node.common.run.run_token`): ``data_offset`` is then 2 (``seq run``) or 4
  (``seq first_arm G run``); a header without it (1 or 3 values) is read as token 0;
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
``*_msg`` helpers import ``std_msgs`` lazily, the two ``*_cdr`` ones work on the serialised
bytes (what the simulator publishes and the actor takes, :mod:`pg_node.ros.table_msg`).
"""
from dataclasses import dataclass
import math

import numpy as np
from pg_node.ros import table_msg

HEADER_SIZE = 2                 # seq, run
GROUP_HEADER_SIZE = 4           # seq, first arm, number of groups, run
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
    first_arm: int = 0
    groups: int = 1
    run: int = 0

    @property
    def num_envs(self) -> int:
        """Return the number of arms ``N`` of the message."""
        return int(np.shape(self.obs)[0])

    @property
    def arms(self) -> slice:
        """Return the simulator's arms the message holds."""
        return slice(self.first_arm, self.first_arm + self.num_envs)


def field_sizes(obs_dim: int):
    """Return ``[(label, size), ...]`` of one row for observations of size ``obs_dim``."""
    return [(name, obs_dim if size is None else size) for name, size in FIELDS]


def pack(tr: Transition):
    """
    Pack ``tr`` into ``(dims, data_offset, data)``: a :mod:`pg_node.ros.table_msg` table.

    ``dims`` is ``[(label, size, stride), ...]`` as described in the module docstring and
    ``data`` a flat float64 array of length ``1 + N * W``.
    """
    obs = np.asarray(tr.obs, dtype=np.float64)
    if obs.ndim != 2:
        raise ValueError(f'obs must be (N, obs_dim), got shape {obs.shape}')
    n, obs_dim = obs.shape
    fields = {}
    for name, size in field_sizes(obs_dim):
        col = np.asarray(getattr(tr, name), dtype=np.float64).reshape(n, -1)
        if col.shape[1] != size:
            raise ValueError(f'field {name!r} has {col.shape[1]} values per env, '
                             f'expected {size}')
        fields[name] = col
    header = ([tr.seq, tr.first_arm, tr.groups] if tr.groups > 1 else [tr.seq]) + [tr.run]
    return table_msg.pack(header, fields, rows_label=ENV_LABEL)


def unpack(dims, data_offset: int, data) -> Transition:
    """
    Check a ``(dims, data_offset, data)`` layout and return the :class:`Transition`.

    Raise ``ValueError`` naming the first mismatch: wrong labels or order, inconsistent
    sizes or strides, a data length that does not match, non-whole ids or flags not 0/1,
    non-finite values or values beyond :data:`pg_node.ros.table_msg.MAX_ABS`.
    """
    dims = [(str(label), int(size), int(stride)) for label, size, stride in dims]
    obs_dim = dims[1][1] if len(dims) > 1 and dims[1][0] == 'obs' else None
    widths = {name: obs_dim if size is None else size for name, size in FIELDS}
    # with the run token (2 or 4 values) or without it (1 or 3: token 0)
    header_size = data_offset if data_offset in (1, 2, 3, 4) else HEADER_SIZE
    header, table = table_msg.unpack(dims, data_offset, data, header_size, widths,
                                     rows_label=ENV_LABEL)
    if dims[0][1] < 1:
        raise ValueError('a transition needs at least one env (dim size 0)')
    values = header.tolist()
    if not all(math.isfinite(v) and v == round(v) for v in values):
        raise ValueError('seq, first arm, groups and run must be whole numbers')
    values = [int(v) for v in values]
    run = values.pop() if header_size in (HEADER_SIZE, GROUP_HEADER_SIZE) else 0
    seq, first_arm, groups = values if len(values) == 3 else (values[0], 0, 1)
    if first_arm < 0 or groups < 1 or run < 0:
        raise ValueError(f'first arm {first_arm} < 0, groups {groups} < 1 or run {run} < 0')
    fields = table_msg.check_fields(table, BOOL_FIELDS, INT_FIELDS)
    return Transition(seq=seq, first_arm=first_arm, groups=groups, run=run, **fields)


def to_cdr(tr: Transition) -> bytes:
    """Return ``tr`` serialised: the bytes of :func:`to_msg`'s message, for ``publish``."""
    return table_msg.to_cdr(*pack(tr), remember=True)


#: layouts met before: bytes length -> (bytes before the data, dims, data_offset, dtype)
_known_layouts = {}


def from_cdr(raw: bytes) -> Transition:
    """
    Return the :class:`Transition` in serialised bytes (a ``raw=True`` subscription's).

    The same checks as :func:`from_msg`. A simulator sends one layout for a whole run, so
    the bytes before the data of a layout that passed once are remembered: a message that
    starts with them has that layout, and only its values are decoded and checked.
    """
    known = _known_layouts.get(len(raw))
    if known is not None and raw.startswith(known[0]):
        prefix, dims, data_offset, dtype = known
        # a copy: CDR puts the doubles 4 bytes off an 8-byte boundary, and numpy is several
        # times slower on unaligned arrays
        data = np.frombuffer(raw, dtype, offset=len(prefix)).astype(np.float64)
        return unpack(dims, data_offset, data)
    dims, data_offset, data = table_msg.from_msg(table_msg.from_cdr(raw))
    tr = unpack(dims, data_offset, data)
    # remember it if the data are the last 8 * n bytes, as rclpy and rosbags write them
    dtype = np.dtype('<f8' if raw[1:2] == b'\x01' else '>f8')
    at = len(raw) - 8 * data.size
    if at > 0 and np.array_equal(np.frombuffer(raw, dtype, offset=at), data):
        if len(_known_layouts) >= table_msg.REMEMBERED_LAYOUTS:
            _known_layouts.clear()
        _known_layouts[len(raw)] = (raw[:at], dims, data_offset, dtype)
    return tr


def to_msg(tr: Transition):
    """Return ``tr`` as a ``std_msgs/Float64MultiArray``."""
    return table_msg.to_msg(*pack(tr))


def from_msg(msg) -> Transition:
    """Return the :class:`Transition` in a ``std_msgs/Float64MultiArray`` (ValueError if bad)."""
    return unpack(*table_msg.from_msg(msg))
