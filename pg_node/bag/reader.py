"""
Read rosbag2 MCAP bags, ours or anyone's, and survive damaged files.

A bag is either a rosbag2 directory (``metadata.yaml`` beside one or more ``.mcap`` files)
or a bare ``.mcap`` file. :class:`BagReader` lists the topics (type, message count, offered
QoS) and iterates the messages of all files in log-time order as raw CDR bytes, optionally
deserialised into the installed rclpy message classes.

Every file is read by a linear scan of its records, never through its summary section, so
a file whose writer was killed (no summary, no footer, a chunk cut in half) still yields
every message up to the damage. The reader then records a :class:`Damage` (file, byte
offset, reason) in :attr:`BagReader.problems` and carries on with the next file; it never
hangs on a corrupted length field, because every length is checked against the file size
before anything is read.
"""
import heapq
import os
from pathlib import Path
import struct
from typing import NamedTuple, Optional
import warnings
import zlib

from pg_node.bag import ros_types
import yaml

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER = 0x01
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_METADATA = 0x0C
OP_DATA_END = 0x0F

_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')
_RECORD_HEAD = struct.Struct('<BQ')
_MESSAGE_HEAD = struct.Struct('<HIQQ')
_CHUNK_HEAD = struct.Struct('<QQQI')


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


class Schema(NamedTuple):
    """An MCAP schema record."""

    id: int  # noqa: A003 - the MCAP record field's name
    name: str
    encoding: str
    data: bytes


class Channel(NamedTuple):
    """An MCAP channel record."""

    id: int  # noqa: A003 - the MCAP record field's name
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict


class _Malformed(Exception):
    pass


def _string(buf, pos):
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    if pos + n > len(buf):
        raise _Malformed('string runs past its record')
    return bytes(buf[pos:pos + n]).decode('utf-8'), pos + n


def _str_map(buf, pos):
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    end = pos + n
    if end > len(buf):
        raise _Malformed('map runs past its record')
    out = {}
    while pos < end:
        key, pos = _string(buf, pos)
        value, pos = _string(buf, pos)
        out[key] = value
    return out, end


def _parse_schema(body):
    (sid,) = _U16.unpack_from(body, 0)
    name, pos = _string(body, 2)
    encoding, pos = _string(body, pos)
    (n,) = _U32.unpack_from(body, pos)
    pos += 4
    if pos + n > len(body):
        raise _Malformed('schema data runs past its record')
    return Schema(sid, name, encoding, bytes(body[pos:pos + n]))


def _parse_channel(body):
    cid, sid = struct.unpack_from('<HH', body, 0)
    topic, pos = _string(body, 4)
    encoding, pos = _string(body, pos)
    metadata, pos = _str_map(body, pos)
    return Channel(cid, sid, topic, encoding, metadata)


def _decompress(compression, data, size):
    if compression == '':
        return data
    if compression == 'zstd':
        import zstandard
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == 'lz4':
        import lz4.frame
        return lz4.frame.decompress(data)
    raise _Malformed(f'unsupported chunk compression {compression!r}')


class McapScan:
    """
    Linear, damage-tolerant scan of one MCAP file.

    Iterating yields ``(kind, value)`` events in file order: ``('schema', Schema)``,
    ``('channel', Channel)``, ``('messages', [(channel_id, sequence, log_time,
    publish_time, data), ...])`` for each chunk (or loose message) and
    ``('metadata', (name, dict))``. After the iteration, :attr:`damage` is None for a
    complete file or the :class:`Damage` where reading stopped, and :attr:`end_offset` is
    the end of the last record read whole.
    """

    def __init__(self, path, verify_crc=True):
        """Prepare to scan ``path``; nothing is read until iteration."""
        self.path = str(path)
        self.verify_crc = verify_crc
        self.damage: Optional[Damage] = None
        self.complete = False
        self.end_offset = 0
        self.header = None
        self.schemas = {}
        self.channels = {}
        self.metadata = []
        self.chunks = 0

    def _stop(self, offset, reason):
        self.damage = Damage(self.path, offset, reason)

    def __iter__(self):
        """Yield the file's records as events, stopping cleanly at the first damage."""
        try:
            size = os.path.getsize(self.path)
            f = open(self.path, 'rb')
        except OSError as exc:
            self._stop(0, f'cannot open: {exc}')
            return
        with f:
            if f.read(8) != MAGIC:
                self._stop(0, 'not an MCAP file (bad magic)')
                return
            pos = 8
            self.end_offset = pos
            while True:
                head = f.read(9)
                if not head:
                    self._stop(pos, 'file ends without a footer (writer did not finish)')
                    return
                if len(head) < 9:
                    self._stop(pos, 'truncated record header')
                    return
                opcode, length = _RECORD_HEAD.unpack(head)
                if pos + 9 + length > size:
                    self._stop(pos, f'truncated record (opcode 0x{opcode:02x}, {length} bytes '
                                    f'declared, {size - pos - 9} left)')
                    return
                if opcode == OP_FOOTER:
                    self.end_offset = pos + 9 + length
                    self.complete = True
                    return
                if opcode not in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_METADATA,
                                  OP_HEADER):
                    f.seek(length, os.SEEK_CUR)
                    pos += 9 + length
                    self.end_offset = pos
                    if opcode == OP_DATA_END:
                        self.complete = True
                    continue
                body = f.read(length)
                try:
                    events = self._events(opcode, body)
                except (_Malformed, struct.error, UnicodeDecodeError, ValueError,
                        RuntimeError) as exc:
                    self._stop(pos, f'corrupted record (opcode 0x{opcode:02x}): {exc}')
                    return
                except Exception as exc:  # noqa: B902 - decompressor errors of any kind
                    self._stop(pos, f'corrupted record (opcode 0x{opcode:02x}): {exc!r}')
                    return
                pos += 9 + length
                self.end_offset = pos
                yield from events

    def _events(self, opcode, body):
        """Parse one top-level record whole (so that a bad chunk yields nothing)."""
        if opcode == OP_HEADER:
            profile, p = _string(body, 0)
            library, _ = _string(body, p)
            self.header = (profile, library)
            return []
        if opcode == OP_METADATA:
            name, p = _string(body, 0)
            data, _ = _str_map(body, p)
            self.metadata.append((name, data))
            return [('metadata', (name, data))]
        if opcode == OP_CHUNK:
            return self._chunk_events(body)
        return self._inner_events(opcode, memoryview(body), loose=True)

    def _chunk_events(self, body):
        _, _, usize, crc = _CHUNK_HEAD.unpack_from(body, 0)
        compression, p = _string(body, _CHUNK_HEAD.size)
        (n,) = _U64.unpack_from(body, p)
        p += 8
        if p + n > len(body):
            raise _Malformed('chunk records run past the chunk')
        data = _decompress(compression, bytes(body[p:p + n]), usize)
        if len(data) != usize:
            raise _Malformed(f'chunk decompressed to {len(data)} bytes, expected {usize}')
        if self.verify_crc and crc and zlib.crc32(data) != crc:
            raise _Malformed('chunk CRC mismatch')
        events, messages = [], []
        view = memoryview(data)
        q = 0
        while q < len(view):
            if q + 9 > len(view):
                raise _Malformed('truncated record inside chunk')
            opcode, length = _RECORD_HEAD.unpack_from(view, q)
            q += 9
            if q + length > len(view):
                raise _Malformed('record runs past the end of its chunk')
            inner = view[q:q + length]
            q += length
            if opcode == OP_MESSAGE:
                cid, seq, log, pub = _MESSAGE_HEAD.unpack_from(inner, 0)
                messages.append((cid, seq, log, pub, bytes(inner[_MESSAGE_HEAD.size:])))
            else:
                events += self._inner_events(opcode, inner, loose=False)
        self.chunks += 1
        events.append(('messages', messages))  # also when empty: one event per chunk
        return events

    def _inner_events(self, opcode, body, loose):
        if opcode == OP_SCHEMA:
            schema = _parse_schema(body)
            self.schemas[schema.id] = schema
            return [('schema', schema)]
        if opcode == OP_CHANNEL:
            channel = _parse_channel(body)
            self.channels[channel.id] = channel
            return [('channel', channel)]
        if opcode == OP_MESSAGE:
            cid, seq, log, pub = _MESSAGE_HEAD.unpack_from(body, 0)
            return [('messages', [(cid, seq, log, pub, bytes(body[_MESSAGE_HEAD.size:]))])]
        return []


def _record_start_times(path):
    """
    Return the earliest log time of each chunk and loose message, in file order.

    Reads only record headers (seeking over bodies), so it is cheap; it stops at the
    first record that runs past the end of the file.
    """
    starts = []
    try:
        size = os.path.getsize(path)
        with open(path, 'rb') as f:
            if f.read(8) != MAGIC:
                return starts
            pos = 8
            while pos + 9 <= size:
                f.seek(pos)
                opcode, length = _RECORD_HEAD.unpack(f.read(9))
                if pos + 9 + length > size or opcode == OP_FOOTER:
                    break
                if opcode == OP_CHUNK and length >= 16:
                    first, last = struct.unpack('<QQ', f.read(16))
                    # an empty chunk (schemas and channels only) holds nothing back
                    starts.append(float('inf') if first == last == 0 else first)
                elif opcode == OP_MESSAGE and length >= 14:
                    starts.append(struct.unpack('<6xQ', f.read(14))[0])
                pos += 9 + length
    except OSError:
        pass
    return starts


def _file_messages(scan, file_index):
    """
    Yield ``(log_time, file_index, n, topic, msg_type, data)`` in log-time order.

    A heap holds the messages read so far; one is given out once no later chunk of the
    file can hold an earlier message, which the chunk headers' start times tell (read
    ahead of time). Ties keep file order.
    """
    starts = _record_start_times(scan.path)
    later = [float('inf')] * (len(starts) + 1)
    for i in range(len(starts) - 1, -1, -1):
        later[i] = min(starts[i], later[i + 1])
    heap = []
    n = 0
    k = 0
    resolved = {}
    for kind, value in scan:
        if kind == 'channel':
            schema = scan.schemas.get(value.schema_id)
            resolved[value.id] = (value.topic, schema.name if schema else '')
        if kind != 'messages':
            continue
        bound = later[k] if k < len(later) else float('inf')
        k += 1
        while heap and heap[0][0] <= bound:
            yield heapq.heappop(heap)
        for cid, _, log, _, data in value:
            topic_type = resolved.get(cid)
            if topic_type is not None:  # a message before its channel: skip it
                heapq.heappush(heap, (log, file_index, n, topic_type[0], topic_type[1], data))
                n += 1
    while heap:
        yield heapq.heappop(heap)


def _find_bag_files(path: Path):
    """Return (metadata dict or None, list of .mcap paths) for a bag dir or .mcap file."""
    if path.is_file():
        return None, [path]
    meta_path = path / 'metadata.yaml'
    if meta_path.is_file():
        try:
            meta = yaml.safe_load(meta_path.read_text())['rosbag2_bagfile_information']
        except (yaml.YAMLError, KeyError, TypeError, OSError):
            meta = None
        if meta is not None:
            files = [path / Path(p).name for p in meta.get('relative_file_paths', [])]
            files = [f for f in files if f.suffix == '.mcap']
            extra = sorted(set(path.glob('*.mcap')) - set(files), key=_split_index)
            return meta, files + extra
    return None, sorted(path.glob('*.mcap'), key=_split_index)


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
    """

    def __init__(self, path, warn=True):
        """Open the bag at ``path``: a directory or an ``.mcap`` file."""
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f'no bag at {self.path}')
        self.warn = warn
        self.metadata, self.files = _find_bag_files(self.path)
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
            for kind, value in scan:
                if kind == 'messages':
                    for m in value:
                        ch = scan.channels.get(m[0])
                        if ch is not None:
                            counts[ch.topic] = counts.get(ch.topic, 0) + 1
            for ch in scan.channels.values():
                schema = scan.schemas.get(ch.schema_id)
                channels.setdefault(ch.topic, (ch, schema))
            self._note(scan)
        for topic, (ch, schema) in channels.items():
            if topic in topics and self.metadata is not None:
                continue
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

    def unknown_topic_types(self) -> dict:
        """Return {topic: type} for the topics whose message type is not installed."""
        return {name: t.msg_type for name, t in self.topics.items()
                if ros_types.message_class(t.msg_type) is None}

    def message_definitions(self) -> dict:
        """Return {type name: (schema encoding, definition text)} from the files' schemas."""
        out = {}
        for f in self.files:
            scan = McapScan(f)
            for kind, value in scan:
                if kind == 'schema':
                    out.setdefault(value.name, (value.encoding, value.data.decode()))
        return out
