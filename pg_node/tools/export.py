"""
``python -m pg_node export RUN -o policy.onnx``: a trained policy that runs without pg_node.

Takes a run directory (its newest readable checkpoint), a directory of ``ckpt_*.pt`` files or
one such file, and writes the policy as ONNX (:mod:`pg_node.rl.onnx_export`: observation
normalisation inside the graph, outputs ``mean`` and ``std``) and its card beside it
(``policy.json``: observation layout, joint names, control range, control step, the arm
model). onnxruntime runs it from any language; ``policy_node -p policy:=policy.onnx`` runs
it without torch. The export is checked on the spot: the ONNX graph's mean actions must
equal the checkpoint's within ``--tolerance`` on observations of the task.
"""
import argparse
from pathlib import Path
import sys


def check_export(policy, onnx_path: Path, n: int = 256, seed: int = 0) -> float:
    """Return the largest difference between torch's and the export's means on ``n`` states."""
    import numpy as np
    from pg_node.rl.trained_policy import OnnxPolicy
    import torch
    rng = np.random.default_rng(seed)
    mean = policy.obs_norm.mean.numpy() if policy.obs_norm.enabled else 0.0
    std = np.sqrt(policy.obs_norm.var.numpy()) if policy.obs_norm.enabled else 1.0
    obs = mean + std * rng.normal(scale=2.0, size=(n, policy.obs_dim))
    with torch.no_grad():
        want = policy.mean_action(torch.as_tensor(obs, dtype=torch.float32)).numpy()
    got = OnnxPolicy(onnx_path).mean(obs)
    return float(np.abs(got - want).max())


def main(argv=None) -> int:
    """Run ``python -m pg_node export``."""
    parser = argparse.ArgumentParser(prog='python -m pg_node export',
                                     description='Export a trained policy as ONNX.')
    parser.add_argument('policy', help='a run directory, its checkpoints/ (the newest valid '
                                       'one is used) or a ckpt_*.pt file')
    parser.add_argument('-o', '--output', required=True, help='the .onnx file to write')
    parser.add_argument('--tolerance', type=float, default=1e-5,
                        help='largest allowed difference of the mean action (default: '
                             '%(default)s)')
    args = parser.parse_args(argv)
    out = Path(args.output)
    if out.suffix != '.onnx':
        print(f'export: -o {out}: the output must end in .onnx (the card is written beside it '
              f'as {out.stem}.json)', file=sys.stderr)
        return 2
    from pg_node.rl.onnx_export import export_policy
    from pg_node.rl.trained_policy import PolicySourceError, TorchPolicy, find_checkpoint
    try:
        state, file = find_checkpoint(args.policy)
        trained = TorchPolicy(state, file)
    except PolicySourceError as exc:
        print(f'export: {exc}', file=sys.stderr)
        return 1
    try:
        card = export_policy(trained.policy, trained.card, out)
    except OSError as exc:
        print(f'export: cannot write {out}: {exc.strerror}', file=sys.stderr)
        return 1
    except ValueError as exc:
        print(f'export: {exc}', file=sys.stderr)
        return 1
    diff = check_export(trained.policy, out)
    if not diff <= args.tolerance:
        print(f'export: the ONNX mean action differs from the checkpoint by {diff:.3g} '
              f'(more than {args.tolerance:g})', file=sys.stderr)
        return 1
    print(f'exported policy version {state["version"]} of {file} to {out} and {card} '
          f'(largest difference from the checkpoint: {diff:.2g})')
    return 0
