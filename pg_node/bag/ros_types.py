"""
ROS 2 message types and QoS profiles as rosbag2 stores them.

Helpers shared by the bag writer and reader: turning a message class or a type name into
the canonical ``pkg/msg/Type`` string, finding the message class, building the full
``ros2msg`` definition text that rosbag2_storage_mcap puts in an MCAP schema, finding the
``RIHS01_...`` type description hash, and converting QoS profiles to and from the YAML
form of rosbag2 metadata version 9 (Jazzy); and :func:`float64_field`, the value every
writer of a ``float64[]`` message field gives it.
"""
import array
import functools
import importlib
import json
import os
from pathlib import Path
import re
import sys

import numpy as np
import yaml


def float64_field(values) -> array.array:
    """
    Return ``values``, row-major, as the ``array.array('d')`` a ``float64[]`` field holds.

    rclpy copies an ``array.array`` into the message in one go; a list is converted element
    by element.
    """
    return array.array('d', np.ascontiguousarray(values, dtype=np.float64).tobytes())


# rmw's RMW_DURATION_INFINITE, as rosbag2 writes it for "no deadline/lifespan/lease".
INFINITE_SEC = 9223372036
INFINITE_NSEC = 854775807

_TYPE_RE = re.compile(r'^([a-zA-Z][a-zA-Z0-9_]*)/(?:(msg|srv|action)/)?([a-zA-Z][a-zA-Z0-9_]*)$')
# Same patterns as rosbag2_storage_mcap's message_definition_cache.cpp: the first word of
# each line of a .msg file is its field type.
_MSG_FIELD_TYPE_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string'))
_DELIMITER = '=' * 80 + '\n'


def type_name(msg_type) -> str:
    """
    Return ``pkg/msg/Type`` for a message class, an instance or a type string.

    ``sensor_msgs/JointState`` is completed to ``sensor_msgs/msg/JointState``.
    """
    if isinstance(msg_type, str):
        match = _TYPE_RE.match(msg_type.strip())
        if not match:
            raise ValueError(f'not a ROS 2 message type name: {msg_type!r}')
        pkg, ns, name = match.groups()
        return f'{pkg}/{ns or "msg"}/{name}'
    cls = msg_type if isinstance(msg_type, type) else type(msg_type)
    module = cls.__module__.split('.')
    if len(module) < 2 or not hasattr(cls, 'get_fields_and_field_types'):
        raise TypeError(f'not a ROS 2 message class: {cls!r}')
    return f'{module[0]}/{module[1]}/{cls.__name__}'


@functools.lru_cache(maxsize=None)
def message_class(name: str):
    """Return the installed rclpy message class for a type name, or None if it is unknown."""
    try:
        pkg, ns, cls = type_name(name).split('/')
    except ValueError:
        return None
    try:
        module = importlib.import_module(f'{pkg}.{ns}')
    except ImportError:
        return None
    return getattr(module, cls, None)


def _share_dirs(pkg: str):
    # the ROS wheels install share/<pkg> into the environment's prefix: found there also
    # when AMENT_PREFIX_PATH is not set (python -m pytest run without make)
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]
    for prefix in prefixes:
        if prefix:
            yield Path(prefix) / 'share' / pkg
    try:
        from ament_index_python.packages import get_package_share_directory
        yield Path(get_package_share_directory(pkg))
    except Exception:  # noqa: B902 - package unknown to the index, or no index at all
        return


@functools.lru_cache(maxsize=None)
def _interface_file(name: str, suffix: str):
    pkg, ns, cls = type_name(name).split('/')
    for share in _share_dirs(pkg):
        path = share / ns / f'{cls}{suffix}'
        if path.is_file():
            return path
    return None


@functools.lru_cache(maxsize=None)
def jazzy_typestore():
    """Return the ``rosbags`` type store of ROS 2 Jazzy (one, shared: it is read-only here)."""
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def _msg_dependencies(text: str, package: str):
    deps = set()
    for match in _MSG_FIELD_TYPE_RE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVES:
            continue
        deps.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(deps)


@functools.lru_cache(maxsize=None)
def message_definition(name: str):
    """
    Return ``(encoding, text)`` of the full message definition that rosbag2 records.

    The text is the type's own ``.msg`` file followed, depth first, by each dependency
    (in sorted order, each once) after a line of 80 ``=`` and a ``MSG: pkg/Type`` line,
    exactly as rosbag2_storage_mcap builds it from the installed ``share/<pkg>/msg``
    files. A type whose ``.msg`` is not installed is taken from the ``rosbags`` Jazzy type
    store. Raises KeyError if neither knows the type.
    """
    name = type_name(name)
    if _interface_file(name, '.msg') is not None:
        seen = set()

        def full_text(ident):
            path = _interface_file(ident, '.msg')
            if path is None:
                raise KeyError(f'no .msg definition installed for {ident}')
            text = path.read_text()
            for dep in _msg_dependencies(text, ident.split('/')[0]):
                if dep not in seen:
                    seen.add(dep)
                    text += '\n' + _DELIMITER + 'MSG: ' + dep + '\n' + full_text(dep)
            return text

        try:
            return 'ros2msg', full_text(name)
        except KeyError:
            pass
    store = jazzy_typestore()
    if name not in store.types:
        raise KeyError(f'message type {name} is neither installed nor in the rosbags store')
    text, _ = store.generate_msgdef(name, ros_version=2)
    return 'ros2msg', text


@functools.lru_cache(maxsize=None)
def type_hash(name: str) -> str:
    """
    Return the ``RIHS01_...`` type description hash of a type, or '' if unknown.

    Read from the ``share/<pkg>/msg/<Type>.json`` type description that rosidl installs in
    Jazzy, else computed by the ``rosbags`` Jazzy type store.
    """
    name = type_name(name)
    path = _interface_file(name, '.json')
    if path is not None:
        try:
            for entry in json.loads(path.read_text()).get('type_hashes', []):
                if entry.get('type_name') == name:
                    return entry['hash_string']
        except (ValueError, KeyError, OSError):
            pass
    try:
        store = jazzy_typestore()
        if name in store.types:
            return store.hash_rihs01(name)
    except Exception:  # noqa: B902 - a type the store cannot hash: rosbag2 allows ''
        pass
    return ''


def _duration(value):
    """Turn an rclpy Duration, a nanosecond count or a ``{sec, nsec}`` dict into a dict."""
    if isinstance(value, dict):
        return {'sec': int(value['sec']), 'nsec': int(value['nsec'])}
    ns = value if isinstance(value, int) else int(getattr(value, 'nanoseconds', 0))
    if ns <= 0 or ns >= INFINITE_SEC * 10**9:
        # rclpy's "default" (0) is what Fast DDS offers as infinite, which is how
        # rosbag2 records it from the graph.
        return {'sec': INFINITE_SEC, 'nsec': INFINITE_NSEC}
    return {'sec': ns // 10**9, 'nsec': ns % 10**9}


def _policy(value, default):
    name = getattr(value, 'name', value)
    name = str(name).lower() if name is not None else default
    return default if name in ('system_default', 'unknown', '') else name


def qos_to_dict(qos=None) -> dict:
    """
    Return one QoS profile as a rosbag2 v9 dict (policy names, ``{sec, nsec}`` times).

    ``qos`` is an ``rclpy.qos.QoSProfile``, a dict in this same form, or None for rclpy's
    default publisher profile (keep_last 10, reliable, volatile). System defaults are
    written as what a Jazzy publisher actually offers: keep_last, reliable, volatile,
    automatic liveliness, infinite durations.
    """
    if isinstance(qos, dict):
        base = qos
    elif qos is None:
        base = {'history': 'keep_last', 'depth': 10, 'reliability': 'reliable',
                'durability': 'volatile'}
    else:
        base = {name: getattr(qos, name) for name in (
            'history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
            'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions')}
    return {
        'history': _policy(base.get('history'), 'keep_last'),
        'depth': int(base.get('depth', 0) or 0),
        'reliability': _policy(base.get('reliability'), 'reliable'),
        'durability': _policy(base.get('durability'), 'volatile'),
        'deadline': _duration(base.get('deadline', 0)),
        'lifespan': _duration(base.get('lifespan', 0)),
        'liveliness': _policy(base.get('liveliness'), 'automatic'),
        'liveliness_lease_duration': _duration(base.get('liveliness_lease_duration', 0)),
        'avoid_ros_namespace_conventions': bool(
            base.get('avoid_ros_namespace_conventions', False)),
    }


def qos_list(qos=None) -> list:
    """Return the ``offered_qos_profiles`` list for one profile, a list of them, or None."""
    if isinstance(qos, (list, tuple)):
        return [qos_to_dict(q) for q in qos]
    return [qos_to_dict(qos)]


def qos_yaml(profiles: list) -> str:
    """
    Serialise an ``offered_qos_profiles`` list as yaml-cpp's ``YAML::Dump`` prints it.

    This string goes into the MCAP channel's ``offered_qos_profiles`` metadata, as
    rosbag2_storage_mcap's ``serialize_rclcpp_qos_vector`` writes it.
    """
    lines = []
    for p in profiles:
        lines.append(f'- history: {p["history"]}')
        lines.append(f'  depth: {p["depth"]}')
        lines.append(f'  reliability: {p["reliability"]}')
        lines.append(f'  durability: {p["durability"]}')
        for key in ('deadline', 'lifespan'):
            lines += [f'  {key}:', f'    sec: {p[key]["sec"]}', f'    nsec: {p[key]["nsec"]}']
        lines.append(f'  liveliness: {p["liveliness"]}')
        lease = p['liveliness_lease_duration']
        lines += ['  liveliness_lease_duration:', f'    sec: {lease["sec"]}',
                  f'    nsec: {lease["nsec"]}']
        lines.append('  avoid_ros_namespace_conventions: '
                     + ('true' if p['avoid_ros_namespace_conventions'] else 'false'))
    return '\n'.join(lines)


_V8_NAMES = {
    'history': {1: 'keep_last', 2: 'keep_all'},
    'reliability': {1: 'reliable', 2: 'best_effort', 4: 'best_available'},
    'durability': {1: 'transient_local', 2: 'volatile', 4: 'best_available'},
    'liveliness': {1: 'automatic', 3: 'manual_by_topic', 4: 'best_available'},
}


def parse_qos(value) -> list:
    """
    Parse ``offered_qos_profiles`` in any rosbag2 form into a list of v9 dicts.

    Accepts the v9 YAML list, the YAML-in-a-string form (metadata up to v8 and MCAP
    channel metadata) and v8's integer enums.
    """
    if not value:
        return []
    if isinstance(value, (bytes, str)):
        value = yaml.safe_load(value) or []
    out = []
    for item in value:
        item = dict(item)
        for key, names in _V8_NAMES.items():
            if isinstance(item.get(key), int):
                item[key] = names.get(item[key], 'system_default')
        out.append(qos_to_dict(item))
    return out


def qos_profile(qos: dict):
    """Return an ``rclpy.qos.QoSProfile`` for a v9 QoS dict (for replaying a topic)."""
    from rclpy.duration import Duration
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile,
                           ReliabilityPolicy)

    def dur(d):
        if d['sec'] >= INFINITE_SEC:
            return Duration()
        return Duration(seconds=d['sec'], nanoseconds=d['nsec'])

    def pol(enum, name, default):
        try:
            return enum[name.upper()]
        except KeyError:
            return default

    history = pol(HistoryPolicy, qos['history'], HistoryPolicy.KEEP_LAST)
    return QoSProfile(
        history=history,
        depth=max(1, qos['depth']) if history == HistoryPolicy.KEEP_LAST else qos['depth'],
        reliability=pol(ReliabilityPolicy, qos['reliability'], ReliabilityPolicy.RELIABLE),
        durability=pol(DurabilityPolicy, qos['durability'], DurabilityPolicy.VOLATILE),
        deadline=dur(qos['deadline']),
        lifespan=dur(qos['lifespan']),
        liveliness=pol(LivelinessPolicy, qos['liveliness'], LivelinessPolicy.AUTOMATIC),
        liveliness_lease_duration=dur(qos['liveliness_lease_duration']),
        avoid_ros_namespace_conventions=qos['avoid_ros_namespace_conventions'])
