"""
``python -m pg_node robustness RUN [RUN ...]``: how far trained policies hold up off-model.

Each run's policy is evaluated (deterministic mean action, :func:`pg_node.rl.evaluate.
evaluate_policy`) on its own arm model changed along one axis at a time, every value of
:data:`GRID`: link masses x0.5-2, joint armature (the motors' reflected inertia) x0.5-2,
motor strength x0.6-1.4, joint damping x0.5-3, command latency 0-3 control steps and joint
angle noise 0-0.05 rad. Every point is the same ``--episodes`` episodes (starts and goals),
so runs and perturbations compare episode for episode; the nominal arm is each axis'
neutral value, and the error of a point's change from it is the paired one.

``--train ppo,dr --seeds 0,1,2`` first trains each preset with each seed through the
graph (``python -m pg_node train``, into ``<out>/runs/<preset>_s<seed>``; a finished run
is kept and reused), then compares the presets, each the mean over its seeds: the
benchmark of BENCHMARKS.md ("Robustness") in one invocation.

Writes ``robustness.csv`` (one row per run or preset, axis and value: return, the
standard error of its change from nominal, mean final distance, share within 2 cm),
``robustness.json`` and ``robustness.png`` (return and final distance against each axis,
one line per run or preset) into ``--out``, and prints a table for each with, per axis,
its worst point and the ratio of its final distance to the nominal one.
"""
import argparse
import csv
import json
from pathlib import Path
import subprocess
import sys
from typing import Dict, List

import numpy as np
from pg_node.common.run_dir import RunDir
from pg_node.tools.args import positive_int

#: axis (a --perturb key) -> values; the first value that leaves the arm nominal is its centre
GRID: Dict[str, List[float]] = {
    'mass_scale': [0.5, 0.75, 1.0, 1.5, 2.0],
    'armature_scale': [0.5, 0.75, 1.0, 1.5, 2.0],
    'gear_scale': [0.6, 0.8, 1.0, 1.2, 1.4],
    'damping_scale': [0.5, 1.0, 2.0, 3.0],
    'latency_steps': [0, 1, 2, 3],
    'obs_noise': [0.0, 0.01, 0.02, 0.05],
}
NOMINAL = {'mass_scale': 1.0, 'armature_scale': 1.0, 'gear_scale': 1.0, 'damping_scale': 1.0,
           'latency_steps': 0, 'obs_noise': 0.0}
LABELS = {'mass_scale': 'link masses (x)', 'armature_scale': 'joint armature (x)',
          'gear_scale': 'motor strength (x)', 'damping_scale': 'joint damping (x)',
          'latency_steps': 'command latency (steps)', 'obs_noise': 'joint angle noise (rad)'}
FIELDS = ('run', 'axis', 'value', 'return', 'change_se', 'final_distance_cm',
          'reached_share', 'episodes')


class RunError(Exception):
    """A run that cannot be evaluated; the message says why in one line."""


def load_run(path: str):
    """Return ``(name, policy, model)`` of a run directory or checkpoint."""
    from pg_node.rl.learner import policy_from_checkpoint
    from pg_node.rl.trained_policy import find_checkpoint, PolicySourceError
    try:
        state, _ = find_checkpoint(path)
    except PolicySourceError as exc:
        raise RunError(str(exc)) from None
    name = RunDir.of_checkpoint(path).path.name
    return name, policy_from_checkpoint(state), state['config']['model']


def sweep(policy, model: str, episodes: int, seed: int, grid=None) -> Dict:
    """Evaluate ``policy`` at every point of ``grid``; return per-episode arrays per point."""
    from pg_node.common.perturbations import parse_perturbation
    from pg_node.rl.evaluate import evaluate_policy
    points = {}
    cache = {}
    for axis, values in (grid or GRID).items():
        for value in values:
            key = None if value == NOMINAL.get(axis) else (axis, value)
            if key not in cache:
                terms = {} if key is None else parse_perturbation([f'{axis}={value:g}'])
                res = evaluate_policy(policy, model, episodes, seed, perturbation=terms)
                cache[key] = (np.asarray(res['eval_returns']),
                              np.asarray(res['eval_final_distances']))
            points[(axis, value)] = cache[key]
    return points


def summarise(sweeps: List[Dict]) -> List[Dict]:
    """
    Return one row per point over the episodes of one or more sweeps (seeds of a preset).

    ``change_se`` is the standard error of the mean change of return from the nominal
    point, over the paired episodes (the same starts and goals at every point).
    """
    from pg_node.rl.evaluate import REACHED
    rows = []
    for (axis, value) in sweeps[0]:
        ret = np.concatenate([s[(axis, value)][0] for s in sweeps])
        dist = np.concatenate([s[(axis, value)][1] for s in sweeps])
        base = np.concatenate([s[(axis, NOMINAL[axis])][0] for s in sweeps])
        change = ret - base
        rows.append({'axis': axis, 'value': value, 'return': float(ret.mean()),
                     'change_se': float(change.std(ddof=1) / np.sqrt(change.size)),
                     'final_distance_cm': float(100 * dist.mean()),
                     'reached_share': float(np.mean(dist <= REACHED)),
                     'episodes': int(ret.size)})
    return rows


def worst(rows: List[Dict]) -> Dict[str, Dict]:
    """Return per axis the point of largest final distance and its ratio to the nominal."""
    out = {}
    for axis in dict.fromkeys(r['axis'] for r in rows):
        pts = [r for r in rows if r['axis'] == axis]
        nominal = next(r for r in pts if r['value'] == NOMINAL[axis])
        bad = max(pts, key=lambda r: r['final_distance_cm'])
        out[axis] = {'value': bad['value'], 'final_distance_cm': bad['final_distance_cm'],
                     'ratio': bad['final_distance_cm'] / nominal['final_distance_cm'],
                     'return': bad['return'], 'nominal_return': nominal['return']}
    return out


def table(name: str, rows: List[Dict]) -> str:
    """Return a markdown table of one run's sweep and its worst point per axis."""
    lines = [f'### {name}', '',
             '| axis | value | return (± s.e. of the change) | final distance (cm) | '
             'within 2 cm |', '|---|---|---|---|---|']
    for r in rows:
        lines.append(f"| {r['axis']} | {r['value']:g} | {r['return']:.2f} ± "
                     f"{r['change_se']:.2f} | {r['final_distance_cm']:.2f} | "
                     f"{100 * r['reached_share']:.0f}% |")
    lines += ['', '| axis | worst value | final distance (cm) | x nominal |', '|---|---|---|---|']
    for axis, w in worst(rows).items():
        lines.append(f"| {axis} | {w['value']:g} | {w['final_distance_cm']:.2f} | "
                     f"{w['ratio']:.2f} |")
    return '\n'.join(lines)


def plot(results: Dict[str, List[Dict]], output: Path, title: str = None):
    """Draw return and final distance against each axis, one line per run."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    axes_names = list(dict.fromkeys(r['axis'] for rows in results.values() for r in rows))
    fig, axes = plt.subplots(2, len(axes_names), figsize=(3.2 * len(axes_names), 6.4),
                             squeeze=False)
    for k, axis in enumerate(axes_names):
        for name, rows in results.items():
            pts = [r for r in rows if r['axis'] == axis]
            x = [r['value'] for r in pts]
            axes[0, k].errorbar(x, [r['return'] for r in pts],
                                yerr=[2 * r['change_se'] for r in pts], marker='o',
                                capsize=3, label=name)
            axes[1, k].plot(x, [r['final_distance_cm'] for r in pts], marker='o', label=name)
        for row in (0, 1):
            axes[row, k].axvline(NOMINAL[axis], color='0.7', lw=0.8, ls='--')
            axes[row, k].grid(alpha=0.3)
        axes[1, k].axhline(2.0, color='0.5', lw=0.8, ls=':')
        axes[1, k].set_xlabel(LABELS.get(axis, axis))
        axes[1, k].set_ylim(bottom=0)
    axes[0, 0].set_ylabel('mean return (± 2 s.e. of the change)')
    axes[1, 0].set_ylabel('mean final distance (cm)')
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title or 'Robustness: one perturbation at a time (dashed: the model; '
                          'dotted: 2 cm)')
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    plt.close(fig)


def train_presets(presets: List[str], seeds: List[int], steps: int, runs_dir: Path,
                  log) -> List[tuple]:
    """Train each preset with each seed through the graph; return ``(group, run dir)``."""
    out = []
    for preset in presets:
        group = Path(preset).stem
        for seed in seeds:
            run = runs_dir / f'{group}_s{seed}'
            if RunDir(run).summary.is_file():
                log(f'robustness: {run} is trained already; using it')
            else:
                log(f'robustness: training {preset}, seed {seed}, {steps} steps -> {run}')
                cmd = [sys.executable, '-m', 'pg_node', 'train', '--config', preset,
                       '--seed', str(seed), '--total-steps', str(steps), '--run-dir',
                       str(run), '--no-progress']
                res = subprocess.run(cmd, stdout=subprocess.DEVNULL)
                if res.returncode != 0:
                    raise RunError(f'training {preset} seed {seed} failed (exit '
                                   f'{res.returncode}); its logs are in {run}/logs')
            out.append((group, run))
    return out


def _seeds(text: str) -> List[int]:
    try:
        seeds = [int(x) for x in text.split(',') if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a comma-separated list of '
                                         'seeds') from None
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f'{text!r}: need seeds >= 0')
    return seeds


def main(argv=None) -> int:
    """Run ``python -m pg_node robustness``."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node robustness',
        description='Evaluate trained policies on arms that are not their model (heavier, '
                    'weaker, more damped, late commands, noisy joints) and compare them.')
    parser.add_argument('runs', nargs='*', metavar='RUN',
                        help='run directories (or checkpoints) to compare')
    parser.add_argument('--train', metavar='PRESETS',
                        help='comma-separated presets or config files to train first, each '
                             'with every --seeds, then compare (e.g. ppo,dr)')
    parser.add_argument('--seeds', type=_seeds, default=[0, 1, 2],
                        help='seeds of --train (default: 0,1,2)')
    parser.add_argument('--total-steps', type=positive_int, default=1_000_000,
                        help='steps of each --train run (default: %(default)s)')
    parser.add_argument('--episodes', type=positive_int, default=100,
                        help='episodes per point, the same ones at every point '
                             '(default: %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='evaluation seed (default: 0)')
    parser.add_argument('--out', default='robustness',
                        help='directory for robustness.csv/.json/.png (default: %(default)s)')
    parser.add_argument('--title', help='title of the plot')
    args = parser.parse_args(argv)
    if not args.runs and not args.train:
        parser.error('give run directories to compare, or --train PRESETS')
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        print(f'robustness: --out {out} is a file, not a directory', file=sys.stderr)
        return 2

    def log(text):
        print(text, file=sys.stderr, flush=True)

    runs = [(None, Path(p)) for p in args.runs]
    try:
        if args.train:
            presets = [p.strip() for p in args.train.split(',') if p.strip()]
            from pg_node.common.paths import config_file
            for preset in presets:
                config_file(preset)
            runs += train_presets(presets, args.seeds, args.total_steps, out / 'runs', log)
        loaded = [(group, *load_run(str(path))) for group, path in runs]
    except RunError as exc:
        print(f'robustness: {exc}', file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:
        print(f'robustness: {exc}', file=sys.stderr)
        return 2
    names = [n for _, n, _, _ in loaded]
    if len(set(names)) != len(names):
        # two runs of the same name (a/run, b/run): name them by their paths instead
        names = [str(p) for _, p in runs]
    sweeps: Dict[str, List[Dict]] = {}
    for (group, _, policy, model), name in zip(loaded, names):
        log(f'robustness: {name} ({model}), {sum(map(len, GRID.values()))} points of '
            f'{args.episodes} episodes')
        sweeps.setdefault(group or name, []).append(
            sweep(policy, model, args.episodes, args.seed))
    results = {name: summarise(s) for name, s in sweeps.items()}
    for name, rows in results.items():
        seeds = len(sweeps[name])
        print(table(name + (f' (mean of {seeds} runs)' if seeds > 1 else ''), rows) + '\n')
    out.mkdir(parents=True, exist_ok=True)
    with open(out / 'robustness.csv', 'w', newline='') as f:
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        for name, rows in results.items():
            for r in rows:
                writer.writerow({'run': name, **r})
    (out / 'robustness.json').write_text(json.dumps(
        {name: {'runs': len(sweeps[name]), 'points': rows, 'worst': worst(rows)}
         for name, rows in results.items()}, indent=1))
    plot(results, out / 'robustness.png', args.title)
    log(f'robustness: wrote {out / "robustness.csv"}, {out / "robustness.json"} and '
        f'{out / "robustness.png"}')
    return 0
