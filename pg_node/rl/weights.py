"""
A network's state (parameters and normalisation statistics) as one flat float64 vector.

The learner publishes its policy this way and the actors load it; the layout (names and
shapes, in ``state_dict`` order) travels with the vector, and loading refuses a vector whose
layout does not match the receiving network, naming the first difference.
"""
from typing import List, Tuple

import numpy as np
import torch
from torch import nn

Layout = List[Tuple[str, Tuple[int, ...]]]


def layout_of(module: nn.Module) -> Layout:
    """Return ``[(name, shape), ...]`` of every tensor in ``module.state_dict()``."""
    return [(k, tuple(v.shape)) for k, v in module.state_dict().items()]


def flatten_state(module: nn.Module) -> Tuple[Layout, np.ndarray]:
    """Return ``(layout, vector)`` of the module's whole state."""
    state = module.state_dict()
    vec = np.concatenate([v.detach().double().reshape(-1).numpy() for v in state.values()])
    return layout_of(module), vec


def load_flat_state(module: nn.Module, layout: Layout, vec) -> None:
    """Load a ``(layout, vector)`` pair into ``module``; ValueError if they do not fit."""
    vec = np.asarray(vec, dtype=np.float64)
    want = layout_of(module)
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
    ref = module.state_dict()
    for name, shape in layout:
        n = int(np.prod(shape))
        state[name] = torch.as_tensor(vec[pos:pos + n].reshape(shape), dtype=ref[name].dtype)
        pos += n
    module.load_state_dict(state)
