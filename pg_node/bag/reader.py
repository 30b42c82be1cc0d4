"""
Read rosbag2 MCAP bags, ours or anyone's, and survive damaged files.

A bag is either a rosbag2 directory (``metadata.yaml`` beside one or more ``.mcap`` files)
or a bare ``.mcap`` file. :class:`BagReader` lists the topics (type, message count, offered
QoS) and iterates the messages of all files in log-time order as raw CDR bytes, optionally
deserialised into the installed rclpy message classes.

The records are read by the ``mcap`` library (``mcap.stream_reader.StreamReader``; each
chunk opened, and its CRC checked, by ``breakup_chunk``) in one linear pass over each file,
never through its summary section, so a file whose writer was killed (no summary, no
footer, a chunk cut in half) still yields every message up to the damage. The reader then
records a :class:`Damage` (file, byte offset, reason) in :attr:`BagReader.problems` and
carries on with the next file; it never hangs on a corrupted length field, because the
file the library reads from refuses, before reading, any read that runs past its end.
"""
import heapq
import os
from pathlib import Path
from typing import NamedTuple, Optional
import warnings

from mcap.exceptions import InvalidMagic
from mcap.records import Channel, Chunk, DataEnd, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk, CRCValidationError, StreamReader
from mcap.writer import MCAP0_MAGIC
from pg_node.bag import ros_types
import yaml


#: the damage of a file that does not even start as MCAP: nothing in it is recoverable
NOT_MCAP = 'not an MCAP file (bad magic)'


class Damage(NamedTuple):
    """Where and why reading one file of a bag stopped early."""

    path: str
    offset: int
    reason: str

    def __str__(self):
        """Return a one-line description naming the file and the byte offset."""
        return f'{self.path}: stopped at byte {self.offset}: {self.reason}'


class BagDamageWarning(UserWarning):
    """Warned when a bag file is truncated or corrupted; the messages before it were read."""


class TopicInfo(NamedTuple):
    """One topic of a bag: name, type, message count, offered QoS and type hash."""

    name: str
    msg_type: str
    message_count: int
    offered_qos_profiles: list
    type_description_hash: str = ''
    serialization_format: str = 'cdr'


class BagMessage(NamedTuple):
    """One message: topic, type, log time (ns), raw CDR bytes and, if asked, the object."""

    topic: str
    msg_type: str
    log_time_ns: int
    data: bytes
    msg: object = None


class _PastTheEnd(Exception):
    """A read asked for more bytes than the file has left."""

    def __init__(self, wanted, left):
        super().__init__(wanted, left)
        self.wanted, self.left = wanted, left


class _Bounded:
    """The file as StreamReader sees it: a read that would run past its end raises first."""

    def __init__(self, f):
        self._read = f.read
        self.size = os.fstat(f.fileno()).st_size
        self.pos = 0   # kept here: a buffered file's tell() is a system call

    def tell(self):
        return self.pos

    def read(self, n=-1):
        left = self.size - self.pos
        if n > left:
            raise _PastTheEnd(n, left)
        data = self._read(left if n < 0 else n)
        self.pos += len(data)
        return data


class McapScan:
    """
    Linear, damage-tolerant scan of one MCAP file by ``mcap``'s ``StreamReader``.

    Iterating yields the data section's ``mcap.records`` in file order: ``Schema``,
    ``Channel``, ``Message`` and ``Metadata``, each chunk's records in its place (a chunk is
    decompressed and its CRC checked whole first, so a bad chunk yields nothing), or with
    ``open_chunks=False`` the ``Chunk`` records themselves. :attr:`record_offset` is where
    the top-level record being yielded starts (the chunk, for the records it holds). After
    the iteration, :attr:`complete` tells whether the file was read to its end (footer and
    magic), else :attr:`damage` is the :class:`Damage` where reading stopped;
    :attr:`schemas` and :attr:`channels` (by id) and :attr:`metadata` (``(name, dict)``)
    hold what was read.
    """

    def __init__(self, path, verify_crc=True, open_chunks=True):
        """Prepare to scan ``path``; nothing is read until iteration."""
        self.path = str(path)
        self.verify_crc = verify_crc
        self.open_chunks = open_chunks
        self.damage: Optional[Damage] = None
        self.complete = False
        self.record_offset = 0
        self.schemas = {}
        self.channels = {}
        self.metadata = []

    def __iter__(self):
        """Yield the file's records, stopping cleanly at the first damage."""
        try:
            f = open(self.path, 'rb')
        except OSError as exc:
            self.damage = Damage(self.path, 0, f'cannot open: {exc}')
            return
        with f:
            stream = _Bounded(f)
            # chunks come whole, opened below; the data section's CRC is not checked
            records = StreamReader(stream, emit_chunks=True, record_size_limit=None).records
            at = 0              # where the record being read starts
            summary = False     # past the data section: schemas and channels repeated
            while True:
                try:
                    record = next(records, None)
                    inner = (record,)
                    if isinstance(record, Chunk) and self.open_chunks:
                        inner = breakup_chunk(record, validate_crc=self.verify_crc)
                except Exception as exc:  # noqa: B902 - any failure inside the file is damage
                    self.damage = Damage(self.path, at, _reason(exc, at == stream.tell()))
                    return
                if record is None:
                    self.complete = True
                    return
                self.record_offset = at
                for r in inner:
                    if isinstance(r, Message):   # most records: tested first
                        pass
                    elif isinstance(r, Schema):
                        self.schemas[r.id] = r
                    elif isinstance(r, Channel):
                        self.channels[r.id] = r
                    elif isinstance(r, Metadata):
                        self.metadata.append((r.name, r.metadata))
                    elif isinstance(r, DataEnd):
                        summary = True
                    elif not isinstance(r, Chunk):
                        continue
                    if not summary:
                        yield r
                at = stream.tell()


def _reason(exc, at_record_start):
    """Say why reading stopped, from the exception that stopped it."""
    if isinstance(exc, _PastTheEnd):
        if at_record_start and exc.left == 0:
            return 'file ends without a footer (writer did not finish)'
        return (f'truncated record: it runs past the end of the file ({exc.wanted} more '
                f'bytes wanted, {exc.left} left)')
    if isinstance(exc, InvalidMagic):
        return NOT_MCAP
    if isinstance(exc, CRCValidationError):
        return f'corrupted record: CRC mismatch ({exc})'
    return f'corrupted record: {exc!r}'


def _file_messages(scan, file_index):
    """
    Yield ``(log_time, file_index, n, topic, msg_type, data)`` in log-time order.

    A heap holds the messages read so far; one is given out once no later chunk of the
    file can hold an earlier message, which the chunks' start times tell (read ahead of
    time by a scan that does not open the chunks). Ties keep file order.
    """
    ahead = McapScan(scan.path, verify_crc=False, open_chunks=False)
    offsets, starts = [], []
    for r in ahead:
        if isinstance(r, (Chunk, Message)):
            offsets.append(ahead.record_offset)
            starts.append(r.message_start_time if isinstance(r, Chunk) else r.log_time)
    later = [float('inf')] * (len(starts) + 1)   # later[k]: earliest start from record k on
    for i in range(len(starts) - 1, -1, -1):
        later[i] = min(starts[i], later[i + 1])
    heap = []
    n = 0
    k = 0
    current = None
    resolved = {}
    for record in scan:
        if not isinstance(record, Message):
            if isinstance(record, Channel):
                schema = scan.schemas.get(record.schema_id)
                resolved[record.id] = (record.topic, schema.name if schema else '')
            continue
        if scan.record_offset != current:
            current = scan.record_offset
            while k < len(offsets) and offsets[k] < current:
                k += 1
            while heap and heap[0][0] <= later[k]:
                yield heapq.heappop(heap)
        topic_type = resolved.get(record.channel_id)
        if topic_type is not None:  # a message before its channel: skip it
            heapq.heappush(heap, (record.log_time, file_index, n, *topic_type, record.data))
            n += 1
    while heap:
        yield heapq.heappop(heap)


def read_metadata_yaml(directory):
    """Return the ``rosbag2_bagfile_information`` of ``directory/metadata.yaml``, or None."""
    try:
        meta = yaml.safe_load((Path(directory) / 'metadata.yaml').read_text())
        return dict(meta['rosbag2_bagfile_information'])
    except (yaml.YAMLError, KeyError, TypeError, ValueError, OSError):
        return None


def _find_bag_files(path: Path):
    """
    Return (metadata dict or None, .mcap paths to read, unlisted paths left out).

    A directory's files are those ``metadata.yaml`` lists, then any other ``.mcap`` file
    (a writer killed before it listed its newest split), except one that does not even
    start as MCAP: ``reindex`` leaves such a file out of the metadata and beside the bag.
    """
    if path.is_file():
        return None, [path], []
    meta = read_metadata_yaml(path)
    if meta is not None:
        files = [path / Path(p).name for p in meta.get('relative_file_paths', [])]
        files = [f for f in files if f.suffix == '.mcap']
        extra = sorted(set(path.glob('*.mcap')) - set(files), key=_split_index)
        left_out = [f for f in extra if not _starts_as_mcap(f)]
        return meta, files + [f for f in extra if f not in left_out], left_out
    return None, sorted(path.glob('*.mcap'), key=_split_index), []


def _starts_as_mcap(path: Path) -> bool:
    try:
        with open(path, 'rb') as f:
            return f.read(len(MCAP0_MAGIC)) == MCAP0_MAGIC
    except OSError:
        return False


def _split_index(path: Path):
    stem = path.stem
    tail = stem.rsplit('_', 1)[-1]
    return (int(tail) if tail.isdigit() else 0, path.name)


class BagReader:
    """
    Read a rosbag2 MCAP bag directory or a bare ``.mcap`` file.

    Use :attr:`topics` (name -> :class:`TopicInfo`) and :meth:`messages`. After each full
    pass, :attr:`problems` lists the :class:`Damage` of each file that could not be read to
    its end, and :attr:`unknown_types` maps each topic whose type is not installed to that
    type (those messages are still yielded, raw, with ``msg`` None), and
    :attr:`decode_errors` counts per topic the messages whose CDR would not deserialise.
    :attr:`files` are the files read, :attr:`left_out` the ``.mcap`` files beside them
    that neither ``metadata.yaml`` lists nor start as MCAP; :meth:`check_files` reads them
    all to tell which are damaged.
    """

    def __init__(self, path, warn=True):
        """Open the bag at ``path``: a directory or an ``.mcap`` file."""
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f'no bag at {self.path}')
        self.warn = warn
        self.metadata, self.files, self.left_out = _find_bag_files(self.path)
        if not self.files:
            raise FileNotFoundError(f'no .mcap files in {self.path}')
        missing = [str(f) for f in self.files if not f.exists()]
        self.problems = [Damage(m, 0, 'listed in metadata.yaml but missing') for m in missing]
        self.files = [f for f in self.files if f.exists()]
        self.unknown_types = {}
        self.decode_errors = {}
        self._topics = None

    @property
    def topics(self) -> dict:
        """
        Map each topic name to its :class:`TopicInfo`.

        Types, counts and QoS come from ``metadata.yaml`` when it lists topics (for a bag
        whose writer was killed, counts are those of its last metadata update; see
        ``bag_writer.reindex``); for a bare file or a directory without one, from a scan
        of the files (counts) and the MCAP channels (QoS, type hash).
        """
        if self._topics is None:
            self._topics = self._load_topics()
        return self._topics

    def _load_topics(self):
        topics = {}
        if self.metadata is not None:
            for entry in self.metadata.get('topics_with_message_count') or []:
                tm = entry['topic_metadata']
                topics[tm['name']] = TopicInfo(
                    tm['name'], tm['type'], int(entry.get('message_count', 0)),
                    ros_types.parse_qos(tm.get('offered_qos_profiles')),
                    tm.get('type_description_hash', '') or '',
                    tm.get('serialization_format', 'cdr'))
        if topics:
            return topics
        counts = {}
        channels = {}
        for f in self.files:
            scan = McapScan(f)
            for record in scan:
                ch = isinstance(record, Message) and scan.channels.get(record.channel_id)
                if ch:
                    counts[ch.topic] = counts.get(ch.topic, 0) + 1
            for ch in scan.channels.values():
                schema = scan.schemas.get(ch.schema_id)
                channels.setdefault(ch.topic, (ch, schema))
            self._note(scan)
        for topic, (ch, schema) in channels.items():
            topics[topic] = TopicInfo(
                topic, schema.name if schema else '', counts.get(topic, 0),
                ros_types.parse_qos(ch.metadata.get('offered_qos_profiles', '')),
                ch.metadata.get('topic_type_hash', ''), ch.message_encoding)
        return topics

    def _note(self, scan):
        if scan.damage is not None and scan.damage not in self.problems:
            self.problems.append(scan.damage)
            if self.warn:
                warnings.warn(str(scan.damage), BagDamageWarning, stacklevel=3)

    def __iter__(self):
        """Iterate ``(topic, msg_type, log_time_ns, raw_cdr_bytes)`` in log-time order."""
        for m in self.messages():
            yield m[:4]

    def messages(self, topics=None, deserialize=False, start_ns=None, end_ns=None):
        """
        Yield :class:`BagMessage` of every file, merged in log-time order.

        ``topics`` restricts to those names; ``deserialize`` fills ``msg`` with an rclpy
        message object when the type is installed (topics whose type is not are listed in
        :attr:`unknown_types`); ``start_ns``/``end_ns`` bound the log time (end exclusive).
        """
        wanted = set(topics) if topics is not None else None
        scans = [McapScan(f) for f in self.files]
        streams = [_file_messages(s, i) for i, s in enumerate(scans)]
        classes = {}
        deserialize_message = None
        if deserialize:
            from rclpy.serialization import deserialize_message
        try:
            for log, _, _, topic, msg_type, data in heapq.merge(*streams):
                if wanted is not None and topic not in wanted:
                    continue
                if (start_ns is not None and log < start_ns) or (
                        end_ns is not None and log >= end_ns):
                    continue
                msg = None
                if deserialize:
                    if msg_type not in classes:
                        classes[msg_type] = ros_types.message_class(msg_type)
                    cls = classes[msg_type]
                    if cls is None:
                        self.unknown_types.setdefault(topic, msg_type)
                    else:
                        try:
                            msg = deserialize_message(data, cls)
                        except Exception:  # noqa: B902 - bad CDR: yield raw, count it
                            self.decode_errors[topic] = self.decode_errors.get(topic, 0) + 1
                yield BagMessage(topic, msg_type, log, data, msg)
        finally:
            for s in scans:
                self._note(s)

    def check_files(self) -> list:
        """
        Read every file to its end, CRCs checked; return the :class:`Damage` of each bad one.

        A listed file that is missing counts too. :attr:`topics` may take its counts from
        ``metadata.yaml``, which cannot know of damage: this is what tells whether the
        files hold what it says (``reindex`` makes them agree).
        """
        found = [d for d in self.problems if 'missing' in d.reason]
        for f in self.files:
            scan = McapScan(f)
            for _ in scan:
                pass
            if scan.damage is not None:
                found.append(scan.damage)
        return found

    def unknown_topic_types(self) -> dict:
        """Return {topic: type} for the topics whose message type is not installed."""
        return {name: t.msg_type for name, t in self.topics.items()
                if ros_types.message_class(t.msg_type) is None}

    def message_definitions(self) -> dict:
        """Return {type name: (schema encoding, definition text)} from the files' schemas."""
        out = {}
        for f in self.files:
            for r in McapScan(f):
                if isinstance(r, Schema):
                    out.setdefault(r.name, (r.encoding, r.data.decode()))
        return out
