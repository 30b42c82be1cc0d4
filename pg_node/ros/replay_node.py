"""
replay_node: play a rosbag2 MCAP bag back onto its topics, as ``ros2 bag play`` does.

Run it as ``ros2 run pg_node replay_node --ros-args -p bag:=<dir or .mcap>`` or as
``python -m pg_node replay <bag> [--rate 4] [--loop] ...``; both forms take the same
options (``--help`` lists them) and any mix of the two, command-line options winning over
``-p`` parameters. It plays any rosbag2 MCAP bag whose message types are installed, not only
pg_node's: messages are read by :class:`pg_node.bag.reader.BagReader` and published as the
CDR bytes the bag holds, so nothing is deserialised on the way.

Timing: message ``m`` is published when ``(log_time(m) - log_time(first)) / rate`` of wall
time has passed since the first; ``rate`` 0 (or ``inf``) plays as fast as possible.
``start_offset`` skips that many seconds of the bag. ``loop`` starts over at the end.

QoS: each topic is published with the QoS its recorder offered (``offered_qos_profiles``):
if all its publishers offered the same profile, that one; otherwise the most permissive
(best effort if any was, volatile if any was, the largest depth). ``keep_all`` publishes
with keep-all history instead, so that a fast replay into a reliable keep-all subscriber
loses nothing.

Clock (parameter ``clock``): ``auto`` (default) replays a recorded ``/clock`` topic as it
is (pg_node's bags hold simulated time there) and otherwise publishes ``/clock`` from the
recorded log times at ``clock_rate`` Hz of bag time; ``log_time`` always does the latter
(and skips a recorded ``/clock``); ``off`` publishes no clock of its own.

Subscribers: before the first message the node waits up to ``wait_timeout`` s (default 3)
until every played topic has ``wait_for_subscribers`` matched subscribers (default 1; 0
does not wait). A subscriber that is already running is not matched at once: DDS discovery
takes a moment, and a fast replay that started without waiting could be over before it,
delivering nothing. Topics still without a subscriber are named in a warning. The wait
sees only the replay's side of each match (the subscriber may match the replay a moment
later and miss what came before): a subscriber that needs every message resumes a
``start_paused`` replay with ``~/set_pause`` once it has matched.

At the end the node waits up to ``wait_acked_timeout`` s until reliable subscribers have
acknowledged every message (a fast replay is otherwise over before they have read it), and
reports per topic what it published and what it knows of the delivery: no subscriber
(reached nobody), acknowledged by every reliable subscriber (with keep-all history: every
message; keep-last: a subscriber slower than the replay may have missed older ones), not
acknowledged in time, or best effort (not confirmed).

Topics: ``topics`` limits playback to those names; ``remap`` takes ``from:=to`` pairs.
Command topics (a name ending in ``/commands``: ``/pg_node/commands`` in pg_node's bags,
``/arm_controller/commands`` in older ones, what a ros2_control controller takes; or in
``/joint_trajectory``, a joint trajectory controller's, ``policy_node``'s default) are left
out, with a warning, unless ``commands`` is true or ``topics`` names them: a bag played on a
network with a real arm must not drive it.
Topics whose type is not installed, or whose messages are not CDR, are skipped and listed
in a warning at start.

Damage: a truncated or corrupted file plays up to the damage; the node then logs the file,
the byte offset and the reason, and the log time of the last message played, and exits
with status 3 (0 when the bag played to its end, 1 when there is no bag or nothing could be
played, 2 for a bad option or parameter: the codes docs/troubleshooting.md lists).
``--info`` reads every file to its end too, names a damaged one and exits with 3.

Services (``std_srvs``; rosbag2's own player uses ``rosbag2_interfaces``, which pg_node
does not depend on): ``~/set_pause`` (``SetBool``: true pauses, false resumes; the same
name as sim_node's and mujoco_ros2_control's), ``~/toggle_paused`` (``Trigger``) and
``~/play_next`` (``Trigger``: while paused, publish the next message only).

``main(args)`` takes the arguments without the program name: ``python -m pg_node replay``
passes its own list, the ``replay_node`` console script passes ``sys.argv[1:]``. ROS
arguments (after ``--ros-args``) go to ``rclpy.init``, the rest to argparse, so one parser
serves both ways of starting the node.
"""
import argparse
import difflib
import math
import sys
import threading
import time

from pg_node.bag import ros_types
from pg_node.bag.reader import BagReader, NOT_MCAP
from pg_node.common.run_dir import RunDir
from pg_node.ros import runtime
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
import rclpy
from rclpy.exceptions import InvalidParameterTypeException, ParameterUninitializedException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_srvs.srv import SetBool, Trigger

#: the exit statuses docs/troubleshooting.md lists: played to the end (--info: every file
#: whole); no bag there or nothing played; a bad option or parameter; a damaged file (played
#: up to the damage; --info: named)
EXIT_OK, EXIT_NOTHING, EXIT_USAGE, EXIT_DAMAGED = 0, 1, 2, 3

#: (name, default, ROS parameter type, description)
PARAMETERS = (
    ('bag', '', ParameterType.PARAMETER_STRING, 'rosbag2 directory or .mcap file to play'),
    ('rate', 1.0, ParameterType.PARAMETER_DOUBLE,
     'playback speed factor; 0 or inf: as fast as possible'),
    ('start_offset', 0.0, ParameterType.PARAMETER_DOUBLE,
     'seconds of the bag to skip at the start'),
    ('topics', [], ParameterType.PARAMETER_STRING_ARRAY,
     'topics to play (empty: all)'),
    ('remap', [], ParameterType.PARAMETER_STRING_ARRAY,
     'topic remappings, each "from:=to"'),
    ('commands', False, ParameterType.PARAMETER_BOOL,
     'also play command topics (names ending in /commands or /joint_trajectory), which a '
     'controller would obey'),
    ('loop', False, ParameterType.PARAMETER_BOOL, 'start over at the end of the bag'),
    ('clock', 'auto', ParameterType.PARAMETER_STRING,
     'auto: replay a recorded /clock, else publish log time; log_time; off'),
    ('clock_rate', 40.0, ParameterType.PARAMETER_DOUBLE,
     'Hz of bag time at which /clock is published from log time'),
    ('start_paused', False, ParameterType.PARAMETER_BOOL, 'start paused (see ~/set_pause)'),
    ('keep_all', False, ParameterType.PARAMETER_BOOL,
     'publish with keep-all history, so that a fast replay drops nothing'),
    ('wait_for_subscribers', 1, ParameterType.PARAMETER_INTEGER,
     'before playing, wait until every topic has this many matched subscribers (0: no wait)'),
    ('wait_timeout', 3.0, ParameterType.PARAMETER_DOUBLE,
     'seconds to wait for subscribers at most'),
    ('delay', 0.0, ParameterType.PARAMETER_DOUBLE, 'seconds to sleep before playing'),
    ('wait_acked_timeout', 10.0, ParameterType.PARAMETER_DOUBLE,
     'at the end, seconds to wait for reliable subscribers to acknowledge every message'),
)


def merge_qos(profiles):
    """
    Return one rosbag2 QoS dict for a topic recorded from these offered profiles.

    All equal: that one. Otherwise the one that every subscriber can match: best effort if
    any publisher was, volatile if any was, the largest depth (rosbag2's adaptation).
    """
    if not profiles:
        return ros_types.qos_to_dict(None)
    if all(p == profiles[0] for p in profiles):
        return dict(profiles[0])
    out = dict(profiles[0])
    if any(p['reliability'] == 'best_effort' for p in profiles):
        out['reliability'] = 'best_effort'
    if any(p['durability'] == 'volatile' for p in profiles):
        out['durability'] = 'volatile'
    out['depth'] = max(p['depth'] for p in profiles)
    return out


#: what each parameter type takes, in the words of an error
_KIND = {ParameterType.PARAMETER_STRING: 'a string', ParameterType.PARAMETER_DOUBLE: 'a number',
         ParameterType.PARAMETER_BOOL: 'true or false',
         ParameterType.PARAMETER_INTEGER: 'an integer'}
#: parameters every rclpy node may be given
ROS_KEYS = ('use_sim_time', 'start_type_description_service')


def parse_remaps(items):
    """
    Turn ``['/a:=/b', ...]`` into ``{'/a': '/b'}``; raise ValueError on a malformed item.

    >>> parse_remaps(['/joint_states:=/replay/joint_states', ''])
    {'/joint_states': '/replay/joint_states'}
    """
    out = {}
    for item in items:
        if not item:
            continue
        src, sep, dst = item.partition(':=')
        if not sep or not src or not dst:
            raise ValueError(f'remap {item!r} is not of the form from:=to')
        out[src.strip()] = dst.strip()
    return out


class ReplayNode(Node):
    """Publish a bag's messages with their timing and QoS; see the module docstring."""

    def __init__(self, **kwargs):
        """Declare the parameters, open the bag and create one publisher per played topic."""
        super().__init__('replay_node', **kwargs)
        given = getattr(self, '_parameter_overrides', {})
        names = [name for name, *_ in PARAMETERS]
        for name in sorted(given):
            # as the other nodes do (pg_node.ros.parameters): a typo is refused, not ignored
            if name not in names and name not in ROS_KEYS and not name.startswith('qos_'):
                close = difflib.get_close_matches(name, names, n=1)
                hint = f' (did you mean {close[0]!r}?)' if close else ''
                raise ValueError(f"unknown parameter 'replay_node.{name}'{hint}; allowed: "
                                 f'{", ".join(names)}')
        p = {}
        for name, default, ptype, text in PARAMETERS:
            descriptor = ParameterDescriptor(type=ptype, description=text)
            if ptype == ParameterType.PARAMETER_STRING_ARRAY:
                # rclpy types an empty list default as a byte array: declare the type only
                try:
                    self.declare_parameter(name, Parameter.Type.STRING_ARRAY, descriptor)
                    p[name] = list(self.get_parameter(name).value)
                except ParameterUninitializedException:
                    p[name] = list(default)
                except InvalidParameterTypeException:
                    raise ValueError(f'parameter {name!r}: {given[name].value!r} is not allowed; '
                                     'expected a list of strings') from None
                continue
            try:
                self.declare_parameter(name, default, descriptor)
            except InvalidParameterTypeException:
                # an integer for a double (rate:=2), as the other nodes take it; anything
                # else is refused in one line saying what the parameter takes
                value = given[name].value
                if (ptype == ParameterType.PARAMETER_DOUBLE and isinstance(value, int)
                        and not isinstance(value, bool)):
                    self.declare_parameter(name, float(value), descriptor,
                                           ignore_override=True)
                else:
                    raise ValueError(f'parameter {name!r}: {value!r} is not allowed; expected '
                                     f'{_KIND[ptype]}') from None
            p[name] = self.get_parameter(name).value
        self.params = p
        if not p['bag']:
            raise ValueError('no bag given (parameter bag, or the first argument)')
        self.rate = float(p['rate'])
        if not self.rate >= 0:
            raise ValueError(f'rate must be >= 0 (0: as fast as possible), not {self.rate:g}')
        self.as_fast_as_possible = self.rate <= 0 or math.isinf(self.rate)
        self.reader = BagReader(p['bag'], warn=False)
        self.remap = parse_remaps(p['remap'])
        wanted = [t for t in p['topics'] if t]
        topics = self.reader.topics
        unknown_wanted = [t for t in wanted if t not in topics]
        if unknown_wanted:
            self.get_logger().warning(f'not in the bag: {", ".join(unknown_wanted)}')
        clock_mode = p['clock']
        if clock_mode not in ('auto', 'log_time', 'off'):
            raise ValueError(f'clock must be auto, log_time or off, not {clock_mode!r}')
        recorded_clock = ('/clock' in topics and (not wanted or '/clock' in wanted)
                          and topics['/clock'].msg_type == 'rosgraph_msgs/msg/Clock')
        self.generate_clock = clock_mode == 'log_time' or (
            clock_mode == 'auto' and not recorded_clock)
        self.skipped = {}
        self.publishers_ = {}
        for name, info in topics.items():
            if wanted and name not in wanted:
                continue
            if is_command_topic(name) and not (p['commands'] or name in wanted):
                self.skipped[name] = ('a command topic, which a controller would obey '
                                      '(--commands, or naming it in --topics, plays it)')
                continue
            if name == '/clock' and clock_mode == 'log_time':
                self.skipped[name] = 'a recorded /clock (clock:=log_time publishes its own)'
                continue
            if info.serialization_format != 'cdr':
                self.skipped[name] = f'{info.serialization_format} messages, not cdr'
                continue
            cls = ros_types.message_class(info.msg_type)
            if cls is None:
                self.skipped[name] = f'type {info.msg_type} is not installed'
                continue
            qos = ros_types.qos_profile(merge_qos(info.offered_qos_profiles))
            if p['keep_all']:
                qos.history = HistoryPolicy.KEEP_ALL
            self.publishers_[name] = self.create_publisher(
                cls, self.remap.get(name, name), qos)
        for name, why in self.skipped.items():
            self.get_logger().warning(f'skipping {name}: {why}')
        self.clock_pub = None
        if self.generate_clock:
            self.clock_pub = self.create_publisher(Clock, self.remap.get('/clock', '/clock'),
                                                   10)
        self._cond = threading.Condition()
        self.paused = bool(p['start_paused'])
        self._rebase = False
        self._next = 0
        self.stopping = False
        self.done = threading.Event()
        self.played = 0
        self.published = dict.fromkeys(self.publishers_, 0)
        self.subscribers_at_first = {}
        self.unacked = set()
        self.passes = 0
        self.last_log_time = None
        self.damage = []
        self.error = None
        self.create_service(SetBool, '~/set_pause', self.on_set_pause)
        self.create_service(Trigger, '~/toggle_paused', self.on_toggle_paused)
        self.create_service(Trigger, '~/play_next', self.on_play_next)
        n_msgs = sum(topics[t].message_count for t in self.publishers_)
        speed = 'as fast as possible' if self.as_fast_as_possible else f'at rate {self.rate:g}'
        self.get_logger().info(
            f'playing {self.reader.path}: {len(self.publishers_)} topics, {n_msgs} messages, '
            f'{speed}' + (', looping' if p['loop'] else '') + (
                ', paused' if self.paused else ''))
        self._thread = threading.Thread(target=self._run, name='replay', daemon=True)

    # -- services --------------------------------------------------------------------------
    def _set_paused(self, paused: bool):
        with self._cond:
            if self.paused and not paused:
                self._rebase = True
            self.paused = paused
            self._cond.notify_all()

    def on_set_pause(self, request, response):
        """Pause (data true) or resume (data false)."""
        self._set_paused(bool(request.data))
        response.success = True
        response.message = 'paused' if self.paused else 'playing'
        return response

    def on_toggle_paused(self, request, response):
        """Pause if playing, resume if paused."""
        self._set_paused(not self.paused)
        response.success = True
        response.message = 'paused' if self.paused else 'playing'
        return response

    def on_play_next(self, request, response):
        """While paused, publish the next message."""
        with self._cond:
            if not self.paused:
                response.success = False
                response.message = 'not paused'
                return response
            self._next += 1
            self._cond.notify_all()
        response.success = True
        response.message = 'next message queued'
        return response

    # -- playback --------------------------------------------------------------------------
    def start(self):
        """Start the playback thread."""
        self._thread.start()

    def stop(self):
        """Ask the playback thread to end, and wait for it."""
        with self._cond:
            self.stopping = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(5.0)

    def _run(self):
        try:
            self._wait_for_subscribers()
            if self.params['delay'] > 0:
                with self._cond:
                    self._cond.wait_for(lambda: self.stopping, self.params['delay'])
            while not self.stopping:
                self._play_once()
                self.passes += 1
                if not self.params['loop'] or self.damage or not self.played:
                    break
            self._wait_acked()
        except Exception as exc:  # noqa: B902 - report any failure, never die silently
            self.error = exc
            self.get_logger().error(f'playback failed: {exc!r}')
        finally:
            self.done.set()

    def _wait_acked(self):
        """Let reliable subscribers fetch what is still only in our history (at exit)."""
        from rclpy.duration import Duration
        deadline = time.monotonic() + max(0.0, float(self.params['wait_acked_timeout']))
        late = []
        for name, pub in self.publishers_.items():
            left = deadline - time.monotonic()
            if self.stopping or not pub.wait_for_all_acked(Duration(seconds=max(0.0, left))):
                late.append(name)
        self.unacked = set(late)
        if late and not self.stopping:
            self.get_logger().warning(f'not acknowledged by every subscriber in time: '
                                      f'{", ".join(late)}')

    def _wait_for_subscribers(self):
        need = int(self.params['wait_for_subscribers'])
        if need <= 0:
            return
        deadline = time.monotonic() + float(self.params['wait_timeout'])
        while not self.stopping and time.monotonic() < deadline:
            if all(pub.get_subscription_count() >= need
                   for pub in self.publishers_.values()):
                return
            time.sleep(0.02)
        missing = [n for n, pub in self.publishers_.items()
                   if pub.get_subscription_count() < need]
        if missing and len(missing) == len(self.publishers_):
            self.get_logger().warning(
                f'no topic has {need} matched subscriber(s) after {self.params["wait_timeout"]:g} '
                f's; playing anyway (what nobody subscribes to reaches nobody)')
        elif missing:
            self.get_logger().warning(f'playing although these topics have fewer than {need} '
                                      f'subscribers: {", ".join(missing)}')

    def _wait_until(self, log_time):
        """Sleep until ``log_time`` is due (or until stopping); honour pause and play_next."""
        with self._cond:
            while not self.stopping:
                if self.paused:
                    if self._next > 0:
                        self._next -= 1
                        self._rebase = True
                        return True
                    self._cond.wait(0.2)
                    continue
                if self._rebase or self._r0 is None:
                    # (re)start the wall clock: keep the gap since the last message played
                    self._rebase = False
                    self._r0 = time.monotonic()
                    last = self.last_log_time
                    self._b0 = log_time if last is None or last > log_time else last
                if self.as_fast_as_possible:
                    return True
                due = self._r0 + (log_time - self._b0) / self.rate / 1e9
                delay = due - time.monotonic()
                if delay <= 0:
                    return True
                self._cond.wait(min(delay, 0.2))
        return False

    def _play_once(self):
        reader = self.reader
        reader.problems = [d for d in reader.problems if 'missing' in d.reason]
        offset_ns = int(round(float(self.params['start_offset']) * 1e9))
        first = None
        self._r0, self._b0 = None, None
        self.last_log_time = None
        last_clock = None
        clock_period = 1e9 / max(float(self.params['clock_rate']), 1e-9)
        topics = list(self.publishers_)
        for m in reader.messages(topics=topics):
            if first is None:
                first = m.log_time_ns
            if m.log_time_ns < first + offset_ns:
                continue
            if not self._wait_until(m.log_time_ns):
                return
            if self.clock_pub is not None and (
                    last_clock is None or m.log_time_ns - last_clock >= clock_period):
                last_clock = m.log_time_ns
                t = m.log_time_ns
                clock = Clock()
                clock.clock.sec, clock.clock.nanosec = t // 10**9, t % 10**9
                self.clock_pub.publish(clock)
            data = m.data if isinstance(m.data, bytes) else bytes(m.data)
            pub = self.publishers_[m.topic]
            if m.topic not in self.subscribers_at_first:
                self.subscribers_at_first[m.topic] = pub.get_subscription_count()
            pub.publish(data)
            self.played += 1
            self.published[m.topic] += 1
            self.last_log_time = m.log_time_ns
        self.damage = list(reader.problems)
        for d in self.damage:
            where = ('no message played' if self.last_log_time is None else
                     f'last message played at log time {self.last_log_time} ns')
            self.get_logger().error(f'bag damaged, playback stopped early: {d} ({where})')
        if reader.decode_errors:
            self.get_logger().warning(f'undecodable messages: {reader.decode_errors}')

    def delivery(self):
        """
        Return ``{topic: (published, subscribers, status)}`` of what was played.

        ``status``: ``no subscriber`` (none matched at the topic's first message nor at the
        end: nothing reached anyone), ``delivered`` (reliable keep-all, acknowledged),
        ``acknowledged`` (reliable keep-last: the newest messages were; a subscriber slower
        than the replay may have missed older ones), ``not acknowledged`` (reliable, not in
        time) or ``best effort`` (delivery not confirmed by DDS).
        """
        out = {}
        for name, pub in self.publishers_.items():
            n = self.published.get(name, 0)
            subs = pub.get_subscription_count()
            first = self.subscribers_at_first.get(name, subs)
            qos = pub.qos_profile
            if max(subs, first) == 0:
                status = 'no subscriber'
            elif qos.reliability != ReliabilityPolicy.RELIABLE:
                status = 'best effort'
            elif name in self.unacked:
                status = 'not acknowledged'
            elif qos.history == HistoryPolicy.KEEP_ALL and first > 0:
                status = 'delivered'
            else:
                status = 'acknowledged'
            out[name] = (n, subs, status)
        return out

    def report(self):
        """Log what was published per topic and what is known of its delivery."""
        log = self.get_logger()
        rows = self.delivery()
        nobody = sorted(t for t, (_, _, st) in rows.items() if st == 'no subscriber')
        log.info(f'published {self.played} messages on {len(rows)} topics; '
                 f'{len(rows) - len(nobody)} had subscribers, {len(nobody)} none')
        for name, (n, subs, status) in sorted(rows.items()):
            log.info(f'  {name}: {n} published, {subs} subscriber(s), {status}')
        if nobody:
            lost = sum(rows[t][0] for t in nobody)
            log.warning(f'no subscriber on {len(nobody)} topic(s) (listed above): {lost} '
                        f'messages reached nobody')


def split_ros_args(argv):
    """
    Split ``argv`` into ``(plain, ros)``: ROS arguments are ``--ros-args ... [--]`` blocks.

    >>> split_ros_args(['bag', '--rate', '2', '--ros-args', '-p', 'loop:=true', '--', '-l'])
    (['bag', '--rate', '2', '-l'], ['--ros-args', '-p', 'loop:=true', '--'])
    """
    plain, ros, inside = [], [], False
    for arg in argv:
        if arg == '--ros-args':
            inside = True
        if inside:
            ros.append(arg)
            if arg == '--':
                inside = False
        else:
            plain.append(arg)
    return plain, ros


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float('nan')
    if not value >= 0:
        raise argparse.ArgumentTypeError(f'expected a number >= 0 (0: as fast as possible), '
                                         f'got {text!r}')
    return value


def resolve_bag(path: str) -> str:
    """Return the bag of ``path``: its ``bag/`` when it is a run directory, else ``path``."""
    run = RunDir(path)
    return str(run.bag) if run.has_bag() else path


def bags_of(path: str) -> list:
    """Return the bags ``path`` names: a run directory's (``bag``, ``bag_1``, ...), or itself."""
    run = RunDir(path)
    return [str(b) for b in run.bags()] if run.has_bag() else [path]


def is_command_topic(name: str) -> bool:
    """
    Return whether a topic carries commands a controller would act on.

    A forward command controller's ``commands``, or a joint trajectory controller's
    ``joint_trajectory`` (what ``policy_node`` sends by default).

    >>> is_command_topic('/pg_node/commands'), is_command_topic('/arm_controller/commands')
    (True, True)
    >>> is_command_topic('/arm_controller/joint_trajectory'), is_command_topic('/joint_states')
    (True, False)
    """
    return name.rstrip('/').rsplit('/', 1)[-1] in ('commands', 'joint_trajectory')


def build_parser() -> argparse.ArgumentParser:
    """Return the argparse parser of ``python -m pg_node replay``."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node replay',
        description='Play a rosbag2 MCAP bag back onto its topics (like ros2 bag play). '
                    'Options override -p parameters given after --ros-args.')
    parser.add_argument('bag', nargs='?',
                        help='bag directory, .mcap file, or run directory (with bag/)')
    parser.add_argument('--rate', '-r', type=_non_negative,
                        help='speed factor; 0: as fast as possible')
    parser.add_argument('--start-offset', type=float, help='seconds of the bag to skip')
    parser.add_argument('--topics', nargs='+', help='play only these topics')
    parser.add_argument('--remap', nargs='+', metavar='FROM:=TO', help='rename topics')
    parser.add_argument('--commands', action='store_true', default=None,
                        help='also play command topics (left out by default: a controller '
                             'on the network would obey them)')
    parser.add_argument('--loop', '-l', action='store_true', default=None)
    parser.add_argument('--clock', choices=('auto', 'log_time', 'off'))
    parser.add_argument('--clock-rate', type=float, help='Hz of bag time (log_time clock)')
    parser.add_argument('--start-paused', action='store_true', default=None)
    parser.add_argument('--keep-all', action='store_true', default=None,
                        help='keep-all history: a fast replay drops nothing')
    parser.add_argument('--wait-for-subscribers', type=int, metavar='N',
                        help='before playing, wait until every topic has N matched '
                             'subscribers (default 1; 0: do not wait)')
    parser.add_argument('--wait-timeout', type=float, metavar='SECONDS',
                        help='wait that long for subscribers at most (default 3)')
    parser.add_argument('--delay', type=float, help='seconds to sleep before playing')
    parser.add_argument('--wait-acked-timeout', type=float,
                        help='seconds to wait at the end for acknowledgements (default 10)')
    parser.add_argument('--info', action='store_true',
                        help="print the bag's topics (type, count, QoS) and exit")
    return parser


def print_info(path) -> int:
    """
    Print what ``ros2 bag info`` would, in short, and the damage; return the exit status.

    A run directory stands for all its bags (``bag``, ``bag_1`` after a resume or a learner
    restart). Every file is read to its end: a damaged one is named, with where and why it
    stops, and the status is :data:`EXIT_DAMAGED`.
    """
    status = EXIT_OK
    for bag in bags_of(path):
        try:
            reader = BagReader(bag, warn=False)
        except (ValueError, OSError) as exc:
            print(f'replay: {exc}', file=sys.stderr)
            return EXIT_NOTHING
        topics = reader.topics
        width = max((len(n) for n in topics), default=5)
        print(f'bag: {reader.path}  files: {len(reader.files)}')
        for name, info in sorted(topics.items()):
            qos = merge_qos(info.offered_qos_profiles)
            installed = ros_types.message_class(info.msg_type) is not None
            print(f'  {name:<{width}}  {info.msg_type:<40} {info.message_count:>8}  '
                  f'{qos["reliability"]}/{qos["durability"]}/depth {qos["depth"]}'
                  + ('' if installed else '  (type not installed)'))
        for f in reader.left_out:
            print(f'  not read: {f} (not listed in metadata.yaml, not an MCAP file)')
        damage = reader.check_files()
        for d in damage:
            print(f'  damaged: {d}')
        if any(d.reason != NOT_MCAP for d in damage):
            counted = ' (the counts above are what metadata.yaml says)' if (
                reader.metadata is not None and reader.metadata.get(
                    'topics_with_message_count')) else ''
            print(f'  {len(damage)} damaged file(s){counted}; python -m pg_node reindex '
                  f'{reader.path} keeps what is before the damage and makes the bag whole')
        if damage:
            status = EXIT_DAMAGED
    return status


def main(args=None) -> int:
    """Start the node (see the module docstring for ``args``); return the exit status."""
    argv = list(sys.argv[1:] if args is None else args)
    plain, ros = split_ros_args(argv)
    try:
        opts = build_parser().parse_args(plain)
    except SystemExit as exc:
        return int(exc.code or 0)
    if opts.info:
        if not opts.bag:
            print('--info needs a bag', file=sys.stderr)
            return EXIT_USAGE
        return print_info(opts.bag)
    if opts.bag:
        bags = bags_of(opts.bag)
        if len(bags) > 1:       # a resumed run, or one whose learner restarted
            print(f'replay: {opts.bag} holds {len(bags)} bags ({", ".join(bags)}); playing '
                  f'the first, give another to play it', file=sys.stderr)
        opts.bag = resolve_bag(opts.bag)
    values = {'bag': opts.bag, 'rate': opts.rate, 'start_offset': opts.start_offset,
              'topics': opts.topics, 'remap': opts.remap, 'commands': opts.commands,
              'loop': opts.loop,
              'clock': opts.clock, 'clock_rate': opts.clock_rate,
              'start_paused': opts.start_paused, 'keep_all': opts.keep_all,
              'wait_for_subscribers': opts.wait_for_subscribers,
              'wait_timeout': opts.wait_timeout, 'delay': opts.delay,
              'wait_acked_timeout': opts.wait_acked_timeout}
    overrides = [Parameter(k, value=v) for k, v in values.items() if v is not None]
    reason = runtime.init_quietly(['replay_node'] + ros)
    if reason is not None:
        print(f'replay_node: {reason}', file=sys.stderr)
        return EXIT_NOTHING
    node = None
    status = EXIT_OK
    with runtime.stop_on_signals() as stop:
        runtime.stop_with_supervisor(stop)
        try:
            try:
                node = ReplayNode(parameter_overrides=overrides)
            except OSError as exc:          # no bag there, no .mcap file in it
                print(f'replay_node: {exc}', file=sys.stderr)
                return EXIT_NOTHING
            except ValueError as exc:       # a parameter it does not take
                print(f'replay_node: {exc}', file=sys.stderr)
                return EXIT_USAGE
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            node.start()
            while rclpy.ok() and not node.done.is_set() and not stop:
                executor.spin_once(timeout_sec=runtime.SPIN_TIMEOUT)
            node.report()
            if node.damage:
                status = EXIT_DAMAGED
            elif node.error is not None or not node.played:
                status = EXIT_NOTHING
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            if node is not None:
                node.stop()
                node.destroy_node()
            rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    sys.exit(main())
