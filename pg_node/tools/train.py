"""
``python -m pg_node train``: the whole training graph, supervised.

Validates the configuration (``--config`` plus ``key=value`` overrides) before anything
starts, writes the resolved parameters to ``<run_dir>/params.yaml``, starts ``sim_node`` and
``actor_node`` in one process (``sim_and_actor``: their lock-step exchange needs no other
process to wake) and ``critic_node`` and ``learner_node`` in another
(``critic_and_learner``: the batch stays in the process; ``--separate``: every node a
process of its own), each process in its own session and logging to ``<run_dir>/logs/``,
shows a progress bar read from the learner's ``progress.csv``, and supervises: a node that
dies is restarted (at most ``--max-restarts`` times each, with doubling back-off); the
learner resumes from its newest checkpoint, the critic V from its own, the actor picks up
the latched weights, and a restarted simulator starts fresh episodes (the learner writes the
ones it cut short to the bag as such). When the learner has learned ``total_steps`` (or on
Ctrl-C) the nodes are stopped with SIGINT (then SIGTERM, then SIGKILL), the deterministic
policy is evaluated over ``--eval-episodes`` episodes, and ``summary.json`` and
``learning_curve.png`` are written next to ``checkpoints/``, ``bag/`` and ``progress.csv``.

``--config`` takes a parameter file's path or a preset's name: ``--config ppo`` is the
package's ``config/ppo.yaml`` (tuned PPO), ``--config a2c`` its ``config/a2c.yaml`` (A2C
tuned for reacher2, the same values as the default ``config/pg_node.yaml``). A preset names only
the values of its algorithm; every other value is the default.
"""
import argparse
from datetime import datetime
import os
from pathlib import Path
import sys
import time
from typing import List, Optional

from pg_node.common import graph_plan
from pg_node.common.config_files import load_config
from pg_node.common.graph_plan import module_of
from pg_node.common.param_schema import ConfigError
from pg_node.common.params import SHARED
from pg_node.common.paths import preset_names
from pg_node.common.run import run_id_for_dir, run_namespace
from pg_node.common.run_dir import RunDir
from pg_node.tools.args import non_negative_float, run_id_arg
from pg_node.tools.processes import (EXIT_INTERRUPTED, Interrupts, shutting_down,
                                     terminate_as_interrupt)
from pg_node.tools.progress_view import format_rate, format_return, ProgressView, supervise
from pg_node.tools.supervisor import make_bags_whole, Supervisor
import yaml


#: what one host runs of a run (``--part``)
PARTS = graph_plan.PARTS


def parse_args(argv):
    """Parse the command line."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node train',
        description='Train the arm with A2C over the ROS 2 graph (sim, actor, critic, '
                    'learner nodes as processes).')
    parser.add_argument('overrides', nargs='*', metavar='key=value',
                        help='override any parameter (node.key=value for one node only)')
    parser.add_argument('--config', help='ROS 2 parameter file, or the name of a preset in the '
                                         f"package's config/: {', '.join(preset_names())} "
                                         '(default: config/pg_node.yaml, A2C)')
    parser.add_argument('--total-steps', type=int, help='environment steps to learn')
    parser.add_argument('--seed', type=int, help='seed of everything')
    parser.add_argument('--run-dir', help='where the run writes everything '
                                          '(default: runs/<date-time>)')
    parser.add_argument('--eval-episodes', type=int, default=100, help='default: %(default)s')
    parser.add_argument('--max-restarts', type=int, default=3,
                        help='restarts allowed per node (default: %(default)s)')
    parser.add_argument('--restart-delay', type=non_negative_float, default=1.0,
                        help='seconds before a dead node is first restarted, doubling at each '
                             'further restart (default: %(default)s)')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    parser.add_argument('--stall-timeout', type=non_negative_float, default=300.0,
                        metavar='SECONDS',
                        help='stop, saying why, once no step has been learned for this long '
                             '(the progress line says so after 30 s); 0: never '
                             '(default: %(default)s)')
    parser.add_argument('--run-id', type=run_id_arg,
                        help="the run's name on the ROS network: its nodes and topics live "
                             'under /<run id>, and messages of other runs are dropped '
                             "(default: from the run dir's name)")
    parser.add_argument('--network', action='store_true',
                        help='let the graph reach other machines (ROS_AUTOMATIC_DISCOVERY_RANGE'
                             '=SUBNET); default: this machine only (LOCALHOST). A value of '
                             'that variable in the environment wins over both')
    parser.add_argument('--part', choices=PARTS, default='all',
                        help='one run on many hosts: learner (the critic and the learner, on '
                             'one host) or workers (simulator/actor pairs, on each other host); '
                             'default: all of it here. Needs --run-id, the same on every host')
    parser.add_argument('--actors', metavar='IDS',
                        help="with --part workers: this host's actor ids, e.g. 2,3 or 0-3 "
                             '(default: every actor of num_actors)')
    parser.add_argument('--wait-learner', type=float, default=120.0, metavar='SECONDS',
                        help='with --part workers: how long to wait for the learner host to '
                             'announce the run (default: %(default)s)')
    parser.add_argument('--separate', action='store_true',
                        help='run every node as a process of its own (default: each '
                             'simulator and its actor in one process, sim_and_actor, and '
                             'the critic and the learner in another, critic_and_learner: '
                             'faster)')
    return parser.parse_intermixed_args(argv)   # key=value before and after options


def resolve_config(args) -> dict:
    """Return the validated configuration of every node, overrides applied."""
    from pg_node.common.paths import config_file, default_config
    from pg_node.rl.update_settings import check_settings
    overrides = list(args.overrides)
    if args.total_steps is not None:
        overrides.append(f'total_steps={args.total_steps}')
    if args.seed is not None:
        overrides.append(f'seed={args.seed}')
    run_dir = args.run_dir or os.path.join('runs', datetime.now().strftime('%Y%m%d-%H%M%S'))
    overrides.append(f'run_dir={os.path.abspath(run_dir)}')
    if getattr(args, 'run_id', None) is not None:
        overrides.append(f'run_id={args.run_id}')
    try:
        path = config_file(args.config) if args.config else default_config()
    except FileNotFoundError as exc:
        raise ConfigError(str(exc)) from None
    cfg = load_config(path, overrides, check=check_settings)
    if not cfg[SHARED]['run_id']:
        # a run always has an identity on the network: its directory's name by default
        cfg = load_config(path, overrides + [f'run_id={run_id_for_dir(run_dir)}'])
    # what every node will check of the model, checked once here: a model that compiles but
    # is no pg_node arm made both processes crash, restart and crash again
    from pg_node.common.paths import resolve_model
    from pg_node.sim.arm_task import check_arm, NotAnArm
    try:
        model = resolve_model(cfg[SHARED]['model'])
        check_arm(model, cfg['sim_node']['position_delta'])
    except NotAnArm as exc:
        raise ConfigError(f"parameter 'model': {exc}") from None
    if model == Path(os.path.expanduser(cfg[SHARED]['model'])):
        # a file, not a shipped name: absolute, so that the run's checkpoints play, evaluate
        # and export from any folder
        cfg[SHARED]['model'] = str(model.resolve())
    return cfg


#: Jazzy's discovery range: LOCALHOST keeps a graph on this machine, SUBNET opens it
DISCOVERY_RANGE = 'ROS_AUTOMATIC_DISCOVERY_RANGE'


#: what each discovery range reaches, in the words ``train`` prints
REACH = {'LOCALHOST': 'this machine only', 'SUBNET': 'this machine and its subnet',
         'OFF': 'no automatic discovery (ROS_STATIC_PEERS only)'}


def discovery_env(network: bool, environ=os.environ, asked: str = '--network'):
    """
    Return ``({'ROS_AUTOMATIC_DISCOVERY_RANGE': value}, why)`` for the nodes' environment.

    The user's own setting of the variable wins; otherwise ``LOCALHOST`` (this machine
    only), or ``SUBNET`` with ``network`` (which the option ``asked`` asked for).

    >>> discovery_env(False, {})
    ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}, 'default; --network opens it')
    >>> discovery_env(True, {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF'})[1]
    'set in the environment'
    """
    given = environ.get(DISCOVERY_RANGE, '').strip()
    if given:
        return {DISCOVERY_RANGE: given}, 'set in the environment'
    if network:
        return {DISCOVERY_RANGE: 'SUBNET'}, asked
    return {DISCOVERY_RANGE: 'LOCALHOST'}, 'default; --network opens it'


def write_params(cfg: dict, path: Path):
    """Write the resolved configuration as a ROS 2 parameter file (``/**/<node>`` keys)."""
    sections = {f'/**/{name}': {'ros__parameters': values} for name, values in cfg.items()
                if name != SHARED}
    path.write_text('# Resolved parameters of this run, written by python -m pg_node train.\n'
                    + yaml.safe_dump(sections, sort_keys=False))


#: a simulator/actor pair's processes, (name, module), the simulator's first: composed or not
PAIR_PROCESSES = {compose: [(exe, module_of(exe)) for exe, _ in table]
                  for compose, table in graph_plan.PAIR_PROCESSES.items()}
#: the critic's and the learner's processes, the learner's last: composed or not
TRAINING_PROCESSES = {compose: [(exe, module_of(exe)) for exe, _ in table]
                      for compose, table in graph_plan.TRAINING_PROCESSES.items()}


def learner_process(compose: bool = False) -> str:
    """Return the name of the process the learner runs in."""
    return graph_plan.learner_process(compose)


def run_plan(cfg: dict, compose: bool = False, part: str = 'all',
             actors: Optional[List[int]] = None) -> list:
    """Return the graph plan (:mod:`pg_node.common.graph_plan`) of a run's configuration."""
    shared = cfg[SHARED]
    return graph_plan.part_plan(shared['run_id'], shared['run_dir'], shared['seed'],
                                shared['num_envs'], shared['num_actors'], compose, part, actors)


def node_commands(params: Path, cfg: dict, compose: bool = False, part: str = 'all',
                  actors: Optional[List[int]] = None) -> dict:
    """
    Return ``{process name: command}`` for the graph of :func:`run_plan`.

    Every process gets ``params`` (the resolved configuration, which holds the run's id,
    directory and seed: all the run's only pair needs) and its namespace. A pair of several
    has a parameter file of its own, ``params_arm<i>.yaml``, with its values under its nodes'
    full names (a later parameter file wins, and only a node's full name reaches one
    namespace). With ``compose`` each pair is one process, ``sim_and_actor``
    (``sim_and_actor_<i>``), holding both nodes, and the critic and the learner are one,
    ``critic_and_learner``. ``part``: ``learner`` leaves the pairs out, ``workers`` the critic
    and the learner, and starts the pairs of ``actors`` only (default: all).
    """
    cmds = {}
    for proc in run_plan(cfg, compose, part, actors):
        own = []
        if proc.pair is not None and proc.pair.tag:
            ns_file = params.with_name(f'params_arm{proc.pair.actor_id}.yaml')
            ns_file.write_text(yaml.safe_dump({
                f'{proc.namespace}/{node}': {'ros__parameters': values}
                for node, values in proc.pair.values().items()}))
            own = ['--params-file', str(ns_file)]
        # one __ns remap per process: rcl takes the first that matches
        cmds[proc.name] = [sys.executable, '-m', proc.module, '--ros-args', '--params-file',
                           str(params), *own, '-r', f'__ns:={proc.namespace}']
    return cmds


def sim_seeds(cfg: dict, compose: bool = False) -> dict:
    """Return each simulator's seed by the name of its process in :func:`node_commands`."""
    return {proc.name: proc.pair.seed for proc in run_plan(cfg, compose)
            if graph_plan.SIMULATOR in proc.values}


def evaluate_run(run_dir: Path, episodes: int) -> dict:
    """
    Evaluate the newest checkpoint's deterministic policy.

    At the run's control step (its ``sim_node.frame_skip``, as ``python -m pg_node eval``
    takes it from the policy's card): a policy trained at ``frame_skip:=20`` and evaluated
    at the default 2 would act ten times as often, in episodes a tenth as long.
    """
    from pg_node.rl.checkpoint import list_checkpoints, load_latest
    from pg_node.rl.evaluate import evaluate_policy
    from pg_node.rl.learner import policy_from_checkpoint
    from pg_node.rl.trained_policy import card_control, checkpoint_card
    checkpoints = RunDir(run_dir).checkpoints
    state, problems = load_latest(checkpoints)
    for p in problems:
        print(p, file=sys.stderr)
    if state is None:
        return {}
    ckpt = next(path for path, version in list_checkpoints(checkpoints)
                if version == state['version'])
    card = checkpoint_card(state, ckpt)
    res = evaluate_policy(policy_from_checkpoint(state), state['config']['model'], episodes,
                          state['config']['seed'], **card_control(card))
    res['policy_version'] = int(state['version'])
    res['checkpoint'] = str(ckpt)
    return res


def resume_point(run_dir: Path) -> Optional[dict]:
    """
    Return what the learner will resume from: the newest valid checkpoint in ``checkpoints/``.

    ``{'version', 'env_steps', 'wall_seconds', 'checkpoint'}``, or None for a fresh run.
    Read before the nodes start, so that the console can say it resumed.
    """
    run = RunDir(run_dir)
    if not run.has_checkpoint():
        return None
    from pg_node.rl.checkpoint import checkpoint_path, load_latest
    directory = run.checkpoints
    state, _ = load_latest(directory)
    if state is None:
        return None
    return {'version': int(state['version']), 'env_steps': int(state.get('env_steps', 0)),
            'wall_seconds': float(state.get('wall_seconds', 0.0)),
            'checkpoint': str(checkpoint_path(directory, int(state['version'])))}


def check_part(args, cfg: dict) -> Optional[List[int]]:
    """Return the actor ids of a worker host (None for other parts); ConfigError if bad."""
    if args.part != 'all' and args.run_id is None:
        raise ConfigError(f'--part {args.part} needs --run-id NAME, the same on every host '
                          'of the run')
    if args.actors is not None and args.part != 'workers':
        raise ConfigError('--actors is for --part workers')
    if args.part != 'workers':
        return None
    n = cfg[SHARED]['num_actors']
    from pg_node.tools.hosts import parse_actors
    try:
        return parse_actors(args.actors or f'0-{n - 1}', n)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def main(argv=None) -> int:
    """Run ``python -m pg_node train``."""
    args = parse_args(argv)
    try:
        cfg = resolve_config(args)
        actors = check_part(args, cfg)
    except ConfigError as exc:
        print(f'configuration error: {exc}', file=sys.stderr)
        return 2
    run = RunDir(cfg[SHARED]['run_dir'])
    run_dir, params = run.path, run.params
    total = cfg['learner_node']['total_steps']
    start = resume_point(run_dir) if args.part != 'workers' else None
    if start is not None and start['env_steps'] >= total:
        # a finished run is left as it is: no new bag, no summary written over
        print(f"{run_dir}: already learned {start['env_steps']} steps (total_steps {total}); "
              'raise --total-steps to go on', flush=True)
        return 0
    if args.part != 'workers':      # a worker host writes its run folder once it has joined
        run.make()
        write_params(cfg, params)
    n_act = cfg[SHARED]['num_actors']
    algo = f"{cfg['learner_node']['algo']} (phi = {cfg['critic_node']['estimator']})"
    part = {'all': '', 'learner': ' (this host: the critic and the learner)',
            'workers': f' (this host: actors {",".join(map(str, actors or []))})'}[args.part]
    print(f'pg_node: training {algo}, {n_act} x {cfg[SHARED]["num_envs"]} x '
          f'{cfg[SHARED]["model"]} ({cfg[SHARED]["sync_mode"]}), for {total} steps{part}; '
          f'run dir {run_dir}', flush=True)
    run_id = cfg[SHARED]['run_id']
    discovery, why = discovery_env(args.network or args.part != 'all',
                                   asked='--network' if args.network else f'--part {args.part}')
    value = discovery[DISCOVERY_RANGE]
    print(f'run id {run_id}: topics {run_namespace(run_id).rstrip("/")}/pg_node/..., '
          f'graph on {REACH.get(value, value)} ({DISCOVERY_RANGE}={value}: {why})',
          flush=True)
    if args.part != 'all':
        os.environ.update(discovery)        # this process's own node, beside the nodes'
    if args.part == 'workers':
        return run_workers(args, cfg, actors, params, discovery)
    announcer = None
    if args.part == 'learner':
        from pg_node.tools.hosts import Announcer
        announcer = Announcer(cfg)
    if start is not None:
        print(f"resumed from policy version {start['version']} ({start['env_steps']} steps "
              f"learned, {start['checkpoint']})", flush=True)
    bags_before = run.bags()    # a resumed run's learner writes the next: bag_1, ...
    compose = not args.separate
    sup = Supervisor(run_dir, node_commands(params, cfg, compose, args.part), args.max_restarts,
                     total, sim_seeds(cfg, compose), learner_process(compose), env=discovery,
                     restart_delay=args.restart_delay)
    view = ProgressView(run.progress, total, start, bar=not args.no_progress)
    interrupts = Interrupts()
    with interrupts.handled():  # SIGTERM / SIGHUP stop the nodes as Ctrl-C does
        return supervise_and_report(args, cfg, sup, view, start, announcer, interrupts,
                                    bags_before)


def supervise_and_report(args, cfg: dict, sup: Supervisor, view: ProgressView,
                         start: Optional[dict], announcer, interrupts: Interrupts,
                         bags_before: list) -> int:
    """
    Run the graph until done, failed or interrupted; evaluate, write and print the summary.

    The first Ctrl-C stops the nodes (and says how to skip the evaluation); the second,
    while they stop or during the evaluation, skips it (``summary.json``'s ``evaluation``:
    ``skipped``); further ones change nothing: the summary and the curve are written.
    ``bags_before``: the run's bag folders before this session (a resume writes the next).
    """
    run = sup.run
    state, interrupted = run_until_stopped(args, sup, view, announcer, interrupts)
    if state == 'failed':
        print(f'training failed: {sup.failed}; logs in {run.logs}', file=sys.stderr)
    elif state == 'stalled':
        print(f'training stopped: {sup.failed}', file=sys.stderr)
    for line in make_bags_whole(sup.unfinished_bags):
        print(line)
    rows = run.read_progress()
    summary = session_summary(sup, view, start, rows, bags_before, interrupted, state)
    evaluate_unless_skipped(run, args.eval_episodes, interrupts, summary)
    summary['curve'] = [{'env_steps': r['env_steps'], 'wall_seconds': r['wall_seconds'],
                         'episode_return': r['episode_return']} for r in rows]
    summary['config'] = dict(cfg)
    summary['wall_seconds_total'] = time.monotonic() - view.t0  # this command, evaluation too
    run.write_summary(summary)
    if rows:
        # the same figure as python -m pg_node plot <run dir>: returns, speed, losses, entropy
        from pg_node.tools.plot import plot_run, RunData
        plot_run(RunData(run.path), run.curve)
    print_report(run, summary, view, bags_before)
    if state in ('failed', 'stalled'):
        return 1
    return EXIT_INTERRUPTED if interrupted else 0


def run_until_stopped(args, sup: Supervisor, view: ProgressView, announcer,
                      interrupts: Interrupts) -> tuple:
    """
    Supervise the graph until done, failed or Ctrl-C; stop the nodes; return the outcome.

    ``(state, interrupted)``. Whatever ended it, the nodes are stopped, the worker hosts
    (``announcer``) told, and the rows the learner wrote while it was being stopped shown.
    """
    state = 'running'
    interrupted = False
    try:
        with interrupts.raising():
            state = supervise(sup, view, args.stall_timeout)
    except KeyboardInterrupt as exc:
        interrupted = True
        skip = (f'; Ctrl-C again skips the evaluation that follows ({args.eval_episodes} '
                'episodes)' if args.eval_episodes > 0 else '')
        print(f'\ninterrupted{f" by {exc}" if str(exc) else ""}: stopping the nodes{skip}',
              file=sys.stderr, flush=True)
    finally:
        # a second Ctrl-C is counted, not raised: it must not leave nodes behind
        sup.stop_all()
        if announcer is not None:
            announcer.finish(state)     # the worker hosts stop their nodes and end
            announcer.close()
        # the rows the learner wrote while it was being stopped are this session's too (an
        # interrupted fresh run said '185344 steps in this session (189952 in all)')
        view.poll()
        view.close()
    return state, interrupted


def session_summary(sup: Supervisor, view: ProgressView, start: Optional[dict], rows: list,
                    bags_before: list, interrupted: bool, state: str) -> dict:
    """
    Return the summary of the run and of this session: steps, times, restarts, usage, bags.

    ``rows``: the run's progress rows, every session's; ``start``: what this session
    resumed from (None: a fresh run).
    """
    last = view.last  # the newest row of this session (None: it learned nothing)
    summary = {'interrupted': interrupted, 'failed': state in ('failed', 'stalled'),
               'stalled': sup.failed if state == 'stalled' else None,
               'total_steps': int(rows[-1]['env_steps']) if rows else 0,
               'resumed_from_version': start['version'] if start else None,
               # the learner's clock, which goes on across resumes
               'wall_seconds': rows[-1]['wall_seconds'] if rows else 0.0,
               'session_steps': int(last['env_steps']) - view.start_steps if last else 0,
               # from this session's first update to its last, by the learner's clock
               'session_training_seconds': (last['wall_seconds'] - view.first['wall_seconds']
                                            if last else 0.0),
               # from the start of this command to its first progress row
               'bringup_seconds': view.bringup_seconds,
               'restarts': sup.restarts,
               'nodes': sup.usage()}
    bags = sup.run.bags()
    # every bag of the run, in order (plot and replay --info read them all), and this
    # session's: a resumed run's are new folders beside the first
    summary['bags'] = [b.name for b in bags]
    summary['session_bags'] = [b.name for b in bags if b not in bags_before]
    summary['steps_per_second'] = view.steps_per_second(last) if last else float('nan')
    return summary


def evaluate_unless_skipped(run: RunDir, episodes: int, interrupts: Interrupts,
                            summary: dict):
    """
    Evaluate the run's newest checkpoint into ``summary``, unless Ctrl-C says not to.

    ``summary['evaluation']`` says what happened: ``no checkpoint``, ``skipped`` (a second
    Ctrl-C, before or during it) or ``done`` (and the evaluation's figures are added).
    """
    summary['evaluation'] = 'no checkpoint'
    if not run.has_checkpoint():
        return
    if not summary['total_steps']:
        # only the initial policy's checkpoint: nothing to evaluate but an untrained policy
        summary['evaluation'] = 'nothing learned'
        return
    summary['evaluation'] = 'skipped'
    if interrupts.count < 2:
        print(f'evaluating the deterministic policy over {episodes} episodes '
              '(Ctrl-C skips it) ...', flush=True)
        try:
            with interrupts.raising():
                summary.update(evaluate_run(run.path, episodes))
            summary['evaluation'] = 'done'
        except KeyboardInterrupt:
            pass


def print_report(run: RunDir, summary: dict, view: ProgressView, bags_before: list):
    """Print the end of a run: the evaluation, the speed, the nodes' usage, the files."""
    # a failed run prints only what exists: no evaluation of nothing, no path to no file
    if 'eval_return' in summary:
        print(f"deterministic evaluation: return {summary['eval_return']:.2f} +/- "
              f"{summary['eval_return_std']:.2f} over {summary['eval_episodes']} episodes, "
              f"final distance {100 * summary['eval_final_distance']:.2f} cm, "
              f"{100 * summary['eval_reached']:.0f}% within 2 cm, "
              f"policy version {summary['policy_version']}")
    elif summary['evaluation'] == 'nothing learned':
        print('nothing learned yet (stopped before the first update): no evaluation')
    elif summary['evaluation'] == 'skipped':
        print(f'evaluation skipped (Ctrl-C): python -m pg_node eval {run.path} evaluates the '
              'run')
    else:
        print('no policy to evaluate: the learner wrote no checkpoint')
    if view.last is not None:
        print("training episodes' mean return (last update): "
              f"{format_return(view.last['episode_return'])}")
    bringup = ('not over: no update yet' if view.bringup_seconds is None
               else f'{view.bringup_seconds:.1f} s')
    print(f"{summary['session_steps']} steps learned in this session "
          f"({summary['total_steps']} in all): {format_rate(summary['steps_per_second'])} "
          'steps/s from its first update to its last '
          f"({summary['session_training_seconds']:.1f} s); "
          f"bring-up {bringup}, {summary['wall_seconds_total']:.0f} s in total")
    print('nodes (peak memory, CPU in training): ' + '; '.join(
        f"{name} {format_rate(u['peak_rss_mb'])} MB, {u['cpu_seconds_training']:.1f} s"
        for name, u in summary['nodes'].items()))
    this = ' (this session)' if bags_before else ''
    files = [('run dir', run.path, '')] + [
        ('bag', run.path / b, this if b in summary['session_bags'] else '')
        for b in summary['bags']] + [
        ('checkpoint', Path(summary.get('checkpoint', run.path / 'no checkpoint')), ''),
        ('summary', run.summary, ''), ('curve', run.curve, '')]
    print('\n'.join(f'{label + ":":<11} {path}{note}'
                    for label, path, note in files if path.exists()))


def run_workers(args, cfg: dict, actors: List[int], params: Path, discovery: dict) -> int:
    """
    Run this host's simulator/actor pairs of a run whose learner runs on another host.

    Waits for the learner host's announcement (:mod:`pg_node.tools.hosts`), refuses to join a
    run that no learner announces or whose configuration differs (leaving no run folder:
    it is written once the host has joined), then supervises the pairs
    (restarting one that dies) until the learner host says the run has ended.
    """
    from pg_node.tools.hosts import Follower
    run_id, run = cfg[SHARED]['run_id'], RunDir(cfg[SHARED]['run_dir'])
    run_dir = run.path
    follower = Follower(run_id)
    state, interrupted = 'running', False
    try:
        print(f'waiting for the learner host of run {run_id} (at most {args.wait_learner:g} '
              's) ...', flush=True)
        info = follower.wait(args.wait_learner)
        if info is None:
            print(f'configuration error: no learner host announces run {run_id!r} on ROS '
                  f'domain {os.environ.get("ROS_DOMAIN_ID", "0")} after '
                  f'{args.wait_learner:g} s: start train --part learner --run-id {run_id} '
                  'there first, or check the run id, ROS_DOMAIN_ID and discovery',
                  file=sys.stderr)
            return 2
        wrong = follower.check(cfg)
        if wrong is not None:
            print(f'configuration error: {wrong}', file=sys.stderr)
            return 2
        if follower.done():
            print(f'run {run_id} has ended on the learner host ({info["state"]}): nothing '
                  'to do', file=sys.stderr)
            return 1
        run.make()
        write_params(cfg, params)
        compose = not args.separate
        sup = Supervisor(run_dir, node_commands(params, cfg, compose, 'workers', actors),
                         args.max_restarts, None, sim_seeds(cfg, compose),
                         learner_process(compose), env=discovery,
                         restart_delay=args.restart_delay)
        print(f'joined run {run_id}: starting {", ".join(sup.commands)}; logs in '
              f'{run.logs}', flush=True)
        try:
            with terminate_as_interrupt():
                sup.start_all()
                while state == 'running':
                    follower.spin(0.5)
                    state = 'done' if follower.done() else sup.check()
        except KeyboardInterrupt as exc:
            interrupted = True
            print(f'\ninterrupted{f" by {exc}" if str(exc) else ""}: stopping the nodes',
                  file=sys.stderr)
        finally:
            with shutting_down():
                sup.stop_all()
    finally:
        follower.close()
    if state == 'failed':
        print(f'worker host failed: {sup.failed}; logs in {run.logs}', file=sys.stderr)
    summary = {'part': 'workers', 'actors': actors, 'interrupted': interrupted,
               'failed': state == 'failed', 'learner_host_state': (follower.info or {}).get(
                   'state'), 'restarts': sup.restarts, 'nodes': sup.usage(),
               'config': dict(cfg)}
    run.write_summary(summary)
    if state == 'done':
        print(f'run {run_id} has ended on the learner host '
              f'({follower.info["state"]}); this host ran actors '
              f'{",".join(map(str, actors))}, restarts {sup.restarts}')
    return 1 if state == 'failed' else 0
