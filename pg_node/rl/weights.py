"""
A network's state (parameters and normalisation statistics) as one flat float64 vector.

The learner publishes its policy this way and the actors load it; the layout (names and
shapes, in ``state_dict`` order) travels with the vector, and loading refuses a vector whose
layout does not match the receiving network, naming the first difference.

Only the functions that take a torch module import torch, so :func:`unflatten` (the checks
and the split) also serves the torch-free sampler of the actor
(:class:`pg_node.rl.sampler.NumpySampler`).
"""
from typing import Dict, List, Tuple

import numpy as np

Layout = List[Tuple[str, Tuple[int, ...]]]


def layout_of(module) -> Layout:
    """Return ``[(name, shape), ...]`` of every tensor in ``module.state_dict()``."""
    return _layout_of_state(module.state_dict())


def _layout_of_state(state) -> Layout:
    return [(k, tuple(v.shape)) for k, v in state.items()]


def flatten_state(module) -> Tuple[Layout, np.ndarray]:
    """Return ``(layout, vector)`` of the module's whole state."""
    import torch
    state = module.state_dict()
    with torch.no_grad():     # one cat in torch, then one array: faster (docs/results/PROFILE.md)
        vec = torch.cat([v.reshape(-1).double() for v in state.values()]).numpy()
    return _layout_of_state(state), vec


def unflatten(layout: Layout, vec, want: Layout) -> Dict[str, np.ndarray]:
    """
    Return ``{name: float64 array}`` of a ``(layout, vector)`` pair that must fit ``want``.

    ValueError, naming the first difference, when the layout is not ``want``, the vector's
    length is not the layout's, or a value is not finite.
    """
    vec = np.asarray(vec, dtype=np.float64)
    layout = [(str(n), tuple(int(d) for d in s)) for n, s in layout]
    if layout != want:
        diff = next(((a, b) for a, b in zip(layout, want) if a != b),
                    (f'{len(layout)} tensors', f'{len(want)} tensors'))
        raise ValueError(f'weights layout does not match the network: got {diff[0]}, '
                         f'expected {diff[1]}')
    total = sum(int(np.prod(s)) for _, s in layout)
    if vec.shape != (total,):
        raise ValueError(f'weights vector has {vec.size} values, layout needs {total}')
    if not np.all(np.isfinite(vec)):
        raise ValueError('weights vector holds non-finite values')
    state, pos = {}, 0
    for name, shape in layout:
        n = int(np.prod(shape))
        state[name] = vec[pos:pos + n].reshape(shape)
        pos += n
    return state


def load_flat_state(module, layout: Layout, vec) -> None:
    """Load a ``(layout, vector)`` pair into ``module``; ValueError if they do not fit."""
    import torch
    ref = module.state_dict()
    state = unflatten(layout, vec, layout_of(module))
    module.load_state_dict({name: torch.as_tensor(value, dtype=ref[name].dtype)
                            for name, value in state.items()})
