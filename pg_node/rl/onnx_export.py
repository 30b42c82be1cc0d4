"""
A :class:`~pg_node.rl.policy.GaussianPolicy` as an ONNX graph, normalisation included.

The graph is written operator by operator from the policy's weights (``onnx.helper``),
mirroring :meth:`GaussianPolicy.mean_std` step for step, all in float32 as torch runs it:

* ``obs`` ``[N, D]`` -> ``clip((obs - mean) / sqrt(var + eps), -clip, clip)`` (the running
  normaliser's statistics frozen as constants, :mod:`pg_node.rl.normalization`);
* the trunk: ``Gemm`` (``x W^T + b``) and the activation (``Tanh``, ``Relu``, ``Elu``) per
  hidden layer;
* output ``mean`` ``[N, A]``: the mean head; output ``std`` ``[N, A]``:
  ``exp(clip(log_std, LOG_STD_MIN, LOG_STD_MAX))``, a constant row or the second head.

Writing the few operators by hand needs only ``onnx`` (no exporter, no onnxscript) and keeps
the graph as small as the network; a policy of any other shape is refused.
"""
from pathlib import Path
from typing import Dict

import numpy as np

OPSET = 17
ACTIVATION_OPS = {'Tanh': 'Tanh', 'ReLU': 'Relu', 'ELU': 'Elu'}


def policy_graph(policy):
    """Return the ``onnx.ModelProto`` of ``policy``'s mean and standard deviation."""
    import onnx
    from onnx import helper, numpy_helper, TensorProto
    import torch
    from pg_node.rl.policy import LOG_STD_MAX, LOG_STD_MIN
    nodes, inits = [], []

    def const(name, value):
        inits.append(numpy_helper.from_array(np.asarray(value, dtype=np.float32), name))
        return name

    x = 'obs'
    norm = policy.obs_norm
    if norm.enabled:
        with torch.no_grad():
            mean = norm.mean.to(torch.float32).numpy()
            std = torch.sqrt(norm.var + norm.eps).to(torch.float32).numpy()
        nodes += [helper.make_node('Sub', [x, const('norm_mean', mean)], ['centred']),
                  helper.make_node('Div', ['centred', const('norm_std', std)], ['scaled']),
                  helper.make_node('Clip', ['scaled', const('norm_low', -norm.clip),
                                            const('norm_high', norm.clip)], ['normalized'])]
        x = 'normalized'
    layers = list(policy.trunk) if isinstance(policy.trunk, torch.nn.Sequential) else []
    k = 0
    for layer in layers:
        name = type(layer).__name__
        if isinstance(layer, torch.nn.Linear):
            w = layer.weight.detach().numpy()
            b = layer.bias.detach().numpy()
            out = f'h{k}_linear'
            nodes.append(helper.make_node('Gemm', [x, const(f'trunk{k}_w', w),
                                                   const(f'trunk{k}_b', b)], [out], transB=1))
        elif name in ACTIVATION_OPS:
            out = f'h{k}'
            extra = {'alpha': float(layer.alpha)} if name == 'ELU' else {}
            nodes.append(helper.make_node(ACTIVATION_OPS[name], [x], [out], **extra))
            k += 1
        else:
            raise ValueError(f'cannot export a policy layer of type {name}')
        x = out
    if not layers and not isinstance(policy.trunk, torch.nn.Identity):
        raise ValueError(f'cannot export a policy trunk of type {type(policy.trunk).__name__}')

    def head(linear, out):
        w, b = linear.weight.detach().numpy(), linear.bias.detach().numpy()
        nodes.append(helper.make_node('Gemm', [x, const(f'{out}_w', w), const(f'{out}_b', b)],
                                      [out], transB=1))

    head(policy.mu, 'mean')
    if policy.state_dependent_std:
        head(policy.log_std_head, 'log_std_raw')
    else:
        # log_std is one row; adding 0 * mean gives it the batch's shape, as expand_as does
        nodes += [helper.make_node('Mul', ['mean', const('zero', 0.0)], ['zeros']),
                  helper.make_node('Add', ['zeros', const('log_std',
                                                          policy.log_std.detach().numpy())],
                                   ['log_std_raw'])]
    nodes += [helper.make_node('Clip', ['log_std_raw', const('log_std_min', LOG_STD_MIN),
                                        const('log_std_max', LOG_STD_MAX)], ['log_std_clipped']),
              helper.make_node('Exp', ['log_std_clipped'], ['std'])]
    d, a = policy.obs_dim, policy.act_dim
    graph = helper.make_graph(
        nodes, 'pg_node_policy',
        [helper.make_tensor_value_info('obs', TensorProto.FLOAT, ['batch', d])],
        [helper.make_tensor_value_info('mean', TensorProto.FLOAT, ['batch', a]),
         helper.make_tensor_value_info('std', TensorProto.FLOAT, ['batch', a])],
        inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', OPSET)],
                              producer_name='pg_node')
    model.ir_version = min(model.ir_version, 8)   # readable by older onnxruntimes too
    onnx.checker.check_model(model)
    return model


def export_policy(policy, card: Dict, path) -> Path:
    """
    Write ``policy`` as ONNX to ``path`` and its card as JSON beside it; return the card's path.

    ``card`` is :func:`pg_node.rl.trained_policy.make_card`'s; the file names are recorded in it.
    """
    import json
    import onnx
    from pg_node.rl.trained_policy import sidecar_path
    path = Path(path)
    model = policy_graph(policy)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(path))
    card = dict(card, onnx=path.name, inputs={'obs': ['batch', policy.obs_dim]},
                outputs={'mean': ['batch', policy.act_dim], 'std': ['batch', policy.act_dim]})
    side = sidecar_path(path)
    side.write_text(json.dumps(card, indent=1) + '\n')
    return side
