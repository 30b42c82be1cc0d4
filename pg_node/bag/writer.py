"""
Write rclpy messages into a rosbag2 bag (MCAP storage, as ROS 2 Jazzy records it).

A bag is a directory ``<run>/`` holding ``metadata.yaml`` (rosbag2 metadata version 9) and
the files ``<run>_0.mcap``, ``<run>_1.mcap``, ... The MCAP records are written by the
``mcap`` library's ``Writer``; pg_node gives it what rosbag2_storage_mcap would: profile
``ros2``, one ``ros2msg`` schema per type holding the full message definition text, one
``cdr`` channel per topic with the ``offered_qos_profiles`` and ``topic_type_hash``
metadata, messages serialised by ``rclpy.serialization.serialize_message``, chunks
compressed with zstd at level 1 as the mcap C++ writer does, and at the end of each file
the ``rosbag2`` metadata record (the bag's metadata as YAML under ``serialized_metadata``).

Crash safety: messages wait in memory until they make a chunk of ``chunk_size`` bytes (or
the chunk is ``chunk_max_age_s`` old, checked at each write); then the Writer gets them all
at once, writes them as one chunk and the file is flushed to the operating system, so a
process killed with SIGKILL leaves every completed chunk on disk. ``metadata.yaml`` is
replaced atomically (temporary file, then ``os.replace``) when a file is opened or closed
and at most every ``metadata_interval_s`` after a chunk, so it is always a valid file
describing data that is on disk. :func:`reindex` (like ``ros2 bag reindex``) turns what a
killed writer left into a complete bag. On Ctrl-C or SIGTERM the caller calls
:meth:`BagWriter.close` from its shutdown path; close is idempotent and defers those
signals while it writes.

The writer creates no ROS node: it is a plain object a node (or a test) owns.
"""
import contextlib
import os
from pathlib import Path
import signal
import threading
import time

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Message, Metadata, Schema
import mcap.writer
from mcap.writer import CompressionType, LIBRARY_IDENTIFIER, Writer
from pg_node.bag import ros_types
from pg_node.bag.reader import _split_index, McapScan, NOT_MCAP, read_metadata_yaml
import yaml

METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'
PROFILE = 'ros2'
LIBRARY = f'pg_node bag_writer ({LIBRARY_IDENTIFIER})'
DEFAULT_CHUNK_SIZE = 768 * 1024  # mcap C++ writer's default, which rosbag2 uses
_COMPRESSION = {'': CompressionType.NONE, 'none': CompressionType.NONE,
                None: CompressionType.NONE, 'zstd': CompressionType.ZSTD,
                'lz4': CompressionType.LZ4}


def _record_size(record) -> int:
    builder = RecordBuilder()
    record.write(builder)
    return builder.count


# a message record's bytes besides its data, as the library encodes it
_MESSAGE_OVERHEAD = _record_size(Message(channel_id=0, log_time=0, data=b'', publish_time=0,
                                         sequence=0))


class _Zstandard:
    """
    The ``zstandard`` module as mcap's Writer sees it: ``compress`` at zstd level 1.

    mcap 1.6's Writer takes no compression level and compresses each chunk with
    ``zstandard.compress(data)``, that is level 3; the mcap C++ writer that rosbag2 uses
    compresses at level 1 (its ``CompressionLevel::Default``). For JointState chunks level
    1 is 2.8 times faster for sizes within 0.2%, so the Writer is handed this module.
    """

    def __init__(self, module):
        self._module = module

    def __getattr__(self, name):
        return getattr(self._module, name)

    def compress(self, data, level=1):
        """Compress ``data`` into one zstd frame, at ``level``."""
        return self._module.compress(data, level)


if getattr(mcap.writer, 'zstandard', None) is not None and not isinstance(
        mcap.writer.zstandard, _Zstandard):
    mcap.writer.zstandard = _Zstandard(mcap.writer.zstandard)


@contextlib.contextmanager
def _signals_deferred():
    """
    Hold SIGINT/SIGTERM while a chunk or a file is being finished, never left half-written.

    Their Python handlers are swapped for one that only notes the signal; on leaving, the
    original handlers come back and each noted signal is raised again, so the caller's
    Ctrl-C/SIGTERM handling runs once the file is consistent. (Blocking the signals at
    the OS level is not enough: a signal that already arrived runs its Python handler at
    the next bytecode.)
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []

    def hold(signum, frame):
        caught.append(signum)

    old = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(signum)
        # only a Python handler is swapped: SIG_DFL or SIG_IGN as Python sees them may stand
        # for a C handler (rclpy's SIGTERM handler), which restoring them would remove
        if callable(handler):
            old[signum] = signal.signal(signum, hold)
    try:
        yield
    finally:
        for signum, handler in old.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(caught):
            signal.raise_signal(signum)


class McapFile:
    """
    One MCAP file, written by ``mcap.writer.Writer`` one whole chunk at a time.

    :meth:`add_message` only queues a message; :meth:`write_chunk` hands the queue to the
    Writer as one chunk (the Writer never cuts a chunk by itself) and flushes the file, so
    the messages counted in :attr:`message_count` are exactly those on disk.
    """

    def __init__(self, path, chunk_size=DEFAULT_CHUNK_SIZE, compression='zstd', fsync=False):
        """Create ``path`` and write the MCAP magic and the ``ros2`` header record."""
        if compression not in _COMPRESSION:
            raise ValueError(f'unknown chunk compression {compression!r} (none, zstd, lz4)')
        self.path = Path(path)
        self.chunk_size = int(chunk_size)
        self.fsync = fsync
        self._f = open(self.path, 'xb')
        self._mcap = Writer(self._f, chunk_size=2**62, compression=_COMPRESSION[compression])
        self._mcap.start(PROFILE, LIBRARY)
        self._f.flush()
        self._written = self._f.tell()   # bytes on disk (tell() is a system call: not per message)
        self._schema_ids = {}    # (name, encoding, data) -> id
        self.pending = []        # Writer.add_message arguments of the open chunk
        self.pending_bytes = 0
        self.message_count = 0   # messages in completed chunks (on disk)
        self.channel_counts = {}
        self.start_time = None
        self.end_time = None
        self.closed = False

    @property
    def size(self) -> int:
        """Bytes written so far plus the open chunk (a size estimate for splitting)."""
        return self._written + self.pending_bytes

    def add_schema(self, name, encoding, data) -> int:
        """Register a schema (once per distinct definition) and return its id."""
        data = data.encode('utf-8') if isinstance(data, str) else bytes(data)
        key = (name, encoding, data)
        if key not in self._schema_ids:
            with _signals_deferred():
                self._schema_ids[key] = self._mcap.register_schema(name, encoding, data)
        return self._schema_ids[key]

    def add_channel(self, topic, message_encoding, schema_id, metadata) -> int:
        """Register a channel and return its id; its record goes into the next chunk."""
        with _signals_deferred():
            cid = self._mcap.register_channel(topic, message_encoding, schema_id, metadata)
        self.channel_counts.setdefault(cid, 0)
        return cid

    def add_message(self, channel_id, log_time, data, publish_time=None, sequence=0):
        """Queue one serialised message for the open chunk (see :meth:`write_chunk`)."""
        self.pending.append((channel_id, log_time, data,
                             log_time if publish_time is None else publish_time,
                             sequence & 0xFFFFFFFF))
        self.pending_bytes += _MESSAGE_OVERHEAD + len(data)

    def write_chunk(self) -> bool:
        """Write the queued messages as one chunk and flush it; False if none were queued."""
        if not self.pending:
            return False
        with _signals_deferred():
            pending = self.pending
            add, counts = self._mcap.add_message, self.channel_counts
            for cid, log_time, data, publish_time, sequence in pending:
                add(cid, log_time, data, publish_time, sequence)
                counts[cid] += 1
            self._mcap.flush()   # the chunk, its message indexes, then the OS
            self._written = self._f.tell()
            if self.fsync:
                os.fsync(self._f.fileno())
            times = [m[1] for m in pending]
            low, high = min(times), max(times)
            self.start_time = low if self.start_time is None else min(self.start_time, low)
            self.end_time = high if self.end_time is None else max(self.end_time, high)
            self.message_count += len(pending)
            self.pending = []
            self.pending_bytes = 0
        return True

    def add_metadata(self, name, data):
        """Write a metadata record (after the open chunk; indexed in the summary)."""
        with _signals_deferred():
            self.write_chunk()
            self._mcap.add_metadata(name, data)

    def close(self, metadata=()):
        """Write the last chunk, the metadata records, the summary and the footer."""
        if self.closed:
            return
        with _signals_deferred():
            self.write_chunk()
            for name, data in metadata:
                self._mcap.add_metadata(name, data)
            self._mcap.finish()
            self._f.flush()
            os.fsync(self._f.fileno())
            self._f.close()
            self.closed = True


_serialize_message = None


def _serialize(msg):
    """Return rclpy's CDR bytes of ``msg`` (rclpy imported on first use, not per message)."""
    global _serialize_message
    if _serialize_message is None:
        from rclpy.serialization import serialize_message as _serialize_message
    return _serialize_message(msg)


class _Topic:
    __slots__ = ('name', 'type', 'cls', 'qos', 'hash', 'encoding', 'definition', 'count',
                 'seq')

    def __init__(self, name, msg_type, qos):
        self.name = name
        self.type = ros_types.type_name(msg_type)
        self.cls = ros_types.message_class(self.type)
        self.qos = ros_types.qos_list(qos)
        self.hash = ros_types.type_hash(self.type)
        self.encoding, self.definition = ros_types.message_definition(self.type)
        self.count = 0
        self.seq = 0

    def metadata(self, count):
        return {'topic_metadata': {
            'name': self.name, 'type': self.type, 'serialization_format': 'cdr',
            'offered_qos_profiles': self.qos, 'type_description_hash': self.hash},
            'message_count': count}


def _atomic_write(path: Path, text: str):
    tmp = path.with_name(f'.{path.name}.tmp')
    with open(tmp, 'w') as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def bag_metadata(topics, files, custom_data=None) -> dict:
    """
    Return the ``rosbag2_bagfile_information`` dict of rosbag2 metadata version 9.

    ``topics`` is a list of ``topics_with_message_count`` entries; ``files`` a list of
    ``(relative path, starting time ns, duration ns, message count)``.
    """
    starts = [f[1] for f in files if f[3]]
    ends = [f[1] + f[2] for f in files if f[3]]
    start = min(starts) if starts else 0
    return {
        'version': METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': (max(ends) - start) if ends else 0},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f[3] for f in files),
        'topics_with_message_count': topics,
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f[0] for f in files],
        'files': [{'path': p, 'starting_time': {'nanoseconds_since_epoch': s},
                   'duration': {'nanoseconds': d}, 'message_count': n}
                  for p, s, d, n in files],
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ROS_DISTRO,
    }


# libyaml's emitter when PyYAML has it: the metadata of a bag with many topics is dumped
# often, and the pure-Python emitter is slow at it (docs/results/PROFILE.md).
_YAML_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


def _dump(info) -> str:
    return yaml.dump(info, Dumper=_YAML_DUMPER, default_flow_style=False, sort_keys=False)


def write_metadata_yaml(directory, info):
    """Atomically replace ``directory/metadata.yaml`` with this bag information."""
    _atomic_write(Path(directory) / 'metadata.yaml',
                  _dump({'rosbag2_bagfile_information': info}))


class BagWriter:
    """
    Record rclpy messages into a rosbag2 MCAP bag directory, split into files.

    ``split_max_bytes``, ``split_max_duration_ns`` and ``split_max_messages`` start a new
    file when the current one reaches them (0: never); ``split_max_episodes`` does so after
    that many messages on ``episode_topic`` (one message per finished episode), and
    :meth:`split` does it on request. ``chunk_size`` bounds what a SIGKILL can lose, as does
    ``chunk_max_age_s`` for slow topics (checked on each write).
    """

    def __init__(self, directory, split_max_bytes=0, split_max_duration_ns=0,
                 split_max_messages=0, split_max_episodes=0, episode_topic=None,
                 chunk_size=DEFAULT_CHUNK_SIZE, chunk_max_age_s=1.0, compression='zstd',
                 fsync=False, metadata_interval_s=1.0, custom_data=None, on_chunk=None):
        """Create the bag directory (it must not exist, or be empty) and its first file."""
        self.directory = Path(directory)
        if self.directory.exists() and any(self.directory.iterdir()):
            raise FileExistsError(f'bag directory {self.directory} exists and is not empty')
        self.directory.mkdir(parents=True, exist_ok=True)
        self.name = self.directory.name
        self.split_max_bytes = int(split_max_bytes)
        self.split_max_duration_ns = int(split_max_duration_ns)
        self.split_max_messages = int(split_max_messages)
        self.split_max_episodes = int(split_max_episodes)
        self.episode_topic = episode_topic
        self.chunk_size = chunk_size
        self.chunk_max_age_s = chunk_max_age_s
        self.compression = compression
        self.fsync = fsync
        self.metadata_interval_s = metadata_interval_s
        self.custom_data = dict(custom_data or {})
        self.on_chunk = on_chunk
        self._topics = {}
        self._done_files = []       # (path, start, duration, count, per-topic counts)
        self._file = None
        self._file_topics = {}      # topic -> channel id in the open file
        self._file_counts = {}      # topic -> messages written to the open file
        self._file_first_t = None
        self._file_episodes = 0
        self._chunk_opened = time.monotonic()
        self._last_meta = 0.0
        self.closed = False
        # A node may write from several executor threads; every public call holds this.
        self._lock = threading.RLock()
        self._open_file()

    # -- topics and messages -------------------------------------------------------------
    def add_topic(self, name, msg_type, qos=None):
        """
        Declare a topic with its type (a class or ``pkg/msg/Type``) and offered QoS.

        ``qos`` is an ``rclpy.qos.QoSProfile``, a rosbag2 QoS dict, a list of either (one
        per publisher), or None for rclpy's default publisher profile.
        """
        with self._lock:
            self._add_topic(name, msg_type, qos)

    def _add_topic(self, name, msg_type, qos):
        if self.closed:
            raise RuntimeError('bag writer is closed')
        if name in self._topics:
            topic = self._topics[name]
            if topic.type != ros_types.type_name(msg_type):
                raise ValueError(f'topic {name} already added with type {topic.type}')
            return
        self._topics[name] = _Topic(name, msg_type, qos)
        if self._file is not None:
            self._add_channel(self._topics[name])
        self._write_metadata()

    def _add_channel(self, topic):
        sid = self._file.add_schema(topic.type, topic.encoding, topic.definition)
        self._file_topics[topic.name] = self._file.add_channel(
            topic.name, 'cdr', sid,
            {'offered_qos_profiles': ros_types.qos_yaml(topic.qos),
             'topic_type_hash': topic.hash})
        self._file_counts.setdefault(topic.name, 0)

    def write(self, topic, msg, t_ns, publish_time_ns=None):
        """
        Record ``msg`` (an rclpy message, or CDR bytes) on ``topic`` at log time ``t_ns``.

        A topic not yet added is added with the message's type and the default QoS; a
        message of another type than its topic's raises TypeError.
        """
        with self._lock:
            self._write(topic, msg, t_ns, publish_time_ns)

    def _write(self, topic, msg, t_ns, publish_time_ns):
        if self.closed:
            raise RuntimeError('bag writer is closed')
        if isinstance(msg, (bytes, bytearray, memoryview)):
            if topic not in self._topics:
                raise KeyError(f'topic {topic} must be added before writing raw bytes')
            data = bytes(msg)
        else:
            if topic not in self._topics:
                self._add_topic(topic, type(msg), None)
            expected = self._topics[topic]
            if expected.cls is not type(msg):
                raise TypeError(f'topic {topic} has type {expected.type}, got {type(msg)!r}')
            data = _serialize(msg)
        t_ns = int(t_ns)
        if not 0 <= t_ns < 2**64 or not 0 <= (publish_time_ns or 0) < 2**64:
            # checked now: the message is encoded only when its chunk is written
            raise ValueError(f'log/publish time out of uint64 range: {t_ns}, {publish_time_ns}')
        if self._file is None:
            self._open_file()
        if (self.split_max_duration_ns and self._file_first_t is not None
                and t_ns - self._file_first_t >= self.split_max_duration_ns):
            self.split()
        info = self._topics[topic]
        f = self._file
        f.add_message(self._file_topics[topic], t_ns, data, publish_time_ns, info.seq)
        info.seq += 1
        info.count += 1
        self._file_counts[topic] += 1
        if self._file_first_t is None:
            self._file_first_t = t_ns
        if f.pending_bytes >= f.chunk_size or (
                self.chunk_max_age_s is not None
                and time.monotonic() - self._chunk_opened >= self.chunk_max_age_s):
            self._write_chunk()
        if topic == self.episode_topic:
            self._file_episodes += 1
            if self.split_max_episodes and self._file_episodes >= self.split_max_episodes:
                self.split()
                return
        if ((self.split_max_bytes and self._file.size >= self.split_max_bytes)
                or (self.split_max_messages
                    and sum(self._file_counts.values()) >= self.split_max_messages)):
            self.split()

    def flush(self, metadata=True):
        """
        Write the open chunk now, e.g. at the end of an episode, and metadata.yaml.

        With ``metadata=False``, metadata.yaml is rewritten only if the last rewrite is
        older than ``metadata_interval_s`` (what a frequent caller wants).
        """
        with self._lock:
            if not self.closed and self._file is not None:
                self._write_chunk()
                self._write_metadata(force=metadata)

    # -- files ---------------------------------------------------------------------------
    @property
    def file_index(self) -> int:
        """Index of the file being written (0 for ``<run>_0.mcap``)."""
        return len(self._done_files)

    @property
    def flushed_message_count(self) -> int:
        """Messages in completed chunks, that is, on disk and safe from a SIGKILL."""
        done = sum(f[3] for f in self._done_files)
        return done + (self._file.message_count if self._file is not None else 0)

    @property
    def message_count(self) -> int:
        """Messages written so far, flushed or not."""
        return self.flushed_message_count + (len(self._file.pending) if self._file else 0)

    def _file_path(self, index):
        return self.directory / f'{self.name}_{index}.mcap'

    def _open_file(self):
        # held as a file's finishing is: a SIGTERM between creating the file and holding it
        # in self._file left a file that close() never finished (header only, no footer)
        with _signals_deferred():
            self._file = McapFile(self._file_path(self.file_index), self.chunk_size,
                                  self.compression, self.fsync)
            self._file_topics = {}
            self._file_counts = {}
            self._file_first_t = None
            self._file_episodes = 0
            self._chunk_opened = time.monotonic()
            for topic in self._topics.values():
                self._add_channel(topic)
            self._write_metadata(force=True)

    def _write_chunk(self):
        if self._file.write_chunk():
            self._chunk_opened = time.monotonic()
            self._write_metadata()
            if self.on_chunk is not None:
                self.on_chunk(self)

    def _current_file_entry(self):
        """Return the open file's entry: what of it is on disk (in completed chunks)."""
        f = self._file
        counts = {t: f.channel_counts[cid] for t, cid in self._file_topics.items()}
        start = f.start_time or 0
        return (f.path.name, start, (f.end_time or start) - start, sum(counts.values()), counts)

    def _info(self):
        files = list(self._done_files)
        if self._file is not None:
            files.append(self._current_file_entry())
        totals = {}
        for f in files:
            for t, n in f[4].items():
                totals[t] = totals.get(t, 0) + n
        topics = [t.metadata(totals.get(name, 0)) for name, t in self._topics.items()]
        return bag_metadata(topics, [f[:4] for f in files], self.custom_data)

    def _write_metadata(self, force=False):
        now = time.monotonic()
        if not force and now - self._last_meta < self.metadata_interval_s:
            return
        self._last_meta = now
        write_metadata_yaml(self.directory, self._info())

    def _close_file(self):
        f = self._file
        with _signals_deferred():
            self._write_chunk()
            entry = self._current_file_entry()
            self._done_files.append(entry)
            self._file = None
            info = self._info()
            f.close(metadata=[('rosbag2', {'serialized_metadata': _dump(info)})])
            write_metadata_yaml(self.directory, info)

    def split(self):
        """
        Finish the current file now; the next message goes into a new file.

        A no-op if the current file holds no message. The next file is created by the
        next :meth:`write`, so a split after the last episode leaves no empty file.
        """
        with self._lock:
            if self.closed or self._file is None or not any(self._file_counts.values()):
                return
            self._close_file()

    def close(self):
        """Finish the open file and write the final metadata.yaml; safe to call twice."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            with _signals_deferred():
                if self._file is not None:
                    self._close_file()

    def __enter__(self):
        """Return the writer itself."""
        return self

    def __exit__(self, *exc):
        """Close the bag, also when leaving on an exception (Ctrl-C included)."""
        self.close()
        return False

    @property
    def topics(self) -> dict:
        """Map topic name to (type, message count written)."""
        return {n: (t.type, t.count) for n, t in self._topics.items()}


class ReindexReport:
    """What :func:`reindex` found: per file its message count and any damage repaired."""

    def __init__(self):
        """Start an empty report."""
        self.files = []  # (name, message count, damage or None)
        self.unrecoverable = []  # (name, damage): not MCAP at all, left as they were
        self.kept = []   # the damaged originals kept beside their repair

    @property
    def repaired(self):
        """Return the files that had to be rewritten, with their damage."""
        return [(name, damage) for name, _, damage in self.files if damage is not None]

    @property
    def message_count(self):
        """Return the messages the reindexed bag holds."""
        return sum(n for _, n, _ in self.files)

    def __repr__(self):
        """Return a short summary."""
        return f'ReindexReport(files={self.files!r})'


def _free_name(path: Path) -> Path:
    """Return ``path``, or ``path.1``, ``path.2``, ... : the first that does not exist."""
    k, free = 0, path
    while free.exists():
        k += 1
        free = path.with_name(f'{path.name}.{k}')
    return free


def reindex(directory, compression='zstd', keep_damaged=True) -> ReindexReport:
    """
    Recover a bag whose writer was killed, like ``ros2 bag reindex``.

    Each ``.mcap`` file is read record by record (:class:`McapScan`). A complete file is
    left alone; a truncated or damaged one is rewritten by the ``mcap`` Writer (temporary
    file, then ``os.replace``) into a complete MCAP file holding everything before the
    damage. Then ``metadata.yaml`` is rewritten from what the files really contain: counts,
    times, and each topic's QoS and type hash from its MCAP channel (from the old
    metadata.yaml where a channel has none).

    Nothing the user had is lost: each damaged original is kept beside its repair as
    ``<name>.damaged`` (rosbag2 keeps what it cannot read, too), unless ``keep_damaged`` is
    False. A file that is no MCAP at all (not its magic) holds nothing recoverable:
    it is left as it is, out of metadata.yaml, and listed in ``report.unrecoverable``; when
    no file is left, metadata.yaml is not rewritten either.
    """
    directory = Path(directory)
    info = read_metadata_yaml(directory) or {}
    custom = info.get('custom_data')
    old = {}
    with contextlib.suppress(KeyError, TypeError):
        for entry in info.get('topics_with_message_count') or []:
            old[entry['topic_metadata']['name']] = entry['topic_metadata']
    report = ReindexReport()
    topics = {}   # name -> topic_metadata
    totals = {}
    files = []
    damaged = []
    for path in sorted(directory.glob('*.mcap'), key=_split_index):
        scan = McapScan(path)
        counts, times = _copy_records(scan, None, topics)
        damage = scan.damage
        if damage is not None and damage.reason == NOT_MCAP:
            report.unrecoverable.append((path.name, damage))
            continue
        if damage is not None:
            damaged.append(path)
        n = sum(counts.values())
        for t, c in counts.items():
            totals[t] = totals.get(t, 0) + c
        start = min(times, default=0)
        files.append((path.name, start, max(times, default=0) - start, n))
        report.files.append((path.name, n, damage))
    entries = []
    for name, tm in topics.items():
        tm = dict(tm)
        if name in old and old[name].get('type') == tm['type']:
            # The channel's QoS is what readers match metadata.yaml against (rosbags
            # yields nothing for a topic whose two QoS differ), so it wins.
            tm['offered_qos_profiles'] = tm['offered_qos_profiles'] or ros_types.parse_qos(
                old[name].get('offered_qos_profiles'))
            tm['type_description_hash'] = (tm['type_description_hash']
                                           or old[name].get('type_description_hash', ''))
        entries.append({'topic_metadata': tm, 'message_count': totals.get(name, 0)})
    info = bag_metadata(entries, files, custom)
    for path in damaged:
        tmp = path.with_name(f'.{path.name}.reindex')
        if tmp.exists():
            tmp.unlink()
        writer = McapFile(tmp, compression=compression)
        _copy_records(McapScan(path), writer, {})
        writer.close(metadata=[('rosbag2', {'serialized_metadata': _dump(info)})])
        if keep_damaged:
            kept = _free_name(path.with_name(path.name + '.damaged'))
            os.replace(path, kept)
            report.kept.append(kept.name)
        os.replace(tmp, path)
    if files:
        write_metadata_yaml(directory, info)
    return report


def _copy_records(scan, writer, topics):
    """Read every whole record of ``scan``; copy them into ``writer`` if it is not None."""
    counts, times = {}, []
    schema_map, channel_map = {}, {}
    for record in scan:
        if isinstance(record, Message):
            channel = scan.channels.get(record.channel_id)
            if channel is None:
                continue
            counts[channel.topic] += 1
            times.append(record.log_time)
            if writer is not None:
                writer.add_message(channel_map[channel.id], record.log_time, record.data,
                                   record.publish_time, record.sequence)
                if writer.pending_bytes >= writer.chunk_size:
                    writer.write_chunk()
        elif isinstance(record, Schema) and writer is not None:
            schema_map[record.id] = writer.add_schema(record.name, record.encoding, record.data)
        elif isinstance(record, Channel):
            schema = scan.schemas.get(record.schema_id)
            topics.setdefault(record.topic, {
                'name': record.topic, 'type': schema.name if schema else '',
                'serialization_format': record.message_encoding,
                'offered_qos_profiles': ros_types.parse_qos(
                    record.metadata.get('offered_qos_profiles', '')),
                'type_description_hash': record.metadata.get('topic_type_hash', '')})
            counts.setdefault(record.topic, 0)
            if writer is not None:
                channel_map[record.id] = writer.add_channel(
                    record.topic, record.message_encoding, schema_map.get(record.schema_id, 0),
                    record.metadata)
        elif isinstance(record, Metadata) and writer is not None and record.name != 'rosbag2':
            writer.add_metadata(record.name, record.metadata)
    return counts, times
