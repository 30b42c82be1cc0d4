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
"""
import array
from typing import Dict, Mapping, Optional, Sequence, Tuple

import numpy as np
from pg_node.bag.ros_types import float64_field

ROWS_LABEL = 'rows'
#: Largest magnitude a real value on pg_node's wire may have (observations, actions,
#: rewards, advantages and torque commands of the arm stay far below): 1e300 is a bug
#: upstream, and one such value would poison the running observation statistics for good.
MAX_ABS = 1e6


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
    return data[:header_size].copy(), out


def check_fields(table: Mapping[str, np.ndarray], bool_fields=(), int_fields=()
                 ) -> Dict[str, np.ndarray]:
    """
    Check the values of unpacked fields and return them typed.

    Every value must be finite; ``bool_fields`` hold 0.0 or 1.0 (returned as bool),
    ``int_fields`` whole numbers (int64), the rest real values within :data:`MAX_ABS`
    (float64 copies). Width-1 fields come back as ``(R,)``, wider ones as ``(R, w)``.
    Raise ``ValueError`` naming the first field that breaks its rule.
    """
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


def from_msg(msg):
    """Return ``(dims, data_offset, data)`` of a ``std_msgs/Float64MultiArray``."""
    dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
    return dims, msg.layout.data_offset, np.frombuffer(msg.data, dtype=np.float64) \
        if isinstance(msg.data, array.array) else np.asarray(msg.data, dtype=np.float64)
