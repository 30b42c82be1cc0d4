"""
How a pg_node node process runs, from ``rclpy.init`` to its exit code.

rclpy's init and executor, stop signals, the supervisor's death, CPU niceness, and the
``main`` loop (:func:`run`) with its exit codes.

A bad configuration (:class:`pg_node.common.param_schema.ConfigError`, raised by any layer)
ends the process in one line with exit code 2; SIGINT and SIGTERM end the loop between callbacks.
"""
import contextlib
import os
import signal
import sys
import textwrap
import threading
from typing import Callable, Iterator, List, Mapping, Optional, Union

from pg_node.common.param_schema import ConfigError
from pg_node.common.paths import SUPERVISOR_ENV
from pg_node.ros import local_hop
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


#: the executors a node can spin in (environment variable ``PG_NODE_EXECUTOR``)
EXECUTORS = ('events', 'single_threaded')


def make_executor(context=None):
    """
    Return the executor named by ``PG_NODE_EXECUTOR``: ``events`` (default) or ``single_threaded``.

    ``events`` is rclpy's EventsExecutor (``rclpy.experimental``), whose wait loop and
    dispatch are C++: every message of the lock-step loop wakes a node, and rclpy's Python
    ``SingleThreadedExecutor`` spends more per wake-up than the actor spends sampling (see
    docs/results/PROFILE.md). Its ``spin()`` does not return on shutdown in this rclpy, so
    nodes call ``spin_once`` in a loop, which does. ``single_threaded`` is rclpy's default
    executor, the one ``rclpy.spin`` uses. ``context``: rclpy's default context if None.
    """
    name = os.environ.get('PG_NODE_EXECUTOR', 'events').strip() or 'events'
    if name == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if name == 'single_threaded':
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor(context=context)
    raise ConfigError(f'PG_NODE_EXECUTOR={name!r}: choose one of {", ".join(EXECUTORS)}')


def take_nice(nice: int) -> Optional[str]:
    """
    Give every thread of this process the niceness ``nice``; return why not, or None.

    What ``renice -n <nice> -p <pid>`` does to a running process, thread by thread (on
    Linux a thread has its own niceness; threads started later inherit their creator's).
    A thread already nicer than ``nice`` keeps its own: lowering it back needs
    CAP_SYS_NICE.
    """
    try:
        for tid in sorted(int(t) for t in os.listdir('/proc/self/task')):
            try:
                if os.getpriority(os.PRIO_PROCESS, tid) < nice:
                    os.setpriority(os.PRIO_PROCESS, tid, nice)
            except ProcessLookupError:
                continue                   # the thread ended meanwhile
    except (OSError, AttributeError) as exc:
        return getattr(exc, 'strerror', None) or str(exc)
    return None


def take_idle() -> Optional[str]:
    """
    Put every thread of this process under the SCHED_IDLE policy; return why not, or None.

    What ``chrt --idle -a -p 0 <pid>`` does; threads started later inherit it. A thread
    under SCHED_IDLE runs only when no other thread wants its core, and a waking thread of
    the normal policy takes the core from it at once, where a nice-10 thread keeps it for
    a while (measured: docs/results/PROFILE.md, "Measurements and incidents behind code
    choices"). An unprivileged process cannot leave the policy again.
    """
    if not hasattr(os, 'SCHED_IDLE'):
        return 'SCHED_IDLE is Linux only'
    try:
        for tid in sorted(int(t) for t in os.listdir('/proc/self/task')):
            try:
                os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))
            except ProcessLookupError:
                continue                   # the thread ended meanwhile
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


def _apply_cpu_params(node: Node) -> None:
    """Take the node's ``nice`` and ``sched_idle`` parameters, if it has them; say so."""
    if not node.has_parameter('nice'):
        return
    nice = node.get_parameter('nice').value
    if nice:
        refused = take_nice(nice)
        if refused is None:
            node.get_logger().info(f'running at CPU niceness {nice} (parameter nice)')
        else:
            node.get_logger().warning(f'nice {nice}: the system refused ({refused}); running '
                                      'at the niceness it was started with')
    if (node.has_parameter('sched_idle') and node.get_parameter('sched_idle').value
            and node.get_parameter('sync_mode').value == 'sync'):
        refused = take_idle()
        if refused is None:
            node.get_logger().info('running under SCHED_IDLE: a core only when the simulator '
                                   'and the actor leave one (parameter sched_idle)')
        else:
            node.get_logger().warning(f'sched_idle: the system refused ({refused}); running '
                                      'under the normal policy')


def make_together(*factories: Callable[[], Node]) -> List[Node]:
    """
    Build the nodes of one process in turn (composition); return them as a list.

    When one fails (a refused parameter), the nodes built before it are closed (their
    ``close()``, if they have one: the simulator's MuJoCo threads) and destroyed before the
    error goes on to :func:`run`, which reports it.
    """
    built = []
    try:
        for make in factories:
            built.append(make())
    except BaseException:
        for node in reversed(built):
            if hasattr(node, 'close'):
                node.close()
            node.destroy_node()
        raise
    return built


class StopRequest:
    """Which stop signal arrived (``signum``), if one did; see :func:`stop_on_signals`."""

    def __init__(self):
        self.signum: Optional[int] = None

    def __bool__(self) -> bool:
        return self.signum is not None


#: the signals that stop a node: Ctrl-C and ``ros2 launch``'s first, docker's and systemd's
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: how long a node's spin loop waits at most for an event: its latency to a stop signal
SPIN_TIMEOUT = 0.1


@contextlib.contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    """
    Turn SIGINT and SIGTERM into a request that the spin loop reads between callbacks.

    rclpy's own handlers (``rclpy.init``'s default) do not do that: SIGINT raises
    KeyboardInterrupt inside whatever callback runs, which the events executor logs as a
    fatal error of that callback with its stack, and SIGTERM shuts the context down under a
    callback that may be publishing. Here the handler only notes the signal; the callback
    finishes, and the loop stops after it (within :data:`SPIN_TIMEOUT` when idle, since the
    executor waits in C++ and Python runs the handler when it returns). Call
    ``rclpy.init`` with ``SignalHandlerOptions.NO`` so that rclpy installs none of its own.

    A second signal acts as it would without this block (KeyboardInterrupt, or termination
    by SIGTERM): ``ros2 launch`` escalates from SIGINT to SIGTERM to SIGKILL when a node
    takes too long to stop, and a user's second Ctrl-C should not be swallowed. Installed
    whatever the inherited disposition: a node started by ``cmd &`` from a script has
    SIGINT ignored, and rclpy's handler took it in that case too. Main thread only (Python
    runs signal handlers there); elsewhere the block changes nothing.

    SIGHUP (a closed terminal, and the death of the node's supervisor:
    :func:`stop_with_supervisor`) is a stop request too, but every one only asks, for the
    whole block: the kernel may send the parent-death signal twice within microseconds,
    and the second must not kill the node while it saves.
    """
    request = StopRequest()
    old = {}
    kept = {}

    def restore():
        while old:
            sig, handler = old.popitem()
            signal.signal(sig, handler)

    def note(signum, frame):
        request.signum = signum
        restore()

    def note_hangup(signum, frame):
        if request.signum is None:
            request.signum = signum

    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            old[sig] = signal.signal(sig, note)
        kept[signal.SIGHUP] = signal.signal(signal.SIGHUP, note_hangup)
    try:
        yield request
    finally:
        restore()
        for sig, handler in kept.items():
            signal.signal(sig, handler)


PR_SET_PDEATHSIG = 1    # <linux/prctl.h>


def stop_with_supervisor(request: StopRequest) -> bool:
    """
    Have the kernel send this process SIGHUP when the supervisor that started it dies.

    A supervisor starts its nodes in sessions of their own, so a Ctrl-C reaches each once,
    and stops them on its way out; killed with SIGKILL (``kill -9``, the OOM killer, a
    test's timeout) it cannot. Without this its nodes would run on, a training graph on the
    ROS domain that the next run joins and hears, feeding its simulator foreign commands.
    SIGHUP is a stop request (:func:`stop_on_signals`): the node closes its bag and
    checkpoint and exits. Not SIGTERM: the kernel may send the signal more than once, and a
    second SIGTERM kills a node that is saving, as it should in ``ros2 launch``'s
    escalation (the incident and the trace: docs/results/PROFILE.md, "Measurements and
    incidents behind code choices").

    Only when ``PG_NODE_SUPERVISOR_PID`` names this process's parent (``prctl`` watches the
    parent): a node started by ``ros2 run`` or ``ros2 launch`` has no such variable, and one
    that inherited a stale one is left alone. A supervisor that died before this ran is
    noted in ``request`` as a SIGHUP. Linux only; elsewhere nothing changes. Return whether
    the node now stops with its supervisor.
    """
    named = os.environ.get(SUPERVISOR_ENV, '').strip()
    if not named.isdigit() or not sys.platform.startswith('linux'):
        return False
    supervisor = int(named)
    if os.getppid() != supervisor:
        try:
            os.kill(supervisor, 0)
        except ProcessLookupError:
            request.signum = signal.SIGHUP        # it died before we got here
        except PermissionError:
            pass
        return False
    import ctypes
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGHUP), 0, 0, 0) != 0:
        return False
    if os.getppid() != supervisor:                # it died between the two looks
        request.signum = signal.SIGHUP
    return True


def init_quietly(args=None) -> Optional[str]:
    """
    ``rclpy.init`` without rclpy's signal handlers; return the reason if rcl refuses.

    rcl's own log lines of a refusal (bad ``--params-file``, ROS arguments it cannot parse)
    are held back so that the caller can report one line; when init succeeds, whatever it
    wrote to stderr is passed on.
    """
    import tempfile
    with tempfile.TemporaryFile() as held:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(held.fileno(), 2)
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            error = None
        except _rclpy.RCLError as exc:
            error = exc
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if error is not None:
            # "failed to initialize rcl: <reason>[\n], at /src/file.c:line, ...": the reason
            reason = str(error).replace('failed to initialize rcl: ', '', 1)
            return reason.split(', at /')[0].split('\n')[0].strip()
        held.seek(0)
        text = held.read()
        if text:
            sys.stderr.buffer.write(text)
            sys.stderr.flush()
    return None


def params_help(name: str, table: Mapping, args=None) -> bool:
    """
    Print ``name``'s parameters if the command line asks ``--help``/``-h``; return whether.

    Asked before ``--ros-args`` (rclpy is not initialised: no graph is joined). ``table``:
    a map of parameter name to :class:`pg_node.common.param_schema.Param`.
    """
    argv = list(sys.argv if args is None else args)
    if '--ros-args' in argv:
        argv = argv[:argv.index('--ros-args')]
    if not {'-h', '--help'} & set(argv):
        return False
    print(f'usage: ros2 run pg_node {name} [--ros-args -p NAME:=VALUE ... '
          '| --params-file FILE]\n\nparameters (default; live: ros2 param set takes it while '
          'the node runs):')
    for key, param in table.items():
        live = ', live' if param.live else ''
        choices = f' One of: {", ".join(map(str, param.choices))}.' if param.choices else ''
        print(f'  {key} ({param.default!r}{live})')
        print(textwrap.fill(param.description + choices, 79, initial_indent=' ' * 6,
                            subsequent_indent=' ' * 6))
    return True


def run(make_node: Callable[[], Union[Node, List[Node]]], args=None,
        cleanup: Optional[Callable[[Union[Node, List[Node]]], None]] = None) -> int:
    """
    Init rclpy, spin the node until Ctrl-C / shutdown, clean up; return an exit code.

    ``make_node`` may return a list of nodes: they share the process and its executor
    (composition); ``cleanup`` gets what ``make_node`` returned.

    A node ends the process by setting its ``exit_code`` attribute (the learner, done):
    the loop stops after that callback, without an exception through the executor, which
    would log it as a fatal error of the callback. SIGINT and SIGTERM stop the loop the
    same way, between callbacks (:func:`stop_on_signals`), and the nodes are cleaned up.

    The node style of ``ros2/demos``' talker; a bad configuration is reported in one line
    (exit code 2) instead of a traceback, also a ``--params-file`` that is no valid YAML
    parameter file or ROS arguments that rcl cannot parse (:func:`init_quietly`).
    """
    reason = init_quietly(args)
    if reason is not None:
        print(f'configuration error: {reason}', file=sys.stderr)
        return 2
    node = None
    code = 0
    with stop_on_signals() as stop:
        stop_with_supervisor(stop)
        try:
            node = make_node()
            executor = make_executor()
            for each in _nodes(node):
                executor.add_node(each)
            for each in _nodes(node):
                _apply_cpu_params(each)       # after the executor: its threads exist now
            # the nodes that can end the process, looked up once: the loop runs per callback
            enders = [n for n in _nodes(node) if hasattr(n, 'exit_code')]
            while rclpy.ok() and not stop:
                # hand-overs inside the process (pg_node.ros.local_hop) first; while some
                # are left, the executor takes only what is ready, without waiting
                if local_hop.PENDING:
                    local_hop.deliver()
                executor.spin_once(timeout_sec=0.0 if local_hop.PENDING else SPIN_TIMEOUT)
                ended = next((n.exit_code for n in enders if n.exit_code is not None), None)
                if ended is not None:
                    code = ended
                    break
        except (KeyboardInterrupt, ExternalShutdownException):
            pass                              # a second signal, or a shutdown from elsewhere
        except ConfigError as exc:           # also a model that is no arm (NotAnArm)
            print(f'configuration error: {exc}', file=sys.stderr)
            code = 2
        except SystemExit as exc:
            code = int(exc.code or 0)
        finally:
            # still under stop_on_signals: a first signal now does not cut the saving short
            if node is not None:
                if cleanup is not None:
                    cleanup(node)
                for each in _nodes(node):
                    each.destroy_node()
            rclpy.try_shutdown()
    return code


def _nodes(node: Union[Node, List[Node]]) -> List[Node]:
    return node if isinstance(node, list) else [node]
