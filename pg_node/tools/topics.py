"""
``python -m pg_node topics``: the graph's topics, types, publishers, subscribers and rates.

For users without the ``ros2`` command line (``ros2 topic list -t``, ``ros2 topic info``,
``ros2 topic hz`` in one). It joins the graph (``ROS_DOMAIN_ID`` as usual) and waits for
discovery to settle (:func:`wait_for_discovery`: the graph's topic list unchanged for
``--settle`` seconds once it holds more than ``/parameter_events`` and ``/rosout``, at most
``--discovery`` seconds), then listens to every topic whose type is installed for
``--duration`` seconds more (topics found meanwhile are listened to from then on) with a
best-effort, volatile subscription (which matches any
publisher) taking the serialised bytes only, and prints one row per topic: type, number of
publishers and of subscribers (its own listener not counted), messages received and rate in
Hz (over the time between the first and the last message received). The table fits the
terminal (80 columns: each type goes under its topic) without cutting a name. ``--json``
prints the same as JSON.

Several training runs on one domain each have their topics under ``/<run_id>/``
(:mod:`pg_node.common.run`): the table's title names the runs found, and ``--run NAME``
lists (and listens to) only that run's topics and ``/diagnostics``, and waits for discovery
until a topic of that run has been seen (at most ``--discovery`` seconds).
"""
import argparse
import json
import sys
import time

from pg_node.common.run import run_label, run_namespace, run_of_topic
from pg_node.tools.args import non_negative_float, run_id_arg


def in_run(name: str, run) -> bool:
    """
    Return whether topic ``name`` is shown for ``run`` (None: every topic).

    >>> in_run('/exp1/pg_node/rollout', 'exp1'), in_run('/exp2/joint_states', 'exp1')
    (True, False)
    >>> in_run('/diagnostics', 'exp1'), in_run('/exp2/joint_states', None)
    (True, True)
    """
    return run is None or name == '/diagnostics' or name.startswith(
        run_namespace(run).rstrip('/') + '/')


def runs_in(names) -> list:
    """Return the run ids whose episode topic is among the topic ``names``, sorted."""
    return sorted({run for name in names for run in [run_of_topic(name, 'episode')]
                   if run is not None})


#: the topics of any node, this tool's own too: a graph of these only is not an answer yet
TRIVIAL_TOPICS = frozenset({'/parameter_events', '/rosout'})
DISCOVERY_MAX = 5.0
SETTLE = 1.0
POLL = 0.1


def wait_for_discovery(names, spin, settle=SETTLE, longest=DISCOVERY_MAX,
                       clock=time.monotonic, wanted=None) -> bool:
    """
    Spin until discovery settles; return whether it did (False: ``longest`` seconds passed).

    Settled: the topic names (``names()``, polled every :data:`POLL` s between calls of
    ``spin(seconds)``) have not changed for ``settle`` seconds and hold a topic besides
    :data:`TRIVIAL_TOPICS` (and, given ``wanted(name)``, a topic it accepts). On a loaded
    machine the first answers list only those two, and the nodes' topics come later, one
    node (one DDS participant) at a time, sometimes more than ``settle`` seconds apart: each
    change starts the wait again, and ``wanted`` keeps it going until the topics asked for
    (one run's, see :func:`survey`) have come, however long the others came before them.
    """
    start = clock()
    seen, since = None, start
    while True:
        now = clock()
        current = frozenset(names())
        if current != seen:
            seen, since = current, now
        elif (seen - TRIVIAL_TOPICS and (wanted is None or any(map(wanted, seen)))
              and now - since >= settle):
            return True
        if now - start >= longest:
            return False
        spin(POLL)


def survey(discovery=DISCOVERY_MAX, duration=2.0, include_hidden=False, context=None,
           run=None, settle=SETTLE):
    """
    Return one dict per topic: name, types, publishers, subscribers, count, rate_hz.

    Waits for discovery to settle first (:func:`wait_for_discovery`, ``settle`` seconds of
    no change, at most ``discovery`` seconds), then measures for ``duration`` seconds.
    ``run``: only that run's topics and ``/diagnostics`` (:func:`in_run`).
    """
    from pg_node.bag import ros_types
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(context=context)
    node = rclpy.create_node('pg_node_topics', context=context,
                             start_parameter_services=False)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    times, listening, topics = {}, set(), {}
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT,
                     durability=DurabilityPolicy.VOLATILE)

    def refresh():
        graph = node.get_topic_names_and_types()
        for name, types in graph:
            if name in topics or not in_run(name, run) or (not include_hidden and any(
                    part.startswith('_') for part in name.split('/'))):
                continue
            topics[name] = types
            times[name] = []
            cls = ros_types.message_class(types[0]) if len(types) == 1 else None
            if cls is None:
                continue

            def on_message(data, stamps=times[name]):
                stamps.append(time.monotonic())
            node.create_subscription(cls, name, on_message, qos, raw=True)
            listening.add(name)
        return [name for name, _ in graph]

    def spin(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=max(0.0, min(0.05, end - time.monotonic())))

    try:
        # what is found is listened to from then on, while discovery settles too; one run's
        # listing waits for a topic of that run, not only for /diagnostics (any run's)
        wanted = None if run is None else (
            lambda name: name != '/diagnostics' and in_run(name, run))
        wait_for_discovery(refresh, spin, settle, discovery, wanted=wanted)
        # discovery goes on while we listen: a topic found late is measured for less time
        end = time.monotonic() + duration
        next_refresh = 0.0
        while time.monotonic() < end:
            if time.monotonic() >= next_refresh:
                refresh()
                next_refresh = time.monotonic() + 0.25
            executor.spin_once(timeout_sec=0.05)
        rows = []
        for name, types in sorted(topics.items()):
            stamps = times[name]
            if name not in listening:
                rate = None
            elif len(stamps) >= 2 and stamps[-1] > stamps[0]:
                rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
            else:
                rate = 0.0
            subs = node.count_subscribers(name) - (1 if name in listening else 0)
            rows.append({'name': name, 'types': list(types),
                         'publishers': node.count_publishers(name), 'subscribers': subs,
                         'count': len(stamps) if name in listening else None,
                         'rate_hz': rate})
        return rows
    finally:
        node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)


def title(rows, run=None) -> str:
    """Return the table's title: the run shown, or the runs found."""
    if run is not None:
        return f'ROS 2 topics of run {run_label(run)}'
    runs = runs_in(r['name'] for r in rows)
    if len(runs) > 1:
        return f'ROS 2 topics (runs: {", ".join(map(run_label, runs))}; --run NAME shows one)'
    return 'ROS 2 topics' + (f' (run {run_label(runs[0])})' if runs else '')


def table(rows, width: int = 80, caption: str = 'ROS 2 topics'):
    """
    Return a rich Table of :func:`survey` rows that fits ``width`` columns without cutting.

    Topic and type share a column when one row each would not fit (the type on a second,
    indented line), and the rate is given in Hz in its header only.
    """
    from rich import box
    from rich.table import Table
    cells = []
    for r in rows:
        rate = '-' if r['rate_hz'] is None else f'{r["rate_hz"]:.1f}'
        types = ', '.join(r['types']) + ('' if r['count'] is not None else ' (not installed)')
        count = '-' if r['count'] is None else str(r['count'])
        cells.append((r['name'], types, str(r['publishers']), str(r['subscribers']), count,
                      rate))
    numbers = ('pub', 'sub', 'msgs', 'Hz')
    widths = [max([len(h)] + [len(c[i + 2]) for c in cells]) for i, h in enumerate(numbers)]
    name_w = max([5] + [len(c[0]) for c in cells])
    type_w = max([4] + [len(c[1]) for c in cells])
    # SIMPLE box: no vertical lines, one space of padding each side of a cell
    one_line = name_w + type_w + sum(widths) + 2 * (2 + len(numbers))
    stacked = one_line > width
    out = Table(title=caption, header_style='bold', box=box.SIMPLE, pad_edge=False)
    if stacked:
        out.add_column('topic\n  type', no_wrap=True)
    else:
        out.add_column('topic', no_wrap=True)
        out.add_column('type', no_wrap=True)
    for h in numbers:
        out.add_column(h, justify='right', no_wrap=True)
    for c in cells:
        head = (f'{c[0]}\n  {c[1]}',) if stacked else c[:2]
        out.add_row(*head, *c[2:])
    return out


def main(argv=None) -> int:
    """List the topics; return the exit status."""
    parser = argparse.ArgumentParser(prog='python -m pg_node topics',
                                     description='Topics with types, endpoints and rates.')
    parser.add_argument('--duration', type=float, default=2.0,
                        help='seconds to measure rates over')
    parser.add_argument('--discovery', type=non_negative_float, default=DISCOVERY_MAX,
                        help='at most this many seconds to wait for discovery first; the '
                             'wait ends once the topic list (more than /parameter_events and '
                             '/rosout) has not changed for --settle seconds (default: '
                             '%(default)s)')
    parser.add_argument('--settle', type=non_negative_float, default=SETTLE,
                        help='seconds without a new or gone topic that end the wait for '
                             'discovery (default: %(default)s)')
    parser.add_argument('--include-hidden', action='store_true')
    parser.add_argument('--json', action='store_true', help='print JSON')
    parser.add_argument('--run', type=run_id_arg,
                        help="only this run's topics (and /diagnostics); waits for discovery "
                             'until one of them is seen')
    args = parser.parse_args(argv)
    try:
        rows = survey(args.discovery, args.duration, args.include_hidden, run=args.run,
                      settle=args.settle)
    except KeyboardInterrupt:
        return 130
    if args.run is not None and not any(r['name'] != '/diagnostics' for r in rows):
        print(f'topics: no topic of run {run_label(args.run)} found in {args.discovery:g} s '
              '(is it on this ROS_DOMAIN_ID?)', file=sys.stderr)
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        from rich.console import Console
        console = Console()
        console.print(table(rows, console.width, title(rows, args.run)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
