"""
Tables of named numeric fields in a ``std_msgs/Float64MultiArray``: pg_node's wire format.

pg_node sends rollouts, annotated batches and policy weights as standard messages, so that
nothing needs building and ``ros2 topic echo`` shows them. One message is a small header of
named scalars followed by an ``R x W`` row-major table:

* ``layout.data_offset = H``: ``data[0:H]`` are the header values, in the order that the
  message kind documents (the names are fixed per topic, not sent);
* ``layout.dim[0]``: ``label='rows'``, ``size=R``, ``stride=R*W``;
* ``layout.dim[1:]``: one per field, ``label`` its name, ``size`` = ``stride`` = its width.

Unpacking checks everything against what the receiver expects and raises ``ValueError``
naming the first difference, so a node can drop a malformed message and say why.

On the lock-step path (the transition and the command, every control step) the nodes skip
rclpy's message objects: they publish the CDR bytes of :func:`to_cdr` and subscribe with
``raw=True``, decoding with :func:`from_cdr` (the ``rosbags`` CDR codec, numpy arrays
instead of Python objects). The bytes are the same as rclpy's, so every other subscriber,
``ros2 topic echo`` and a bag see the same message.
"""
import array
import functools
from typing import Dict, Mapping, Optional, Sequence, Tuple

import numpy as np
from pg_node.bag.ros_types import float64_field, jazzy_typestore
from pg_node.common.bounds import MAX_ABS

ROWS_LABEL = 'rows'
#: Whole numbers (ids, counters) are exact in float64 up to this magnitude.
MAX_WHOLE = 2.0 ** 53


class Table(dict):
    """
    The fields of an unpacked table: ``{name: (R, w) view}`` in row order.

    ``matrix`` is the ``(R, W)`` table they are column slices of, which :func:`check_fields`
    checks in one pass.
    """

    def __init__(self, fields, matrix: np.ndarray):
        super().__init__(fields)
        self.matrix = matrix


def pack(header: Sequence[float], fields: Mapping[str, np.ndarray], rows_label=ROWS_LABEL
         ) -> Tuple[list, int, np.ndarray]:
    """Return ``(dims, data_offset, data)`` for a header and ``{name: (R,) or (R, w)}``."""
    cols, dims = [], []
    n_rows = None
    for name, value in fields.items():
        col = np.asarray(value, dtype=np.float64)
        if col.ndim == 1:
            col = col[:, None]
        col = col.reshape(col.shape[0], -1)
        if n_rows is None:
            n_rows = col.shape[0]
        elif col.shape[0] != n_rows:
            raise ValueError(f'field {name!r} has {col.shape[0]} rows, expected {n_rows}')
        cols.append(col)
        dims.append((name, col.shape[1], col.shape[1]))
    n_rows = n_rows or 0
    width = sum(d[1] for d in dims)
    table = np.concatenate(cols, axis=1) if cols else np.zeros((0, 0))
    header = np.asarray(header, dtype=np.float64).reshape(-1)
    data = np.concatenate([header, table.reshape(-1)])
    return [(rows_label, n_rows, n_rows * width)] + dims, header.size, data


def unpack(dims, data_offset: int, data, header_size: int,
           widths: Mapping[str, Optional[int]], rows_label=ROWS_LABEL
           ) -> Tuple[np.ndarray, Dict[str, np.ndarray]]:
    """
    Check a layout against the expected fields and return ``(header, {name: (R, w)})``.

    ``widths`` lists the expected fields in order, with their width or None for any width.
    """
    dims = [(str(label), int(size), int(stride)) for label, size, stride in dims]
    data = np.asarray(data, dtype=np.float64)
    if data_offset != header_size:
        raise ValueError(f'data_offset is {data_offset}, expected {header_size}')
    if not dims or dims[0][0] != rows_label:
        raise ValueError(f'dim labels must start with {rows_label!r}, got '
                         f'{[d[0] for d in dims][:1]}')
    names = [d[0] for d in dims[1:]]
    if names != list(widths):
        raise ValueError(f'field labels {names} are not the expected {list(widths)}')
    for (label, size, stride), want in zip(dims[1:], widths.values()):
        if size < 1 or stride != size or (want is not None and size != want):
            raise ValueError(f'field {label!r} has size {size} / stride {stride}, expected '
                             f'{want if want is not None else "size = stride >= 1"}')
    n_rows = dims[0][1]
    width = sum(d[1] for d in dims[1:])
    if n_rows < 0 or dims[0][2] != n_rows * width:
        raise ValueError(f'{rows_label} dim has size {n_rows} / stride {dims[0][2]}, '
                         f'expected stride {n_rows * width}')
    if data.shape != (header_size + n_rows * width,):
        raise ValueError(f'data has {data.size} values, the layout needs '
                         f'{header_size + n_rows * width}')
    table = data[header_size:].reshape(n_rows, width)
    out, col = {}, 0
    for label, size, _ in dims[1:]:
        out[label] = table[:, col:col + size]
        col += size
    return data[:header_size].copy(), Table(out, table)


def check_fields(table: Mapping[str, np.ndarray], bool_fields=(), int_fields=()
                 ) -> Dict[str, np.ndarray]:
    """
    Check the values of unpacked fields and return them typed.

    Every value must be finite; ``bool_fields`` hold 0.0 or 1.0 (returned as bool),
    ``int_fields`` whole numbers (int64), the rest real values within :data:`MAX_ABS`
    (float64 copies). Width-1 fields come back as ``(R,)``, wider ones as ``(R, w)``.
    Raise ``ValueError`` naming the first field that breaks its rule.

    A :class:`Table` (what :func:`unpack` returns) is checked in one pass over its
    ``matrix`` first: every column within its field's bounds, and the bool and int columns
    whole. A good message passes that and only needs typing (a 64-arm transition: 51 -> 35-40
    us); one that fails it is checked field by field, which names the culprit (and lets
    a whole number beyond 2**53 through, as it always did).
    """
    if isinstance(table, Table):
        fast = _checked_at_once(table, bool_fields, int_fields)
        if fast is not None:
            return fast
    out = {}
    for name, block in table.items():
        # one reduction per field for a good message; the errors are told apart after
        if name in bool_fields:
            if not ((block == 0.0) | (block == 1.0)).all():
                _raise_bad(name, block, 'must hold 0.0 or 1.0')
            value = block.astype(bool)
        elif name in int_fields:
            if not np.isfinite(block).all() or not (block == np.round(block)).all():
                _raise_bad(name, block, 'must hold whole numbers')
            value = block.astype(np.int64)
        else:
            if not np.abs(block).max(initial=0.0) <= MAX_ABS:  # False for NaN too
                _raise_bad(name, block, f'holds absurd values (|x| > {MAX_ABS:g})')
            value = block.copy()
        out[name] = value[:, 0] if value.shape[1] == 1 else value
    return out


def _checked_at_once(table: Table, bool_fields, int_fields) -> Optional[Dict]:
    """Return :func:`check_fields`' result for a good table, None if any rule may be broken."""
    layout = tuple((name, block.shape[1]) for name, block in table.items())
    low, high, whole = _bounds(layout, tuple(bool_fields), tuple(int_fields))
    m = table.matrix
    # within bounds (NaN is not); the whole-number columns then fit int64 exactly
    if m.shape[1] != low.size or not ((m >= low) & (m <= high)).all():
        return None
    ints = m.astype(np.int64)
    if whole.size and not (ints == m)[:, whole].all():
        return None
    out, col = {}, 0
    for name, width in layout:
        cols = slice(col, col + width)
        value = (ints[:, cols] != 0) if name in bool_fields else ints[:, cols] \
            if name in int_fields else m[:, cols].copy()
        out[name] = value[:, 0] if width == 1 else value
        col += width
    return out


@functools.lru_cache(maxsize=64)
def _bounds(layout: tuple, bool_fields: tuple, int_fields: tuple):
    """Return per-column lower and upper bounds and the columns that must be whole."""
    low, high, whole, col = [], [], [], 0
    for name, width in layout:
        lo, hi = (0.0, 1.0) if name in bool_fields else (-MAX_WHOLE, MAX_WHOLE) \
            if name in int_fields else (-MAX_ABS, MAX_ABS)
        low += [lo] * width
        high += [hi] * width
        if name in bool_fields or name in int_fields:
            whole += range(col, col + width)
        col += width
    return np.array(low), np.array(high), np.array(whole, dtype=np.intp)


def _raise_bad(name: str, block: np.ndarray, rule: str):
    """Raise the ValueError of a field that broke its rule: non-finite values come first."""
    if not np.isfinite(block).all():
        raise ValueError(f'field {name!r} holds non-finite values')
    raise ValueError(f'field {name!r} {rule}')


def to_msg(dims, data_offset: int, data):
    """Build the ``std_msgs/Float64MultiArray`` of a packed table."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in dims]
    msg.layout.data_offset = int(data_offset)
    msg.data = float64_field(data)
    return msg


FLOAT64_MULTI_ARRAY = 'std_msgs/msg/Float64MultiArray'


#: How many layouts a remembering encoder or decoder keeps (a node sends or receives one or
#: two; more means they change, and the memory starts again)
REMEMBERED_LAYOUTS = 16
#: layouts serialised before (``to_cdr(..., remember=True)``): (dims, data_offset, length)
#: -> the bytes before the data
_known_prefixes: Dict[tuple, bytes] = {}


def to_cdr(dims, data_offset: int, data, remember: bool = False) -> bytes:
    """
    Return a packed table as the serialised ``std_msgs/Float64MultiArray`` (CDR, little endian).

    What rclpy's ``serialize_message(to_msg(...))`` returns, built without the message
    object; ``Publisher.publish`` sends ``bytes`` as they are. With ``remember`` (a sender
    whose layout stays the same message after message: the simulator's transitions), the
    bytes before the data of a layout serialised once are kept, and the next message of
    that layout is those bytes and the data's (the same bytes; a 64-arm transition's
    ``to_cdr`` 44 -> 26 us with its packing, timeit best of 7).
    """
    if remember:
        flat = np.ascontiguousarray(data, dtype='<f8').reshape(-1)
        key = (tuple(map(tuple, dims)), int(data_offset), flat.size)
        prefix = _known_prefixes.get(key)
        if prefix is not None:
            return prefix + flat.tobytes()
        raw = to_cdr(dims, data_offset, flat)
        at = len(raw) - 8 * flat.size
        if raw[at:] == flat.tobytes():     # the data are the last bytes, as CDR puts them
            if len(_known_prefixes) >= REMEMBERED_LAYOUTS:
                _known_prefixes.clear()
            _known_prefixes[key] = raw[:at]
        return raw
    store = jazzy_typestore()
    dim_t = store.types['std_msgs/msg/MultiArrayDimension']
    msg = store.types[FLOAT64_MULTI_ARRAY](
        layout=store.types['std_msgs/msg/MultiArrayLayout'](
            dim=[dim_t(label=label, size=size, stride=stride) for label, size, stride in dims],
            data_offset=int(data_offset)),
        data=np.ascontiguousarray(data, dtype=np.float64).reshape(-1))
    return bytes(store.serialize_cdr(msg, FLOAT64_MULTI_ARRAY))


def from_cdr(raw: bytes):
    """
    Decode serialised ``std_msgs/Float64MultiArray`` bytes (a ``raw=True`` subscription's).

    Return a message with the fields of ``std_msgs``' (``layout.dim[i].label/size/stride``,
    ``layout.data_offset``, ``data`` as a float64 numpy array), which :func:`from_msg` and
    the message kinds' unpackers take as they take rclpy's. ``ValueError`` if the bytes are
    not such a message (truncated, another type's, an unknown encoding).
    """
    try:
        return jazzy_typestore().deserialize_cdr(raw, FLOAT64_MULTI_ARRAY)
    except Exception as exc:  # noqa: B902 - rosbags raises struct.error, IndexError, ...
        raise ValueError(f'not a serialised Float64MultiArray ({len(raw)} bytes): '
                         f'{type(exc).__name__}: {exc}') from None


def from_msg(msg):
    """Return ``(dims, data_offset, data)`` of a ``std_msgs/Float64MultiArray``."""
    dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
    return dims, msg.layout.data_offset, np.frombuffer(msg.data, dtype=np.float64) \
        if isinstance(msg.data, array.array) else np.asarray(msg.data, dtype=np.float64)
