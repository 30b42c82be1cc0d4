"""
Tests of pg_node.bag.reader on bags it did not write, and on damaged ones.

Bags come from the PyPI ``rosbags`` writer (MCAP storage, metadata version 9) and from
pg_node's writer, then get truncated or corrupted on purpose.
"""
import os
from pathlib import Path
import shutil
import struct
import warnings

import numpy as np
from pg_node.bag.reader import BagDamageWarning, BagReader, McapScan
from pg_node.bag.writer import BagWriter
import pytest
from rclpy.serialization import serialize_message
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.serde import SerdeError
from rosbags.typesys import get_types_from_msg, get_typestore, Stores
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

T0 = 1_700_000_000_000_000_000
BLOB_MSG = 'uint8[] data\nstring note\n'
INF = QosTime(9223372036, 854775807)


def _rosbags_qos(reliability=QosReliability.RELIABLE, depth=10):
    return Qos(QosHistory.KEEP_LAST, depth, reliability, QosDurability.VOLATILE, INF, INF,
               QosLiveliness.AUTOMATIC, INF, False)


@pytest.fixture(scope='module')
def rosbags_bag(tmp_path_factory):
    """Write a bag with the rosbags package: MCAP storage, one topic of an unknown type."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(BLOB_MSG, 'pg_test_msgs/msg/Blob'))
    path = tmp_path_factory.mktemp('rosbags') / 'foreign'
    Blob = store.types['pg_test_msgs/msg/Blob']
    StringT = store.types['std_msgs/msg/String']
    JS = store.types['sensor_msgs/msg/JointState']
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']
    expected = []
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        chat = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=store,
                                     offered_qos_profiles=[_rosbags_qos()])
        joints = writer.add_connection(
            '/joint_states', 'sensor_msgs/msg/JointState', typestore=store,
            offered_qos_profiles=[_rosbags_qos(QosReliability.BEST_EFFORT, 5)])
        blob = writer.add_connection('/blob', 'pg_test_msgs/msg/Blob', typestore=store,
                                     offered_qos_profiles=[_rosbags_qos()])
        for i in range(30):
            t = T0 + i * 1_000_000
            writer.write(chat, t, store.serialize_cdr(StringT(data=f'hello {i}'),
                                                      'std_msgs/msg/String'))
            expected.append(('/chatter', t, f'hello {i}'))
            js = JS(header=Header(stamp=Time(sec=1, nanosec=i), frame_id='base'),
                    name=['a', 'b'], position=np.array([i, -i], dtype=float),
                    velocity=np.array([0.5, 0.5]), effort=np.array([1.0, 2.0]))
            writer.write(joints, t + 10, store.serialize_cdr(js, 'sensor_msgs/msg/JointState'))
            expected.append(('/joint_states', t + 10, float(i)))
            b = Blob(data=np.array([i % 256, 7], dtype=np.uint8), note='x')
            writer.write(blob, t + 20, store.serialize_cdr(b, 'pg_test_msgs/msg/Blob'))
            expected.append(('/blob', t + 20, None))
    return path, expected


def test_reads_a_bag_written_by_rosbags(rosbags_bag):
    path, expected = rosbags_bag
    reader = BagReader(path)
    topics = reader.topics
    assert {n: (t.msg_type, t.message_count) for n, t in topics.items()} == {
        '/chatter': ('std_msgs/msg/String', 30),
        '/joint_states': ('sensor_msgs/msg/JointState', 30),
        '/blob': ('pg_test_msgs/msg/Blob', 30)}
    qos = topics['/joint_states'].offered_qos_profiles[0]
    assert (qos['reliability'], qos['depth']) == ('best_effort', 5)
    assert reader.unknown_topic_types() == {'/blob': 'pg_test_msgs/msg/Blob'}
    got = []
    for m in reader.messages(deserialize=True):
        if m.topic == '/chatter':
            assert isinstance(m.msg, String)
            got.append((m.topic, m.log_time_ns, m.msg.data))
        elif m.topic == '/joint_states':
            assert isinstance(m.msg, JointState)
            assert list(m.msg.effort) == [1.0, 2.0] and m.msg.header.frame_id == 'base'
            got.append((m.topic, m.log_time_ns, m.msg.position[0]))
        else:
            assert m.msg is None and m.msg_type == 'pg_test_msgs/msg/Blob'
            assert len(m.data) > 0
            got.append((m.topic, m.log_time_ns, None))
    assert got == expected                          # all of them, in log-time order
    assert reader.unknown_types == {'/blob': 'pg_test_msgs/msg/Blob'}
    assert reader.problems == []
    definitions = reader.message_definitions()
    assert definitions['pg_test_msgs/msg/Blob'][1].startswith('uint8[] data')


def test_plain_iteration_gives_four_tuples(rosbags_bag):
    path, expected = rosbags_bag
    items = list(BagReader(path))
    assert len(items) == len(expected)
    topic, msg_type, t, data = items[0]
    assert (topic, msg_type, t) == ('/chatter', 'std_msgs/msg/String', expected[0][1])
    assert isinstance(data, bytes)


def test_bare_mcap_file_and_topic_filter(rosbags_bag):
    path, expected = rosbags_bag
    mcap_file = next(path.glob('*.mcap'))
    reader = BagReader(mcap_file)
    assert reader.topics['/chatter'].message_count == 30
    assert reader.topics['/joint_states'].offered_qos_profiles[0]['reliability'] == 'best_effort'
    chatter = list(reader.messages(topics=['/chatter'], start_ns=T0 + 5_000_000))
    assert [m.log_time_ns for m in chatter] == [t for n, t, _ in expected
                                                if n == '/chatter' and t >= T0 + 5_000_000]


def _write_numbered(directory, n, chunk_size=2048, **kwargs):
    """Write n Float64MultiArray messages whose data[0] is their index; return their times."""
    times = []
    kwargs.setdefault('compression', 'none')
    with BagWriter(directory, chunk_size=chunk_size, **kwargs) as w:
        w.add_topic('/numbers', Float64MultiArray)
        for i in range(n):
            t = T0 + i * 1000
            w.write('/numbers', Float64MultiArray(data=[float(i)] * 8), t)
            times.append(t)
    return times


def _indices(reader):
    out = []
    for m in reader.messages(deserialize=True):
        out.append(int(m.msg.data[0]))
    return out


@pytest.mark.timeout(60)
@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_truncated_file_yields_a_prefix_and_says_where(tmp_path, compression):
    _write_numbered(tmp_path / 'full', 2000, compression=compression)
    mcap_file = tmp_path / 'full' / 'full_0.mcap'
    size = mcap_file.stat().st_size
    with open(mcap_file, 'r+b') as f:
        f.truncate(size // 2)
    reader = BagReader(tmp_path / 'full')
    with pytest.warns(BagDamageWarning, match='full_0.mcap'):
        got = _indices(reader)
    assert 0 < len(got) < 2000
    assert got == list(range(len(got)))
    assert len(reader.problems) == 1
    damage = reader.problems[0]
    assert damage.path == str(mcap_file)
    assert 0 < damage.offset <= size // 2
    assert 'truncated' in damage.reason
    assert str(damage).startswith(str(mcap_file))


@pytest.mark.timeout(60)
def test_corrupted_chunk_stops_there(tmp_path):
    _write_numbered(tmp_path / 'bad', 1000)
    path = tmp_path / 'bad' / 'bad_0.mcap'
    scan = McapScan(path)
    chunk_offsets = []
    with open(path, 'rb') as f:
        data = f.read()
    pos = 8
    while pos < len(data) - 8:
        opcode, length = struct.unpack_from('<BQ', data, pos)
        if opcode == 0x06:
            chunk_offsets.append(pos)
        if opcode == 0x0F:
            break
        pos += 9 + length
    assert len(chunk_offsets) > 4
    bad = chunk_offsets[3]
    corrupted = bytearray(data)
    corrupted[bad + 200] ^= 0xFF                     # inside the chunk's records: CRC fails
    path.write_bytes(bytes(corrupted))
    reader = BagReader(path, warn=False)
    got = _indices(reader)
    assert got == list(range(len(got))) and 0 < len(got) < 1000
    assert [d.offset for d in reader.problems] == [bad]
    assert 'CRC' in reader.problems[0].reason
    del scan


@pytest.mark.timeout(60)
def test_absurd_length_field_does_not_hang_or_allocate(tmp_path):
    _write_numbered(tmp_path / 'huge', 300)
    path = tmp_path / 'huge' / 'huge_0.mcap'
    data = bytearray(path.read_bytes())
    # the first record after the header record: make its length 2**62
    header_len = struct.unpack_from('<Q', data, 9)[0]
    second = 8 + 9 + header_len
    struct.pack_into('<Q', data, second + 1, 2**62)
    path.write_bytes(bytes(data))
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagDamageWarning)
        reader = BagReader(path)
        assert list(reader.messages()) == []
    assert reader.problems[0].offset == second


def test_multi_file_bag_is_merged_in_log_time_order(tmp_path):
    """Chunks and files whose times overlap still come out sorted by log time."""
    rng = np.random.default_rng(3)
    times = (T0 + rng.permutation(3000) * 1000).tolist()
    with BagWriter(tmp_path / 'mixed', chunk_size=1024, split_max_messages=700,
                   compression='none') as w:
        for i, t in enumerate(times):
            w.write('/numbers', Float64MultiArray(data=[float(i)]), t)
    assert len(list((tmp_path / 'mixed').glob('*.mcap'))) == 5
    reader = BagReader(tmp_path / 'mixed')
    got = [m.log_time_ns for m in reader.messages()]
    assert got == sorted(times)
    assert reader.topics['/numbers'].message_count == 3000


def test_directory_without_metadata_yaml(tmp_path):
    _write_numbered(tmp_path / 'nometa', 500, split_max_messages=200)
    os.remove(tmp_path / 'nometa' / 'metadata.yaml')
    reader = BagReader(tmp_path / 'nometa')
    assert [f.name for f in reader.files] == ['nometa_0.mcap', 'nometa_1.mcap',
                                              'nometa_2.mcap']
    assert reader.topics['/numbers'].message_count == 500
    assert _indices(reader) == list(range(500))


def test_missing_file_is_reported(tmp_path):
    _write_numbered(tmp_path / 'gone', 500, split_max_messages=200)
    shutil.move(tmp_path / 'gone' / 'gone_1.mcap', tmp_path / 'elsewhere.mcap')
    reader = BagReader(tmp_path / 'gone', warn=False)
    assert [Path(d.path).name for d in reader.problems] == ['gone_1.mcap']
    assert len(_indices(reader)) == 300


def test_empty_float64_arrays_fast_cdr_padding(tmp_path):
    """
    Fast CDR (rclpy) pads before an empty float64[]; we and rclpy read it back.

    The PyPI rosbags 0.11.9 deserialiser rejects such messages ("CDR message size
    mismatch"): JointState must fill position, velocity and effort for rosbags readers.
    This test fails (and should be updated) once rosbags accepts the padding.
    """
    js = JointState(name=['a', 'b'], position=[1.0, 2.0])   # velocity, effort empty
    with BagWriter(tmp_path / 'pad') as w:
        w.write('/joint_states', js, T0)
    (m,) = list(BagReader(tmp_path / 'pad').messages(deserialize=True))
    assert list(m.msg.position) == [1.0, 2.0] and list(m.msg.effort) == []
    # the bag holds rclpy's bytes. Fast CDR does not initialise its alignment filler: the
    # last 8 bytes (where the empty float64[] would align) differ from one serialisation to
    # the next (a clean-clone CI run saw byte 72 differ), so only the bytes before them
    # can be compared
    expected = serialize_message(js)
    assert len(m.data) == len(expected) == 76 and m.data[:68] == expected[:68]
    store = get_typestore(Stores.ROS2_JAZZY)
    with pytest.raises(SerdeError):
        store.deserialize_cdr(m.data, 'sensor_msgs/msg/JointState')
