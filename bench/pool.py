"""
Independent benchmark runs, one at a time in the bench's process or ``jobs`` at a time.

A 1M-step learning run trains in one process on one core for most of its time (the arm's
two stepping threads and a single torch thread), so on a slow 2-core machine the ``curves``
and ``learning`` sections of ``python -m bench`` (about 50 such runs) take longer
than a working session. ``--jobs 2`` runs them two at a time, each in a fresh process of
its own (``multiprocessing``'s spawn start method: nothing of the bench's process state
leaks in, as in a sequential run that starts clean). Training graph runs never go through
here: four node processes need the machine to themselves.

pg_node's in-process runs compute the same numbers either way (seeded numpy, one torch
thread, deterministic MuJoCo). Their clocks do not: a run's wall seconds and steps/s then
count a neighbour on the other core, which the report says.
"""
import multiprocessing
import signal
import sys
import traceback
from typing import Callable, Dict, Optional, Sequence, Tuple

Task = Tuple[Callable[..., Dict], tuple]
#: said under a report's table whose runs went ``--jobs`` at a time
JOBS_NOTE = (' **{jobs} {runs} trained at a time** (`--jobs {jobs}`), each in its own '
             "process: their wall seconds and steps/s count the neighbours' load; pg_node's "
             'evaluations are those of runs made one at a time.')


def guarded(fn: Callable[..., Dict], args: tuple) -> Dict:
    """Return ``fn(*args)``, or ``{'error': first line}`` (traceback to stderr) if it raises."""
    try:
        return fn(*args)
    except Exception as exc:  # noqa: B902 - a failed run is reported in its table, not fatal
        print(traceback.format_exc(), file=sys.stderr, flush=True)
        return {'error': (str(exc).splitlines() or [type(exc).__name__])[0]}


def _worker_start():
    # Ctrl-C in a terminal reaches the whole foreground group: the bench stops the workers
    # itself (terminate), so a worker must not die half-way through writing a result
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import torch
        torch.set_num_threads(1)   # one core per run: the neighbour has the other
    except ImportError:
        pass


def _indexed(item):
    i, fn, args = item
    return i, guarded(fn, args)


def run_all(tasks: Sequence[Task], jobs: int, done: Callable[[int, Dict], None],
            before: Optional[Callable[[int], None]] = None) -> None:
    """
    Run ``tasks`` (``(module-level function, args)``), ``jobs`` at a time.

    ``done(i, result)`` is called in the bench's process as task ``i`` finishes (in the
    order they finish). With ``jobs`` 1 the tasks run here, in order, each after
    ``before(i)`` (a log line: with workers, when a task starts is not seen). On KeyboardInterrupt
    (Ctrl-C, or SIGTERM turned into one) the workers are terminated and it propagates; the
    tasks that finished have been handed to ``done``.
    """
    if jobs <= 1 or len(tasks) <= 1:
        for i, (fn, args) in enumerate(tasks):
            if before is not None:
                before(i)
            done(i, guarded(fn, args))
        return
    ctx = multiprocessing.get_context('spawn')
    # a fresh process per run (maxtasksperchild=1), as the first run of a sequential bench
    pool = ctx.Pool(min(jobs, len(tasks)), initializer=_worker_start, maxtasksperchild=1)
    try:
        items = [(i, fn, args) for i, (fn, args) in enumerate(tasks)]
        for i, result in pool.imap_unordered(_indexed, items, chunksize=1):
            done(i, result)
        pool.close()
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()
