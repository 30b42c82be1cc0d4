"""Small network builders shared by the policy and the value function."""
from typing import Sequence, Type

from torch import nn

ACTIVATIONS = {'tanh': nn.Tanh, 'relu': nn.ReLU, 'elu': nn.ELU}


def activation(name: str) -> Type[nn.Module]:
    """Return the activation class called ``name`` (``tanh``, ``relu`` or ``elu``)."""
    try:
        return ACTIVATIONS[name]
    except KeyError:
        raise ValueError(f'unknown activation {name!r}; choose one of: '
                         f'{", ".join(ACTIVATIONS)}') from None


def mlp(sizes: Sequence[int], act: Type[nn.Module] = nn.Tanh,
        output_act: Type[nn.Module] = nn.Identity) -> nn.Sequential:
    """Build a multilayer perceptron ``sizes[0] -> ... -> sizes[-1]`` (Spinning Up's ``mlp``)."""
    layers = []
    for j in range(len(sizes) - 1):
        layers += [nn.Linear(sizes[j], sizes[j + 1]),
                   act() if j < len(sizes) - 2 else output_act()]
    return nn.Sequential(*layers)
