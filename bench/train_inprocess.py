r"""
Train a preset in one process (the graph's computation, bit for bit) and evaluate it.

``pg_node.rl.train_inprocess`` with a parameter file and overrides: progress every
``--every`` steps (training return, value loss, KL), then the deterministic evaluation over
``--eval-episodes`` episodes: return, mean final fingertip distance, share within 2 cm::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/train_inprocess.py arm7 5000000 \
        model=/tmp/ur5/ur5.xml [seed=1 ...] [--save DIR]

The in-process rows of BENCHMARKS.md's UR5 section came from this code (then a script in
/tmp). ``--save DIR`` keeps the learner's checkpoint in ``DIR/checkpoints`` and the resolved
parameters in ``DIR/params.yaml``, as ``train`` writes them (for ``eval``,
``play``, ``export``). Not a test: nothing is asserted.
"""
import argparse
from pathlib import Path
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main() -> int:
    """Train, print progress and the evaluation."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('config', help='a preset name (arm7, ppo, dr...) or a parameter file')
    parser.add_argument('steps', type=float, help='environment steps (5e6 works)')
    parser.add_argument('overrides', nargs='*', help='key=value, as train takes them')
    parser.add_argument('--every', type=int, default=250_000, help='steps between lines')
    parser.add_argument('--eval-episodes', type=int, default=100)
    parser.add_argument('--save', type=Path, help='keep the checkpoint in DIR/checkpoints')
    args = parser.parse_args()
    from pg_node.common.config_files import load_config
    from pg_node.common.paths import config_file
    from pg_node.rl.train_inprocess import train_inprocess
    cfg = load_config(config_file(args.config), args.overrides)
    last = [0]

    def progress(info):
        if info['env_steps'] - last[0] >= args.every:
            last[0] = info['env_steps']
            print(f"step {info['env_steps']:,}: {info['wall_seconds']:.0f} s, training return "
                  f"{info['episode_return']:.3f}, value loss {info.get('value_loss', 0):.4f}, "
                  f"approx KL {info.get('approx_kl', float('nan')):.4f}", flush=True)

    t0 = time.perf_counter()
    summary = train_inprocess(cfg, int(args.steps), callback=progress,
                              eval_episodes=args.eval_episodes)
    if args.save:
        from pg_node.common.run_dir import RunDir
        run = RunDir(args.save)
        summary['learner'].save(run.checkpoints)
        # the run's parameters, as train writes them: eval and the card read its frame_skip,
        # randomization and position_delta there
        from pg_node.tools.train import write_params
        write_params(cfg, run.params)
    print(f"{summary['total_steps']:,} steps in {time.perf_counter() - t0:.0f} s "
          f"({summary['steps_per_second']:,.0f} steps/s); deterministic evaluation over "
          f"{args.eval_episodes} episodes: return {summary['eval_return']:.3f}, final distance "
          f"{100 * summary['eval_final_distance']:.2f} cm, "
          f"{100 * summary['eval_reached']:.0f}% within 2 cm", flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
